"""Direct shear box test of frictional spheres (python -m pardem.drivers.direct_shear).

    python -m pardem.drivers.direct_shear [--config deck.toml] [--set section.key=value ...] [--out DIR]
        [--steps N] [--restart CHECKPOINT.h5] [--quiet]

A gas of polydisperse spheres in a box is compressed by a servo-controlled lid to the normal
stress sigma_n, then the upper half box (triangle-mesh walls) moves along x at a constant speed
(``pardem.protocols.direct_shear`` describes the protocol and the measures). The deck's defaults
are the schema's (``drivers/direct_shear_short.toml`` is a shorter run).

Writes ``DIR/direct_shear.csv`` and ``.h5`` (the series: step, time [s], displacement [m],
shear_force, normal_force [N], tau, sigma_n [Pa], friction = tau/sigma_n, dilation [m],
kinetic_energy [J]), ``DIR/direct_shear.json`` (peak and residual friction coefficients, the
dilation at the peak and at the end, the servo's normal stress error, the deck, ``finished``,
``restarted_from``, ``checkpoints``), checkpoints in ``DIR/checkpoints``. ``--steps N`` stops
at step N with a checkpoint that ``--restart`` continues from bit for bit.

Exit codes: 0 done, 1 unexpected error, 2 bad input (one line naming the field), 3 unstable run.
"""
import pardem
from pardem.drivers import cli
from pardem.drivers.granular import GranularDriver
from pardem.drivers.runner import protocol_main
from pardem.protocols import direct_shear as ds

RESTART_MAY_CHANGE = ("run.progress_seconds", "run.watchdog_seconds", "run.slab_axis")


def parser(comm=None):
    return cli.granular_parser("direct_shear", __doc__, ds.SCHEMA, RESTART_MAY_CHANGE, comm=comm,
                               outputs="DIR/direct_shear.csv, direct_shear.h5, direct_shear.json, checkpoints/")


def main(argv=None):
    return protocol_main(DirectShear, parser, argv)


class DirectShear(GranularDriver):
    name = "direct_shear"
    schema = ds.SCHEMA
    summary_name = "direct_shear.json"
    error_types = (ValueError,)
    restart_may_change = RESTART_MAY_CHANGE
    restart_what = "run.slab_axis, run.progress_seconds, run.watchdog_seconds"
    columns, units, description = ds.COLUMNS, ds.UNITS, ds.DESCRIPTION
    slab_axes = ds.AXES

    def build(self, run):
        run.state = {"driver": "direct_shear", "stage": "prepare"}
        return ds.build(run.comm, run.deck)

    def start(self, run):
        self.open_series(run)
        run.progress.say(f"pardem {pardem.__version__} direct_shear: {run.case.n_elements} spheres on "
                         f"{run.comm.size} rank(s), dt = {run.sim.dt:.4g} s; output {run.out}")

    def execute(self, run):
        case, deck, state = run.case, run.deck, run.state
        if state["stage"] == "prepare":
            ds.prepare(case, deck, run.operations, run.args.steps)
            ds.start_shear(case, deck)
            state["stage"] = "shear"
        if state["stage"] == "shear":
            ds.shear(case, deck, list(run.series.rows), run.operations, run.args.steps, run.series.append)
            state["stage"] = "done"

    def summary(self, run):
        rows = run.series.rows
        return {**(ds.summary(rows, run.deck) if len(rows) > 1 else {}), "n_elements": run.case.n_elements,
                "series": ["direct_shear.csv", "direct_shear.h5"]}

    def finish(self, run, summary):
        if run.stopped:
            print(f"{run.stopped}; continue with --restart "
                  f"{run.writer.written[-1] if run.writer.written else '(no checkpoint)'}", flush=True)
        elif "peak_friction" in summary:
            run.progress.say(f"peak tau/sigma_n = {summary['peak_friction']:.3f} at d = "
                             f"{summary['displacement_at_peak']:.4g} m, residual {summary['residual_friction']:.3f}, "
                             f"dilation at peak {summary['dilation_at_peak']:.3g} m; outputs in {run.out}")
        return cli.EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
