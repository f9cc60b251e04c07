"""Element-wall contact (pardem.physics.walls), docs/physics.md sections 5 and 8, against independent results.

Normal laws
    Hertz sphere-plane ``fn = 4/3 E* sqrt(R) delta^(3/2)`` with ``1/E* = (1 - nu^2)/E + (1 - nu_w^2)/E_w``
    written out here; linear ``kn delta``; both as forces of the returned energy (F = -dU/dx), and
    the linear law against a NumPy evaluation of ``k * overlap`` per element and plate.
Restitution
    a sphere hitting a moving wall rebounds, in the wall's frame, at ``e`` times its approach speed.
Coulomb limit
    a rigid block of four spheres with unequal overlaps, pressed by ``F_n`` and pulled by a slow
    tangential ramp ``F_t(t)``: while it sticks its displacement is the quasi-static
    ``F_t = sum_i min(kt_i s, mu fn_i)`` (partial slip included, kt_i analytic), it starts sliding when
    ``F_t = mu F_n`` and then accelerates as ``M dv/dt = F_t - mu F_n``.
Sliding into rolling
    friction acts at the contact point, so the angular momentum about it is conserved exactly
    (``m l v + I w``) and the sphere ends rolling at ``v0 / (1 + I / (m l^2))`` (5/7 v0 for l = R).
Kinematic identities
    moment balance about the contact point, history carried by a rigid tilt of the wall with its
    element, no turn of the history by a drilling spin, owned rows only, no contact no force.
"""
import math

import numpy as np
import pytest

from pardem.physics import walls as W
from pardem.physics.hertz_mindlin import hertz_damping_coefficient
from pardem.physics.linear_contact import damping_ratio
from pardem.physics.verlet import kick, kick_drift
from pardem.engine.state import Elements
from _util import perpendicular, random_unit, rotmat

RHO = 2500.0
YOUNG, NU = 1.0e9, 0.3
WALL_YOUNG, WALL_NU = 3.0e9, 0.2
HERTZ_TC = 3.21807   # elastic Hertz contact time t_c = 3.21807 (m / K)^(2/5) v^(-1/5), test_contacts


def e_star(young=YOUNG, nu=NU, wall_young=WALL_YOUNG, wall_nu=WALL_NU):
    return 1.0 / ((1.0 - nu**2) / young + (1.0 - wall_nu**2) / wall_young)


def g_star(young=YOUNG, nu=NU, wall_young=WALL_YOUNG, wall_nu=WALL_NU):
    g, gw = young / (2 * (1 + nu)), wall_young / (2 * (1 + wall_nu))
    return 1.0 / ((2.0 - nu) / g + (2.0 - wall_nu) / gw)


def hertz_params(**kw):
    return W.Params(law="hertz", young=YOUNG, poisson=NU, wall_young=WALL_YOUNG,
                    wall_poisson=WALL_NU, **kw)


def one_wall(normal, offset, velocity=(0.0, 0.0, 0.0)):
    return (np.array([normal], dtype=float), np.array([offset], dtype=float),
            np.array([velocity], dtype=float), np.zeros((1, 3)))


def run(params, e, normals, offsets, velocities, hist=None, dt=1e-7):
    """One call on zeroed loads: (energy, f, t, wall_force, history)."""
    if hist is None:
        hist = W.new_history(params, e.n_total, len(offsets))
    wf = np.zeros((len(offsets), 3))
    e.f[:] = 0.0
    e.t[:] = 0.0
    energy = W.compute(params, e, normals, offsets, velocities, hist, dt, wf)
    return energy, e.f.copy(), e.t.copy(), wf, hist


BOX = 5e-2   # the walls of the kinematic tests are the faces of a polytope around the origin


def spheres_on_walls(rng, radii, normals, overlaps):
    """Element k touching wall k by overlaps[k]; wall k has offset ``-BOX`` (it lies ``BOX`` from the
    origin, facing it), and the element sits near the foot of the perpendicular."""
    pos = []
    for r, n, d in zip(radii, normals, overlaps):
        pos.append(-(BOX - r + d) * np.asarray(n) + 1e-3 * perpendicular(n, rng))
    return Elements.from_spheres(np.array(pos), np.asarray(radii, dtype=float), RHO)


def overlaps_of(e, normals, offsets):
    return e.radius[:, None] - (e.x @ normals.T - offsets[None, :])


# ------------------------------------------------------------------------------------------------
# normal laws

@pytest.mark.parametrize("law", ["hertz", "linear"])
def test_normal_force_law_and_energy(law):
    rng = np.random.default_rng(1)
    nw = 5
    normals = np.array([random_unit(rng) for _ in range(nw)])
    radii = rng.uniform(0.8e-3, 1.3e-3, nw)
    overlaps = rng.uniform(1e-3, 2e-2, nw) * radii
    e = spheres_on_walls(rng, radii, normals, overlaps)
    e.v[:] = rng.normal(size=(nw, 3))      # ignored: undamped and frictionless
    e.w[:] = rng.normal(size=(nw, 3)) * 100.0
    # the walls lie far apart, so element k touches wall k only
    offsets = np.full(nw, -BOX)
    assert np.sum(overlaps_of(e, normals, offsets) > 0) == nw
    overlaps = np.diag(overlaps_of(e, normals, offsets))   # as rounded in the positions
    kn = 3e5
    params = hertz_params() if law == "hertz" else W.Params(kn=kn)
    energy, f, t, wf, _ = run(params, e, normals, offsets, np.zeros((nw, 3)))
    if law == "hertz":
        fn = 4.0 / 3.0 * e_star() * np.sqrt(radii) * overlaps**1.5
        u = 8.0 / 15.0 * e_star() * np.sqrt(radii) * overlaps**2.5
    else:
        fn = kn * overlaps
        u = 0.5 * kn * overlaps**2
    np.testing.assert_allclose(f, fn[:, None] * normals, rtol=1e-12, atol=1e-14 * fn.max())
    np.testing.assert_array_equal(t, 0.0)
    np.testing.assert_allclose(wf, -f, rtol=1e-15, atol=0)
    assert energy == pytest.approx(u.sum(), rel=1e-12)
    # F = -dU/dx and the tangent stiffness dfn/d(delta) that walls.stiffness reports
    h = 1e-10
    for k in range(nw):
        for d in range(3):
            U = []
            for sgn in (1, -1):
                e.x[k, d] += sgn * h
                U.append(run(params, e, normals, offsets, np.zeros((nw, 3)))[0])
                e.x[k, d] -= sgn * h
            assert -(U[0] - U[1]) / (2 * h) == pytest.approx(f[k, d], rel=1e-5, abs=1e-7 * fn.max())
        e.x[k] -= h * normals[k]          # overlap + h
        fn_plus = run(params, e, normals, offsets, np.zeros((nw, 3)))[1][k] @ normals[k]
        e.x[k] += h * normals[k]
        kn_tangent, _ = W.stiffness(params, radii[k], overlaps[k])
        assert (fn_plus - fn[k]) / h == pytest.approx(kn_tangent, rel=1e-4)


def test_rigid_wall_and_same_material():
    """wall_young = inf gives E* = E / (1 - nu^2); the default wall material is the element's."""
    rigid = W.Params(law="hertz", young=YOUNG, poisson=NU, wall_young=math.inf)
    same = W.Params(law="hertz", young=YOUNG, poisson=NU)
    assert rigid.stiff_n == pytest.approx(YOUNG / (1 - NU**2), rel=1e-15)
    assert same.stiff_n == pytest.approx(e_star(wall_young=YOUNG, wall_nu=NU), rel=1e-15)
    assert same.stiff_t == pytest.approx(g_star(wall_young=YOUNG, wall_nu=NU), rel=1e-15)


def plate_forces(x, radius, f, n_owned, axis, positions, sides, stiffness, plate_force):
    """Reference: linear frictionless plates in NumPy (the engine's former plate kernel)."""
    energy = 0.0
    for p in range(len(positions)):
        overlap = np.clip(radius[:n_owned] - sides[p] * (x[:n_owned, axis] - positions[p]), 0.0, None)
        fn = stiffness[p] * overlap
        f[:n_owned, axis] += sides[p] * fn
        plate_force[p] = fn.sum()
        energy += float(np.sum(0.5 * fn * overlap))
    return energy


def test_linear_walls_equal_plate_forces():
    """Axis planes with the linear frictionless law reproduce the plate law (NumPy reference)."""
    rng = np.random.default_rng(2)
    pos = rng.uniform(0.0, 1e-2, size=(300, 3))
    e = Elements.from_spheres(pos, rng.uniform(0.3e-3, 0.6e-3, 300), RHO)
    e.n_owned = 250
    for axis in range(3):
        positions, sides = np.array([0.4e-3, 9.5e-3]), np.array([1.0, -1.0])
        stiffness = np.full(2, 2e5)
        plate_force = np.zeros(2)
        e.f[:] = 0.0
        u_ref = plate_forces(e.x, e.radius, e.f, e.n_owned, axis, positions, sides, stiffness,
                             plate_force)
        f_ref = e.f.copy()
        normals, offsets = W.axis_planes(axis, positions, sides)
        energy, f, t, wf, _ = run(W.Params(kn=2e5), e, normals, offsets, np.zeros((2, 3)))
        assert np.count_nonzero(f_ref[:, axis]) > 10
        np.testing.assert_allclose(f, f_ref, rtol=1e-15, atol=0)
        np.testing.assert_allclose(-np.sum(wf * normals, axis=1), plate_force, rtol=1e-14)
        assert energy == pytest.approx(u_ref, rel=1e-14)


# ------------------------------------------------------------------------------------------------
# restitution

def drop(params, e, n, wall_v, v_in, dt, max_steps=100_000):
    """Sphere row 0 hits the wall (normal n, moving at wall_v) with velocity v_in; velocity Verlet.

    Returns the velocity after the separation [m/s].
    """
    normals, offsets, velocities, wf = one_wall(n, 0.0, wall_v)
    off0 = e.x[0] @ n - e.radius[0] - 10 * dt * ((wall_v - v_in) @ n)   # contact after ~10 steps
    hist = W.new_history(params, 1, 1)
    e.v[0] = v_in
    offsets[0] = off0
    W.compute(params, e, normals, offsets, velocities, hist, dt, wf)
    touched = False
    for k in range(1, max_steps):
        kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 1)
        offsets[0] = off0 + (wall_v @ n) * k * dt
        W.compute(params, e, normals, offsets, velocities, hist, dt, wf)
        kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 1)
        delta = e.radius[0] - (e.x[0] @ n - offsets[0])
        touched |= delta > 0.0
        if touched and delta <= 0.0:
            return e.v[0].copy()
    raise AssertionError("the sphere did not leave the wall")


@pytest.mark.parametrize("law", ["hertz", "linear"])
@pytest.mark.parametrize("e_target", [0.9, 0.5, 0.1])
def test_restitution_on_a_moving_wall(law, e_target):
    rng = np.random.default_rng(3)
    n = random_unit(rng)
    tau = perpendicular(n, rng)
    R = 1e-3
    e = Elements.from_spheres(np.zeros((1, 3)), R, RHO)
    m = e.mass[0]
    wall_v = 0.3 * n + 0.4 * tau
    v_in = -0.9 * n - 0.2 * tau
    approach = (wall_v - v_in) @ n
    if law == "hertz":
        params = hertz_params(restitution=e_target)
        K = 4.0 / 3.0 * e_star() * np.sqrt(R)
        dt = HERTZ_TC * (m / K) ** 0.4 * approach**-0.2 / 2000
    else:
        kn = 2e4
        params = W.Params(kn=kn, restitution=e_target)
        dt = np.pi / np.sqrt(kn / m) / 2000
    v_out = drop(params, e, n, wall_v, v_in, dt)
    rebound = (v_out - wall_v) @ n
    assert rebound / approach == pytest.approx(e_target, rel=1e-2)
    # frictionless: the tangential velocity is untouched, no spin
    t_in = v_in - (v_in @ n) * n
    np.testing.assert_allclose(v_out - (v_out @ n) * n, t_in, rtol=0, atol=1e-14)
    assert np.all(e.w == 0.0)
    measured = rebound / approach
    print(f"\n{law} e={e_target}: measured {measured:.5f} ({measured / e_target - 1:+.1e})")


def test_damped_normal_force_formula():
    """One contact with an approach rate: fn = kn delta + 2 zeta sqrt(kn m) d(delta)/dt (zeta from
    the no-tension calibration) and Hertz fn_el + gamma sqrt(m 2 E* a) d(delta)/dt."""
    rng = np.random.default_rng(4)
    n = random_unit(rng)
    R, delta = 1e-3, 2e-6
    e = spheres_on_walls(rng, [R], [n], [delta])
    normals, offsets, velocities, _ = one_wall(n, -BOX, 0.1 * n)
    e.v[0] = -0.25 * n + 0.3 * perpendicular(n, rng)
    rate = 0.35                                      # d(delta)/dt = (V_wall - v) . n
    delta = overlaps_of(e, normals, offsets)[0, 0]
    m = e.mass[0]
    lin = W.Params(kn=1e5, restitution=0.4)
    f = run(lin, e, normals, offsets, velocities)[1][0]
    assert f @ n == pytest.approx(1e5 * delta + 2 * damping_ratio(0.4) * np.sqrt(1e5 * m) * rate,
                                  rel=1e-12)
    hz = hertz_params(restitution=0.4)
    f = run(hz, e, normals, offsets, velocities)[1][0]
    a = np.sqrt(R * delta)
    expected = (4 / 3 * e_star() * a * delta
                + hertz_damping_coefficient(0.4) * np.sqrt(m * 2 * e_star() * a) * rate)
    assert f @ n == pytest.approx(expected, rel=1e-12)
    # leaving fast enough: the dashpot would pull, the force is clipped at zero
    e.v[0] = 5.0 * n
    assert np.all(run(lin, e, normals, offsets, velocities)[1] == 0.0)
    assert np.all(run(hz, e, normals, offsets, velocities)[1] == 0.0)


# ------------------------------------------------------------------------------------------------
# Coulomb limit: a rigid block of spheres on a frictional wall

def _solve_heights(fn_of, extras, radii, F_n):
    """Block height z (n . X - offset) with sum_i fn_i(extras_i - z) = F_n (bisection)."""
    lo, hi = -1e-2, extras.min()            # z -> -inf: huge force; z = min extra: smallest
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        d = extras - mid
        if np.sum(fn_of(np.maximum(d, 0.0), radii)) > F_n:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("law, restitution", [("hertz", 1.0), ("linear", 1.0), ("linear", 0.5)])
def test_coulomb_limit_of_a_block(law, restitution):
    rng = np.random.default_rng(5)
    n = random_unit(rng)
    tau = perpendicular(n, rng)
    b = np.cross(n, tau)
    radii = np.array([1.0, 1.2, 0.9, 1.1]) * 1e-3
    corners = np.array([[-1.5, -1.5], [1.5, -1.5], [-1.5, 1.5], [1.5, 1.5]]) * 1e-3
    mu, F_n = 0.4, 2.0
    if law == "hertz":
        params = hertz_params(friction=mu, restitution=restitution)
        Es, Gs = e_star(), g_star()

        def fn_of(d, r):
            return 4.0 / 3.0 * Es * np.sqrt(r) * d**1.5

        def kt_of(d, r):
            return 8.0 * Gs * np.sqrt(r * d)
        d_ref = (F_n / 4 / (4.0 / 3.0 * Es * np.sqrt(1e-3))) ** (2 / 3)
    else:
        kn, kt = 4e5, 2.5e5
        params = W.Params(kn=kn, kt=kt, friction=mu, restitution=restitution)

        def fn_of(d, r):
            return kn * d

        def kt_of(d, r):
            return np.full_like(d, kt)
        d_ref = F_n / 4 / kn
    extras = np.array([0.0, 0.3, 0.6, 0.9]) * d_ref
    z = _solve_heights(fn_of, extras, radii, F_n)
    deltas = extras - z
    fn = fn_of(deltas, radii)
    kts = kt_of(deltas, radii)
    assert np.sum(fn) == pytest.approx(F_n, rel=1e-12)
    s_slip = mu * fn / kts                  # each contact slides beyond its own elastic slip
    order = np.argsort(s_slip)
    assert s_slip.max() > 1.3 * s_slip.min()   # contacts slide one after the other
    s_el = s_slip.max()

    def quasi_static_force(s):
        return np.sum(np.minimum(kts[None, :] * s[:, None], mu * fn[None, :]), axis=1)

    offset = 0.37e-3
    rel = np.array([c[0] * tau + c[1] * b + (r - x) * n for c, r, x in zip(corners, radii, extras)])
    X0 = (offset + z) * n + 2e-3 * tau
    e = Elements.from_spheres(X0 + rel, radii, RHO)
    M = e.mass.sum()
    normals, offsets, velocities, wf = one_wall(n, offset)
    hist = W.new_history(params, 4, 1)
    assert hist.shape == (4, 1, 3)

    period = 2 * np.pi * np.sqrt(M / kts.sum())
    dt = period / 20
    ramp_periods, smooth = 500, 20 * period
    T_ramp = ramp_periods * period
    rate = 1.3 * mu * F_n / T_ramp          # dF_t/dt after the smooth start

    def applied(time):
        if time < smooth:
            return 0.5 * rate * (time - smooth / np.pi * np.sin(np.pi * time / smooth))
        return rate * (time - 0.5 * smooth)

    def forces(X, V, time):
        e.x[:] = X + rel
        e.v[:] = V
        e.f[:] = 0.0
        e.t[:] = 0.0
        W.compute(params, e, normals, offsets, velocities, hist, dt, wf)
        return e.f.sum(axis=0) - F_n * n + applied(time) * tau

    X, V = X0.copy(), np.zeros(3)
    F = forces(X, V, 0.0)
    rows = []
    steps = int(T_ramp / dt)
    for k in range(1, steps + 1):
        V += 0.5 * dt / M * F
        X += dt * V
        F = forces(X, V, k * dt)
        V += 0.5 * dt / M * F
        rows.append((k * dt, applied(k * dt), (X - X0) @ tau, V @ tau, wf[0] @ tau, wf[0] @ n,
                     (X - X0) @ n, (X - X0) @ b))
    time, Ft, s, v, ft_wall, fn_wall, sn, sb = np.array(rows).T
    # the normal load is carried, the block neither sinks nor drifts sideways
    np.testing.assert_allclose(-fn_wall, F_n, rtol=1e-9)
    assert np.abs(sn).max() < 1e-9 * d_ref and np.abs(sb).max() < 1e-9 * s_el
    # sticking: the displacement is the quasi-static one of the analytic springs (partial slip
    # included), so it stays within the elastic slip s_el
    stick = Ft < 0.99 * mu * F_n
    grid = np.linspace(0.0, s_el, 20001)
    s_qs = np.interp(Ft[stick], quasi_static_force(grid), grid)
    assert np.abs(s[stick] - s_qs).max() < 1e-2 * s_el
    assert s[stick].max() < s_el
    first_slip = quasi_static_force(s_slip[order[:1]])[0]      # before it, no contact slides
    early = (Ft > 0.3 * first_slip) & (Ft < 0.9 * first_slip)
    np.testing.assert_allclose(Ft[early] / s[early], kts.sum(), rtol=1e-2)
    # onset of sliding: the displacement leaves the elastic range when F_t reaches mu F_n
    on = np.argmax(s > 1.05 * s_el)
    assert on > 0
    assert Ft[on] / (mu * F_n) == pytest.approx(1.0, abs=1e-2)
    assert Ft[on] > (1.0 - 1e-3) * mu * F_n
    # then it slides and accelerates against the full Coulomb force: M dv/dt = F_t - mu F_n
    assert s[-1] > 100 * s_el
    np.testing.assert_allclose(ft_wall[on:], mu * F_n, rtol=1e-9)   # the wall is dragged along
    gain = np.trapezoid(Ft[on:] - mu * F_n, time[on:]) / M
    assert v[-1] - v[on] == pytest.approx(gain, rel=1e-3)
    assert np.all(np.diff(v[on:]) > 0.0)
    print(f"\n{law} e={restitution}: onset at F_t / mu F_n = {Ft[on] / (mu * F_n):.5f}, "
          f"stick error {np.abs(s[stick] - s_qs).max() / s_el:.1e} s_el, slip ratios "
          f"{np.round(s_slip / s_el, 3)}")


# ------------------------------------------------------------------------------------------------
# sliding into rolling

@pytest.mark.parametrize("law", ["hertz", "linear"])
def test_sliding_sphere_ends_rolling(law):
    rng = np.random.default_rng(6)
    n = random_unit(rng)
    tau = perpendicular(n, rng)
    R, P, mu, v0 = 1e-3, 0.05, 0.3, 0.2
    if law == "hertz":
        params = hertz_params(friction=mu)
        delta = (P / (4.0 / 3.0 * e_star() * np.sqrt(R))) ** (2 / 3)
        kt = 8.0 * g_star() * np.sqrt(R * delta)
    else:
        kt = 2e4
        params = W.Params(kn=5e4, kt=kt, friction=mu, restitution=0.3)
        delta = P / 5e4
    e = spheres_on_walls(rng, [R], [n], [delta])
    normals, offsets, velocities, wf = one_wall(n, -BOX)
    hist = W.new_history(params, 1, 1)
    m, I = e.mass[0], e.inertia[0]
    l = R - delta / 2
    v_roll = v0 / (1.0 + I / (m * l * l))
    e.v[0] = v0 * tau
    omega_t = np.sqrt(kt * (1 / m + l * l / I))
    dt = 2 * np.pi / omega_t / 40

    def angular_momentum():
        """About the contact point x - l n."""
        return np.cross(l * n, m * e.v[0]) + I * e.w[0]

    L0 = angular_momentum()
    a_slide = mu * P / m
    t_slide = (v0 - v_roll) / a_slide
    steps = int(3 * t_slide / dt) + 4000
    W.compute(params, e, normals, offsets, velocities, hist, dt, wf)
    e.f[0] -= P * n
    rows = []
    for k in range(1, steps + 1):
        kick_drift(e.x, e.v, e.w, e.q, e.rot, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 1)
        W.compute(params, e, normals, offsets, velocities, hist, dt, wf)
        e.f[0] -= P * n
        kick(e.v, e.w, e.f, e.t, e.inv_mass, e.inv_inertia, dt, 1)
        slip = e.v[0] - l * np.cross(e.w[0], n)
        rows.append((k * dt, e.v[0] @ tau, l * np.cross(e.w[0], n) @ tau, slip @ tau,
                     np.linalg.norm(hist[0, 0]), np.abs(angular_momentum() - L0).max()))
    time, v, lw, slip, h, dL = np.array(rows).T
    # the normal pressing stays balanced, the motion stays along tau
    assert abs((e.x[0] @ n + BOX) - (R - delta)) < 1e-9 * delta
    assert dL.max() < 1e-12 * np.abs(L0).max()
    # sliding: Coulomb force mu P, the sphere decelerates and spins up at the rates it implies
    sliding = (time < 0.8 * t_slide) & (h > (1 - 1e-9) * mu * P)
    assert sliding.sum() > 0.5 * np.sum(time < 0.8 * t_slide)
    both = sliding[1:] & sliding[:-1]
    np.testing.assert_allclose(np.diff(v)[both] / dt, -a_slide, rtol=1e-6)
    np.testing.assert_allclose(np.diff(lw)[both] / dt, a_slide * m * l * l / I, rtol=1e-6)
    # then rolling: the stored force stays within the cap (without a tangential dashpot the
    # stick oscillation starts at the cap, so it touches it at every swing)
    rolling = time > 1.2 * t_slide
    assert np.all(h[rolling] <= mu * P * (1 + 1e-8))    # fn = P to the rounding of the overlap
    print(f"\nslip velocity while rolling: mean {np.mean(slip[rolling]):.2e}, "
          f"largest {np.abs(slip[rolling]).max():.2e} m/s; v_roll {v_roll:.4f}")
    if law == "linear":   # the tangential dashpot brings the contact to rest
        assert v[-1] == pytest.approx(v_roll, rel=1e-6)
        assert lw[-1] == pytest.approx(v_roll, rel=1e-6)
    else:                 # undamped stick oscillation about the rolling velocity
        assert np.mean(v[rolling]) == pytest.approx(v_roll, rel=1e-2)
        assert np.mean(lw[rolling]) == pytest.approx(v_roll, rel=1e-2)
    assert abs(v_roll / v0 - 5 / 7) < 1e-2                      # l is almost R
    print(f"\n{law}: rolling at {v[-1]:.6f} m/s (last step), analytic {v_roll:.6f}; "
          f"|dL|/L {dL.max() / np.abs(L0).max():.1e}")


# ------------------------------------------------------------------------------------------------
# kinematic identities

def _random_contacts(rng):
    """Six elements, three walls (offsets -BOX), random velocities: elements 0-2 touch one wall
    each, elements 3-5 sit in the corner of two walls. Returns (elements, normals, offsets)."""
    normals = np.array([random_unit(rng) for _ in range(3)])
    radii = rng.uniform(0.8e-3, 1.2e-3, 6)
    e = spheres_on_walls(rng, radii[:3], normals, radii[:3] * 0.01)
    extra = []
    for k, (a, c) in enumerate([(0, 1), (1, 2), (0, 2)]):
        A = np.array([normals[a], normals[c], np.cross(normals[a], normals[c])])
        rhs = np.array([0.99 * radii[3 + k] - BOX, 0.985 * radii[3 + k] - BOX, 0.0])
        extra.append(np.linalg.solve(A, rhs))
    e = Elements.from_spheres(np.vstack([e.x, extra]), radii, RHO)
    e.v[:] = rng.normal(size=(6, 3)) * 0.1
    e.w[:] = rng.normal(size=(6, 3)) * 100.0
    offsets = np.full(3, -BOX)
    assert np.count_nonzero(overlaps_of(e, normals, offsets) > 0) >= 9
    return e, normals, offsets


@pytest.mark.parametrize("which", range(4), ids=["linear", "linear_damped", "hertz", "hertz_damped"])
def test_moment_balance_and_single(which):
    """Element and wall balance about the contact point; compute() is the sum of single()."""
    params = [W.Params(kn=3e5, kt=2e5, friction=0.4), W.Params(kn=3e5, kt=2e5, friction=0.4,
                                                                 restitution=0.5),
              hertz_params(friction=0.4), hertz_params(friction=0.4, restitution=0.5)][which]
    rng = np.random.default_rng(7)
    e, normals, offsets = _random_contacts(rng)
    velocities = rng.normal(size=(3, 3)) * 0.1
    dt = 1e-6
    hist0 = rng.normal(size=(6, 3, 3)) * 0.02      # some beyond the cap, some along n
    hist = hist0.copy()
    energy, f, t, wf, _ = run(params, e, normals, offsets, velocities, hist, dt)
    touching = overlaps_of(e, normals, offsets) > 0
    assert touching.sum() >= 9 and touching.sum(axis=1).max() >= 2
    assert np.all(hist[~touching] == 0.0)
    f_sum, t_sum, wf_sum, u_sum = np.zeros((6, 3)), np.zeros((6, 3)), np.zeros((3, 3)), 0.0
    for k in range(6):
        for wl in range(3):
            r = W.single(params, e, k, normals[wl], -BOX, velocities[wl], hist0[k, wl], dt)
            assert r["touching"] == touching[k, wl]
            if not r["touching"]:
                assert np.all(r["force"] == 0.0) and np.all(r["torque"] == 0.0)
                continue
            F, T, xc = r["force"], r["torque"], r["contact_point"]
            # the contact point lies in the middle of the overlap, and the loads have no moment
            # about it: the wall's reaction -F acts there without a couple
            delta = e.radius[k] - (e.x[k] @ normals[wl] + BOX)
            assert xc @ normals[wl] + BOX == pytest.approx(-delta / 2, abs=1e-15)
            np.testing.assert_allclose(T + np.cross(e.x[k] - xc, F), 0.0,
                                       atol=1e-14 * np.abs(F).max() * 1e-3)
            # Coulomb: the tangential force never exceeds mu fn
            fnk = F @ normals[wl]
            assert fnk > 0.0
            assert np.linalg.norm(F - fnk * normals[wl]) <= 0.4 * fnk * (1 + 1e-12)
            np.testing.assert_array_equal(r["history"], hist[k, wl])
            f_sum[k] += F
            t_sum[k] += T
            wf_sum[wl] -= F
            u_sum += r["energy"]
    np.testing.assert_allclose(f, f_sum, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(t, t_sum, rtol=1e-14, atol=1e-19)
    np.testing.assert_allclose(wf, wf_sum, rtol=1e-14, atol=1e-16)
    assert energy == pytest.approx(u_sum, rel=1e-14)
    # some stored forces were beyond mu fn and were scaled back to it
    assert np.any(np.abs(np.linalg.norm(hist[touching], axis=1)
                         / np.linalg.norm(hist0[touching], axis=1) - 1) > 0.1)


@pytest.mark.parametrize("law", ["hertz", "linear"])
def test_history_follows_a_rigid_tilt(law):
    """A wall tilting with an element stuck on it (the wall's velocity at the contact point matches
    the element's): no slip, the stored force stays in the plane, keeps its size and turns with it."""
    rng = np.random.default_rng(8)
    n0 = random_unit(rng)
    tau = perpendicular(n0, rng)
    R, delta, mu = 1e-3, 3e-6, 0.5
    params = hertz_params(friction=mu) if law == "hertz" else W.Params(kn=3e5, kt=2e5, friction=mu)
    e = spheres_on_walls(rng, [R], [n0], [delta])
    centre = e.x[0] + rng.normal(size=3) * 2e-3
    x0 = e.x[0].copy()
    fn = W.single(params, e, 0, n0, -BOX)["force"] @ n0
    h0 = 0.6 * mu * fn * (0.8 * tau + 0.6 * np.cross(n0, tau))
    hist = h0.reshape(1, 1, 3).copy()
    axis = perpendicular(n0, rng)
    total, steps, dt = np.pi / 2, 2000, 1e-6
    Omega = axis * total / steps / dt
    l = R - delta / 2
    worst_n = worst_mag = 0.0
    for k in range(1, steps + 1):
        Rk = rotmat(axis * total * k / steps)
        n = Rk @ n0
        e.x[0] = centre + Rk @ (x0 - centre)
        offset = e.x[0] @ n - (R - delta)
        e.v[0] = np.cross(Omega, e.x[0] - centre)
        e.w[0] = Omega
        xc = e.x[0] - l * n
        _, f, _, _, _ = run(params, e, n[None, :], np.array([offset]),
                            np.cross(Omega, xc - centre)[None, :], hist, dt)
        worst_n = max(worst_n, abs(hist[0, 0] @ n) / np.linalg.norm(h0))
        worst_mag = max(worst_mag, abs(np.linalg.norm(hist[0, 0]) / np.linalg.norm(h0) - 1))
        assert f[0] @ n == pytest.approx(fn, rel=1e-8)
    h_rot = rotmat(axis * total) @ h0
    angle = np.arccos(np.clip(hist[0, 0] @ h_rot / np.linalg.norm(h0) ** 2, -1, 1))
    assert worst_n < 1e-12 and worst_mag < 1e-12
    assert angle < 1e-3      # first-order carry: O(total angle x step angle)
    print(f"\n{law}: |h.n|/|h| {worst_n:.1e}, magnitude {worst_mag:.1e}, direction {angle:.1e} rad")


def test_drilling_spin_does_not_turn_the_history():
    """The stored force lives in the (non-rotating) wall's frame: an element spinning about the
    normal moves no contact point, so the force stays exactly where it was."""
    rng = np.random.default_rng(9)
    n = random_unit(rng)
    tau = perpendicular(n, rng)
    params = W.Params(kn=3e5, kt=2e5, friction=0.5)
    e = spheres_on_walls(rng, [1e-3], [n], [3e-6])
    e.w[0] = 2000.0 * n
    h0 = 0.2 * tau
    hist = h0.reshape(1, 1, 3).copy()
    for _ in range(100):
        _, f, t, _, _ = run(params, e, n[None, :], np.full(1, -BOX), np.zeros((1, 3)), hist, 1e-6)
    np.testing.assert_allclose(hist[0, 0], h0, rtol=1e-14, atol=1e-17)
    delta = overlaps_of(e, n[None, :], np.full(1, -BOX))[0, 0]
    np.testing.assert_allclose(f[0], 3e5 * delta * n + h0, rtol=1e-13)


def test_no_contact_no_force_and_history_cleared():
    rng = np.random.default_rng(10)
    n = random_unit(rng)
    for params in (W.Params(kn=1e5, friction=0.3, restitution=0.5), hertz_params(friction=0.3)):
        e = spheres_on_walls(rng, [1e-3], [n], [-1e-9])     # a gap of 1 nm
        e.v[0] = -n
        e.w[0] = rng.normal(size=3) * 100
        hist = np.full((1, 1, 3), 0.1)
        energy, f, t, wf, _ = run(params, e, n[None, :], np.full(1, -BOX), np.zeros((1, 3)), hist)
        assert energy == 0.0
        assert np.all(f == 0.0) and np.all(t == 0.0) and np.all(wf == 0.0)
        assert np.all(hist == 0.0)


@pytest.mark.parametrize("frictional", [False, True])
def test_only_owned_rows(frictional):
    """Ghost rows are left untouched (loads and history) and add nothing to the wall force: the
    result equals that of the owned rows alone."""
    rng = np.random.default_rng(11)
    params = hertz_params(friction=0.3 if frictional else 0.0, restitution=0.7)
    e, normals, offsets = _random_contacts(rng)
    velocities = rng.normal(size=(3, 3)) * 0.1
    e.n_owned = 3
    hist = W.new_history(params, 6, 3)
    hist[:] = 0.01
    e.f[:3] = e.t[:3] = 0.0
    e.f[3:] = e.t[3:] = 7.0          # ghost rows: must stay as they are
    wf = np.zeros((3, 3))
    energy = W.compute(params, e, normals, offsets, velocities, hist, 1e-6, wf)
    assert np.all(e.f[3:] == 7.0) and np.all(e.t[3:] == 7.0) and np.all(hist[3:] == 0.01)
    owned = Elements.from_spheres(e.x[:3], e.radius[:3], RHO)
    owned.v[:] = e.v[:3]
    owned.w[:] = e.w[:3]
    hist_o = W.new_history(params, 3, 3)
    hist_o[:] = 0.01
    energy_o, f_o, t_o, wf_o, _ = run(params, owned, normals, offsets, velocities, hist_o, 1e-6)
    np.testing.assert_array_equal(e.f[:3], f_o)
    np.testing.assert_array_equal(e.t[:3], t_o)
    np.testing.assert_array_equal(wf, wf_o)
    np.testing.assert_array_equal(hist[:3], hist_o)
    assert energy == energy_o
    assert np.count_nonzero(f_o) > 0 and np.count_nonzero(overlaps_of(e, normals, offsets)[3:] > 0) > 0


@pytest.mark.parametrize("which", range(2), ids=["linear_damped", "hertz_damped"])
def test_axis_aligned_sweep_equals_general_sweep(which):
    """Walls normal to a coordinate axis take a sweep that reads one coordinate per row; forced
    through the general three-coordinate sweep (axes = -1) they give the same loads and history."""
    params = [W.Params(kn=3e5, kt=2e5, friction=0.4, restitution=0.5),
              hertz_params(friction=0.4, restitution=0.5)][which]
    rng = np.random.default_rng(13)
    pos = rng.uniform(0.0, 1e-2, size=(400, 3))
    e = Elements.from_spheres(pos, rng.uniform(0.3e-3, 0.6e-3, 400), RHO)
    e.v[:] = rng.normal(size=(400, 3)) * 0.1
    e.w[:] = rng.normal(size=(400, 3)) * 100.0
    normals = np.vstack([W.axis_planes(ax, [0.3e-3, 9.6e-3], [1.0, -1.0])[0] for ax in range(3)])
    offsets = np.concatenate([W.axis_planes(ax, [0.3e-3, 9.6e-3], [1.0, -1.0])[1] for ax in range(3)])
    velocities = rng.normal(size=(6, 3)) * 0.1
    np.testing.assert_array_equal(W.aligned_axes(normals), [0, 0, 1, 1, 2, 2])
    hist0 = rng.normal(size=(400, 6, 3)) * 1e-3
    results = []
    for axes in (W.aligned_axes(normals), np.full(6, -1)):
        hist = hist0.copy()
        f, t, wf = np.zeros((400, 3)), np.zeros((400, 3)), np.zeros((6, 3))
        energy = W.wall_loop(params.law, params.damped, params.frictional)(
            e.x, e.v, e.w, e.radius, e.mass, f, t, 400, normals, offsets, axes, velocities, hist,
            1e-6, params.stiff_n, params.stiff_t, params.friction, params.damp_n, params.damp_t, wf)
        results.append((energy, f, t, wf, hist))
    assert np.count_nonzero(np.any(results[0][1] != 0.0, axis=1)) > 50
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)


def test_frictionless_walls_need_no_history():
    rng = np.random.default_rng(12)
    e, normals, offsets = _random_contacts(rng)
    for params in (W.Params(kn=3e5, restitution=0.5), hertz_params(restitution=0.5)):
        hist = W.new_history(params, 6, 3)
        assert hist.shape == (6, 0, 3) and hist.nbytes == 0
        _, f, t, wf, _ = run(params, e, normals, offsets, np.zeros((3, 3)), hist)
        # forces along the normals only (the elements slide and spin), no torque
        assert np.all(t == 0.0)
        for k in range(6):
            touched = normals[overlaps_of(e, normals, offsets)[k] > 0]
            coef = np.linalg.lstsq(touched.T, f[k], rcond=None)
            np.testing.assert_allclose(touched.T @ coef[0], f[k], atol=1e-14 * np.abs(f[k]).max())
    frictional = W.Params(kn=3e5, friction=0.2)
    with pytest.raises(ValueError, match="history"):
        run(frictional, e, normals, offsets, np.zeros((3, 3)), np.zeros((6, 0, 3)))


def test_bad_parameters():
    bad = [
        (dict(law="plastic", kn=1.0), "walls.law"),
        (dict(kn=-1.0), "walls.kn"),
        (dict(kn=None), "walls.kn"),
        (dict(kn=1.0, kt=0.0), "walls.kt"),
        (dict(kn=1.0, friction=-0.1), "walls.friction"),
        (dict(kn=1.0, friction=float("nan")), "walls.friction"),
        (dict(kn=1.0, restitution=0.0), "walls.restitution"),
        (dict(kn=1.0, restitution=1.2), "walls.restitution"),
        (dict(kn=1.0, tangential_damping=-1.0), "walls.tangential_damping"),
        (dict(law="hertz", young=0.0, poisson=0.3), "walls.young"),
        (dict(law="hertz", young=math.inf, poisson=0.3), "walls.young"),
        (dict(law="hertz", young=1e9, poisson=0.5), "walls.poisson"),
        (dict(law="hertz", young=1e9, poisson=0.3, wall_young=-1.0), "walls.wall_young"),
        (dict(law="hertz", young=1e9, poisson=0.3, wall_poisson=-1.0), "walls.wall_poisson"),
        (dict(law="hertz", young=1e9, poisson=0.3, tangential_damping=0.1), "walls.tangential_damping"),
    ]
    for kw, name in bad:
        with pytest.raises(ValueError, match=name.replace(".", r"\.")):
            W.Params(**kw)
    e = Elements.from_spheres(np.zeros((1, 3)), 1e-3, RHO)
    p = W.Params(kn=1.0)
    hist = W.new_history(p, 1, 1)
    with pytest.raises(ValueError, match="normals"):
        run(p, e, np.array([[0.0, 0.0, 1.1]]), np.zeros(1), np.zeros((1, 3)), hist)
    with pytest.raises(ValueError, match="velocities"):
        run(p, e, np.array([[0.0, 0.0, 1.0]]), np.zeros(1), np.zeros((2, 3)), hist)
    with pytest.raises(ValueError, match="sides"):
        W.axis_planes(0, [0.0, 1.0], [1.0, 0.5])
    with pytest.raises(ValueError, match="axis"):
        W.axis_planes(3, [0.0], [1.0])


def test_walls_module_imports_neither_mpi_nor_h5py():
    """STYLE pattern 1: physics kernels are pure array code."""
    import ast
    import inspect
    tree = ast.parse(inspect.getsource(W))
    names = {a.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import)
             for a in node.names}
    names |= {node.module.split(".")[0] for node in ast.walk(tree)
              if isinstance(node, ast.ImportFrom) and node.module}
    assert not names & {"mpi4py", "h5py"}
