"""Run under mpiexec: a small compression with ParaView snapshots (``ParaViewWriter``).

Usage: ``mpiexec -n K python paraview_run.py OUTDIR``. Writes the snapshots in ``OUTDIR/vtk``,
``OUTDIR/run.json`` (rank 0: global counts, deck values, time step, snapshot steps) and, for the
test to compare the pieces with, ``OUTDIR/state-rRRRR.npz`` (each rank: its owned gids, positions,
velocities and reference positions at the end, i.e. at the last snapshot).
"""
import json
import os
import sys

import numpy as np

from pardem.protocols.compression import build_case
from pardem.config import check_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.io.paraview import ParaViewWriter
from pardem.parallel.communicator import Communicator

K = 8                 # elements per box edge
R = 0.25e-3           # element radius [m]
STEPS, EVERY = 40, 10

out = sys.argv[1]
comm = Communicator()
deck = check_deck(COMPRESS_SCHEMA, {
    "domain": {"box": [2 * R * K] * 3, "radius": R},
    "bonds": {"young": 1e8, "radius_ratio": 0.5, "damping": 0.1},
    "loading": {"plate_speed": 2.0, "strain": 0.02, "ramp_time": 0.0},
    # slabs along the load and a tiny skin: the ghost layers are rebuilt between snapshots
    "parallel": {"slab_axis": "x"},
    "run": {"skin": 0.002e-3},
})
case = build_case(comm, deck)
sim = case.sim
sim.run(STEPS, operations=[ParaViewWriter(os.path.join(out, "vtk"), comm, EVERY)])

e = sim.elements
n = e.n_owned
np.savez(os.path.join(out, f"state-r{comm.rank:04d}.npz"), gid=e.gid[:n], x=e.x[:n], v=e.v[:n],
         x0=e.x0[:n], radius=e.radius[:n])
if comm.is_root:
    with open(os.path.join(out, "run.json"), "w") as fh:
        json.dump({"ranks": comm.size, "k": K, "radius": R, "young": 1e8, "radius_ratio": 0.5,
                   "n_elements": case.constants.n_elements, "n_bonds": case.constants.n_bonds, "dt": sim.dt,
                   "steps": list(range(EVERY, STEPS + 1, EVERY)), "last_step": sim.step_count}, fh)
