"""Granular case for the parallel tests: a frictional Hertz gas in a periodic cell.

    python granular_run.py OUT.npz STEPS [--checkpoint-at K PATH] [--restart PATH] [--servo]
        [--slab-axis A] [--law hertz_mindlin|linear]

Writes the owned state gathered on rank 0, sorted by gid (x, v, w, and the contact histories keyed
by gid pair), plus per-step kinetic and contact energies.
"""
import argparse

import numpy as np

from pardem import restart

from pardem.engine import granular
from pardem.engine.contacts import pair_keys
from pardem.parallel.communicator import Communicator
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from _util import granular_case

R = 0.1e-3
p = argparse.ArgumentParser()
p.add_argument("out")
p.add_argument("steps", type=int)
p.add_argument("--checkpoint-at", nargs=2)
p.add_argument("--restart")
p.add_argument("--servo", action="store_true")
p.add_argument("--slab-axis", type=int, default=0)
p.add_argument("--law", default="hertz_mindlin")
p.add_argument("--n", type=int, default=9)
p.add_argument("--random", action="store_true", help="uniform random centres, radii R (1 +- 0.2)")
p.add_argument("--rate", type=float, default=None, help="isotropic strain rate of the cell [1/s]")
a = p.parse_args()
comm = Communicator()

if a.restart:
    case = restart.load_case(comm, a.restart)
else:
    pos, L = granular.simple_cubic(a.n, R, spacing=2.02, jitter=0.01, seed=7)
    rng = np.random.default_rng(3)
    radii = R * rng.uniform(0.97, 1.03, len(pos))
    if a.random:
        pos = rng.uniform(0.0, L, pos.shape)
        radii = R * rng.uniform(0.8, 1.2, len(pos))
    vel = rng.normal(0.0, 3.0, pos.shape)
    omega = rng.normal(0.0, 3e4, pos.shape)
    params = ({"young": 72e9, "poisson": 0.2, "friction": 0.5, "restitution": 0.9}
              if a.law == "hertz_mindlin" else {"kn": 2e5, "kt": 1.5e5, "friction": 0.4, "restitution": 0.8})
    servo = (5e6, 2e-6, 20.0) if a.servo else None
    rate = (0.0, 0.0, 0.0) if a.servo else (-300.0, -200.0, -100.0)
    if a.rate is not None:
        rate = (a.rate,) * 3
    case = granular_case(comm, pos, radii, 2500.0, a.law, params, np.zeros(3), np.full(3, L), 1e-8,
                          0.05 * R, rate=rate, servo=servo, velocities=vel,
                          angular_velocities=omega, slab_axis=a.slab_axis, balance_every=50,
                          allow_overlaps=a.random)    # uniform random centres overlap
sim = case.sim
energies = []


class Record:
    trigger = 1

    def __call__(self, s):
        energies.append((s.step_count, s.kinetic_energy(), float(comm.sum(s.contact_energy)),
                         float(comm.sum(s.contacts.n_touching))))


ops = [Record()]
if a.checkpoint_at:
    k, path = int(a.checkpoint_at[0]), a.checkpoint_at[1]

    class Write:
        trigger = k

        def __call__(self, s):
            if s.step_count == k:
                restart.save(case.sim, extras=case.extras, path=path)
    ops.append(Write())
sim.run(a.steps - sim.step_count, ops)

e = sim.elements
n = e.n_owned
c = sim.contacts
live = np.any(c.history != 0.0, axis=1) & c.counted_once(n)
parts = comm.comm.gather({"gid": e.gid[:n], "x": e.x[:n], "v": e.v[:n], "w": e.w[:n],
                         "radius": e.radius[:n],
                         "keys": c.keys[live], "hist": c.history[live],
                         "pairs": pair_keys(e.gid[c.i], e.gid[c.j])}, root=0)
if comm.rank == 0:
    cat = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    o = np.argsort(cat["gid"])
    ho = np.argsort(cat["keys"])
    np.savez(a.out, gid=cat["gid"][o], x=cat["x"][o], v=cat["v"][o], w=cat["w"][o],
             radius=cat["radius"][o], skin=c.skin,
             keys=cat["keys"][ho], hist=cat["hist"][ho], energies=np.array(energies),
             pairs=np.unique(cat["pairs"]), length=sim.cell.length, rate=sim.cell.rate,
             cuts=sim.domain.slabs.cut_s if sim.domain is not None else np.zeros(0))
if comm.rank == 0:
    import sys
    print("rebuilds", c.builds, "contacts", len(cat["keys"]), "rebalances",
          getattr(sim.domain, "rebalances", 0), file=sys.stderr)
