"""Where a GRAN or GRAN-SHEAR step spends its time, per kernel and per rank.

    python benchmarks/profile_gran.py [--n 40] [--steps 500] [--repeats 3]
    mpiexec -n 2 python benchmarks/profile_gran.py --n 40
    python benchmarks/profile_gran.py --case shear --n 8000     # N spheres (shear_case.py)
    python benchmarks/profile_gran.py --case shear --n 8000 --kernel 100   # the contact loop alone

Builds the GRAN case of ``bench_gran.py``, runs the warm-up, then times ``--steps`` steps of
``Simulation.run`` with a timer around each piece of ``Simulation.step`` (the wrappers cost about a
microsecond a call; ``--clock cpu`` times with the process's CPU clock): the first half kick and drift, the second half kick, the contact force loop,
the slab layer's update (ghost refresh, with its displacement reduction; rebuilds counted apart),
the single-process rebuild check, the list rebuilds, and the rest (Python between the calls, the
stability checks of ``run``); inside a rebuild, the cell's wrap, the cell-list build
(``VerletList.rebuild``: binning, sort, scan) and the history carried over (``contacts.lookup``);
the periodic cell's affine step. The best of ``--repeats`` rounds is reported per piece (a loaded
machine only adds time), in microseconds per step and as a share of the step.

``--kernel K``: instead, after the warm-up, time ``K`` force evaluations (``Contacts.compute``,
without the energy, as the steps between operations) on the fixed list, best of ``--repeats``
rounds: microseconds per call and nanoseconds per listed pair (one rank).
"""
import argparse
import time
from collections import defaultdict

import numpy as np

import shear_case
from pardem.engine import contacts as contacts_mod
from pardem.engine import periodic_cell
from pardem.engine import simulation
from pardem.engine.granular import simple_cubic
from pardem.engine.system import Cell, ContactModel, Decomposition, Integration, Particles, System, build
from pardem.parallel import slab_comm
from pardem.physics import neighbours
from pardem.parallel.communicator import Communicator

R, RHO, DT = 0.1e-3, 2500.0, 1e-8
PARAMS = {"young": 72e9, "poisson": 0.2, "friction": 0.5}
SPENT = defaultdict(float)
CLOCK = [time.perf_counter]
CALLS = defaultdict(int)


def timed(name, fn):
    def wrapper(*a, **k):
        t0 = CLOCK[0]()
        try:
            return fn(*a, **k)
        finally:
            SPENT[name] += CLOCK[0]() - t0
            CALLS[name] += 1
    return wrapper


def instrument():
    simulation.kick_drift = timed("kick_drift", simulation.kick_drift)
    simulation.kick = timed("kick", simulation.kick)
    C = contacts_mod.Contacts
    C.compute = timed("contact loop", C.compute)
    C.rebuild = timed("  contact list rebuild", C.rebuild)
    C.needs_rebuild = timed("rebuild check", C.needs_rebuild)
    S = slab_comm.SlabComm
    S.forward = timed("ghost forward", S.forward)
    S.update = timed("slab update", S.update)
    simulation.Simulation.check_stability = timed("stability check", simulation.Simulation.check_stability)
    neighbours.VerletList.rebuild = timed("  cell list build (in rebuild)", neighbours.VerletList.rebuild)
    contacts_mod.lookup = timed("  history lookup (in rebuild)", contacts_mod.lookup)
    periodic_cell.PeriodicCell.deform = timed("cell affine step", periodic_cell.PeriodicCell.deform)
    periodic_cell.PeriodicCell.wrap = timed("  cell wrap (at rebuilds)", periodic_cell.PeriodicCell.wrap)
    simulation.Simulation.rebuild_contacts = timed("list rebuild (1 rank)", simulation.Simulation.rebuild_contacts)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--case", choices=["gran", "shear"], default="gran")
    p.add_argument("--n", type=int, default=40, help="GRAN: spheres per edge; GRAN-SHEAR: spheres")
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                   help="cpu: this process's CPU time (steadier on a loaded machine; MPI waits "
                        "spin, so they count as busy)")
    p.add_argument("--kernel", type=int, default=0,
                   help="time this many contact force evaluations on the fixed list instead")
    p.add_argument("--orientation", choices=["on", "off"], default="on",
                   help="integrate the grains' orientations (as bench_gran.py --orientation)")
    args = p.parse_args()
    CLOCK[0] = time.perf_counter if args.clock == "wall" else time.process_time
    comm = Communicator()
    if args.case == "shear":
        N = args.n
        system = shear_case.system(shear_case.load(N), orientation=args.orientation == "on")
    else:
        N = args.n**3
        pos, side = simple_cubic(args.n, R, spacing=1.998, jitter=0.0002, seed=12345)
        system = System(Particles(pos, R, RHO), contacts=ContactModel("hertz_mindlin", PARAMS),
                        cell=Cell(np.zeros(3), np.full(3, side)),
                        integration=Integration(dt=DT, orientation=args.orientation == "on"),
                        decomposition=Decomposition(slab_axis=0, skin=0.1 * R))
    sim = build(comm, system)
    sim.run(200 if args.case == "shear" else 100)
    if args.kernel > 0:
        c, e = sim.contacts, sim.elements
        best = np.inf
        for _ in range(args.repeats):
            t0 = CLOCK[0]()
            for _ in range(args.kernel):
                c.compute(e, sim.dt, with_energy=False)
            best = min(best, (CLOCK[0]() - t0) / args.kernel)
        if comm.is_root:
            print(f"{args.case.upper()} n = {args.n}: contact loop alone on {len(c.i)} listed pairs "
                  f"({int(c.n_touching)} touching, rows sorted: {c.sorting(e.n_owned)}), best of "
                  f"{args.repeats} x {args.kernel}: {1e6 * best:.1f} us/call, "
                  f"{1e9 * best / max(len(c.i), 1):.1f} ns per listed pair")
        return
    instrument()
    best, best_wall = None, np.inf
    for _ in range(args.repeats):
        SPENT.clear()
        CALLS.clear()
        comm.barrier()
        t0 = CLOCK[0]()
        sim.run(args.steps)
        comm.barrier()
        wall = CLOCK[0]() - t0
        if wall < best_wall:
            best_wall, best = wall, (dict(SPENT), dict(CALLS))
    spent, calls = best
    # the slab update contains the forward refresh and any rebuild: split them
    # (indented names are parts of another piece: a rebuild's)
    if "slab update" in spent:
        spent["slab update: rebuild"] = spent.get("  contact list rebuild", 0.0)
        spent["slab update (reduction, check, migration, ghosts)"] = (
            spent.pop("slab update") - spent.get("ghost forward", 0.0) - spent["slab update: rebuild"])
    rows = sorted(spent.items(), key=lambda kv: (kv[0].startswith(" "), -kv[1]))
    other = best_wall - sum(v for k, v in spent.items() if not k.startswith(" "))
    table = comm.gather((rows, other, best_wall, dict(calls)))
    pairs = comm.sum(len(sim.contacts.i))
    if comm.is_root:
        print(f"{args.case.upper()} n = {args.n} ({N} elements), {comm.size} rank(s), {args.steps} steps, best of "
              f"{args.repeats}: {1e6 * best_wall / args.steps:.1f} us/step, "
              f"{N * args.steps / best_wall:.3e} element-steps/s; {pairs} pairs listed at the end")
        for r, (rows, other, wall, calls) in enumerate(table):
            print(f"rank {r}:")
            for name, s in rows + [("rest (Python, run loop)", other)]:
                print(f"  {name:34s} {1e6 * s / args.steps:9.1f} us/step  {100 * s / wall:5.1f} %"
                      f"  calls {calls.get(name, '-')}")


if __name__ == "__main__":
    main()
