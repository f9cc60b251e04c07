"""Calibration of the beam bonds from target domain properties (docs/physics.md section 6), with a check.

    python -m pardem.drivers.calibrate [--config targets.toml] [--set section.key=value ...]
                                       [--out DIR] [--verify] [--quick] [--steps N] [--restart DIR] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.calibrate --config drivers/calibrate_beech.toml --verify

From the targets deck (E_L^D, E_T^D, optionally E_R^D, G^D, density, strengths, densification
threshold; see ``pardem.protocols.calibration.CALIBRATE_SCHEMA`` or ``--help``) it computes the bond
parameters of the ordered lattice by both shear relations (``bonds.relations`` chooses the one
written: ``exact``, the face-bonded lattice's, whose G is G^D, or ``section6``, W's, which reproduces
W's bond set and gives the lattice G^D / 2), and writes ``DIR/compress_calibrated.toml`` (a deck for
``python -m pardem.drivers.compress --config``) and ``DIR/calibration.json`` (targets, both bond sets
and their analytic predictions, the lattice's Poisson ratio 0).

``--verify`` then measures the calibrated ordered domain, one run after the other on every rank:
compressions along L (x), R (y) and T (z) (the compression case of ``pardem.protocols.compression``,
loaded over ``verify.transits`` axial wave transits: quasi-static slope modulus) and simple shear in the
LR, LT and RT planes (``pardem.protocols.shear``; ``verify.shear_plane`` may pick one). The runs are
elastic (strength thresholds left out). Per run: ``DIR/series/<run>.csv`` and ``.h5`` (columns with
units), ``DIR/paraview/<run>/pardem.pvd`` when ``output.vtk_every`` > 0, and its record in
``DIR/records/rank-0.jsonl`` (written as soon as the run ends). ``calibration.json`` gets, per modulus,
the target, the lattice's prediction, the measured value and both relative errors; ``calibration.png``
plots every run's stress against its strain with the target and predicted slopes. The verification
passes when every measured modulus is within ``verify.tolerance`` (2 %) of the lattice's prediction;
with ``exact`` relations that prediction is the target (``targets_met``), with ``section6`` the shear
moduli miss their target by -50 % (reported, expected). ``--quick`` verifies on a cube of
``verify.quick_elements`` elements per edge instead of the deck's domain (the written deck keeps the
deck's domain). ``--restart DIR`` continues a killed or stopped verification of DIR: the runs recorded
there are not run again (the deck and options must be the same); it writes into a new folder
(``--out``, default ``DIR-restart-<time>``), which receives every record.

Compact domains (``domain.kind = "compact"``): no closed form exists, so the bonds are calibrated by
measurement (``pardem.protocols.compact_calibration``): from the closed form times
``compact.start_factors``, Newton iterations on the logarithms of the bond moduli (L, R, T) and radii,
with the sensitivity matrix measured from the bonds' energy shares, until the mean over
``compact.realisations`` packings (seeds ``domain.seed + k``, a task farm over the ranks: realisation k
on rank k mod n, alone, so the result is the same for any number of ranks) of E_L, E_R, E_T
(compressions) and G in ``compact.shear_plane`` (simple shear) are all within ``compact.tolerance``
(2 %) of their targets. Writes ``DIR/calibration_history.json`` (after every iteration: bonds, mean and
per-realisation moduli, relative errors, sensitivity matrix, step), ``DIR/calibration_history.png``
(errors [%] and bond parameters against the iteration), ``DIR/calibration.json`` and
``DIR/compress_calibrated.toml`` (a compact compress deck with the last measured bonds). Exit code 6
when a target is still missed after ``compact.max_iterations`` measurements. ``--verify``, ``--quick``,
``--steps`` and ``--restart`` apply to ordered domains only. Runtime: about 10 s per realisation and
iteration for a cube of 18 radii (716 elements), 4 transits; 4-6 iterations from a far start.

Runtime (2-core development machine, 2 ranks): ``--quick --verify`` on the beech deck (8^3 elements,
6 runs) about 10 s; ``--verify`` on the 10 mm cube of 21^3 elements a few minutes.

Exit codes: those of ``pardem.drivers.cli`` (0 done and verified, 1 unexpected error, 2 bad input:
one line naming the field or option and its allowed values, nothing has run, 3 a verification run
became unstable, 4 the results could not be written, 5 a run too short to measure its modulus, e.g.
with ``--steps``), and 6 the verification failed (a modulus off its prediction by more than
``verify.tolerance``) or the compact calibration did not converge.
"""
import contextlib
import copy
import dataclasses
import json
import math
import os
import sys
import time

import pardem
from pardem.protocols import calibration as calib
from pardem.drivers import cli
from pardem.drivers.cli import (MAX_STEPS, EXIT_NOT_MEASURED, EXIT_OK, EXIT_UNSTABLE, driver_parser, fail_usage,
                                plain_json, study_restart)
from pardem.drivers.runner import StudyDriver, protocol_main
from pardem.protocols.compression import SeriesSampler, build_case, measure, with_plate_speed
from pardem.protocols import shear as shear_protocol
from pardem.config import DeckError, check_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.io.paraview import ParaViewWriter
from pardem.io.records import RecordLog, read_study_header, start_study_folder
from pardem.io.series import SeriesCSV, dict_row
from pardem.io.series_h5 import SeriesH5
from pardem.io.summary import write_json, write_text
from pardem.errors import DecompositionError
from pardem.errors import InstabilityError
from pardem.triggers import as_trigger

DECK_NAME = "compress_calibrated.toml"
STRENGTH_KEYS = ("tensile_strength", "shear_strength", "densification_stress", "densification_p0")
EXIT_VERIFY_FAILED = 6          # after pardem.drivers.cli's codes (0-5)


def parser(comm=None):
    p = driver_parser("python -m pardem.drivers.calibrate", __doc__.split("\n\n")[0], calib.CALIBRATE_SCHEMA,
                      run_options=False, comm=comm, out_default="runs/calibrate-<timestamp>",
                      epilog="exit code 6: the verification failed (a modulus off its prediction by more than "
                             "verify.tolerance)")
    p.add_argument("--verify", action="store_true",
                   help="measure E_L^D, E_R^D, E_T^D (compressions) and G^D in LR, LT, RT (simple shear) of the "
                        "calibrated ordered domain and report them against the targets")
    p.add_argument("--quick", action="store_true",
                   help="verify on a small cube (verify.quick_elements per edge) instead of the deck's domain")
    p.add_argument("--steps", type=int, metavar="N",
                   help="--verify: run each verification run for N steps only (smoke tests; a run too short "
                        "to measure its modulus ends with exit code 5)")
    p.add_argument("--restart", metavar="DIR",
                   help="continue the verification whose output is DIR: the runs recorded in DIR/records are "
                        "not run again; the same deck and options are required (the deck defaults to DIR's); "
                        "the results go to a new folder (--out, default DIR-restart-<time>) holding every record")
    return p


def main(argv=None):
    return protocol_main(Calibrate, parser, argv)


def strengths_supported():
    """True when the compress deck knows the rupture and densification keys."""
    return all(k in COMPRESS_SCHEMA["bonds"] for k in STRENGTH_KEYS)


def calibrated_deck(deck):
    """(targets, calibration, raw compress deck, checked compress deck) of the checked targets deck,
    by its ``bonds.relations``; DeckError on unusable targets."""
    targets = calib.Targets.from_deck(deck)
    cal = calib.calibrate(targets, deck["bonds"]["relations"])
    raw = calib.compress_deck(cal, deck, strengths_supported())
    return targets, cal, raw, check_deck(COMPRESS_SCHEMA, raw)


def both_calibrations(targets):
    """{relations: {"bonds": ..., "predicted": ...}} for every shear relation whose bonds exist (a
    relation that would need r > R_MAX gets its one-line reason instead)."""
    out = {}
    for rel in calib.RELATIONS:
        try:
            cal = calib.calibrate(targets, rel)
        except DeckError as err:
            out[rel] = {"refused": str(err)}
            continue
        out[rel] = {"bonds": cal.as_dict(), "predicted": calib.predictions(cal)}
    return out


MIN_EDGE_ELEMENTS = 4     # the strain fits need free elements in 3 dimensions in every test


def verification_raw(raw, deck, quick):
    """The raw compress deck of the verification runs: elastic (no thresholds), quick box if asked.

    DeckError when the domain has fewer than MIN_EDGE_ELEMENTS elements along an edge."""
    v = copy.deepcopy(raw)
    R = deck["domain"]["radius"]
    if quick:
        v["domain"]["box"] = [2.0 * R * deck["verify"]["quick_elements"]] * 3
    else:
        counts = [math.floor((x - 1.98 * R) / (2.0 * R)) + 1 for x in v["domain"]["box"]]   # as the lattice
        if min(counts) < MIN_EDGE_ELEMENTS:
            raise DeckError(f"domain.box = {list(v['domain']['box'])} with domain.radius = {R} holds {counts} "
                            f"elements per edge: --verify expects at least {MIN_EDGE_ELEMENTS} along every "
                            f"axis (box edges >= {2 * MIN_EDGE_ELEMENTS * R:.6g} m)")
    for k in ("tensile_strength", "shear_strength", "densification_stress"):
        if k in v["bonds"]:
            v["bonds"][k] = 0.0
    return v


def verification_runs(deck):
    """The verification runs in order: (name, kind, direction), kind "compression" (direction L, R,
    T) or "shear" (plane LR, LT, RT)."""
    runs = [(f"compression_{k}", "compression", k) for k in "LRT"]
    v = deck["verify"]
    if v["shear"]:
        planes = tuple(calib.SHEAR_PLANES) if v["shear_plane"] == "all" else (v["shear_plane"],)
        runs += [(f"shear_{p}", "shear", p) for p in planes]
    return runs


COMPRESSION_COLUMNS = ("step", "time", "plate_displacement", "force_fixed", "force_moving",
                       "eps_xx", "eps_yy", "eps_zz", "eps_xy", "eps_xz", "eps_yz",
                       "bonds_broken", "bonds_broken_step", "bonds_yielded")


@contextlib.contextmanager
def _run_outputs(comm, out, name, kind, vtk_every):
    """(sinks, operations) of one verification run: its series CSV and HDF5 (rank 0) and its ParaView
    writer (every rank) when ``vtk_every``; the files are closed on exit."""
    sinks, ops = [], []
    with contextlib.ExitStack() as files:
        if comm.is_root:
            folder = os.path.join(out, "series")
            os.makedirs(folder, exist_ok=True)
            if kind == "shear":
                cols, units = shear_protocol.SERIES_COLUMNS, shear_protocol.SERIES_UNITS
                csv = SeriesCSV(os.path.join(folder, f"{name}.csv"), cols, dict_row(cols), units=units)
                h5 = SeriesH5(os.path.join(folder, f"{name}.h5"), columns=cols, units=units, row=dict_row(cols),
                              description=shear_protocol.SERIES_DESCRIPTION, int_columns=("step",))
            else:
                csv = SeriesCSV(os.path.join(folder, f"{name}.csv"))
                h5 = SeriesH5(os.path.join(folder, f"{name}.h5"))
            files.callback(csv.close)
            files.callback(h5.close)
            sinks += [csv.append, h5.append]
        if vtk_every:
            ops.append(_LazyParaView(os.path.join(out, "paraview", name), comm, vtk_every))
        yield sinks, ops


def compression_run(comm, raw, axis, strain, transits, out, name, output, steps=None):
    """Quasi-static compression of the compress deck ``raw`` along ``axis`` (collective): the plate
    speed makes the loading last ``transits`` axial wave transits. Returns the run's record."""
    raw = copy.deepcopy(raw)
    raw.setdefault("loading", {}).update(axis=axis, strain=strain)
    probe = build_case(comm, check_deck(COMPRESS_SCHEMA, raw))
    case = with_plate_speed(probe, strain * probe.constants.length / (transits * probe.constants.transit_time))
    if steps is not None:
        case = dataclasses.replace(case, n_steps=int(steps))
    every = output["series_every"] or max(1, case.n_steps // 200)
    with _run_outputs(comm, out, name, "compression", output["vtk_every"]) as (sinks, ops):
        sampler = SeriesSampler(case, every, sinks)
        sampler(case.sim)
        for op in ops:
            op(case.sim)
        case.sim.run(case.n_steps, operations=[sampler, *ops])
    result = measure(case)
    a = case.constants.axis
    curve = {"strain": [float(-s["eps"][a, a]) for s in case.samples],
             "stress": [float(0.5 * (s["force_fixed"] + s["force_moving"]) / case.constants.cross_section)
                        for s in case.samples]}
    return {"modulus": result["young_modulus"], "modulus_secant": result["young_modulus_secant"],
            "axis": axis, "steps": case.n_steps, "n_elements": case.constants.n_elements,
            "plate_speed": case.deck["loading"]["plate_speed"], "poisson_ratios": result["poisson_ratios"],
            "samples_after_ramp": result.get("samples_after_ramp"), "curve": curve}


def shear_run(comm, raw, plane, strain, transits, out, name, output, estimate, steps=None):
    """Simple shear of ``plane`` (collective); the run's record."""
    deck = check_deck(COMPRESS_SCHEMA, raw)
    with _run_outputs(comm, out, name, "shear", output["vtk_every"]) as (sinks, ops):
        r = shear_protocol.run_shear(comm, deck, plane, strain, transits, shear_estimate=estimate, sinks=sinks,
                                     operations=ops, every=output["series_every"] or None, steps=steps)
    return {"modulus": r["shear_modulus"], "modulus_secant": r["shear_modulus_secant"], "plane": plane,
            "steps": r["steps"], "n_elements": r["n_elements"], "n_driven": r["n_driven"], "gamma": r["gamma"],
            "element_rotation": r["element_rotation"], "samples_after_ramp": r["samples_after_ramp"],
            "curve": {"strain": r["curve"]["gamma"], "stress": r["curve"]["stress"]}}


class _LazyParaView:
    """A ParaView writer made at its first call (collective), when the run's time step is known:
    every ``trigger`` steps and after the run's last step (each run is one ``sim.run``)."""
    at_end = True

    def __init__(self, directory, comm, trigger):
        self.directory, self.comm, self.trigger, self._w = directory, comm, as_trigger(trigger), None

    def __call__(self, sim):
        if self._w is None:
            self._w = ParaViewWriter(self.directory, self.comm, self.trigger, dt=sim.dt, at_end=True)
        self._w(sim)


def _row(name, kind, direction, target, predicted, measured, tolerance):
    def err(ref):
        return measured / ref - 1.0 if ref and math.isfinite(measured) else math.nan
    e_t, e_p = err(target), err(predicted)
    return {"run": name, "kind": kind, "direction": direction, "target": target, "predicted": predicted,
            "measured": measured, "relative_error": e_t, "relative_error_predicted": e_p,
            "ok": bool(math.isfinite(e_p) and abs(e_p) <= tolerance),
            "target_met": bool(math.isfinite(e_t) and abs(e_t) <= tolerance)}


def verify(comm, raw, deck, targets, cal, quick, say, out, finished=None, on_record=None, steps=None):
    """The verification runs and the report's ``verification`` dict (collective). ``finished``: the
    records of runs done before (a restart), by run name; ``on_record(record)`` after each run."""
    v, output = deck["verify"], deck["output"]
    finished = finished or {}
    vraw = verification_raw(raw, deck, quick)
    pred = calib.predictions(cal)
    E_target = dict(zip("LRT", targets.young()))
    rows, records = {}, {}
    for name, kind, d in verification_runs(deck):
        if name in finished:
            rec = finished[name]
            say(f"{name}: recorded before, not run again")
        else:
            t0 = time.perf_counter()
            if kind == "compression":
                rec = compression_run(comm, vraw, calib.AXES[d], v["strain"], v["transits"], out, name, output,
                                      steps)
            else:
                rec = shear_run(comm, vraw, d, v["shear_strain"],
                                v["transits"], out, name, output, pred[f"shear_{d}"], steps)
            rec.update(name=name, kind=kind, direction=d, seconds=time.perf_counter() - t0)
            if on_record is not None:
                on_record(rec)
            say(f"{name}: {'E' if kind == 'compression' else 'G'} = {rec['modulus']:.6g} Pa "
                f"({rec['n_elements']} elements, {rec['steps']} steps, {rec['seconds']:.1f} s)")
        records[name] = rec
        if kind == "compression":
            rows[name] = _row(name, kind, d, E_target[d], pred[f"young_{d}"], rec["modulus"], v["tolerance"])
            rows[name]["poisson_ratios"] = rec["poisson_ratios"]
        else:
            rows[name] = _row(name, kind, d, targets.shear, pred[f"shear_{d}"], rec["modulus"], v["tolerance"])
            rows[name]["section6"] = pred[f"shear_{d}_section6"]
    measured = all(math.isfinite(r["measured"]) for r in rows.values())
    return {"domain": {"box": vraw["domain"]["box"], "radius": vraw["domain"]["radius"], "quick": quick},
            "relations": deck["bonds"]["relations"],
            "strain": v["strain"], "shear_strain": v["shear_strain"], "transits": v["transits"],
            "tolerance": v["tolerance"], "quantities": rows, "runs": records, "measured": measured,
            "verification_ok": measured and all(r["ok"] for r in rows.values()),
            "targets_met": measured and all(r["target_met"] for r in rows.values()),
            "note": "predicted: the face-bonded lattice's moduli of the calibrated bonds (E = pi/4 E r^2, G_ab = "
                    "(3 pi / 32) 2 x y / (x + y), x = E r^4); relative_error is against the target, "
                    "relative_error_predicted against the prediction; 'section6' is the shear modulus W's "
                    "rotation-blocked relation ascribes to the same bonds (twice the lattice's). With "
                    "relations = exact the predictions are the targets; with section6 the lattice's G is "
                    "G^D / 2 (relative_error -0.5). Nothing is tuned: the measurements are reported as they are. "
                    + calib.POISSON_NOTE}


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def deck_text(raw, header):
    """TOML text of a raw compress deck, each key commented with its schema description."""
    lines = [f"# {h}" if h else "#" for h in header]
    for section, table in raw.items():
        lines += ["", f"[{section}]"]
        for key, value in table.items():
            doc = COMPRESS_SCHEMA[section][key].doc
            lines.append(f"{key} = {_toml_value(value)}    # {doc}")
    return "\n".join(lines) + "\n"


def _header(targets, cal, deck, config):
    E = targets.young()
    rel = deck["bonds"]["relations"]
    c = "8/3" if rel == "exact" else "4/3"
    G = [calib.lattice_shear_modulus(cal.young, cal.radius_ratio, p) for p in calib.SHEAR_PLANES]
    lines = [f"Compress deck calibrated by `python -m pardem.drivers.calibrate` (pardem {pardem.__version__})",
             f"from {config or 'the built-in targets'} (docs/physics.md section 6, ordered lattice, "
             f"bonds.relations = {rel}):",
             f"  targets: E_L^D = {E[0]:.6g} Pa, E_R^D = {E[1]:.6g} Pa, E_T^D = {E[2]:.6g} Pa, "
             f"G^D = {targets.shear:.6g} Pa, rho_D = {targets.density:.6g} kg/m^3",
             f"  tensile strength^D (L, R, T) = {list(targets.tensile_strength)} Pa, shear strength^D = "
             f"{list(targets.shear_strength)} Pa,",
             f"  densification threshold^D (T) = {targets.densification_stress:.6g} Pa, "
             f"p0 = {targets.densification_p0:g}",
             f"  r_k^2 = ({c}) G^D / E_k^D, E_k^mu = (4/pi) E_k^D / r_k^2, sigma^mu = 4 / (pi r_k^2) sigma^D,",
             "  element density = (6/pi) rho_D.",
             f"The lattice of these bonds has G_LR, G_LT, G_RT = {', '.join(f'{g:.6g}' for g in G)} Pa "
             + ("(= G^D: the lattice's own relation)" if rel == "exact" else
                "(G^D / 2: W's relation blocks the element rotations, the lattice's elements turn freely)") + ",",
             f"and Poisson ratio {calib.LATTICE_POISSON:g} (see calibration.json)."]
    if not strengths_supported():
        lines.append("NOTE: this pardem's compress deck has no rupture/densification keys: bond thresholds "
                     f"(L, R, T) tensile {list(cal.tensile_strength)} Pa, shear {list(cal.shear_strength)} Pa, "
                     f"densification {cal.densification_stress:.6g} Pa were left out.")
    return lines


def format_table(report):
    v = report["verification"]
    lines = [f"{'run':<15} {'target [Pa]':>13} {'lattice [Pa]':>13} {'measured [Pa]':>14} {'vs target':>10} "
             f"{'vs lattice':>10}"]
    for name, r in v["quantities"].items():
        lines.append(f"{name:<15} {r['target']:13.5e} {r['predicted']:13.5e} {r['measured']:14.5e} "
                     f"{100 * r['relative_error']:+9.2f} % {100 * r['relative_error_predicted']:+9.2f} %")
    return "\n".join(lines)


class Calibrate(StudyDriver):
    """The calibration: the closed form of an ordered lattice (and its verification runs, one
    after the other on every rank), or a compact domain's calibration by measurement (a task farm
    of realisations per iteration); summary ``calibration.json``."""
    name = "calibrate"
    schema = calib.CALIBRATE_SCHEMA
    summary_name = "calibration.json"
    common_key = None

    def inspect(self, run):
        """The header of the calibration being continued (its deck is the base), or {}."""
        comm = run.comm
        return comm.bcast(read_study_header(run.args.restart) if comm.is_root else None) or {}

    def base_deck(self, run):
        return None if run.args.config else run.meta.get("deck")

    def read_deck(self, run):
        """The targets deck; on ``--restart DIR``, the verification runs recorded there (the same
        deck and options required)."""
        comm, args = run.comm, run.args
        deck = cli.read_deck(comm, calib.CALIBRATE_SCHEMA, args,
                             base=self.base_deck(run) if run.meta is not None else None,
                             check=lambda deck: self.check(args, deck))
        self.header = plain_json({"driver": "calibrate", "deck": deck,
                                  "options": {"verify": args.verify, "quick": args.quick, "steps": args.steps}})
        self.finished = {}
        if args.restart:      # the runs done there, by name
            self.finished = {r["name"]: r for r in study_restart(comm, args.restart, self.header, "a calibration",
                                                                 parts=("deck", "options"), driver="calibrate")
                             if "name" in r}
        return deck

    def check(self, args, deck):
        """DeckError on options the deck's domain does not take, unusable targets, or a
        verification domain too small; keeps the calibration of an ordered domain."""
        self.compact = deck["domain"]["kind"] == "compact"
        if self.compact:
            used = [o for o, v in (("--verify", args.verify), ("--quick", args.quick), ("--steps", args.steps is not None),
                                   ("--restart", args.restart)) if v]
            if used:
                raise DeckError(f"{used[0]} applies to domain.kind = \"ordered\": a compact calibration "
                                f"measures its domain at every iteration (section [compact])")
            calib.calibrate(calib.Targets.from_deck(deck), deck["bonds"]["relations"])   # the start exists
            return
        if args.steps is not None and not 1 <= args.steps <= MAX_STEPS:
            raise DeckError(f"--steps {args.steps}: expected an integer from 1 to {MAX_STEPS:.0e}")
        if (args.steps is not None or args.restart) and not args.verify:
            raise DeckError("--steps and --restart apply to --verify: add --verify")
        self.targets, self.cal, self.raw, _checked = calibrated_deck(deck)
        if args.verify:
            verification_raw(self.raw, deck, args.quick)     # refuse a domain too small before writing

    def build(self, run):
        if self.compact:
            from pardem.protocols import compact_calibration as cc
            self.plan = cc.make_plan(run.deck)
            return self.plan
        return self.cal

    def start(self, run):
        comm, args, out = run.comm, run.args, run.out
        self.say = ((lambda text: print(text, flush=True)) if comm.is_root and not args.quiet
                    else (lambda text: None))
        if self.compact:
            return self.start_compact(run)
        deck, targets, cal = run.deck, self.targets, self.cal
        self.report = {
            "pardem_version": pardem.__version__, "driver": "calibrate", "n_ranks": comm.size,
            "targets": {**targets.__dict__, "young_R": targets.young()[1]},
            "relations": deck["bonds"]["relations"], "bonds": cal.as_dict(),
            "predicted": calib.predictions(cal), "calibrations": both_calibrations(targets),
            "poisson_ratio": calib.LATTICE_POISSON, "poisson_note": calib.POISSON_NOTE,
            "deck": os.path.join(out, DECK_NAME), "strengths_in_deck": strengths_supported(),
            "targets_deck": deck, "restarted_from": args.restart, "runs_reused": sorted(self.finished)}
        if comm.is_root:
            if args.verify:
                start_study_folder(out, self.header, self.finished)
            write_text(os.path.join(out, DECK_NAME), deck_text(self.raw, _header(targets, cal, deck, args.config)))
            b = cal
            print(f"pardem {pardem.__version__}: calibration (docs/physics.md section 6, relations "
                  f"{deck['bonds']['relations']}): E^mu (L, R, T) = "
                  f"{', '.join(f'{x:.5g}' for x in b.young)} Pa, r (L, R, T) = "
                  f"{', '.join(f'{x:.4g}' for x in b.radius_ratio)}, element density {b.element_density:.5g} kg/m^3; "
                  f"lattice Poisson ratio {calib.LATTICE_POISSON:g}; wrote {os.path.join(out, DECK_NAME)}", flush=True)
            if not strengths_supported():
                print("warning: the compress deck of this pardem has no rupture/densification keys: the "
                      "thresholds are in calibration.json only", file=sys.stderr, flush=True)
        comm.barrier()

    def execute(self, run):
        comm, args, out = run.comm, run.args, run.out
        if self.compact:
            return self.execute_compact(run)
        if args.verify:
            log = RecordLog(out, 0) if comm.is_root else None
            with _measurement_failures(comm, "verification domain", "a verification run"):
                self.report["verification"] = verify(comm, self.raw, run.deck, self.targets, self.cal, args.quick,
                                                     self.say, out, self.finished, log.append if log else None,
                                                     args.steps)

    def summary(self, run):
        if self.compact:
            return self.summary_compact(run)
        self.report["wall_seconds"] = time.perf_counter() - run.t_start
        return self.report

    def finish(self, run, summary):
        if self.compact:
            return self.finish_compact(run, summary)
        args, out, report, deck = run.args, run.out, summary, run.deck
        written = ["calibration.json", DECK_NAME]
        code = EXIT_OK
        if args.verify:
            v = report["verification"]
            print(format_table(report), flush=True)
            if _plot(report, os.path.join(out, "calibration.png")):
                written.append("calibration.png")
            tol = 100 * v["tolerance"]
            if not v["measured"]:
                bad = [k for k, r in v["quantities"].items() if not math.isfinite(r["measured"])]
                sys.stderr.write(f"pardem: error: run(s) {', '.join(bad)} too short to measure a modulus (fewer "
                                 f"than 3 samples after the ramp): drop --steps or raise it; wrote "
                                 f"{os.path.join(out, 'calibration.json')}\n")
                code = EXIT_NOT_MEASURED
            else:
                print(f"verification (every modulus within {tol:g} % of the lattice's prediction): "
                      f"{'yes' if v['verification_ok'] else 'NO'}; targets met within {tol:g} %: "
                      f"{'yes' if v['targets_met'] else 'no'}"
                      + ("" if v["targets_met"] or deck["bonds"]["relations"] != "section6" else
                         " (section6: the lattice's G is G^D / 2, use bonds.relations = \"exact\")"), flush=True)
                code = EXIT_OK if v["verification_ok"] else EXIT_VERIFY_FAILED
        print(f"wrote {', '.join(os.path.join(out, w) for w in written)} in {report['wall_seconds']:.1f} s",
              flush=True)
        return code

    # the compact-domain calibration by measurement (pardem.protocols.compact_calibration): writes
    # DIR/calibration_history.json after every iteration, then DIR/calibration.json,
    # DIR/compress_calibrated.toml (the last measured bonds) and DIR/calibration_history.png; exit
    # code 6 when a target is still missed after compact.max_iterations measurements

    def start_compact(self, run):
        comm, out, plan = run.comm, run.out, self.plan
        self.history = []
        self.hist_path = os.path.join(out, HISTORY_NAME)
        if comm.is_root:
            print(f"pardem {pardem.__version__}: compact-domain calibration by measurement: targets "
                  + ", ".join(f"{n} = {v:.5g} Pa" for n, v in zip(plan.targets, plan.values))
                  + f"; {len(plan.seeds)} realisation(s) (seeds {plan.seeds[0]}..{plan.seeds[-1]}) on {comm.size} "
                    f"rank(s); output {out}", flush=True)

    def execute_compact(self, run):
        from pardem.protocols import compact_calibration as cc
        comm, plan = run.comm, self.plan

        def on_iteration(entry):
            self.history.append(entry)
            if comm.is_root:
                write_json(self.hist_path, {"targets": dict(zip(plan.targets, plan.values)), "history": self.history})
        with _measurement_failures(comm, "compact calibration", "a calibration run"):
            self.result = cc.calibrate_compact(comm, run.deck, self.say, on_iteration)

    def summary_compact(self, run):
        result, deck = self.result, run.deck
        return {"pardem_version": pardem.__version__, "driver": "calibrate", "n_ranks": run.comm.size,
                "kind": "compact", "targets": result["targets"], "relations_of_start": deck["bonds"]["relations"],
                "compact": result, "deck": os.path.join(run.out, DECK_NAME), "targets_deck": deck,
                "wall_seconds": time.perf_counter() - run.t_start,
                "note": "bonds: the last measured set (the calibrated one when converged); measured: the mean over "
                        "the realisations of the quasi-static slope moduli of each test; the sensitivity matrix "
                        "rows are d ln M / d ln (E_L^mu, E_R^mu, E_T^mu, radii) from the bonds' energy shares "
                        "(pardem.protocols.compact_calibration)"}

    def finish_compact(self, run, report):
        from pardem.protocols import compact_calibration as cc
        args, out, result, hist_path = run.args, run.out, self.result, self.hist_path
        b = result["bonds"]
        raw = cc.compress_raw(run.deck, b["young"], b["radius_ratio"])
        write_json(hist_path, {"targets": result["targets"], "history": result["history"]})
        header = [f"Compress deck of a compact domain calibrated by measurement (`python -m pardem.drivers.calibrate`, "
                  f"pardem {pardem.__version__})",
                  f"from {args.config or 'the built-in targets'}: " + ", ".join(
                      f"{n} = {v:.6g} Pa" for n, v in result["targets"].items()),
                  f"mean over seeds {result['seeds']} (domain.seed selects one of them): " + ", ".join(
                      f"{n} {100 * e:+.2f} %" for n, e in result["relative_error"].items()),
                  f"{'converged' if result['converged'] else 'NOT converged'} after {result['iterations']} "
                  f"measurement(s) (tolerance {100 * result['tolerance']:g} %); see {CALIBRATION_JSON}."]
        write_text(os.path.join(out, DECK_NAME), deck_text(raw, header))
        written = [CALIBRATION_JSON, HISTORY_NAME, DECK_NAME]
        try:
            from pardem.io.calibration_plot import plot_compact_history
            plot_compact_history(result, os.path.join(out, HISTORY_PLOT))
            written.append(HISTORY_PLOT)
        except ImportError:
            sys.stderr.write("pardem: note: matplotlib is not installed, so no calibration_history.png "
                             "(pip install 'pardem[plot]')\n")
        tol = 100 * result["tolerance"]
        if result["converged"]:
            print(f"calibrated: every mean modulus within {tol:g} % of its target after {result['iterations']} "
                  f"measurement(s): E^mu (L, R, T) = {', '.join(f'{x:.6g}' for x in b['young'])} Pa, r (L, R, T) = "
                  f"{', '.join(f'{x:.5g}' for x in b['radius_ratio'])}", flush=True)
        else:
            missed = [n for n, e in result["relative_error"].items() if not abs(e) <= result["tolerance"]]
            sys.stderr.write(f"pardem: error: the compact calibration did not converge in {result['iterations']} "
                             f"measurement(s): {', '.join(missed)} still off by more than {tol:g} % (see "
                             f"{hist_path}; a shear target far from G ~ E / 2 may be out of reach of a compact "
                             f"bond network)\n")
        print(f"wrote {', '.join(os.path.join(out, w) for w in written)} in {report['wall_seconds']:.1f} s",
              flush=True)
        return EXIT_OK if result["converged"] else EXIT_VERIFY_FAILED


@contextlib.contextmanager
def _measurement_failures(comm, context, run_name):
    """Around the measurement runs (collective): a domain they cannot build ends with one line
    ``<context>: <reason>`` and exit 2, an unstable run with one line naming ``run_name`` and exit 3."""
    try:
        yield
    except (DeckError, DecompositionError) as err:
        fail_usage(comm, f"{context}: {err}")
    except InstabilityError as err:
        if comm.is_root:
            sys.stderr.write(f"pardem: error: {run_name} became unstable {err}\n")
        raise SystemExit(EXIT_UNSTABLE)


HISTORY_NAME = "calibration_history.json"
HISTORY_PLOT = "calibration_history.png"


CALIBRATION_JSON = "calibration.json"


def _plot(report, path):
    """calibration.png (True), or a note on stderr without matplotlib (False)."""
    from pardem.io.anisotropy_plot import plot_calibration
    try:
        plot_calibration(report["verification"], path)
    except ImportError:
        sys.stderr.write("pardem: note: matplotlib is not installed, so no calibration.png "
                         "(pip install 'pardem[plot]')\n")
        return False
    return True


if __name__ == "__main__":
    sys.exit(main())
