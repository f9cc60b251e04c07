"""GRAN benchmark: Hertz-Mindlin with history in a periodic simple cubic packing, 1 or more ranks.

Issue 5, item 8: N = n^3 monodisperse spheres, R = 0.1 mm, density 2500 kg/m^3, E = 72 GPa
(G = 30 GPa, Poisson 0.2), friction 0.5, no gravity, no damping; simple cubic lattice of spacing
1.998 R jittered uniformly by +-0.0002 R per axis (seed 12345) in a periodic box of side
n * 1.998 R; dt = 1e-8 s; 100 warm-up steps then 2000 timed steps; n = 20, 40, 60.

    python benchmarks/bench_gran.py [--sizes 20 40 60] [--steps 2000] [--reproducible off]
    mpiexec -n 2 python benchmarks/bench_gran.py

``--reproducible off`` sets ``pardem.engine.contacts.REPRODUCIBLE = False`` (lists in cell order,
float sums; issue 16 item 8 asks what the bitwise rank independence costs). ``--orientation off``
builds the case with ``orientation=False``: the grains' orientations are not integrated (no contact
force reads them, and LAMMPS' ``fix nve/sphere`` does not integrate them either); the trajectory
is the same to the bit (``energy_end``).

The case is the engine's (``pardem.engine.system.build``: slabs along x, which is periodic, so the
first and last ranks are neighbours; Verlet list with skin 0.1 R; ``Simulation.run``). Prints and
writes JSON (``results/bench_gran_<P>ranks.json``) with element-steps per second, wall time per step,
the CPU seconds of the timed steps (largest over the ranks; on a loaded machine the 1-rank figure
of merit that other processes do not change much),
the share of time in communication and whether the lists were rebuilt during the timed steps.
"""
import argparse
import json
import os
import time

import numpy as np

from pardem.engine import contacts as contacts_mod
from pardem.engine.granular import simple_cubic
from pardem.engine.system import Cell, ContactModel, Decomposition, Integration, Particles, System, build
from pardem.parallel.communicator import Communicator

R, RHO, DT = 0.1e-3, 2500.0, 1e-8
PARAMS = {"young": 72e9, "poisson": 0.2, "friction": 0.5}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[20, 40, 60])
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--out", default=None)
    p.add_argument("--reproducible", choices=["on", "off"], default="on",
                   help="contacts.REPRODUCIBLE (default on, the library's default)")
    p.add_argument("--orientation", choices=["on", "off"], default="on",
                   help="integrate the grains' orientations (default on, the library's default; "
                        "LAMMPS' fix nve/sphere does not)")
    args = p.parse_args()
    contacts_mod.REPRODUCIBLE = args.reproducible == "on"
    comm = Communicator()
    out = args.out or os.path.join(os.path.dirname(__file__), "results", f"bench_gran_{comm.size}ranks.json")
    rows = []
    for n in args.sizes:
        pos, side = simple_cubic(n, R, spacing=1.998, jitter=0.0002, seed=12345)
        system = System(Particles(pos, R, RHO), contacts=ContactModel("hertz_mindlin", PARAMS),
                        cell=Cell(np.zeros(3), np.full(3, side)),
                        integration=Integration(dt=DT, orientation=args.orientation == "on"),
                        decomposition=Decomposition(slab_axis=0, skin=0.1 * R))
        sim = build(comm, system)
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
        rebuilt = comm.max(sim.contacts.builds - b0)
        N = n**3
        mem = comm.sum(sim.elements.nbytes() + sim.contacts.nbytes())
        row = {"n": n, "elements": N, "ranks": comm.size, "steps": args.steps, "dt": DT,
               "pairs_listed": int(comm.sum(len(sim.contacts.i))),
               "contacts": int(comm.sum(sim.contacts.n_touching)),
               "seconds": wall, "seconds_per_step": wall / args.steps,
               "cpu_seconds": float(comm.max(cpu)),
               "element_steps_per_second": N * args.steps / wall,
               "communication_share": float(comm.max(comm_s)) / wall,
               "rebuilds_during_timed_steps": int(rebuilt),
               "reproducible": sim.contacts.reproducible, "orientation": sim.orientation,
               "bytes_per_element": float(mem) / N,
               "energy_end": float(sim.kinetic_energy() + comm.sum(sim.contact_energy))}
        rows.append(row)
        if comm.is_root:
            print(f"n = {n:3d}: {N:7d} spheres on {comm.size} rank(s) {row['contacts']:8d} contacts  "
                  f"{wall:7.2f} s  {1e3 * row['seconds_per_step']:7.3f} ms/step  "
                  f"{row['element_steps_per_second']:.3e} element-steps/s  comm {100 * row['communication_share']:.1f} %  "
                  f"rebuilds during timed steps: {row['rebuilds_during_timed_steps']}  "
                  f"{row['bytes_per_element']:.0f} B/element", flush=True)
    if comm.is_root:
        with open(out, "w") as fh:
            json.dump({"benchmark": "gran", "ranks": comm.size, "results": rows}, fh, indent=2)
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
