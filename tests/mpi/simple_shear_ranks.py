"""A sheared periodic packing (tests/_shear_case.py) through flips on any number of ranks; rank 0
writes the final state by gid to argv[1] (an .npz) for tests/test_simple_shear.py."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

import _shear_case as sc  # noqa: E402
import pardem  # noqa: E402

comm = pardem.Communicator()
sim = pardem.build(comm, sc.system())
sim.run(700)
out = sc.state(sim)
out["flips"] = np.array(sim.cell.flips)
out["axis"] = np.array(-1 if sim.domain is None else sim.domain.slabs.axis)
if comm.rank == 0:
    np.savez(sys.argv[1], **out)
