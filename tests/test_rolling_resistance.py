"""Hertz-Mindlin with elastic-plastic rolling resistance (pardem.physics.hertz_mindlin_rolling).

Analytic and independent checks:

* the neighbour-list loop equals its all-pairs twin and ``single`` bit for bit (random cluster,
  random stored forces and torques, some beyond their caps), and every pair's loads balance
  (total force and angular momentum zero);
* steady imposed relative rolling of two pressed spheres (no slip at the contact point): the
  torque grows as ``k_r theta`` with ``k_r = k_t R*^2``, ``k_t = 4 G / (2 - nu) sqrt(R* delta)``
  (docs/physics.md's same-material Mindlin stiffness, not the law's ``8 G* a`` code path), then
  stays on the cap ``mu_r R* fn``, ``fn = 4/3 E* sqrt(R*) delta^(3/2)``, opposing the rolling;
* two pressed spheres (translations clamped) started with opposite spins oscillate at
  ``Omega = sqrt(k_r / I_eff)``, ``I_eff = I / 2`` (the relative angle obeys
  ``theta'' = -2 k_r / I theta``), below the cap;
* with ``mu_r = 0`` the forces, torques, histories and energies are hertz_mindlin's, bit for bit
  (kernel and a whole run through ``pardem.build``).
"""
import numpy as np
import pytest

import pardem
from pardem.engine.state import Elements
from pardem.physics import contact_laws
from pardem.physics import hertz_mindlin as hm
from pardem.physics import hertz_mindlin_rolling as hmr
from test_contacts import _all_pairs, _random_cluster

YOUNG, NU, RHO = 1.0e9, 0.3, 2500.0
SHEAR = YOUNG / (2.0 * (1.0 + NU))
E_STAR_SAME = SHEAR / (1.0 - NU)          # identical grains, docs/physics.md
R = 1e-3


def _random_history(rng, n_pairs):
    """Stored tangential forces [N], rolling torques [N m] (some beyond their caps, some with a
    normal component, which the carry removes) and stale normal forces (rewritten by the step)."""
    hist = np.zeros((n_pairs, hmr.WIDTH))
    hist[:, :3] = rng.normal(size=(n_pairs, 3)) * 0.05
    # caps mu_r R* fn ~ 1e-4 to 1e-2 N m here: magnitudes on both sides
    hist[:, hmr.ROLL:hmr.ROLL + 3] = rng.normal(size=(n_pairs, 3)) * 10 ** rng.uniform(-6, -1, (n_pairs, 1))
    hist[:, hmr.NORMAL] = rng.uniform(0.0, 1.0, n_pairs)
    return hist


MODELS = {
    "default_kr": hmr.Params(YOUNG, NU, rolling_friction=0.1, friction=0.4),
    "damped": hmr.Params(YOUNG, NU, rolling_friction=0.1, friction=0.4, restitution=0.6),
    "fixed_kr": hmr.Params(YOUNG, NU, rolling_friction=0.1, friction=0.4, rolling_stiffness=1e-3),
}


@pytest.mark.parametrize("name", sorted(MODELS))
def test_list_loop_equals_all_pairs_twin_and_single(name):
    params = MODELS[name]
    law = contact_laws.law("hertz_mindlin_rolling")
    assert law is hmr
    rng = np.random.default_rng(7)
    e = _random_cluster(rng)
    i, j = _all_pairs(e)
    dt = 1e-6
    hist = _random_history(rng, len(i))
    before = hist.copy()
    full = np.zeros((e.n_total, e.n_total, hmr.WIDTH))
    full[i, j] = hist
    energy = law.compute(params, e, i, j, hist, dt)
    f, t = e.f.copy(), e.t.copy()
    touching = np.linalg.norm(e.x[j] - e.x[i], axis=1) < e.radius[i] + e.radius[j]
    assert touching.sum() > 20 and (~touching).sum() > 0
    assert np.all(hist[~touching] == 0.0)     # apart: every column forgotten
    # the rolling springs act, some on their cap mu_r R* fn (the stored torques were random)
    roll = np.linalg.norm(hist[:, hmr.ROLL:hmr.ROLL + 3], axis=1)
    r_star = e.radius[i] * e.radius[j] / (e.radius[i] + e.radius[j])
    cap = params.rolling_friction * r_star * hist[:, hmr.NORMAL]
    assert np.all(roll <= cap * (1 + 1e-12))
    assert np.sum(touching & (roll > cap * (1 - 1e-12))) > 3
    assert np.sum(touching & (roll < cap * 0.99)) > 3
    # a torque without force: the forces are hertz_mindlin's, the torques are not
    e2 = Elements.from_spheres(e.x.copy(), e.radius.copy(), RHO)
    e2.v[:], e2.w[:] = e.v, e.w
    hist_hm = before[:, :3].copy()
    hm.compute(params.hertz, e2, i, j, hist_hm, dt)
    np.testing.assert_array_equal(e2.f, f)
    np.testing.assert_array_equal(hist_hm, hist[:, :3])
    assert np.abs(t - e2.t).max() > 1e-3 * np.abs(t).max()
    # the pairs balance: total force and angular momentum about the origin vanish
    scale = np.abs(f).max()
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-13 * scale)
    L = (np.cross(e.x, f) + t).sum(axis=0)
    np.testing.assert_allclose(L, 0.0, atol=1e-13 * scale * 1e-3)   # arms ~1e-3 m
    # single: the step of one pair, nothing modified, torques balanced
    for p in range(len(i)):
        r = law.single(params, e, int(i[p]), int(j[p]), before[p], dt)
        np.testing.assert_array_equal(r["history"], hist[p])
        if touching[p]:
            Lp = (np.cross(e.x[i[p]], r["force_i"]) - np.cross(e.x[j[p]], r["force_i"])
                  + r["torque_i"] + r["torque_j"])
            np.testing.assert_allclose(Lp, 0.0, atol=1e-13 * np.abs(r["force_i"]).max() * 1e-3)
    # the all-pairs twin: the same bits
    e.f[:] = 0.0
    e.t[:] = 0.0
    energy_bf = law.compute_all_pairs(params, e, full, dt)
    np.testing.assert_array_equal(e.f, f)
    np.testing.assert_array_equal(e.t, t)
    np.testing.assert_array_equal(full[i, j], hist)
    assert energy_bf == energy
    # without the energy: the same loads; the exact accumulator gets the same energy
    e.f[:] = 0.0
    e.t[:] = 0.0
    hist2 = before.copy()
    assert np.isnan(law.compute(params, e, i, j, hist2, dt, with_energy=False))
    np.testing.assert_array_equal(e.t, t)
    np.testing.assert_array_equal(hist2, hist)
    from pardem.physics import exact_accumulate as xa
    xacc = xa.zeros(10)
    hist3 = before.copy()
    assert law.compute(params, e, i, j, hist3, dt, acc=np.zeros(10), xacc=xacc) == 0.0
    assert xa.value(xacc)[9] == pytest.approx(energy, rel=1e-12)   # float vs exact sum order


def _pressed_pair(delta):
    """Two spheres of radius R along x at overlap ``delta`` [m]."""
    return Elements.from_spheres(np.array([[0.0, 0.0, 0.0], [2 * R - delta, 0.0, 0.0]]),
                                 np.array([R, R]), RHO)


def test_torque_grows_as_k_r_theta_then_caps_at_mu_r_r_star_fn():
    """Steady relative rolling about z (w_i = -w_j: no slip at the contact point)."""
    delta, mu_r, omega, dt = 2e-6, 0.05, 10.0, 1e-7
    params = hmr.Params(YOUNG, NU, rolling_friction=mu_r, friction=0.5)
    e = _pressed_pair(delta)
    e.w[0] = [0.0, 0.0, omega]
    e.w[1] = [0.0, 0.0, -omega]
    r_star = R / 2
    fn = 4.0 / 3.0 * E_STAR_SAME * np.sqrt(r_star) * delta**1.5
    k_t = 4.0 * SHEAR / (2.0 - NU) * np.sqrt(r_star * delta)
    k_r = k_t * r_star**2
    cap = mu_r * r_star * fn
    steps_to_cap = cap / (k_r * 2 * omega * dt)
    assert 20 < steps_to_cap < 2000
    i, j = np.array([0], np.int32), np.array([1], np.int32)
    hist = np.zeros((1, hmr.WIDTH))
    torques = []
    for _ in range(int(2 * steps_to_cap)):
        e.f[:] = 0.0
        e.t[:] = 0.0
        hmr.compute(params, e, i, j, hist, dt)
        torques.append(e.t.copy())
        np.testing.assert_allclose(e.f[0], [-fn, 0.0, 0.0], rtol=1e-12, atol=1e-12 * fn)
    torques = np.array(torques)
    np.testing.assert_array_equal(torques[:, 1], -torques[:, 0])      # equal and opposite
    tz = torques[:, 0, 2]
    assert np.abs(torques[:, 0, :2]).max() == 0.0                      # about z only
    # below the cap: k_r theta, theta = 2 omega (k + 1) dt, opposing the rolling of i
    k = np.arange(len(tz))
    below = k + 1 < 0.95 * steps_to_cap
    np.testing.assert_allclose(tz[below], -k_r * 2 * omega * (k[below] + 1) * dt, rtol=1e-12)
    # then on the cap (the Mindlin force is zero: its torque adds nothing)
    np.testing.assert_allclose(tz[k + 1 > 1.05 * steps_to_cap], -cap, rtol=1e-12)
    # reversing the rolling unloads along the stiffness k_r (elastic-plastic, not viscous)
    e.w[:] *= -1.0
    e.t[:] = 0.0
    hmr.compute(params, e, i, j, hist, dt)
    assert e.t[0, 2] == pytest.approx(-cap + k_r * 2 * omega * dt, rel=1e-12)


def test_oscillation_at_rolling_frequency():
    """Two pressed spheres (translations clamped, rotations free) started with opposite spins:
    theta = 2 theta_i obeys I theta'' = -2 k_r theta, so w_i(t) = w0 cos(Omega t), Omega^2 = 2 k_r / I."""
    delta, mu_r = 1e-6, 0.2
    r_star = R / 2
    k_r = 4.0 * SHEAR / (2.0 - NU) * np.sqrt(r_star * delta) * r_star**2
    mass = RHO * 4.0 / 3.0 * np.pi * R**3
    inertia = 0.4 * mass * R**2
    big_omega = np.sqrt(2.0 * k_r / inertia)
    fn = 4.0 / 3.0 * E_STAR_SAME * np.sqrt(r_star) * delta**1.5
    w0 = 0.3 * mu_r * r_star * fn / k_r * big_omega / 2    # torque amplitude 0.3 of the cap
    x = np.array([[0.0, 0.0, 0.0], [2 * R - delta, 0.0, 0.0]])
    system = pardem.System(
        pardem.Particles(x, R, RHO, angular_velocities=[[0, 0, w0], [0, 0, -w0]]),
        contacts=pardem.ContactModel("hertz_mindlin_rolling",
                                     {"young": YOUNG, "poisson": NU, "friction": 0.5,
                                      "rolling_friction": mu_r}),
        integration=pardem.Integration(dt_fraction=0.05))
    sim = pardem.build(pardem.Communicator(), system)
    pardem.add_fixes(sim, pardem.Clamp([0, 1], dofs="xyz", rotations=""))
    period = 2 * np.pi / big_omega
    assert 100 < period / sim.dt < 2000
    spins = []

    class Sample:
        trigger = 1

        def __call__(self, s):
            spins.append(s.elements.w[:2, 2].copy())

    sim.run(int(3.2 * period / sim.dt), [Sample()])
    w = np.array(spins)
    np.testing.assert_array_equal(w[:, 1], -w[:, 0])
    # Verlet's spin after step k: w0 cos(Omega (k + 1) dt) to O((Omega dt)^2) = 5e-4 (the run's
    # initial force evaluation already turns the spring by w0 dt, as it does the Mindlin spring)
    t = np.arange(2, len(w) + 2) * sim.dt
    assert (big_omega * sim.dt) ** 2 < 5e-4
    np.testing.assert_allclose(w[:, 0], w0 * np.cos(big_omega * t), atol=1e-3 * w0)
    # the period from the downward zero crossings (linear interpolation: error (Omega dt)^2)
    s = w[:, 0]
    k = np.flatnonzero((s[:-1] > 0) & (s[1:] <= 0))
    crossings = (k + 1 + s[k] / (s[k] - s[k + 1])) * sim.dt
    assert len(crossings) == 3
    assert np.mean(np.diff(crossings)) == pytest.approx(period, rel=1e-4)   # (Omega dt)^2 / 24 = 2e-5


def test_zero_rolling_friction_is_hertz_mindlin_bitwise():
    rng = np.random.default_rng(3)
    for restitution in (1.0, 0.6):
        e = _random_cluster(rng)
        e2 = Elements.from_spheres(e.x.copy(), e.radius.copy(), RHO)
        e2.v[:], e2.w[:] = e.v, e.w
        i, j = _all_pairs(e)
        hist = _random_history(rng, len(i))
        hist[:, hmr.ROLL:] = 0.0
        hist_hm = hist[:, :3].copy()
        a = hmr.compute(hmr.Params(YOUNG, NU, rolling_friction=0.0, friction=0.4,
                                   restitution=restitution), e, i, j, hist, 1e-6)
        b = hm.compute(hm.Params(YOUNG, NU, friction=0.4, restitution=restitution), e2, i, j,
                       hist_hm, 1e-6)
        np.testing.assert_array_equal(e.f, e2.f)
        np.testing.assert_array_equal(e.t, e2.t)
        np.testing.assert_array_equal(hist[:, :3], hist_hm)
        assert a == b

    # a whole run: a cluster of spinning grains through pardem.build
    def run(law, extra):
        c = _random_cluster(np.random.default_rng(4))
        params = {"young": YOUNG, "poisson": NU, "friction": 0.4, "restitution": 0.8, **extra}
        system = pardem.System(pardem.Particles(c.x, c.radius, RHO, c.v * 0.1, c.w * 0.1),
                               contacts=pardem.ContactModel(law, params),
                               integration=pardem.Integration(dt=2e-7))
        sim = pardem.build(pardem.Communicator(), system)
        sim.run(300)
        return sim.elements
    a, b = run("hertz_mindlin_rolling", {"rolling_friction": 0.0}), run("hertz_mindlin", {})
    for k in ("x", "v", "w", "f", "t"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
    # and with rolling resistance the run differs (the test can fail)
    c = run("hertz_mindlin_rolling", {"rolling_friction": 0.2})
    assert not np.array_equal(c.w, b.w)


def test_bad_parameters_and_deck_keys():
    with pytest.raises(ValueError, match="rolling_friction"):
        hmr.Params(YOUNG, NU, rolling_friction=-0.1)
    with pytest.raises(ValueError, match="rolling_stiffness"):
        hmr.Params(YOUNG, NU, rolling_friction=0.1, rolling_stiffness=0.0)
    with pytest.raises(ValueError, match="young"):
        hmr.Params(-1.0, NU, rolling_friction=0.1)
    section = {"young": YOUNG, "poisson": NU, "friction": 0.3, "restitution": 1.0}
    with pytest.raises(ValueError, match="rolling_friction"):
        hmr.deck_params(section, {})
    p = hmr.Params(**hmr.deck_params({**section, "rolling_friction": 0.1}, {}))
    assert p.rolling_friction == 0.1 and p.rolling_stiffness is None
    # a given k_r bounds the step by its rotation: 1/omega, omega^2 = 2 k_r / I
    stiff = hmr.Params(YOUNG, NU, rolling_friction=0.1, rolling_stiffness=1.0)
    inertia = 0.4 * RHO * 4 / 3 * np.pi * R**5
    assert hmr.critical_time_step(stiff, np.array([R]), RHO) == pytest.approx(np.sqrt(inertia / 2.0))


def test_checkpoint_round_trip_continues_bitwise(tmp_path):
    """The rolling torques live in the contact history: a run saved and loaded (pardem.save /
    pardem.load) continues with the same bits as the uninterrupted run."""
    def system():
        c = _random_cluster(np.random.default_rng(6))
        params = {"young": YOUNG, "poisson": NU, "friction": 0.4, "rolling_friction": 0.2}
        return pardem.System(pardem.Particles(c.x, c.radius, RHO, c.v * 0.1, c.w * 0.1),
                             contacts=pardem.ContactModel("hertz_mindlin_rolling", params),
                             integration=pardem.Integration(dt=2e-7))
    comm = pardem.Communicator()
    ref = pardem.build(comm, system())
    ref.run(200)
    sim = pardem.build(comm, system())
    sim.run(100)
    assert np.any(sim.contacts.history[:, hmr.ROLL:hmr.ROLL + 3] != 0.0)
    pardem.save(sim, str(tmp_path / "state.h5"))
    back = pardem.load(comm, str(tmp_path / "state.h5"))
    assert pardem.describe(back).contacts.params["rolling_friction"] == 0.2
    back.run(100)
    for k in ("x", "v", "w"):
        np.testing.assert_array_equal(getattr(back.elements, k), getattr(ref.elements, k))
