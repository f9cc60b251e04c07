"""Velocity Verlet with the exact quaternion update (pardem.physics.verlet), docs/physics.md section 10.

A free element spinning at constant angular velocity ends at the exact rotation exp(w t) q0; an
undamped bonded lattice vibrating freely (plates far away) conserves its total energy (kinetic +
bond elastic) and its linear and angular momentum (orbital + spin).

Energy: the on-step energy of velocity Verlet oscillates by O((omega dt)^2) (about 1 % at 0.3 dt_c
when the run starts with kinetic energy only); what Verlet conserves for a linear system is the
modified energy ``E - dt^2/8 sum(|f|^2/m + |t|^2/I)``, checked here to 1e-4, together with the absence
of drift of the on-step energy (half-run averages within 1e-3).
"""
import numpy as np
import pytest

from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.domains.ordered import ordered_lattice
from pardem.physics.quaternion import (quat_from_rotvec, quat_multiply_into, quat_to_matrix,
                                       quat_to_matrix_into, rotate_world)
from pardem.physics.neighbours import max_displacement2
from pardem.physics.verlet import BLOCK, enforce_plane, kick, kick_drift
from pardem.physics.timestep import critical_time_step, eigen_bound, max_tau
from pardem.engine.simulation import Simulation
from pardem.engine.state import Elements, Plates
from _util import FakeComm, loads, quat, random_rotvec, random_unit, rotmat

R = 1e-3
DENSITY = 1000.0


def far_plates(k=1e6):
    """A pair of plates far outside every test system: they never touch an element."""
    return Plates.pair(0, -10.0, 10.0, 0.0, k)


def test_quaternion_helpers_match_rodrigues():
    rng = np.random.default_rng(6)
    for _ in range(20):
        a, b = random_rotvec(rng, 3.0), random_rotvec(rng, 3.0)
        qa, qb = quat_from_rotvec(a), quat_from_rotvec(b)
        np.testing.assert_allclose(quat_to_matrix(qa), rotmat(a), atol=1e-14)
        out = np.empty(4)
        quat_multiply_into(qa, qb, out)
        np.testing.assert_allclose(quat_to_matrix(out), rotmat(a) @ rotmat(b), atol=1e-14)
        # one step of rotate_world by w dt = b applies exp(b) on the world side
        q = qa.copy()
        rotate_world(q, b / 1e-3, 1e-3)
        np.testing.assert_allclose(quat_to_matrix(q), rotmat(b) @ rotmat(a), atol=1e-13)


@pytest.mark.parametrize("angle_per_step", [0.1, 3e-3, 1e-6])
def test_free_rotation_is_exact(angle_per_step):
    rng = np.random.default_rng(1)
    e = Elements.from_spheres(np.array([[0.001, -0.002, 0.003]]), R, DENSITY)
    q0 = quat(random_rotvec(rng, np.pi))
    e.q[0] = q0
    e.refresh_rotations()
    w = random_unit(rng) * 2000.0
    v = random_unit(rng) * 0.3
    e.w[0] = w
    e.v[0] = v
    x0 = e.x[0].copy()
    bonds = make_bonds(e, np.zeros((0, 2), dtype=np.int64), BeamMaterial(1e9, 0.5, 0.3, 0.0), np.eye(3))
    dt = angle_per_step / np.linalg.norm(w)
    n = 10_000
    sim = Simulation(FakeComm(), e, bonds, far_plates(), dt)
    sim.run(n)
    T = n * dt
    expected = rotmat(w * T) @ _matrix(q0)
    e.refresh_rotations()       # without bonds the time loop leaves the cached matrices to be refreshed on demand
    np.testing.assert_allclose(e.rot[0], expected, atol=1e-10)
    np.testing.assert_allclose(_matrix(e.q[0]), expected, atol=1e-10)
    assert np.linalg.norm(e.q[0]) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(e.w[0], w, rtol=0, atol=1e-12 * np.linalg.norm(w))
    np.testing.assert_allclose(e.x[0], x0 + v * T, rtol=0, atol=1e-12)


def _kick_drift_one_row_at_a_time(x, v, w, q, rot, f, t, inv_mass, inv_inertia, dt, n_owned,
                                   with_rot):
    """kick_drift as it was before blocking: each row's update, then ``rotate_world``."""
    h = 0.5 * dt
    for k in range(n_owned):
        for d in range(3):
            v[k, d] += inv_mass[k] * h * f[k, d]
            w[k, d] += inv_inertia[k] * h * t[k, d]
            x[k, d] += dt * v[k, d]
        rotate_world(q[k], w[k], dt)
        if with_rot:
            quat_to_matrix_into(q[k], rot[k])
    f[:] = 0.0
    t[:] = 0.0


@pytest.mark.parametrize("with_rot", [True, False])
def test_blocked_kick_drift_equals_one_row_at_a_time(with_rot):
    """The blocked kick_drift (series branch vectorised over a block, exact exponential in a last
    pass) gives the same bits as the row-by-row update, for every branch of ``rotate_world``:
    no rotation, the series (|w dt|^2 < 1e-4), the exact exponential, a non-finite w; over more
    than two blocks, a partial last block and ghost rows."""
    rng = np.random.default_rng(31)
    n_owned, n_ghost, dt = 2 * BLOCK + 37, 9, 1e-6
    n = n_owned + n_ghost
    rows = [rng.normal(size=(n, 3)) for _ in range(3)]
    x, v = rows[0], rows[1]
    scale = rng.choice([0.0, 1e2, 3e3, 1e5], size=n)   # |w dt|: 0, 1e-4, 3e-3 (series), 0.1 (exact)
    w = rows[2] * scale[:, None]
    w[17] = [np.nan, 0.0, 1.0]
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    a = [x, v, w, q, rng.normal(size=(n, 3, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
         rng.random(n) + 0.5, rng.random(n) + 0.5]
    a[6][scale == 0.0] = 0.0        # no torque either: these rows do not turn
    b = [arr.copy() for arr in a]
    x_ref = x + rng.normal(size=x.shape) * 1e-6
    assert kick_drift(*a, dt, n_owned, with_rot) == 0.0    # no reference: nothing measured
    a = [arr.copy() for arr in b]
    moved2 = kick_drift(*a, dt, n_owned, with_rot, x_ref)
    _kick_drift_one_row_at_a_time(*b, dt, n_owned, with_rot)
    # the displacement measured during the drift is the rebuild check's own pass, bit for bit
    assert moved2 == max_displacement2(b[0], x_ref, n_owned) > 0.0
    ang2 = np.sum((b[2][:n_owned] * dt) ** 2, axis=1)
    assert np.any(ang2 == 0.0) and np.any((ang2 > 0.0) & (ang2 < 1e-4)) and np.any(ang2 > 1e-4)
    for name, got, want in zip("x v w q rot f t".split(), a, b):
        np.testing.assert_array_equal(got, want, err_msg=name)


def test_a_nan_speed_is_not_forgotten_by_later_rows():
    """``kick``'s largest squared speed stays NaN once a row gave NaN, and ``enforce_plane``'s
    largest offset too (a finite later row used to replace it, hiding a blow-up from the check)."""
    n = 5
    v, w, f, t = (np.zeros((n, 3)) for _ in range(4))
    v[1, 0] = np.nan
    v[3, 0] = 2.0
    ones = np.ones(n)
    assert np.isnan(kick(v, w, f, t, ones, ones, 1e-6, n))
    x = np.zeros((n, 3))
    x[1, 2] = np.nan
    x[3, 2] = 1e-3
    assert np.isnan(enforce_plane(x, v, w, f, t, 0.0, n, np.zeros(3)))
    # and the drift's displacement from the build counts a NaN position as infinite
    x[:] = 0.0
    q = np.zeros((n, 4))
    q[:, 0] = 1.0
    moved2 = kick_drift(x, v, w, q, np.zeros((n, 3, 3)), f, t, ones, ones, 1e-6, n, False, np.zeros((n, 3)))
    assert moved2 == np.inf


def _matrix(q):
    """Rotation matrix of a unit quaternion, from its axis-angle form (independent of pardem)."""
    q = np.asarray(q) / np.linalg.norm(q)
    s = np.linalg.norm(q[1:])
    if s == 0.0:
        return np.eye(3)
    return rotmat(q[1:] / s * 2.0 * np.arctan2(s, q[0]))


def _lattice(rng, damping=0.0, edge=5):
    pos, pairs, frame = ordered_lattice([edge * 2 * R] * 3, R)
    e = Elements.from_spheres(pos, R, DENSITY)
    mat = BeamMaterial(young=(2e9, 1e9, 0.5e9), radius_ratio=(0.5, 0.7, 0.9), poisson=0.3,
                       damping=damping)
    b = make_bonds(e, pairs, mat, frame)
    lam = eigen_bound(b.i, b.j, b.L0, b.ka, b.kb, b.kt, e.mass, e.inertia, e.n_owned,
                      np.zeros(e.n_total))
    dt_c = critical_time_step(lam, max_tau(b))
    omega = np.sqrt(lam)
    # small random motion: strains ~1e-6, well inside the linear regime
    e.v[:] = rng.normal(size=e.v.shape) * 1e-6 * 2 * R * omega
    e.w[:] = rng.normal(size=e.w.shape) * 1e-6 * omega
    return e, b, dt_c


def _energy(sim):
    """(kinetic + bond elastic energy, kinetic energy, Verlet modified energy) of the current step.

    Evaluated independently of the run's own bookkeeping (the run's f, t are left untouched).
    """
    e = sim.elements
    f, t = e.f.copy(), e.t.copy()
    fb, tb, u = loads(sim.bonds, e)
    e.f[:], e.t[:] = f, t
    kin = 0.5 * np.sum(e.mass * np.sum(e.v**2, axis=1)) + 0.5 * np.sum(e.inertia * np.sum(e.w**2, axis=1))
    shadow = sim.dt**2 / 8 * (np.sum(np.sum(fb**2, axis=1) / e.mass)
                              + np.sum(np.sum(tb**2, axis=1) / e.inertia))
    return kin + u, kin, kin + u - shadow


def _momenta(e, origin):
    p = (e.mass[:, None] * e.v).sum(axis=0)
    L = (np.cross(e.x - origin, e.mass[:, None] * e.v) + e.inertia[:, None] * e.w).sum(axis=0)
    return p, L


@pytest.fixture(scope="module")
def free_lattice_run():
    """10^4 undamped steps of a 5x5x5 lattice at 0.3 dt_c; energies sampled every 20 steps."""
    rng = np.random.default_rng(2024)
    e, b, dt_c = _lattice(rng)
    origin = e.x.mean(axis=0)
    p0, L0_ = _momenta(e, origin)
    scale_p = np.sum(e.mass * np.linalg.norm(e.v, axis=1))
    scale_L = np.sum(e.mass * np.linalg.norm(e.x - origin, axis=1) * np.linalg.norm(e.v, axis=1)
                     + e.inertia * np.linalg.norm(e.w, axis=1))
    sim = Simulation(FakeComm(), e, b, far_plates(), 0.3 * dt_c)
    energies = [_energy(sim)]

    class Sample:
        trigger = 20

        def __call__(self, s):
            energies.append(_energy(s))

    sim.run(10_000, operations=[Sample()])
    p1, L1 = _momenta(e, origin)
    return dict(energies=np.array(energies), p=(p0, p1, scale_p), L=(L0_, L1, scale_L), sim=sim)


def test_energy_conserved(free_lattice_run):
    en = free_lattice_run["energies"]
    total, kin, modified = en[:, 0], en[:, 1], en[:, 2]
    # energy is exchanged between kinetic and elastic forms ...
    assert kin.min() < 0.8 * total[0]
    # ... while Verlet's modified energy stays put
    assert np.abs(modified - modified[0]).max() < 1e-4 * total[0]
    # the on-step energy only oscillates (O((omega dt)^2)) and does not drift
    assert np.abs(total - total[0]).max() < 0.02 * total[0]
    half = len(total) // 2
    assert abs(total[1:half].mean() - total[half:].mean()) < 1e-3 * total[0]


def test_momentum_conserved(free_lattice_run):
    p0, p1, sp = free_lattice_run["p"]
    L0_, L1, sL = free_lattice_run["L"]
    np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-12 * sp)
    np.testing.assert_allclose(L1, L0_, rtol=0, atol=1e-12 * sL)


def test_raw_energy_within_tenth_of_percent():
    """Issue 2 item 7: kinetic + elastic energy of an undamped vibrating lattice stays within 0.1 %
    over 10^4 steps. At 0.1 dt_c Verlet's on-step oscillation, O((omega dt)^2), is below that."""
    rng = np.random.default_rng(11)
    e, b, dt_c = _lattice(rng)
    sim = Simulation(FakeComm(), e, b, far_plates(), 0.1 * dt_c)
    totals = [_energy(sim)[0]]

    class Sample:
        trigger = 50

        def __call__(self, s):
            totals.append(_energy(s)[0])

    sim.run(10_000, operations=[Sample()])
    totals = np.array(totals)
    assert np.abs(totals - totals[0]).max() < 1e-3 * totals[0]
