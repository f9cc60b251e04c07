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
import time

import pardem
from pardem.drivers import cli
from pardem.drivers.granular import GranularDriver
from pardem.drivers.runner import protocol_main
from pardem.io import triaxial_plot
from pardem.protocols import triaxial

# deck keys a restart may change besides [output] and [checkpoint] (the rest is the physics)
RESTART_MAY_CHANGE = ("run.progress_seconds", "run.watchdog_seconds", "run.slab_axis", "loading.strain", "preparation.max_steps")


def parser(comm=None):
    return cli.granular_parser("triaxial", __doc__, triaxial.SCHEMA, RESTART_MAY_CHANGE, comm=comm,
                               deck_title="deck keys and defaults (drivers/triaxial_cemented.toml)",
                               outputs="DIR/triaxial.csv, triaxial.h5, triaxial.json, triaxial.png, "
                                       "checkpoints/, paraview/")


def main(argv=None):
    return protocol_main(Triaxial, parser, argv)


class Triaxial(GranularDriver):
    name = "triaxial"
    schema = triaxial.SCHEMA
    summary_name = "triaxial.json"
    error_types = (ValueError,)
    restart_may_change = RESTART_MAY_CHANGE
    restart_what = "the run length (--steps, loading.strain, preparation.max_steps), run.slab_axis, run.progress_seconds"
    columns, units, description, int_columns = (triaxial.COLUMNS, triaxial.UNITS, triaxial.DESCRIPTION,
                                                triaxial.INT_COLUMNS)
    slab_axes = triaxial.AXES

    def check(self, run, deck):
        triaxial.check_deck(deck)

    def build(self, run):
        run.state = {"driver": "triaxial", "stage": "prepare", "met": 0, "checked_step": -1, "prep": None,
                     "n_cem": None, "preparation_seconds": None}
        return triaxial.build(run.comm, run.deck)

    def start(self, run):
        self.open_series(run)
        pc = run.deck["loading"]["confining_pressure"]
        sim = run.sim
        run.progress.say(f"pardem {pardem.__version__} triaxial: {run.case.n_elements} spheres on "
                         f"{run.comm.size} rank(s), dt = {sim.dt:.4g} s; isotropic compression to pc = {pc:.4g} Pa; "
                         f"output {run.out}" + (f"; restarted from {run.args.restart} (step {sim.step_count}, "
                                                f"{run.state['stage']})" if run.meta else ""))

    def execute(self, run):
        case, deck, state, progress = run.case, run.deck, run.state, run.progress
        if state["stage"] == "prepare":
            state["prep"] = triaxial.prepare(case, deck, progress, state, run.operations, run.args.steps)
            state["preparation_seconds"] = time.perf_counter() - run.t_start
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
            triaxial.load(case, deck, rows=list(run.series.rows), operations=run.operations, progress=progress,
                          stop=run.args.steps, on_row=run.series.append)
            state["stage"] = "done"

    def summary(self, run):
        pc = run.deck["loading"]["confining_pressure"]
        rows = run.series.rows
        result = triaxial.summary(rows, pc) if rows else {}
        result["cements_lost_at_rebuilds"] = int(round(float(run.comm.sum(float(run.sim.contacts.lost)))))
        return {**result, "confining_pressure": pc, "n_elements": run.case.n_elements,
                "cemented_pairs": run.state["n_cem"], "preparation": run.state["prep"],
                "preparation_seconds": run.state["preparation_seconds"],
                "series": ["triaxial.csv", "triaxial.h5"]}

    def finish(self, run, summary):
        rows, pc = run.series.rows, summary["confining_pressure"]
        if run.deck["output"]["plot"] and rows:
            triaxial_plot.plot(f"{run.out}/triaxial.png", rows, pc)
        if run.stopped:
            print(f"{run.stopped}; continue with --restart "
                  f"{run.writer.written[-1] if run.writer.written else '(no checkpoint: checkpoint.at_end = false)'}",
                  flush=True)
        elif rows:
            run.progress.say(
                f"peak q = {summary['peak_deviator']:.4g} Pa ({summary['peak_stress_ratio']:.3f} pc) at eps_a = "
                f"{summary['strain_at_peak']:.4f}; final eps_v = {summary['final_volumetric_strain']:.4g}, broken "
                f"fraction {summary['final_broken_fraction']:.3f}; lateral stress within "
                f"{100 * summary['lateral_stress_error_max']:.2f} % of pc (mean "
                f"{100 * summary['lateral_stress_error_mean']:.2f} %); {summary['wall_seconds']:.1f} s; "
                f"outputs in {run.out}")
        return cli.EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
