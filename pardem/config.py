"""Input decks: TOML files plus ``--set section.key=value`` overrides, checked against a schema.

Every field is checked before any work starts. A bad field raises ``DeckError`` whose message is one
line naming the field and the values it allows; drivers print it and exit with status 2.
"""
import copy
import math
import sys
import tomllib
from dataclasses import dataclass
from typing import Any, Callable


class DeckError(ValueError):
    """A deck field is unknown, of the wrong type or out of range."""


class Schema(dict):
    """A deck schema ``{section: {key: Field}}`` with cross-field checks.

    ``checks``: functions ``check(deck)`` of a deck whose every field passed its own checker;
    each raises ``DeckError`` (one line naming the keys) for a combination that cannot run
    (memory, run length, derived magnitudes). ``check_deck`` runs them in order after the fields,
    so every caller of ``load_deck`` / ``check_deck`` gets them. A plain dict is a schema without
    checks; ``add_checks`` appends to a ``Schema``.
    """

    def __init__(self, sections=(), checks=()):
        super().__init__(sections)
        self.checks = tuple(checks)

    def add_checks(self, *checks):
        self.checks = self.checks + tuple(checks)
        return self


INT64_MAX = 2**63 - 1      # integer keys end up in numpy int64 arithmetic
# Deepest nesting of arrays and inline tables a deck may hold. No key takes more than a list of
# lists (depth 2); the parser (tomllib) and the checkers recurse once per level, and a few hundred
# levels exhaust Python's stack (a RecursionError of thousands of lines), so deeper text is
# refused before it is parsed.
MAX_NESTING = 16
DOUBLE_MIN = sys.float_info.min   # smallest normal double: below it a number has lost precision


@dataclass(frozen=True)
class Field:
    """One deck key: default value, a checker returning the normalised value, and its allowed values."""
    default: Any
    check: Callable[[str, Any], Any]
    doc: str


def _is_number(v):
    """A finite int or float (not a bool); an int beyond the doubles' range is not a number."""
    if isinstance(v, bool):
        return False
    if isinstance(v, int):
        return abs(v) <= sys.float_info.max
    return isinstance(v, float) and math.isfinite(v)


def number(lo=None, hi=None, lo_open=True, hi_open=True, integer=False):
    """Checker for a number in an interval; ``None`` bounds are infinite (integers: within int64).

    Subnormal values (nonzero, below 2.2e-308 in magnitude) are refused: they carry fewer than 53
    bits and overflow when inverted. ``check.bounds`` = (lo, hi, lo_open, hi_open, integer)."""
    lb = "(" if lo_open or lo is None else "["
    rb = ")" if hi_open or hi is None else "]"
    kind = "an integer" if integer else "a number"
    allowed = f"{kind} in {lb}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{rb}"

    def check(name, v):
        if integer and not (isinstance(v, int) and not isinstance(v, bool)):
            raise DeckError(f"{name} = {_short(v)}: expected {allowed}")
        if not _is_number(v):
            raise DeckError(f"{name} = {_short(v)}: expected {allowed}")
        bad_lo = lo is not None and (v <= lo if lo_open else v < lo)
        bad_hi = hi is not None and (v >= hi if hi_open else v > hi)
        if bad_lo or bad_hi:
            raise DeckError(f"{name} = {_short(v)} is out of range: expected {allowed}")
        if integer and abs(v) > INT64_MAX:
            raise DeckError(f"{name} = {_short(v)} is too large: expected {allowed}, within 64-bit "
                            f"integers (|value| < 2^63)")
        if not integer and v != 0 and abs(v) < DOUBLE_MIN:
            raise DeckError(f"{name} = {v!r} is a subnormal number (below {DOUBLE_MIN:.4g} in magnitude, "
                            f"less than double precision): expected {allowed}, not subnormal")
        return int(v) if integer else float(v)
    check.allowed = allowed
    check.bounds = (lo, hi, lo_open, hi_open, integer)
    return check


def _short(v, limit=80):
    """``repr(v)`` cut to ``limit`` characters (a huge integer or list must not flood the line)."""
    try:
        r = repr(v).replace("\n", " ")
    except ValueError:   # an integer of more digits than Python converts to text
        return "an integer of more than 4300 digits"
    return r if len(r) <= limit else r[:limit - 5] + "[...]"


def positive():
    return number(lo=0.0)


def number_or_triple(inner):
    """Checker for a number or a list of three numbers (L, R, T values), each passing ``inner``."""
    def check(name, v):
        if isinstance(v, list):
            if len(v) != 3:
                raise DeckError(f"{name} = {_short(v)}: expected one number or a list of 3 ({inner.allowed})")
            return tuple(inner(f"{name}[{k}]", x) for k, x in enumerate(v))
        return inner(name, v)
    check.inner = inner
    return check


def strength():
    """Checker: a stress threshold [Pa] >= 0, or [L, R, T] all > 0 (0 = none)."""
    inner = number(lo=0.0, lo_open=False)

    def check(name, v):
        if isinstance(v, list):
            if len(v) != 3:
                raise DeckError(f"{name} = {_short(v)}: expected one number >= 0 or a list of 3 numbers > 0 "
                                f"(L, R, T)")
            vals = tuple(inner(f"{name}[{k}]", x) for k, x in enumerate(v))
            if min(vals) == 0.0 and max(vals) > 0.0:
                raise DeckError(f"{name} = {_short(v)}: expected all three values > 0, or the single number 0 "
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
            raise DeckError(f"{name} = {_short(v)}: expected a list of 3 numbers, each {inner.allowed}")
        return tuple(inner(f"{name}[{k}]", x) for k, x in enumerate(v))
    check.inner = inner
    return check


def choice(*options, case_sensitive=False):
    def check(name, v):
        if isinstance(v, str):
            for o in options:
                if v == o or (not case_sensitive and v.lower() == o.lower()):
                    return o
        raise DeckError(f"{name} = {_short(v)}: expected one of {', '.join(repr(o) for o in options)}")
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
    check.inner = inner
    return check


def auto_or(inner):
    """Checker for the string "auto" or a value passing ``inner``."""
    return word_or("auto", inner)


def number_list(inner, min_len=1):
    """Checker for a list of at least ``min_len`` numbers, each passing ``inner``."""
    def check(name, v):
        if not isinstance(v, list) or len(v) < min_len:
            raise DeckError(f"{name} = {_short(v)}: expected a list of at least {min_len} numbers, each "
                            f"{inner.allowed}")
        return [inner(f"{name}[{k}]", x) for k, x in enumerate(v)]
    check.inner = inner
    return check


def optional(inner):
    """Checker accepting ``0`` / missing as 'not set' (None) for optional integer counts."""
    def check(name, v):
        if v is None or v == 0:
            return None
        return inner(name, v)
    check.inner = inner
    return check


def fractions_or(word):
    """Checker for ``word`` or an increasing list of fractions in (0, 1)."""
    def check(name, v):
        if v == word:
            return word
        if (isinstance(v, list) and all(_is_number(x) and 0 < x < 1 for x in v)
                and all(a < b for a, b in zip(v, v[1:]))):
            return tuple(float(x) for x in v)
        raise DeckError(f"{name} = {_short(v)}: expected \"{word}\" or an increasing list of fractions in (0, 1)")
    return check


def boolean(name, v):
    if not isinstance(v, bool):
        raise DeckError(f"{name} = {_short(v)}: expected true or false")
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
    """``section.key=value`` -> (section, key, value); value is read as TOML, else as a string.
    A value nested more than ``MAX_NESTING`` deep is refused before it is parsed."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise DeckError(f"--set {_trim(text)!r}: expected section.key=value")
    path, raw = text.split("=", 1)
    section, key = path.strip().split(".", 1)
    name = _trim(path.strip())
    if _too_deep(f"v = {raw}") is not None:
        raise DeckError(f"--set {name}=...: {_DEEP}")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    except RecursionError:   # a backstop of the scan above
        raise DeckError(f"--set {name}=...: {_DEEP}") from None
    except ValueError:   # an integer of more than 4300 digits
        raise DeckError(f"--set {name}=...: the value is an integer of more than 4300 digits") from None
    return section, key, value


def _nested_deeper(value, limit):
    """True when lists, tuples or dicts nest more than ``limit`` deep in ``value`` (iterative: a
    value of any depth, e.g. built by a script, is measured without recursion)."""
    stack = [(value, 0)]
    while stack:
        v, depth = stack.pop()
        if isinstance(v, (list, tuple, dict)):
            if depth >= limit:
                return True
            stack.extend((x, depth + 1) for x in (v.values() if isinstance(v, dict) else v))
    return False


_DEEP = (f"arrays or inline tables nested more than {MAX_NESTING} levels deep; expected a number, a "
         f"string, or a list of them")
_CLOSE = {"[": "]", "{": "}"}


def _too_deep(text, limit=MAX_NESTING):
    """Where TOML ``text`` nests arrays or inline tables more than ``limit`` deep: ``(line, key)``,
    the 1-based line and the key (as written, prefixed by its ``[table]``) whose value does so, or
    None. A linear scan that skips strings and comments, so that the parser never sees such text.
    Table headers (``[a]``, ``[[a]]``) open and close on their own line and count as nesting too,
    which ``limit`` leaves room for."""
    depth, line, table, key = 0, 1, "", ""
    i, n = 0, len(text)
    line_start = True
    while i < n:
        c = text[i]
        if c == "\n":
            line, line_start = line + 1, True
            i += 1
            continue
        if c in " \t\r":
            i += 1
            continue
        if c == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        if c in "\"'":
            quote = text[i:i + 3] if text[i:i + 3] in ('"""', "'''") else c
            j = i + len(quote)
            while j < n and not text.startswith(quote, j):
                if c == '"' and text[j] == "\\":
                    j += 1
                j += 1
            line += text.count("\n", i, j)
            i = j + len(quote)
            line_start = False
            continue
        if depth == 0 and line_start and c == "[":    # a [table] or [[array of tables]] header
            j = text.find("\n", i)
            j = n if j < 0 else j
            table = text[i:j].split("#", 1)[0].strip().strip("[]").strip()
            i, line_start = j, False
            continue
        if depth == 0 and line_start:    # a key: text up to its "="
            j = text.find("=", i)
            if j < 0:
                return None
            key = text[i:j].strip()
            i, line_start = j + 1, False
            continue
        if c in "[{":
            depth += 1
            if depth > limit:
                return line, ".".join(part for part in (table, key) if part)
        elif c in "]}":
            depth = max(depth - 1, 0)
        line_start = False
        i += 1
    return None


def apply_overrides(raw, overrides):
    """``raw`` (nested dict, changed in place) with the ``--set SECTION.KEY=VALUE`` texts applied."""
    for text in overrides:
        section, key, value = parse_override(text)
        raw.setdefault(section, {})
        if not isinstance(raw[section], dict):
            raise DeckError(f"[{section}] must be a table")
        raw[section][key] = value
    return raw


def parse_toml(text, where):
    """The TOML table of deck text ``text``; DeckError (one line, ``where`` naming the source) for
    text nested too deep or not valid TOML."""
    deep = _too_deep(text)
    if deep is not None:
        raise DeckError(f"{where}: {_trim(deep[1]) or 'a value'} (line {deep[0]}): {_DEEP}")
    try:
        return tomllib.loads(text)
    except RecursionError:   # a backstop of the scan above
        raise DeckError(f"{where}: {_DEEP}") from None
    except tomllib.TOMLDecodeError as err:
        raise DeckError(f"{where}: not valid TOML ({_one_line(err)})") from None
    except ValueError as err:   # an integer of more than 4300 digits
        raise DeckError(f"{where}: unreadable value ({_one_line(err)})") from None


def _trim(name, limit=80):
    """A deck name as written, on one line and at most ``limit`` characters."""
    text = " ".join(str(name).split())
    return text if len(text) <= limit else text[:limit - 5] + "[...]"


def _one_line(err):
    return " ".join(str(err).split())


def check_deck(schema, raw, checks=()):
    """The checked deck of the raw tables ``raw``: unknown sections and keys are refused, every
    field passes its checker (defaults fill the rest), then the cross-field checks of the schema
    (``Schema.checks``) and ``checks`` run on the checked deck. DeckError (one line) on failure."""
    if not isinstance(raw, dict):
        raise DeckError(f"the deck must be a table of sections, not {type(raw).__name__}")
    deck = defaults(schema)
    for section, table in raw.items():
        if section not in schema:
            raise DeckError(f"unknown section [{_trim(section)}]: allowed sections are {', '.join(schema)}")
        if not isinstance(table, dict):
            raise DeckError(f"[{section}] must be a table of keys")
        for key, value in table.items():
            if key not in schema[section]:
                raise DeckError(f"unknown key {section}.{_trim(key)}: allowed keys in [{section}] are "
                                f"{', '.join(schema[section])}")
            if _nested_deeper(value, MAX_NESTING):
                raise DeckError(f"{section}.{key}: {_DEEP}")
            deck[section][key] = value
    for section, fields in schema.items():
        for key, f in fields.items():
            deck[section][key] = f.check(f"{section}.{key}", deck[section][key])
    for check in tuple(getattr(schema, "checks", ())) + tuple(checks):
        try:
            check(deck)
        except ArithmeticError as err:   # a check's own arithmetic overflowed: still one line
            raise DeckError(f"the deck's values overflow the checks of {check.__name__} "
                            f"({_one_line(err)}): expected physically meaningful magnitudes") from None
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
