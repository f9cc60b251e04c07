"""Calibration of the beam bonds from target domain properties (docs/physics.md section 6), with a check.

    python -m pardem.drivers.calibrate [--config targets.toml] [--set section.key=value ...]
                                       [--out DIR] [--verify] [--quick] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.calibrate --config drivers/calibrate_beech.toml --verify

From the targets deck (E_L^D, E_T^D, optionally E_R^D, G^D, density, strengths, densification
threshold; see ``pardem.protocols.calibration.CALIBRATE_SCHEMA`` or ``--help``) it computes the bond parameters
of the ordered lattice (``pardem.protocols.calibration.calibrate``) and writes ``DIR/compress_calibrated.toml``, a
deck for ``python -m pardem.drivers.compress --config``, and ``DIR/calibration.json`` (targets, bond
parameters, analytic predictions).

``--verify`` then measures the calibrated ordered domain: compressions along L (x) and T (z) (and R
(y) when E_R^D is a separate target), by the compression case of ``pardem.protocols.compression`` loaded over
``verify.transits`` axial wave transits (quasi-static slope modulus), and a simple-shear test of
``verify.shear_plane`` (``pardem.protocols.shear``). The runs are elastic (the strength thresholds are
left out) and use every rank (one run after the other). ``calibration.json`` gets, per quantity,
the target, the measured value and the relative error; the shear row also holds the beam-theory
prediction of the lattice (section 6's shear relation is twice the Euler-Bernoulli lattice value, see
``pardem.protocols.calibration``). ``--quick`` verifies on a cube of ``verify.quick_elements`` elements per edge
instead of the deck's domain (the written deck keeps the deck's domain).

Runtime (2-core development machine, 2 ranks): ``--quick --verify`` on the beech deck (8^3 elements)
about 2 s (up to 15 s when the cores are busy); ``--verify`` on the 10 mm cube
of 21^3 elements about 75 s.

Exit codes: 0 done, 1 unexpected error (all ranks stop), 2 bad input (one line naming the field or
option and its allowed values; nothing has run), 3 a verification run became unstable.
"""
import copy
import datetime
import json
import math
import os
import sys
import time

import pardem
from pardem.protocols import calibration as calib
from pardem.drivers.cli import EXIT_OK, EXIT_UNSTABLE, driver_parser, fail_usage, read_deck, run_driver
from pardem.protocols.compression import SeriesSampler, build_case, measure, with_plate_speed
from pardem.config import DeckError, check_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.io.summary import write_json
from pardem.parallel.communicator import Communicator
from pardem.engine.errors import DecompositionError
from pardem.protocols.shear import run_shear
from pardem.engine.errors import InstabilityError

DECK_NAME = "compress_calibrated.toml"
STRENGTH_KEYS = ("tensile_strength", "shear_strength", "densification_stress", "densification_p0")
ROUND_TRIP_TOLERANCE = 0.02     # E_L^D and E_T^D must come back within 2 %


def parser(comm=None):
    p = driver_parser("python -m pardem.drivers.calibrate", __doc__.split("\n\n")[0], calib.CALIBRATE_SCHEMA,
                      run_options=False, comm=comm)
    p.add_argument("--verify", action="store_true",
                   help="measure E_L^D, E_T^D (compressions) and G^D (simple shear) of the calibrated "
                        "ordered domain and report them against the targets")
    p.add_argument("--quick", action="store_true",
                   help="verify on a small cube (verify.quick_elements per edge) instead of the deck's domain")
    return p


def main(argv=None):
    comm = Communicator()
    return run_driver(comm, run, parser(comm).parse_args(argv))


def strengths_supported():
    """True when the compress deck knows the rupture and densification keys."""
    return all(k in COMPRESS_SCHEMA["bonds"] for k in STRENGTH_KEYS)


def calibrated_deck(deck):
    """(targets, calibration, raw compress deck, checked compress deck) of the checked targets deck;
    DeckError on unusable targets."""
    targets = calib.Targets.from_deck(deck)
    cal = calib.calibrate(targets)
    raw = calib.compress_deck(cal, deck, strengths_supported())
    return targets, cal, raw, check_deck(COMPRESS_SCHEMA, raw)


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


def compression_modulus(comm, raw, axis, strain, transits):
    """Quasi-static Young's modulus [Pa] of the compress deck ``raw`` along ``axis`` (collective):
    the plate speed makes the loading last ``transits`` axial wave transits. Returns the record."""
    raw = copy.deepcopy(raw)
    raw.setdefault("loading", {}).update(axis=axis, strain=strain)
    probe = build_case(comm, check_deck(COMPRESS_SCHEMA, raw))
    case = with_plate_speed(probe, strain * probe.constants.length / (transits * probe.constants.transit_time))
    sampler = SeriesSampler(case, max(1, case.n_steps // 200))
    sampler(case.sim)
    case.sim.run(case.n_steps, operations=[sampler])
    result = measure(case)
    return {"axis": axis, "young_modulus": result["young_modulus"],
            "young_modulus_secant": result["young_modulus_secant"],
            "analytic": case.constants.analytic_young, "steps": case.n_steps, "n_elements": case.constants.n_elements,
            "plate_speed": case.deck["loading"]["plate_speed"], "poisson_ratios": result["poisson_ratios"]}


def _row(target, measured, **extra):
    err = measured / target - 1.0 if target and math.isfinite(measured) else math.nan
    return {"target": target, "measured": measured, "relative_error": err, **extra}


def verify(comm, raw, deck, targets, cal, quick, say):
    """The verification runs and the report's ``verification`` dict (collective)."""
    v = deck["verify"]
    vraw = verification_raw(raw, deck, quick)
    plane = v["shear_plane"]
    pred = calib.predictions(cal, plane)
    axes = [("young_L", "x", targets.young_L), ("young_T", "z", targets.young_T)]
    if targets.young_R is not None:
        axes.insert(1, ("young_R", "y", targets.young_R))
    quantities, runs = {}, {}
    for name, axis, target in axes:
        t0 = time.perf_counter()
        rec = compression_modulus(comm, vraw, axis, v["strain"], v["transits"])
        rec["seconds"] = time.perf_counter() - t0
        runs[name] = rec
        quantities[name] = _row(target, rec["young_modulus"], analytic=pred[name])
        say(f"compression along {axis}: E = {rec['young_modulus']:.6g} Pa ({rec['n_elements']} elements, "
            f"{rec['steps']} steps, {rec['seconds']:.1f} s)")
    if v["shear"]:
        t0 = time.perf_counter()
        shear = run_shear(comm, check_deck(COMPRESS_SCHEMA, vraw), plane, v["shear_strain"], v["transits"],
                          shear_estimate=pred["shear_beam"])
        shear["seconds"] = time.perf_counter() - t0
        runs["shear"] = shear
        G = shear["shear_modulus"]
        quantities["shear"] = _row(targets.shear, G, plane=plane, section6=pred["shear_section6"],
                                   beam_theory=pred["shear_beam"],
                                   relative_error_beam=G / pred["shear_beam"] - 1.0)
        say(f"simple shear in {plane}: G = {G:.6g} Pa ({shear['n_elements']} elements, "
            f"{shear['steps']} steps, {shear['seconds']:.1f} s)")
    return {"domain": {"box": vraw["domain"]["box"], "radius": vraw["domain"]["radius"], "quick": quick},
            "strain": v["strain"], "shear_strain": v["shear_strain"], "transits": v["transits"],
            "quantities": quantities, "runs": runs,
            "round_trip_ok": all(abs(quantities[k]["relative_error"]) <= ROUND_TRIP_TOLERANCE
                                 for k, _, _ in axes),
            "round_trip_tolerance": ROUND_TRIP_TOLERANCE,
            "note": "shear: 'target' is G^D, which section 6's relation E r^4 = 16/(3 pi) G^D ascribes to the "
                    "calibrated bonds; 'beam_theory' is (3 pi / 32) E r^4 (harmonic mean over the plane's "
                    "two bond directions), the Euler-Bernoulli prediction for the face-bonded cubic lattice, "
                    "half of section 6's value. Nothing is tuned: the measurement is reported as is."}


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
    lines = [f"Compress deck calibrated by `python -m pardem.drivers.calibrate` (pardem {pardem.__version__})",
             f"from {config or 'the built-in targets'} (docs/physics.md section 6, ordered lattice):",
             f"  targets: E_L^D = {E[0]:.6g} Pa, E_R^D = {E[1]:.6g} Pa, E_T^D = {E[2]:.6g} Pa, "
             f"G^D = {targets.shear:.6g} Pa, rho_D = {targets.density:.6g} kg/m^3",
             f"  tensile strength^D (L, R, T) = {list(targets.tensile_strength)} Pa, shear strength^D = "
             f"{list(targets.shear_strength)} Pa,",
             f"  densification threshold^D (T) = {targets.densification_stress:.6g} Pa, "
             f"p0 = {targets.densification_p0:g}",
             "  r_k^2 = (4/3) G^D / E_k^D, E_k^mu = (4/pi) E_k^D / r_k^2, sigma^mu = 4 / (pi r_k^2) sigma^D,",
             "  element density = (6/pi) rho_D.",
             "Section 6's shear relation is twice the Euler-Bernoulli value of the lattice: this deck's ordered",
             f"domain has G^D = {calib.lattice_shear_modulus(cal.young, cal.radius_ratio, 'LT'):.6g} Pa "
             f"by beam theory (see calibration.json)."]
    if not strengths_supported():
        lines.append("NOTE: this pardem's compress deck has no rupture/densification keys: bond thresholds "
                     f"(L, R, T) tensile {list(cal.tensile_strength)} Pa, shear {list(cal.shear_strength)} Pa, "
                     f"densification {cal.densification_stress:.6g} Pa were left out.")
    return lines


def format_table(report):
    q = report["verification"]["quantities"]
    lines = [f"{'quantity':<10} {'target [Pa]':>13} {'measured [Pa]':>14} {'error':>9}"]
    for name, label in (("young_L", "E_L^D"), ("young_R", "E_R^D"), ("young_T", "E_T^D"), ("shear", "G^D")):
        if name in q:
            r = q[name]
            lines.append(f"{label:<10} {r['target']:13.5e} {r['measured']:14.5e} {100 * r['relative_error']:+8.2f} %")
    if "shear" in q:
        r = q["shear"]
        lines.append(f"{'G^D beam':<10} {r['beam_theory']:13.5e} {r['measured']:14.5e} "
                     f"{100 * r['relative_error_beam']:+8.2f} %   (Euler-Bernoulli lattice, plane {r['plane']}; "
                     f"section 6 predicts {r['section6']:.5e})")
    return "\n".join(lines)


def run(comm, args):
    t_start = time.perf_counter()
    deck = read_deck(comm, calib.CALIBRATE_SCHEMA, args)
    try:
        targets, cal, raw, _checked = calibrated_deck(deck)
        if args.verify:
            verification_raw(raw, deck, args.quick)     # refuse a domain too small before writing
    except DeckError as err:
        fail_usage(comm, str(err))
    out = args.out or os.path.join("runs", "calibrate-" + comm.bcast(
        datetime.datetime.now().strftime("%Y%m%d-%H%M%S")))
    say = (lambda text: print(text, flush=True)) if comm.is_root and not args.quiet else (lambda text: None)
    report = {"pardem_version": pardem.__version__, "driver": "calibrate", "n_ranks": comm.size,
              "targets": {**targets.__dict__, "young_R": targets.young()[1]}, "bonds": cal.as_dict(),
              "predicted": calib.predictions(cal, deck["verify"]["shear_plane"]),
              "deck": os.path.join(out, DECK_NAME), "strengths_in_deck": strengths_supported(),
              "targets_deck": deck}
    if comm.is_root:
        os.makedirs(out, exist_ok=True)
        with open(os.path.join(out, DECK_NAME), "w") as fh:
            fh.write(deck_text(raw, _header(targets, cal, deck, args.config)))
        b = cal
        print(f"pardem {pardem.__version__}: calibration (docs/physics.md section 6): E^mu (L, R, T) = "
              f"{', '.join(f'{x:.5g}' for x in b.young)} Pa, r (L, R, T) = "
              f"{', '.join(f'{x:.4g}' for x in b.radius_ratio)}, element density {b.element_density:.5g} kg/m^3; "
              f"wrote {os.path.join(out, DECK_NAME)}", flush=True)
        if not strengths_supported():
            print("warning: the compress deck of this pardem has no rupture/densification keys: the "
                  "thresholds are in calibration.json only", file=sys.stderr, flush=True)
    if args.verify:
        try:
            report["verification"] = verify(comm, raw, deck, targets, cal, args.quick, say)
        except (DeckError, DecompositionError) as err:
            fail_usage(comm, f"verification domain: {err}")
        except InstabilityError as err:
            if comm.is_root:
                sys.stderr.write(f"pardem: error: a verification run became unstable {err}\n")
            raise SystemExit(EXIT_UNSTABLE)
    report["wall_seconds"] = time.perf_counter() - t_start
    if comm.is_root:
        write_json(os.path.join(out, "calibration.json"), report)   # NaN -> null
        if args.verify:
            print(format_table(report), flush=True)
            ok = report["verification"]["round_trip_ok"]
            names = ", ".join(k.replace("young_", "E_") + "^D" for k in report["verification"]["quantities"]
                              if k.startswith("young_"))
            print(f"round trip {names} within {100 * ROUND_TRIP_TOLERANCE:g} %: {'yes' if ok else 'NO'}", flush=True)
        print(f"wrote {os.path.join(out, 'calibration.json')} in {report['wall_seconds']:.1f} s", flush=True)
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
