"""Hertz-Mindlin contact with tangential history and Coulomb friction. docs/physics.md section 8.

Kinematics, sign conventions, the history carry and the output layout are those of
``pardem.physics.contact_frame`` (normal ``n`` from i to j, history = elastic tangential force on i).
A row of ``pardem.physics.contact_laws``: the per-pair functions below (``pair_function``) run in
the shared loops of ``pardem.physics.pair_loop``.

Laws
----
Overlap ``delta`` [m], ``R* = R_i R_j / (R_i + R_j)``, contact radius ``a = sqrt(R* delta)``:

* normal (Hertz): ``fn_el = 4/3 E* sqrt(R*) delta^(3/2) = 4/3 E* a delta``;
* tangential (Mindlin, no-slip stiffness, incremental): ``dft = -kt ds``, ``kt = 8 G* a``; while the
  contact opens the stored force is first scaled by ``kt(new) / kt(old)`` (``unload_rescale``), so
  that no load-unload cycle creates energy;
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
state measure, not a potential). With the unloading rescale it is a storage function of the
law: no step raises it by more than the work done on the contact (a step at fixed ``kt`` is
elastic; loading lowers ``|h|^2 / (2 kt)`` at fixed ``h``; the rescale multiplies it by
``kt(new) / kt(old) < 1``), so the law is passive.

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

from pardem.physics.arguments import keywords, real
from pardem.physics.contact_frame import carry_force, clear_history, update_history
from pardem.physics.pair_loop import law_interface, touching
from pardem.physics.timestep import rayleigh_time_step

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

@keywords("hertz_mindlin.Params")
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
        # Poisson ratio: (-1, 0.5), the deck's range (pardem.config); the moduli need nu > -1
        real("hertz_mindlin.young", self.young, lo=0.0, unit="[Pa]")
        real("hertz_mindlin.poisson", self.poisson, lo=-1.0, hi=0.5)
        if self.young2 is not None:
            real("hertz_mindlin.young2", self.young2, lo=0.0, unit="[Pa]", note="None: young")
        if self.poisson2 is not None:
            real("hertz_mindlin.poisson2", self.poisson2, lo=-1.0, hi=0.5, note="None: poisson")
        real("hertz_mindlin.friction", self.friction, lo=0.0, lo_open=False, note="Coulomb coefficient")
        real("hertz_mindlin.restitution", self.restitution, lo=0.0, hi=1.0, hi_open=False)
        for name, unit in (("cement_normal", "[N/m]"), ("cement_tangential", "[N/m]"),
                           ("cement_fade_time", "[s]")):
            real(f"hertz_mindlin.{name}", getattr(self, name), lo=0.0, lo_open=False, unit=unit)
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
def hertz_normal(r_star, m_star, delta, rate, e_star, gamma, damped):
    """Hertz normal force of a contact of effective radius ``r_star`` [m] (``R*``; ``R`` on a plane)
    and mass ``m_star`` [kg] at overlap ``delta > 0`` [m] closing at ``rate = d(delta)/dt`` [m/s]:
    damped when ``damped`` (a compile-time constant), clipped at zero. Returns ``(fn [N], fn_el
    [N] the elastic part, a [m] the contact radius)``."""
    a = np.sqrt(r_star * delta)                  # contact radius sqrt(R* delta)
    fn_el = 4.0 / 3.0 * e_star * a * delta       # Hertz
    fn = fn_el
    if damped:
        fn += gamma * np.sqrt(m_star * 2.0 * e_star * a) * rate
        if fn < 0.0:
            fn = 0.0
    return fn, fn_el, a


@njit(cache=True, inline="always", error_model="numpy")
def mindlin_stiffness(g_star, a):
    """Mindlin no-slip tangential stiffness ``8 G* a`` [N/m] at contact radius ``a`` [m]."""
    return 8.0 * g_star * a


@njit(cache=True, inline="always", error_model="numpy")
def unload_rescale(hist, p, delta, un, dt):
    """Scale the stored tangential force ``hist[p, 0:3]`` by ``kt(new) / kt(old) = a / a_old =
    sqrt(delta / delta_old)`` while the contact opens (``un = d(delta)/dt < 0``), in place.

    ``delta_old = delta - un dt`` is the overlap of the previous step (exact for a normal relative
    motion, to second order in the tangential one). Without it an unloaded contact keeps a force
    its smaller ``kt`` cannot give back, and a closed load-unload cycle below sliding creates
    energy (``tests/test_mindlin_cycle.py``). While the contact closes nothing is scaled, as in
    LAMMPS' ``mindlin_rescale/force`` and Thornton's unloading rule.
    """
    if un < 0.0:
        s = np.sqrt(delta / (delta - un * dt))
        hist[p, 0] *= s
        hist[p, 1] *= s
        hist[p, 2] *= s


@njit(cache=True, inline="always", error_model="numpy")
def hertz_mindlin_forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0, ut1, ut2, spin, mass, hist,
                         dt, e_star, g_star, mu, gamma, damped):
    """The laws of a touching pair (overlap ``delta`` > 0 [m], normal ``n``, relative motion ``un``,
    ``ut``, ``spin`` of ``contact_frame``): Hertz normal force (damped when ``damped``, a
    compile-time constant), Mindlin tangential force with the Coulomb cap, ``hist[p]`` updated.
    Returns ``(fn [N], h0, h1, h2 [N], elastic energy [J])``."""
    m_star = mass[i] * mass[j] / (mass[i] + mass[j])     # dead code unless damped
    fn, fn_el, a = hertz_normal(ri * rj / rsum, m_star, delta, un, e_star, gamma, damped)
    kt = mindlin_stiffness(g_star, a)
    unload_rescale(hist, p, delta, un, dt)
    h0, h1, h2 = update_history(hist, p, n0, n1, n2, ut0, ut1, ut2, spin, dt, kt, mu * fn)
    return fn, h0, h1, h2, 0.4 * fn_el * delta + 0.5 * (h0 * h0 + h1 * h1 + h2 * h2) / kt


def _plain_forces(damped):
    """The ``pair_loop.forces`` of the plain law, ``c = (E*, G*, mu, gamma)``."""
    @njit(cache=True, inline="always", error_model="numpy")
    def forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0, ut1, ut2, spin, mass, hist, dt, c):
        e_star, g_star, mu, gamma = c
        fn, h0, h1, h2, energy = hertz_mindlin_forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un,
                                                      ut0, ut1, ut2, spin, mass, hist, dt, e_star,
                                                      g_star, mu, gamma, damped)
        return True, fn, h0, h1, h2, energy
    return forces


@njit(cache=True, inline="always", error_model="numpy")
def cemented_engaged(p, hist, dist2, rsum):
    """A cemented pair is computed while it touches or holds a cement (intact or fading)."""
    return hist[p, CEMENT_STATE] != 0.0 or dist2 < rsum * rsum


def _cemented_forces(damped):
    """The ``pair_loop.forces`` of the cemented law, ``c = (E*, G*, mu, gamma, Sn, St, fade_step)``
    (``fade_step``: decrease of the fading factor per step, ``dt / t_fade``, or > 1 to drop a broken
    cement on the next step); history of 9 columns (module docstring)."""
    @njit(cache=True, inline="always", error_model="numpy")
    def forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2, un, ut0, ut1, ut2, spin, mass, hist, dt, c):
        e_star, g_star, mu, gamma, sn, st, fade_step = c
        state = hist[p, 8]
        fn = 0.0
        h0 = h1 = h2 = 0.0
        energy = 0.0
        if delta > 0.0:      # the Hertz-Mindlin part, exactly the plain law
            fn, h0, h1, h2, energy = hertz_mindlin_forces(p, i, j, ri, rj, rsum, delta, n0, n1, n2,
                                                          un, ut0, ut1, ut2, spin, mass, hist, dt,
                                                          e_star, g_star, mu, gamma, damped)
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
                return False, fn, h0, h1, h2, energy
            fn += scale * sn * stretch
            h0 += scale * c0
            h1 += scale * c1
            h2 += scale * c2
            energy += e_c
        return True, fn, h0, h1, h2, energy
    return forces


@lru_cache(maxsize=None)
def _law_function(damped, cemented):
    if cemented:
        return _cemented_forces(damped), cemented_engaged
    return _plain_forces(damped), touching


def pair_function(params):
    """``(forces, engaged)`` of ``pair_loop`` for these parameters (damping and cement chosen
    here, compiled in only when used)."""
    return _law_function(bool(params.damped), bool(params.cemented))


def cement_constants(params, dt):
    """``(Sn, St, fade_step)`` of the cemented kernel (``fade_step = dt / t_fade``, 2 for
    ``t_fade = 0``: the cement is dropped on the step after rupture)."""
    t_f = params.cement_fade_time
    return (float(params.cement_normal), float(params.cement_tangential),
            float(dt) / t_f if t_f > 0.0 else 2.0)


def constants(params, dt):
    """The ``c`` tuple of ``pair_function(params)``: ``(E*, G*, mu, gamma)`` [Pa, Pa, -, -], plus
    ``cement_constants`` when cemented."""
    p = params
    c = (float(p.e_star), float(p.g_star), float(p.friction), float(p.gamma))
    return c + cement_constants(p, dt) if p.cemented else c


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
    """``(k_constant, k_hertz)``: the normal tangent stiffness ``2 E* sqrt(R* delta)`` [N/m] in the
    form of ``timestep.contact_stiffness``."""
    return 0.0, 2.0 * params.e_star


def cement_time_step(params, r_min, density):
    """``1 / omega`` [s] of two spheres of radius ``r_min`` [m] joined by the stiffer cement spring
    alone (``omega^2 = 2 k / m``): the cement's share of the critical step (well above the
    Rayleigh step for cements softer than the Hertz contact)."""
    m = density * 4.0 / 3.0 * np.pi * float(r_min) ** 3
    k = max(params.cement_normal, params.cement_tangential)
    return float(np.sqrt(m / (2.0 * k)))


def critical_time_step(params, radii, density):
    """Critical step [s] of spheres of radii ``radii`` [m] and ``density`` [kg/m^3]: the Rayleigh
    step of the smallest (``timestep.rayleigh_time_step``), and the cement's when cemented."""
    r_min = float(np.min(radii))
    g = params.young / (2.0 * (1.0 + params.poisson))
    dt_c = rayleigh_time_step(r_min, density, g, params.poisson)
    if params.cemented:
        dt_c = min(dt_c, cement_time_step(params, r_min, density))
    return dt_c


def deck_params(section, auto):
    """The ``Params`` dict of a deck's ``contacts`` section (``young``, ``poisson``, ``friction``,
    ``restitution``); ``auto["young"]()`` [Pa] is called for ``young = "auto"``."""
    young = auto["young"]() if section["young"] == "auto" else section["young"]
    return {"young": young, "poisson": section["poisson"], "friction": section["friction"],
            "restitution": section["restitution"]}


@njit(cache=True, error_model="numpy")
def _elastic_normal(ri, rj, delta, e_star, out):
    for p in range(delta.shape[0]):
        rsum = ri[p] + rj[p]
        out[p] = hertz_normal(ri[p] * rj[p] / rsum, 0.0, delta[p], 0.0, e_star, 0.0, False)[1]


def elastic_normal_force(params, r_i, r_j, delta):
    """Elastic Hertz normal force [N] [n] of contacts of radii ``r_i``, ``r_j`` [m] [n] at overlaps
    ``delta > 0`` [m] [n] (the kernel's value, damping excluded)."""
    out = np.empty(len(delta))
    _elastic_normal(np.ascontiguousarray(r_i, dtype=np.float64),
                    np.ascontiguousarray(r_j, dtype=np.float64),
                    np.ascontiguousarray(delta, dtype=np.float64), float(params.e_star), out)
    return out
