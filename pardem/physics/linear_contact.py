"""Linear spring-dashpot contact with tangential history and Coulomb friction. docs/physics.md section 8.

Kinematics, sign conventions, the history carry and the output layout are those of
``pardem.physics.contact_frame`` (normal ``n`` from i to j, history ``h`` = elastic tangential force
on i, ``u`` = velocity of i's contact point relative to j's, ``u . n = d(delta)/dt``).

Laws
----
* normal: ``fn = kn delta + cn d(delta)/dt``, clipped at zero (repulsive only, no tension);
* tangential: ``dh = -kt ds`` (incremental spring, ``ds = u_t dt``), ``|h| <= mu fn``; the force on i
  is ``ft = h - ct u_t``, also capped at ``mu fn``. (docs/physics.md writes ``+ ct v_t``: with ``v_t`` the
  sliding velocity of the partner; the damping always opposes the sliding of the element it acts on.)
* ``cn = 2 zeta_n sqrt(kn m*)``, ``ct = 2 zeta_t sqrt(kt m*)``, ``m* = m_i m_j / (m_i + m_j)``.

Damping ratio from the restitution coefficient ``e``
---------------------------------------------------
With ``omega0 = sqrt(kn / m*)`` the overlap obeys ``delta'' + 2 zeta omega0 delta' + omega0^2 delta = 0``.
The textbook relation ``zeta = -ln e / sqrt(pi^2 + ln^2 e)`` assumes the contact ends at
``delta = 0``, where the dashpot pulls (tension). With the no-tension clip the contact ends earlier,
when ``kn delta + cn delta' = 0``, i.e. at ``omega t = pi - 2 asin(zeta)``, and the rebound speed is then
exactly ``v0 exp(-omega0 zeta t)``::

    e(zeta) = exp(-zeta (pi - 2 asin zeta) / sqrt(1 - zeta^2))        zeta < 1
            = exp(-2)                                                  zeta = 1
            = exp(-2 zeta acosh(zeta) / sqrt(zeta^2 - 1))              zeta > 1

(Schwager and Poeschel 2007). ``damping_ratio(e)`` inverts it (bisection); this is what ``Params`` uses,
so the clipped contact has restitution ``e``. The textbook ``zeta`` would give ``e = 0.902, 0.550,
0.253`` instead of 0.9, 0.5, 0.1 (``textbook_damping_ratio`` is kept for comparison). Below
``e = exp(-2) = 0.135`` the normal dashpot is overdamped (``zeta > 1``); the explicit step must then
also resolve ``1 / (zeta omega0)``.
The tangential damping ratio ``zeta_t`` defaults to ``zeta_n``.

Energy
------
Returned per call: ``sum 1/2 kn delta^2 + |h|^2 / (2 kt)`` [J] (the elastic springs only).

References
----------
Cundall P.A., Strack O.D.L., Geotechnique 29 (1979) 47.
Schwager T., Poeschel T., Granular Matter 9 (2007) 465 ("Coefficient of restitution and linear-dashpot
model revisited").
"""
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numba import njit

from pardem.physics.contact_frame import (NO_RATE, NO_SHIFT, add_love_weber, affine_motion,
                                          check_pairs, clear_history, contact_geometry, coulomb_cap,
                                          pair_separation, relative_motion, scatter_pair,
                                          update_history, write_pair)


def restitution(zeta):
    """Restitution coefficient of the no-tension linear spring-dashpot with damping ratio ``zeta``."""
    z = float(zeta)
    if z < 0.0:
        raise ValueError(f"damping ratio must be >= 0, got {z}")
    if z == 0.0:
        return 1.0
    if abs(z - 1.0) < 1e-8:   # both branches tend to exp(-2); avoid 0/0
        return float(np.exp(-2.0 - 4.0 / 3.0 * (z - 1.0)))
    if z < 1.0:
        return float(np.exp(-z * (np.pi - 2.0 * np.arcsin(z)) / np.sqrt(1.0 - z * z)))
    return float(np.exp(-2.0 * z * np.arccosh(z) / np.sqrt(z * z - 1.0)))


@lru_cache(maxsize=64)
def damping_ratio(e):
    """Damping ratio ``zeta`` giving restitution ``e`` in (0, 1] with the no-tension clip (exact)."""
    e = float(e)
    if not 0.0 < e <= 1.0:
        raise ValueError(f"restitution must be in (0, 1], got {e}")
    if e == 1.0:
        return 0.0
    lo, hi = 0.0, 1.0
    while restitution(hi) > e:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if restitution(mid) > e:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-15 * hi:
            break
    return 0.5 * (lo + hi)


def textbook_damping_ratio(e):
    """``-ln e / sqrt(pi^2 + ln^2 e)``: exact only if the dashpot may pull at the end of contact."""
    le = np.log(float(e))
    return float(-le / np.sqrt(np.pi**2 + le * le))


@dataclass(frozen=True)
class Params:
    """Linear spring-dashpot parameters.

    kn, kt : normal and tangential stiffness [N/m] (> 0).
    friction : Coulomb coefficient ``mu >= 0``.
    restitution : normal restitution coefficient in (0, 1]; sets ``zeta_n = damping_ratio(e)``.
    tangential_damping : ratio ``zeta_t`` of the tangential dashpot (default: ``zeta_n``).
    Derived (read only): zeta_n, zeta_t, damped (False compiles the undamped kernel).
    """
    kn: float
    kt: float
    friction: float = 0.5
    restitution: float = 1.0
    tangential_damping: float = None
    zeta_n: float = field(init=False)
    zeta_t: float = field(init=False)
    damped: bool = field(init=False)

    def __post_init__(self):
        for name in ("kn", "kt"):
            val = getattr(self, name)
            if not (np.isfinite(val) and val > 0.0):
                raise ValueError(f"linear_contact.{name} must be a positive stiffness [N/m], got {val}")
        if not (np.isfinite(self.friction) and self.friction >= 0.0):
            raise ValueError(f"linear_contact.friction must be >= 0, got {self.friction}")
        if not (0.0 < self.restitution <= 1.0):
            raise ValueError(f"linear_contact.restitution must be in (0, 1], got {self.restitution}")
        zn = damping_ratio(self.restitution)
        zt = zn if self.tangential_damping is None else float(self.tangential_damping)
        if not (np.isfinite(zt) and zt >= 0.0):
            raise ValueError(f"linear_contact.tangential_damping must be >= 0, got {zt}")
        object.__setattr__(self, "zeta_n", zn)
        object.__setattr__(self, "zeta_t", zt)
        object.__setattr__(self, "damped", zn > 0.0 or zt > 0.0)


@njit(cache=True, inline="always", error_model="numpy")
def linear_pair(p, i, j, s0, s1, s2, g0, g1, g2, x, v, w, radius, mass, hist, dt, kn, kt, mu, zeta_n, zeta_t,
                out, damped, deforming):
    """Contact of rows i and j (image shift ``s`` [m] added to ``x_j``), history row ``hist[p]``.

    ``g`` [1/s]: diagonal strain rate of a deforming periodic cell (velocities are then the
    fluctuations about the affine field, see ``contact_frame.affine_motion``).

    Writes ``out[9]`` = (F_i, T_i, T_j) and updates ``hist[p]`` when the spheres touch; clears
    ``hist[p]`` otherwise. ``damped`` and ``deforming`` must be compile-time constants. Returns
    ``(touching, elastic energy [J])``.
    """
    d0, d1, d2, dist2, ri, rj, rsum = pair_separation(i, j, s0, s1, s2, x, radius)
    if dist2 >= rsum * rsum:
        clear_history(hist, p)
        return False, 0.0
    n0, n1, n2, delta, li, lj = contact_geometry(d0, d1, d2, dist2, ri, rj, rsum)
    un, ut0, ut1, ut2, spin = relative_motion(i, j, v, w, n0, n1, n2, li, lj)
    if deforming:
        un, ut0, ut1, ut2 = affine_motion(un, ut0, ut1, ut2, d0, d1, d2, n0, n1, n2, g0, g1, g2)
    fn = kn * delta
    m_star = mass[i] * mass[j] / (mass[i] + mass[j])
    if damped:
        fn += 2.0 * zeta_n * np.sqrt(kn * m_star) * un
        if fn < 0.0:
            fn = 0.0
    cap = mu * fn
    h0, h1, h2 = update_history(hist, p, n0, n1, n2, ut0, ut1, ut2, spin, dt, kt, cap)
    energy = 0.5 * kn * delta * delta + 0.5 * (h0 * h0 + h1 * h1 + h2 * h2) / kt
    if damped:
        ct = 2.0 * zeta_t * np.sqrt(kt * m_star)
        f0, f1, f2 = coulomb_cap(h0 - ct * ut0, h1 - ct * ut1, h2 - ct * ut2, cap)
        write_pair(out, n0, n1, n2, fn, f0, f1, f2, li, lj)
    else:
        write_pair(out, n0, n1, n2, fn, h0, h1, h2, li, lj)
    return True, energy


def _pair_loop(damped, periodic, deforming, with_energy=True):
    """Loop over a pair list; ``damped``, ``periodic`` (image shifts are read), ``deforming``
    (the cell's strain rate is read) and ``with_energy`` (the energy is summed) are frozen as
    compile-time constants."""
    @njit(cache=True, error_model="numpy")
    def loop(pi, pj, shift, rate, x, v, w, radius, mass, f, t, hist, dt, kn, kt, mu, zeta_n, zeta_t,
             n_owned, acc):
        out = np.empty(9)
        energy = 0.0
        s0 = s1 = s2 = 0.0
        g0 = g1 = g2 = 0.0
        # Love-Weber sums in registers (an array accumulator would be stored every pair, since
        # the compiler cannot prove it does not alias f and t)
        a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
        count = 0
        if deforming:
            g0, g1, g2 = rate[0], rate[1], rate[2]
        for p in range(pi.shape[0]):
            i = pi[p]
            j = pj[p]
            if periodic:
                s0 = shift[p, 0]
                s1 = shift[p, 1]
                s2 = shift[p, 2]
            touching, e = linear_pair(p, i, j, s0, s1, s2, g0, g1, g2, x, v, w, radius, mass, hist,
                                      dt, kn, kt, mu, zeta_n, zeta_t, out, damped, deforming)
            if touching:
                scatter_pair(i, j, f, t, out)
                if i < n_owned:   # counted once over the ranks (the owner of the lower gid)
                    if with_energy:
                        energy += e
                    b0 = (x[j, 0] - x[i, 0]) + s0
                    b1 = (x[j, 1] - x[i, 1]) + s1
                    b2 = (x[j, 2] - x[i, 2]) + s2
                    a00 += b0 * out[0]
                    a01 += b0 * out[1]
                    a02 += b0 * out[2]
                    a10 += b1 * out[0]
                    a11 += b1 * out[1]
                    a12 += b1 * out[2]
                    a20 += b2 * out[0]
                    a21 += b2 * out[1]
                    a22 += b2 * out[2]
                    count += 1
        add_love_weber(acc, a00, a01, a02, a10, a11, a12, a20, a21, a22, count)
        return energy
    return loop


def _all_pairs_loop(damped):
    """Brute-force O(n^2) loop over every pair ``i < j`` of all rows (test oracle)."""
    @njit(cache=True, error_model="numpy")
    def loop(x, v, w, radius, mass, f, t, hist_full, dt, kn, kt, mu, zeta_n, zeta_t):
        out = np.empty(9)
        energy = 0.0
        n = x.shape[0]
        for i in range(n):
            hist_i = hist_full[i]
            for j in range(i + 1, n):
                touching, e = linear_pair(j, i, j, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, x, v, w, radius,
                                          mass, hist_i, dt, kn, kt, mu, zeta_n, zeta_t, out, damped,
                                          False)
                if touching:
                    scatter_pair(i, j, f, t, out)
                    energy += e
        return energy
    return loop


@lru_cache(maxsize=None)
def pair_loop(damped, periodic, deforming=False, with_energy=True):
    """The compiled pair-list kernel for one sub-model choice (built once per choice).

    ``loop(i, j, shift, rate, x, v, w, radius, mass, f, t, history, dt, kn, kt, mu, zeta_n, zeta_t,
    n_owned, acc)``: same contract as ``hertz_mindlin.pair_loop``.
    """
    return _pair_loop(bool(damped), bool(periodic), bool(deforming), bool(with_energy))


@lru_cache(maxsize=None)
def all_pairs_loop(damped):
    """``loop(x, v, w, radius, mass, f, t, history_full, dt, kn, kt, mu, zeta_n, zeta_t)`` over all
    row pairs, history ``[n, n, 3]`` indexed ``[i, j]`` with ``i < j`` (test oracle)."""
    return _all_pairs_loop(bool(damped))


def cutoff(params, rmax):
    """Largest centre distance at which two spheres of radius <= ``rmax`` [m] interact [m]."""
    return 2.0 * float(rmax)


def normal_stiffness(params):
    """``(k_constant, k_hertz)`` of ``timestep.contact_stiffness``: the constant ``kn`` [N/m]."""
    return float(params.kn), 0.0


def compute(params, elements, i, j, history, dt, shift=None, rate=None, acc=None, with_energy=True):
    """Add the contact forces of the pairs ``(i[p], j[p])`` to ``elements.f``/``elements.t``.

    Same arguments as ``hertz_mindlin.compute``. Returns the elastic energy [J] (NaN when not
    ``with_energy``).
    """
    check_pairs(i, j, history, shift)
    e, p = elements, params
    loop = pair_loop(p.damped, shift is not None, rate is not None and bool(np.any(rate != 0.0)),
                     with_energy)
    energy = loop(i, j, NO_SHIFT if shift is None else shift, NO_RATE if rate is None else rate,
                  e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, history, float(dt), p.kn, p.kt,
                  p.friction, p.zeta_n, p.zeta_t, e.n_owned, np.zeros(10) if acc is None else acc)
    return energy if with_energy else float("nan")


def compute_all_pairs(params, elements, history_full, dt):
    """Brute-force version of ``compute`` over all row pairs, history ``[n, n, 3]`` (tests)."""
    e, p = elements, params
    return all_pairs_loop(p.damped)(e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, history_full,
                                    float(dt), p.kn, p.kt, p.friction, p.zeta_n, p.zeta_t)


def single(params, elements, i, j, history_row, dt, shift=(0.0, 0.0, 0.0)):
    """Diagnostics of one pair, nothing modified: dict with ``force_i``, ``torque_i``, ``torque_j``,
    ``history`` (the value the step would store), ``energy`` and ``touching``."""
    e, p = elements, params
    hist = np.array(history_row, dtype=np.float64).reshape(1, 3)
    out = np.zeros(9)
    s = np.asarray(shift, dtype=np.float64)
    touching, energy = _single_kernel(i, j, s, e.x, e.v, e.w, e.radius, e.mass, hist, float(dt),
                                      p.kn, p.kt, p.friction, p.zeta_n, p.zeta_t, out, p.damped)
    return {"touching": bool(touching), "force_i": out[0:3].copy(), "torque_i": out[3:6].copy(),
            "torque_j": out[6:9].copy(), "history": hist[0].copy(), "energy": float(energy)}


@njit(cache=True, error_model="numpy")
def _single_kernel(i, j, s, x, v, w, radius, mass, hist, dt, kn, kt, mu, zeta_n, zeta_t, out, damped):
    if damped:
        return linear_pair(0, i, j, s[0], s[1], s[2], 0.0, 0.0, 0.0, x, v, w, radius, mass, hist,
                           dt, kn, kt, mu, zeta_n, zeta_t, out, True, False)
    return linear_pair(0, i, j, s[0], s[1], s[2], 0.0, 0.0, 0.0, x, v, w, radius, mass, hist, dt,
                       kn, kt, mu, zeta_n, zeta_t, out, False, False)
