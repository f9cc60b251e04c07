"""Exact, order-independent sums of float64 values (a fixed-point superaccumulator).

Why: a floating-point sum depends on the order of its terms, so a global sum made of per-rank
partial sums differs in its last bits between 1, 2 and 3 ranks; when such a sum feeds back into
the dynamics (a stress servo, FIRE's power, an equilibrium decision), the runs diverge
chaotically. Here each term is added EXACTLY into an integer accumulator, so the result depends
only on the multiset of terms, never on their order or on how they are split between ranks.

Layout: one accumulator is ``NLIMB`` int64 limbs of 32 bits each; limb ``l`` weighs
``2^(32 l - OFFSET)``, which covers every finite double (2^-1074 .. 2^1024) with room for carries.
A term ``m 2^e`` (53-bit integer mantissa ``m``) lands in three consecutive limbs, each addition
below 2^33 in magnitude, so about 2^30 terms can be added before ``normalize`` is needed (the
callers normalize after every loop). ``normalize`` brings limbs ``0 .. NLIMB-2`` into
``[0, 2^32)`` with a signed top limb: the canonical form of the integer, so equal sums have equal
limbs, and limbs below 2^32 are exact in float64 (a float ``MPI_SUM`` of up to 2^20 ranks' limbs
is exact in any order: ``pardem.parallel.exact_sum``). ``to_float`` rounds the canonical form to
float64 (faithfully, within one ulp), a function of the exact value only.

Non-finite terms (NaN, inf) are not representable: ``add`` skips them and returns False, and the
callers report such a sum as NaN (a blown-up run is caught by the stability check anyway).

All kernels are pure Numba functions over arrays (no MPI).
"""
import math

import numpy as np
from numba import njit

from pardem.physics.timestep import touching_stiffness

LIMB_BITS = 32
OFFSET = 1130          # bit 0 of limb 0 weighs 2^-OFFSET (below 2^-1074 - 53)
NLIMB = 70             # 70 * 32 = 2240 bits > OFFSET + 1024 + carry room
_M32 = (1 << 32) - 1
_TWO53 = 9007199254740992.0


@njit(cache=True, inline="always", error_model="numpy")
def add(acc, k, v):
    """Add the float ``v`` exactly to accumulator row ``acc[k]`` [NLIMB] int64. Returns False (and
    adds nothing) when ``v`` is NaN or infinite."""
    if v == 0.0:
        return True
    if not (v - v == 0.0):      # NaN or inf
        return False
    m, e = math.frexp(v)        # v = m 2^e, 0.5 <= |m| < 1
    mant = np.int64(m * _TWO53)   # exact: |mant| < 2^53
    pos = e - 53 + OFFSET
    s = np.int64(1)
    if mant < 0:
        s = np.int64(-1)
        mant = -mant
    idx = pos >> 5
    sh = pos & 31
    lo = (mant & _M32) << sh     # < 2^63
    hi = (mant >> 32) << sh      # < 2^52
    acc[k, idx] += s * (lo & _M32)
    acc[k, idx + 1] += s * ((lo >> 32) + (hi & _M32))
    acc[k, idx + 2] += s * (hi >> 32)
    return True


@njit(cache=True, error_model="numpy")
def normalize(acc):
    """Canonical form of every row of ``acc`` [K, NLIMB] in place (limbs below the top in
    ``[0, 2^32)``, the top one signed)."""
    for k in range(acc.shape[0]):
        for l in range(NLIMB - 1):
            c = acc[k, l] >> 32          # floor division by 2^32 (arithmetic shift)
            acc[k, l] -= c << 32
            acc[k, l + 1] += c


@njit(cache=True, error_model="numpy")
def _row_to_float(acc, k, work):
    """float64 of canonical row ``k`` (``work`` [NLIMB] int64 scratch)."""
    neg = acc[k, NLIMB - 1] < 0
    for l in range(NLIMB):
        work[l] = -acc[k, l] if neg else acc[k, l]
    if neg:   # renormalize the magnitude (digits back into [0, 2^32))
        for l in range(NLIMB - 1):
            c = work[l] >> 32
            work[l] -= c << 32
            work[l + 1] += c
    t = NLIMB - 1
    while t >= 0 and work[t] == 0:
        t -= 1
    if t < 0:
        return 0.0
    # the top three limbs (at least 65 significant bits) carry the value to within an ulp; the
    # limbs below can only matter for ties, which a faithful rounding may settle either way
    # (deterministically: a function of the canonical limbs)
    r = float(work[t])
    for l in range(t - 1, max(t - 3, -1), -1):
        r = r * 4294967296.0 + float(work[l])
    low = max(t - 2, 0)
    r = math.ldexp(r, LIMB_BITS * low - OFFSET)
    return -r if neg else r


@njit(cache=True, error_model="numpy")
def to_float(acc, out):
    """``out[k]`` = float64 of canonical row ``acc[k]`` (call ``normalize`` first)."""
    work = np.empty(NLIMB, dtype=np.int64)
    for k in range(acc.shape[0]):
        out[k] = _row_to_float(acc, k, work)


@njit(cache=True, error_model="numpy")
def add_columns(values, n, acc):
    """Add ``values[:n, k]`` exactly to ``acc[k]`` for every column k ([n, K] float64); returns
    False if a value was not finite (then the sums are not valid). Normalizes ``acc``."""
    ok = True
    for r in range(n):
        for k in range(values.shape[1]):
            ok &= add(acc, k, values[r, k])
    normalize(acc)
    return ok


@njit(cache=True, error_model="numpy")
def power_terms(v, f, n_owned, acc):
    """FIRE's ``(F . v, |v|^2, |F|^2)`` over the owned rows, exactly, into ``acc`` [3, NLIMB]
    (each product rounded once per component, as ``physics.fire.power_sums`` does). Returns
    False on a non-finite term."""
    ok = True
    for k in range(n_owned):
        for d in range(3):
            ok &= add(acc, 0, f[k, d] * v[k, d])
            ok &= add(acc, 1, v[k, d] * v[k, d])
            ok &= add(acc, 2, f[k, d] * f[k, d])
    normalize(acc)
    return ok


@njit(cache=True, error_model="numpy")
def kinetic_terms(v, w, mass, inertia, n_owned, acc):
    """Kinetic energy of the owned rows [J], each element's term as in
    ``physics.verlet.kinetic_energy``, summed exactly into ``acc`` [1, NLIMB]."""
    ok = True
    for k in range(n_owned):
        ok &= add(acc, 0, 0.5 * mass[k] * (v[k, 0] ** 2 + v[k, 1] ** 2 + v[k, 2] ** 2))
        ok &= add(acc, 0, 0.5 * inertia[k] * (w[k, 0] ** 2 + w[k, 1] ** 2 + w[k, 2] ** 2))
    normalize(acc)
    return ok


@njit(cache=True, error_model="numpy")
def affine_stiffness_terms(pi, pj, shift, periodic, x, radius, n_owned, k_constant, k_hertz, acc):
    """``kd2 = sum k |d|^2`` [N m] of ``timestep.contact_stiffness`` (same per-pair arithmetic),
    over the touching pairs whose ``i`` is owned, exactly into ``acc`` [1, NLIMB]."""
    ok = True
    s0 = s1 = s2 = 0.0
    for p in range(pi.shape[0]):
        i = pi[p]
        if i >= n_owned:
            continue
        j = pj[p]
        if periodic:
            s0, s1, s2 = shift[p, 0], shift[p, 1], shift[p, 2]
        k, dist2 = touching_stiffness(i, j, s0, s1, s2, x, radius, k_constant, k_hertz)
        if k < 0.0:
            continue
        ok &= add(acc, 0, k * dist2)
    normalize(acc)
    return ok


def zeros(k):
    """A fresh accumulator of ``k`` sums [k, NLIMB] int64."""
    return np.zeros((int(k), NLIMB), dtype=np.int64)


def value(acc):
    """float64 values [K] of the (normalized) accumulator rows."""
    out = np.empty(acc.shape[0])
    to_float(acc, out)
    return out
