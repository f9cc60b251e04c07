"""Point-load response function of a 2D granular packing (python -m pardem.drivers.response).

    python -m pardem.drivers.response [--config deck.toml] [--set section.key=value ...] [--out DIR] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.response --config drivers/response_short.toml --out runs/resp

A 2D packing is prepared frictionless at the pressure p in a periodic cell (isotropic protocol),
optionally replicated k_x x k_y times, opened along y with a clamped bottom row and a rigid top row
(loaded by its reference force, or clamped), friction restored; after relaxing to the reference
equilibrium, the free grain at the top centre gets an extra downward force F (a fraction of the
mean contact force); the dynamic (undamped) response is recorded at a few times, then the static
one after relaxing again. ``pardem.protocols.response`` describes the protocol and the measures.

Writes ``DIR/response.json`` (the summary: the force F, the loaded grain, the wave speed, height
and transit time, the reference state, ``static`` and ``dynamic`` (each: x and depth bin centres
[m], ``dsigma_yy`` [nz][nx] [Pa], ``transmitted_over_F`` per layer, profile widths, the same for
Flamant's half-plane and the layer on a rigid base, the width fits), the reactions of the rows,
geometry, deck, timings), ``DIR/response.csv`` and ``DIR/response.h5`` (one row per relaxation
check: ``pardem.protocols.response.SERIES_COLUMNS``), ``DIR/response.png`` (needs matplotlib),
``DIR/response_vtk/response.pvd`` (the perturbation per grain, ``output.perturbation_vtk``) and
ParaView snapshots of the whole state in ``DIR/paraview`` (``output.vtk_every``). A checkpoint of
the final state is written (``[checkpoint]``), but the driver does not restart from one: run it
again.

Exit codes: 0 done, 1 unexpected error (all ranks stop), 2 bad input (one line naming the field),
3 the run became unstable.
"""
import os
import time

import numpy as np

import pardem
from pardem.config import DeckError
from pardem.drivers import cli
from pardem.drivers.runner import GranularDriver, run_protocol
from pardem.io import response_plot
from pardem.parallel.communicator import Communicator
from pardem.protocols import isotropic as iso
from pardem.protocols import response


def parser(comm=None):
    return cli.driver_parser("python -m pardem.drivers.response", __doc__.split("\n\n")[0], response.SCHEMA,
                             comm=comm, out_default="runs/response-<timestamp>",
                             deck_title="deck keys and defaults (drivers/response.toml)",
                             epilog="outputs: DIR/response.json, response.csv, response.h5, response.png, "
                                    "response_vtk/response.pvd, checkpoints/, paraview/")


def main(argv=None):
    comm = Communicator()
    return cli.run_driver(comm, lambda comm, args: run_protocol(comm, args, Response()), parser(comm).parse_args(argv))


class Response(GranularDriver):
    name = "response"
    schema = response.SCHEMA
    summary_name = "response.json"
    error_types = (ValueError,)
    columns, units, description, int_columns = (response.SERIES_COLUMNS, response.SERIES_UNITS,
                                                response.SERIES_DESCRIPTION, response.SERIES_INT)
    slab_axes = "xy"

    def inspect(self, run):
        raise DeckError(f"--restart {run.args.restart}: the response driver does not restart from a "
                        "checkpoint; run it again")

    def check(self, run, deck):
        if run.args.steps is not None:
            raise DeckError("--steps: the response driver runs its stages to their criteria "
                            "(relax.max_steps caps each relaxation)")

    def build(self, run):
        run.state = {"driver": "response", "stage": "prepare", "result": None}
        return iso.build_gas(run.comm, response.iso_deck(run.deck))

    def start(self, run):
        self.open_series(run)
        k = run.deck["replicate"]["copies"]
        run.progress.say(f"pardem {pardem.__version__} response: {run.deck['sample']['n']} grains (2D) x "
                         f"{k[0]} x {k[1]} copies on {run.comm.size} rank(s), p = "
                         f"{run.deck['preparation']['pressure']:g} Pa; output {run.out}")

    def execute(self, run):
        comm, deck, progress = run.comm, run.deck, run.progress
        t0 = time.perf_counter()
        case, info = iso.prepare(comm, response.iso_deck(deck), deck["preparation"]["pressure"], case=run.case,
                                 progress=progress, run=iso.SweepRun(operations=run.operations))
        case.sim.elements.v[:] = 0.0
        case.sim.elements.w[:] = 0.0
        b = info["balance"]
        run.state["preparation"] = {"converged": info["converged"], "steps": info["steps"],
                                    "pressure": b["pressure"], "unbalanced": b["unbalanced"],
                                    "seconds": time.perf_counter() - t0}
        progress.say(f"prepared in {info['steps']} steps ({time.perf_counter() - t0:.1f} s): p = "
                     f"{b['pressure']:.5g} Pa, converged: {info['converged']}")
        layer = response.make_layer(comm, case, deck, progress)
        run.case = layer.case
        run.state["stage"] = "respond"
        vtk = None
        if comm.is_root and deck["output"]["perturbation_vtk"]:
            vtk = response_plot.PerturbationVTK(os.path.join(run.out, "response_vtk"))

        def on_record(label, state, result):
            if state is None or vtk is None:
                return
            pg = result["per_grain"]
            g = layer.geometry
            area = g["length"][0] * g["length"][1]
            phi = float(np.sum(np.pi * state["radius"] ** 2) / area)
            vtk.write(layer.sim.time, state["x"], state["radius"],
                      response.per_grain_stress(pg["dM_yy"], state["radius"], g["thickness"], phi),
                      pg["dM_yy"], pg["displacement"], np.arange(len(state["radius"])))

        res = response.respond(layer, deck, progress, run.operations, on_row=run.series.append,
                               on_record=on_record)
        if res is not None:
            res.pop("_per_grain", None)
        run.state["result"] = res
        run.state["stage"] = "done"

    def summary(self, run):
        return {"result": run.state.get("result"), "preparation": run.state.get("preparation"),
                "conventions": {"stress": "Love-Weber, per unit area of the plane divided by the thickness t "
                                          "(the mean diameter) [Pa], tension positive",
                                "dsigma_yy": "change of sigma_yy from the reference state, binned: sum of the "
                                             "grains' dM_yy over dx h t",
                                "depth": "below the loaded grain's centre [m]",
                                "x": "horizontal offset from the loaded grain (periodic) [m]",
                                "flamant": "sigma_yy = -2 F z^3 / (pi t r^4), with periodic images"},
                "series": ["response.csv", "response.h5"]}

    def protocol_state(self, run):
        st = dict(run.state)
        st["result"] = None     # the summary holds it; the checkpoint need not
        return st

    def finish(self, run, summary):
        res = summary["result"]
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
