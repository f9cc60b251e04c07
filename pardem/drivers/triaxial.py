"""Triaxial test of a cemented granular packing (python -m pardem.drivers.triaxial).

    python -m pardem.drivers.triaxial [--config deck.toml] [--set section.key=value ...] [--out DIR] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.triaxial --config drivers/triaxial_cemented.toml --out runs/tx

Prepares a packing by isotropic compression to the confining pressure pc, cements every contact
(rupture energies uniform in mean +- half-width), then shortens the axial edge of the periodic
cell at a constant rate while servo-controlling the lateral stresses to pc (``pardem.protocols.triaxial``
describes the protocol and the measures). The deck's defaults are ``drivers/triaxial_cemented.toml``.

Writes ``DIR/triaxial.csv`` (one row per sample of the loading: step, time [s], eps_axial,
eps_vol (compression / contraction positive), q, p, sigma_axial, sigma_lateral_1, sigma_lateral_2
[Pa, compression positive], broken_fraction, cements_intact, cements_fading, coordination,
kinetic_energy [J]), ``DIR/triaxial.json`` (peak deviator and the strain at peak, final values,
broken fraction, the lateral stress error, ``cements_lost_at_rebuilds`` (intact cements a list
rebuild could not find in reach: 0 for decks that pass the skin check), the preparation's end state,
the deck, timings) and
``DIR/triaxial.png`` (deviator, volumetric strain and broken fraction against axial strain; needs
matplotlib).

Exit codes: 0 done, 1 unexpected error (all ranks stop), 2 bad input (one line naming the field),
3 the run became unstable.
"""
import csv
import datetime
import os
import sys
import time

import pardem
from pardem.protocols import triaxial
from pardem.drivers.cli import EXIT_OK, EXIT_UNSTABLE, driver_parser, fail_usage, run_driver
from pardem.config import DeckError, load_deck
from pardem.io.summary import write_json
from pardem.parallel.communicator import Communicator
from pardem.engine.errors import InstabilityError


def parser(comm=None):
    p = driver_parser("python -m pardem.drivers.triaxial", __doc__.split("\n\n")[0], triaxial.SCHEMA,
                      run_options=False, comm=comm, out_default="runs/triaxial-<timestamp>",
                      deck_title="deck keys and defaults (drivers/triaxial_cemented.toml)",
                      epilog="outputs: DIR/triaxial.csv, DIR/triaxial.json, DIR/triaxial.png")
    return p


def main(argv=None):
    comm = Communicator()
    return run_driver(comm, run, parser(comm).parse_args(argv))


def say(comm, quiet, text):
    if comm.is_root and not quiet:
        print(text, flush=True)


def run(comm, args):
    t0 = time.perf_counter()
    try:
        deck = load_deck(triaxial.SCHEMA, args.config, args.overrides)
        triaxial.check_deck(deck)
    except (DeckError, ValueError) as err:
        fail_usage(comm, str(err))
    out = args.out
    if out is None:
        stamp = comm.bcast(datetime.datetime.now().strftime("%Y%m%d-%H%M%S"))
        out = os.path.join("runs", f"triaxial-{stamp}")
    if comm.is_root:
        os.makedirs(out, exist_ok=True)
    comm.barrier()
    progress = 0.0 if args.quiet else deck["output"]["progress_seconds"]
    pc = deck["loading"]["confining_pressure"]
    try:
        case = triaxial.build(comm, deck)
    except ValueError as err:
        fail_usage(comm, str(err))
    sim = case.sim
    n = case.constants["n_elements"]
    say(comm, args.quiet, f"triaxial: {n} spheres on {comm.size} rank(s), dt = {sim.dt:.4g} s; "
                          f"isotropic compression to pc = {pc:.4g} Pa")
    try:
        prep = triaxial.prepare(case, deck, progress)
        t_prep = time.perf_counter() - t0
        say(comm, args.quiet, f"prepared in {prep['steps']} steps ({t_prep:.1f} s): p = "
                              f"{prep['pressure']:.4g} Pa, solid fraction {prep['solid_fraction']:.4f}, "
                              f"Z = {prep['coordination']:.2f}, converged: {prep['converged']}")
        n_cem = triaxial.cement(case, deck)
        triaxial.start_loading(case, deck)
        say(comm, args.quiet, f"{n_cem} contacts cemented; loading along {deck['loading']['axis']} to "
                              f"eps_a = {deck['loading']['strain']} at {deck['loading']['strain_rate']} 1/s "
                              f"({triaxial.loading_steps(case, deck)} steps)")
        rows = triaxial.load(case, deck, progress_seconds=progress)
    except InstabilityError as err:
        if comm.is_root:
            sys.stderr.write(f"pardem: the run became unstable: {err}\n")
        raise SystemExit(EXIT_UNSTABLE)
    wall = time.perf_counter() - t0
    result = triaxial.summary(rows, pc)
    result["cements_lost_at_rebuilds"] = int(round(float(comm.sum(float(sim.contacts.lost)))))
    if comm.is_root:
        write_series(os.path.join(out, "triaxial.csv"), rows)
        write_json(os.path.join(out, "triaxial.json"), {
            **result, "confining_pressure": pc, "n_elements": n, "cemented_pairs": n_cem,
            "n_ranks": comm.size, "dt": sim.dt, "steps": sim.step_count, "preparation": prep,
            "wall_seconds": wall, "preparation_seconds": t_prep, "deck": deck,
            "pardem_version": getattr(pardem, "__version__", None)})
        if deck["output"]["plot"]:
            plot(os.path.join(out, "triaxial.png"), rows, pc)
    say(comm, args.quiet,
        f"peak q = {result['peak_deviator']:.4g} Pa ({result['peak_stress_ratio']:.3f} pc) at eps_a = "
        f"{result['strain_at_peak']:.4f}; final eps_v = {result['final_volumetric_strain']:.4g}, broken "
        f"fraction {result['final_broken_fraction']:.3f}; lateral stress within "
        f"{100 * result['lateral_stress_error_max']:.2f} % of pc (mean "
        f"{100 * result['lateral_stress_error_mean']:.2f} %); {wall:.1f} s; outputs in {out}")
    return EXIT_OK


def write_series(path, rows):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(triaxial.COLUMNS)
        for r in rows:
            w.writerow([repr(float(r[k])) if isinstance(r[k], float) else r[k] for k in triaxial.COLUMNS])


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
    ax[0].set_ylabel("q / pc")
    ax[1].plot(ea, [100 * r["eps_vol"] for r in rows])
    ax[1].set_ylabel("eps_v [%] (contraction +)")
    ax[2].plot(ea, [r["broken_fraction"] for r in rows])
    ax[2].set_ylabel("broken cement fraction")
    ax[2].set_xlabel("axial strain [%]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].set_title(f"cemented triaxial test, pc = {pc:.3g} Pa")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
