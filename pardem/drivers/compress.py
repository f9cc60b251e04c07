"""Compression of a bonded domain between two plates; measures Young's modulus and Poisson ratios.

    python -m pardem.drivers.compress [--config deck.toml] [--set section.key=value ...]
                                      [--out DIR] [--steps N]

Writes ``DIR/summary.json`` and ``DIR/series.csv`` (docs/outputs.md). With no options it runs the default
case: the 10 mm cube of 21^3 elements compressed along x to 0.5 % nominal strain.
"""
import os
import sys
import time

import numpy as np

import pardem
from pardem.drivers import cli
from pardem.drivers.runner import ProtocolDriver, run_protocol
from pardem.io.series import SeriesCSV
from pardem.io.series_h5 import SeriesH5
from pardem.parallel.communicator import Communicator
from pardem.parallel.slab_comm import rank_report
from pardem.protocols.compression import (MIN_FIT_SAMPLES, SeriesSampler, build_case, checkpoint_payload,
                                          loading_warning, measure, restore_case)
from pardem.protocols.compression_deck import COMPRESS_SCHEMA, upgrade


class Compress(ProtocolDriver):
    name = "compress"
    schema = COMPRESS_SCHEMA

    def paraview_trigger(self, run, every):
        return every, True    # one sim.run: its last step too

    def base_deck(self, run):
        return upgrade(run.meta["deck"])

    def build(self, run):
        return build_case(run.comm, run.deck, steps=run.args.steps)

    def restore(self, run):
        return restore_case(run.comm, run.deck, run.args.restart, steps=run.args.steps, meta=run.meta)

    def payload(self, run):
        return checkpoint_payload(run.case)

    def total_steps(self, run):
        return run.case.n_steps

    def start(self, run):
        comm, case, sim = run.comm, run.case, run.sim
        c = case.constants
        every = run.deck["output"]["series_every"] or max(1, case.n_steps // 200)
        sinks = []
        if comm.is_root:
            # a restart writes the series from the run's start
            csv = SeriesCSV(os.path.join(run.out, "series.csv"))
            run.files.callback(csv.close)
            h5 = SeriesH5(os.path.join(run.out, "series.h5"), samples=case.samples)
            run.files.callback(h5.close)
            for s in case.samples:
                csv.append(s)
            sinks += [csv.append, h5.append]
            print(f"pardem {pardem.__version__}: compression along {'xyz'[c.axis]}, {c.n_elements} elements, "
                  f"{c.n_bonds} bonds, {comm.size} rank(s)\n"
                  f"dt = {sim.dt:.4e} s (critical {c.dt_critical:.4e} s), steps {sim.step_count} to "
                  f"{case.n_steps}, output {run.out}"
                  + (f", restarted from {run.args.restart}" if run.args.restart else ""), flush=True)
            warning = loading_warning(case)
            if warning:
                print(warning, file=sys.stderr, flush=True)
        sampler = SeriesSampler(case, every, sinks)
        if sim.step_count == 0:
            sampler(sim)   # the initial state
        axis = c.axis
        sampler.sinks.append(lambda s: run.progress.report(
            s["step"], f"t = {s['time']:.4e} s  eps = {s['eps'][axis, axis]:+.4e}  F = {s['force_fixed']:.4e} N"))
        run.state["sampler"] = sampler

    def execute(self, run):
        run.state["first_step"] = run.sim.step_count
        t = time.perf_counter()
        try:
            run.sim.run(run.case.steps_left, operations=[run.state["sampler"]] + run.operations)
        finally:
            run.state["run_seconds"] = time.perf_counter() - t

    def summary(self, run):
        comm, case, sim = run.comm, run.case, run.sim
        c = case.constants
        result = measure(case)
        per_rank = (sim.domain.report(sim.elements, sim.bonds, sim.seconds_computing) if sim.domain is not None
                    else [rank_report(0, sim.elements, sim.bonds, sim.seconds_computing)])
        counts = comm.sum([sim.elements.n_owned, int(np.count_nonzero(sim.bonds.counted_once(sim.elements.n_owned)))])
        wall_run = run.state.get("run_seconds", 0.0)
        steps_run = sim.step_count - run.state.get("first_step", sim.step_count)
        return {
            "n_elements": c.n_elements, "n_bonds": c.n_bonds,
            "n_elements_end": int(counts[0]), "n_bonds_end": int(counts[1]),
            "slab_axis": "xyz"[c.slab_axis], "per_rank": per_rank,
            "dt_critical": c.dt_critical, "loading_axis": "xyz"[c.axis],
            "nominal_strain": sim.plates.displacement() / c.length,
            "ramp_time": sim.plates.ramp_time,
            "wave_transit_time": c.transit_time,
            "cross_section": c.cross_section,
            "domain": {k: c.domain_facts[k] for k in ("solid_fraction", "packing_fraction", "mean_radius",
                                                      "coordination", "removed_elements", "max_overlap")
                       if k in c.domain_facts},
            **result,
            "young_modulus_analytic": c.analytic_young,
            "run_seconds": wall_run,
            "element_steps_per_second": c.n_elements * steps_run / wall_run if wall_run > 0 else float("nan"),
            "compile_seconds": case.compile_seconds,   # kernels compiled or loaded, not in run_seconds
            "bytes_per_element": (sim.elements.nbytes() + sim.bonds.nbytes()) / max(sim.elements.n_owned, 1),
        }

    def finish(self, run, summary):
        case, sim, out = run.case, run.sim, run.out
        c = case.constants
        E = summary["young_modulus"]
        if not np.isfinite(E):
            sys.stderr.write(
                f"pardem: error: the run is too short to measure the modulus: "
                f"{summary['samples_after_ramp']} sample(s) after the {sim.plates.ramp_time:.4g} s ramp, "
                f"expected at least {MIN_FIT_SAMPLES}; run longer (--steps, loading.strain) or sample more "
                f"often (output.series_every); wrote {out}/summary.json\n")
            return cli.EXIT_NOT_MEASURED
        nus = ", ".join(f"nu_{k} = {v:.4f}" for k, v in summary["poisson_ratios"].items())
        line = (f"E_{'xyz'[c.axis]} = {E / 1e6:.3f} MPa (quasi-static slope), "
                f"{summary['young_modulus_secant'] / 1e6:.3f} MPa (secant, fixed plate)")
        if np.isfinite(c.analytic_young):
            line += (f";  analytic pi/4 E r^2 = {c.analytic_young / 1e6:.3f} MPa "
                     f"({100 * (E / c.analytic_young - 1):+.2f} %)")
        if sim.bonds.breakable or sim.bonds.densify_p0 > 0.0:
            nus += (f"\npeak stress {summary['peak_stress'] / 1e6:.4g} MPa at strain "
                    f"{summary['strain_at_peak']:.4g}; bonds broken {summary['bonds_broken']} of {c.n_bonds}, "
                    f"yielded {summary['bonds_yielded']}")
        if summary["domain"]:
            d = summary["domain"]
            nus += (f"\ncompact domain: solid fraction {d['solid_fraction']:.4f}, coordination "
                    f"{d['coordination']:.2f}, mean radius {d['mean_radius']:.4g} m")
        print(line + f"\n{nus}\nwrote {out}/summary.json, series.csv and series.h5 "
              f"in {summary['wall_seconds']:.1f} s ({summary['element_steps_per_second']:.3e} element-steps/s)",
              flush=True)
        return cli.EXIT_OK


def main(argv=None):
    comm = Communicator()
    args = cli.driver_parser("python -m pardem.drivers.compress", __doc__.split("\n\n")[0],
                             COMPRESS_SCHEMA, comm=comm).parse_args(argv)
    return cli.run_driver(comm, lambda comm, args: run_protocol(comm, args, Compress()), args)


if __name__ == "__main__":
    sys.exit(main())
