"""GRAN-SHEAR benchmark (``shear_case.py``): a sheared dense random packing, 1 or more ranks.

    python benchmarks/bench_shear.py [--n 8000] [--warmup 200] [--steps 2000]
    mpiexec -n 2 python benchmarks/bench_shear.py --n 64000

Builds the case (``pardem.engine.system.build``: slabs along x, Hertz-Mindlin with history,
orientations not integrated, as LAMMPS' ``fix nve/sphere``), runs the warm-up, then times
``--steps`` steps of ``Simulation.run`` between two barriers. Writes JSON (``--out``) with the
element-steps per second, the CPU seconds of the timed steps (largest over the ranks), the list
builds during the timed steps, the contacts at the end, the bytes per element and the sanity line
(Z, Love-Weber stress with LAMMPS' sign, compression positive, peculiar kinetic energy).
"""
import argparse
import json
import os
import time

import numpy as np

import shear_case
from pardem.engine.reducer import granular_measures
from pardem.engine.system import build
from pardem.parallel.communicator import Communicator


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=8000)
    p.add_argument("--warmup", type=int, default=200)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--out", default=None)
    p.add_argument("--orientation", choices=["on", "off"], default="off")
    args = p.parse_args()
    comm = Communicator()
    out = args.out or os.path.join(os.path.dirname(__file__), "results", f"bench_shear_{comm.size}ranks.json")
    st = shear_case.load(args.n)
    sim = build(comm, shear_case.system(st, orientation=args.orientation == "on"))
    sim.run(args.warmup)
    b0 = sim.contacts.builds
    c0 = sim.domain.seconds_communicating if sim.domain is not None else 0.0
    comm.barrier()
    t0, p0 = time.perf_counter(), time.process_time()
    sim.run(args.steps)
    cpu = time.process_time() - p0
    comm.barrier()
    wall = time.perf_counter() - t0
    comm_s = (sim.domain.seconds_communicating if sim.domain is not None else 0.0) - c0
    m = granular_measures(sim)
    s = -np.asarray(m["stress"])
    mem = comm.sum(sim.elements.nbytes() + sim.contacts.nbytes())
    row = {"n": args.n, "elements": args.n, "ranks": comm.size, "steps": args.steps,
           "seconds": wall, "seconds_per_step": wall / args.steps, "cpu_seconds": float(comm.max(cpu)),
           "element_steps_per_second": args.n * args.steps / wall,
           "communication_share": float(comm.max(comm_s)) / wall,
           "rebuilds_during_timed_steps": int(comm.max(sim.contacts.builds - b0)),
           "pairs_listed": int(comm.sum(len(sim.contacts.i))), "contacts": int(m["n_contacts"]),
           "bytes_per_element": float(mem) / args.n,
           "sanity": {"Z": float(m["Z"]), "P": float(np.trace(s) / 3), "Pxx": float(s[0, 0]),
                      "Pyy": float(s[1, 1]), "Pzz": float(s[2, 2]), "ke": float(m["kinetic_energy"])}}
    if comm.is_root:
        print(f"GRAN-SHEAR N = {args.n} on {comm.size} rank(s): {wall:.2f} s  "
              f"{1e3 * row['seconds_per_step']:.3f} ms/step  {row['element_steps_per_second']:.3e} "
              f"element-steps/s  rebuilds {row['rebuilds_during_timed_steps']}  contacts {row['contacts']}  "
              f"{row['bytes_per_element']:.0f} B/element  sanity {row['sanity']}", flush=True)
        with open(out, "w") as fh:
            json.dump({"benchmark": "shear", "ranks": comm.size, "results": [row]}, fh, indent=2)


if __name__ == "__main__":
    main()
