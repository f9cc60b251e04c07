"""Compression of a bonded domain between two plates; measures Young's modulus and Poisson ratios.

    python -m pardem.drivers.compress [--config deck.toml] [--set section.key=value ...]
                                      [--out DIR] [--steps N]

Writes ``DIR/summary.json`` and ``DIR/series.csv`` (see README). With no options it runs the default
case: the 10 mm cube of 21^3 elements compressed along x to 0.5 % nominal strain.
"""
import contextlib
import os
import sys
import time

import numpy as np

import pardem
from pardem.drivers.cli import EXIT_NOT_MEASURED, default_out, driver_parser, fail_usage, read_deck, run_driver
from pardem.protocols.compression import (MIN_FIT_SAMPLES, SeriesSampler, build_case, checkpoint_payload, loading_warning,
                                measure, restore_case)
from pardem.io import checkpoint
from pardem.io.checkpoint_writer import CheckpointWriter
from pardem.io.paraview import ParaViewWriter
from pardem.io.progress import Progress
from pardem.config import DeckError
from pardem.protocols.compression_deck import COMPRESS_SCHEMA, upgrade
from pardem.io.series import SeriesCSV
from pardem.io.series_h5 import SeriesH5
from pardem.io.summary import write_json
from pardem.parallel.communicator import Communicator
from pardem.parallel.slab_comm import rank_report
from pardem.engine.errors import DecompositionError
from pardem.engine.simulation import FaultInjection


def main(argv=None):
    comm = Communicator()
    args = driver_parser("python -m pardem.drivers.compress", __doc__.split("\n\n")[0],
                         COMPRESS_SCHEMA, comm=comm).parse_args(argv)
    return run_driver(comm, run, args)


def run(comm, args):
    with contextlib.ExitStack() as files:   # closes the series files whatever happens
        return _run(comm, args, files)


def _run(comm, args, files):
    t_start = time.perf_counter()
    try:
        if args.restart:
            meta = checkpoint.inspect(args.restart)
            deck = read_deck(comm, COMPRESS_SCHEMA, args, base=upgrade(meta["deck"]))
            case = restore_case(comm, deck, args.restart, steps=args.steps)
        else:
            deck = read_deck(comm, COMPRESS_SCHEMA, args)
            case = build_case(comm, deck, steps=args.steps)
        checkpoint.parallel_hdf5(deck["checkpoint"]["driver"])   # refuse "mpio" without MPI h5py now
    except (DeckError, checkpoint.CheckpointError, DecompositionError) as err:
        fail_usage(comm, str(err))
    out = args.out or default_out(comm, "compress", args.restart)
    sim = case.sim
    n_el, n_bonds = case.constants.n_elements, case.constants.n_bonds
    every = deck["output"]["series_every"] or max(1, case.n_steps // 200)
    sinks = []
    if comm.is_root:
        os.makedirs(out, exist_ok=True)
        # a restart writes the series from the run's start
        csv = SeriesCSV(os.path.join(out, "series.csv"))
        files.callback(csv.close)
        h5 = SeriesH5(os.path.join(out, "series.h5"), samples=case.samples)
        files.callback(h5.close)
        for s in case.samples:
            csv.append(s)
        sinks += [csv.append, h5.append]
        print(f"pardem {pardem.__version__}: compression along {'xyz'[case.constants.axis]}, {n_el} elements, "
              f"{n_bonds} bonds, {comm.size} rank(s)\n"
              f"dt = {sim.dt:.4e} s (critical {case.constants.dt_critical:.4e} s), steps {sim.step_count} to "
              f"{case.n_steps}, output {out}" + (f", restarted from {args.restart}" if args.restart else ""),
              flush=True)
        warning = loading_warning(case)
        if warning:
            print(warning, file=sys.stderr, flush=True)
    sampler = SeriesSampler(case, every, sinks)
    if sim.step_count == 0:
        sampler(sim)   # the initial state
    # after the initial sample: the rate is measured from the first sample of the run on
    progress = Progress(comm, case.n_steps, deck["run"]["progress_seconds"], n_el, quiet=args.quiet)
    axis = case.constants.axis
    sampler.sinks.append(lambda s: progress.report(
        s["step"], f"t = {s['time']:.4e} s  eps = {s['eps'][axis, axis]:+.4e}  F = {s['force_fixed']:.4e} N"))
    ck = deck["checkpoint"]
    writer = CheckpointWriter(lambda: checkpoint_payload(case), os.path.join(out, "checkpoints"), ck["every_steps"],
                              ck["every_seconds"], ck["keep"], ck["driver"])
    operations = [sampler, writer]
    if deck["output"]["vtk_every"]:
        operations.append(ParaViewWriter(os.path.join(out, "paraview"), comm, deck["output"]["vtk_every"],
                                         resume_step=sim.step_count if args.restart else None, dt=sim.dt))
        if sim.step_count == 0:
            operations[-1](sim)    # the initial state
    fault = FaultInjection.from_environment()
    if fault:
        operations.append(fault)
    t_run = time.perf_counter()
    steps_run = case.steps_left
    sim.run(steps_run, operations=operations)   # an InstabilityError ends the run in run_driver (exit 3)
    files.close()
    if ck["at_end"]:
        writer.write(sim)
    wall_run = time.perf_counter() - t_run
    result = measure(case)
    per_rank = (sim.domain.report(sim.elements, sim.bonds, sim.seconds_computing) if sim.domain is not None
                else [rank_report(0, sim.elements, sim.bonds, sim.seconds_computing)])
    counts = comm.sum([sim.elements.n_owned, int(np.count_nonzero(sim.bonds.counted_once(sim.elements.n_owned)))])
    if comm.is_root:
        summary = {
            "pardem_version": pardem.__version__,
            "driver": "compress",
            "n_elements": n_el, "n_bonds": n_bonds, "n_ranks": comm.size,
            "n_elements_end": int(counts[0]), "n_bonds_end": int(counts[1]),
            "slab_axis": "xyz"[case.constants.slab_axis], "per_rank": per_rank,
            "steps": sim.step_count, "dt": sim.dt, "dt_critical": case.constants.dt_critical,
            "time": sim.time, "loading_axis": "xyz"[case.constants.axis],
            "nominal_strain": sim.plates.displacement() / case.constants.length,
            "ramp_time": sim.plates.ramp_time,
            "wave_transit_time": case.constants.transit_time,
            "cross_section": case.constants.cross_section,
            "domain": {k: case.constants.domain_facts[k] for k in ("solid_fraction", "packing_fraction", "mean_radius",
                                                                 "coordination", "removed_elements", "max_overlap")
                       if k in case.constants.domain_facts},
            **result,
            "young_modulus_analytic": case.constants.analytic_young,
            "wall_seconds": time.perf_counter() - t_start,
            "run_seconds": wall_run,
            "element_steps_per_second": n_el * steps_run / wall_run,
            "restarted_from": args.restart, "checkpoints": writer.written,
            "bytes_per_element": (sim.elements.nbytes() + sim.bonds.nbytes()) / max(sim.elements.n_owned, 1),
            "deck": deck,
        }
        write_json(os.path.join(out, "summary.json"), summary)
        E = result["young_modulus"]
        if not np.isfinite(E):
            sys.stderr.write(
                f"pardem: error: the run is too short to measure the modulus: "
                f"{result['samples_after_ramp']} sample(s) after the {sim.plates.ramp_time:.4g} s ramp, "
                f"expected at least {MIN_FIT_SAMPLES}; run longer (--steps, loading.strain) or sample more "
                f"often (output.series_every); wrote {out}/summary.json\n")
            raise SystemExit(EXIT_NOT_MEASURED)
        nus = ", ".join(f"nu_{k} = {v:.4f}" for k, v in result["poisson_ratios"].items())
        line = (f"E_{'xyz'[case.constants.axis]} = {E / 1e6:.3f} MPa (quasi-static slope), "
                f"{result['young_modulus_secant'] / 1e6:.3f} MPa (secant, fixed plate)")
        if np.isfinite(case.constants.analytic_young):
            line += (f";  analytic pi/4 E r^2 = {case.constants.analytic_young / 1e6:.3f} MPa "
                     f"({100 * (E / case.constants.analytic_young - 1):+.2f} %)")
        if sim.bonds.breakable or sim.bonds.densify_p0 > 0.0:
            nus += (f"\npeak stress {result['peak_stress'] / 1e6:.4g} MPa at strain "
                    f"{result['strain_at_peak']:.4g}; bonds broken {result['bonds_broken']} of {n_bonds}, "
                    f"yielded {result['bonds_yielded']}")
        if summary["domain"]:
            d = summary["domain"]
            nus += (f"\ncompact domain: solid fraction {d['solid_fraction']:.4f}, coordination "
                    f"{d['coordination']:.2f}, mean radius {d['mean_radius']:.4g} m")
        print(line + f"\n{nus}\nwrote {out}/summary.json, series.csv and series.h5 "
              f"in {summary['wall_seconds']:.1f} s ({summary['element_steps_per_second']:.3e} element-steps/s)",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
