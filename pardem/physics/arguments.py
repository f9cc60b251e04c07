"""Checks of the arguments users give to parameter classes and builders (setup only, no kernel).

A bad argument gives one ``ValueError`` naming it, its allowed range and its unit; an unknown or
missing keyword lists the valid names (``keywords``), where Python would raise a bare
``TypeError``. The checks return what they were given (or a float64 array), so a class that keeps
its fields as given keeps their bits. Range conventions follow ``pardem.config.number`` (the deck's):
numbers are finite unless a bound says ``inf``, never bools, never subnormal (below
``DOUBLE_MIN`` in magnitude they carry fewer than 53 bits and overflow when inverted).
"""
import functools
import inspect
import math
import numbers
import sys

import numpy as np

DOUBLE_MIN = sys.float_info.min   # smallest normal double


def short(value, limit=80):
    """``repr(value)`` cut to ``limit`` characters (a huge list must not flood the message)."""
    try:
        text = repr(value)
    except Exception:   # a user object whose repr fails still gets named by its type
        text = f"<{type(value).__name__}>"
    return text if len(text) <= limit else text[:limit - 3] + "..."


def interval(lo=None, hi=None, lo_open=True, hi_open=True, inf=False):
    """The text of an interval: ``(0, inf)``, ``(-1, 0.5)``, ``[0, inf)``, ``(0, 1]``; ``inf``:
    the upper end ``inf`` is included (``(0, inf]``)."""
    lb = "(" if lo_open or lo is None else "["
    rb = ("]" if inf else ")") if hi is None else (")" if hi_open else "]")
    return f"{lb}{'-inf' if lo is None else format(lo, 'g')}, {'inf' if hi is None else format(hi, 'g')}{rb}"


def is_real(value):
    """A real scalar: Python or NumPy int or float, or a 0-d integer/float array; not a bool."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, numbers.Real):
        return True
    return isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf"


def real(name, value, lo=None, hi=None, lo_open=True, hi_open=True, unit="", inf=False, note=""):
    """``value`` as a float if it is a real number in the interval (``None``: unbounded), or
    ValueError ``name = value: expected a number in (lo, hi) [unit]``.

    ``inf``: ``+inf`` is allowed (an open upper end, e.g. a rigid wall's modulus); otherwise the
    number must be finite. ``note`` is added to the message (what a special value means).
    """
    where = interval(lo, hi, lo_open, hi_open, inf and hi is None)
    unit_text = f" {unit}" if unit else ""
    note_text = f" ({note})" if note else ""
    allowed = f"a number in {where}{unit_text}{note_text}"
    if not is_real(value):
        raise ValueError(f"{name} = {short(value)}: expected {allowed}, got a {type(value).__name__}")
    try:
        v = float(value)
    except OverflowError:
        raise ValueError(f"{name} = {short(value)} is too large for a double: expected {allowed}") from None
    if math.isnan(v) or (math.isinf(v) and not (inf and v > 0.0)):
        raise ValueError(f"{name} = {short(value)}: expected {allowed}")
    bad_lo = lo is not None and (v <= lo if lo_open else v < lo)
    bad_hi = hi is not None and (v >= hi if hi_open else v > hi)
    if bad_lo or bad_hi:
        raise ValueError(f"{name} = {short(value)} is out of range: expected {allowed}")
    if v != 0.0 and abs(v) < DOUBLE_MIN:
        raise ValueError(f"{name} = {v!r} is a subnormal number (below {DOUBLE_MIN:.4g} in magnitude): "
                         f"expected {allowed}, not subnormal")
    return v


def choice(name, value, options):
    """``value`` if it is one of the strings ``options``, or ValueError listing them."""
    if not isinstance(value, str) or value not in options:
        raise ValueError(f"{name} = {short(value)}: expected one of {', '.join(map(repr, options))}")
    return value


def array(name, value, unit=""):
    """``value`` as a float64 array, or ValueError naming ``name`` (ragged lists, strings, objects)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        unit_text = f" {unit}" if unit else ""
        raise ValueError(f"{name} must be an array of numbers{unit_text}, got {short(value)}") from None
    return arr


def vector3(name, value, unit="", finite=True):
    """A float64 vector of shape (3,), finite, or ValueError naming ``name``."""
    arr = array(name, value, unit)
    unit_text = f" {unit}" if unit else ""
    if arr.shape != (3,) or (finite and not np.all(np.isfinite(arr))):
        raise ValueError(f"{name} = {short(value)}: expected 3 finite numbers{unit_text}, got shape "
                         f"{arr.shape}")
    return arr


def keywords(label):
    """Decorator of a class (its ``__init__``) or a function: an unknown keyword, a missing or
    doubly given argument, or too many positional ones raise one ValueError naming ``label`` and
    listing the valid names, instead of Python's ``TypeError``. Calls that bind are passed on
    unchanged. (A ``**keywords`` catch-all of the function is left to the function itself.)"""
    def decorate(target):
        func = target.__init__ if inspect.isclass(target) else target
        params = list(inspect.signature(func).parameters.values())
        if inspect.isclass(target):
            params = params[1:]   # self
        named = [p for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
        positional = [p.name for p in params if p.kind == p.POSITIONAL_OR_KEYWORD]
        names = [p.name for p in named]
        known = frozenset(names)
        required = [p.name for p in named if p.default is p.empty]
        open_keywords = any(p.kind == p.VAR_KEYWORD for p in params)
        valid = f"valid names are {', '.join(names)}"

        def check(args, kwargs):
            if len(args) > len(positional):
                raise ValueError(f"{label}() takes at most {len(positional)} positional arguments "
                                 f"({', '.join(positional)}), got {len(args)}")
            given = positional[:len(args)]
            for key in kwargs:
                if key in given:
                    raise ValueError(f"{label}() got {key!r} twice (by position and by keyword)")
                if key not in known and not open_keywords:
                    raise ValueError(f"{label}() got an unexpected keyword {key!r}: {valid}")
            missing = [k for k in required if k not in kwargs and k not in given]
            if missing:
                raise ValueError(f"{label}() is missing {', '.join(map(repr, missing))}: {valid}")

        if inspect.isclass(target):
            @functools.wraps(func)
            def __init__(self, *args, **kwargs):
                check(args, kwargs)
                func(self, *args, **kwargs)
            target.__init__ = __init__
            return target

        @functools.wraps(func)
        def wrapper(*args, **kwargs):
            check(args, kwargs)
            return func(*args, **kwargs)
        return wrapper
    return decorate


__all__ = ["DOUBLE_MIN", "short", "interval", "is_real", "real", "choice", "array", "vector3", "keywords"]
