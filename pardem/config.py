"""Input decks: TOML files plus ``--set section.key=value`` overrides, checked against a schema.

Every field is checked before any work starts. A bad field raises ``DeckError`` whose message is one
line naming the field and the values it allows; drivers print it and exit with status 2.
"""
import copy
import math
import tomllib
from dataclasses import dataclass
from typing import Any, Callable


class DeckError(ValueError):
    """A deck field is unknown, of the wrong type or out of range."""


@dataclass(frozen=True)
class Field:
    """One deck key: default value, a checker returning the normalised value, and its allowed values."""
    default: Any
    check: Callable[[str, Any], Any]
    doc: str


def _is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def number(lo=None, hi=None, lo_open=True, hi_open=True, integer=False):
    """Checker for a number in an interval; ``None`` bounds are infinite."""
    lb = "(" if lo_open or lo is None else "["
    rb = ")" if hi_open or hi is None else "]"
    kind = "an integer" if integer else "a number"
    allowed = f"{kind} in {lb}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{rb}"

    def check(name, v):
        if integer and not (isinstance(v, int) and not isinstance(v, bool)):
            raise DeckError(f"{name} = {v!r}: expected {allowed}")
        if not _is_number(v):
            raise DeckError(f"{name} = {v!r}: expected {allowed}")
        bad_lo = lo is not None and (v <= lo if lo_open else v < lo)
        bad_hi = hi is not None and (v >= hi if hi_open else v > hi)
        if bad_lo or bad_hi:
            raise DeckError(f"{name} = {v!r} is out of range: expected {allowed}")
        return int(v) if integer else float(v)
    check.allowed = allowed
    return check


def positive():
    return number(lo=0.0)


def number_or_triple(inner):
    """Checker for a number or a list of three numbers (L, R, T values), each passing ``inner``."""
    def check(name, v):
        if isinstance(v, list):
            if len(v) != 3:
                raise DeckError(f"{name} = {v!r}: expected one number or a list of 3 ({inner.allowed})")
            return tuple(inner(f"{name}[{k}]", x) for k, x in enumerate(v))
        return inner(name, v)
    return check


def strength():
    """Checker: a stress threshold [Pa] >= 0, or [L, R, T] all > 0 (0 = none)."""
    inner = number(lo=0.0, lo_open=False)

    def check(name, v):
        if isinstance(v, list):
            if len(v) != 3:
                raise DeckError(f"{name} = {v!r}: expected one number >= 0 or a list of 3 numbers > 0 "
                                f"(L, R, T)")
            vals = tuple(inner(f"{name}[{k}]", x) for k, x in enumerate(v))
            if min(vals) == 0.0 and max(vals) > 0.0:
                raise DeckError(f"{name} = {v!r}: expected all three values > 0, or the single number 0 "
                                f"for no threshold")
            return vals
        return inner(name, v)
    check.allowed = "a number >= 0 or [L, R, T]"
    return check


def same_or(inner):
    """Checker for "same" (E_R^D = E_T^D in the calibration targets) or a value passing ``inner``."""
    return word_or("same", inner, "E_R^D = E_T^D")


def triple(inner):
    def check(name, v):
        if not isinstance(v, list) or len(v) != 3:
            raise DeckError(f"{name} = {v!r}: expected a list of 3 numbers, each {inner.allowed}")
        return tuple(inner(f"{name}[{k}]", x) for k, x in enumerate(v))
    return check


def choice(*options, case_sensitive=False):
    def check(name, v):
        if isinstance(v, str):
            for o in options:
                if v == o or (not case_sensitive and v.lower() == o.lower()):
                    return o
        raise DeckError(f"{name} = {v!r}: expected one of {', '.join(repr(o) for o in options)}")
    return check


def word_or(word, inner, meaning=""):
    """Checker for the string ``word`` or a value passing ``inner`` (``meaning`` explains the word
    in the error message)."""
    def check(name, v):
        if v == word:
            return word
        try:
            return inner(name, v)
        except DeckError as err:
            raise DeckError(f"{err} or \"{word}\"{f' ({meaning})' if meaning else ''}") from None
    return check


def auto_or(inner):
    """Checker for the string "auto" or a value passing ``inner``."""
    return word_or("auto", inner)


def number_list(inner, min_len=1):
    """Checker for a list of at least ``min_len`` numbers, each passing ``inner``."""
    def check(name, v):
        if not isinstance(v, list) or len(v) < min_len:
            raise DeckError(f"{name} = {v!r}: expected a list of at least {min_len} numbers, each "
                            f"{inner.allowed}")
        return [inner(f"{name}[{k}]", x) for k, x in enumerate(v)]
    return check


def optional(inner):
    """Checker accepting ``0`` / missing as 'not set' (None) for optional integer counts."""
    def check(name, v):
        if v is None or v == 0:
            return None
        return inner(name, v)
    return check


def fractions_or(word):
    """Checker for ``word`` or an increasing list of fractions in (0, 1)."""
    def check(name, v):
        if v == word:
            return word
        if (isinstance(v, list) and all(_is_number(x) and 0 < x < 1 for x in v)
                and all(a < b for a, b in zip(v, v[1:]))):
            return tuple(float(x) for x in v)
        raise DeckError(f"{name} = {v!r}: expected \"{word}\" or an increasing list of fractions in (0, 1)")
    return check


def boolean(name, v):
    if not isinstance(v, bool):
        raise DeckError(f"{name} = {v!r}: expected true or false")
    return v


# The compress driver's deck. Defaults are the issue's default case (docs/physics.md W study cube).
COMPRESS_SCHEMA = {
    "domain": {
        "kind": Field("ordered", choice("ordered", "compact"),
                      "domain builder: ordered (cubic lattice, face bonds) or compact (dense random "
                      "packing, solid fraction >= 0.63, bonds within bond_gap)"),
        "box": Field([0.01, 0.01, 0.01], triple(positive()), "box edge lengths [m]"),
        "radius": Field(0.2381e-3, positive(),
                        "element radius [m]; compact: the requested mean radius (the packing ends "
                        "within about 1 % of it)"),
        "density": Field(1000.0, positive(),
                         "element density rho_e [kg/m^3], used as given for both kinds; the represented "
                         "continuum's density is rho_e times the solid fraction (pi/6 ordered, 0.63-0.64 "
                         "compact), docs/physics.md section 1"),
        "tilt_deg": Field(0.0, number(-90.0, 90.0, lo_open=False, hi_open=False),
                          "tilt of the LRT frame about T (z) [deg]; ordered: the lattice turns with it"),
        "seed": Field(0, number(lo=0, lo_open=False, integer=True),
                      "compact: seed of the random packing (the same seed gives the same packing)"),
        "dispersity": Field(0.1, number(0.0, 0.5, lo_open=False),
                            "compact: radii uniform in radius * (1 - dispersity, 1 + dispersity)"),
        "bond_gap": Field(0.01, number(0.0, 0.5, lo_open=False, hi_open=False),
                          "compact: bond the pairs whose surface gap is below bond_gap * mean radius"),
    },
    "bonds": {
        "young": Field(100e6, number_or_triple(positive()), "bond Young's modulus, or [E_L, E_R, E_T] [Pa]"),
        "law": Field("TOR", choice("TOR", "hankinson", "linear", "spherical"), "anisotropy law"),
        "radius_ratio": Field(1.0, number_or_triple(positive()),
                              "bond radius / mean element radius, or [r_L, r_R, r_T]"),
        "poisson": Field(0.3, number(-1.0, 0.5), "bond Poisson ratio"),
        "damping": Field(0.2, number(0.0, 1.0, lo_open=False, hi_open=False), "bond damping ratio"),
        "tensile_strength": Field(0.0, strength(),
                                  "bond tensile strength sigma_max = F / S [Pa], or [L, R, T] (all > 0, "
                                  "by the anisotropy law); 0 = unbreakable in tension"),
        "shear_strength": Field(0.0, strength(),
                                "bond shear strength tau_max = |T| / S [Pa], or [L, R, T] (all > 0); "
                                "0 = unbreakable in shear"),
        "densification_stress": Field(0.0, number(lo=0.0, lo_open=False),
                                      "densification threshold sigma0 [Pa] of the bonds initially along "
                                      "T, in compression (docs/physics.md section 7); 0 = elastic"),
        "densification_p0": Field(0.05, positive(),
                                  "densification factor p0: the threshold grows as exp(p / p0) with "
                                  "the plastic strain p"),
    },
    "contacts": {
        "law": Field("auto", choice("auto", "none", "hertz_mindlin", "linear"),
                     "element-element contacts (pairs not joined by an intact bond); auto = "
                     "hertz_mindlin when bonds can break, none otherwise"),
        "young": Field("auto", auto_or(positive()),
                       "hertz_mindlin: Young's modulus of the elements [Pa]; auto = the largest bond modulus"),
        "poisson": Field(0.3, number(-1.0, 0.5), "hertz_mindlin: Poisson ratio of the elements"),
        "stiffness": Field("auto", auto_or(positive()),
                           "linear: kn = kt [N/m]; auto = the mean axial bond stiffness"),
        "friction": Field(0.3, number(lo=0.0, lo_open=False), "Coulomb friction coefficient"),
        "restitution": Field(1.0, number(0.0, 1.0, hi_open=False),
                             "normal restitution coefficient of contacts; 1 = undamped"),
    },
    "plates": {
        "law": Field("linear", choice("linear", "hertz"),
                     "element-wall normal law of the plates and lateral walls"),
        "stiffness": Field("auto", auto_or(positive()),
                           "linear law: element-wall stiffness kn = kt [N/m]; auto = mean axial bond stiffness"),
        "young": Field("auto", auto_or(positive()),
                       "hertz law: Young's modulus of the elements against the rigid walls [Pa]; "
                       "auto = the largest bond modulus"),
        "poisson": Field(0.3, number(-1.0, 0.5), "hertz law: Poisson ratio of the elements"),
        "friction": Field(0.0, number(lo=0.0, lo_open=False),
                          "Coulomb friction coefficient of the walls; 0 = frictionless (no history)"),
        "restitution": Field(1.0, number(0.0, 1.0, hi_open=False),
                             "normal restitution coefficient of element-wall impacts; 1 = undamped"),
        "lateral_walls": Field(False, boolean,
                               "fixed walls on the four faces across the load (at the outer element "
                               "surfaces): a laterally confined test"),
    },
    "loading": {
        "axis": Field("x", choice("x", "y", "z"), "loading axis"),
        "strain": Field(0.005, number(0.0, 0.5), "nominal strain imposed by the moving plate"),
        "plate_speed": Field(0.5, positive(), "moving plate speed [m/s]"),
        "ramp_time": Field("auto", auto_or(number(lo=0.0, lo_open=False)),
                           "time [s] over which the plate speed rises smoothly from 0; auto = 4 L / c "
                           "(two periods of the slowest axial mode, c from the bonds along the "
                           "axis), at most the time to cover half the travel"),
    },
    "run": {
        "dt": Field("auto", auto_or(positive()), "time step [s], or auto = dt_fraction * critical step"),
        "dt_fraction": Field(0.5, number(0.0, 1.0, hi_open=False), "fraction of the critical step when dt = auto"),
        "progress_seconds": Field(5.0, positive(), "seconds between progress lines (rank 0)"),
    },
    "parallel": {
        "slab_axis": Field("auto", choice("auto", "x", "y", "z"),
                           "axis the slabs are stacked along; auto = longest extent, not the loading axis"),
        "skin": Field("auto", auto_or(positive()),
                      "displacement budget between ghost rebuilds [m]; auto = 0.2 R"),
        "balance_every": Field(200, number(lo=0, lo_open=False, integer=True),
                               "steps between load-balance checks; 0 = never"),
        "balance_threshold": Field(0.05, number(0.0, 1.0), "re-cut slabs when per-rank loads differ by more (max/min - 1)"),
        "balance_by": Field("count", choice("count", "time"), "load measure: owned elements or computing seconds"),
        "initial_split": Field("balanced", fractions_or("balanced"),
                               "initial cuts: balanced, or cumulative element fractions (one per cut)"),
    },
    "checkpoint": {
        "every_steps": Field(0, number(lo=0, lo_open=False, integer=True), "steps between checkpoints; 0 = off"),
        "every_seconds": Field(1800.0, number(lo=0.0, lo_open=False),
                               "wall seconds between checkpoints; 0 = off"),
        "keep": Field(3, number(lo=1, lo_open=False, integer=True), "how many checkpoints to keep"),
        "at_end": Field(True, boolean, "write a checkpoint when the run ends"),
        "driver": Field("auto", choice("auto", "mpio", "serial"),
                        "HDF5 writing: collective MPI-IO, ranks taking turns, or auto"),
    },
    "output": {
        "series_every": Field(0, optional(number(lo=0, integer=True)),
                              "steps between series samples; 0 = about 200 samples per run"),
        "vtk_every": Field(0, number(lo=0, lo_open=False, integer=True),
                           "steps between ParaView snapshots (DIR/paraview/pardem.pvd); 0 = none"),
    },
}


# Keys a restart may change: run length, output and parallel settings. Any other difference
# would change the physics of the continued run, and the restart is refused.
RESTART_MAY_CHANGE = {"loading.strain", "run.progress_seconds"}
RESTART_MAY_CHANGE_SECTIONS = {"output", "checkpoint", "parallel"}


def physics_differences(old, new):
    """Keys (``section.key``) whose values differ between two checked decks and may not on restart."""
    out = []
    for section, table in new.items():
        if section in RESTART_MAY_CHANGE_SECTIONS:
            continue
        for key, value in table.items():
            name = f"{section}.{key}"
            if key not in old.get(section, {}) and _plain(value) == _plain(_default(section, key)):
                continue   # a key added after the checkpoint was written, left at its default
            before = old.get(section, {}).get(key)
            if name not in RESTART_MAY_CHANGE and _plain(before) != _plain(value):
                out.append((name, before, value))
    return out


def _default(section, key):
    f = COMPRESS_SCHEMA.get(section, {}).get(key)
    return None if f is None else f.default


def _plain(v):
    return [_plain(x) for x in v] if isinstance(v, (list, tuple)) else v


def raw_deck(value):
    """A checked deck back to TOML-like values (tuples -> lists), so it can be checked again."""
    if isinstance(value, dict):
        return {k: raw_deck(v) for k, v in value.items()}
    return _plain(value)


def defaults(schema):
    return {s: {k: copy.deepcopy(f.default) for k, f in fields.items()} for s, fields in schema.items()}


def parse_override(text):
    """``section.key=value`` -> (section, key, value); value is read as TOML, else as a string."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise DeckError(f"--set {text!r}: expected section.key=value")
    path, raw = text.split("=", 1)
    section, key = path.strip().split(".", 1)
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return section, key, value


def load_deck(schema, path=None, overrides=(), base=None):
    """Read ``path`` (TOML, may be None; else start from the deck ``base``), apply overrides, check
    every field; returns a nested dict."""
    raw = copy.deepcopy(base) if base is not None and path is None else {}
    if path is not None:
        try:
            with open(path, "rb") as fh:
                raw = tomllib.load(fh)
        except FileNotFoundError:
            raise DeckError(f"--config {path}: no such file") from None
        except (OSError, UnicodeDecodeError) as err:
            raise DeckError(f"--config {path}: cannot be read ({err})") from None
        except tomllib.TOMLDecodeError as err:
            raise DeckError(f"--config {path}: not valid TOML ({err})") from None
    for text in overrides:
        section, key, value = parse_override(text)
        raw.setdefault(section, {})
        if not isinstance(raw[section], dict):
            raise DeckError(f"[{section}] must be a table")
        raw[section][key] = value
    return check_deck(schema, raw)


def check_deck(schema, raw):
    deck = defaults(schema)
    for section, table in raw.items():
        if section not in schema:
            raise DeckError(f"unknown section [{section}]: allowed sections are {', '.join(schema)}")
        if not isinstance(table, dict):
            raise DeckError(f"[{section}] must be a table of keys")
        for key, value in table.items():
            if key not in schema[section]:
                raise DeckError(f"unknown key {section}.{key}: allowed keys in [{section}] are "
                                f"{', '.join(schema[section])}")
            deck[section][key] = value
    for section, fields in schema.items():
        for key, f in fields.items():
            deck[section][key] = f.check(f"{section}.{key}", deck[section][key])
    return deck


def describe(schema):
    """Human-readable list of the deck keys with their defaults (for ``--help``)."""
    lines = []
    for section, fields in schema.items():
        lines.append(f"[{section}]")
        for key, f in fields.items():
            lines.append(f"  {key} = {f.default!r}   # {f.doc}")
    return "\n".join(lines)
