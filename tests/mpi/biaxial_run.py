"""The 2-rank halves of tests/test_biaxial.py: ``biaxial_run.py MODE OUT.npz``.

MODE ``open``: ``test_biaxial.open_run`` (a case opened by ``pardem.engine.open_cell``);
MODE ``membrane``: ``test_biaxial.membrane_run`` (the membrane load on several ranks).
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from pardem.parallel.communicator import Communicator  # noqa: E402
import test_biaxial  # noqa: E402

if __name__ == "__main__":
    comm = Communicator()
    mode, out = sys.argv[1], sys.argv[2]
    state = {"open": test_biaxial.open_run, "membrane": getattr(test_biaxial, "membrane_run", None)}[mode](comm)
    if comm.is_root:
        np.savez(out, **state)
