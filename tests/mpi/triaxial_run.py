"""Cemented triaxial loading from a prepared checkpoint, for the parallel tests.

    python triaxial_run.py CHECKPOINT.h5 OUT.npz STEPS [--checkpoint-at K PATH] [--rate R]

Restores the granular case of CHECKPOINT (a cemented packing with the triaxial servo, written by
``tests/test_triaxial.py``), runs the loading until STEPS steps after its start, and writes the
owned state gathered on rank 0 sorted by gid (x, v, w), the cement histories keyed by gid pair, the
cell, and the sampled rows (``pardem.protocols.triaxial.COLUMNS``).
"""
import argparse

import numpy as np

from pardem import restart

from pardem.protocols import triaxial
from pardem.parallel.communicator import Communicator

p = argparse.ArgumentParser()
p.add_argument("checkpoint")
p.add_argument("out")
p.add_argument("steps", type=int)
p.add_argument("--checkpoint-at", nargs=2)
a = p.parse_args()
comm = Communicator()
case = restart.load_case(comm, a.checkpoint)
sim = case.sim
deck = {"output": {"samples": 20}}
ops = []
if a.checkpoint_at:
    k, path = int(a.checkpoint_at[0]), a.checkpoint_at[1]
    start = case.extras["triaxial_reference"]["step"]

    class Write:
        trigger = 1

        def __call__(self, s):
            if s.step_count == start + k:
                restart.save(case.sim, extras=case.extras, path=path)
    ops.append(Write())
rows = triaxial.load(case, deck, steps=a.steps, operations=ops)
intact, fading = triaxial.cementing.cement_counts(sim)
lost = int(round(float(comm.sum(float(sim.contacts.lost)))))

e = sim.elements
n = e.n_owned
c = sim.contacts
live = np.any(c.history != 0.0, axis=1) & c.counted_once(n)
parts = comm.comm.gather({"gid": e.gid[:n], "x": e.x[:n], "v": e.v[:n], "w": e.w[:n],
                          "keys": c.keys[live], "hist": c.history[live]}, root=0)
if comm.rank == 0:
    cat = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    o = np.argsort(cat["gid"])
    ho = np.argsort(cat["keys"])
    np.savez(a.out, gid=cat["gid"][o], x=cat["x"][o], v=cat["v"][o], w=cat["w"][o],
             keys=cat["keys"][ho], hist=cat["hist"][ho], length=sim.cell.length,
             rate=sim.cell.rate, intact=intact, lost=lost, builds=sim.contacts.builds, fading=fading, step=sim.step_count,
             rows=np.array([[r[k] for k in triaxial.COLUMNS] for r in rows]))
