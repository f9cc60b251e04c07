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
    check.options = tuple(options)   # listed by ``describe`` (--help)
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
    if hasattr(inner, "options"):
        check.options = (word,) + tuple(inner.options)
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


def restart_differences(schema, old, new, may_change=(), may_change_sections=()):
    """Keys (``section.key``, old, new) whose values differ between two checked decks of ``schema``
    and that a restart may not change: every key outside ``may_change`` (``section.key`` names)
    and ``may_change_sections``. A key the old deck lacks (added since it was written) counts as
    unchanged when the new deck leaves it at its default."""
    out = []
    for section, table in new.items():
        if section in may_change_sections:
            continue
        for key, value in table.items():
            name = f"{section}.{key}"
            f = schema.get(section, {}).get(key)
            if key not in old.get(section, {}) and _plain(value) == _plain(None if f is None else f.default):
                continue   # a key added after the checkpoint was written, left at its default
            before = old.get(section, {}).get(key)
            if name not in may_change and _plain(before) != _plain(value):
                out.append((name, before, value))
    return out


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
    """Human-readable list of the deck keys with their defaults, and the allowed values of every
    choice key (for ``--help``)."""
    lines = []
    for section, fields in schema.items():
        lines.append(f"[{section}]")
        for key, f in fields.items():
            options = getattr(f.check, "options", None)
            allowed = f" (one of: {', '.join(map(str, options))})" if options else ""
            lines.append(f"  {key} = {f.default!r}   # {f.doc}{allowed}")
    return "\n".join(lines)
