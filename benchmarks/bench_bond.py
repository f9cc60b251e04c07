"""BOND benchmark: bonded simple cubic lattice compressed between plates (issue 2, item 8).

n^3 elements (n = 21, 40, 60), R = 0.25 mm, density 1000 kg/m^3, beam bonds E = 100 MPa, bond
radius = R, Poisson 0.3, no damping; frictionless plates normal to x, fixed at x_min, moving at
-0.05 m/s at x_max; dt = 1e-7 s; 100 warm-up steps, then 2000 timed steps.

    python benchmarks/bench_bond.py [--sizes 21 40 60] [--steps 2000] [--out benchmarks/results/bench_bond.json]

Prints and writes JSON: seconds, wall time per step and element-steps per second per size, and the
memory of the state in bytes per element. Run on one rank (the per-core figure).
"""
import argparse
import json
import os
import platform
import time

import numpy as np

from pardem.bonding import BeamMaterial, make_bonds
from pardem.domains.ordered import ordered_lattice
from pardem.parallel.communicator import Communicator
from pardem.physics.timestep import critical_time_step, eigen_bound
from pardem.simulation import Simulation
from pardem.state import Elements, Plates

R = 0.25e-3
DT = 1e-7


def build(n, comm):
    pos, pairs, frame = ordered_lattice([n * 2 * R] * 3, R)
    e = Elements.from_spheres(pos, R, 1000.0)
    b = make_bonds(e, pairs, BeamMaterial(young=100e6, radius_ratio=1.0, poisson=0.3, damping=0.0), frame)
    k_plate = float(np.mean(b.ka))
    plates = Plates.pair(0, pos[:, 0].min() - R, pos[:, 0].max() + R, 0.05, k_plate, ramp_time=0.0)
    lam = eigen_bound(b.i, b.j, b.L0, b.ka, b.kb, b.kt, e.mass, e.inertia, e.n_owned, k_plate / e.mass)
    dt_c = critical_time_step(lam)
    assert DT < dt_c, f"dt {DT} above critical {dt_c}"
    return Simulation(comm, e, b, plates, DT), dt_c


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[21, 40, 60])
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "bench_bond.json"))
    args = p.parse_args()
    comm = Communicator()
    results = []
    for n in args.sizes:
        sim, dt_c = build(n, comm)
        sim.run(args.warmup)
        t0 = time.perf_counter()
        sim.run(args.steps)
        wall = time.perf_counter() - t0
        ne, nb = sim.elements.n_owned, sim.bonds.n
        row = {
            "n": n, "elements": ne, "bonds": nb, "steps": args.steps, "dt": DT, "dt_critical": dt_c,
            "seconds": wall, "seconds_per_step": wall / args.steps,
            "element_steps_per_second": ne * args.steps / wall,
            "bytes_per_element": (sim.elements.nbytes() + sim.bonds.nbytes()) / ne,
            "plate_force_end": float(sim.plates.force_local[0]),
        }
        results.append(row)
        print(f"n = {n:3d}: {ne:8d} elements {nb:8d} bonds  {wall:8.3f} s  "
              f"{1e3 * row['seconds_per_step']:8.3f} ms/step  {row['element_steps_per_second']:.3e} element-steps/s  "
              f"{row['bytes_per_element']:.0f} B/element", flush=True)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump({"benchmark": "bond", "ranks": comm.size, "machine": platform.machine(),
                   "processor": platform.processor(), "cpus": os.cpu_count(), "results": results}, fh, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
