"""The cemented triaxial test of a deck on any number of ranks, for tests/test_rank_independence.py.

    mpiexec -n P python rank_independence_triaxial.py DECK.toml OUT.npz [KEY=VALUE ...]

Builds the deck's gas, prepares it under the isotropic servo, cements it and loads it
(``pardem.protocols.triaxial``: build, prepare, cement, start_loading, load), then writes on rank
0 the owned state gathered and sorted by gid (x, v, w, q), the contact histories keyed by gid
pair, the cell, the preparation's measures and the loading rows (``triaxial.COLUMNS``).
"""
import sys

import numpy as np

from pardem.io.deck_file import load_deck
from pardem.parallel.communicator import Communicator
from pardem.protocols import triaxial

deck_path, out = sys.argv[1], sys.argv[2]
deck = load_deck(triaxial.SCHEMA, deck_path, sys.argv[3:])
comm = Communicator()
case = triaxial.build(comm, deck)
prep = triaxial.prepare(case, deck)
triaxial.cement(case, deck)
triaxial.start_loading(case, deck)
rows = triaxial.load(case, deck)

sim = case.sim
e, c = sim.elements, sim.contacts
n = e.n_owned
live = np.any(c.history != 0.0, axis=1) & c.counted_once(n)
parts = comm.gather({"gid": e.gid[:n], "x": e.x[:n], "v": e.v[:n], "w": e.w[:n], "q": e.q[:n],
                     "keys": c.keys[live], "hist": c.history[live]})
if comm.is_root:
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    o = np.argsort(cat["gid"])
    h = np.argsort(cat["keys"])
    np.savez(out, gid=cat["gid"][o], x=cat["x"][o], v=cat["v"][o], w=cat["w"][o], q=cat["q"][o],
             keys=cat["keys"][h], hist=cat["hist"][h], length=sim.cell.length, rate=sim.cell.rate,
             step=sim.step_count, dt=sim.dt,
             prep=np.array([prep["steps"], prep["pressure"], prep["kinetic_energy"],
                            prep["coordination"], float(prep["converged"])]),
             rows=np.array([[r[k] for k in triaxial.COLUMNS] for r in rows], dtype=float))
