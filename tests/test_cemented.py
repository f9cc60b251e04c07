"""Cemented Hertz-Mindlin contacts (docs/physics.md section 8) against their analytic form: one pair.

Normal stiffness = Hertz tangent stiffness + Sn (central differences), tension carried when the
spheres are apart, rupture at the first step whose stored energy exceeds the threshold (pure normal
pull: at the displacement sqrt(2 E_th / Sn)), linear fading of the cement over the fade time and
then exactly the plain kernel's force, the tangential cement spring St ds, the thresholds as a
function of (seed, pair) only, and the refusal of cements that could outlive the Verlet skin.
"""
import numpy as np
import pytest

from pardem.engine import cement
from pardem.engine.contacts import Contacts, pair_keys
from pardem.physics import hertz_mindlin as hm
from pardem.engine.state import Elements
from _util import granular_case

R = 0.5e-3
RHO = 2500.0
SN, ST = 2e5, 1.5e5
PARAMS = dict(young=70e9, poisson=0.3, friction=0.3)
I = np.array([0], np.int32)
J = np.array([1], np.int32)


def cemented(fade=2e-7, restitution=1.0, **kw):
    return hm.Params(**PARAMS, restitution=restitution, cement_normal=SN, cement_tangential=ST,
                     cement_fade_time=fade, **kw)


def pair(delta, vy=0.0):
    """Two spheres along x with overlap ``delta`` [m]; sphere 0 moving at ``vy`` [m/s]."""
    e = Elements.from_spheres(np.array([[0.0, 0.0, 0.0], [2 * R - delta, 0.0, 0.0]]), R, RHO,
                              np.array([0, 1]))
    e.v[0, 1] = vy
    return e


def intact(delta0, threshold=1e-5):
    h = np.zeros((1, 9))
    h[0, hm.CEMENT_DELTA0] = delta0
    h[0, hm.CEMENT_THRESHOLD] = threshold
    h[0, hm.CEMENT_STATE] = 1.0
    return h


def force_on_i(params, e, hist, dt=1e-8):
    e.f[:] = 0.0
    e.t[:] = 0.0
    energy = hm.compute(params, e, I, J, hist, dt)
    return e.f[0].copy(), energy


def normal_force(params, delta, hist):
    return -force_on_i(params, pair(delta), hist.copy())[0][0]   # fn > 0 repulsive, n = +x


def test_history_width_and_plain_kernel_untouched():
    assert hm.history_width(hm.Params(**PARAMS)) == 3
    assert hm.history_width(cemented()) == 9
    plain = hm.Params(**PARAMS)
    # a cemented law on an uncemented row (state 0) is the plain law, bit for bit
    for delta in (1e-6, 3e-7):
        e1, e2 = pair(delta, vy=0.02), pair(delta, vy=0.02)
        h1, h2 = np.zeros((1, 3)), np.zeros((1, 9))
        for _ in range(5):
            f1, en1 = force_on_i(plain, e1, h1)
            f2, en2 = force_on_i(cemented(), e2, h2)
            np.testing.assert_array_equal(f1, f2)
            np.testing.assert_array_equal(h1[0], h2[0, :3])
            assert en1 == en2
            assert not np.any(h2[0, 3:])


def test_normal_stiffness_is_hertz_plus_sn():
    p = cemented()
    e_star, _ = hm.effective_moduli(PARAMS["young"], PARAMS["poisson"])
    delta0 = 1e-6
    h = intact(delta0, threshold=1.0)
    for delta in (0.5e-6, 1e-6, 2e-6):
        eps = 1e-10
        k_fd = (normal_force(p, delta + eps, h) - normal_force(p, delta - eps, h)) / (2 * eps)
        k_hertz = 2.0 * e_star * np.sqrt(R / 2 * delta)      # d/d(delta) of 4/3 E* sqrt(R*) delta^1.5
        assert k_fd == pytest.approx(k_hertz + SN, rel=1e-5)
        fn = normal_force(p, delta, h)
        assert fn == pytest.approx(4 / 3 * e_star * np.sqrt(R / 2) * delta**1.5 + SN * (delta - delta0),
                                   rel=1e-12)


def test_tension_is_carried_when_apart():
    p = cemented()
    delta0 = 1e-6
    for gap in (1e-7, 2e-6):        # spheres apart by ``gap``: delta = -gap, no Hertz force
        h = intact(delta0, threshold=1.0)
        f, energy = force_on_i(p, pair(-gap), h)
        assert f[0] == pytest.approx(SN * (gap + delta0), rel=1e-12)   # i pulled towards j (+x)
        assert energy == pytest.approx(0.5 * SN * (gap + delta0) ** 2, rel=1e-12)
        assert h[0, hm.CEMENT_STATE] == 1.0 and not np.any(h[0, :3])
    # the same gap without cement: no force, and the plain row is cleared
    f, _ = force_on_i(p, pair(-1e-7), np.zeros((1, 9)))
    assert not np.any(f)


def test_rupture_at_the_analytic_stretch_then_fade_then_plain():
    """j pulled away along n at 1e-8 m per step from delta0: the cement breaks at the first step with
    1/2 Sn (delta - delta0)^2 > E_th, i.e. just past sqrt(2 E_th / Sn); then the pair is held: the
    cement force falls linearly to zero over the fade time, then the force equals the plain
    kernel's on the same configuration."""
    dt, fade = 1e-8, 1e-7                 # the fade lasts 10 steps
    p = cemented(fade=fade)
    delta0, e_th, dx = 3e-6, 2e-6, 1e-8
    h = intact(delta0, threshold=e_th)
    x_break = np.sqrt(2 * e_th / SN)      # 4.47e-6 m
    e = pair(delta0)
    e.v[1, 0] = dx / dt                   # the approach rate the kernel sees: pure separation
    k = 0
    while h[0, hm.CEMENT_STATE] > 0.0:
        k += 1
        e.x[1, 0] = (2 * R - delta0) + k * dx
        f, _ = force_on_i(p, e, h, dt)
        delta = 2 * R - e.x[1, 0]
        if h[0, hm.CEMENT_STATE] > 0.0:
            assert 0.5 * SN * (delta - delta0) ** 2 <= e_th
        assert k < 10000
    stretch = delta0 - delta
    assert stretch > x_break and stretch - dx <= x_break * (1 + 1e-9)
    assert stretch == pytest.approx(x_break, abs=1.01 * dx)
    assert 0.5 * SN * stretch**2 > e_th                     # the breaking step itself
    assert h[0, hm.CEMENT_STATE] == -1.0
    # the full cement force still acts on the breaking step
    e_star, _ = hm.effective_moduli(PARAMS["young"], PARAMS["poisson"])
    hertz = 4 / 3 * e_star * np.sqrt(R / 2) * max(delta, 0.0) ** 1.5
    assert -f[0] == pytest.approx(hertz + SN * (delta - delta0), rel=1e-9)
    # hold the pair: fading
    e.v[:] = 0.0
    plain = hm.Params(**PARAMS)
    n_fade = int(round(fade / dt))
    for m in range(1, n_fade + 3):
        f, _ = force_on_i(p, e, h, dt)
        s = max(1.0 - m * dt / fade, 0.0)
        ref = hertz + s * SN * (delta - delta0)
        assert -f[0] == pytest.approx(ref, rel=1e-9, abs=1e-12 * SN * stretch)
        if m < n_fade - 1:
            assert h[0, hm.CEMENT_STATE] == pytest.approx(-s, rel=1e-9)
    assert not np.any(h[0, 3:])                               # back to a plain row
    # then exactly the plain kernel on the same configuration
    e_plain = pair(delta)
    for _ in range(3):
        f, _ = force_on_i(p, e, h, dt)
        fp, _ = force_on_i(plain, e_plain, np.zeros((1, 3)), dt)
        np.testing.assert_array_equal(f, fp)


def test_rupture_tests_the_elastic_cement_energy_not_the_damping():
    """The cement's strength criterion is its stored elastic energy (docs/physics.md 8), which
    the normal (Hertz) damping does not enter: pulled apart fast (10 m/s), a damped pair
    (restitution 0.3) breaks at the same step as an undamped one, while its total normal force
    differed (the damping acted)."""
    dt, dx = 1e-8, 1e-7                   # 10 m/s
    delta0, e_th = 3e-6, 2e-6
    broke, forces = {}, {}
    for e_r in (1.0, 0.3):
        p = cemented(fade=1e-7, restitution=e_r)
        h = intact(delta0, threshold=e_th)
        e = pair(delta0)
        e.v[1, 0] = dx / dt
        k = 0
        forces[e_r] = []
        while h[0, hm.CEMENT_STATE] > 0.0:
            k += 1
            e.x[1, 0] = (2 * R - delta0) + k * dx
            forces[e_r].append(-force_on_i(p, e, h, dt)[0][0])
            assert k < 1000
        broke[e_r] = k
    assert broke[0.3] == broke[1.0]
    # first step, still overlapping (delta = 2.9e-6 m): the dashpot pulled (rate < 0)
    assert forces[0.3][0] < forces[1.0][0] - 1e-3 * abs(forces[1.0][0])


def test_rupture_under_compression_with_hertz_then_plain_equals_uncemented_kernel():
    """Pushed together: the cement breaks in compression too (the energy is symmetric); after
    the fade, cemented and uncemented kernels give the same forces and histories while the pair
    slides (friction, Mindlin history)."""
    dt = 1e-8
    p = cemented(fade=5e-8)
    plain = hm.Params(**PARAMS)
    delta0 = 1e-6
    h = intact(delta0, threshold=1e-7)            # breaks at a compressive stretch of 1e-6 m
    e = pair(delta0, vy=0.05)
    for k in range(400):
        e.x[1, 0] = (2 * R - delta0) - 1e-8 * k
        force_on_i(p, e, h, dt)
        if h[0, hm.CEMENT_STATE] == 0.0:
            break
    assert h[0, hm.CEMENT_STATE] == 0.0 and 100 < k < 400
    e2 = pair(0.0, vy=0.05)
    e2.x[:] = e.x
    h2 = h[:, :3].copy()
    for m in range(20):
        e.x[1, 0] -= 1e-9
        e2.x[1, 0] -= 1e-9
        f1, en1 = force_on_i(p, e, h, dt)
        f2, en2 = force_on_i(plain, e2, h2, dt)
        np.testing.assert_array_equal(f1, f2)
        np.testing.assert_array_equal(h[0, :3], h2[0])
        assert en1 == en2


def test_tangential_cement_spring():
    """Sphere i slides along y at u for one step: Mindlin h = -kt u dt and cement -St u dt."""
    dt, u = 1e-8, 0.03
    p = cemented()
    _, g_star = hm.effective_moduli(PARAMS["young"], PARAMS["poisson"])
    delta = 1e-6
    h = intact(delta, threshold=1.0)
    e = pair(delta, vy=u)
    f, energy = force_on_i(p, e, h, dt)
    kt = 8 * g_star * np.sqrt(R / 2 * delta)
    assert h[0, 4] == pytest.approx(-ST * u * dt, rel=1e-12)
    assert h[0, 1] == pytest.approx(-kt * u * dt, rel=1e-12)
    assert f[1] == pytest.approx(-(kt + ST) * u * dt, rel=1e-12)
    assert f[0] == pytest.approx(-4 / 3 * hm.effective_moduli(PARAMS["young"], PARAMS["poisson"])[0]
                                 * np.sqrt(R / 2) * delta**1.5, rel=1e-12)   # no normal stretch
    # n steps: the cement force grows linearly (no Coulomb cap on the cement)
    for _ in range(9):
        f, energy = force_on_i(p, e, h, dt)
    assert h[0, 4] == pytest.approx(-10 * ST * u * dt, rel=1e-9)
    e_c = (10 * ST * u * dt) ** 2 / (2 * ST)
    assert energy == pytest.approx(0.4 * 4 / 3 * hm.effective_moduli(PARAMS["young"], PARAMS["poisson"])[0]
                                   * np.sqrt(R / 2) * delta**2.5 + h[0, 1] ** 2 / (2 * kt) + e_c, rel=1e-9)
    # a threshold just below the tangential energy of the next step breaks it then
    h[0, hm.CEMENT_THRESHOLD] = (11 * ST * u * dt) ** 2 / (2 * ST) * (1 - 1e-6)
    force_on_i(p, e, h, dt)
    assert h[0, hm.CEMENT_STATE] == -1.0


def test_cement_force_turns_with_a_rigid_rotation():
    """The cement tangential force is carried in the contact plane: |f_ct| is kept when the pair
    turns rigidly (no spurious rupture by rotation)."""
    dt = 1e-8
    p = cemented()
    delta = 1e-6
    h = intact(delta, threshold=1.0)
    h[0, 4] = 0.2                          # cement tangential force along y
    e = pair(delta)
    ang = 1e-3
    c, s = np.cos(ang), np.sin(ang)
    e.x[1] = (2 * R - delta) * np.array([c, s, 0.0])
    force_on_i(p, e, h, dt)
    assert np.linalg.norm(h[0, 3:6]) == pytest.approx(0.2, rel=1e-12)
    assert abs(h[0, 3:6] @ np.array([c, s, 0.0])) < 1e-14


def test_thresholds_depend_on_seed_and_pair_only():
    keys = pair_keys(np.arange(0, 4000), np.arange(1, 4001))
    t = cement.thresholds(7, keys, 2.5e-5, 2e-5)
    assert t.min() >= 5e-6 and t.max() <= 4.5e-5
    assert t.mean() == pytest.approx(2.5e-5, rel=0.02)
    assert np.std(t) == pytest.approx(2e-5 / np.sqrt(3), rel=0.03)           # uniform
    perm = np.random.default_rng(0).permutation(len(keys))
    np.testing.assert_array_equal(cement.thresholds(7, keys[perm], 2.5e-5, 2e-5), t[perm])
    assert not np.array_equal(cement.thresholds(8, keys, 2.5e-5, 2e-5), t)


def test_cement_that_could_outlive_the_skin_is_refused():
    p = cemented()
    x = cement.max_stretch(p, 2.5e-5, 2e-5)
    assert x == pytest.approx(np.sqrt(2 * 4.5e-5 / SN))
    cement.check(p, 2.5e-5, 2e-5, skin=1.01 * x)
    with pytest.raises(ValueError, match="skin"):
        cement.check(p, 2.5e-5, 2e-5, skin=0.99 * x)
    with pytest.raises(ValueError, match="half_width"):
        cement.check(p, 1e-5, 2e-5, skin=1.0)
    with pytest.raises(ValueError, match="cement_normal"):
        cement.check(hm.Params(**PARAMS), 2.5e-5, 2e-5, skin=1.0)


def test_contacts_widen_and_narrow_the_history():
    c = Contacts(hm, hm.Params(**PARAMS), skin=1e-5)
    assert c.width == 3 and c.history.shape == (0, 3)
    c.history = np.ones((4, 3))
    c.set_params(cemented())
    assert c.width == 9 and c.history.shape == (4, 9) and not np.any(c.history[:, 3:])
    c.history[1, hm.CEMENT_STATE] = 1.0
    with pytest.raises(ValueError, match="cement"):
        c.set_params(hm.Params(**PARAMS))
    c.history[1, hm.CEMENT_STATE] = 0.0
    c.set_params(hm.Params(**PARAMS))
    assert c.history.shape == (4, 3)
    np.testing.assert_array_equal(c.history, np.ones((4, 3)))


def test_rebuild_reports_an_intact_cement_out_of_reach():
    """An intact cement whose spheres are moved beyond R_i + R_j + skin (parameters the cement
    check refuses) is counted in ``Contacts.lost``; a broken one is not."""
    skin = 0.1 * R
    for state, lost in ((1.0, 1), (-0.5, 0)):
        c = Contacts(hm, cemented(), skin=skin)
        e = pair(1e-6)
        c.rebuild(e)
        assert len(c.i) == 1 and c.history.shape == (1, 9)
        c.history[0] = intact(1e-6, threshold=1.0)[0]
        c.history[0, hm.CEMENT_STATE] = state
        e.x[1, 0] += 2 * skin
        c.rebuild(e)
        assert len(c.i) == 0 and c.lost == lost
        e.x[1, 0] -= 2 * skin
        c.rebuild(e)                      # back in reach: a fresh, uncemented contact
        assert len(c.i) == 1 and not np.any(c.history)


def test_contact_forces_count_cemented_pairs_apart_and_fading_as_the_kernel_applies_them():
    """``packing.contact_forces(sim, cement=True)`` rebuilds each pair's force from its history
    (NumPy): it must include a pair pulled apart that an intact cement holds and a fading one, with
    the force the kernel applied. A chain of four spheres, cemented, then the first pulled apart
    (intact cement in tension, sliding sideways) and the last pair's cement set fading: the end
    spheres have one pair each, so the kernel's total force on them is that pair's force.
    Tolerance: round-off of the two groupings of the same terms (1e-12 of the force)."""
    from pardem.parallel.communicator import Communicator
    from pardem.engine import packing
    overlap = 1e-7
    pos = np.array([[k * (2 * R - overlap), 0.0, 0.0] for k in range(4)])
    params = dict(PARAMS, cement_normal=SN, cement_tangential=ST, cement_fade_time=1e-7)
    case = granular_case(Communicator(), pos, R, RHO, "hertz_mindlin", params, np.full(3, -2 * R),
                          np.full(3, 12 * R), 1e-9, 0.1 * R, periodic=(False, False, False))
    sim = case.sim
    assert cement.cement_contacts(sim, 1e-4, 5e-5, seed=3) == 3   # thresholds far above the loads
    e, c = sim.elements, sim.contacts
    g0 = int(np.flatnonzero(e.gid == 0)[0])
    g3 = int(np.flatnonzero(e.gid == 3)[0])
    e.x[g0, 0] -= 3 * overlap              # pair (0, 1) apart by 2 overlaps: the cement pulls
    e.v[g0, 1] = 0.2                       # sliding: a tangential cement force
    last = np.flatnonzero((e.gid[c.i] == 2) & (e.gid[c.j] == 3) | (e.gid[c.i] == 3) & (e.gid[c.j] == 2))
    c.history[last, hm.CEMENT_STATE] = -0.6  # fading, and stretched: its fading force is not 0
    e.x[g3, 0] += 0.5 * overlap
    e.f[:] = 0.0
    e.t[:] = 0.0
    sim.compute_forces()
    cf = packing.contact_forces(sim, cement=True)
    assert len(cf["fn"]) == 3
    first = np.flatnonzero((cf["gid_i"] == 0) & (cf["gid_j"] == 1))[0]
    end = np.flatnonzero((cf["gid_i"] == 2) & (cf["gid_j"] == 3))[0]
    assert not cf["touching"][first] and cf["intact"][first] and cf["fn"][first] == 0.0
    assert cf["touching"][end] and not cf["intact"][end]
    fading = 0.59 * SN * 0.5 * overlap       # (0.6 - dt / t_fade) Sn |delta - delta0| [N]
    assert fading > 0.2 * abs(-e.f[g3][0])   # a large part of the pair's force
    F0, F3 = e.f[g0], -e.f[g3]
    assert F0[0] > 0.0 and abs(F0[1]) > 0.0      # pulled towards sphere 1, dragged sideways
    np.testing.assert_allclose(cf["force"][first], F0, rtol=0, atol=1e-12 * np.abs(F0).max())
    np.testing.assert_allclose(cf["force"][end], F3, rtol=0, atol=1e-12 * np.abs(F3).max())
    # without the cement columns the apart pair would be missing and the fading one differ
    plain = packing.contact_forces(sim)
    assert len(plain["fn"]) == 2
