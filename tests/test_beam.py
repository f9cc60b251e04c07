"""Beam bond kernel (pardem.physics.beam), docs/physics.md section 2.

Checks a two-element beam against textbook results (axial E S / L0, torsion G I0 / L0, cantilever
tip deflection P L^3 / (3 E I) and rotation P L^2 / (2 E I)), the force and moment balance of the bond,
invariance under rigid-body motions (positions, orientations and velocities) and frame
indifference, consistency of forces and moments with the returned elastic energy (finite
differences), and the axial and twist damping ratios of a free oscillating pair against the damped
oscillator (reduced mass / reduced inertia, c = 2 zeta sqrt(k m*)).
"""
import numpy as np
import pytest

from _util import (beam_constants, free_oscillation, loads, log_decrement_ratio, perpendicular, qmul, quat,
                   random_rotvec, random_unit, reduced, relative_rotation, rotate_element, rotmat, two_elements)

R1, R2 = 1.0e-3, 1.5e-3
L0 = R1 + R2
YOUNG, RR, NU = 2.0e9, 0.6, 0.3
S, I, I0, G = beam_constants(R1, R2, YOUNG, RR, NU)


def general_pair(rng, damping=0.0):
    """A bond along a random direction between elements with random initial orientations."""
    n = random_unit(rng)
    q1 = quat(random_rotvec(rng, np.pi))
    q2 = quat(random_rotvec(rng, np.pi))
    e, b = two_elements(n, R1, R2, YOUNG, RR, NU, damping, q1=q1, q2=q2,
                        origin=rng.uniform(-0.01, 0.01, 3))
    return e, b, n


@pytest.fixture(params=["axis_aligned", "general"])
def pair(request):
    """(elements, bonds, n): one bond along x with identity orientations, or a general one."""
    if request.param == "axis_aligned":
        e, b = two_elements((1.0, 0.0, 0.0), R1, R2, YOUNG, RR, NU, 0.0)
        return e, b, np.array([1.0, 0.0, 0.0])
    return general_pair(np.random.default_rng(11))


def test_axial_stiffness(pair):
    e, b, n = pair
    delta = 1e-6 * L0
    e.x[1] += delta * n
    f, t, _ = loads(b, e)
    expected = YOUNG * S / L0 * delta
    # tension pulls 1 towards 2 and 2 towards 1
    np.testing.assert_allclose(f[0], expected * n, rtol=0, atol=1e-4 * expected)
    np.testing.assert_allclose(f[1], -expected * n, rtol=0, atol=1e-4 * expected)
    assert np.abs(t).max() < 1e-4 * expected * L0


def test_torsion_stiffness(pair):
    e, b, n = pair
    alpha = 1e-5
    rotate_element(e, 1, alpha * n)
    f, t, _ = loads(b, e)
    expected = G * I0 / L0 * alpha
    # element 2 twisted by +alpha about n: restoring moment -k alpha n on 2, reaction on 1
    np.testing.assert_allclose(t[1], -expected * n, rtol=0, atol=1e-4 * expected)
    np.testing.assert_allclose(t[0], expected * n, rtol=0, atol=1e-4 * expected)
    assert np.abs(f).max() < 1e-4 * expected / L0


def _tip_residual(e, b, x2_0, q2_0, z, P, load):
    """Scaled out-of-balance (force + load, moment) on element 2 at displacement/rotation ``z``."""
    e.x[1] = x2_0 + z[:3]
    e.q[1] = qmul(quat(z[3:]), q2_0)
    e.refresh_rotations()
    f, t, _ = loads(b, e)
    return np.concatenate([(f[1] + load) / P, t[1] / (P * L0)])


@pytest.mark.parametrize("general", [False, True])
def test_cantilever(general):
    """Element 1 clamped, transverse load P on element 2: Newton solve of the static equilibrium."""
    rng = np.random.default_rng(5)
    if general:
        e, b, n = general_pair(rng)
    else:
        e, b = two_elements((1.0, 0.0, 0.0), R1, R2, YOUNG, RR, NU, 0.0)
        n = np.array([1.0, 0.0, 0.0])
    d = perpendicular(n, rng) if general else np.array([0.0, 1.0, 0.0])
    v_exp_per_P = L0**3 / (3.0 * YOUNG * I)
    P = 1e-5 * L0 / v_exp_per_P            # tip deflection 1e-5 L0: linear regime
    v_exp = P * v_exp_per_P
    th_exp = P * L0**2 / (2.0 * YOUNG * I)
    load = P * d
    x2_0, q2_0 = e.x[1].copy(), e.q[1].copy()
    z = np.zeros(6)
    h = np.concatenate([np.full(3, 1e-3 * v_exp), np.full(3, 1e-3 * th_exp)])
    for _ in range(8):
        r = _tip_residual(e, b, x2_0, q2_0, z, P, load)
        if np.abs(r).max() < 1e-11:
            break
        J = np.empty((6, 6))
        for k in range(6):
            dz = np.zeros(6)
            dz[k] = h[k]
            J[:, k] = (_tip_residual(e, b, x2_0, q2_0, z + dz, P, load)
                       - _tip_residual(e, b, x2_0, q2_0, z - dz, P, load)) / (2 * h[k])
        z = z - np.linalg.solve(J, r)
    r = _tip_residual(e, b, x2_0, q2_0, z, P, load)
    assert np.abs(r).max() < 1e-9, "Newton did not reach equilibrium"
    deflection = z[:3] @ d
    rotation = z[3:] @ np.cross(n, d)          # the tip turns from n towards the load
    # the two-node Euler-Bernoulli beam is exact for a tip load: only geometric nonlinearity
    # (deflection 1e-5 L0) separates the kernel from the textbook values
    assert deflection == pytest.approx(v_exp, rel=1e-4)
    assert rotation == pytest.approx(th_exp, rel=1e-4)
    # no axial displacement, no twist, nothing out of the loading plane (to first order)
    other = np.cross(n, d)
    assert abs(z[:3] @ n) < 1e-3 * v_exp and abs(z[:3] @ other) < 1e-3 * v_exp
    assert abs(z[3:] @ n) < 1e-3 * th_exp and abs(z[3:] @ d) < 1e-3 * th_exp


def _random_state(rng, damping):
    e, b, n = general_pair(rng, damping)
    for k in range(2):
        rotate_element(e, k, random_rotvec(rng, 0.3))
    e.x[1] += L0 * rng.uniform(-0.03, 0.03, 3)      # stretch and transverse offset
    if damping:
        omega = np.sqrt(YOUNG * S / L0 / e.mass.min())
        e.v[:] = rng.normal(size=(2, 3)) * 0.01 * L0 * omega
        e.w[:] = rng.normal(size=(2, 3)) * 0.01 * omega
    return e, b


@pytest.mark.parametrize("damping", [0.0, 0.2])
def test_force_and_moment_balance(damping):
    rng = np.random.default_rng(42)
    for _ in range(25):
        e, b = _random_state(rng, damping)
        f, t, _ = loads(b, e)
        fscale = np.abs(f).max()
        assert fscale > 0.0
        np.testing.assert_allclose(f[0] + f[1], 0.0, atol=1e-12 * fscale)
        lever = e.x[1] - e.x[0]
        total = t[0] + t[1] + np.cross(lever, f[1])
        mscale = np.abs(t).max() + np.linalg.norm(lever) * fscale
        np.testing.assert_allclose(total, 0.0, atol=1e-12 * mscale)


def test_damped_kernel_at_rest_equals_elastic_kernel():
    """With zero velocities the damped code path gives the elastic loads of the undamped one."""
    for seed in range(5):
        e0, b0 = _random_state(np.random.default_rng(seed), 0.0)
        e1, b1 = _random_state(np.random.default_rng(seed), 0.2)
        e1.v[:] = 0.0
        e1.w[:] = 0.0
        assert b1.tau_a[0] > 0.0 and b0.tau_a[0] == 0.0
        f0, t0, u0 = loads(b0, e0)
        f1, t1, u1 = loads(b1, e1)
        np.testing.assert_allclose(f1, f0, rtol=0, atol=1e-13 * np.abs(f0).max())
        np.testing.assert_allclose(t1, t0, rtol=0, atol=1e-13 * np.abs(t0).max())
        assert u1 == pytest.approx(u0, rel=1e-13)


def _rigid_move(e, Q_rv, centre, shift):
    Q = rotmat(Q_rv)
    e.x[:] = centre + (e.x - centre) @ Q.T + shift
    for k in range(2):
        e.q[k] = qmul(quat(Q_rv), e.q[k])
    e.refresh_rotations()
    return Q


def test_rigid_body_motion_gives_no_force():
    rng = np.random.default_rng(7)
    for _ in range(10):
        e, b, n = general_pair(rng, damping=0.2)
        centre = rng.uniform(-0.02, 0.02, 3)
        _rigid_move(e, 2.0 * random_unit(rng), centre, rng.uniform(-0.01, 0.01, 3))
        f, t, energy = loads(b, e)
        scale = YOUNG * S
        assert np.abs(f).max() < 1e-10 * scale
        assert np.abs(t).max() < 1e-10 * scale * L0
        assert abs(energy) < 1e-20 * scale * L0
        # rigid velocity field: v = V + Omega x (x - c), w = Omega on both ends
        Omega = random_unit(rng) * 1e3
        V = random_unit(rng) * 1.0
        e.v[:] = V + np.cross(Omega, e.x - centre)
        e.w[:] = Omega
        f, t, _ = loads(b, e)
        # damping force scale of a relative speed |Omega| L0 along the axis
        dscale = b.ka[0] * b.tau_a[0] * np.linalg.norm(Omega) * L0
        assert dscale > 0.0
        assert np.abs(f).max() < 1e-10 * dscale
        assert np.abs(t).max() < 1e-10 * dscale * L0
        # control: the same speeds with one end spinning the other way do load the bond
        e.w[1] = -Omega
        f, t, _ = loads(b, e)
        assert np.abs(t).max() > 1e-3 * dscale * L0


@pytest.mark.parametrize("damping", [0.0, 0.2])
def test_frame_indifference(damping):
    """Deformed (and moving) pair rotated rigidly: forces and moments rotate with it."""
    rng = np.random.default_rng(3)
    for _ in range(10):
        e, b = _random_state(rng, damping)
        f, t, en = loads(b, e)
        centre = rng.uniform(-0.02, 0.02, 3)
        Q_rv = random_rotvec(rng, np.pi)
        Q = _rigid_move(e, Q_rv, centre, rng.uniform(-0.01, 0.01, 3))
        e.v[:] = e.v @ Q.T
        e.w[:] = e.w @ Q.T
        f2, t2, en2 = loads(b, e)
        fs, ts = np.abs(f).max(), np.abs(t).max()
        np.testing.assert_allclose(f2, f @ Q.T, atol=1e-9 * fs)
        np.testing.assert_allclose(t2, t @ Q.T, atol=1e-9 * ts)
        assert en2 == pytest.approx(en, rel=1e-9)


def test_forces_are_minus_energy_gradient():
    """Force = -dE/dx and moment = -dE/dphi (world rotation vector) by central differences."""
    rng = np.random.default_rng(21)
    for _ in range(5):
        e, b, n = general_pair(rng)
        for k in range(2):
            rotate_element(e, k, random_rotvec(rng, 1e-3))
        e.x[1] += L0 * rng.uniform(-1e-3, 1e-3, 3)
        f, t, _ = loads(b, e)
        x_ref, q_ref = e.x.copy(), e.q.copy()
        hx, hr = 1e-8 * L0, 1e-8

        def energy_at(k, d, kind, h):
            e.x[:] = x_ref
            e.q[:] = q_ref
            if kind == "x":
                e.x[k, d] += h
            else:
                rv = np.zeros(3)
                rv[d] = h
                e.q[k] = qmul(quat(rv), q_ref[k])
            e.refresh_rotations()
            return loads(b, e)[2]

        grad_x = np.array([[(energy_at(k, d, "x", hx) - energy_at(k, d, "x", -hx)) / (2 * hx)
                            for d in range(3)] for k in range(2)])
        grad_r = np.array([[(energy_at(k, d, "r", hr) - energy_at(k, d, "r", -hr)) / (2 * hr)
                            for d in range(3)] for k in range(2)])
        fs = np.abs(f).max()
        ts = np.abs(t).max()
        np.testing.assert_allclose(f, -grad_x, atol=5e-4 * fs)
        np.testing.assert_allclose(t, -grad_r, atol=2e-3 * ts)


def _assert_damped_release(s, dt, A, omega, zeta):
    """The signal ``s`` follows the damped oscillator released from rest at ``A``, and its
    logarithmic decrement gives back the damping ratio."""
    t = dt * np.arange(len(s))
    omega_d = omega * np.sqrt(1.0 - zeta**2)
    exact = A * np.exp(-zeta * omega * t) * (np.cos(omega_d * t)
                                              + zeta / np.sqrt(1 - zeta**2) * np.sin(omega_d * t))
    assert np.abs(s - exact).max() < 0.02 * A
    assert log_decrement_ratio(s) == pytest.approx(zeta, rel=0.03)


def _random_axis_pair(seed, zeta):
    """(n, elements, bonds): the R1-R2 pair bonded along a random unit ``n``, damping ratio ``zeta``."""
    n = random_unit(np.random.default_rng(seed))
    return (n, *two_elements(n, R1, R2, YOUNG, RR, NU, zeta))


@pytest.mark.parametrize("zeta", [0.05, 0.2])
def test_axial_damping_ratio(zeta):
    """Free pair, axial release: decay and frequency of the damped oscillator with m* and c."""
    n, e, b = _random_axis_pair(8, zeta)
    m_red = reduced(e.mass[0], e.mass[1])
    omega = np.sqrt(YOUNG * S / L0 / m_red)
    A = 1e-5 * L0
    e.x[1] += A * n
    s, dt = free_oscillation(e, b, omega * np.sqrt(1.0 - zeta**2),
                             lambda el: np.linalg.norm(el.x[1] - el.x[0]) - L0)
    _assert_damped_release(s, dt, A, omega, zeta)
    # the total momentum of the free pair stays zero
    p = (e.mass[:, None] * e.v).sum(axis=0)
    assert np.abs(p).max() < 1e-12 * m_red * omega * A


@pytest.mark.parametrize("zeta", [0.05, 0.2])
def test_twist_damping_ratio(zeta):
    """Free pair, released twisted: torsional oscillator with reduced inertia and G I0 / L0."""
    n, e, b = _random_axis_pair(9, zeta)
    omega = np.sqrt(G * I0 / L0 / reduced(e.inertia[0], e.inertia[1]))
    A = 1e-5
    rotate_element(e, 1, A * n)
    # the twist: the relative rotation q2 q1^-1 about n
    s, dt = free_oscillation(e, b, omega * np.sqrt(1.0 - zeta**2), lambda el: relative_rotation(el, n))
    _assert_damped_release(s, dt, A, omega, zeta)
    # pure twist: no force, the centres stay put
    assert np.abs(e.x - e.x0).max() < 1e-12 * L0


def test_bending_damping_ratio():
    """Free pair released with equal and opposite end rotations (pure bending, no shear force).

    The mode's coordinate is the relative rotation th = th2 - th1 about a normal to the bond; with
    the reduced inertia i* = I1 I2 / (I1 + I2) it obeys i* th'' = -(E I / L0) th - c th', and
    docs/physics.md section 2 asks c = 2 zeta sqrt(k i*) with this mode's k = E I / L0, i.e. ratio zeta.
    """
    zeta = 0.2
    e, b = two_elements((1.0, 0.0, 0.0), R1, R1, YOUNG, RR, NU, zeta)
    axis = np.array([0.0, 0.0, 1.0])
    A = 1e-5
    rotate_element(e, 0, -0.5 * A * axis)
    rotate_element(e, 1, 0.5 * A * axis)
    _, I_b, _, _ = beam_constants(R1, R1, YOUNG, RR, NU)
    omega = np.sqrt(YOUNG * I_b / (2 * R1) / reduced(e.inertia[0], e.inertia[1]))
    s, dt = free_oscillation(e, b, omega * np.sqrt(1 - zeta**2), lambda el: relative_rotation(el, axis))
    # the mode's stiffness and inertia are E I / L0 and i*: it oscillates at about omega
    # (omega_d / omega > 0.979 for any zeta <= 0.2), and the centres stay put
    crossings = np.nonzero(np.sign(s[1:]) != np.sign(s[:-1]))[0]
    half_period = np.mean(np.diff(crossings)) * dt
    assert half_period == pytest.approx(np.pi / omega, rel=0.03)
    assert np.abs(e.x - e.x0).max() < 1e-12 * R1
    measured = log_decrement_ratio(s)
    assert measured == pytest.approx(zeta, rel=0.05), (
        f"bending mode damping ratio {measured:.4f}, expected zeta = {zeta} "
        f"(half period {half_period:.4e} s)")
