"""2D biaxial compression with rigid granular platens and flexible membranes (python -m pardem.drivers.biaxial).

    python -m pardem.drivers.biaxial [--config deck.toml] [--set section.key=value ...] [--out DIR]
        [--steps N] [--restart CHECKPOINT.h5] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.biaxial --config drivers/biaxial_short.toml --out runs/bx

For each confining pressure pc: a 2D packing prepared frictionless at pc in a periodic cell, opened,
cut between two rigid granular platens, wrapped in two flexible membranes loaded by pc, then
compressed between the platens at a constant axial strain rate with friction on
(``pardem.protocols.biaxial`` describes the protocol, the conventions and the measures). The
deck's defaults are the 10,000-grain case of ``drivers/biaxial.toml``.

Writes ``DIR/biaxial.csv`` and ``DIR/biaxial.h5`` (the series with units: step, time [s],
pressure_index, pc [Pa], eps_axial, eps_vol (compression / contraction positive), sigma_axial,
sigma_lateral, q, s [Pa], sin_phi, sigma_axial_platens [Pa], coordination, sliding_fraction,
membrane_grains, n_grains, cements_intact, cements_fading, cements_broken, broken_fraction,
kinetic_energy [J]), ``DIR/biaxial.json`` (per pressure: the
preparation, the sample, peak and residual friction angles, the dilatancy angle, the lateral
stress error, and per localisation window the shear band (angle, width in mean diameters,
centre, contrast, and whether the field is localised at all: ``shear_band.detect``) with the
Mohr-Coulomb, Roscoe and Arthur predictions, printed side by side for a localised band; the deck, ``finished``,
``restarted_from``, ``checkpoints``, timings: ``stage_seconds``, ``stage_steps``, ``seconds_per_step`` and
``element_steps_per_second`` per stage (prepare, open, settle, load), ``peak_rss_mib`` per rank), ``DIR/biaxial.png`` (q / pc and eps_v against
eps_a; cemented: the broken cements too), ``DIR/localisation-P-W.png`` (maps of the incremental shear strain and grain rotations of
window W of pressure P) and ``DIR/localisation-P-W.vtu`` (the same fields for ParaView, with
the cements each grain lost in the window), and for cemented samples (``[cement] enabled = true``,
``drivers/biaxial_cemented.toml``) ``DIR/cements-P.png`` (the broken cements as segments between
the pair centres, coloured by the axial strain at rupture, over the grains at the end) and
``DIR/cements-P.vtu`` (per grain the broken and intact cements, the broken cements as lines with
their strain at rupture); the JSON's ``cements`` per pressure: cements at the start, broken at
the end, the broken fraction at the peak and at the end, the share of broken cements in the last
localised window's band against the band's share of all cements. The cement law keeps no rupture time, so
the strain at rupture is that of the first sample at which a cement was no longer intact
(``biaxial.CementRecord``, resolution ``loading.strain / output.samples``);
checkpoints in ``DIR/checkpoints`` and ParaView snapshots in ``DIR/paraview``
(``output.vtk_every``). ``--restart DIR/checkpoints/checkpoint-<step>.h5`` continues a run from any stage (the
preparation with its FIRE state and servo, the settling, the loading, a membrane rebuild's step:
bit for bit on the same number of ranks); ``--steps N`` stops it at step N (counted from the run's
start, over all stages, the preparation included), leaving a checkpoint to continue from. The
stages of each pressure are ``pardem.protocols.biaxial.STAGES``, run by ``stages.run_stages``.

Exit codes: 0 done, 1 unexpected error (all ranks stop), 2 bad input (one line naming the field),
3 the run became unstable.
"""
import os
import time

import numpy as np

import pardem
from pardem.config import DeckError
from pardem.drivers import cli
from pardem.drivers.granular import GranularDriver
from pardem.drivers.runner import protocol_main
from pardem.engine import granular
from pardem.io import biaxial_plot
from pardem.physics import shear_band
from pardem.protocols import biaxial
from pardem.protocols import granular_output as gout
from pardem.protocols import stages

RESTART_MAY_CHANGE = ("run.progress_seconds", "run.watchdog_seconds", "run.slab_axis")
SNAP_KEYS = ("gid", "x", "theta", "pair_i", "pair_j", "cements")
CEMENT_KEYS = ("initial", "keys", "strain", "step")


def parser(comm=None):
    return cli.granular_parser("biaxial", __doc__, biaxial.SCHEMA, RESTART_MAY_CHANGE, comm=comm,
                               deck_title="deck keys and defaults (drivers/biaxial.toml)",
                               outputs="DIR/biaxial.csv, biaxial.h5, biaxial.json, biaxial.png, "
                                       "localisation-P-W.png/.vtu, cements-P.png/.vtu (cemented), checkpoints/, paraview/")


def main(argv=None):
    return protocol_main(Biaxial, parser, argv)


def band_line(window):
    """One line on a localisation window's band: its angle beside the predictions when the field
    is localised (``shear_band.detect``), else that no band formed."""
    b, p = window["band"], window["predictions"]
    head = f"  window to eps_a = {window['strain_end']:.3f}: "
    if b is None or not b.get("localised"):
        why = "" if b is None else (f" (best line at {b['angle_deg']:.1f} deg: contrast "
                                    f"{b.get('contrast', float('nan')):.2f}, strip rank {b.get('score', float('nan')):.3f} "
                                    f"against {b.get('null_score', float('nan')):.3f} shuffled)")
        return head + "no localised shear band" + why
    return (head + f"band at {b['angle_deg']:.1f} deg, width {b['width_d']:.1f} d, contrast {b['contrast']:.1f}; "
            f"Mohr-Coulomb {p['mohr_coulomb']:.1f}, Roscoe {p['roscoe']:.1f}, Arthur {p['arthur']:.1f} deg")


def fresh_state(index, pc):
    """The state of confining pressure ``index`` before its first stage (``biaxial.STAGES``);
    ``sweep``: the preparation's ``stages.SweepRun`` state while it runs."""
    return {"index": index, "pc": pc, "stage": biaxial.STAGES[0], "prep": None, "geo": None, "settle_start": None,
            "reference": None, "events_done": [], "windows": [], "membrane": None, "sweep": None}


class Biaxial(GranularDriver):
    name = "biaxial"
    schema = biaxial.SCHEMA
    summary_name = "biaxial.json"
    error_types = (ValueError,)
    restart_may_change = RESTART_MAY_CHANGE
    restart_what = "run.slab_axis, run.progress_seconds, run.watchdog_seconds"
    columns, units, description, int_columns = biaxial.COLUMNS, biaxial.UNITS, biaxial.DESCRIPTION, biaxial.INT_COLUMNS
    slab_axes = "xy"

    def __init__(self):
        self.mem = self.platens = None
        self.pending = {}        # localisation window -> snapshot of its start
        self.record = None       # cemented: biaxial.CementRecord of the current loading
        self.clock = None        # gout.StageClock: wall seconds and steps per stage
        self.sweep = None        # the preparation's stages.SweepRun while it runs (its state goes into checkpoints)

    def check(self, run, deck):
        if deck["run"]["slab_axis"] == "z":
            raise DeckError("run.slab_axis = 'z': expected 'x' or 'y' (the grains lie in the plane z = 0)")

    def build(self, run):
        pcs = run.deck["loading"]["confining_pressures"]
        run.state = {"driver": "biaxial", "results": [], "current": fresh_state(0, pcs[0])}
        return stages.build_gas(run.comm, biaxial.iso_deck(run.deck))

    def restore(self, run):
        case = super().restore(run)
        cur = run.state["current"]
        if cur["stage"] in ("settle", "load"):
            self.mem, *self.platens = biaxial.install(case, run.deck, cur["pc"], cur["geo"], cur["membrane"],
                                                      moving=cur["stage"] == "load", restored=True)
            total = cur.get("platen_reactions")
            if total is not None:
                # the last force evaluation's platen reactions (a sample replayed on restart reads
                # them): their total on rank 0, so that the samples' sum over the ranks is it exactly
                for fix, r in zip(self.platens, np.reshape(total, (2, 3))):
                    fix.reaction[:] = r if run.comm.is_root else 0.0
        series = run.meta["series"]
        for w in {int(k.split("_")[1]) for k in series if k.startswith("window_")}:
            snap = {k: np.asarray(series[f"window_{w}_{k}"]) for k in SNAP_KEYS}
            snap["x"] = snap["x"].reshape(-1, 2)
            self.pending[w] = snap
        if cur["stage"] in ("settle", "load") and "cement_initial" in series:
            self.record = biaxial.CementRecord.from_state({k: np.asarray(series[f"cement_{k}"]) for k in CEMENT_KEYS})
        return case

    def protocol_state(self, run):
        cur = dict(run.state["current"])
        cur["membrane"] = self.mem.state() if self.mem is not None else None
        if self.sweep is not None:
            cur["sweep"] = self.sweep.snapshot(interrupted=run.interrupted is not None)
        cur["platen_reactions"] = (run.comm.sum(np.concatenate([p.reaction for p in self.platens])).tolist()
                                   if self.platens else None)       # collective: every rank writes the payload
        clock = self.clock.state(run.sim.step_count) if self.clock is not None else run.state.get("clock")
        return {**run.state, "current": cur, "clock": clock}

    def payload(self, run):
        groups, series, attrs = super().payload(run)
        for w, snap in self.pending.items():
            for k in SNAP_KEYS:
                series[f"window_{w}_{k}"] = np.asarray(snap[k]).ravel()
        if self.record is not None:
            for k, v in self.record.state().items():
                series[f"cement_{k}"] = v
        return groups, series, attrs

    def start(self, run):
        self.open_series(run)
        self.clock = gout.StageClock(run.state.get("clock"))
        geo = run.state["current"]["geo"]
        if geo is not None:
            run.progress.n_elements = geo["n_grains"]
        d = run.deck
        run.progress.say(f"pardem {pardem.__version__} biaxial (2D): {d['sample']['n']} grains on {run.comm.size} "
                         f"rank(s), dt = {run.sim.dt:.4g} s; confining pressures "
                         f"{', '.join(f'{p:.3g}' for p in d['loading']['confining_pressures'])} Pa; output {run.out}"
                         + (f"; restarted from {run.args.restart} (step {run.sim.step_count}, "
                            f"{run.state['current']['stage']})" if run.meta else ""))

    # -- the run: the protocol's stages (biaxial.STAGES) per confining pressure ----------------

    def execute(self, run):
        pcs = run.deck["loading"]["confining_pressures"]
        resume = run.meta is not None      # the first stage continues the checkpoint's
        while run.state["current"]["index"] < len(pcs):
            k = run.state["current"]["index"]
            stages.run_stages(run.state["current"],
                              [(name, lambda again, name=name: getattr(self, f"stage_{name}")(run, again))
                               for name in biaxial.STAGES], resume=resume)
            resume = False
            run.state["current"] = fresh_state(k + 1, pcs[k + 1] if k + 1 < len(pcs) else None)

    def stage_prepare(self, run, resume):
        """The frictionless periodic packing at pc (``stages.prepare``): resumed from a checkpoint
        written in it with its FIRE state and relaxation start; the run's operations (checkpoints,
        ParaView) run in it and ``--steps`` stops it at that step."""
        deck, progress, cur = run.deck, run.progress, run.state["current"]
        k, pc = cur["index"], cur["pc"]
        self.clock.enter("prepare", run.sim.step_count)
        if k > 0 and not run.case.sim.cell.periodic[1]:     # a new gas after the last loading
            step, t = run.sim.step_count, run.sim.time
            run.case = stages.build_gas(run.comm, biaxial.iso_deck(deck))
            granular.continue_clock(run.sim, step, t)
        resume = resume and cur.get("sweep") is not None
        self.sweep = stages.SweepRun(operations=run.operations, stop=run.args.steps,
                                     state=dict(cur["sweep"]) if resume else None, exact_stop=True)
        t0 = time.perf_counter()
        if resume:
            progress.say(f"pc = {pc:.4g} Pa: continuing the preparation from step {run.sim.step_count}")
        run.case, info = stages.prepare(run.comm, biaxial.iso_deck(deck), float(pc), case=run.case,
                                        progress=progress, run=self.sweep, resume=resume)
        self.sweep = None
        cur["sweep"] = None
        b = info["balance"]
        cur["prep"] = {"steps": info["steps"], "converged": info["converged"], "pressure": b["pressure"],
                       "unbalanced": b["unbalanced"], "kinetic": b["kinetic"],
                       "seconds": self.clock.state(run.sim.step_count)["seconds"]["prepare"]}
        progress.say(f"pc = {pc:.4g} Pa: prepared in {info['steps']} steps ({time.perf_counter() - t0:.1f} s), "
                     f"p = {b['pressure']:.4g} Pa, converged: {info['converged']}")

    def stage_open(self, run, resume):
        """The packing replicated, opened, cut between the platens; friction on; membranes and
        platens installed (no step: a checkpoint is never inside it)."""
        deck, progress, cur, stop = run.deck, run.progress, run.state["current"], run.args.steps
        if stop is not None and run.sim.step_count >= stop:
            raise gout.StepLimit(f"stopped at step {run.sim.step_count} (--steps {stop}), after the preparation")
        self.clock.enter("open", run.sim.step_count)
        run.case, geo = biaxial.open_sample(run.comm, run.case, deck)
        cur["geo"] = geo
        progress.n_elements = geo["n_grains"]      # the rate counts the grains kept (and copied)
        progress.start(run.sim.step_count)          # and is measured afresh: a step's cost changed
        if biaxial.start_loading(run.case, deck, geo, None):
            self.record = biaxial.CementRecord(biaxial.intact_cements(run.sim))
        self.mem, *self.platens = biaxial.install(run.case, deck, cur["pc"], geo)
        cur["settle_start"] = run.sim.step_count
        progress.say(f"opened: {geo['n_grains']} of {geo['n_before']} grains kept, platens of "
                     f"{len(geo['bottom'])} and {len(geo['top'])} grains, membranes of "
                     f"{len(self.mem.chains['left'])} and {len(self.mem.chains['right'])} grains; "
                     f"friction {deck['material']['friction']}")

    def stage_settle(self, run, resume):
        """The settling steps with the platens at rest (to ``settle_start + loading.settle_steps``)."""
        cur = run.state["current"]
        self.clock.enter("settle", run.sim.step_count)
        biaxial.settle(run.case, run.deck, cur, run.operations, run.args.steps)
        cur["reference"] = biaxial.reference(run.case, self.mem, cur["geo"], run.deck)
        biaxial.set_moving(self.platens, run.deck, cur["geo"])

    def stage_load(self, run, resume):
        """The loading to ``loading.strain`` (samples, localisation windows), then the pressure's
        results."""
        deck, progress, cur, stop = run.deck, run.progress, run.state["current"], run.args.steps
        k, pc = cur["index"], cur["pc"]
        self.clock.enter("load", run.sim.step_count)
        total = biaxial.loading_steps(deck, run.sim.dt)
        progress.total = cur["reference"]["step"] + total
        progress.say(f"loading pc = {pc:.4g} Pa to eps_a = {deck['loading']['strain']} at "
                     f"{deck['loading']['strain_rate']} 1/s ({total} steps)")

        def on_row(row):
            run.series.append(row)
            progress.report(row["step"], f"pc {row['pc']:.3g}: eps_a = {row['eps_axial']:.4f}, q/pc = "
                                         f"{row['q'] / row['pc']:.4f}, eps_v = {row['eps_vol']:.3e}, "
                                         f"sigma_l/pc = {row['sigma_lateral'] / row['pc']:.4f}, "
                                         f"sliding {row['sliding_fraction']:.3f}")
        biaxial.load(run.case, deck, cur, self.mem, self.platens, on_row, run.operations, stop,
                     on_event=lambda step: self.event(run, step), record=self.record,
                     # set only by a stop checkpoint of an earlier version (its step's operations undone)
                     replay=resume and cur.pop("replay", False))
        rows = [r for r in run.series.rows if r["pressure_index"] == k]
        result = {"pc": pc, "preparation": cur["prep"], "sample": {kk: cur["geo"][kk] for kk in
                  ("n_grains", "n_before", "y_bottom", "y_top", "mean_radius")},
                  "platen_grains": [len(cur["geo"]["bottom"]), len(cur["geo"]["top"])],
                  **biaxial.angles(rows, deck["loading"]["residual_fraction"])}
        result["windows"] = [dict(w, predictions=shear_band.predictions(result["phi_peak_deg"],
                                                                        result["psi_max_deg"]))
                             for w in cur["windows"]]
        if self.record is not None:
            result["cements"] = self.cement_outputs(run, rows, result)
        self.clock.close(run.sim.step_count)
        progress.n_elements = deck["sample"]["n"]
        progress.start(run.sim.step_count)
        run.state["results"].append(result)
        progress.say(f"pc = {pc:.4g} Pa: phi_peak = {result['phi_peak_deg']:.2f} deg at eps_a = "
                     f"{result['strain_at_peak']:.4f}, phi_residual = {result['phi_residual_deg']:.2f} deg, "
                     f"psi_max = {result['psi_max_deg']:.2f} deg; from the platens and pc: phi_peak = "
                     f"{result['phi_peak_boundary_deg']:.2f} deg, phi_residual = "
                     f"{result['phi_residual_boundary_deg']:.2f} deg")
        for w in result["windows"]:
            progress.say(band_line(w))
        self.mem = self.platens = self.record = None

    def event(self, run, step):
        """A localisation window's start or end at ``step`` (collective)."""
        deck, cur = run.deck, run.state["current"]
        events = biaxial.event_steps(deck, run.sim.dt, cur["reference"]["step"])
        snap = None
        for w, (s0, s1) in enumerate(events):
            if step == s1 and w in self.pending:
                snap = snap or biaxial.snapshot(run.sim)
                ref = self.pending.pop(w)
                d_mean = 2.0 * cur["geo"]["mean_radius"]
                field = biaxial.window_field(ref, snap, cur["geo"]["bottom"] + cur["geo"]["top"], d_mean,
                                             deck["localisation"]["band_fraction"])
                eps = deck["localisation"]["strains"][w]
                band = field["band"]
                cur["windows"].append({"window": w, "strain_end": eps, "window_strain": deck["localisation"]["window"],
                                       "band": None if band is None else {k: band[k] for k in
                                                                          ("angle_deg", "width_d", "centre", "direction",
                                                                           "peak", "background", "contrast",
                                                                           "score", "null_score", "localised")},
                                       "mean_abs_spin": float(np.mean(np.abs(field["spin"]))),
                                       "cements_broken": int(field["cements_broken"].sum() // 2),
                                       "files": [f"localisation-{cur['index']}-{w}.png", f"localisation-{cur['index']}-{w}.vtu"]})
                radius = self._radii(run, snap["gid"])
                if run.comm.is_root:
                    base = os.path.join(run.out, f"localisation-{cur['index']}-{w}")
                    biaxial_plot.write_fields(base + ".vtu", field, snap["gid"], radius)
                    if deck["output"]["plot"]:
                        biaxial_plot.maps(base + ".png", field, radius,
                                          f"pc = {cur['pc']:.3g} Pa, eps_a {eps - deck['localisation']['window']:.3f}"
                                          f" -> {eps:.3f}")
        for w, (s0, s1) in enumerate(events):
            if step == s0:
                snap = snap or biaxial.snapshot(run.sim)
                self.pending[w] = snap

    def cement_outputs(self, run, rows, result):
        """The damage of a cemented loading (collective): ``biaxial.cement_damage``, the share of the
        broken cements in the last window's shear band against the band's share of all the cements
        (midpoints at the end of the loading; above 1: damage localised in the band), and on rank 0
        ``DIR/cements-P.png`` (``biaxial_plot.cement_map``) and ``DIR/cements-P.vtu``."""
        cur, deck, rec = run.state["current"], run.deck, self.record
        out = biaxial.cement_damage(rows, rec)
        snap = biaxial.snapshot(run.sim)
        gid, x = snap["gid"], snap["x"]
        radius = self._radii(run, gid)
        broken = np.searchsorted(gid, biaxial.key_pairs(rec.keys))            # rows [m, 2]
        every = np.searchsorted(gid, biaxial.key_pairs(rec.initial))
        band = next((w["band"] for w in reversed(result["windows"]) if w["band"] is not None
                     and w["band"].get("localised")), None)     # no band, no share in it
        if band is not None and len(rec.keys):
            d_mean = 2.0 * cur["geo"]["mean_radius"]
            in_broken = biaxial.band_share(0.5 * (x[broken[:, 0]] + x[broken[:, 1]]), band, d_mean)
            in_all = biaxial.band_share(0.5 * (x[every[:, 0]] + x[every[:, 1]]), band, d_mean)
            out.update(broken_in_band=in_broken, cements_in_band=in_all,
                       band_concentration=in_broken / in_all if in_all > 0 else None)
        k = cur["index"]
        out["files"] = [f"cements-{k}.png", f"cements-{k}.vtu"]
        if run.comm.is_root:
            base = os.path.join(run.out, f"cements-{k}")
            biaxial_plot.write_cement_fields(base + ".vtu", x, gid, radius, rec.per_grain(gid), snap["cements"],
                                             broken, rec.strain)
            if deck["output"]["plot"]:
                biaxial_plot.cement_map(base + ".png", x, radius, np.stack([x[broken[:, 0]], x[broken[:, 1]]], axis=1),
                                        rec.strain, f"pc = {cur['pc']:.3g} Pa: {len(rec.keys)} of {len(rec.initial)} "
                                        f"cements broken by eps_a = {rows[-1]['eps_axial']:.3f} (grains at the end)",
                                        band)
        run.progress.say(f"pc = {cur['pc']:.4g} Pa: {out['broken_at_end']} of {out['cements_at_start']} cements "
                         f"broken (fraction {out['broken_fraction_at_peak']:.3f} at the peak, "
                         f"{out['broken_fraction_at_end']:.3f} at the end)")
        return out

    @staticmethod
    def _radii(run, gids):
        """The radii of ``gids`` (collective; rank 0 gets them in that order)."""
        e, n = run.sim.elements, run.sim.elements.n_owned
        parts = run.comm.allgather((e.gid[:n].copy(), e.radius[:n].copy()))
        g = np.concatenate([p[0] for p in parts])
        r = np.concatenate([p[1] for p in parts])
        return r[np.argsort(g)][np.searchsorted(np.sort(g), gids)]

    def summary(self, run):
        clock = self.clock if self.clock is not None else gout.StageClock(run.state.get("clock"))
        geo = run.state["current"]["geo"] or (run.state["results"][-1]["sample"] if run.state["results"] else None)
        opened = geo["n_grains"] if geo is not None else run.deck["sample"]["n"]
        return {"pressures": run.state["results"], "n_elements": run.deck["sample"]["n"],
                # grains x steps / s: the preparation steps sample.n grains, the later stages the
                # grains kept in the (last) opened sample, replicated or not
                **clock.summary(run.sim.step_count, lambda k: run.deck["sample"]["n"] if k == "prepare" else opened),
                "conventions": {"stress": "Love-Weber stress of all contacts over the membrane polygon's area "
                                          "times the thickness t (the mean diameter); compression positive",
                                "eps_vol": "1 - A/A0, contraction positive", "eps_axial": "1 - H/H0",
                                "sin_phi": "q / (sigma_axial + sigma_lateral)",
                                "dilatancy": "sin psi = -d eps_v / (2 d eps_a - d eps_v), largest over the loading",
                                "band_angle": "from the x axis (the minor principal stress direction), degrees"},
                "series": ["biaxial.csv", "biaxial.h5"]}

    def finish(self, run, summary):
        if run.deck["output"]["plot"] and run.series.rows:
            biaxial_plot.curves(os.path.join(run.out, "biaxial.png"), run.series.rows)
        if run.stopped:
            print(f"{run.stopped}; continue with --restart "
                  f"{run.writer.written[-1] if run.writer.written else '(no checkpoint: checkpoint.at_end = false)'}",
                  flush=True)
        else:
            run.progress.say(f"done in {summary['wall_seconds']:.1f} s; outputs in {run.out}")
        return cli.EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
