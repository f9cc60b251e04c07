"""Where the default compress job's time goes, next to ``bench_bond.py`` on the same lattice (issue 14, item 4).

    python benchmarks/profile_compress.py [--steps 1000] [--warmup 100] [--repeats 3] [--out FILE.json]
    mpiexec -n 2 python benchmarks/profile_compress.py ...
    python benchmarks/profile_compress.py --ranks 1 2      # both, the 2-rank run through mpiexec

Three cases of the same 21^3 simple cubic lattice, each built once and warmed up, then run
``--steps`` steps in turn, interleaved (A B C A B C ...) for ``--repeats`` rounds:

* ``compress``: the default compress job (``pardem.protocols.compression.build_case`` of the empty
  deck: bonds damped at 0.2, auto time step and ramp) with the operations its driver runs: the
  series sampler every ``n_steps // 200`` steps feeding the CSV and HDF5 series and the progress
  line, and the checkpoint writer (1800 s default: it looks at the clock every 10 steps, a
  broadcast on several ranks);
* ``bench``: ``bench_bond.py``'s case (``bond_case.bond_deck(21, 21, 21)``: undamped, no operations);
* ``bench_damped``: the same with the compress job's damping ratio 0.2 (``bench_bond.py --damping 0.2``);
* ``compress_row_flush``: ``compress`` with the HDF5 series written and flushed at every row
  (``SeriesH5(flush_seconds=0)``, the behaviour before its row buffer).

Every piece of ``Simulation.step`` and ``run`` is timed by a wrapper (a few hundred nanoseconds a
call): the bond force loop, the walls (plates), contacts, the Verlet kicks, the slab layer's update
(ghost exchange, migrations and rebuilds, balance checks: all the per-step communication), the
stability checks (a reduction every 50 steps), each operation (its sinks timed apart). "Python
overhead" is the rest of the timed ``run`` (the loop, the trigger tests, the step's Python between
the kernels, the wrappers themselves). The bond loop's damping share is measured apart on the
case's own state: the damped and the undamped compiled loop alternately on the same arrays
(best of many calls), the difference times the loop's calls.

The machine may be loaded by other jobs: times are CPU seconds of each process
(``time.process_time``, ``--clock wall`` for wall time), which other load changes less than wall
time; MPICH waits by spinning, so on 2 ranks a rank waiting for the other counts that wait in the
exchange (and a rank descheduled by other load makes its partner spin). The best round (smallest
total) of each case is reported. The series rows are also timed in wall time (rank 0): a flush
waits for the file system, which CPU time does not see. Prints a table per rank count; writes
JSON (``--out``).
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict

import numpy as np

from bond_case import bond_deck

from pardem.config import check_deck
from pardem.engine import contacts as contacts_mod
from pardem.engine import simulation
from pardem.io.checkpoint_writer import CheckpointWriter
from pardem.io.progress import Progress
from pardem.io.series import SeriesCSV
from pardem.io.series_h5 import SeriesH5
from pardem.parallel import slab_comm
from pardem.parallel.communicator import Communicator
from pardem.physics import beam
from pardem.protocols.compression import SeriesSampler, build_case, checkpoint_payload
from pardem.protocols.compression_deck import COMPRESS_SCHEMA

CLOCK = [time.process_time]
SPENT = defaultdict(float)
SPENT_WALL = defaultdict(float)   # wall time of the same calls (file I/O waits are not CPU time)
CALLS = defaultdict(int)

# the table's rows: (label, timer names summed)
ROWS = [("bond kernel, elastic part", ("bond kernel",)),       # minus the damping share below
        ("bond damping (in the kernel)", ()),
        ("walls / contacts", ("walls", "contacts")),
        ("verlet (kick_drift + kick)", ("kick_drift", "kick")),
        ("exchange / communication", ("slab update",)),
        ("stability checks", ("stability check",)),
        ("op: sampler (reducer)", ("sampler",)),
        ("op: series CSV + HDF5", ("series csv", "series h5")),
        ("op: progress", ("progress",)),
        ("op: checkpoint trigger", ("checkpoint",)),
        ("Python overhead", ())]


def timed(name, fn):
    def wrapper(*a, **k):
        t0, w0 = CLOCK[0](), time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            SPENT[name] += CLOCK[0]() - t0
            SPENT_WALL[name] += time.perf_counter() - w0
            CALLS[name] += 1
    return wrapper


class TimedOp:
    """An operation with its ``trigger`` and ``at_end``, timed under ``name``."""

    def __init__(self, name, op):
        self.name, self.op = name, op
        self.trigger, self.at_end = op.trigger, getattr(op, "at_end", False)

    def __call__(self, sim):
        t0 = CLOCK[0]()
        try:
            self.op(sim)
        finally:
            SPENT[self.name] += CLOCK[0]() - t0
            CALLS[self.name] += 1


def instrument():
    """Timers around the pieces of a step (module globals of ``pardem.engine.simulation``)."""
    simulation.compute_bonds = timed("bond kernel", simulation.compute_bonds)
    simulation.kick_drift = timed("kick_drift", simulation.kick_drift)
    simulation.kick = timed("kick", simulation.kick)
    simulation.walls.compute = timed("walls", simulation.walls.compute)
    contacts_mod.Contacts.compute = timed("contacts", contacts_mod.Contacts.compute)
    slab_comm.SlabComm.update = timed("slab update", slab_comm.SlabComm.update)
    simulation.Simulation.check_stability = timed("stability check", simulation.Simulation.check_stability)


def damping_share(sim, calls=200):
    """Fraction of the bond loop's time spent in its damping terms on ``sim``'s current state: the
    damped and the undamped loop alternately on copies of the force arrays (CPU time, best of
    ``calls`` calls each). 0 for undamped bonds."""
    b, e = sim.bonds, sim.elements
    if not b.damped or b.n == 0:
        return 0.0
    densify = b.densify_p0 > 0.0
    f, t = e.f.copy(), e.t.copy()
    best = {}
    for damped in (True, False) * calls:
        loop = beam.bond_loop(damped, b.breakable, densify)
        state, plastic = b.state.copy(), b.plastic.copy()
        t0 = time.process_time()
        loop(b.i, b.j, e.x, e.v, e.w, e.q, f, t, b.L0, b.ka, b.kb, b.kt, b.tau_a, b.tau_t, b.rot_damping,
             b.u1, b.p1, b.u2, b.p2, state, b.f_tensile, b.f_shear, b.f_yield, plastic,
             b.densify_p0 if densify else 1.0, e.n_owned)
        dt = time.process_time() - t0
        best[damped] = min(best.get(damped, np.inf), dt)
    return max(0.0, 1.0 - best[False] / best[True])


class Case:
    def __init__(self, comm, name, folder):
        self.name, self.comm = name, comm
        self.closers = []
        if name.startswith("compress"):
            self.case = build_case(comm, check_deck(COMPRESS_SCHEMA, {}))
            # compress_row_flush: the HDF5 series written and flushed at every row, as before the
            # row buffer of SeriesH5 (flush_seconds = 0 is that behaviour)
            self.operations = self._compress_operations(os.path.join(folder, name),
                                                        0.0 if name == "compress_row_flush" else None)
        else:
            self.case = build_case(comm, bond_deck(21, 21, 21, damping=0.2 if name == "bench_damped" else 0.0),
                                   steps=10**9)
            self.operations = []
        self.sim = self.case.sim

    def _compress_operations(self, folder, flush_seconds=None):
        """The operations of ``pardem.drivers.compress`` (``Compress.start`` and ``run_protocol``)."""
        comm, case, sim = self.comm, self.case, self.case.sim
        if comm.is_root:
            os.makedirs(folder, exist_ok=True)
        deck = case.deck
        every = deck["output"]["series_every"] or max(1, case.n_steps // 200)
        progress = Progress(comm, case.n_steps, deck["run"]["progress_seconds"], int(comm.sum(sim.elements.n_owned)),
                            stream=open(os.devnull, "w"))
        sinks = []
        if comm.is_root:
            csv = SeriesCSV(os.path.join(folder, "series.csv"))
            h5 = SeriesH5(os.path.join(folder, "series.h5"), samples=case.samples,
                          **({} if flush_seconds is None else {"flush_seconds": flush_seconds}))
            self.closers += [csv.close, h5.close]
            sinks += [timed("series csv", csv.append), timed("series h5", h5.append)]
        axis = case.constants.axis
        sinks.append(timed("progress", lambda s: progress.report(
            s["step"], f"t = {s['time']:.4e} s  eps = {s['eps'][axis, axis]:+.4e}  F = {s['force_fixed']:.4e} N")))
        sampler = SeriesSampler(case, every, sinks)
        ck = deck["checkpoint"]
        writer = CheckpointWriter(lambda: checkpoint_payload(case), os.path.join(folder, "checkpoints"),
                                  ck["every_steps"], ck["every_seconds"], ck["keep"], ck["driver"],
                                  start_step=sim.step_count)
        # the checkpoint writer's period of looks (None: it never looks)
        self.sample_every, self.checkpoint_every = every, getattr(writer.trigger, "period", None)
        return [TimedOp("sampler", sampler), TimedOp("checkpoint", writer)]

    def run(self, steps):
        """Run ``steps`` steps; returns this rank's timers and totals for them."""
        SPENT.clear()
        SPENT_WALL.clear()
        CALLS.clear()
        d = self.sim.domain
        r0 = d.rebuilds if d is not None else 0
        self.comm.barrier()
        w0, c0 = time.perf_counter(), CLOCK[0]()
        self.sim.run(steps, self.operations)
        total = CLOCK[0]() - c0
        wall = time.perf_counter() - w0
        self.comm.barrier()
        spent = dict(SPENT)
        # the sinks run inside the sampler: keep the sampler's own time
        spent["sampler"] = spent.get("sampler", 0.0) - sum(spent.get(k, 0.0) for k in ("series csv", "series h5",
                                                                                      "progress"))
        series_wall = sum(SPENT_WALL.get(k, 0.0) for k in ("series csv", "series h5"))
        return {"total": total, "wall": wall, "spent": spent, "calls": dict(CALLS), "series_wall": series_wall,
                "rebuilds": (d.rebuilds if d is not None else 0) - r0}

    def close(self):
        for c in self.closers:
            c()


def table_rows(result, share):
    """Seconds per step of every row of ``ROWS`` (this rank), the damping split out of the bond loop."""
    steps, spent = result["steps"], result["spent"]
    out = {}
    for label, names in ROWS:
        out[label] = sum(spent.get(k, 0.0) for k in names) / steps
    bond = out["bond kernel, elastic part"]
    out["bond damping (in the kernel)"] = share * bond
    out["bond kernel, elastic part"] = (1.0 - share) * bond
    out["Python overhead"] = result["total"] / steps - sum(v for k, v in out.items() if k != "Python overhead")
    return out


def profile(args):
    """Run the interleaved rounds on this communicator; returns the JSON-able result (every rank)."""
    comm = Communicator()
    if args.clock == "wall":
        CLOCK[0] = time.perf_counter
    folder = tempfile.mkdtemp(prefix="profile_compress_") if comm.is_root else None
    folder = comm.bcast(folder)
    names = ["compress", "bench", "bench_damped", "compress_row_flush"]
    cases = {n: Case(comm, n, folder) for n in names}
    for c in cases.values():
        c.sim.run(args.warmup, c.operations)
    instrument()
    best = {}
    for _ in range(args.repeats):
        for n in names:
            r = cases[n].run(args.steps)
            r["steps"] = args.steps
            # rank totals: the slowest rank sets the pace
            r["total_max"] = float(comm.max(r["total"]))
            r["wall_max"] = float(comm.max(r["wall"]))
            if n not in best or r["total_max"] < best[n]["total_max"]:
                best[n] = r
    out = {"ranks": comm.size, "steps": args.steps, "repeats": args.repeats, "clock": args.clock, "cases": {}}
    for n in names:
        c, r = cases[n], best[n]
        share = damping_share(c.sim)
        rows = table_rows(r, share)
        per_rank = comm.comm.allgather(rows)
        n_el = c.case.constants.n_elements
        out["cases"][n] = {
            "elements": n_el, "bonds": c.case.constants.n_bonds, "dt": c.sim.dt,
            "damped": bool(c.sim.bonds.damped), "damping_share_of_bond_loop": share,
            "rows_seconds_per_step_per_rank": per_rank,
            "rows_seconds_per_step_mean": {k: float(np.mean([p[k] for p in per_rank])) for k in rows},
            "seconds_per_step_max_rank": r["total_max"] / r["steps"],
            "wall_seconds_per_step": r["wall_max"] / r["steps"],
            "element_steps_per_cpu_second": n_el * r["steps"] / r["total_max"],
            "element_steps_per_second": n_el * r["steps"] / r["wall_max"],
            "rebuilds": r["rebuilds"], "calls": r["calls"],
            "bond_kernel_seconds_per_step": float(comm.comm.allreduce(r["spent"].get("bond kernel", 0.0))
                                                  / comm.size / r["steps"]),
            "series_wall_seconds_per_step_rank0": float(comm.bcast(r["series_wall"])) / r["steps"],
            **({"sample_every": c.sample_every, "checkpoint_every": c.checkpoint_every,
                "n_steps_of_the_job": c.case.n_steps} if n.startswith("compress") else {}),
        }
        c.close()
    comm.barrier()
    if comm.is_root:
        shutil.rmtree(folder, ignore_errors=True)
    return out


def print_table(res):
    cases = res["cases"]
    names = list(cases)
    unit = "CPU" if res["clock"] == "cpu" else "wall"
    print(f"\n{res['ranks']} rank(s), {res['steps']} steps, best of {res['repeats']} interleaved rounds; "
          f"ms per step ({unit} time, mean over ranks)")
    print(f"{'':34s}" + "".join(f"{n:>14s}" for n in names) + f"{'compress - bench':>18s}")
    for label, _ in ROWS:
        vals = [cases[n]["rows_seconds_per_step_mean"][label] * 1e3 for n in names]
        print(f"{label:34s}" + "".join(f"{v:14.4f}" for v in vals) + f"{vals[0] - vals[1]:18.4f}")
    tot = [sum(cases[n]["rows_seconds_per_step_mean"].values()) * 1e3 for n in names]
    print(f"{'total (mean rank)':34s}" + "".join(f"{v:14.4f}" for v in tot) + f"{tot[0] - tot[1]:18.4f}")
    for key, label in (("bond_kernel_seconds_per_step", "bond kernel, all of it"),
                       ("series_wall_seconds_per_step_rank0", "series CSV + HDF5, wall, rank 0")):
        vals = [cases[n][key] * 1e3 for n in names]
        print(f"{label:34s}" + "".join(f"{v:14.4f}" for v in vals) + f"{vals[0] - vals[1]:18.4f}")
    for key, fmt in (("element_steps_per_cpu_second", "{:14.3e}"), ("element_steps_per_second", "{:14.3e}")):
        print(f"{key.replace('_', ' '):34s}" + "".join(fmt.format(cases[n][key]) for n in names))
    ratio = cases["compress"]["element_steps_per_cpu_second"] / cases["bench"]["element_steps_per_cpu_second"]
    ratio_d = cases["compress"]["element_steps_per_cpu_second"] / cases["bench_damped"]["element_steps_per_cpu_second"]
    ratio_w = cases["compress"]["element_steps_per_second"] / cases["bench"]["element_steps_per_second"]
    ratio_f = (cases["compress_row_flush"]["element_steps_per_second"]
               / cases["bench"]["element_steps_per_second"])
    print(f"compress / bench (wall): {ratio_w:.3f}, with the per-row HDF5 flush of before: {ratio_f:.3f}")
    print(f"compress / bench (per CPU s): {ratio:.3f};  compress / bench_damped: {ratio_d:.3f};  "
          f"rebuilds: " + ", ".join(f"{n} {cases[n]['rebuilds']}" for n in names)
          + f";  damping share of the bond loop: {cases['compress']['damping_share_of_bond_loop']:.3f}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--clock", choices=["cpu", "wall"], default="cpu")
    p.add_argument("--ranks", type=int, nargs="+", default=None,
                   help="run on each of these rank counts (rank counts > 1 through mpiexec) and print all tables")
    p.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                                 "profile_compress.json"))
    args = p.parse_args()
    if args.ranks:
        results = []
        mpiexec = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
        for n in args.ranks:
            with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
                path = fh.name
            cmd = [sys.executable, os.path.abspath(__file__), "--steps", str(args.steps), "--warmup",
                   str(args.warmup), "--repeats", str(args.repeats), "--clock", args.clock, "--out", path]
            subprocess.run(([mpiexec, "-n", str(n)] if n > 1 else []) + cmd, check=True)
            with open(path) as fh:
                results.append(json.load(fh))
            os.unlink(path)
        for r in results:
            print_table(r)
        _write(args.out, {"benchmark": "profile_compress", "results": results})
        return
    res = profile(args)
    if Communicator().is_root:
        print_table(res)
        _write(args.out, res)


def _write(path, payload):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as fh:
        json.dump(payload, fh, indent=2)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
