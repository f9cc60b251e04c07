"""Sphere-sphere contact laws (pardem.physics.hertz_mindlin, linear_contact, contact_frame,
viscous_damping), docs/physics.md section 8, each against an independent analytic result.

Head-on Hertz impact
    ``m* d''(delta) = -K delta^(3/2)``, ``K = 4/3 E* sqrt(R*)``, ``delta(0) = 0``, ``delta'(0) = v``
    (relative impact speed v, reduced mass ``m* = m1 m2 / (m1 + m2)``). Energy conservation
    ``1/2 m* delta'^2 + 2/5 K delta^(5/2) = 1/2 m* v^2`` gives the largest overlap
    ``delta_max = (5 m* v^2 / (4 K))^(2/5)`` and, with ``x = delta / delta_max``, the duration
    ``t_c = 2 (delta_max / v) int_0^1 dx / sqrt(1 - x^(5/2))``, where the integral is
    ``(2/5) B(2/5, 1/2) = (2/5) Gamma(2/5) Gamma(1/2) / Gamma(9/10) = 1.47164``. Hence::

        t_c = 2.94328 delta_max / v = 3.21807 (m* / K)^(2/5) v^(-1/5)
            = 2.86827 (m*^2 / (R* E*^2 v))^(1/5)

    (the last form is the classical "2.87"). Written with ``E* sqrt(R*)`` instead of ``K`` the
    constant is 2.86827, not 3.21807: the two differ by ``(4/3)^(2/5)``. The test evaluates the
    constant from the Gamma functions.

Linear spring-dashpot restitution
    the target ``e`` itself (the damping ratio is derived in linear_contact from the no-tension
    solution of the damped oscillator; the simulation must rebound at ``e v``).
Coulomb and stiffness
    ``|ft| = mu fn`` once sliding, ``ft = kt s`` before, ``kt = 4 G/(2 - nu) sqrt(R* delta)`` written
    with the identical-grain formula of docs/physics.md (independent of the general ``G*`` code path).
Rigid rotation, Newton's third law, angular momentum
    exact identities of any objective contact law.
Elastic gas
    energy conservation of a frictionless undamped Hertz gas under velocity Verlet.
"""
from math import gamma as Gamma

import numpy as np
import pytest
from numba import njit

from pardem.physics import hertz_mindlin as hm
from pardem.physics import hertz_mindlin_rolling as hmr
from pardem.physics import linear_contact as lc
from pardem.physics.verlet import kick, kick_drift
from pardem.physics.viscous_damping import damp_elements
from pardem.engine.state import Elements
from _util import perpendicular, random_unit, rotmat

YOUNG, NU, RHO = 1.0e9, 0.3, 2500.0
SHEAR = YOUNG / (2.0 * (1.0 + NU))
E_STAR_SAME = SHEAR / (1.0 - NU)          # identical grains, docs/physics.md
HERTZ_INTEGRAL = 0.4 * Gamma(0.4) * Gamma(0.5) / Gamma(0.9)   # int_0^1 dx / sqrt(1 - x^2.5)


def hertz_K(e_star, r_star):
    return 4.0 / 3.0 * e_star * np.sqrt(r_star)


def hertz_duration(m_star, r_star, e_star, v):
    """Analytic contact time of an elastic Hertz impact at relative speed v (module docstring)."""
    delta_max = (5.0 * m_star * v * v / (4.0 * hertz_K(e_star, r_star))) ** 0.4
    return 2.0 * HERTZ_INTEGRAL * delta_max / v, delta_max


def mindlin_kt_same(r_star, delta):
    """docs/physics.md: kt = 4 G / (2 - nu) sqrt(R* delta) for identical grains."""
    return 4.0 * SHEAR / (2.0 - NU) * np.sqrt(r_star * delta)


def two_spheres(R1, R2, n, gap, density=RHO):
    e = Elements.from_spheres(np.array([np.zeros(3), (R1 + R2 + gap) * n]), np.array([R1, R2]), density)
    return e


PAIR_I = np.array([0], dtype=np.int32)
PAIR_J = np.array([1], dtype=np.int32)


def collide(e, params, module, v_rel, n, dt, max_steps=200_000):
    """Head-on collision of rows 0 and 1 with velocity Verlet.

    Returns (contact duration [s] from the interpolated zero crossings of the overlap, largest
    overlap [m], relative normal speed after separation [m/s]).
    """
    m1, m2 = e.mass
    e.v[0] = v_rel * m2 / (m1 + m2) * n
    e.v[1] = -v_rel * m1 / (m1 + m2) * n
    hist = np.zeros((1, 3))
    rsum = e.radius.sum()
    module.compute(params, e, PAIR_I, PAIR_J, hist, dt)
    prev = rsum - np.linalg.norm(e.x[1] - e.x[0])
    t_start = t_end = None
    delta_max = 0.0
    for k in range(1, max_steps):
        kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 2)
        module.compute(params, e, PAIR_I, PAIR_J, hist, dt)
        kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 2)
        delta = rsum - np.linalg.norm(e.x[1] - e.x[0])
        delta_max = max(delta_max, delta)
        if prev <= 0.0 < delta:
            t_start = (k - 1 + prev / (prev - delta)) * dt
        if t_start is not None and prev > 0.0 >= delta:
            t_end = (k - 1 + prev / (prev - delta)) * dt
            break
        prev = delta
    assert t_end is not None, "the spheres did not separate"
    # the force is zero from here on (either no overlap or a clipped dashpot): the speed is final
    return t_end - t_start, delta_max, float(np.dot(e.v[1] - e.v[0], n))


# ------------------------------------------------------------------------------------------------
# head-on collisions

@pytest.mark.parametrize("R1, R2", [(1e-3, 1e-3), (1e-3, 1.6e-3)])
def test_hertz_head_on_duration_and_rebound(R1, R2):
    rng = np.random.default_rng(1)
    n = random_unit(rng)
    v = 1.0
    params = hm.Params(YOUNG, NU, friction=0.0)
    assert params.e_star == pytest.approx(E_STAR_SAME, rel=1e-14)
    e = two_spheres(R1, R2, n, gap=0.0)
    m_star = e.mass[0] * e.mass[1] / e.mass.sum()
    r_star = R1 * R2 / (R1 + R2)
    tc, dmax = hertz_duration(m_star, r_star, E_STAR_SAME, v)
    e.x[1] += 20 * tc / 2000 * v * n   # contact starts after 20 steps
    duration, delta_max, v_out = collide(e, params, hm, v, n, tc / 2000)
    # the classical closed form agrees with the Gamma-function constant
    assert tc == pytest.approx(2.86827 * (m_star**2 / (r_star * E_STAR_SAME**2 * v)) ** 0.2, rel=1e-5)
    assert duration == pytest.approx(tc, rel=1e-2)
    assert delta_max == pytest.approx(dmax, rel=1e-3)
    assert v_out == pytest.approx(v, rel=1e-3)
    # no sideways motion, no spin, total momentum still zero
    np.testing.assert_allclose(e.mass @ e.v, 0.0, atol=1e-14 * e.mass[0] * v)
    assert np.abs(e.w).max() == 0.0
    print(f"\nHertz R1={R1} R2={R2}: t_c {duration:.6e} vs {tc:.6e} s "
          f"({duration / tc - 1:+.2e}), delta_max {delta_max / dmax - 1:+.2e}, "
          f"rebound {v_out / v - 1:+.2e}")


@pytest.mark.parametrize("e_target", [0.9, 0.5, 0.1])
def test_linear_restitution(e_target):
    n = np.array([0.0, 0.6, 0.8])
    e = two_spheres(1e-3, 1.3e-3, n, gap=0.0)
    kn = 2e4
    params = lc.Params(kn=kn, kt=0.8 * kn, friction=0.3, restitution=e_target)
    m_star = e.mass[0] * e.mass[1] / e.mass.sum()
    omega0 = np.sqrt(kn / m_star)
    dt = np.pi / omega0 / 2000
    v = 0.5
    e.x[1] += 10 * dt * v * n
    _, _, v_out = collide(e, params, lc, v, n, dt)
    assert v_out / v == pytest.approx(e_target, rel=1e-2)
    print(f"\nlinear e={e_target}: zeta={params.zeta_n:.6f} measured e={v_out / v:.6f} "
          f"({v_out / v / e_target - 1:+.2e})")


def test_textbook_damping_ratio_misses_with_no_tension():
    """The textbook zeta(e) assumes the dashpot pulls at the end; with the clip the rebound is
    ``restitution(zeta)``, checked here, and it is not e (why linear_contact inverts the exact law)."""
    zeta = lc.textbook_damping_ratio(0.5)
    n = np.array([1.0, 0.0, 0.0])
    e = two_spheres(1e-3, 1e-3, n, gap=0.0)
    kn = 2e4
    m_star = e.mass[0] / 2
    dt = np.pi / np.sqrt(kn / m_star) / 2000
    v = 0.5
    e.x[1] += 10 * dt * v * n
    params = lc.Params(kn=kn, kt=kn, friction=0.3, restitution=lc.restitution(zeta))
    assert params.zeta_n == pytest.approx(zeta, rel=1e-12)
    _, _, v_out = collide(e, params, lc, v, n, dt)
    assert v_out / v == pytest.approx(lc.restitution(zeta), rel=1e-3)
    assert v_out / v > 0.54
    print(f"\ntextbook zeta({0.5}) = {zeta:.5f}: measured e = {v_out / v:.5f}")


@pytest.mark.parametrize("e_target", [0.9, 0.5, 0.1])
def test_hertz_damped_restitution_independent_of_speed(e_target):
    params = hm.Params(YOUNG, NU, friction=0.0, restitution=e_target)
    n = np.array([0.0, 0.0, 1.0])
    measured = []
    for v in (0.05, 2.0):
        e = two_spheres(1e-3, 1e-3, n, gap=0.0)
        m_star = e.mass[0] / 2
        tc, _ = hertz_duration(m_star, 0.5e-3, params.e_star, v)
        dt = tc / 2000
        e.x[1] += 10 * dt * v * n
        _, _, v_out = collide(e, params, hm, v, n, dt)
        measured.append(v_out / v)
        assert v_out / v == pytest.approx(e_target, rel=1e-2)
    print(f"\nHertz damped e={e_target}: gamma={params.gamma:.6f} measured {measured}")


def test_hertz_damping_weak_limit():
    """Weak damping: 1 - e^2 = (dissipation along the elastic path) / (1/2 m* v^2) = 3.4414 gamma."""
    const = 4.0 * np.sqrt(1.5) * np.sqrt(1.25) * 0.4 * Gamma(0.5) * Gamma(1.5) / Gamma(2.0)
    gamma = 1e-4
    e = hm.hertz_restitution(gamma)
    assert (1.0 - e) / (1.0 - np.sqrt(1.0 - const * gamma)) == pytest.approx(1.0, abs=1e-3)
    assert hm.hertz_restitution(0.0) == pytest.approx(1.0, abs=1e-9)
    assert hm.hertz_restitution(hm.hertz_damping_coefficient(0.3)) == pytest.approx(0.3, abs=1e-9)


def test_linear_restitution_closed_form_is_continuous():
    for z in (0.3, 0.999999, 1.0, 1.000001, 3.0):
        assert 0.0 < lc.restitution(z) < 1.0
    assert lc.restitution(1.0 - 1e-6) == pytest.approx(lc.restitution(1.0 + 1e-6), rel=1e-5)
    assert lc.damping_ratio(np.exp(-2.0)) == pytest.approx(1.0, rel=1e-9)


# ------------------------------------------------------------------------------------------------
# Coulomb limit and tangential stiffness

def _pressed_pair(module, rng, delta_rel=0.01):
    """Two spheres overlapping by delta along a random n; model params, fn, kt (analytic)."""
    R1, R2 = 1e-3, 1.2e-3
    n = random_unit(rng)
    tau = perpendicular(n, rng)
    r_star = R1 * R2 / (R1 + R2)
    delta = delta_rel * r_star
    e = two_spheres(R1, R2, n, gap=-delta)
    mu = 0.4
    if module is hm:
        params = hm.Params(YOUNG, NU, friction=mu)
        fn = 4.0 / 3.0 * E_STAR_SAME * np.sqrt(r_star) * delta**1.5
        kt = mindlin_kt_same(r_star, delta)
    else:
        params = lc.Params(kn=3e5, kt=1e5, friction=mu)
        fn = 3e5 * delta
        kt = 1e5
    return e, params, n, tau, delta, fn, kt, mu


@pytest.mark.parametrize("module", [hm, lc], ids=["hertz_mindlin", "linear"])
def test_coulomb_cap_and_stiffness_sliding(module):
    """Sphere 1 slides on sphere 0 along a circle (constant overlap): ft = kt s, then mu fn."""
    rng = np.random.default_rng(3)
    e, params, n, tau, delta, fn, kt, mu = _pressed_pair(module, rng)
    dist = e.radius.sum() - delta
    s_slip = mu * fn / kt
    steps, s_end = 400, 3.0 * s_slip
    ds, dt = s_end / steps, 1e-6
    speed = ds / dt
    hist = np.zeros((1, 3))
    forces = []
    for k in range(1, steps + 1):
        phi = k * ds / dist
        phi_mid = (k - 0.5) * ds / dist
        e.x[1] = dist * (np.cos(phi) * n + np.sin(phi) * tau)
        e.v[1] = speed * (-np.sin(phi_mid) * n + np.cos(phi_mid) * tau)
        e.f[:] = 0.0
        e.t[:] = 0.0
        module.compute(params, e, PAIR_I, PAIR_J, hist, dt)
        n_now = e.x[1] / dist
        tau_now = -np.sin(phi) * n + np.cos(phi) * tau
        f0 = e.f[0]
        np.testing.assert_array_equal(e.f[1], -f0)
        # normal force: the law's value at this overlap
        assert -f0 @ n_now == pytest.approx(fn, rel=1e-9)
        ft = f0 - (f0 @ n_now) * n_now
        np.testing.assert_allclose(ft, hist[0], rtol=0, atol=1e-12 * fn)
        # sphere 0 is dragged along by sphere 1, tangentially
        assert ft @ tau_now == pytest.approx(np.linalg.norm(ft), rel=1e-9)
        # torques l_k n x ft, l_k = R_k - delta / 2
        np.testing.assert_allclose(e.t[0], (e.radius[0] - delta / 2) * np.cross(n_now, ft),
                                   rtol=0, atol=1e-12 * fn * 1e-3)
        np.testing.assert_allclose(e.t[1], (e.radius[1] - delta / 2) * np.cross(n_now, ft),
                                   rtol=0, atol=1e-12 * fn * 1e-3)
        forces.append((k * ds, np.linalg.norm(ft)))
    s, ft = np.array(forces).T
    stick = s < 0.9 * s_slip
    np.testing.assert_allclose(ft[stick] / s[stick], kt, rtol=1e-6)
    slide = s > 1.1 * s_slip
    np.testing.assert_allclose(ft[slide], mu * fn, rtol=1e-2)
    assert ft.max() == pytest.approx(mu * fn, rel=1e-2)
    print(f"\n{module.__name__}: stick stiffness {np.max(np.abs(ft[stick] / s[stick] / kt - 1)):.1e}, "
          f"sliding force {np.max(np.abs(ft[slide] / (mu * fn) - 1)):.1e} (relative errors)")


@pytest.mark.parametrize("module", [hm, lc], ids=["hertz_mindlin", "linear"])
def test_tangential_displacement_includes_rotation(module):
    """Turning sphere 1 by theta about n x tau shifts its contact point by l_1 theta along tau."""
    rng = np.random.default_rng(4)
    e, params, n, tau, delta, fn, kt, mu = _pressed_pair(module, rng)
    l1 = e.radius[1] - delta / 2
    omega, dt = 50.0, 1e-7
    e.w[1] = omega * np.cross(n, tau)
    hist = np.zeros((1, 3))
    for k in range(1, 11):
        module.compute(params, e, PAIR_I, PAIR_J, hist, dt)
        np.testing.assert_allclose(hist[0], -kt * l1 * omega * k * dt * tau, rtol=1e-9,
                                   atol=1e-15 * fn)
    assert np.linalg.norm(hist[0]) < mu * fn   # still sticking


def test_coulomb_force_ramp_dynamic():
    """A non-rotating sphere pressed by P on a fixed one, pushed by a slow tangential ramp T(t):
    it sticks with T = kt s, then slides once T exceeds mu P; the friction force stays at mu P."""
    R = 1e-3
    n = np.array([0.0, 0.0, 1.0])
    tau = np.array([1.0, 0.0, 0.0])
    e = two_spheres(R, R, n, gap=0.0)
    mu, P = 0.3, 1.0
    params = hm.Params(YOUNG, NU, friction=mu)
    r_star = R / 2
    delta = (P / hertz_K(E_STAR_SAME, r_star)) ** (2.0 / 3.0)
    e.x[1] = (2 * R - delta) * n
    kt = mindlin_kt_same(r_star, delta)
    for k in (0,):                       # sphere 0 fixed, neither sphere turns
        e.inv_mass[k] = 0.0
    e.inv_inertia[:] = 0.0
    m = e.mass[1]
    omega = np.sqrt(kt / m)
    dt = 2 * np.pi / omega / 60
    C = omega                            # zeta = 1/2 on the tangential mode
    T_end, ramp_steps = 1.5 * mu * P, 15_000
    hist = np.zeros((1, 3))
    x0 = e.x[1].copy()
    rows = []
    for k in range(1, ramp_steps + 1):
        kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 2)
        T = T_end * k / ramp_steps
        e.f[1] += -P * n + T * tau
        hm.compute(params, e, PAIR_I, PAIR_J, hist, dt)
        damp_elements(e, C)
        kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 2)
        rows.append((T, (e.x[1] - x0) @ tau, hist[0] @ tau, np.linalg.norm(hist[0])))
    T, s, h, hmag = np.array(rows).T
    stick = (T > 0.2 * mu * P) & (T < 0.8 * mu * P)
    np.testing.assert_allclose(h[stick] / s[stick], kt, rtol=1e-2)
    np.testing.assert_allclose(h[stick], T[stick], rtol=1e-2)
    assert hmag.max() == pytest.approx(mu * P, rel=1e-2)
    assert np.all(hmag <= mu * P * (1 + 1e-2))
    assert s[-1] > 20 * mu * P / kt     # it slid far beyond the elastic slip
    print(f"\ndynamic ramp: stick stiffness {np.max(np.abs(h[stick] / s[stick] / kt - 1)):.1e}, "
          f"max |ft| / mu P - 1 = {hmag.max() / (mu * P) - 1:+.1e}")


# ------------------------------------------------------------------------------------------------
# rigid rotation of a loaded contact

@pytest.mark.parametrize("module", [hm, lc], ids=["hertz_mindlin", "linear"])
def test_history_follows_rigid_rotation(module):
    rng = np.random.default_rng(5)
    e, params, n, tau, delta, fn, kt, mu = _pressed_pair(module, rng)
    h0 = 0.6 * mu * fn * (0.8 * tau + 0.6 * np.cross(n, tau))
    hist = h0[None, :].copy()
    centre = 0.5 * (e.x[0] + e.x[1])
    X0 = e.x - centre
    axis = random_unit(rng)
    total, steps = np.pi / 2, 2000
    Omega = axis * total / steps / 1e-6      # angular velocity [rad/s], dt = 1e-6 s
    dt = 1e-6
    worst_n = worst_mag = worst_f = worst_L = 0.0
    for k in range(1, steps + 1):
        Rk = rotmat(axis * total * k / steps)
        e.x[:] = centre + X0 @ Rk.T
        e.v[:] = np.cross(Omega, e.x - centre)
        e.w[:] = Omega
        e.f[:] = 0.0
        e.t[:] = 0.0
        module.compute(params, e, PAIR_I, PAIR_J, hist, dt)
        nk = Rk @ n
        worst_n = max(worst_n, abs(hist[0] @ nk) / np.linalg.norm(h0))
        worst_mag = max(worst_mag, abs(np.linalg.norm(hist[0]) / np.linalg.norm(h0) - 1.0))
        worst_f = max(worst_f, np.abs(e.f[0] + e.f[1]).max() / fn)
        L = np.cross(e.x[0], e.f[0]) + np.cross(e.x[1], e.f[1]) + e.t[0] + e.t[1]
        worst_L = max(worst_L, np.abs(L).max() / (fn * 1e-3))
    assert worst_n < 1e-12
    assert worst_mag < 1e-6
    assert worst_f < 1e-14
    assert worst_L < 1e-12
    # and the stored force turned with the pair (spin about n included)
    h_rot = rotmat(axis * total) @ h0
    angle = np.arccos(np.clip(hist[0] @ h_rot / np.linalg.norm(h0) ** 2, -1, 1))
    assert angle < 1e-3
    print(f"\n{module.__name__}: |h.n|/|h| {worst_n:.1e}, magnitude {worst_mag:.1e}, "
          f"F_i + F_j {worst_f:.1e}, torque balance {worst_L:.1e}, direction error {angle:.1e} rad")


# ------------------------------------------------------------------------------------------------
# random configurations: Newton's third law, angular momentum, loop vs brute force, periodic shifts

def _random_cluster(rng, n_side=3):
    """n_side^3 spheres on a jittered lattice of spacing 1.9 mm, radius ~1 mm: many overlaps."""
    g = np.arange(n_side) * 1.9e-3
    pos = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    pos += rng.uniform(-1.5e-4, 1.5e-4, pos.shape)
    radius = rng.uniform(0.95e-3, 1.1e-3, len(pos))
    e = Elements.from_spheres(pos, radius, RHO)
    e.v[:] = rng.normal(size=e.v.shape) * 0.3
    e.w[:] = rng.normal(size=e.w.shape) * 300.0
    return e


def _all_pairs(e, skin=0.2e-3):
    i, j = np.triu_indices(e.n_total, 1)
    d = np.linalg.norm(e.x[j] - e.x[i], axis=1)
    keep = d < e.radius[i] + e.radius[j] + skin
    return i[keep].astype(np.int32), j[keep].astype(np.int32)


def _models():
    return [
        (hm, hm.Params(YOUNG, NU, friction=0.4)),
        (hm, hm.Params(YOUNG, NU, friction=0.4, restitution=0.6)),
        (lc, lc.Params(kn=3e5, kt=1e5, friction=0.4)),
        (lc, lc.Params(kn=3e5, kt=1e5, friction=0.4, restitution=0.6)),
    ]


@pytest.mark.parametrize("model", range(4), ids=["hm", "hm_damped", "linear", "linear_damped"])
def test_random_configuration_balance_and_brute_force(model):
    module, params = _models()[model]
    rng = np.random.default_rng(10 + model)
    e = _random_cluster(rng)
    i, j = _all_pairs(e)
    dt = 1e-6
    # random stored forces: some beyond the cap (they get scaled back), some along n (removed)
    hist = rng.normal(size=(len(i), 3)) * 0.05
    full = np.zeros((e.n_total, e.n_total, 3))
    full[i, j] = hist
    assert len(i) > 40
    energy = module.compute(params, e, i, j, hist, dt)
    f, t = e.f.copy(), e.t.copy()
    touching = np.linalg.norm(e.x[j] - e.x[i], axis=1) < e.radius[i] + e.radius[j]
    assert touching.sum() > 20 and (~touching).sum() > 0
    assert np.all(hist[~touching] == 0.0)
    # Newton's third law and angular momentum about the origin
    scale = np.abs(f).max()
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-13 * scale)
    L = (np.cross(e.x, f) + t).sum(axis=0)
    np.testing.assert_allclose(L, 0.0, atol=1e-13 * scale * 1e-3)
    # pair by pair (single), equal and opposite and torque balanced
    for p in np.flatnonzero(touching)[:10]:
        r = module.single(params, e, int(i[p]), int(j[p]), full[i[p], j[p]], dt)
        np.testing.assert_allclose(r["history"], hist[p], rtol=1e-14, atol=0)
        Lp = (np.cross(e.x[i[p]], r["force_i"]) - np.cross(e.x[j[p]], r["force_i"])
              + r["torque_i"] + r["torque_j"])
        np.testing.assert_allclose(Lp, 0.0, atol=1e-13 * np.abs(r["force_i"]).max() * 1e-3)
    # the pair-list loop equals the brute-force loop over all pairs
    e.f[:] = 0.0
    e.t[:] = 0.0
    energy_bf = module.compute_all_pairs(params, e, full, dt)
    np.testing.assert_allclose(e.f, f, rtol=1e-13, atol=1e-14 * scale)
    np.testing.assert_allclose(e.t, t, rtol=1e-13, atol=1e-17 * scale)
    np.testing.assert_allclose(full[i, j], hist, rtol=1e-13, atol=0)
    assert energy_bf == pytest.approx(energy, rel=1e-13)
    # some contacts slide: their stored force sits on the cap
    assert energy > 0.0


@pytest.mark.parametrize("model", [1, 3], ids=["hm_damped", "linear_damped"])
def test_cluster_conserves_momenta(model):
    """A frictional, damped cluster integrated with velocity Verlet (brute-force pairs, history
    [n, n, 3]) keeps its linear and angular momentum (orbital + spin) to round-off, while the
    contacts dissipate energy: both follow from the pairwise balance of forces and torques."""
    module, params = _models()[model]
    rng = np.random.default_rng(30 + model)
    e = _random_cluster(rng)
    n = e.n_total
    full = np.zeros((n, n, 3))
    dt = 2e-7

    def momenta():
        p = e.mass @ e.v
        L = (np.cross(e.x, e.mass[:, None] * e.v) + e.inertia[:, None] * e.w).sum(axis=0)
        kin = 0.5 * np.sum(e.mass * np.sum(e.v**2, axis=1) + e.inertia * np.sum(e.w**2, axis=1))
        return p, L, kin

    u0 = module.compute_all_pairs(params, e, full, dt)
    p0, L0, k0 = momenta()
    scale_p = np.sum(e.mass * np.linalg.norm(e.v, axis=1))
    scale_L = np.sum(e.mass * np.linalg.norm(e.x, axis=1) * np.linalg.norm(e.v, axis=1)
                     + e.inertia * np.linalg.norm(e.w, axis=1))
    for _ in range(400):
        kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, dt, n)
        u = module.compute_all_pairs(params, e, full, dt)
        kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, dt, n)
    p1, L1, k1 = momenta()
    np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-13 * scale_p)
    np.testing.assert_allclose(L1, L0, rtol=0, atol=1e-11 * scale_L)   # round-off of 400 drifts
    assert k1 + u < 0.99 * (k0 + u0)


@pytest.mark.parametrize("module", [hm, lc], ids=["hertz_mindlin", "linear"])
def test_periodic_shift_equals_translated_partner(module):
    """Moving every element by its own lattice vector L m_k and passing shifts L (m_i - m_j) gives
    the forces, torques and history of the unshifted configuration."""
    params = _models()[0 if module is hm else 2][1]
    rng = np.random.default_rng(21)
    e = _random_cluster(rng)
    i, j = _all_pairs(e)
    hist0 = rng.normal(size=(len(i), 3)) * 0.05
    hist = hist0.copy()
    energy = module.compute(params, e, i, j, hist, 1e-6)
    f, t = e.f.copy(), e.t.copy()
    box = 7.3e-3
    m = rng.integers(-2, 3, size=(e.n_total, 3))
    e.x += box * m
    shift = (box * (m[i] - m[j])).astype(np.float64)
    e.f[:] = 0.0
    e.t[:] = 0.0
    hist_s = hist0.copy()
    energy_s = module.compute(params, e, i, j, hist_s, 1e-6, shift=shift)
    scale = np.abs(f).max()
    np.testing.assert_allclose(e.f, f, rtol=0, atol=1e-8 * scale)
    np.testing.assert_allclose(e.t, t, rtol=0, atol=1e-8 * scale * 1e-3)
    np.testing.assert_allclose(hist_s, hist, rtol=0, atol=1e-8 * np.abs(hist).max())
    assert energy_s == pytest.approx(energy, rel=1e-8)


@pytest.mark.parametrize("module", [hm, lc], ids=["hertz_mindlin", "linear"])
def test_force_is_minus_energy_gradient(module):
    """Frictionless, undamped: F_k = -dU/dx_k (central differences), so the returned energy is the
    potential of the normal law."""
    params = hm.Params(YOUNG, NU, friction=0.0) if module is hm else lc.Params(3e5, 1e5, friction=0.0)
    rng = np.random.default_rng(8)
    e = _random_cluster(rng, n_side=2)
    e.v[:] = 0.0
    e.w[:] = 0.0
    i, j = _all_pairs(e)
    hist = np.zeros((len(i), 3))
    module.compute(params, e, i, j, hist, 1e-6)
    f = e.f.copy()
    h = 1e-9
    for k in range(e.n_total):
        for d in range(3):
            U = []
            for sgn in (1, -1):
                e.x[k, d] += sgn * h
                U.append(module.compute(params, e, i, j, hist, 1e-6))
                e.x[k, d] -= sgn * h
            grad = (U[0] - U[1]) / (2 * h)
            assert -grad == pytest.approx(f[k, d], rel=1e-5, abs=1e-6 * np.abs(f).max())


# ------------------------------------------------------------------------------------------------
# elastic Hertz gas

@njit(cache=True)
def _periodic_pairs(x, radius, box, in_contact):
    """Pairs closer than R_i + R_j (minimum image), their shifts, and the number of new contacts."""
    n = x.shape[0]
    cap = n * 8
    pi = np.empty(cap, np.int32)
    pj = np.empty(cap, np.int32)
    shift = np.empty((cap, 3))
    m = 0
    new = 0
    for i in range(n):
        for j in range(i + 1, n):
            s = np.empty(3)
            d2 = 0.0
            for c in range(3):
                d = x[j, c] - x[i, c]
                s[c] = -box * np.round(d / box)
                d += s[c]
                d2 += d * d
            touching = d2 < (radius[i] + radius[j]) ** 2
            if touching:
                if not in_contact[i, j]:
                    new += 1
                pi[m] = i
                pj[m] = j
                shift[m] = s
                m += 1
            in_contact[i, j] = touching
    return pi[:m], pj[:m], shift[:m], new


def test_hertz_gas_conserves_energy():
    rng = np.random.default_rng(2)
    side = 5
    box = 14e-3
    a = box / side
    g = (np.arange(side) + 0.5) * a
    pos = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    pos += rng.uniform(-0.2e-3, 0.2e-3, pos.shape)
    radius = rng.uniform(0.9e-3, 1.1e-3, len(pos))
    young = 1e8
    params = hm.Params(young, NU, friction=0.0)
    e = Elements.from_spheres(pos, radius, 1000.0)
    e.v[:] = rng.normal(size=e.v.shape)
    e.v -= (e.mass @ e.v) / e.mass.sum()   # zero total momentum
    e.w[:] = rng.normal(size=e.w.shape) * 100.0
    n = e.n_total
    # step: 1/100 of the contact time of the lightest pair at 4x the rms relative speed
    m_min = e.mass.min() / 2
    tc, _ = hertz_duration(m_min, radius.min() / 2, params.e_star, 4 * np.sqrt(6.0))
    dt = tc / 100
    in_contact = np.zeros((n, n), dtype=np.bool_)

    def forces():
        pi, pj, shift, new = _periodic_pairs(e.x, e.radius, box, in_contact)
        hist = np.zeros((len(pi), 3))
        return hm.compute(params, e, pi, pj, hist, dt, shift=shift), new

    def total(u):
        return (0.5 * np.sum(e.mass * np.sum(e.v**2, axis=1))
                + 0.5 * np.sum(e.inertia * np.sum(e.w**2, axis=1)) + u)

    u, _ = forces()
    E0 = total(u)
    collisions = 0
    worst = 0.0
    for _ in range(12_000):
        kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, dt, n)
        e.x %= box
        u, new = forces()
        kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, dt, n)
        collisions += new
        worst = max(worst, abs(total(u) / E0 - 1.0))
    assert collisions > 200
    assert worst < 1e-3
    np.testing.assert_allclose(e.mass @ e.v, 0.0, atol=1e-12 * np.sum(e.mass))
    print(f"\nHertz gas: {n} spheres, {collisions} collisions, worst |E/E0 - 1| = {worst:.2e}")


# ------------------------------------------------------------------------------------------------
# global viscous damping

def test_viscous_damping_decay():
    """A free sphere under -C m v, -C I w slows down as exp(-C t)."""
    e = Elements.from_spheres(np.zeros((1, 3)), 1e-3, RHO)
    e.v[0] = [0.3, -0.2, 0.1]
    e.w[0] = [10.0, 20.0, -5.0]
    v0, w0 = e.v[0].copy(), e.w[0].copy()
    C, dt, steps = 200.0, 1e-5, 1000     # C dt = 2e-3, C T = 2
    power = damp_elements(e, C)
    assert power == pytest.approx(C * (e.mass[0] * v0 @ v0 + e.inertia[0] * w0 @ w0), rel=1e-14)
    for _ in range(steps):
        kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 1)
        damp_elements(e, C)
        kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 1)
    decay = np.exp(-C * dt * steps)
    np.testing.assert_allclose(e.v[0], v0 * decay, rtol=3e-3)
    np.testing.assert_allclose(e.w[0], w0 * decay, rtol=3e-3)
    with pytest.raises(ValueError):
        damp_elements(e, -1.0)


def test_params_validation():
    with pytest.raises(ValueError, match="poisson"):
        hm.Params(YOUNG, 0.6)
    with pytest.raises(ValueError, match="restitution"):
        lc.Params(1e4, 1e4, restitution=0.0)
    with pytest.raises(ValueError, match="kt"):
        lc.Params(1e4, -1.0)
    # two materials: 1/E* = sum (1 - nu^2)/E, 1/G* = sum (2 - nu)/G
    p = hm.Params(YOUNG, NU, young2=3 * YOUNG, poisson2=0.2)
    g2 = 3 * YOUNG / 2.4
    assert p.e_star == pytest.approx(1 / ((1 - NU**2) / YOUNG + (1 - 0.04) / (3 * YOUNG)), rel=1e-14)
    assert p.g_star == pytest.approx(1 / ((2 - NU) / SHEAR + 1.8 / g2), rel=1e-14)
    # identical grains: 8 G* = 4 G / (2 - nu)
    assert 8 * hm.Params(YOUNG, NU).g_star == pytest.approx(4 * SHEAR / (2 - NU), rel=1e-14)
    assert hm.cutoff(p, 1e-3) == lc.cutoff(lc.Params(1, 1), 1e-3) == 2e-3


def test_contact_modules_import_neither_mpi_nor_h5py():
    """STYLE pattern 1: physics kernels are pure array code."""
    import ast
    import inspect
    from pardem.physics import contact_frame, viscous_damping
    for module in (hm, lc, contact_frame, viscous_damping):
        tree = ast.parse(inspect.getsource(module))
        names = {a.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import)
                 for a in node.names}
        names |= {node.module.split(".")[0] for node in ast.walk(tree)
                  if isinstance(node, ast.ImportFrom) and node.module}
        assert not names & {"mpi4py", "h5py"}, module.__name__


# ------------------------------------------------------------------------------------------------
# the registry and the generic loops (pardem.physics.contact_laws, pair_loop)

def _registry_models():
    """Every sub-model of every registered law (a new law must add its own here)."""
    cement = dict(cement_normal=2e4, cement_tangential=1e4, cement_fade_time=3e-6)
    return {
        "hertz_mindlin": [hm.Params(YOUNG, NU, friction=0.4),
                          hm.Params(YOUNG, NU, friction=0.4, restitution=0.6),
                          hm.Params(YOUNG, NU, friction=0.4, **cement),
                          hm.Params(YOUNG, NU, friction=0.4, restitution=0.6, **cement)],
        "linear": [lc.Params(kn=3e5, kt=1e5, friction=0.4),
                   lc.Params(kn=3e5, kt=1e5, friction=0.4, restitution=0.6)],
        "hertz_mindlin_rolling": [hmr.Params(YOUNG, NU, rolling_friction=0.1, friction=0.4),
                                  hmr.Params(YOUNG, NU, rolling_friction=0.1, friction=0.4,
                                             restitution=0.6, rolling_stiffness=1e-3)],
    }


def _cemented_history(rng, n_pairs, width):
    """Random stored tangential forces; with 9 columns also intact, fading and absent cements."""
    hist = np.zeros((n_pairs, width))
    hist[:, :3] = rng.normal(size=(n_pairs, 3)) * 0.05
    if width == hm.WIDTH_CEMENTED:
        state = rng.choice([1.0, -0.5, 0.0], size=n_pairs)
        live = state != 0.0
        hist[live, hm.CEMENT_FORCE:hm.CEMENT_FORCE + 3] = rng.normal(size=(live.sum(), 3)) * 0.01
        hist[live, hm.CEMENT_DELTA0] = rng.uniform(-2e-5, 5e-5, live.sum())
        hist[live, hm.CEMENT_THRESHOLD] = rng.uniform(1e-9, 1e-7, live.sum())
        hist[:, hm.CEMENT_STATE] = state
    return hist


def test_registry_rows_follow_the_protocol():
    from pardem.physics import contact_laws
    assert set(_registry_models()) == set(contact_laws.LAWS)
    members = [m for m in vars(contact_laws.ContactLaw) if not m.startswith("_")]
    for name, row in contact_laws.LAWS.items():
        for member in members:
            assert hasattr(row, member), (name, member)
        assert contact_laws.law(name) is row
        for params in _registry_models()[name]:
            assert isinstance(params, row.Params)
            assert row.history_width(params) >= 3
            k_constant, k_hertz = row.normal_stiffness(params)
            assert k_constant >= 0.0 and k_hertz >= 0.0 and k_constant + k_hertz > 0.0
            assert 0.0 < row.critical_time_step(params, np.array([1e-3]), RHO) < np.inf
    with pytest.raises(ValueError, match="contact law"):
        contact_laws.law_params("plastic", {})


@pytest.mark.parametrize("name,model", [(n, k) for n, ms in _registry_models().items()
                                        for k in range(len(ms))])
def test_generic_loop_equals_all_pairs_twin_and_single_bitwise(name, model):
    """The neighbour-list loop, its all-pairs twin and ``single`` are one generic code path per
    law function: on a pair list in (i, j) order they agree bit for bit (forces, torques, history,
    energy), for every law and sub-model (damping, cement)."""
    from pardem.physics import contact_laws
    law = contact_laws.LAWS[name]
    params = _registry_models()[name][model]
    rng = np.random.default_rng(50 + model)
    e = _random_cluster(rng)
    i, j = _all_pairs(e)
    dt = 1e-6
    width = law.history_width(params)
    hist = _cemented_history(rng, len(i), width)
    full = np.zeros((e.n_total, e.n_total, width))
    full[i, j] = hist
    before = hist.copy()
    energy = law.compute(params, e, i, j, hist, dt)
    f, t = e.f.copy(), e.t.copy()
    assert np.any(f != 0.0) and np.any(hist != before)
    for p in range(len(i)):   # single: the step's loads of one pair, nothing modified
        r = law.single(params, e, int(i[p]), int(j[p]), before[p], dt)
        np.testing.assert_array_equal(r["history"], hist[p])
    e.f[:] = 0.0
    e.t[:] = 0.0
    energy_bf = law.compute_all_pairs(params, e, full, dt)
    np.testing.assert_array_equal(e.f, f)
    np.testing.assert_array_equal(e.t, t)
    np.testing.assert_array_equal(full[i, j], hist)
    assert energy_bf == energy
    # without the energy the loop gives the same loads
    e.f[:] = 0.0
    e.t[:] = 0.0
    hist2 = before.copy()
    assert np.isnan(law.compute(params, e, i, j, hist2, dt, with_energy=False))
    np.testing.assert_array_equal(e.f, f)
    np.testing.assert_array_equal(hist2, hist)


def test_wall_laws_are_the_pair_laws_with_a_sphere_of_infinite_radius():
    """A sphere on a wall and the same sphere against a huge, heavy partner sphere give the same
    normal force (the walls use the pair laws' normal functions with R* = R, m* = m)."""
    from pardem.physics import walls as W
    R, delta, big = 1e-3, 2e-6, 1e3
    for law, pair_params, wall_params in [
            ("hertz", hm.Params(YOUNG, NU, friction=0.0),
             W.Params(law="hertz", young=YOUNG, poisson=NU, wall_young=YOUNG, wall_poisson=NU)),
            ("linear", lc.Params(kn=3e5, kt=1e5, friction=0.0),
             W.Params(law="linear", kn=3e5, kt=1e5))]:
        e = Elements.from_spheres(np.array([[0.0, 0.0, R - delta]]), np.array([R]), RHO)
        r_wall = W.single(wall_params, e, 0, (0.0, 0.0, 1.0), 0.0)
        p = Elements.from_spheres(np.array([[0.0, 0.0, R - delta], [0.0, 0.0, -big]]),
                                  np.array([R, big]), RHO)
        module = hm if law == "hertz" else lc
        r_pair = module.single(pair_params, p, 0, 1, np.zeros(3), 1e-6)
        assert r_wall["touching"] and r_pair["touching"]
        assert r_wall["force"][2] == pytest.approx(r_pair["force_i"][2], rel=1e-5)
