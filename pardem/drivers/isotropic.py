"""Isotropic preparation of a frictionless granular packing at pressures p0, then its elastic moduli.

    python -m pardem.drivers.isotropic [--config deck.toml] [--set section.key=value ...]
        [--pressures 1e5,1e6,...] [--out DIR] [--steps N] [--restart CHECKPOINT.h5] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.isotropic --config drivers/isotropic_glass.toml

A gas of spheres in a periodic cell is compressed by a pressure servo, the kinetic energy removed
by FIRE (adaptive step) or global viscous damping, to static equilibrium at each p0 (ascending, the
same packing continued), measured (p, Z, Z without rattlers, solid fraction, normal force
distribution), then, with friction restored, probed
by small affine strain increments (isotropic and volume-preserving shear) for the bulk and shear
moduli, affine (no relaxation) and relaxed. The protocol and the equilibrium criteria are those of
``pardem.protocols.isotropic``. Default deck: ``drivers/isotropic_glass.toml`` values (10,000 glass spheres).

Writes ``DIR/isotropic.json`` (the summary): ``rows`` (one per pressure: ``p0, p, Z, Z_no_rattlers,
solid_fraction, K_affine, K_relaxed, mu_affine, mu_relaxed``, SI units; a modulus is null when not
measured), ``details`` (per pressure: convergence, steps, criteria values, rattlers, the force
distribution ``f_n / <f_n>`` histogram, moduli strain and relaxations), ``criteria``, ``deck``,
``n_ranks``, ``steps``, ``finished``, ``restarted_from``, ``checkpoints``, ``wall_seconds``;
``DIR/isotropic.csv`` and ``DIR/isotropic.h5`` (the series, one row per equilibrium check:
``pardem.protocols.isotropic.SERIES_COLUMNS``, units in the HDF5 file); ``DIR/isotropic.png``
(pressure / p0 and solid fraction against step) and ``DIR/force_distribution.png`` when matplotlib
is available; checkpoints in ``DIR/checkpoints`` (``[checkpoint]``), ParaView snapshots in
``DIR/paraview`` (``output.vtk_every``). ``--restart DIR/checkpoints/checkpoint-<step>.h5``
continues a run from its checkpoint (bit for bit on the same number of ranks); ``--steps N``
stops it at the first equilibrium check at or after step N (steps of all pressures and stages,
counted from the run's start), leaving a checkpoint to continue from.

Exit codes: 0 done (a pressure that did not reach equilibrium within ``preparation.max_steps`` is
flagged ``converged: false`` in ``details`` and warned about), 1 unexpected error (all ranks stop),
2 bad input (one line naming the option or deck field), 3 the run became unstable.
"""
import contextlib
import os
import sys
import time

import pardem
from pardem.config import DeckError
from pardem.drivers.cli import EXIT_OK, default_out, driver_parser, fail_usage, read_deck, run_driver
from pardem.engine import granular
from pardem.engine.errors import DecompositionError
from pardem.engine.simulation import FaultInjection
from pardem.io import checkpoint
from pardem.io.progress import Progress
from pardem.io.summary import write_json
from pardem.parallel.communicator import Communicator
from pardem.protocols import granular_output as gout
from pardem.protocols import isotropic as iso

# deck keys a restart may change besides [output] and [checkpoint] (the rest is the physics)
RESTART_MAY_CHANGE = ("run.progress_seconds", "run.slab_axis", "preparation.max_steps",
                      "moduli.max_relax_steps")


def parser(comm=None):
    p = driver_parser("python -m pardem.drivers.isotropic", __doc__.split("\n\n")[0], iso.SCHEMA,
                      comm=comm, steps_help=(gout.STEPS_HELP + "; the run stops at the first equilibrium check (every "
                                 "preparation.check_every steps) at or after step N"),
                      restart_help=gout.restart_help(RESTART_MAY_CHANGE), out_default="runs/isotropic-<timestamp>",
                      epilog="outputs: DIR/isotropic.json, isotropic.csv, isotropic.h5, isotropic.png, "
                             "force_distribution.png, checkpoints/, paraview/")
    p.add_argument("--pressures", metavar="P1,P2,...",
                   help="target pressures p0 [Pa], comma-separated (overrides preparation.pressures)")
    return p


def main(argv=None):
    comm = Communicator()
    return run_driver(comm, run, parser(comm).parse_args(argv))


def _pressures(text):
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        vals = []
    if not vals or not all(v > 0.0 and v < float("inf") for v in vals):
        raise DeckError(f"--pressures {text!r}: expected comma-separated positive numbers [Pa]")
    return sorted(vals)


def run(comm, args):
    with contextlib.ExitStack() as files:   # closes the series files whatever happens
        return _run(comm, args, files)


def _run(comm, args, files):
    t0 = time.perf_counter()
    meta = None
    try:
        if args.restart:
            meta = gout.inspect_restart(args.restart, "isotropic")
        deck = read_deck(comm, iso.SCHEMA, args, base=meta["deck"] if meta else None)
        iso.check_sample(deck)
        if args.pressures is not None:
            deck["preparation"]["pressures"] = _pressures(args.pressures)
        if meta is not None:
            gout.check_restart(args.restart, meta, deck, iso.SCHEMA, args.steps, RESTART_MAY_CHANGE,
                               "the run length (--steps, preparation.max_steps, moduli.max_relax_steps), "
                               "run.slab_axis, run.progress_seconds")
        checkpoint.parallel_hdf5(deck["checkpoint"]["driver"])   # refuse "mpio" without MPI h5py now
        if meta is not None:
            case = granular.restore(comm, args.restart, slab_axis="xyz".index(deck["run"]["slab_axis"]))
    except (DeckError, checkpoint.CheckpointError, DecompositionError) as err:
        fail_usage(comm, str(err))
    pressures = sorted(deck["preparation"]["pressures"])
    out = args.out or default_out(comm, "isotropic", args.restart)
    if comm.is_root:
        os.makedirs(out, exist_ok=True)
    comm.barrier()
    n = deck["sample"]["n"]
    progress = Progress(comm, None, deck["run"]["progress_seconds"], n, quiet=args.quiet)
    progress.say(f"pardem {pardem.__version__}: isotropic preparation of {n} spheres on {comm.size} "
                 f"rank(s), p0 = {', '.join(f'{p:g}' for p in pressures)} Pa, output {out}"
                 + (f", restarted from {args.restart} (step {int(meta['step'])})" if meta else ""))
    if meta is None:
        case = iso.build_gas(comm, deck)
        state, rows = None, []
    else:
        state = meta["protocol"]
        rows = gout.rows_of(meta["series"], iso.SERIES_COLUMNS, iso.SERIES_INT)
    sim = case.sim
    series = gout.Series(comm, out, "isotropic", iso.SERIES_COLUMNS, iso.SERIES_UNITS,
                         iso.SERIES_DESCRIPTION, rows, iso.SERIES_INT)
    files.callback(series.close)
    sweep_run = iso.SweepRun(stop=args.steps, state=state)
    st = sweep_run.state

    def on_check(sim, b):
        series.append({
            "step": sim.step_count, "time": sim.time, "pressure_index": st["index"],
            "stage": iso.STAGES.index(st["stage"]), "p0": pressures[st["index"]],
            "pressure": b["pressure"], "solid_fraction": b["solid_volume"] / sim.cell.volume,
            "coordination": 2.0 * b["n_contacts"] / b["n_elements"], "kinetic": b["kinetic"],
            "unbalanced": b["unbalanced"], "unbalanced_max": b["unbalanced_max"], "dt": sim.dt,
            "cell_rate": float(sim.cell.rate[0])})
    sweep_run.on_check = on_check
    writer, paraview = gout.writers(case, deck, out, args.restart,
                                    lambda: (deck, sweep_run.snapshot(), series.rows, iso.SERIES_COLUMNS))
    sweep_run.operations = [writer] + ([paraview] if paraview is not None else [])
    fault = FaultInjection.from_environment()     # tests: a crash at a given step (PARDEM_FAULT)
    if fault:
        sweep_run.operations.append(fault)
    stopped = None
    try:
        rows, details, case = iso.sweep(comm, deck, pressures, progress, case=case, run=sweep_run)
    except gout.StepLimit as err:
        stopped = str(err)
        rows, details = st["rows"], st["details"]
    series.close()
    if deck["checkpoint"]["at_end"]:
        writer.write(sim)
    wall = time.perf_counter() - t0
    if comm.is_root:
        data = {"rows": rows, "details": details, "criteria": iso.criteria_text(deck), "deck": deck,
                "n_ranks": comm.size, "dt": float(case.constants["dt"]), "wall_seconds": wall,
                "units": {"p0": "Pa", "p": "Pa", "K_affine": "Pa", "K_relaxed": "Pa",
                          "mu_affine": "Pa", "mu_relaxed": "Pa", "Z": "1", "solid_fraction": "1"},
                "pardem_version": pardem.__version__, "driver": "isotropic", "n_elements": n,
                "steps": sim.step_count, "time": sim.time, "finished": stopped is None,
                "stopped": stopped, "restarted_from": args.restart, "checkpoints": writer.written,
                "series": ["isotropic.csv", "isotropic.h5"]}
        write_json(os.path.join(out, "isotropic.json"), data)
        written = ["isotropic.json", "isotropic.csv", "isotropic.h5"]
        if deck["output"]["plot"]:
            if _plot(details, os.path.join(out, "force_distribution.png")):
                written.append("force_distribution.png")
            if plot_series(series.rows, os.path.join(out, "isotropic.png")):
                written.append("isotropic.png")
        print(format_table(rows))
        bad = [d["p0"] for d in details if not d["converged"]]
        if bad:
            print(f"warning: no static equilibrium within preparation.max_steps at p0 = "
                  f"{', '.join(f'{p:g}' for p in bad)} Pa (see details in isotropic.json)")
        if stopped:
            print(f"{stopped}: {len(rows)} of {len(pressures)} pressures done; continue with --restart "
                  f"{writer.written[-1] if writer.written else '(no checkpoint: checkpoint.at_end = false)'}")
        print(f"wrote {', '.join(os.path.join(out, w) for w in written)} in {wall:.1f} s")
    return EXIT_OK


def format_table(rows):
    head = ("p0 [Pa]", "p [Pa]", "Z", "Z_nr", "phi", "K_aff [Pa]", "K_rel [Pa]", "mu_aff [Pa]", "mu_rel [Pa]")
    lines = ["  ".join(f"{h:>11s}" for h in head)]
    for r in rows:
        vals = [r[k] for k in iso.ROW_KEYS]
        lines.append("  ".join("       null" if v is None else f"{v:11.5g}" for v in vals))
    return "\n".join(lines)


def _pyplot(name):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        sys.stderr.write(f"pardem: note: matplotlib is not installed, so no {name}\n")
        return None
    return plt


def plot_series(rows, path):
    """``isotropic.png``: p / p0 and the solid fraction against the step, one colour per pressure."""
    plt = _pyplot(os.path.basename(path))
    if plt is None or not rows:
        return False
    fig, ax = plt.subplots(2, 1, figsize=(6, 6), sharex=True)
    for k in sorted({r["pressure_index"] for r in rows}):
        mine = [r for r in rows if r["pressure_index"] == k]
        steps = [r["step"] for r in mine]
        ax[0].plot(steps, [r["pressure"] / r["p0"] for r in mine], ".-", ms=2,
                   label=f"p0 = {mine[0]['p0']:g} Pa")
        ax[1].plot(steps, [r["solid_fraction"] for r in mine], ".-", ms=2)
    ax[0].set_ylabel("p / p0 [-]")
    ax[0].set_yscale("symlog", linthresh=1e-3)
    ax[0].legend(fontsize=8)
    ax[1].set_ylabel("solid fraction [-] (overlaps counted)")
    ax[1].set_xlabel("step [-]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].set_title("isotropic preparation and moduli relaxations")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def _plot(details, path):
    plt = _pyplot("force_distribution.png")
    if plt is None or not details:
        return False
    fig, ax = plt.subplots(figsize=(6, 4))
    for d in details:
        fd = d["force_distribution"]
        e = fd["edges"]
        mid = [0.5 * (a + b) for a, b in zip(e[:-1], e[1:])]
        ax.semilogy(mid, [v if v > 0 else float("nan") for v in fd["density"]], "o-", ms=3,
                    label=f"p0 = {d['p0']:g} Pa")
    ax.set_xlabel("f_n / <f_n> [-]")
    ax.set_ylabel("probability density [-]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


if __name__ == "__main__":
    sys.exit(main())
