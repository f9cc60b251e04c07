"""The 2-rank half of tests/test_membrane.py: ``membrane_allgatherv.py OUT.npz``.

``Communicator.allgatherv`` (rank r sends r + 2 int64s 10 r + i and 3 r float rows [r, i]; both
ranks must get the same rank-ordered result) and ``test_membrane.rebuild_runs`` on 2 ranks.
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from pardem.parallel.communicator import Communicator  # noqa: E402
import test_membrane  # noqa: E402

if __name__ == "__main__":
    comm = Communicator()
    r = comm.rank
    ints = comm.allgatherv(10 * r + np.arange(r + 2, dtype=np.int64))
    floats = comm.allgatherv(np.column_stack([np.full(3 * r, float(r)), np.arange(3 * r, dtype=np.float64)]))
    same = comm.allgather((ints.tolist(), floats.tolist()))
    state = {"ints": ints, "floats": floats, "same_on_both": np.array(int(all(s == same[0] for s in same)))}
    for slot, tag in ((None, "plain"), ((25, 20), "slot")):
        for k, v in test_membrane.rebuild_runs(comm, slot).items():
            state[f"{tag}_{k}"] = v
    if comm.is_root:
        np.savez(sys.argv[1], **state)
