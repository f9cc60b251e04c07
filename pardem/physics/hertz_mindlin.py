"""Hertz-Mindlin contact with tangential history and Coulomb friction. docs/physics.md section 8.

Kinematics, sign conventions, the history carry and the output layout are those of
``pardem.physics.contact_frame`` (normal ``n`` from i to j, history = elastic tangential force on i).

Laws
----
Overlap ``delta`` [m], ``R* = R_i R_j / (R_i + R_j)``, contact radius ``a = sqrt(R* delta)``:

* normal (Hertz): ``fn_el = 4/3 E* sqrt(R*) delta^(3/2) = 4/3 E* a delta``;
* tangential (Mindlin, no-slip stiffness, incremental): ``dft = -kt ds``, ``kt = 8 G* a``;
* Coulomb: ``|ft| <= mu fn`` (the stored force is scaled back when it exceeds the cap);
* optional normal damping (chosen at setup): ``fn = fn_el + gamma sqrt(m* Sn) d(delta)/dt`` with the
  tangent stiffness ``Sn = d fn_el / d delta = 2 E* a`` and ``m* = m_i m_j / (m_i + m_j)``; the total
  ``fn`` is clipped at zero (no tension). No tangential damping (the tangential spring dissipates
  by sliding only).

Effective moduli (``effective_moduli``), Young's modulus ``E_k`` and Poisson ratio ``nu_k`` of the grains,
``G_k = E_k / (2 (1 + nu_k))``::

    1/E* = (1 - nu_1^2)/E_1 + (1 - nu_2^2)/E_2        (different materials)
    1/G* = (2 - nu_1)/G_1  + (2 - nu_2)/G_2

so for identical grains ``E* = E / (2 (1 - nu^2)) = G / (1 - nu)`` and ``G* = G / (2 (2 - nu))``, which
gives ``kt = 8 G* a = 4 G / (2 - nu) sqrt(R* delta)``: docs/physics.md's same-material Mindlin stiffness.
(The source G writes the law with the half overlap and ``Rbar = 2 R*``; it is the same law.)

Damping coefficient
-------------------
The damped Hertz contact is scale free: with ``delta = v T X``, ``t = T tau`` and
``T = (m* / K)^(2/5) v^(-1/5)``, ``K = 4/3 E* sqrt(R*)``, it reads
``X'' = -X^(3/2) - c X^(1/4) X'`` with ``c = gamma sqrt(3/2)``, ``X(0) = 0``, ``X'(0) = 1``, so the
restitution coefficient depends on ``gamma`` only, not on the impact speed, sizes or moduli.
``hertz_damping_coefficient(e)`` solves that equation (RK4, contact ending when the clipped force
vanishes) and inverts it by bisection: the contact then has exactly the restitution ``e``.
For weak damping ``1 - e^2 = 3.4414 gamma`` (dissipation along the elastic path,
``4 sqrt(3/2) sqrt(5/4) (2/5) B(1/2, 3/2) = 3.4414``); the usual Tsuji / LIGGGHTS choice
``gamma = 2 sqrt(5/6) (-ln e) / sqrt(pi^2 + ln^2 e)`` (``tsuji_damping_coefficient``) has the same
weak-damping limit but, with the no-tension clip, rebounds at 0.902, 0.550, 0.253 for a target
``e`` of 0.9, 0.5, 0.1.

Energy
------
Returned per call: the elastic energy ``sum 2/5 fn_el delta + |h|^2 / (2 kt)`` [J]; the normal part
``2/5 fn_el delta = 8/15 E* sqrt(R*) delta^(5/2)`` is the exact potential of the Hertz force
(``= 2/5 kn delta^2`` with the secant stiffness ``kn = fn_el / delta``). The tangential part is the
energy of the current tangential spring (the incremental Mindlin law is path dependent, so it is a
state measure, not a potential).

Cemented contacts (docs/physics.md section 8, G ch. 7)
-------------------------------------------------
With ``cement_normal = Sn > 0`` [N/m] (and ``cement_tangential = St >= 0`` [N/m]) the law is compiled
with cement terms (``Params.cemented``; the plain kernel is unchanged and carries no cement cost).
The history row then has ``history_width(params) = 9`` columns::

    0:3  h        Mindlin tangential force on i [N] (as in the plain law)
    3:6  f_ct     cement tangential force on i [N] (its own incremental history, carried in the
                  rotating contact plane like h)
    6    delta0   overlap at cementation [m] (> 0)
    7    E_th     the pair's rupture energy [J] (> 0)
    8    state    +1 intact; -s while fading (s in (0, 1] the remaining factor); 0 no cement

A pair with ``state = 0`` is a plain Hertz-Mindlin contact (its cement columns are zero, so a
broken-and-faded pair reduces to the 3-column plain state; only the zero columns remain). An intact
cement adds springs in parallel, also in tension (``delta <= 0``, the spheres apart; the Hertz part
is then zero and its history cleared)::

    fn  += Sn (delta - delta0)                (repulsive positive; tension when delta < delta0)
    f_ct = carry(f_ct) - St ds                no Coulomb cap on the cement
    ft  += f_ct

The Coulomb cap of ``h`` uses the Hertz part of ``fn`` only, so the total is exactly the plain law
plus the cement. The cement breaks at the first step where its stored elastic energy
``E_c = 1/2 Sn (delta - delta0)^2 + |f_ct|^2 / (2 St)`` exceeds ``E_th`` (that step still applies
the full cement force; ``state <- -1``). Then, for ``cement_fade_time = t_f`` [s], each step lowers
``s`` by ``dt / t_f`` and applies ``s Sn (delta - delta0)`` and ``s f_ct`` (``f_ct`` frozen at its
value at rupture, carried in the contact plane); when ``s`` reaches 0 the cement columns are cleared
(with ``t_f = 0`` on the step after rupture). The returned energy adds ``E_c`` of the intact
cements (not of the fading ones). Thresholds and ``delta0`` are set by
``pardem.engine.cement`` at cementation, not here.

References
----------
Johnson K.L., Contact Mechanics, CUP 1985, sections 4.2 (Hertz) and 7.2 (Mindlin).
Mindlin R.D., Deresiewicz H., J. Appl. Mech. 20 (1953) 327.
Tsuji Y., Tanaka T., Ishida T., Powder Technol. 71 (1992) 239 (damping form ``sqrt(m* Sn)``).
"""
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numba import njit

from pardem.physics.contact_frame import (NO_RATE, NO_SHIFT, add_love_weber, affine_motion,
                                          carry_force, check_pairs, clear_history, contact_geometry,
                                          pair_separation, relative_motion, scatter_pair,
                                          update_history, write_pair)

WIDTH_PLAIN = 3        # history columns of a plain contact (the Mindlin force)
WIDTH_CEMENTED = 9     # with cement: see the module docstring
CEMENT_FORCE = 3       # columns 3:6, cement tangential force on i [N]
CEMENT_DELTA0 = 6      # overlap at cementation [m]
CEMENT_THRESHOLD = 7   # rupture energy [J]
CEMENT_STATE = 8       # +1 intact, -s fading, 0 none


def effective_moduli(young1, poisson1, young2=None, poisson2=None):
    """``(E*, G*)`` [Pa] of a contact between grains of materials 1 and 2 (2 defaults to 1)."""
    if young2 is None:
        young2 = young1
    if poisson2 is None:
        poisson2 = poisson1
    g1 = young1 / (2.0 * (1.0 + poisson1))
    g2 = young2 / (2.0 * (1.0 + poisson2))
    e_star = 1.0 / ((1.0 - poisson1**2) / young1 + (1.0 - poisson2**2) / young2)
    g_star = 1.0 / ((2.0 - poisson1) / g1 + (2.0 - poisson2) / g2)
    return float(e_star), float(g_star)


# ---------------------------------------------------------------------------------------------
# restitution of the damped Hertz contact (setup only)

@njit(cache=True, error_model="numpy")
def _hertz_restitution(c, steps_per_unit):
    """Restitution of ``X'' = -X^1.5 - c X^0.25 X'``, ``X(0) = 0, X'(0) = 1``, force clipped at 0.

    RK4 in ``tau``; the first step starts from the series ``X = tau - 16/45 c tau^(9/4)``,
    ``X' = 1 - 4/5 c tau^(5/4)`` (the damping term is not smooth at ``X = 0``).
    """
    h = 1.0 / steps_per_unit
    tau = h
    x = tau - 16.0 / 45.0 * c * tau**2.25
    u = 1.0 - 0.8 * c * tau**1.25

    for _ in range(100 * steps_per_unit):   # the contact lasts less than 4 units
        fo = max(x, 0.0) ** 1.5 + c * max(x, 0.0) ** 0.25 * u
        xo = x
        uo = u
        x1 = max(x, 0.0)
        k1x = u
        k1u = -(x1**1.5 + c * x1**0.25 * u)
        x2 = max(x + 0.5 * h * k1x, 0.0)
        u2 = u + 0.5 * h * k1u
        k2x = u2
        k2u = -(x2**1.5 + c * x2**0.25 * u2)
        x3 = max(x + 0.5 * h * k2x, 0.0)
        u3 = u + 0.5 * h * k2u
        k3x = u3
        k3u = -(x3**1.5 + c * x3**0.25 * u3)
        x4 = max(x + h * k3x, 0.0)
        u4 = u + h * k3u
        k4x = u4
        k4u = -(x4**1.5 + c * x4**0.25 * u4)
        x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
        u += h / 6.0 * (k1u + 2.0 * k2u + 2.0 * k3u + k4u)
        tau += h
        if u < 0.0:
            if x <= 0.0:   # back at zero overlap with a positive force (no damping)
                return -(uo + (u - uo) * xo / (xo - x))
            fnew = x**1.5 + c * x**0.25 * u
            if fnew <= 0.0:   # the clipped force vanishes: the spheres separate
                return -(uo + (u - uo) * fo / (fo - fnew))
    return np.nan


@njit(cache=True, error_model="numpy")
def _calibrate(e, steps_per_unit):
    if e >= 1.0:
        return 0.0
    hi = 1.0
    while _hertz_restitution(hi * np.sqrt(1.5), steps_per_unit) > e:
        hi *= 2.0
    lo = 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _hertz_restitution(mid * np.sqrt(1.5), steps_per_unit) > e:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12 * hi:
            break
    return 0.5 * (lo + hi)


_STEPS_PER_UNIT = 5000   # RK4 steps per unit of tau: restitution converged to 1e-9


@lru_cache(maxsize=64)
def hertz_damping_coefficient(restitution):
    """``gamma`` of the damping term ``gamma sqrt(m* Sn) d(delta)/dt`` giving restitution ``e``.

    Exact for the no-tension damped Hertz contact (see the module docstring), to about 1e-9.
    """
    e = float(restitution)
    if not 0.0 < e <= 1.0:
        raise ValueError(f"restitution must be in (0, 1], got {e}")
    return float(_calibrate(e, _STEPS_PER_UNIT))


def hertz_restitution(gamma):
    """Restitution coefficient of the no-tension damped Hertz contact with coefficient ``gamma``."""
    return float(_hertz_restitution(float(gamma) * np.sqrt(1.5), _STEPS_PER_UNIT))


def tsuji_damping_coefficient(restitution):
    """The usual closed form ``gamma = 2 sqrt(5/6) (-ln e) / sqrt(pi^2 + ln^2 e)`` (approximate)."""
    le = np.log(restitution)
    return float(2.0 * np.sqrt(5.0 / 6.0) * (-le) / np.sqrt(np.pi**2 + le * le))


# ---------------------------------------------------------------------------------------------
# parameters and the per-pair law

@dataclass(frozen=True)
class Params:
    """Hertz-Mindlin contact parameters.

    young [Pa], poisson : the grains' material; young2, poisson2 : the partner's material when the
        contacts join two different materials (default: the same).
    friction : Coulomb coefficient ``mu >= 0`` (0: frictionless).
    restitution : normal restitution coefficient in (0, 1]; 1 compiles the undamped kernel.
    cement_normal, cement_tangential : cement springs Sn, St [N/m] (>= 0); Sn > 0 compiles the
        cemented kernel (module docstring); cement_fade_time [s] (>= 0): fading after rupture.
    Derived (read only): e_star, g_star [Pa], gamma (damping coefficient), damped, cemented.
    """
    young: float
    poisson: float
    friction: float = 0.5
    restitution: float = 1.0
    young2: float = None
    poisson2: float = None
    cement_normal: float = 0.0
    cement_tangential: float = 0.0
    cement_fade_time: float = 0.0
    e_star: float = field(init=False)
    g_star: float = field(init=False)
    gamma: float = field(init=False)
    damped: bool = field(init=False)
    cemented: bool = field(init=False)

    def __post_init__(self):
        for name in ("young", "young2"):
            val = getattr(self, name)
            if val is not None and not (np.isfinite(val) and val > 0.0):
                raise ValueError(f"hertz_mindlin.{name} must be a positive number [Pa], got {val}")
        for name in ("poisson", "poisson2"):
            val = getattr(self, name)
            if val is not None and not (-1.0 < val < 0.5):
                raise ValueError(f"hertz_mindlin.{name} must be in (-1, 0.5), got {val}")
        if not (np.isfinite(self.friction) and self.friction >= 0.0):
            raise ValueError(f"hertz_mindlin.friction must be >= 0, got {self.friction}")
        if not (0.0 < self.restitution <= 1.0):
            raise ValueError(f"hertz_mindlin.restitution must be in (0, 1], got {self.restitution}")
        for name in ("cement_normal", "cement_tangential", "cement_fade_time"):
            val = getattr(self, name)
            if not (np.isfinite(val) and val >= 0.0):
                raise ValueError(f"hertz_mindlin.{name} must be a number >= 0, got {val}")
        if self.cement_tangential > 0.0 and self.cement_normal == 0.0:
            raise ValueError("hertz_mindlin.cement_tangential > 0 needs cement_normal > 0 [N/m]")
        e_star, g_star = effective_moduli(self.young, self.poisson, self.young2, self.poisson2)
        object.__setattr__(self, "e_star", e_star)
        object.__setattr__(self, "g_star", g_star)
        object.__setattr__(self, "gamma", hertz_damping_coefficient(self.restitution))
        object.__setattr__(self, "damped", self.restitution < 1.0)
        object.__setattr__(self, "cemented", self.cement_normal > 0.0)


def persistent_rows(history):
    """Mask of the history rows a list rebuild must not drop: the intact cements (9 columns)."""
    if history.shape[1] != WIDTH_CEMENTED:
        return np.zeros(len(history), dtype=bool)
    return history[:, CEMENT_STATE] > 0.0


def history_width(params):
    """Columns of a pair's history row: 3 (plain) or 9 (cemented, see the module docstring)."""
    return WIDTH_CEMENTED if params.cemented else WIDTH_PLAIN


@njit(cache=True, inline="always", error_model="numpy")
def hertz_mindlin_forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0, ut1, ut2, spin, mass, hist,
                         dt, e_star, g_star, mu, gamma, damped):
    """The laws of a touching pair (overlap ``delta`` > 0 [m], normal ``n``, relative motion ``un``,
    ``ut``, ``spin`` of ``contact_frame``): Hertz normal force (damped when ``damped``, a
    compile-time constant), Mindlin tangential force with the Coulomb cap, ``hist[p]`` updated.
    Returns ``(fn [N], h0, h1, h2 [N], elastic energy [J])``."""
    a = np.sqrt(ri * rj / rsum * delta)          # contact radius sqrt(R* delta)
    fn_el = 4.0 / 3.0 * e_star * a * delta       # Hertz
    fn = fn_el
    if damped:
        m_star = mass[i] * mass[j] / (mass[i] + mass[j])
        fn += gamma * np.sqrt(m_star * 2.0 * e_star * a) * un
        if fn < 0.0:
            fn = 0.0
    kt = 8.0 * g_star * a                        # Mindlin
    h0, h1, h2 = update_history(hist, p, n0, n1, n2, ut0, ut1, ut2, spin, dt, kt, mu * fn)
    return fn, h0, h1, h2, 0.4 * fn_el * delta + 0.5 * (h0 * h0 + h1 * h1 + h2 * h2) / kt


@njit(cache=True, inline="always", error_model="numpy")
def hertz_mindlin_pair(p, i, j, s0, s1, s2, g0, g1, g2, x, v, w, radius, mass, hist, dt, e_star, g_star, mu,
                       gamma, out, damped, deforming):
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
    fn, h0, h1, h2, energy = hertz_mindlin_forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0,
                                                  ut1, ut2, spin, mass, hist, dt, e_star, g_star,
                                                  mu, gamma, damped)
    write_pair(out, n0, n1, n2, fn, h0, h1, h2, li, lj)
    return True, energy


@njit(cache=True, inline="always", error_model="numpy")
def hertz_mindlin_cemented_pair(p, i, j, s0, s1, s2, g0, g1, g2, x, v, w, radius, mass, hist, dt,
                                e_star, g_star, mu, gamma, sn, st, fade_step, out, damped,
                                deforming):
    """``hertz_mindlin_pair`` plus the cement of the pair (history row ``hist[p]`` of 9 columns).

    sn, st [N/m]: cement springs; fade_step: decrease of the fading factor per step
    (``dt / t_fade``, or > 1 to drop a broken cement on the next step). Returns ``(interacting,
    elastic energy [J])``; ``interacting`` is True when the spheres touch or a cement acts.
    """
    state = hist[p, 8]
    d0, d1, d2, dist2, ri, rj, rsum = pair_separation(i, j, s0, s1, s2, x, radius)
    if state == 0.0 and dist2 >= rsum * rsum:
        clear_history(hist, p)
        return False, 0.0
    n0, n1, n2, delta, li, lj = contact_geometry(d0, d1, d2, dist2, ri, rj, rsum)
    un, ut0, ut1, ut2, spin = relative_motion(i, j, v, w, n0, n1, n2, li, lj)
    if deforming:
        un, ut0, ut1, ut2 = affine_motion(un, ut0, ut1, ut2, d0, d1, d2, n0, n1, n2, g0, g1, g2)
    fn = 0.0
    h0 = h1 = h2 = 0.0
    energy = 0.0
    if delta > 0.0:      # the Hertz-Mindlin part, exactly the plain law
        fn, h0, h1, h2, energy = hertz_mindlin_forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un,
                                                      ut0, ut1, ut2, spin, mass, hist, dt, e_star,
                                                      g_star, mu, gamma, damped)
    else:
        clear_history(hist, p)
    if state != 0.0:     # the cement, intact (state > 0) or fading (state < 0)
        c0, c1, c2 = carry_force(hist[p, 3], hist[p, 4], hist[p, 5], n0, n1, n2, spin * dt)
        stretch = delta - hist[p, 6]
        scale = 1.0
        if state > 0.0:
            k = st * dt
            c0 -= k * ut0
            c1 -= k * ut1
            c2 -= k * ut2
            e_c = 0.5 * sn * stretch * stretch
            if st > 0.0:
                e_c += 0.5 * (c0 * c0 + c1 * c1 + c2 * c2) / st
            if e_c > hist[p, 7]:
                hist[p, 8] = -1.0          # ruptured: full force this step, then fading
        else:
            scale = -state - fade_step
            e_c = 0.0
            if scale > 0.0:
                hist[p, 8] = -scale
            else:
                scale = 0.0
                c0 = c1 = c2 = 0.0
                for col in range(3, 9):
                    hist[p, col] = 0.0
        hist[p, 3] = c0
        hist[p, 4] = c1
        hist[p, 5] = c2
        if scale == 0.0 and delta <= 0.0:
            return False, energy
        fn += scale * sn * stretch
        h0 += scale * c0
        h1 += scale * c1
        h2 += scale * c2
        energy += e_c
    write_pair(out, n0, n1, n2, fn, h0, h1, h2, li, lj)
    return True, energy


def _pair_loop(damped, periodic, deforming, cemented=False, with_energy=True):
    """Loop over a pair list; ``damped``, ``periodic`` (image shifts are read), ``deforming``
    (the cell's strain rate is read), ``cemented`` (the 9-column history with cement terms;
    ``cement = (Sn, St, fade_step)`` is read) and ``with_energy`` (the energy is summed; without
    it the loop returns 0 and skips the energy's arithmetic, 8 % of the loop) are frozen as
    compile-time constants."""
    @njit(cache=True, error_model="numpy")
    def loop(pi, pj, shift, rate, x, v, w, radius, mass, f, t, hist, dt, e_star, g_star, mu, gamma,
             n_owned, acc, cement):
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
        sn = st = fade_step = 0.0
        if cemented:
            sn, st, fade_step = cement[0], cement[1], cement[2]
        for p in range(pi.shape[0]):
            i = pi[p]
            j = pj[p]
            if periodic:
                s0 = shift[p, 0]
                s1 = shift[p, 1]
                s2 = shift[p, 2]
            if cemented:
                touching, e = hertz_mindlin_cemented_pair(p, i, j, s0, s1, s2, g0, g1, g2, x, v, w,
                                                          radius, mass, hist, dt, e_star, g_star,
                                                          mu, gamma, sn, st, fade_step, out,
                                                          damped, deforming)
            else:
                touching, e = hertz_mindlin_pair(p, i, j, s0, s1, s2, g0, g1, g2, x, v, w, radius,
                                                 mass, hist, dt, e_star, g_star, mu, gamma, out,
                                                 damped, deforming)
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
    def loop(x, v, w, radius, mass, f, t, hist_full, dt, e_star, g_star, mu, gamma):
        out = np.empty(9)
        energy = 0.0
        n = x.shape[0]
        for i in range(n):
            hist_i = hist_full[i]
            for j in range(i + 1, n):
                touching, e = hertz_mindlin_pair(j, i, j, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, x, v, w,
                                                 radius, mass, hist_i, dt, e_star, g_star, mu,
                                                 gamma, out, damped, False)
                if touching:
                    scatter_pair(i, j, f, t, out)
                    energy += e
        return energy
    return loop


@lru_cache(maxsize=None)
def pair_loop(damped, periodic, deforming=False, cemented=False, with_energy=True):
    """The compiled pair-list kernel for one sub-model choice (built once per choice).

    ``loop(i, j, shift, rate, x, v, w, radius, mass, f, t, history, dt, e_star, g_star, mu, gamma,
    n_owned, acc, cement)`` adds the pair forces and torques to ``f``, ``t`` (owned and ghost rows
    alike), updates ``history`` [n_pairs, 3] (``cemented``: [n_pairs, 9]), adds the Love-Weber sums
    of the pairs whose ``i`` is owned to ``acc`` [10] (``contact_frame.add_love_weber``) and
    returns their elastic energy [J] (0 unless ``with_energy``). ``shift`` [n_pairs, 3] [m], the cell's diagonal strain rate
    ``rate`` [3] [1/s] and ``cement`` [3] = (Sn [N/m], St [N/m], fade step) are read only when
    ``periodic``, ``deforming`` and ``cemented`` respectively.
    """
    return _pair_loop(bool(damped), bool(periodic), bool(deforming), bool(cemented), bool(with_energy))


NO_CEMENT = np.zeros(3)


def cement_constants(params, dt):
    """``[Sn, St, fade_step]`` for the cemented kernel (``fade_step = dt / t_fade``, 2 for
    ``t_fade = 0``: the cement is dropped on the step after rupture)."""
    if not params.cemented:
        return NO_CEMENT
    t_f = params.cement_fade_time
    return np.array([params.cement_normal, params.cement_tangential,
                     float(dt) / t_f if t_f > 0.0 else 2.0])


@lru_cache(maxsize=None)
def all_pairs_loop(damped):
    """``loop(x, v, w, radius, mass, f, t, history_full, dt, e_star, g_star, mu, gamma)`` over all
    row pairs, history ``[n, n, 3]`` indexed ``[i, j]`` with ``i < j`` (test oracle)."""
    return _all_pairs_loop(bool(damped))


# ---------------------------------------------------------------------------------------------
# model interface (STYLE pattern 3)

def cutoff(params, rmax):
    """Largest centre distance at which two spheres of radius <= ``rmax`` [m] interact [m]."""
    return 2.0 * float(rmax)


def normal_stiffness(params):
    """``(k_constant, k_hertz)``: the normal tangent stiffness ``2 E* sqrt(R* delta)`` [N/m] in the
    form of ``timestep.contact_stiffness``."""
    return 0.0, 2.0 * params.e_star


def compute(params, elements, i, j, history, dt, shift=None, rate=None, acc=None, with_energy=True):
    """Add the contact forces of the pairs ``(i[p], j[p])`` to ``elements.f``/``elements.t``.

    i, j : [n_pairs] rows (ordered by gid within each pair); history : [n_pairs, 3] tangential force
    on i [N] ([n_pairs, 9] with cement, module docstring), updated in place (zeroed for pairs not
    in contact); dt [s] : step; shift : optional
    [n_pairs, 3] periodic image shift added to ``x_j`` [m]; rate : optional diagonal strain rate [3]
    [1/s] of the periodic cell (needs ``shift``); acc : optional [10] Love-Weber sums, added to.
    Returns the elastic energy [J] of the pairs whose ``i`` is owned (NaN when not
    ``with_energy``: the loop then does not compute it).
    """
    e, p = elements, params
    if p.cemented:
        if history.ndim != 2 or history.shape[1] != WIDTH_CEMENTED:
            raise ValueError(f"cemented contacts need a history of {WIDTH_CEMENTED} columns, got "
                             f"shape {history.shape}")
        check_pairs(i, j, history[:, :3], shift)
        cement = cement_constants(p, dt)
    else:
        check_pairs(i, j, history, shift)
        cement = NO_CEMENT
    loop = pair_loop(p.damped, shift is not None, rate is not None and bool(np.any(rate != 0.0)),
                     p.cemented, with_energy)
    energy = loop(i, j, NO_SHIFT if shift is None else shift, NO_RATE if rate is None else rate,
                  e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, history, float(dt), p.e_star, p.g_star,
                  p.friction, p.gamma, e.n_owned, np.zeros(10) if acc is None else acc, cement)
    return energy if with_energy else float("nan")


def compute_all_pairs(params, elements, history_full, dt):
    """Brute-force version of ``compute`` over all row pairs, history ``[n, n, 3]`` (tests)."""
    e, p = elements, params
    if p.cemented:
        raise ValueError("compute_all_pairs: the brute-force oracle has no cement terms")
    return all_pairs_loop(p.damped)(e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, history_full,
                                    float(dt), p.e_star, p.g_star, p.friction, p.gamma)


def single(params, elements, i, j, history_row, dt, shift=(0.0, 0.0, 0.0)):
    """Diagnostics of one pair, nothing modified: dict with ``force_i``, ``torque_i``, ``torque_j``,
    ``history`` (the value the step would store), ``energy`` and ``touching``."""
    e, p = elements, params
    hist = np.array(history_row, dtype=np.float64).reshape(1, history_width(p))
    out = np.zeros(9)
    s = np.asarray(shift, dtype=np.float64)
    if p.cemented:
        c = cement_constants(p, dt)
        touching, energy = _single_cemented_kernel(i, j, s, e.x, e.v, e.w, e.radius, e.mass, hist,
                                                   float(dt), p.e_star, p.g_star, p.friction,
                                                   p.gamma, c[0], c[1], c[2], out, p.damped)
    else:
        touching, energy = _single_kernel(i, j, s, e.x, e.v, e.w, e.radius, e.mass, hist,
                                          float(dt), p.e_star, p.g_star, p.friction, p.gamma, out,
                                          p.damped)
    return {"touching": bool(touching), "force_i": out[0:3].copy(), "torque_i": out[3:6].copy(),
            "torque_j": out[6:9].copy(), "history": hist[0].copy(), "energy": float(energy)}


@njit(cache=True, error_model="numpy")
def _single_kernel(i, j, s, x, v, w, radius, mass, hist, dt, e_star, g_star, mu, gamma, out, damped):
    if damped:
        return hertz_mindlin_pair(0, i, j, s[0], s[1], s[2], 0.0, 0.0, 0.0, x, v, w, radius, mass,
                                  hist, dt, e_star, g_star, mu, gamma, out, True, False)
    return hertz_mindlin_pair(0, i, j, s[0], s[1], s[2], 0.0, 0.0, 0.0, x, v, w, radius, mass, hist,
                              dt, e_star, g_star, mu, gamma, out, False, False)


@njit(cache=True, error_model="numpy")
def _single_cemented_kernel(i, j, s, x, v, w, radius, mass, hist, dt, e_star, g_star, mu, gamma, sn,
                            st, fade_step, out, damped):
    if damped:
        return hertz_mindlin_cemented_pair(0, i, j, s[0], s[1], s[2], 0.0, 0.0, 0.0, x, v, w,
                                           radius, mass, hist, dt, e_star, g_star, mu, gamma, sn,
                                           st, fade_step, out, True, False)
    return hertz_mindlin_cemented_pair(0, i, j, s[0], s[1], s[2], 0.0, 0.0, 0.0, x, v, w, radius,
                                       mass, hist, dt, e_star, g_star, mu, gamma, sn, st,
                                       fade_step, out, False, False)
