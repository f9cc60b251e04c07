"""Hertz-Mindlin contact plus an elastic-plastic rolling resistance torque (docs/physics.md section 8).

The forces are exactly those of ``pardem.physics.hertz_mindlin`` (plain, uncemented: the same
per-pair function ``hertz_mindlin_forces``, the same bits); this law adds a torque, equal and
opposite on the two grains and without force: the elastic-plastic spring (EPSD, "type C") rolling
resistance of Ai, Chen, Rotter & Ooi (2011).

Rolling resistance
------------------
Relative rolling angular velocity ``w_r = (w_i - w_j) - ((w_i - w_j) . n) n`` [rad/s] (the twist
about the normal ``n`` left out). The spring torque on i, ``M`` [N m], is incremental like the
Mindlin force: per step it is carried into the current contact plane (``contact_frame.carry_force``:
normal component removed, turned by the pair's mean spin about ``n``, former magnitude kept), then::

    M <- M - k_r w_r dt,        |M| <= mu_r R* fn   (scaled back onto the cap: rolling "slip")

with ``R* = R_i R_j / (R_i + R_j)``, ``fn`` the pair's Hertz normal force of the step (damping
included, as for the Coulomb cap) and ``k_r`` [N m/rad] the rolling stiffness: ``rolling_stiffness``
when given, else ``k_t R*^2`` with ``k_t = 8 G* a`` the Mindlin stiffness at the current contact
radius ``a = sqrt(R* delta)`` (Ai et al.'s choice following Iwashita & Oda). Grain i gets ``+M``, j
gets ``-M``. The dashpot of Ai et al.'s model is left out (``eta_r = 0``): the spring dissipates by
rolling slip only. A pair that stops touching forgets its torque (like the Mindlin force).

The returned energy adds the rolling spring's ``|M|^2 / (2 k_r)`` [J] (a state measure, like the
Mindlin part).

How the torque reaches the shared loops
---------------------------------------
``pair_loop``'s ``forces`` sees the contact-point velocity and the mean spin only (not ``w_i - w_j``)
and returns a force (the loop derives both torques from it), so the rolling torque is a second pass
over the same pairs, run by this module's ``compute``, ``compute_all_pairs`` and ``single`` right
after the shared ones: the Hertz-Mindlin pass also stores the step's normal force in the history
(column 6, the cap of the rolling spring), the rolling pass recomputes the pair's geometry with
``contact_frame`` (the same bits as the loop, so the same pairs touch) and adds ``+M``, ``-M`` in
pair order.

History row, ``history_width = 7`` columns::

    0:3  Mindlin tangential force on i [N] (as hertz_mindlin)
    3:6  rolling spring torque on i [N m]
    6    normal force fn of the last evaluation [N] (the rolling cap; rewritten every step)

References
----------
Ai J., Chen J.-F., Rotter J.M., Ooi J.Y., Assessment of rolling resistance models in discrete
element simulations, Powder Technol. 206 (2011) 269-282 (model C, EPSD).
Iwashita K., Oda M., J. Eng. Mech. 124 (1998) 285.
"""
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numba import njit

from pardem.physics import hertz_mindlin as hm
from pardem.physics.contact_frame import (NO_SHIFT, carry_force, contact_geometry, coulomb_cap,
                                          pair_separation)
from pardem.physics.exact_accumulate import add as exact_add
from pardem.physics.exact_accumulate import normalize as exact_normalize
from pardem.physics.hertz_mindlin import hertz_mindlin_forces, mindlin_stiffness
from pardem.physics.pair_loop import law_interface, touching

WIDTH = 7      # history columns (module docstring)
ROLL = 3       # columns 3:6, rolling spring torque on i [N m]
NORMAL = 6     # normal force of the last evaluation [N]


@dataclass(frozen=True)
class Params:
    """Hertz-Mindlin with rolling resistance.

    young [Pa], poisson, friction, restitution, young2, poisson2 : as ``hertz_mindlin.Params``
        (checked there; no cement).
    rolling_friction : ``mu_r >= 0`` (dimensionless): the torque is capped at ``mu_r R* fn``
        (0: no rolling resistance, the forces and torques of hertz_mindlin).
    rolling_stiffness : ``k_r`` [N m/rad] > 0, or None for ``k_t R*^2`` (module docstring).
    Derived (read only): hertz (the ``hertz_mindlin.Params``), e_star, g_star [Pa], gamma, damped.
    """
    young: float
    poisson: float
    rolling_friction: float
    friction: float = 0.5
    restitution: float = 1.0
    young2: float = None
    poisson2: float = None
    rolling_stiffness: float = None
    hertz: hm.Params = field(init=False)
    e_star: float = field(init=False)
    g_star: float = field(init=False)
    gamma: float = field(init=False)
    damped: bool = field(init=False)

    def __post_init__(self):
        mu_r = self.rolling_friction
        if isinstance(mu_r, bool) or not isinstance(mu_r, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(mu_r) and mu_r >= 0.0):
            raise ValueError(f"hertz_mindlin_rolling.rolling_friction must be a number >= 0, got {mu_r!r}")
        k_r = self.rolling_stiffness
        if k_r is not None and (isinstance(k_r, bool)
                                or not isinstance(k_r, (int, float, np.integer, np.floating))
                                or not (np.isfinite(k_r) and k_r > 0.0)):
            raise ValueError(f"hertz_mindlin_rolling.rolling_stiffness must be a number > 0 [N m/rad] "
                             f"or None (k_t R*^2), got {k_r!r}")
        hertz = hm.Params(self.young, self.poisson, friction=self.friction,
                          restitution=self.restitution, young2=self.young2, poisson2=self.poisson2)
        object.__setattr__(self, "hertz", hertz)
        for name in ("e_star", "g_star", "gamma", "damped"):
            object.__setattr__(self, name, getattr(hertz, name))


def history_width(params):
    """Columns of a pair's history row: 7 (module docstring)."""
    return WIDTH


def persistent_rows(history):
    """No row outlives its contact (no cohesion)."""
    return np.zeros(len(history), dtype=bool)


# ---------------------------------------------------------------------------------------------
# the Hertz-Mindlin pass: hertz_mindlin's own per-pair function, plus the normal force stored

@lru_cache(maxsize=None)
def _law_function(damped):
    """The ``pair_loop.forces`` of the law, ``c = (E*, G*, mu, gamma, mu_r, k_r)``."""
    @njit(cache=True, inline="always", error_model="numpy")
    def forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0, ut1, ut2, spin, mass, hist, dt, c):
        e_star, g_star, mu, gamma, mu_r, k_r = c
        fn, h0, h1, h2, energy = hertz_mindlin_forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un,
                                                      ut0, ut1, ut2, spin, mass, hist, dt, e_star,
                                                      g_star, mu, gamma, damped)
        hist[p, NORMAL] = fn
        return True, fn, h0, h1, h2, energy
    return forces, touching


def pair_function(params):
    """``(forces, engaged)`` of ``pair_loop`` for these parameters (damping chosen here)."""
    return _law_function(bool(params.damped))


def constants(params, dt):
    """``(E*, G*, mu, gamma, mu_r, k_r)``; ``k_r = 0`` stands for ``k_t R*^2``."""
    k_r = 0.0 if params.rolling_stiffness is None else float(params.rolling_stiffness)
    return hm.constants(params.hertz, dt) + (float(params.rolling_friction), k_r)


def reads_mass(params):
    """Whether ``forces`` reads the grains' masses: only the damping does."""
    return bool(params.damped)


_hm_compute, _hm_all_pairs, _hm_single = law_interface(pair_function, constants, history_width,
                                                       reads_mass)


# ---------------------------------------------------------------------------------------------
# the rolling pass

@njit(cache=True, inline="always", error_model="numpy")
def rolling_torque(i, j, s0, s1, s2, x, w, radius, hist, p, dt, g_star, mu_r, k_fixed):
    """Update the rolling spring of pair ``(i, j)`` (history row ``hist[p]``, image shift ``s``
    [m]) and return ``(touching, M0, M1, M2 [N m] torque on i, energy [J])``; ``k_fixed`` [N m/rad]
    the rolling stiffness, 0 for ``k_t R*^2``. A pair apart has its rolling columns cleared."""
    d0, d1, d2, dist2, ri, rj, rsum = pair_separation(i, j, s0, s1, s2, x, radius)
    if not dist2 < rsum * rsum:      # as pair_loop.touching: the same pairs act
        hist[p, ROLL] = 0.0
        hist[p, ROLL + 1] = 0.0
        hist[p, ROLL + 2] = 0.0
        hist[p, NORMAL] = 0.0
        return False, 0.0, 0.0, 0.0, 0.0
    n0, n1, n2, delta, li, lj = contact_geometry(d0, d1, d2, dist2, ri, rj, rsum)
    r_star = ri * rj / rsum
    k_r = k_fixed
    if k_r == 0.0:
        k_r = mindlin_stiffness(g_star, np.sqrt(r_star * delta)) * r_star * r_star
    r0 = w[i, 0] - w[j, 0]
    r1 = w[i, 1] - w[j, 1]
    r2 = w[i, 2] - w[j, 2]
    rn = r0 * n0 + r1 * n1 + r2 * n2
    spin = 0.5 * ((w[i, 0] + w[j, 0]) * n0 + (w[i, 1] + w[j, 1]) * n1 + (w[i, 2] + w[j, 2]) * n2)
    m0, m1, m2 = carry_force(hist[p, ROLL], hist[p, ROLL + 1], hist[p, ROLL + 2], n0, n1, n2,
                             spin * dt)
    k = k_r * dt
    m0, m1, m2 = coulomb_cap(m0 - k * (r0 - rn * n0), m1 - k * (r1 - rn * n1),
                             m2 - k * (r2 - rn * n2), mu_r * r_star * hist[p, NORMAL])
    hist[p, ROLL] = m0
    hist[p, ROLL + 1] = m1
    hist[p, ROLL + 2] = m2
    return True, m0, m1, m2, 0.5 * (m0 * m0 + m1 * m1 + m2 * m2) / k_r


@njit(inline="always", cache=True)
def _opposite_torques(t, i, j, m0, m1, m2):
    """The rolling torque (m0, m1, m2) [N m] on row ``i`` and its opposite on row ``j``."""
    t[i, 0] += m0
    t[i, 1] += m1
    t[i, 2] += m2
    t[j, 0] -= m0
    t[j, 1] -= m1
    t[j, 2] -= m2


@njit(cache=True, error_model="numpy")
def _rolling_list(pi, pj, shift, periodic, x, w, radius, t, hist, dt, g_star, mu_r, k_fixed,
                  n_owned, with_energy, exact, xacc):
    """The rolling pass over a pair list, torques added in pair order; returns the energy [J] of
    the pairs whose ``i`` is owned (exactly into ``xacc[9]`` when ``exact``) and whether every
    term was finite."""
    energy = 0.0
    ok = True
    s0 = s1 = s2 = 0.0
    for p in range(pi.shape[0]):
        i = pi[p]
        j = pj[p]
        if periodic:
            s0 = shift[p, 0]
            s1 = shift[p, 1]
            s2 = shift[p, 2]
        acts, m0, m1, m2, e = rolling_torque(i, j, s0, s1, s2, x, w, radius, hist, p, dt, g_star,
                                             mu_r, k_fixed)
        if not acts:
            continue
        _opposite_torques(t, i, j, m0, m1, m2)
        if with_energy and i < n_owned:
            if exact:
                ok &= exact_add(xacc, 9, e)
            else:
                energy += e
    if exact and with_energy:
        exact_normalize(xacc)
    return energy, ok


@njit(cache=True, error_model="numpy")
def _rolling_all_pairs(x, w, radius, t, hist_full, dt, g_star, mu_r, k_fixed):
    energy = 0.0
    n = x.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            acts, m0, m1, m2, e = rolling_torque(i, j, 0.0, 0.0, 0.0, x, w, radius, hist_full[i],
                                                 j, dt, g_star, mu_r, k_fixed)
            if acts:
                _opposite_torques(t, i, j, m0, m1, m2)
                energy += e
    return energy


@njit(cache=True, error_model="numpy")
def _rolling_one(i, j, s, x, w, radius, hist, dt, g_star, mu_r, k_fixed, out):
    acts, out[0], out[1], out[2], e = rolling_torque(i, j, s[0], s[1], s[2], x, w, radius, hist, 0,
                                                     dt, g_star, mu_r, k_fixed)
    return acts, e


def _rolling_constants(params):
    c = constants(params, 0.0)
    return float(params.g_star), c[4], c[5]


def compute(params, elements, i, j, history, dt, shift=None, rate=None, acc=None, with_energy=True,
            xacc=None, with_stress=True):
    """``pair_loop.law_interface``'s ``compute`` (same arguments and return value) plus the
    rolling torques: the Hertz-Mindlin pass, then the rolling pass over the same pairs."""
    e = elements
    energy = _hm_compute(params, e, i, j, history, dt, shift, rate, acc, with_energy, xacc,
                         with_stress)
    exact = xacc is not None
    rolled, ok = _rolling_list(i, j, NO_SHIFT if shift is None else shift, shift is not None, e.x,
                               e.w, e.radius, e.t, history, float(dt), *_rolling_constants(params),
                               e.n_owned, bool(with_energy), exact,
                               xacc if exact else np.zeros((10, 1), dtype=np.int64))
    if exact:
        return energy if ok else np.nan
    return energy + rolled if with_energy else float("nan")


def compute_all_pairs(params, elements, history_full, dt):
    """Brute-force twin of ``compute`` over all row pairs, history ``[n, n, 7]`` (tests)."""
    e = elements
    energy = _hm_all_pairs(params, e, history_full, dt)
    return energy + _rolling_all_pairs(e.x, e.w, e.radius, e.t, history_full, float(dt),
                                       *_rolling_constants(params))


def single(params, elements, i, j, history_row, dt, shift=(0.0, 0.0, 0.0)):
    """Loads of one pair (diagnostics, nothing modified): the dict of ``law_interface``'s
    ``single`` with the rolling torque ``rolling_torque`` [3] [N m] on i included in ``torque_i``
    (and its opposite in ``torque_j``), ``history`` and ``energy``."""
    e = elements
    r = _hm_single(params, e, i, j, history_row, dt, shift)
    hist = r["history"].reshape(1, WIDTH).copy()
    m = np.zeros(3)
    acts, energy = _rolling_one(int(i), int(j), np.asarray(shift, dtype=np.float64), e.x, e.w,
                                e.radius, hist, float(dt), *_rolling_constants(params), m)
    if acts:
        r["torque_i"] = r["torque_i"] + m
        r["torque_j"] = r["torque_j"] - m
        r["energy"] += energy
    r["history"] = hist[0].copy()
    r["rolling_torque"] = m
    return r


# ---------------------------------------------------------------------------------------------
# the rest of the registry row (pardem.physics.contact_laws.ContactLaw)

def cutoff(params, rmax):
    """Largest centre distance at which two spheres of radius <= ``rmax`` [m] interact [m]."""
    return hm.cutoff(params.hertz, rmax)


def normal_stiffness(params):
    """``(k_constant, k_hertz)`` of the Hertz normal law (``hertz_mindlin.normal_stiffness``)."""
    return hm.normal_stiffness(params.hertz)


def critical_time_step(params, radii, density):
    """Critical step [s]: hertz_mindlin's (the Rayleigh step of the smallest sphere; the default
    ``k_r = k_t R*^2`` turns the pair no faster than the Mindlin spring does), and with a given
    ``k_r`` also ``1 / omega``, ``omega^2 = 2 k_r / I`` of two of the smallest spheres."""
    dt_c = hm.critical_time_step(params.hertz, radii, density)
    if params.rolling_stiffness is not None:
        r_min = float(np.min(radii))
        inertia = 0.4 * density * 4.0 / 3.0 * np.pi * r_min**5
        dt_c = min(dt_c, float(np.sqrt(inertia / (2.0 * params.rolling_stiffness))))
    return dt_c


def deck_params(section, auto):
    """The ``Params`` dict of a deck's ``contacts`` section: hertz_mindlin's keys plus
    ``rolling_friction`` (and optionally ``rolling_stiffness``), which a deck schema must provide
    (ValueError naming them otherwise)."""
    if "rolling_friction" not in section:
        raise ValueError("contacts.law = hertz_mindlin_rolling needs contacts.rolling_friction "
                         "(a number >= 0), which this deck's schema does not have")
    params = hm.deck_params(section, auto)
    params["rolling_friction"] = section["rolling_friction"]
    if section.get("rolling_stiffness", "auto") != "auto":
        params["rolling_stiffness"] = section["rolling_stiffness"]
    return params


def elastic_normal_force(params, r_i, r_j, delta):
    """Elastic Hertz normal force [N] [n] (``hertz_mindlin.elastic_normal_force``)."""
    return hm.elastic_normal_force(params.hertz, r_i, r_j, delta)
