"""Linear spring-dashpot contact with tangential history and Coulomb friction. docs/physics.md section 8.

Kinematics, sign conventions, the history carry and the output layout are those of
``pardem.physics.contact_frame`` (normal ``n`` from i to j, history ``h`` = elastic tangential force
on i, ``u`` = velocity of i's contact point relative to j's, ``u . n = d(delta)/dt``).
A row of ``pardem.physics.contact_laws``: the per-pair functions below (``pair_function``) run in
the shared loops of ``pardem.physics.pair_loop``.

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

from pardem.physics.arguments import keywords, real
from pardem.physics.contact_frame import coulomb_cap, update_history
from pardem.physics.pair_loop import law_interface, touching
from pardem.physics.timestep import linear_contact_time_step


def restitution(zeta):
    """Restitution coefficient of the no-tension linear spring-dashpot with damping ratio ``zeta``."""
    z = float(zeta)
    if not z >= 0.0:   # NaN too
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


@keywords("linear_contact.Params")
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
            real(f"linear_contact.{name}", getattr(self, name), lo=0.0, unit="[N/m]")
        real("linear_contact.friction", self.friction, lo=0.0, lo_open=False, note="Coulomb coefficient")
        real("linear_contact.restitution", self.restitution, lo=0.0, hi=1.0, hi_open=False)
        if self.tangential_damping is not None:
            real("linear_contact.tangential_damping", self.tangential_damping, lo=0.0, lo_open=False,
                 note="damping ratio zeta_t; None: zeta_n")
        zn = damping_ratio(self.restitution)
        zt = zn if self.tangential_damping is None else float(self.tangential_damping)
        object.__setattr__(self, "zeta_n", zn)
        object.__setattr__(self, "zeta_t", zt)
        object.__setattr__(self, "damped", zn > 0.0 or zt > 0.0)


@njit(cache=True, inline="always", error_model="numpy")
def linear_normal(kn, m_star, delta, rate, zeta_n, damped):
    """Normal force [N] of the spring-dashpot: ``kn delta`` plus, when ``damped`` (a compile-time
    constant), ``2 zeta_n sqrt(kn m*) rate`` (``rate = d(delta)/dt`` [m/s], mass ``m_star`` [kg]),
    clipped at zero."""
    fn = kn * delta
    if damped:
        fn += 2.0 * zeta_n * np.sqrt(kn * m_star) * rate
        if fn < 0.0:
            fn = 0.0
    return fn


@njit(cache=True, inline="always", error_model="numpy")
def linear_energy(kn, delta):
    """Energy ``1/2 kn delta^2`` [J] of the normal spring ``kn`` [N/m] at overlap ``delta`` [m]."""
    return 0.5 * kn * delta * delta


@njit(cache=True, inline="always", error_model="numpy")
def linear_tangential(hist, p, n0, n1, n2, ut0, ut1, ut2, spin, dt, kt, m_star, zeta_t, cap, damped):
    """Tangential spring ``kt`` [N/m] on the history ``hist[p]`` (carried by ``spin * dt`` about
    ``n``, Coulomb cap ``cap`` [N], ``contact_frame.update_history``) and, when ``damped``, the
    dashpot ``-2 zeta_t sqrt(kt m*) u_t`` added and the sum capped again. Returns ``(h0, h1, h2,
    f0, f1, f2)``: the stored spring force and the applied tangential force [N]."""
    h0, h1, h2 = update_history(hist, p, n0, n1, n2, ut0, ut1, ut2, spin, dt, kt, cap)
    f0, f1, f2 = h0, h1, h2
    if damped:
        ct = 2.0 * zeta_t * np.sqrt(kt * m_star)
        f0, f1, f2 = coulomb_cap(h0 - ct * ut0, h1 - ct * ut1, h2 - ct * ut2, cap)
    return h0, h1, h2, f0, f1, f2


def _forces(damped):
    """The ``pair_loop.forces`` of the law, ``c = (kn, kt, mu, zeta_n, zeta_t)``."""
    @njit(cache=True, inline="always", error_model="numpy")
    def forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0, ut1, ut2, spin, mass, hist, dt, c):
        kn, kt, mu, zeta_n, zeta_t = c
        m_star = mass[i] * mass[j] / (mass[i] + mass[j])
        fn = linear_normal(kn, m_star, delta, un, zeta_n, damped)
        h0, h1, h2, f0, f1, f2 = linear_tangential(hist, p, n0, n1, n2, ut0, ut1, ut2, spin, dt, kt,
                                                   m_star, zeta_t, mu * fn, damped)
        energy = linear_energy(kn, delta) + 0.5 * (h0 * h0 + h1 * h1 + h2 * h2) / kt
        return True, fn, f0, f1, f2, energy
    return forces


@lru_cache(maxsize=None)
def _law_function(damped):
    return _forces(damped), touching


def pair_function(params):
    """``(forces, engaged)`` of ``pair_loop`` for these parameters (damping chosen here)."""
    return _law_function(bool(params.damped))


def constants(params, dt):
    """The ``c`` tuple of ``pair_function(params)``: ``(kn, kt, mu, zeta_n, zeta_t)``."""
    p = params
    return (float(p.kn), float(p.kt), float(p.friction), float(p.zeta_n), float(p.zeta_t))


def history_width(params):
    """Columns of a pair's history row: 3 (the tangential spring force on i [N])."""
    return 3


def persistent_rows(history):
    """Mask of the history rows a list rebuild must not drop: none (no cohesion)."""
    return np.zeros(len(history), dtype=bool)


def reads_mass(params):
    """Whether the law's ``forces`` reads the grains' masses: only its damping does."""
    return bool(params.damped)


compute, compute_all_pairs, single = law_interface(pair_function, constants, history_width,
                                                  reads_mass)


# ---------------------------------------------------------------------------------------------
# the rest of the registry row (pardem.physics.contact_laws.ContactLaw)

def cutoff(params, rmax):
    """Largest centre distance at which two spheres of radius <= ``rmax`` [m] interact [m]."""
    return 2.0 * float(rmax)


def normal_stiffness(params):
    """``(k_constant, k_hertz)`` of ``timestep.contact_stiffness``: the constant ``kn`` [N/m]."""
    return float(params.kn), 0.0


def critical_time_step(params, radii, density):
    """Critical step [s] of spheres of radii ``radii`` [m] and ``density`` [kg/m^3]: the pair of
    the smallest mass (``timestep.linear_contact_time_step``)."""
    r_min = float(np.min(radii))
    m_min = density * 4.0 / 3.0 * np.pi * r_min**3
    return linear_contact_time_step(m_min, params.kn, params.zeta_n)


def deck_params(section, auto):
    """The ``Params`` dict of a deck's ``contacts`` section (``kn = kt = stiffness``, ``friction``,
    ``restitution``); ``auto["stiffness"]()`` [N/m] is called for ``stiffness = "auto"``."""
    k = auto["stiffness"]() if section["stiffness"] == "auto" else section["stiffness"]
    return {"kn": k, "kt": k, "friction": section["friction"], "restitution": section["restitution"]}


@njit(cache=True, error_model="numpy")
def _elastic_normal(delta, kn, out):
    for p in range(delta.shape[0]):
        out[p] = linear_normal(kn, 0.0, delta[p], 0.0, 0.0, False)


def elastic_normal_force(params, r_i, r_j, delta):
    """Elastic normal force ``kn delta`` [N] [n] of contacts at overlaps ``delta > 0`` [m] [n]
    (radii ``r_i``, ``r_j`` unused, for the common interface)."""
    out = np.empty(len(delta))
    _elastic_normal(np.ascontiguousarray(delta, dtype=np.float64), float(params.kn), out)
    return out
