"""Finiteness of state arrays: the stability check's test for NaN and infinity (pure, Numba).

The test reads the IEEE 754 exponent bits (all ones for NaN and +-inf) as integers: a
branch-free count that LLVM vectorises, about one memory pass over the data (~1 ns per value).
"""
import numpy as np
from numba import njit

_EXPONENT = np.uint64(0x7FF0000000000000)


@njit(cache=True, nogil=True)
def count_nonfinite(a):
    """Number of NaN or +-inf values in a 1-D float64 array ``a`` (any length)."""
    bits = a.view(np.uint64)
    n = 0
    for k in range(bits.shape[0]):
        n += (bits[k] & _EXPONENT) == _EXPONENT
    return n


@njit(cache=True, nogil=True)
def count_nan(a):
    """Number of NaN values in a 1-D float64 array ``a`` (infinities allowed)."""
    n = 0
    for k in range(a.shape[0]):
        n += a[k] != a[k]
    return n


def _flat(a):
    """A 1-D float64 view of ``a`` (a copy only when it is not C-contiguous or not float64)."""
    return np.ascontiguousarray(a, dtype=np.float64).reshape(-1)


def first_nonfinite(arrays, allow_inf=()):
    """Index in ``arrays`` of the first float array holding a NaN or an infinity, or -1.

    arrays : sequence of numpy arrays of any shape (non-float ones are skipped: integers are
        always finite); ``allow_inf``: indices of arrays where +-inf is legitimate (only NaN counts).
    """
    for k, a in enumerate(arrays):
        if a is None or a.dtype.kind != "f" or a.size == 0:
            continue
        flat = _flat(a)
        bad = count_nan(flat) if k in allow_inf else count_nonfinite(flat)
        if bad:
            return k
    return -1
