"""Reproducible global sums: the same bits on any number of ranks.

Each rank adds its terms exactly into integer accumulators (``pardem.physics.exact_accumulate``);
the canonical limbs (each below 2^32) are summed over the ranks with one float64 ``MPI_SUM``
(``Communicator.sum``), which is exact in any order for fewer than 2^20 ranks, and the total is
rounded to float64 once. The result is thus a function of the multiset of terms only: neither the
order of the terms on a rank nor their split between ranks changes a bit. Cost: one allreduce of
``70 K`` doubles for ``K`` sums, instead of ``K``.
"""
import numpy as np

from pardem.physics import exact_accumulate as xa


def total(comm, acc, ok=True):
    """Global sums [K] float64 of the per-rank accumulators ``acc`` [K, NLIMB] (normalized) in one
    allreduce; ``ok`` False on any rank (a non-finite term) makes them NaN on every rank.
    Collective, the same bits on every rank."""
    acc = np.asarray(acc, dtype=np.int64)
    bad = not ok
    if comm.size > 1:
        flat = np.concatenate([acc.astype(np.float64).ravel(), [0.0 if ok else 1.0]])
        flat = np.asarray(comm.sum(flat))
        bad = flat[-1] > 0.0
        acc = flat[:-1].reshape(acc.shape).astype(np.int64)
        xa.normalize(acc)
    out = xa.value(acc)
    if bad:
        out[:] = np.nan
    return out


def exact_sum(comm, values):
    """Global sum of this rank's ``values`` (a scalar, [n] terms or [n, K] columns of terms),
    bitwise independent of the decomposition: a float for a scalar or [n], else [K]. A
    non-finite term makes the sum NaN (on every rank). Collective."""
    a = np.asarray(values, dtype=np.float64)
    scalar = a.ndim <= 1
    a = np.ascontiguousarray(a.reshape(-1, 1) if scalar else a)
    acc = xa.zeros(a.shape[1])
    ok = xa.add_columns(a, a.shape[0], acc)
    out = total(comm, acc, ok)
    return float(out[0]) if scalar else out
