"""GRAN benchmark on one rank: Hertz-Mindlin with history in a periodic simple cubic packing.

Issue 5, item 8 (the single-rank kernel part; the MPI slabs do not carry contacts yet):
N = n^3 monodisperse spheres, R = 0.1 mm, density 2500 kg/m^3, E = 72 GPa (G = 30 GPa, Poisson 0.2),
friction 0.5, no gravity, no damping; simple cubic lattice of spacing 1.998 R jittered uniformly
by +-0.0002 R per axis (seed 12345) in a periodic box of side n * 1.998 R; dt = 1e-8 s; 100 warm-up
steps then 2000 timed steps; n = 20, 40, 60.

    python benchmarks/bench_gran.py [--sizes 20 40 60] [--steps 2000]

Each step: half kick and drift (pardem.physics.verlet), the Verlet-list check (skin 0.1 R) and,
when needed, a rebuild with the tangential history carried over by pair gids, the contact loop
(pardem.physics.hertz_mindlin), second half kick. Prints and writes JSON with element-steps per
second, wall time per step and whether the list was rebuilt during the timed steps.
"""
import argparse
import json
import os
import time

import numpy as np

from pardem.physics import hertz_mindlin
from pardem.physics.neighbours import VerletList
from pardem.physics.verlet import kick, kick_drift, kinetic_energy
from pardem.state import Elements

R, RHO, DT = 0.1e-3, 2500.0, 1e-8
PARAMS = hertz_mindlin.Params(young=72e9, poisson=0.2, friction=0.5)


class Granular:
    """Elements in a periodic box with a Verlet list and per-pair tangential history."""

    def __init__(self, n):
        rng = np.random.default_rng(12345)
        a = 1.998 * R
        g = np.arange(n) * a + 0.5 * a
        X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
        pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
        pos += rng.uniform(-0.0002 * R, 0.0002 * R, size=pos.shape)
        self.e = Elements.from_spheres(pos, R, RHO)
        self.box = np.full(3, n * a)
        self.vl = VerletList(0.1 * R, periodic=(True, True, True), box_lo=np.zeros(3), box_hi=self.box)
        self.history = np.zeros((0, 3))
        self.keys = np.zeros(0, dtype=np.int64)
        self.rebuilds = 0
        self._rebuild()

    def _rebuild(self):
        e = self.e
        self.vl.rebuild(e.x, e.radius, e.gid, e.n_owned)
        self.i, self.j, self.shift = self.vl.kernel_arrays()
        keys = e.gid[self.i] * (e.n_total + 1) + e.gid[self.j]      # history keyed by the gid pair
        hist = np.zeros((len(keys), 3))
        if len(self.keys):
            order = np.argsort(self.keys)
            pos = np.searchsorted(self.keys[order], keys)
            pos = np.minimum(pos, len(order) - 1)
            hit = self.keys[order][pos] == keys
            hist[hit] = self.history[order[pos[hit]]]
        self.history, self.keys = hist, keys
        self.rebuilds += 1

    def step(self):
        e = self.e
        kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, DT, e.n_owned)
        if self.vl.needs_rebuild(e.x):
            self._rebuild()
        energy = hertz_mindlin.compute(PARAMS, e, self.i, self.j, self.history, DT, self.shift)
        kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, DT, e.n_owned)
        return energy

    def energy(self):
        e = self.e
        return kinetic_energy(e.v, e.w, e.mass, e.inertia, e.n_owned)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[20, 40, 60])
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "bench_gran.json"))
    args = p.parse_args()
    rows = []
    for n in args.sizes:
        g = Granular(n)
        for _ in range(args.warmup):
            g.step()
        r0 = g.rebuilds
        t0 = time.perf_counter()
        for _ in range(args.steps):
            u = g.step()
        wall = time.perf_counter() - t0
        N = n**3
        row = {"n": n, "elements": N, "pairs": int(len(g.i)), "steps": args.steps, "dt": DT,
               "seconds": wall, "seconds_per_step": wall / args.steps,
               "element_steps_per_second": N * args.steps / wall,
               "rebuilds_during_timed_steps": g.rebuilds - r0,
               "kinetic_plus_elastic_energy_end": float(g.energy() + u)}
        rows.append(row)
        print(f"n = {n:3d}: {N:7d} spheres {row['pairs']:8d} pairs  {wall:7.2f} s  "
              f"{1e3 * row['seconds_per_step']:7.3f} ms/step  {row['element_steps_per_second']:.3e} element-steps/s  "
              f"rebuilds during timed steps: {row['rebuilds_during_timed_steps']}", flush=True)
    with open(args.out, "w") as fh:
        json.dump({"benchmark": "gran", "ranks": 1, "results": rows}, fh, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
