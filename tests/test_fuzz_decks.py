"""Property-based fuzzing of every driver's deck (issue 16, items 6 and 7).

For each driver (compress, isotropic, triaxial, calibrate, anisotropy, mixture, response, biaxial)
decks are generated from its schema: defaults, the bounds of every numeric key and their
neighbours, choice values, and wild values (0, negatives, 1e-300, 1e308, 5e-324, NaN, inf, huge
integers, wrong types, empty lists, strings). Loading a deck must either succeed or raise
``DeckError`` with a one-line message naming a deck key; no other exception. The slow part runs
the drivers on a few generated decks in a subprocess with ``--steps 3`` (or their smallest run)
and a timeout: no traceback, no hang, an exit code of the documented set. The issue's "accepted
nonsense" inputs are explicit cases.
"""
import copy
import math
import os
import subprocess
import sys
import threading

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from pardem.config import DeckError, Schema, check_deck
from pardem.io.deck_file import load_deck
from pardem.protocols import anisotropy_study as study
from pardem.protocols import biaxial
from pardem.protocols import calibration as calib
from pardem.protocols import deck_checks
from pardem.protocols import direct_shear
from pardem.protocols import isotropic as iso
from pardem.protocols import response
from pardem.protocols import triaxial
from pardem.protocols.compression_deck import COMPRESS_SCHEMA

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DRIVERS_DIR = os.path.join(ROOT, "drivers")
EXIT_CODES = {0, 2, 3, 4, 5, 6}   # ok, bad input, unstable, output error, too short to measure, calibration missed

# The calibrate deck's checks live in deck_checks (calibration.py registers them, or the test
# passes them): either way they run here.
CALIBRATE_CHECKS = () if deck_checks.calibrate_checks in getattr(calib.CALIBRATE_SCHEMA, "checks", ()) \
    else deck_checks.CALIBRATE_CHECKS

def _toml(path):
    import tomllib
    with open(path, "rb") as fh:
        return tomllib.load(fh)


# driver -> (schema, base raw deck, extra checks): the decks of all 8 drivers
DRIVERS = {
    "compress": (COMPRESS_SCHEMA, {}, ()),
    "isotropic": (iso.SCHEMA, {}, ()),
    "triaxial": (triaxial.SCHEMA, {}, ()),
    "calibrate": (calib.CALIBRATE_SCHEMA, {}, CALIBRATE_CHECKS),
    "anisotropy": (COMPRESS_SCHEMA, study.STUDY_DECK, ()),
    "mixture": (iso.SCHEMA, _toml(os.path.join(DRIVERS_DIR, "mixture_study.toml")), ()),
    "response": (response.SCHEMA, {}, ()),
    "biaxial": (biaxial.SCHEMA, {}, ()),
}

WILD = [0, -1, 1, 0.0, -0.0, -1.5, 1e-300, -1e-300, 1e308, -1e308, 5e-324, math.nan, math.inf, -math.inf,
        2**63, 10**30, -(2**70), True, False, "", "x", "auto", "same", "nan", "NaN", "inf", "-inf", "1e999",
        [], [0], [1, 2],
        [1e308, 1e308, 1e308], [5e-324, 1.0, 1.0], [math.nan, 1.0, 1.0], [0.0, 0.0, 0.0], [-1.0, 1.0, 1.0],
        ["a", "b", "c"], {"a": 1}]


def _inner_bounds(check):
    """(lo, hi, lo_open, hi_open, integer) of the number checker inside ``check``, or None."""
    while check is not None:
        if hasattr(check, "bounds"):
            return check.bounds
        check = getattr(check, "inner", None)
    return None


def _options(check):
    while check is not None:
        if hasattr(check, "options"):
            return check.options or ()     # None: a checker with no word to list (response's times)
        check = getattr(check, "inner", None)
    return ()


def boundary_values(field):
    """The default, the bounds of its number checker and their neighbours, the choice values."""
    vals = [field.default]
    b = _inner_bounds(field.check)
    if b is not None:
        lo, hi, _, _, integer = b
        for edge in (lo, hi):
            if edge is None:
                continue
            if integer:
                vals += [int(edge) - 1, int(edge), int(edge) + 1]
            else:
                vals += [float(edge), math.nextafter(float(edge), math.inf), math.nextafter(float(edge), -math.inf)]
        if lo is not None and hi is not None:
            vals.append((lo + hi) // 2 if integer else 0.5 * (lo + hi))
    for o in _options(field.check):
        vals += [o, o.upper() if isinstance(o, str) else o]
    if isinstance(field.default, list) and field.default:
        d = list(field.default)
        vals += [d[:-1], d + d[-1:], [d[0]] * 3]
        if b is not None and b[0] is not None:
            vals.append([b[0]] * len(d))
    return vals


def _scaled(default):
    """The default times 10^k, k in [-320, 320] (0 and inf at the ends): every magnitude."""
    nums = [x for x in (default if isinstance(default, list) else [default])
            if isinstance(x, (int, float)) and not isinstance(x, bool)]
    if not nums:
        return st.nothing()
    return st.tuples(st.sampled_from(nums), st.integers(-320, 320)).map(lambda t: t[0] * float(f"1e{t[1]}"))


def values_for(field):
    """Strategy: mostly boundary values and the default at every magnitude (so that the
    cross-field checks see decks whose fields pass), then wild values, any float (NaN and inf
    included), huge integers, text, lists of those."""
    boundary = st.sampled_from(boundary_values(field))
    scaled = _scaled(field.default)
    scalars = st.one_of(boundary, boundary, scaled, scaled, st.sampled_from(WILD),
                        st.floats(allow_nan=True, allow_infinity=True),
                        st.integers(min_value=-(2**70), max_value=2**70), st.text(max_size=5))
    lists = st.lists(st.one_of(scaled, boundary, st.sampled_from(WILD)), min_size=0, max_size=4)
    return st.one_of(scalars, scalars, lists)


def schema_keys(schema):
    return [(s, k) for s, fields in schema.items() for k in fields]


@st.composite
def raw_decks(draw, schema, keys=None):
    """1 to 3 keys of ``schema`` (or of ``keys``) set to generated values; rarely an unknown key
    or section, or a section that is not a table."""
    keys = keys or schema_keys(schema)
    chosen = draw(st.lists(st.sampled_from(keys), min_size=1, max_size=3, unique=True))
    raw = {}
    for s, k in chosen:
        raw.setdefault(s, {})[k] = draw(values_for(schema[s][k]))
    odd = draw(st.integers(0, 19))
    if odd == 0:
        raw.setdefault(chosen[0][0], {})["no_such_key"] = 1
    elif odd == 1:
        raw["no_such_section"] = {"a": 1}
    elif odd == 2:
        raw[chosen[0][0]] = 3.0
    return raw


def merged(base, raw):
    out = copy.deepcopy(base)
    for s, table in raw.items():
        if isinstance(table, dict) and isinstance(out.get(s), dict):
            out[s].update(table)
        else:
            out[s] = table
    return out


def names_a_key(schema, message):
    return (any(f"{s}.{k}" in message for s, k in schema_keys(schema))
            or any(f"[{s}]" in message for s in schema) or message.startswith("unknown section"))


def load_or_refuse(driver, raw):
    """Check the deck of ``driver``; returns the deck or the DeckError message (asserted one line,
    naming a key). Any other exception fails the test."""
    schema, base, checks = DRIVERS[driver]
    try:
        deck = check_deck(schema, merged(base, raw), checks)
        if driver == "calibrate":
            from pardem.drivers.calibrate import calibrated_deck
            calibrated_deck(deck)    # the targets give a compress deck, checked by its schema
        return deck
    except DeckError as err:
        msg = str(err)
        assert msg and "\n" not in msg, repr(msg)
        assert len(msg) < 700, msg
        assert names_a_key(schema, msg) or driver == "calibrate" and names_a_key(COMPRESS_SCHEMA, msg), msg
        return msg


FUZZ = settings(max_examples=150, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.mark.parametrize("driver", list(DRIVERS))
def test_generated_decks_load_or_refuse_in_one_line(driver):
    schema = DRIVERS[driver][0]

    @FUZZ
    @given(raw=raw_decks(schema))
    def property_(raw):
        load_or_refuse(driver, raw)
    property_()


def test_default_decks_and_shipped_decks_load():
    """The fuzzing's reference: every driver's defaults and every deck in drivers/ pass the checks
    (they are the documented, working inputs)."""
    for driver in DRIVERS:
        assert isinstance(load_or_refuse(driver, {}), dict), driver
    for name, schema in (("compress_default.toml", COMPRESS_SCHEMA), ("compress_compact.toml", COMPRESS_SCHEMA),
                         ("anisotropy_ordered.toml", COMPRESS_SCHEMA), ("anisotropy_study.toml", COMPRESS_SCHEMA),
                         ("isotropic_small.toml", iso.SCHEMA), ("isotropic_glass.toml", iso.SCHEMA),
                         ("triaxial_short.toml", triaxial.SCHEMA), ("triaxial_cemented.toml", triaxial.SCHEMA),
                         ("calibrate_beech.toml", calib.CALIBRATE_SCHEMA)):
        load_deck(schema, os.path.join(DRIVERS_DIR, name), checks=CALIBRATE_CHECKS if schema is calib.CALIBRATE_SCHEMA
                  else ())


# -- the issue's accepted nonsense and tracebacks: each refused, naming its key ----------------------

GIB = 2**30
NONSENSE = [
    # (driver, overrides, a key the message must name, text the message must not hold)
    ("compress", ["domain.box=[1, 1, 1]"], "domain.box", None),
    ("compress", ["domain.radius=1e-5"], "domain.radius", None),
    ("compress", ["domain.density=1e-300"], "domain.density", None),
    ("compress", ["plates.stiffness=1e30"], "plates.stiffness", None),
    ("compress", ["bonds.radius_ratio=1e-300"], "bonds.radius_ratio", None),
    ("compress", ["loading.plate_speed=5e-324"], "loading.plate_speed", None),
    ("compress", ["run.dt=5e-324"], "run.dt", None),
    ("compress", ["loading.plate_speed=1e-300"], "loading.plate_speed", None),
    ("compress", ["loading.strain=1e-300"], "loading.strain", None),
    ("compress", ["domain.kind=compact", "domain.bond_gap=0"], "domain.bond_gap", None),
    ("compress", ["domain.box=[1e308, 0.01, 0.01]"], "domain.box", "smaller than one element diameter"),
    ("compress", ["run.dt=1e-3"], "run.dt", None),
    ("compress", ["output.vtk_every=99999999999999999999"], "output.vtk_every", None),
    ("compress", ["loading.ramp_time=1e300"], "loading.ramp_time", None),
    ("anisotropy", ["domain.radius=1e-6"], "domain.radius", None),
    ("triaxial", ["sample.per_edge=1000"], "sample.per_edge", None),
    ("triaxial", ["loading.strain_rate=1e12"], "loading.strain_rate", None),
    ("triaxial", ["loading.strain=1e-300"], "loading.strain", None),
    ("triaxial", ["sample.density=1e-300"], "sample.density", None),
    ("isotropic", ["sample.n=1000000000"], "sample.n", None),
    ("isotropic", ["moduli.strain=1e-300"], "moduli.strain", None),
    ("isotropic", ["preparation.max_rate=1e12"], "preparation.max_rate", None),
    ("calibrate", ["domain.box=[1, 1, 1]"], "domain.box", None),
    ("calibrate", ["targets.density=1e-300"], "targets.density", None),
    # out of range by the physics: moduli beyond any solid, pressures crushing the grains,
    # tolerances that switch a criterion off, a watchdog shorter than its own checks
    ("isotropic", ["material.shear_modulus=1e308"], "material.shear_modulus", None),
    ("mixture", ["material.shear_modulus=1e308"], "material.shear_modulus", None),
    ("triaxial", ["contacts.young=1e308"], "contacts.young", None),
    ("isotropic", ["preparation.pressures=[1e5, 1e308]"], "preparation.pressures[1]", None),
    ("isotropic", ["preparation.pressures=[1e9]"], "preparation.pressures[0]", None),   # G = 30 GPa: E / 72
    ("triaxial", ["loading.confining_pressure=1e308"], "loading.confining_pressure", None),
    ("triaxial", ["loading.confining_pressure=1e9"], "loading.confining_pressure", None),   # E / 70
    ("response", ["preparation.pressure=1e308"], "preparation.pressure", None),
    ("biaxial", ["loading.confining_pressures=[1e308]"], "loading.confining_pressures[0]", None),
    ("isotropic", ["equilibrium.force_tolerance=1e308"], "equilibrium.force_tolerance", None),
    ("isotropic", ["equilibrium.kinetic_tolerance=1.5"], "equilibrium.kinetic_tolerance", None),
    ("response", ["relax.force_tolerance=2"], "relax.force_tolerance", None),
    ("triaxial", ["preparation.kinetic_ratio=1e308"], "preparation.kinetic_ratio", None),
    ("isotropic", ["run.watchdog_seconds=0.001"], "run.watchdog_seconds", None),
    ("compress", ["run.watchdog_seconds=9.9"], "run.watchdog_seconds", None),
    ("biaxial", ["run.watchdog_seconds=true"], "run.watchdog_seconds", None),
]


# the anisotropy study's quick compact domain (about 720 elements; packing in seconds)
COMPACT_SMALL = ["domain.kind=compact", "domain.box=[0.0045, 0.0045, 0.0045]", "domain.radius=0.25e-3",
                 "domain.dispersity=0.45"]


@pytest.fixture
def machine_of_the_issue(monkeypatch):
    """The memory the issue's machine had available (2.9 GiB), so the memory refusals do not
    depend on the machine running the tests."""
    monkeypatch.setattr(deck_checks, "available_memory", lambda: int(2.9 * GIB))


@pytest.mark.parametrize("driver, overrides, key, forbidden", NONSENSE,
                         ids=[f"{d}:{' '.join(o)}" for d, o, _, _ in NONSENSE])
def test_issue_nonsense_is_refused_naming_the_key(driver, overrides, key, forbidden, machine_of_the_issue):
    schema, base, checks = DRIVERS[driver]
    with pytest.raises(DeckError) as err:
        deck = load_deck(schema, None, overrides, base=base or None, checks=checks)
        if driver == "calibrate":
            from pardem.drivers.calibrate import calibrated_deck
            calibrated_deck(deck)
    msg = str(err.value)
    assert "\n" not in msg and key in msg, msg
    if forbidden:
        assert forbidden not in msg, msg


@FUZZ
@given(raw=raw_decks(COMPRESS_SCHEMA))
@example(raw={"domain": {"box": [1e308, 0.01, 0.01]}})
@example(raw={"domain": {"kind": "compact", "bond_gap": 0.0}})
@example(raw={"loading": {"plate_speed": 1e-300}})
@example(raw={"loading": {"strain": 1e-300}})
@example(raw={"run": {"dt": 5e-324}})
@example(raw={"domain": {"density": 1e-300}, "plates": {"stiffness": 1e30}})
def test_compress_examples_of_the_issue(raw):
    """The issue's inputs among generated ones (hypothesis runs the examples first)."""
    out = load_or_refuse("compress", raw)
    if raw in ({"domain": {"box": [1e308, 0.01, 0.01]}}, {"loading": {"plate_speed": 1e-300}},
               {"loading": {"strain": 1e-300}}, {"run": {"dt": 5e-324}},
               {"domain": {"kind": "compact", "bond_gap": 0.0}}):
        assert isinstance(out, str), f"accepted nonsense: {raw}"


def test_memory_refusal_quotes_the_estimate_and_the_available_memory(machine_of_the_issue):
    with pytest.raises(DeckError) as err:
        load_deck(COMPRESS_SCHEMA, None, ["domain.box=[1, 1, 1]"])
    msg = str(err.value)
    assert "GiB" in msg and "2.9 GiB available" in msg, msg


def test_memory_estimate_bounds_the_build(tmp_path):
    """The estimate is not below what a build allocates: tracemalloc's peak over ``build_case`` of
    a small ordered and a small compact deck (numpy's buffers are traced) stays below the
    estimate, and the estimate is within a factor 20 of it (it must refuse only hopeless decks,
    not be wild)."""
    import tracemalloc

    from pardem.parallel.communicator import Communicator
    from pardem.protocols.compression import build_case
    from pardem.protocols.compression_deck import compress_element_counts
    for overrides in (["domain.box=[0.006, 0.006, 0.006]"],
                      COMPACT_SMALL):
        deck = load_deck(COMPRESS_SCHEMA, None, overrides)
        build_case(Communicator(), deck)    # compiles and caches the kernels outside the measure
        tracemalloc.start()
        case = build_case(Communicator(), deck)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        n, bonds, pairs = compress_element_counts(deck)
        est = deck_checks.estimate_memory(n, bonds, pairs)
        # the estimate of the counts themselves: within 30 % of the built domain's (compact: the
        # packing removes rattlers; ordered: exact for a box of whole diameters)
        assert abs(n / case.constants.n_elements - 1.0) < 0.3, (n, case.constants.n_elements)
        assert peak <= est <= 20 * peak, (overrides, peak, est)


def test_critical_step_and_run_length_bounds_hold_for_built_cases():
    """The deck check's critical step is an upper bound of the built case's (so ``run.dt`` above
    it is above the real critical step) and its step count a lower bound of the case's: the
    checks refuse only what the build would refuse or what would run more than 1e10 steps."""
    from pardem.parallel.communicator import Communicator
    from pardem.protocols.compression import build_case
    from pardem.protocols.compression_deck import compress_time_bounds
    small = "domain.box=[0.004, 0.004, 0.004]"
    for overrides in ([small], [small, "domain.tilt_deg=30", "bonds.young=[1e8, 5e6, 1e6]", "bonds.law=hankinson"],
                      [small, "plates.stiffness=1e6", "bonds.radius_ratio=[1.0, 0.5, 0.3]"],
                      [small, "bonds.tensile_strength=1e6", "contacts.young=1e9"],
                      [small, "loading.ramp_time=1e-4", "loading.plate_speed=0.05"],
                      COMPACT_SMALL):
        deck = load_deck(COMPRESS_SCHEMA, None, overrides)
        bounds = compress_time_bounds(deck)
        case = build_case(Communicator(), deck)
        assert bounds["dt_critical_max"] >= case.constants.dt_critical, overrides
        assert bounds["steps_min"] <= case.n_steps, (overrides, bounds["steps_min"], case.n_steps)
        assert bounds["wave_speed_max"] >= case.constants.length / case.constants.transit_time, overrides


# -- --config on what is not a regular file ---------------------------------------------------------

def _load_in_thread(path, seconds=10.0):
    """load_deck(path) in a thread; returns the exception it raised (fails if it blocks)."""
    box = {}

    def target():
        try:
            load_deck(COMPRESS_SCHEMA, path)
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            box["exc"] = exc
    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(seconds)
    return t, box.get("exc")


def test_config_fifo_directory_device_missing_refused_without_blocking(tmp_path):
    fifo = tmp_path / "deck.fifo"
    os.mkfifo(fifo)
    for path, words in ((fifo, "FIFO"), (tmp_path, "directory"), ("/dev/null", "device"),
                        (tmp_path / "missing.toml", "no such file")):
        t, exc = _load_in_thread(str(path))
        if t.is_alive():     # unblock the thread before failing
            with open(fifo, "w"):
                pass
            pytest.fail(f"--config {path} blocked")
        assert isinstance(exc, DeckError), exc
        assert words in str(exc) and "\n" not in str(exc), str(exc)


def test_config_fifo_subprocess_exits_2_at_once(tmp_path):
    fifo = tmp_path / "deck.fifo"
    os.mkfifo(fifo)
    p = subprocess.run([sys.executable, "-m", "pardem.drivers.compress", "--config", str(fifo),
                        "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert p.stderr.strip().count("\n") == 0 and "FIFO" in p.stderr, p.stderr
    assert not (tmp_path / "o").exists()


# -- config toolkit -------------------------------------------------------------------------------

def test_schema_checks_run_after_the_fields_and_extra_checks_too():
    from pardem.config import Field, number
    seen = []

    def both_positive_sum(deck):
        seen.append(dict(deck["s"]))
        if deck["s"]["a"] + deck["s"]["b"] > 1.0:
            raise DeckError("s.a, s.b: a + b above 1")
    schema = Schema({"s": {"a": Field(0.25, number(0.0, 1.0), ""), "b": Field(0.5, number(0.0, 1.0), "")}},
                    checks=(both_positive_sum,))
    assert load_deck(schema, None, ["s.a=0.5"]) == {"s": {"a": 0.5, "b": 0.5}}
    with pytest.raises(DeckError, match="a \\+ b above 1"):
        load_deck(schema, None, ["s.a=0.75"])
    with pytest.raises(DeckError, match="s.a"):
        load_deck(schema, None, ["s.a=2"])     # the field's own check first: the cross check never sees it
    assert all(0.0 < d["a"] < 1.0 for d in seen)
    extra = []
    check_deck(schema, {}, checks=(lambda deck: extra.append(1),))
    assert extra == [1]
    # a plain dict is a schema without checks (every existing caller)
    assert check_deck(dict(schema), {"s": {"a": 0.75}}) == {"s": {"a": 0.75, "b": 0.5}}


def test_subnormal_and_out_of_int64_values_refused():
    for text, key in (("run.dt=5e-324", "run.dt"), ("domain.density=1e-310", "domain.density"),
                      ("domain.seed=9223372036854775808", "domain.seed"),
                      ("output.vtk_every=-9223372036854775809", "output.vtk_every")):
        with pytest.raises(DeckError) as err:
            load_deck(COMPRESS_SCHEMA, None, [text])
        assert key in str(err.value)
    assert load_deck(COMPRESS_SCHEMA, None, ["domain.seed=9223372036854775807"])["domain"]["seed"] == 2**63 - 1


def test_huge_integer_text_is_one_line():
    with pytest.raises(DeckError) as err:
        load_deck(COMPRESS_SCHEMA, None, ["domain.seed=" + "9" * 5000])
    assert "\n" not in str(err.value) and len(str(err.value)) < 300


# -- the drivers in a subprocess on generated decks ------------------------------------------------

def toml_value(v):
    """``v`` as a TOML value for ``--set`` (NaN and inf as TOML writes them)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(v)


SMALL_RUNS = {
    # driver -> (command after python -m, keys the fuzzing leaves alone: they set the run's size or
    # length beyond --steps, which this test bounds by its timeout)
    "compress": (["pardem.drivers.compress", "--set", "domain.box=[0.003, 0.003, 0.003]", "--steps", "3"],
                 {"domain.box", "domain.radius", "domain.kind"}),
    "isotropic": (["pardem.drivers.isotropic", "--config", os.path.join(DRIVERS_DIR, "isotropic_small.toml"),
                   "--set", "sample.n=40", "--set", "output.plot=false", "--steps", "3"],
                  {"sample.n", "sample.radii", "preparation.check_every", "preparation.max_steps",
                   "moduli.max_relax_steps"}),
    "triaxial": (["pardem.drivers.triaxial", "--config", os.path.join(DRIVERS_DIR, "triaxial_short.toml"),
                  "--set", "sample.per_edge=3", "--set", "output.plot=false", "--steps", "3"],
                 {"sample.per_edge", "sample.radius", "preparation.check_every"}),
    "calibrate": (["pardem.drivers.calibrate"], {"domain.box", "domain.radius"}),
    "anisotropy": (["pardem.drivers.anisotropy", "--quick", "--kinds", "ordered", "--laws", "hankinson",
                    "--ratios", "1", "--xi-step", "0", "--no-plot"],
                   {"domain.box", "domain.radius", "domain.kind", "loading.strain", "loading.plate_speed"}),
    # one case of 40 grains whose preparation and moduli relaxations are capped at 200 steps (an
    # unjammed packing: the study records it and goes on)
    "mixture": (["pardem.drivers.mixture", "--quick", "--ratios", "1", "--concentrations", "0.5", "--realisations", "1",
                 "--no-plot", "--set", "sample.n=40", "--set", "preparation.max_steps=200",
                 "--set", "moduli.max_relax_steps=200"],
                {"sample.n", "sample.radii", "sample.fractions", "preparation.pressures", "preparation.max_steps",
                 "preparation.check_every", "moduli.max_relax_steps"}),
    # --steps stops the response's relaxations at their first check at or after it
    "response": (["pardem.drivers.response", "--config", os.path.join(DRIVERS_DIR, "response_short.toml"),
                  "--set", "sample.n=40", "--set", "output.plot=false", "--steps", "3"],
                 {"sample.n", "sample.radii", "replicate.copies", "preparation.check_every", "relax.check_every"}),
    "biaxial": (["pardem.drivers.biaxial", "--config", os.path.join(DRIVERS_DIR, "biaxial_short.toml"),
                 "--set", "sample.n=40", "--set", "output.plot=false", "--steps", "3"],
                {"sample.n", "sample.radii", "replicate.copies"}),
}
RUNS_PER_DRIVER = {"compress": 3, "isotropic": 2, "triaxial": 2, "calibrate": 2, "anisotropy": 1, "mixture": 1,
                   "response": 1, "biaxial": 1}
RUN_TIMEOUT = 150   # s: a run of a few steps of a small deck on a loaded 2-core machine takes < 60 s


def run_driver(driver, raw, tmp_path):
    cmd, _ = SMALL_RUNS[driver]
    sets = [a for s, table in raw.items() if isinstance(table, dict)
            for k, v in table.items() for a in ("--set", f"{s}.{k}={toml_value(v)}")]
    out = tmp_path / f"out-{abs(hash(repr(raw)))}"
    env = dict(os.environ, PYTHONPATH=ROOT, MPLBACKEND="Agg")
    try:
        p = subprocess.run([sys.executable, "-m", *cmd, *sets, "--out", str(out), "--quiet"], capture_output=True,
                           text=True, timeout=RUN_TIMEOUT, cwd=str(tmp_path), env=env)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{driver} with {sets} did not end within {RUN_TIMEOUT} s")
    assert "Traceback" not in p.stderr, (driver, sets, p.stderr[-3000:])
    assert p.returncode in EXIT_CODES, (driver, sets, p.returncode, p.stderr[-3000:])
    if p.returncode == 2:
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1, (driver, sets, p.stderr)
        assert not out.exists(), f"{driver} {sets}: output created before refusing the deck"
    return p


@pytest.mark.slow
@pytest.mark.parametrize("driver", list(SMALL_RUNS))
def test_drivers_on_generated_decks_no_traceback_no_hang(driver, tmp_path):
    schema = DRIVERS[driver][0]
    keys = [(s, k) for s, k in schema_keys(schema) if f"{s}.{k}" not in SMALL_RUNS[driver][1]]

    @settings(max_examples=RUNS_PER_DRIVER[driver], deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(raw=raw_decks(schema, keys))
    @example(raw={})     # the small base run itself: it must start, run and end
    def property_(raw):
        p = run_driver(driver, raw, tmp_path)
        if not raw:
            assert p.returncode in {0, 4, 5}, (driver, p.returncode, p.stderr[-3000:])
    property_()


# -- deep nesting, and the physical ranges at their edges -------------------------------------------

DEEP = 500          # the issue's depth: tomllib alone overflows Python's stack past about 450 levels


def deep_list(depth):
    return "[" * depth + "]" * depth


def deep_table(depth):
    return "{a=" * depth + "1" + "}" * depth


def a_key(driver):
    """A key of the driver's deck (its first number key: the value nested is checked as one)."""
    schema = DRIVERS[driver][0]
    return next(f"{s}.{k}" for s, k in schema_keys(schema) if _inner_bounds(schema[s][k].check) is not None)


def _one_line_naming(err, *words):
    msg = str(err)
    assert "\n" not in msg and len(msg) < 400, msg
    for w in words:
        assert w in msg, msg


@pytest.mark.parametrize("driver", list(DRIVERS))
def test_deep_nesting_is_refused_naming_the_key(driver, tmp_path):
    """``--set key=[[[...]]]`` 500 deep, ``{a={a=...}}`` 400 deep, a ``--config`` file nested as deep
    and a Python deck nested 5,000 deep: one DeckError line naming the key, no RecursionError. A
    list of lists (what real keys take) is judged by the key's own checker, as before."""
    schema, base, checks = DRIVERS[driver]
    key = a_key(driver)
    section, name = key.split(".", 1)
    for value in (deep_list(DEEP), deep_table(400), deep_list(17)):
        with pytest.raises(DeckError) as err:
            load_deck(schema, None, [f"{key}={value}"], base=base or None, checks=checks)
        _one_line_naming(err.value, key, "nested")
    deck = tmp_path / "deep.toml"
    deck.write_text(f"# a deck\n[{section}]\n{name} = {deep_list(DEEP)}\n")
    with pytest.raises(DeckError) as err:
        load_deck(schema, str(deck), checks=checks)
    _one_line_naming(err.value, key, "line 3", "nested")
    deck.write_text(f"[{section}]\n{name} = {deep_table(400)}\n")
    with pytest.raises(DeckError) as err:
        load_deck(schema, str(deck), checks=checks)
    _one_line_naming(err.value, key, "nested")
    value = 1.0
    for _ in range(5000):
        value = [value]
    with pytest.raises(DeckError) as err:
        check_deck(schema, merged(base, {section: {name: value}}), checks)
    _one_line_naming(err.value, key, "nested")
    # brackets inside strings and comments are not nesting: the key's own checker answers
    deck.write_text(f"[{section}]  # {'[' * 40}\n{name} = \"{'[' * 40}\"\n")
    with pytest.raises(DeckError) as err:
        load_deck(schema, str(deck), checks=checks)
    _one_line_naming(err.value, key)
    assert "nested" not in str(err.value)
    with pytest.raises(DeckError) as err:
        load_deck(schema, None, [f"{key}={deep_list(2)}"], base=base or None, checks=checks)
    assert "nested" not in str(err.value)


def test_physical_ranges_accept_their_edges():
    """The edges of the new ranges are accepted: a pressure of E / 100 exactly, a tolerance of 1, a
    watchdog of 0 (off) and of 10 s."""
    E = 2.0 * 30e9 * 1.2      # the isotropic default grains: G = 30 GPa, nu = 0.2
    deck = load_deck(iso.SCHEMA, None, [f"preparation.pressures=[1e5, {E / 100!r}]",
                                        "equilibrium.force_tolerance=1", "run.watchdog_seconds=0"])
    assert deck["preparation"]["pressures"][1] == E / 100 and deck["run"]["watchdog_seconds"] == 0.0
    with pytest.raises(DeckError, match="preparation.pressures\\[1\\]"):
        load_deck(iso.SCHEMA, None, [f"preparation.pressures=[1e5, {math.nextafter(E / 100, math.inf)!r}]"])
    assert load_deck(triaxial.SCHEMA, None, ["run.watchdog_seconds=10", "loading.confining_pressure=7e8"])
    assert load_deck(response.SCHEMA, None, ["relax.force_tolerance=1"])["relax"]["force_tolerance"] == 1.0


def test_shipped_decks_of_every_driver_load():
    """Every deck in drivers/ passes the new ranges (they are the documented inputs)."""
    schemas = {"compress": COMPRESS_SCHEMA, "anisotropy": COMPRESS_SCHEMA, "isotropic": iso.SCHEMA,
               "mixture": iso.SCHEMA, "triaxial": triaxial.SCHEMA, "calibrate": calib.CALIBRATE_SCHEMA,
               "response": response.SCHEMA, "biaxial": biaxial.SCHEMA, "direct": direct_shear.SCHEMA}
    names = sorted(n for n in os.listdir(DRIVERS_DIR) if n.endswith(".toml"))
    assert len(names) >= 15
    for name in names:
        schema = schemas[name.split("_")[0].split(".")[0]]
        load_deck(schema, os.path.join(DRIVERS_DIR, name),
                  checks=CALIBRATE_CHECKS if schema is calib.CALIBRATE_SCHEMA else ())


HUGE_TINY = [1e308, -1e308, 1e-300, 5e-324, 2**64, [1e308, 1e308, 1e308], [1e-300], math.inf, math.nan]


@pytest.mark.parametrize("driver", list(DRIVERS))
def test_every_key_at_huge_and_tiny_magnitudes(driver):
    """Every key of every driver's deck set to a huge or tiny number (or a list of them): the deck
    loads or is refused in one line naming a key; never another exception."""
    schema, base, _ = DRIVERS[driver]
    for s, k in schema_keys(schema):
        for v in HUGE_TINY:
            load_or_refuse(driver, {s: {k: v}})


COMMANDS = {
    "compress": [], "isotropic": [], "triaxial": [], "calibrate": [], "anisotropy": ["--quick"],
    "mixture": ["--quick"], "response": [], "biaxial": [],
}


@pytest.mark.parametrize("driver", list(COMMANDS))
def test_drivers_refuse_deep_nesting_in_one_line(driver, tmp_path):
    """Each of the 8 drivers, on the issue's input (the three forms in turn): exit 2, one line
    naming the key, no traceback, no output folder."""
    key = a_key(driver)
    section, name = key.split(".", 1)
    form = list(COMMANDS).index(driver) % 3
    if form == 2:
        deck = tmp_path / "deep.toml"
        deck.write_text(f"[{section}]\n{name} = {deep_list(DEEP)}\n")
        args = ["--config", str(deck)]
    else:
        args = ["--set", f"{key}={deep_list(DEEP) if form == 0 else deep_table(400)}"]
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", f"pardem.drivers.{driver}", *COMMANDS[driver], *args, "--out", str(out)],
                       capture_output=True, text=True, timeout=300, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=ROOT, MPLBACKEND="Agg"))
    assert p.returncode == 2, p.stderr[-2000:]
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0] and "nested" in lines[0], p.stderr[-2000:]
    assert not out.exists()
