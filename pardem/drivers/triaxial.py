"""Triaxial test of a cemented granular packing (python -m pardem.drivers.triaxial).

    python -m pardem.drivers.triaxial [--config deck.toml] [--set section.key=value ...] [--out DIR]
        [--steps N] [--restart CHECKPOINT.h5] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.triaxial --config drivers/triaxial_cemented.toml --out runs/tx

Prepares a packing by isotropic compression to the confining pressure pc, cements every contact
(rupture energies uniform in mean +- half-width), then shortens the axial edge of the periodic
cell at a constant rate while servo-controlling the lateral stresses to pc (``pardem.protocols.triaxial``
describes the protocol and the measures). The deck's defaults are ``drivers/triaxial_cemented.toml``.

Writes ``DIR/triaxial.csv`` and ``DIR/triaxial.h5`` (the series, with units in the HDF5 file: one
row per sample of the loading: step, time [s], eps_axial, eps_vol (compression / contraction
positive), q, p, sigma_axial, sigma_lateral_1, sigma_lateral_2 [Pa, compression positive],
broken_fraction, cements_intact, cements_fading, coordination, kinetic_energy [J]),
``DIR/triaxial.json`` (the summary: peak deviator and the strain at peak, final values, broken
fraction, the lateral stress error, ``cements_lost_at_rebuilds`` (intact cements a list rebuild
could not find in reach: 0 for decks that pass the skin check), the preparation's end state, the
deck, ``finished``, ``restarted_from``, ``checkpoints``, timings),
``DIR/triaxial.png`` (deviator, volumetric strain and broken fraction against axial strain; needs
matplotlib), checkpoints in ``DIR/checkpoints`` (``[checkpoint]``) and ParaView snapshots in
``DIR/paraview`` (``output.vtk_every``). ``--restart DIR/checkpoints/checkpoint-<step>.h5``
continues a run from its checkpoint (bit for bit on the same number of ranks); ``--steps N``
stops it at step N (preparation and loading steps counted from the run's start), leaving a
checkpoint to continue from.

Exit codes: 0 done, 1 unexpected error (all ranks stop), 2 bad input (one line naming the field),
3 the run became unstable.
"""
import contextlib
import csv
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
from pardem.protocols import triaxial

# deck keys a restart may change besides [output] and [checkpoint] (the rest is the physics)
RESTART_MAY_CHANGE = ("run.progress_seconds", "run.slab_axis", "loading.strain", "preparation.max_steps")


def parser(comm=None):
    p = driver_parser("python -m pardem.drivers.triaxial", __doc__.split("\n\n")[0], triaxial.SCHEMA,
                      comm=comm, steps_help=gout.STEPS_HELP,
                      restart_help=gout.restart_help(RESTART_MAY_CHANGE), out_default="runs/triaxial-<timestamp>",
                      deck_title="deck keys and defaults (drivers/triaxial_cemented.toml)",
                      epilog="outputs: DIR/triaxial.csv, triaxial.h5, triaxial.json, triaxial.png, "
                             "checkpoints/, paraview/")
    return p


def main(argv=None):
    comm = Communicator()
    return run_driver(comm, run, parser(comm).parse_args(argv))


def run(comm, args):
    with contextlib.ExitStack() as files:   # closes the series files whatever happens
        return _run(comm, args, files)


def _run(comm, args, files):
    t0 = time.perf_counter()
    meta = None
    try:
        if args.restart:
            meta = gout.inspect_restart(args.restart, "triaxial")
        deck = read_deck(comm, triaxial.SCHEMA, args, base=meta["deck"] if meta else None)
        triaxial.check_deck(deck)
        if meta is not None:
            gout.check_restart(args.restart, meta, deck, triaxial.SCHEMA, args.steps, RESTART_MAY_CHANGE,
                               "the run length (--steps, loading.strain, preparation.max_steps), "
                               "run.slab_axis, run.progress_seconds")
        checkpoint.parallel_hdf5(deck["checkpoint"]["driver"])   # refuse "mpio" without MPI h5py now
        if meta is None:
            case = triaxial.build(comm, deck)
        else:
            case = granular.restore(comm, args.restart, slab_axis=triaxial.AXES.index(deck["run"]["slab_axis"]))
    except (DeckError, ValueError, checkpoint.CheckpointError, DecompositionError) as err:
        fail_usage(comm, str(err))
    out = args.out or default_out(comm, "triaxial", args.restart)
    if comm.is_root:
        os.makedirs(out, exist_ok=True)
    comm.barrier()
    pc = deck["loading"]["confining_pressure"]
    sim = case.sim
    n = case.constants["n_elements"]
    progress = Progress(comm, None, deck["run"]["progress_seconds"], n, quiet=args.quiet)
    if meta is None:
        state = {"driver": "triaxial", "stage": "prepare", "met": 0, "checked_step": -1, "prep": None,
                 "n_cem": None, "preparation_seconds": None}
        rows = []
    else:
        state = meta["protocol"]
        rows = gout.rows_of(meta["series"], triaxial.COLUMNS, triaxial.INT_COLUMNS)
    series = gout.Series(comm, out, "triaxial", triaxial.COLUMNS, triaxial.UNITS, triaxial.DESCRIPTION,
                         rows, triaxial.INT_COLUMNS)
    files.callback(series.close)
    writer, paraview = gout.writers(case, deck, out, args.restart,
                                    lambda: (deck, state, series.rows, triaxial.COLUMNS))
    ops = [writer] + ([paraview] if paraview is not None else [])
    fault = FaultInjection.from_environment()     # tests: a crash at a given step (PARDEM_FAULT)
    if fault:
        ops.append(fault)
    progress.say(f"pardem {pardem.__version__} triaxial: {n} spheres on {comm.size} rank(s), dt = {sim.dt:.4g} s; "
                 f"isotropic compression to pc = {pc:.4g} Pa; output {out}"
                 + (f"; restarted from {args.restart} (step {sim.step_count}, {state['stage']})" if meta else ""))
    stopped = None
    try:
        if state["stage"] == "prepare":
            state["prep"] = triaxial.prepare(case, deck, progress, state, ops, args.steps)
            state["preparation_seconds"] = time.perf_counter() - t0
            prep = state["prep"]
            progress.say(f"prepared in {prep['steps']} steps ({state['preparation_seconds']:.1f} s): p = "
                         f"{prep['pressure']:.4g} Pa, solid fraction {prep['solid_fraction']:.4f}, "
                         f"Z = {prep['coordination']:.2f}, converged: {prep['converged']}")
            state["n_cem"] = triaxial.cement(case, deck)
            triaxial.start_loading(case, deck)
            state["stage"] = "load"
            progress.say(f"{state['n_cem']} contacts cemented; loading along {deck['loading']['axis']} to "
                         f"eps_a = {deck['loading']['strain']} at {deck['loading']['strain_rate']} 1/s "
                         f"({triaxial.loading_steps(case, deck)} steps)")
        if state["stage"] == "load":
            triaxial.load(case, deck, rows=list(series.rows), operations=ops, progress=progress,
                          stop=args.steps, on_row=series.append)
            state["stage"] = "done"
    except gout.StepLimit as err:
        stopped = str(err)
    series.close()
    if deck["checkpoint"]["at_end"]:
        writer.write(sim)
    wall = time.perf_counter() - t0
    rows = series.rows
    result = triaxial.summary(rows, pc) if rows else {}
    result["cements_lost_at_rebuilds"] = int(round(float(comm.sum(float(sim.contacts.lost)))))
    if comm.is_root:
        write_json(os.path.join(out, "triaxial.json"), {
            **result, "confining_pressure": pc, "n_elements": n, "cemented_pairs": state["n_cem"],
            "n_ranks": comm.size, "dt": sim.dt, "steps": sim.step_count, "preparation": state["prep"],
            "wall_seconds": wall, "preparation_seconds": state["preparation_seconds"], "deck": deck,
            "pardem_version": getattr(pardem, "__version__", None), "driver": "triaxial",
            "finished": stopped is None, "stopped": stopped, "restarted_from": args.restart,
            "checkpoints": writer.written, "series": ["triaxial.csv", "triaxial.h5"]})
        if deck["output"]["plot"] and rows:
            plot(os.path.join(out, "triaxial.png"), rows, pc)
    if stopped and comm.is_root:
        print(f"{stopped}; continue with --restart "
              f"{writer.written[-1] if writer.written else '(no checkpoint: checkpoint.at_end = false)'}",
              flush=True)
    elif rows:
        progress.say(
            f"peak q = {result['peak_deviator']:.4g} Pa ({result['peak_stress_ratio']:.3f} pc) at eps_a = "
            f"{result['strain_at_peak']:.4f}; final eps_v = {result['final_volumetric_strain']:.4g}, broken "
            f"fraction {result['final_broken_fraction']:.3f}; lateral stress within "
            f"{100 * result['lateral_stress_error_max']:.2f} % of pc (mean "
            f"{100 * result['lateral_stress_error_mean']:.2f} %); {wall:.1f} s; outputs in {out}")
    return EXIT_OK


def read_series(path):
    """Columns of ``triaxial.csv`` as a dict of float lists."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {k: [float(r[k]) for r in rows] for k in triaxial.COLUMNS}


def plot(path, rows, pc):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        sys.stderr.write("pardem: note: matplotlib is not installed, so no triaxial.png\n")
        return
    ea = [100 * r["eps_axial"] for r in rows]
    fig, ax = plt.subplots(3, 1, figsize=(6, 8), sharex=True)
    ax[0].plot(ea, [r["q"] / pc for r in rows])
    ax[0].set_ylabel("q / pc [-]")
    ax[1].plot(ea, [100 * r["eps_vol"] for r in rows])
    ax[1].set_ylabel("eps_v [%] (contraction +)")
    ax[2].plot(ea, [r["broken_fraction"] for r in rows])
    ax[2].set_ylabel("broken cement fraction [-]")
    ax[2].set_xlabel("axial strain [%]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].set_title(f"cemented triaxial test, pc = {pc:.3g} Pa")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
