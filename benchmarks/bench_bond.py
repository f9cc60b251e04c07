"""BOND benchmark: bonded simple cubic lattice compressed between plates (issue 2, item 8).

n^3 elements (n = 21, 40, 60), R = 0.25 mm, density 1000 kg/m^3, beam bonds E = 100 MPa, bond
radius = R, Poisson 0.3, no damping; frictionless plates normal to x, fixed at x_min, moving at
-0.05 m/s at x_max; dt = 1e-7 s; 100 warm-up steps, then 2000 timed steps.

    python benchmarks/bench_bond.py [--sizes 21 40 60] [--steps 2000] [--damping 0.2] [--out FILE.json]

Prints and writes JSON: seconds, wall time per step and element-steps per second per size (also
per CPU second of the timed steps, ``element_steps_per_cpu_second``, which other load on a shared
machine changes less), and the memory of the state in bytes per element. One rank: the per-core
figure (see scaling.py for MPI). ``--damping`` gives the bonds a damping ratio (default 0, the peer
case of compare_peers.py; the compress job's bonds have 0.2, so its own figure compares with
``--sizes 21 --damping 0.2``).
"""
import argparse
import json
import os
import platform
import time

from bond_case import DT, bond_deck

from pardem.protocols.compression import build_case
from pardem.parallel.communicator import Communicator


def time_case(comm, deck, warmup, steps):
    """Build the case, run warm-up steps, then time ``steps`` steps; a result row (every rank)."""
    case = build_case(comm, deck, steps=steps)
    sim = case.sim
    sim.run(warmup)
    comm.barrier()
    c0 = sim.seconds_computing
    m0 = sim.domain.seconds_communicating if sim.domain else 0.0
    t0, p0 = time.perf_counter(), time.process_time()
    sim.run(steps)
    cpu = time.process_time() - p0
    comm.barrier()
    wall = time.perf_counter() - t0
    comp = comm.comm.allgather(sim.seconds_computing - c0)
    comm_s = comm.comm.allgather((sim.domain.seconds_communicating if sim.domain else 0.0) - m0)
    mem = comm.sum(sim.elements.nbytes() + sim.bonds.nbytes())
    return {
        "elements": case.constants.n_elements, "bonds": case.constants.n_bonds, "ranks": comm.size, "steps": steps,
        "dt": DT, "dt_critical": case.constants.dt_critical, "seconds": wall, "seconds_per_step": wall / steps,
        "cpu_seconds": float(comm.max(cpu)),
        "element_steps_per_second": case.constants.n_elements * steps / wall,
        "element_steps_per_second_per_rank": case.constants.n_elements * steps / wall / comm.size,
        "element_steps_per_cpu_second": case.constants.n_elements * steps / float(comm.max(cpu)),
        "seconds_computing_per_rank": comp, "seconds_communicating_per_rank": comm_s,
        "bytes_per_element": float(mem) / case.constants.n_elements,
        "slab_axis": "xyz"[case.constants.slab_axis],
    }


def write(path, payload):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as fh:
        json.dump({**payload, "machine": platform.machine(), "cpus": os.cpu_count()}, fh, indent=2)
    print(f"wrote {path}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[21, 40, 60])
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--damping", type=float, default=0.0, help="bond damping ratio (default 0: the peer case)")
    p.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "bench_bond.json"))
    args = p.parse_args()
    comm = Communicator()
    results = []
    for n in args.sizes:
        row = {"n": n, "damping": args.damping,
               **time_case(comm, bond_deck(n, n, n, damping=args.damping), args.warmup, args.steps)}
        results.append(row)
        if comm.is_root:
            print(f"n = {n:3d}: {row['elements']:8d} elements {row['bonds']:8d} bonds  {row['seconds']:8.3f} s  "
                  f"{1e3 * row['seconds_per_step']:8.3f} ms/step  {row['element_steps_per_second']:.3e} "
                  f"element-steps/s  {row['element_steps_per_cpu_second']:.3e} per CPU s  "
                  f"{row['bytes_per_element']:.0f} B/element", flush=True)
    if comm.is_root:
        write(args.out, {"benchmark": "bond", "ranks": comm.size, "damping": args.damping, "results": results})


if __name__ == "__main__":
    main()
