"""Compression of a bonded domain between two plates; measures Young's modulus and Poisson ratios.

    python -m pardem.drivers.compress [--config deck.toml] [--set section.key=value ...]
                                      [--out DIR] [--steps N]

Writes ``DIR/summary.json`` and ``DIR/series.csv`` (see README). With no options it runs the default
case: the 10 mm cube of 21^3 elements compressed along x to 0.5 % nominal strain.
"""
import datetime
import os
import sys
import time

import numpy as np

import pardem
from pardem.cli import EXIT_UNSTABLE, driver_parser, fail_usage, read_deck
from pardem.compression import Progress, SeriesSampler, build_case, loading_warning, measure
from pardem.config import COMPRESS_SCHEMA, DeckError
from pardem.io.series import SeriesCSV
from pardem.io.summary import write_json
from pardem.parallel.communicator import Communicator, report_and_abort
from pardem.simulation import FaultInjection, InstabilityError


def main(argv=None):
    args = driver_parser("python -m pardem.drivers.compress", __doc__.split("\n\n")[0],
                         COMPRESS_SCHEMA).parse_args(argv)
    comm = Communicator()
    try:
        return run(comm, args)
    except SystemExit:
        raise
    except Exception as exc:  # noqa: BLE001 - any other failure must end every rank
        report_and_abort(comm, exc)


def run(comm, args):
    deck = read_deck(comm, COMPRESS_SCHEMA, args)
    t_start = time.perf_counter()
    try:
        case = build_case(comm, deck, steps=args.steps)
    except DeckError as err:
        fail_usage(comm, str(err))
    out = args.out
    if out is None:
        stamp = comm.bcast(datetime.datetime.now().strftime("%Y%m%d-%H%M%S"))
        out = os.path.join("runs", f"compress-{stamp}")
    sim = case.sim
    e = sim.elements
    n_el, n_bonds = case.n_elements, case.n_bonds
    every = deck["output"]["series_every"] or max(1, case.n_steps // 200)
    sinks = []
    series = None
    if comm.is_root:
        os.makedirs(out, exist_ok=True)
        series = SeriesCSV(os.path.join(out, "series.csv"))
        sinks.append(series.append)
        print(f"pardem {pardem.__version__}: compression along {'xyz'[case.axis]}, {n_el} elements, "
              f"{n_bonds} bonds, {comm.size} rank(s)\n"
              f"dt = {sim.dt:.4e} s (critical {case.dt_critical:.4e} s), {case.n_steps} steps, output {out}",
              flush=True)
        warning = loading_warning(case)
        if warning:
            print(warning, file=sys.stderr, flush=True)
        if not args.quiet:
            sinks.append(Progress(case, n_el, deck["run"]["progress_seconds"], sys.stdout))
    sampler = SeriesSampler(case, every, sinks)
    sampler(sim)   # the initial state
    t_run = time.perf_counter()
    try:
        fault = FaultInjection.from_environment()
        sim.run(case.n_steps, operations=[sampler] + ([fault] if fault else []))
    except InstabilityError as err:
        if comm.is_root:
            sys.stderr.write(f"pardem: error: {err}\n")
        raise SystemExit(EXIT_UNSTABLE)
    finally:
        if series is not None:
            series.close()
    wall_run = time.perf_counter() - t_run
    result = measure(case)
    per_rank = sim.domain.report(sim) if sim.domain is not None else [
        {"rank": 0, "owned_elements": e.n_owned, "ghost_elements": 0, "bonds_held": sim.bonds.n,
         "seconds_computing": sim.seconds_computing, "seconds_communicating": 0.0,
         "rebuilds": 0, "rebalances": 0}]
    counts = comm.sum([sim.elements.n_owned, int(np.count_nonzero(sim.bonds.i < sim.elements.n_owned))])
    if comm.is_root:
        summary = {
            "pardem_version": pardem.__version__,
            "driver": "compress",
            "n_elements": n_el, "n_bonds": n_bonds, "n_ranks": comm.size,
            "n_elements_end": int(counts[0]), "n_bonds_end": int(counts[1]),
            "slab_axis": "xyz"[case.slab_axis], "per_rank": per_rank,
            "steps": sim.step_count, "dt": sim.dt, "dt_critical": case.dt_critical,
            "time": sim.time, "loading_axis": "xyz"[case.axis],
            "nominal_strain": sim.plates.displacement() / case.length,
            "ramp_time": sim.plates.ramp_time,
            "wave_transit_time": case.transit_time,
            "cross_section": case.cross_section,
            **result,
            "young_modulus_analytic": case.analytic_young,
            "wall_seconds": time.perf_counter() - t_start,
            "run_seconds": wall_run,
            "element_steps_per_second": n_el * case.n_steps / wall_run,
            "bytes_per_element": (sim.elements.nbytes() + sim.bonds.nbytes()) / max(sim.elements.n_owned, 1),
            "deck": deck,
        }
        write_json(os.path.join(out, "summary.json"), summary)
        E = result["young_modulus"]
        nus = ", ".join(f"nu_{k} = {v:.4f}" for k, v in result["poisson_ratios"].items())
        line = (f"E_{'xyz'[case.axis]} = {E / 1e6:.3f} MPa (quasi-static slope), "
                f"{result['young_modulus_secant'] / 1e6:.3f} MPa (secant, fixed plate)")
        if np.isfinite(case.analytic_young):
            line += (f";  analytic pi/4 E r^2 = {case.analytic_young / 1e6:.3f} MPa "
                     f"({100 * (E / case.analytic_young - 1):+.2f} %)")
        print(line + f"\n{nus}\nwrote {out}/summary.json and {out}/series.csv "
              f"in {summary['wall_seconds']:.1f} s ({summary['element_steps_per_second']:.3e} element-steps/s)",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
