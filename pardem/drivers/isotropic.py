"""Isotropic preparation of a frictionless granular packing at pressures p0, then its elastic moduli.

    python -m pardem.drivers.isotropic [--config deck.toml] [--set section.key=value ...]
        [--pressures 1e5,1e6,...] [--out DIR] [--steps N] [--restart CHECKPOINT.h5] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.isotropic --config drivers/isotropic_glass.toml

A gas of spheres in a periodic cell is compressed by a pressure servo, the kinetic energy removed by
FIRE (adaptive step) or global viscous damping, to static equilibrium at each p0 (ascending, the
same packing continued), measured (p, Z, Z without rattlers, solid fraction, normal force
distribution), then, with friction restored, probed by small affine strain increments (isotropic and
volume-preserving shear) for the bulk and shear moduli, affine (the first step of each increment's
ramp, no relaxation) and relaxed; beside them the static moduli of the contact network's linear
response (``moduli.static``). The protocol and the equilibrium criteria are those of
``pardem.protocols.isotropic``. Default deck: ``drivers/isotropic_glass.toml`` values (10,000 glass
spheres).
``[domain] dimension = 2`` runs the same protocol in the 2D mode (``pardem.engine.plane``: sphere
centres in the plane z = 0, stresses per unit area over the mean diameter, solid fraction as disk
area over cell area).

Writes ``DIR/isotropic.json`` (the summary): ``rows`` (one per pressure: ``p0, p, Z, Z_no_rattlers,
solid_fraction, K_affine, K_relaxed, mu_affine, mu_relaxed, K_static, mu_static``, SI units; a
modulus is null when not measured), ``details`` (per pressure: convergence, steps, criteria values,
rattlers, the force distribution ``f_n / <f_n>`` histogram, ``static`` (the linear response of the
prepared packing: ``pardem.protocols.moduli_check.compact``), ``moduli`` (strain, ramp steps,
relaxations, and ``moduli.static``: K_static, mu_static beside K_relaxed, mu_relaxed and their
relative differences ``K_difference = K_relaxed / K_static - 1``, ``mu_difference``, likewise for
the affine moduli)), ``criteria``, ``deck``, ``n_ranks``, ``steps``, ``finished``,
``restarted_from``, ``checkpoints``, ``wall_seconds``; ``DIR/isotropic.csv`` and
``DIR/isotropic.h5`` (the series, one row per equilibrium check:
``pardem.protocols.isotropic.SERIES_COLUMNS``, units in the HDF5 file); ``DIR/isotropic.png``
(pressure / p0 and solid fraction against step) and ``DIR/force_distribution.png`` when matplotlib
is available; checkpoints in ``DIR/checkpoints`` (``[checkpoint]``), ParaView snapshots in
``DIR/paraview`` (``output.vtk_every``). ``--restart DIR/checkpoints/checkpoint-<step>.h5``
continues a run from its checkpoint (bit for bit on the same number of ranks); ``--steps N`` stops
it at the first equilibrium check at or after step N (steps of all pressures and stages, counted
from the run's start), leaving a checkpoint to continue from.

Exit codes: 0 done (a pressure that did not reach equilibrium within ``preparation.max_steps`` is
flagged ``converged: false`` in ``details`` and warned about), 1 unexpected error (all ranks stop),
2 bad input (one line naming the option or deck field), 3 the run became unstable.
"""
import os
import sys

import pardem
from pardem.config import DeckError
from pardem.drivers import cli
from pardem.drivers.granular import GranularDriver
from pardem.drivers.runner import protocol_main
from pardem.io import isotropic_plot
from pardem.protocols import isotropic as iso
from pardem.protocols import stages

# deck keys a restart may change besides [output] and [checkpoint] (the rest is the physics)
RESTART_MAY_CHANGE = ("run.progress_seconds", "run.watchdog_seconds", "run.slab_axis", "preparation.max_steps",
                      "moduli.max_relax_steps")


def parser(comm=None):
    p = cli.granular_parser("isotropic", __doc__, iso.SCHEMA, RESTART_MAY_CHANGE, comm=comm,
                            steps_note="; the run stops at the first equilibrium check (every "
                                       "preparation.check_every steps) at or after step N",
                            outputs="DIR/isotropic.json, isotropic.csv, isotropic.h5, isotropic.png, "
                                    "force_distribution.png, checkpoints/, paraview/")
    p.add_argument("--pressures", metavar="P1,P2,...",
                   help="target pressures p0 [Pa], comma-separated (overrides preparation.pressures)")
    return p


def main(argv=None):
    return protocol_main(Isotropic, parser, argv)


def _pressures(text):
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        vals = []
    if not vals or not all(v > 0.0 and v < float("inf") for v in vals):
        raise DeckError(f"--pressures {text!r}: expected comma-separated positive numbers [Pa]")
    return sorted(vals)


class Isotropic(GranularDriver):
    name = "isotropic"
    schema = iso.SCHEMA
    summary_name = "isotropic.json"
    restart_may_change = RESTART_MAY_CHANGE
    restart_what = ("the run length (--steps, preparation.max_steps, moduli.max_relax_steps), "
                    "run.slab_axis, run.progress_seconds")
    columns, units, description, int_columns = (iso.SERIES_COLUMNS, iso.SERIES_UNITS, iso.SERIES_DESCRIPTION,
                                                iso.SERIES_INT)

    def check(self, run, deck):
        iso.check_sample(deck)
        if run.args.pressures is not None:
            deck["preparation"]["pressures"] = _pressures(run.args.pressures)
            iso.pressure_checks(deck)

    def build(self, run):
        return stages.build_gas(run.comm, run.deck)

    def protocol_state(self, run):
        return run.state["sweep"].snapshot()

    def start(self, run):
        deck = run.deck
        pressures = sorted(deck["preparation"]["pressures"])
        n = deck["sample"]["n"]
        kind = "spheres" if stages.dimension(deck) == 3 else "spheres in the plane z = 0 (2D)"
        run.progress.say(f"pardem {pardem.__version__}: isotropic preparation of {n} {kind} on {run.comm.size} "
                         f"rank(s), p0 = {', '.join(f'{p:g}' for p in pressures)} Pa, output {run.out}"
                         + (f", restarted from {run.args.restart} (step {int(run.meta['step'])})" if run.meta else ""))
        self.open_series(run)
        sweep_run = stages.SweepRun(stop=run.args.steps, state=run.meta["protocol"] if run.meta else None)
        st = sweep_run.state

        def on_check(sim, b):
            run.series.append({
                "step": sim.step_count, "time": sim.time, "pressure_index": st["index"],
                "stage": iso.STAGES.index(st["stage"]), "p0": pressures[st["index"]],
                "pressure": b["pressure"], "solid_fraction": b["solid_fraction_raw"],
                "coordination": 2.0 * b["n_contacts"] / b["n_elements"], "kinetic": b["kinetic"],
                "unbalanced": b["unbalanced"], "unbalanced_max": b["unbalanced_max"], "dt": sim.dt,
                "cell_rate": float(sim.cell.rate[0])})
        sweep_run.on_check = on_check
        run.state = {"sweep": sweep_run, "pressures": pressures}

    def execute(self, run):
        sweep_run = run.state["sweep"]
        sweep_run.operations = run.operations
        _, _, run.case = iso.sweep(run.comm, run.deck, run.state["pressures"], run.progress, case=run.case,
                                   run=sweep_run)

    def summary(self, run):
        st = run.state["sweep"].state
        deck = run.deck
        return {"rows": st["rows"], "details": st["details"], "criteria": iso.criteria_text(deck),
                "dt": float(run.case.extras["dt"]),
                "units": {"p0": "Pa", "p": "Pa", "K_affine": "Pa", "K_relaxed": "Pa",
                          "mu_affine": "Pa", "mu_relaxed": "Pa", "K_static": "Pa", "mu_static": "Pa", "Z": "1",
                          "solid_fraction": "1"},
                "n_elements": deck["sample"]["n"], "series": ["isotropic.csv", "isotropic.h5"],
                "dimension": stages.dimension(deck), "stress_convention": iso.stress_convention(run.case.sim)}

    def finish(self, run, summary):
        out, rows, details = run.out, summary["rows"], summary["details"]
        written = ["isotropic.json", "isotropic.csv", "isotropic.h5"]
        if run.deck["output"]["plot"]:
            if isotropic_plot.force_distribution(details, os.path.join(out, "force_distribution.png")):
                written.append("force_distribution.png")
            if isotropic_plot.series(run.series.rows, os.path.join(out, "isotropic.png")):
                written.append("isotropic.png")
        print(format_table(rows))
        bad = [d["p0"] for d in details if not d["converged"]]
        if bad:
            print(f"warning: no static equilibrium within preparation.max_steps at p0 = "
                  f"{', '.join(f'{p:g}' for p in bad)} Pa (see details in isotropic.json)")
        if run.stopped:
            print(f"{run.stopped}: {len(rows)} of {len(run.state['pressures'])} pressures done; continue with "
                  f"--restart {run.writer.written[-1] if run.writer.written else '(no checkpoint: checkpoint.at_end = false)'}")
        print(f"wrote {', '.join(os.path.join(out, w) for w in written)} in {summary['wall_seconds']:.1f} s")
        return cli.EXIT_OK


def format_table(rows):
    head = ("p0 [Pa]", "p [Pa]", "Z", "Z_nr", "phi", "K_aff [Pa]", "K_rel [Pa]", "mu_aff [Pa]", "mu_rel [Pa]",
            "K_stat [Pa]", "mu_stat [Pa]")
    lines = ["  ".join(f"{h:>11s}" for h in head)]
    for r in rows:
        vals = [r.get(k) for k in iso.ROW_KEYS]
        lines.append("  ".join("       null" if v is None else f"{v:11.5g}" for v in vals))
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
