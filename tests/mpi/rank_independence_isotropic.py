"""The isotropic sweep of a deck on any number of ranks, for tests/test_rank_independence.py.

    mpiexec -n P python rank_independence_isotropic.py DECK.toml OUT.npz [KEY=VALUE ...]

Runs ``pardem.protocols.isotropic.sweep`` over the deck's pressures (gas, servo compression,
equilibrium, moduli when enabled), then writes on rank 0 the owned state gathered and sorted by gid
(x, v, w), the cell edges, the time step and every number of the rows and details.
"""
import json
import sys

import numpy as np

from pardem.io.deck_file import load_deck
from pardem.parallel.communicator import Communicator
from pardem.protocols import isotropic as iso

deck_path, out = sys.argv[1], sys.argv[2]
deck = load_deck(iso.SCHEMA, deck_path, sys.argv[3:])
comm = Communicator()
rows, details, case = iso.sweep(comm, deck, deck["preparation"]["pressures"])

sim = case.sim
e = sim.elements
n = e.n_owned
parts = comm.gather({"gid": e.gid[:n], "x": e.x[:n], "v": e.v[:n], "w": e.w[:n]})
if comm.is_root:
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    o = np.argsort(cat["gid"])
    for d in details:      # wall times of this process
        d.pop("seconds", None)
        d.pop("moduli_seconds", None)
    np.savez(out, gid=cat["gid"][o], x=cat["x"][o], v=cat["v"][o], w=cat["w"][o],
             length=sim.cell.length, step=sim.step_count, dt=sim.dt,
             results=json.dumps({"rows": rows, "details": details}, sort_keys=True))
