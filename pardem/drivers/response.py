"""Point-load response function of a 2D granular packing (python -m pardem.drivers.response).

    python -m pardem.drivers.response [--config deck.toml] [--set section.key=value ...] [--out DIR]
        [--steps N] [--restart CHECKPOINT.h5] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.response --config drivers/response_short.toml --out runs/resp

A 2D packing is prepared frictionless at the pressure p in a periodic cell (isotropic protocol),
optionally replicated k_x x k_y times, opened along y with a clamped bottom row and a rigid top row
(loaded by its reference force, or clamped), friction restored; after relaxing to the reference
equilibrium, the free grain at the top centre gets an extra downward force F (a fraction of the
mean contact force); the dynamic (undamped) response is recorded at a few times, then the static
one after relaxing again; with ``load.points = K`` the load then goes in turn on K grains along the
top (each measured against the packing relaxed unloaded just before it) and the static profiles
are averaged. ``pardem.protocols.response`` describes the protocol and the measures.

Writes ``DIR/response.json`` (the summary: the force F, the loaded grain, the wave speed, height
and transit time, the reference state, ``static`` and ``dynamic`` (each: x and depth bin centres
[m], ``dsigma_yy`` [nz][nx] [Pa], ``transmitted_over_F`` per layer, profile widths, the same for
Flamant's half-plane and the layer on a rigid base, the width fits; with several load points
``static`` is their average, with ``dsigma_yy_sem`` and ``points``, and ``static_points`` has each
point's own; ``static.linear``: the same measures of the static linear response of the reference
contact network, no sliding, no opening, under the same supports; ``static.contact_changes``: the
contacts that ``opened``, ``closed`` or ``slid`` in the load step, and those at the Coulomb limit in
the reference and loaded states, counts [1]), the reactions of the rows, geometry, deck, timings), ``DIR/response.csv`` and ``DIR/response.h5`` (one row per relaxation
check: ``pardem.protocols.response.SERIES_COLUMNS``), ``DIR/response.png`` (needs matplotlib),
``DIR/response_vtk/response.pvd`` (the perturbation per grain, ``output.perturbation_vtk``) and
ParaView snapshots of the whole state in ``DIR/paraview`` (``output.vtk_every``), checkpoints in
``DIR/checkpoints`` (``[checkpoint]``). The summary also gives the wall seconds and steps of each
stage (``stage_seconds``, ``stage_steps``: prepare, replicate_open, reference, dynamic, static;
summed over restarts), ``seconds_per_step``, ``element_steps_per_second`` and every rank's peak
resident memory ``peak_rss_mib`` (of this process). ``--restart DIR/checkpoints/checkpoint-<step>.h5``
continues a run from any stage (the preparation, the reference relaxation, the dynamic
snapshots, the static relaxation: bit for bit on the same number of ranks; by default into a new
folder ``DIR-restart-<stamp>``); ``--steps N`` stops it at step N (counted from the run's start over
all stages), leaving a checkpoint to continue from; a stop signal (SIGTERM, SIGINT) ends it at a
step boundary with a checkpoint (``checkpoint.at_stop``).

Exit codes: 0 done (or stopped by --steps), 1 unexpected error (all ranks stop), 2 bad input (one
line naming the field), 3 the run became unstable, 128 + N stopped by signal N (checkpoint written).
"""
import os
import time

import numpy as np

import pardem
from pardem.config import DeckError
from pardem.drivers import cli
from pardem.drivers.granular import GranularDriver
from pardem.drivers.runner import protocol_main
from pardem.io import response_plot
from pardem.protocols import granular_output as gout
from pardem.protocols import response
from pardem.protocols import stages

# deck keys a restart may change besides [output] and [checkpoint] (the rest is the physics)
RESTART_MAY_CHANGE = ("run.progress_seconds", "run.watchdog_seconds", "run.slab_axis")


def parser(comm=None):
    return cli.granular_parser("response", __doc__, response.SCHEMA, RESTART_MAY_CHANGE, comm=comm,
                               deck_title="deck keys and defaults (drivers/response.toml)",
                               steps_note="; in a relaxation the run stops at the first check (every "
                                          "relax.check_every steps) at or after step N",
                               outputs="DIR/response.json, response.csv, response.h5, response.png, "
                                       "response_vtk/response.pvd, checkpoints/, paraview/")


def main(argv=None):
    return protocol_main(Response, parser, argv)


class Response(GranularDriver):
    name = "response"
    schema = response.SCHEMA
    summary_name = "response.json"
    error_types = (ValueError,)
    restart_may_change = RESTART_MAY_CHANGE
    restart_what = "run.slab_axis, run.progress_seconds, run.watchdog_seconds"
    columns, units, description, int_columns = (response.SERIES_COLUMNS, response.SERIES_UNITS,
                                                response.SERIES_DESCRIPTION, response.SERIES_INT)
    slab_axes = "xy"

    def __init__(self):
        self.sweep = None        # the preparation's stages.SweepRun (its state goes into checkpoints)
        self.layer = None        # the loaded layer, once the packing is opened
        self.vtk = None
        self.clock = None

    def check(self, run, deck):
        if deck["run"]["slab_axis"] == "z":
            raise DeckError("run.slab_axis = 'z': expected 'x' or 'y' (the grains lie in the plane z = 0)")

    def build(self, run):
        run.state = {"driver": "response", "stage": "prepare", "sweep": None, "preparation": None, "layer": None,
                     "respond": None, "clock": None, "vtk": [], "result": None}
        return stages.build_gas(run.comm, response.iso_deck(run.deck))

    def restore(self, run):
        case = super().restore(run)
        if run.state["stage"] != "prepare":
            self.layer = response.restore_layer(case, run.deck, run.state["layer"], run.meta["series"])
            response.restore_response(self.layer, run.meta["series"])
        return case

    def protocol_state(self, run):
        """The state for a checkpoint (collective: the layer's clamp reactions are gathered)."""
        st = dict(run.state)
        st["result"] = None     # the summary holds it; the checkpoint need not
        if self.sweep is not None:
            st["sweep"] = self.sweep.snapshot(interrupted=run.interrupted is not None)
        st["clock"] = self.clock.state(run.sim.step_count) if self.clock is not None else st["clock"]
        if self.vtk is not None:
            st["vtk"] = list(self.vtk.entries)
        self._arrays = {}
        if self.layer is not None:
            st["layer"], self._arrays = response.layer_state(self.layer)
        return st

    def payload(self, run):
        groups, series, attrs = gout.payload(run.case, run.deck, self.protocol_state(run), run.series.rows,
                                             self.columns)
        series.update(self._arrays)
        if self.layer is not None:
            series.update(response.response_arrays(self.layer))
        return groups, series, attrs

    def start(self, run):
        self.open_series(run)
        self.clock = gout.StageClock(run.state.get("clock"))
        k = run.deck["replicate"]["copies"]
        run.progress.say(f"pardem {pardem.__version__} response: {run.deck['sample']['n']} grains (2D) x "
                         f"{k[0]} x {k[1]} copies on {run.comm.size} rank(s), p = "
                         f"{run.deck['preparation']['pressure']:g} Pa; output {run.out}"
                         + (f"; restarted from {run.args.restart} (step {run.sim.step_count}, "
                            f"{run.state['stage']})" if run.meta else ""))

    def execute(self, run):
        """The protocol's stages (``response.RUN_STAGES``), from the checkpoint's on restart."""
        stages.run_stages(run.state, [(name, lambda again, name=name: getattr(self, f"stage_{name}")(run, again))
                                      for name in response.RUN_STAGES], resume=run.meta is not None)

    def stage_prepare(self, run, resume):
        """The frictionless periodic packing (``stages.prepare``, resumable), then replicated and
        opened into the loaded layer (no step)."""
        comm, deck, progress, stop = run.comm, run.deck, run.progress, run.args.steps
        self.clock.enter("prepare", run.sim.step_count)
        self.sweep = stages.SweepRun(operations=run.operations, stop=stop,
                                     state=dict(run.state["sweep"]) if resume else None)
        t0 = time.perf_counter()
        case, info = stages.prepare(comm, response.iso_deck(deck), deck["preparation"]["pressure"], case=run.case,
                                    progress=progress, run=self.sweep, resume=resume)
        self.sweep = None
        run.state["sweep"] = None
        case.sim.elements.v[:] = 0.0
        case.sim.elements.w[:] = 0.0
        b = info["balance"]
        run.state["preparation"] = {"converged": info["converged"], "steps": info["steps"],
                                    "pressure": b["pressure"], "unbalanced": b["unbalanced"],
                                    "seconds": self.clock.state(run.sim.step_count)["seconds"]["prepare"]}
        progress.say(f"prepared in {info['steps']} steps ({time.perf_counter() - t0:.1f} s): p = "
                     f"{b['pressure']:.5g} Pa, converged: {info['converged']}")
        self.clock.enter("replicate_open", run.sim.step_count)
        self.layer = response.make_layer(comm, case, deck, progress)
        run.case = self.layer.case
        progress.n_elements = int(self.layer.geometry["n_grains"])   # the rate counts the copies
        progress.start(run.sim.step_count)                           # measured afresh
        run.state["respond"] = response.new_state()
        self.clock.close(run.sim.step_count)
        progress.say(f"opened: {self.layer.geometry['n_grains']} grains, rows of {self.layer.geometry['n_bottom']} "
                     f"(bottom) and {self.layer.geometry['n_top']} (top), "
                     f"{self.clock.seconds['replicate_open']:.1f} s")

    def stage_respond(self, run, resume):
        """The reference relaxation, the load, the dynamic and static responses (``response.respond``
        resumes its own sub-stages from ``run.state["respond"]``)."""
        comm, deck, progress, stop = run.comm, run.deck, run.progress, run.args.steps
        layer = self.layer
        if comm.is_root and deck["output"]["perturbation_vtk"]:
            self.vtk = response_plot.PerturbationVTK(os.path.join(run.out, "response_vtk"),
                                                     entries=run.state.get("vtk") or [])

        def on_record(label, state, result):
            if state is None or self.vtk is None:
                return
            pg = result["per_grain"]
            g = layer.geometry
            area = g["length"][0] * g["length"][1]
            phi = float(np.sum(np.pi * state["radius"] ** 2) / area)
            self.vtk.write(layer.sim.time, state["x"], state["radius"],
                           response.per_grain_stress(pg["dM_yy"], state["radius"], g["thickness"], phi),
                           pg["dM_yy"], pg["displacement"], np.arange(len(state["radius"])))

        res = response.respond(layer, deck, progress, run.operations, on_row=run.series.append,
                               on_record=on_record, state=run.state["respond"], stop=stop, clock=self.clock)
        if res is not None:
            res.pop("_per_grain", None)
        run.state["result"] = res

    def summary(self, run):
        clock = self.clock if self.clock is not None else gout.StageClock(run.state.get("clock"))
        n = int(run.comm.sum(run.sim.elements.n_owned))
        return {"result": run.state.get("result"), "preparation": run.state.get("preparation"),
                "stage": run.state.get("stage"), "respond_stage": (run.state.get("respond") or {}).get("stage"),
                "n_grains": n,
                # grains x steps / s (the preparation has the unreplicated sample.n grains)
                **clock.summary(run.sim.step_count, lambda k: run.deck["sample"]["n"] if k == "prepare" else n),
                "conventions": {"stress": "Love-Weber, per unit area of the plane divided by the thickness t "
                                          "(the mean diameter) [Pa], tension positive",
                                "dsigma_yy": "change of sigma_yy from the reference state, binned: sum of the "
                                             "grains' dM_yy over dx h t",
                                "depth": "below the loaded grain's centre [m]",
                                "x": "horizontal offset from the loaded grain (periodic) [m]",
                                "flamant": "sigma_yy = -2 F z^3 / (pi t r^4), with periodic images"},
                "series": ["response.csv", "response.h5"]}

    def finish(self, run, summary):
        res = summary["result"]
        if run.stopped:
            print(f"{run.stopped}; continue with --restart "
                  f"{run.writer.written[-1] if run.writer.written else '(no checkpoint: checkpoint.at_end = false)'}",
                  flush=True)
            return cli.EXIT_OK
        if res is None:
            return cli.EXIT_OK
        if run.deck["output"]["plot"]:
            response_plot.plot(os.path.join(run.out, "response.png"), res)
        st = res["static"]
        tr = np.asarray(st["transmitted_over_F"])
        fits = st["fits_half_max"]
        run.progress.say(
            f"static response: {st['steps']} steps (converged: {st['converged']}); transmitted force / F per layer "
            f"{tr.min():.3f} .. {tr.max():.3f}; half width fits: elastic w = {fits['c'] or float('nan'):.3g} z "
            f"(rms {fits['elastic_residual'] or float('nan'):.2g}), diffusive D = "
            f"{(fits['D'] or float('nan')) / res['geometry']['mean_diameter']:.3g} d (rms "
            f"{fits['diffusive_residual'] or float('nan'):.2g}); Flamant: 0.644 z; top row took "
            f"{res['reactions']['top_share']:.3g} F, bottom {res['reactions']['bottom_share']:.3g} F; "
            f"{summary['wall_seconds']:.1f} s; outputs in {run.out}")
        return cli.EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
