"""Contacts in the engine: parallel agreement, restarts, neighbour lists across ranks and periodic
images, the Love-Weber stress against the cell's virial, the affine cell and the pressure servo
(issue 5). MPI runs are ``mpiexec`` subprocesses of ``tests/mpi/granular_run.py``: a frictional,
damped Hertz gas of 729 polydisperse spheres in a periodic cell shrinking at a diagonal strain
rate, with slabs along a periodic axis (the first and last ranks are neighbours)."""
import os
import shutil
import subprocess
import sys

import numpy as np

from pardem import restart
import pytest

from pardem.engine import granular
from pardem.engine.contacts import STRESS, pair_keys
from pardem.parallel.communicator import Communicator
from pardem.physics.hertz_mindlin import effective_moduli
from pardem.errors import InstabilityError
from _util import granular_case

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
SCRIPT = os.path.join(os.path.dirname(__file__), "mpi", "granular_run.py")
R = 0.1e-3


def run(n, out, steps, *extra):
    cmd = [MPIEXEC, "-n", str(n), sys.executable, SCRIPT, str(out), str(steps)] + [str(x) for x in extra]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    return np.load(out), p.stderr


def rel(a, b, key):
    return float(np.abs(a[key] - b[key]).max() / np.abs(a[key]).max())


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("gran")
    return {n: run(n, d / f"r{n}.npz", 200) for n in (1, 2, 3)}


@pytest.mark.parametrize("n", [2, 3])
def test_ranks_agree_for_200_steps(runs, n):
    (a, log1), (b, _) = runs[1], runs[n]
    assert int(log1.split("rebuilds")[1].split()[0]) >= 5          # lists rebuilt, elements migrated
    assert len(a["keys"]) > 300                                     # many contacts with history
    np.testing.assert_array_equal(a["gid"], b["gid"])
    for key in ("x", "v", "w"):
        assert rel(a, b, key) < 1e-8, key
    np.testing.assert_array_equal(a["keys"], b["keys"])            # same contacts, by gid pair
    assert rel(a, b, "hist") < 1e-8
    np.testing.assert_allclose(a["energies"][:, 1:], b["energies"][:, 1:], rtol=1e-8, atol=0)


def test_three_ranks_rebalanced(runs):
    assert "rebalances 2" in runs[3][1] or "rebalances 1" in runs[3][1]


@pytest.mark.parametrize("n", [1, 2])
def test_restart_is_bit_for_bit(tmp_path, n):
    full, _ = run(n, tmp_path / "full.npz", 300, "--checkpoint-at", 150, tmp_path / "c.h5")
    again, _ = run(n, tmp_path / "again.npz", 300, "--restart", tmp_path / "c.h5")
    for key in ("x", "v", "w", "keys", "hist", "length"):
        np.testing.assert_array_equal(full[key], again[key])
    if n == 2:   # on another number of ranks the lists are rebuilt: same histories by gid pair
        other, _ = run(3, tmp_path / "other.npz", 300, "--restart", tmp_path / "c.h5")
        np.testing.assert_array_equal(full["keys"], other["keys"])
        for key in ("x", "v", "w", "hist"):
            assert rel(full, other, key) < 1e-8, key


@pytest.mark.mpi
def test_compressing_cell_on_three_ranks_slabs_follow_and_restart(tmp_path):
    """Fast isotropic compression (0.5 % strain, affine displacements of several skins between
    list builds) completes on 3 ranks (the slab cuts follow the cell: with fixed cuts the end slab
    shrank until it was thinner than the ghost range), agrees with 1 rank, and a restart from the
    middle is bit for bit (its ghost layers are rebuilt against the moved cuts)."""
    args = ["--rate", -5000, "--checkpoint-at", 600, tmp_path / "c.h5"]
    full, _ = run(3, tmp_path / "full.npz", 1000, *args)
    again, _ = run(3, tmp_path / "again.npz", 1000, "--restart", tmp_path / "c.h5")
    for key in ("x", "v", "w", "keys", "hist", "length", "cuts"):
        np.testing.assert_array_equal(full[key], again[key])
    L0 = 9 * 2.02 * R
    assert full["length"][0] == pytest.approx(L0 * (1 - 5000 * 1e-8) ** 1000, rel=1e-12)
    one, _ = run(1, tmp_path / "one.npz", 1000, "--rate", -5000)
    for key in ("x", "v", "w"):
        assert rel(one, full, key) < 1e-8


def brute_force_keys(x, radius, gid, skin, L):
    """All pairs within R_i + R_j + skin under the minimum image (O(N^2) oracle)."""
    d = x[None, :, :] - x[:, None, :]
    d -= L * np.round(d / L)
    dist = np.sqrt((d**2).sum(-1))
    reach = radius[:, None] + radius[None, :] + skin
    i, j = np.nonzero(np.triu(dist < reach, 1))
    return np.sort(pair_keys(np.minimum(gid[i], gid[j]), np.maximum(gid[i], gid[j])))


@pytest.mark.parametrize("n", [1, 2, 3])
def test_neighbour_list_equals_brute_force_across_ranks(tmp_path, n):
    """Random polydisperse centres (radii R +- 20 %) in a periodic cell, slabs along x."""
    a, _ = run(n, tmp_path / "nb.npz", 0, "--random")
    L = np.full(3, 9 * 2.02 * R)
    expect = brute_force_keys(a["x"], a["radius"], a["gid"], float(a["skin"]), L)
    assert len(expect) > 1000
    np.testing.assert_array_equal(np.unique(a["pairs"]), expect)


def test_slabs_across_a_non_default_periodic_axis(tmp_path):
    a, _ = run(1, tmp_path / "a.npz", 100, "--slab-axis", 2)
    b, _ = run(2, tmp_path / "b.npz", 100, "--slab-axis", 2)
    for key in ("x", "v", "w"):
        assert rel(a, b, key) < 1e-8


def dense_packing(n=6, spacing=1.96, seed=5):
    pos, L = granular.simple_cubic(n, R, spacing=spacing, jitter=0.03, seed=seed)
    radii = R * np.random.default_rng(seed).uniform(0.95, 1.05, len(pos))
    return pos, radii, L


def test_love_weber_stress_equals_cell_virial():
    """sigma = (1/V) dU/dF at F = I: the energy of the packing under an affine deformation F of the
    cell and its contents, by central differences of a brute-force Hertz energy."""
    pos, radii, L = dense_packing()
    young, poisson = 72e9, 0.2
    case = granular_case(Communicator(), pos, radii, 2500.0, "hertz_mindlin",
                          {"young": young, "poisson": poisson, "friction": 0.0}, np.zeros(3),
                          np.full(3, L), 1e-9, 0.05 * R)
    sim = case.sim
    sim.run(0)   # list and forces of the initial state
    assert sim.contacts.n_touching > 2 * len(pos)             # coordination > 4
    sigma = sim.contacts.sums[STRESS].reshape(3, 3) / L**3
    e_star, _ = effective_moduli(young, poisson)
    d0 = pos[None, :, :] - pos[:, None, :]
    d0 -= L * np.round(d0 / L)
    iu = np.triu_indices(len(pos), 1)
    d0 = d0[iu]
    rsum = (radii[:, None] + radii[None, :])[iu]
    rstar = (radii[:, None] * radii[None, :])[iu] / rsum

    def energy(F):
        delta = np.clip(rsum - np.linalg.norm(d0 @ F.T, axis=1), 0.0, None)
        return float(np.sum(8.0 / 15.0 * e_star * np.sqrt(rstar) * delta**2.5))

    h = 1e-7
    virial = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            E = np.zeros((3, 3))
            E[a, b] = h
            virial[a, b] = (energy(np.eye(3) + E) - energy(np.eye(3) - E)) / (2 * h) / L**3
    assert np.trace(sigma) < 0                                          # compression negative
    np.testing.assert_allclose(sigma, virial.T, atol=1e-6 * np.abs(sigma).max())
    np.testing.assert_allclose(sigma, sigma.T, atol=1e-9 * np.abs(sigma).max())


def test_affine_cell_maps_positions_and_edges_exactly():
    """Spheres far apart in a cell deforming at a diagonal rate follow x = lo + (x0 - lo) prod(1 + g dt)."""
    pos, L = granular.simple_cubic(4, R, spacing=4.0, jitter=0.0)
    rate = (-500.0, 200.0, 0.0)
    case = granular_case(Communicator(), pos, R, 2500.0, "hertz_mindlin",
                          {"young": 72e9, "poisson": 0.2}, np.zeros(3), np.full(3, L), 1e-8, 0.1 * R,
                          rate=rate)
    case.sim.run(1000)
    f = (1.0 + np.array(rate) * 1e-8) ** 1000
    x = case.sim.elements.x
    np.testing.assert_allclose(x, pos * f, rtol=1e-12)
    np.testing.assert_allclose(case.sim.cell.length, L * f, rtol=1e-12)


def test_affine_motion_loads_the_tangential_spring():
    """Two touching spheres at rest, the cell stretched along x only: the pair's tangential force is
    -kt times the tangential part of the affine change of the branch vector (linear law, no slip)."""
    kt = 1e5
    d = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0) * 1.999 * R
    pos = np.array([[5 * R, 5 * R, 5 * R], [5 * R, 5 * R, 5 * R] + d])
    g, dt, steps = 50.0, 1e-8, 200
    case = granular_case(Communicator(), pos, R, 2500.0, "linear",
                          {"kn": 1e5, "kt": kt, "friction": 10.0}, np.zeros(3), np.full(3, 10 * R),
                          dt, 0.1 * R, rate=(g, 0.0, 0.0))
    sim = case.sim
    sim.elements.inv_mass[:] = 0.0   # held: only the cell moves them
    sim.elements.inv_inertia[:] = 0.0
    sim.run(steps)
    c = sim.contacts
    e = sim.elements
    d_now = e.x[c.j[0]] - e.x[c.i[0]]
    n = d_now / np.linalg.norm(d_now)
    change = d_now - d if e.gid[c.i[0]] == 0 else -(d_now + d)
    slide = -change          # i's contact point relative to j's
    slide_t = slide - (slide @ n) * n
    np.testing.assert_allclose(c.history[0], -kt * slide_t, rtol=2e-2, atol=1e-12)
    assert np.linalg.norm(c.history[0]) > 1e-4


def test_servo_compresses_a_gas_to_the_target_pressure():
    """A frictionless polydisperse gas (solid fraction 0.35) under the servo ``deps/dt = g (p - p0)``
    jams and is then held at p0: the mean pressure over the last 10 samples is within 1 % of p0,
    and the packing is dense (a frictionless random packing jams near 0.62-0.64)."""
    rng = np.random.default_rng(11)
    n = 125
    radii = R * rng.uniform(0.9, 1.1, n)
    L = (np.sum(4.0 / 3.0 * np.pi * radii**3) / 0.35) ** (1.0 / 3.0)
    pos = rng.uniform(0.0, L, (n, 3))
    p0 = 1e6
    case = granular_case(Communicator(), pos, radii, 2500.0, "hertz_mindlin",
                          {"young": 72e9, "poisson": 0.2, "friction": 0.0, "restitution": 0.5},
                          np.zeros(3), np.full(3, L), 1e-8, 0.1 * R, servo=(p0, 4e-3, 2000.0),
                          viscous_damping=1e5, allow_overlaps=True)     # a random gas: the servo separates it
    sim = case.sim
    # the gas's deep overlaps push grains apart faster than the default runaway bound (0.1 radius
    # per step) in the first steps: Integration.max_step_displacement, raised for this stage
    sim.step_displacement = 1.0
    sim.run(50000)
    p = []
    for _ in range(10):
        sim.run(1000)
        p.append(-np.trace(sim.global_stress()) / 3.0)
    assert abs(np.mean(p) / p0 - 1.0) < 0.01, p
    assert np.all(np.abs(sim.cell.rate) < 1.0)             # settled, static
    phi = np.sum(4.0 / 3.0 * np.pi * radii**3) / sim.cell.volume
    assert 0.60 < phi < 0.66, phi


def test_servo_gain_cap_keeps_the_discrete_loop_stable():
    """The pressure servo against a packing of affine stiffness S (p = p1 - S e, e the cell's log
    strain): each step multiplies the error by 1 - S gain dt. At S gain dt = 3 the uncapped loop
    diverges (x -2 per step); with ``servo_stiffness = S`` the gain is capped at 1 / (2 S dt) and
    the error halves every step, without overshoot."""
    from pardem.engine.periodic_cell import PeriodicCell
    p0, p1, S, dt = 1e5, 1.2e5, 2e8, 1e-8
    gain = 3.0 / (S * dt)
    for capped, factor in ((False, -2.0), (True, 0.5)):
        cell = PeriodicCell(np.zeros(3), np.ones(3), (True,) * 3, servo=(p0, gain, 1e12))
        cell.servo_stiffness = S if capped else 0.0
        errors = []
        for _ in range(8):
            p = p1 - S * cell.strain[0]
            errors.append(p - p0)
            cell.control(np.diag([-p] * 3), dt)
            cell.strain += cell.rate * dt   # the linearised response: e advances by rate * dt
        ratios = np.array(errors[1:]) / np.array(errors[:-1])
        np.testing.assert_allclose(ratios, factor, rtol=1e-9)


def test_coordination_and_solid_fraction_against_brute_force():
    from pardem.engine.reducer import granular_measures
    pos, radii, L = dense_packing(n=5, spacing=1.97)
    case = granular_case(Communicator(), pos, radii, 2500.0, "hertz_mindlin",
                          {"young": 72e9, "poisson": 0.2, "friction": 0.0}, np.zeros(3), np.full(3, L),
                          1e-9, 0.05 * R)
    case.sim.run(0)
    m = granular_measures(case.sim)
    d = pos[None, :, :] - pos[:, None, :]
    d -= L * np.round(d / L)
    dist = np.sqrt((d**2).sum(-1))
    r1, r2 = radii[:, None], radii[None, :]
    touch = np.triu(dist < r1 + r2, 1)
    assert m["n_contacts"] == touch.sum() > len(pos)
    assert m["Z"] == pytest.approx(2.0 * touch.sum() / len(pos), rel=1e-14)
    # lens volumes by numerical quadrature of the overlap (independent of the closed form)
    lens = 0.0
    for a, b in zip(*np.nonzero(touch)):
        ra, rb, dd = radii[a], radii[b], dist[a, b]
        zs = np.linspace(dd - rb, ra, 20001)                 # along the axis, inside both spheres
        area = np.pi * np.minimum(ra**2 - zs**2, rb**2 - (dd - zs) ** 2)
        lens += np.trapezoid(np.clip(area, 0.0, None), zs)
    expect = (np.sum(4.0 / 3.0 * np.pi * radii**3) - lens) / L**3
    assert m["solid_fraction"] == pytest.approx(expect, rel=1e-7)
    assert m["pressure"] > 0.0


def test_linear_contact_critical_step_is_the_stability_limit():
    """``linear_contact_time_step`` is 2 / omega of a pair (omega^2 = kn / m*). A periodic chain of
    6 pre-compressed spheres has omega_max^2 = 4 kn / m = 2 kn / m* (alternating mode), so its
    Verlet limit is dt_c / sqrt(2): bounded at 0.97 of it, divergent at 1.03."""
    from pardem.physics.timestep import linear_contact_time_step
    kn = 1e6
    mass = 2500.0 * 4.0 / 3.0 * np.pi * R**3
    dt_c = linear_contact_time_step(mass, kn)
    a = 1.99 * R
    pos = np.array([[(k + 0.5) * a, 6 * R, 6 * R] for k in range(6)])
    vel = np.zeros((6, 3))
    vel[:, 0] = 1e-3 * np.array([1, -1, 0.5, -0.3, 0.2, -0.4])
    grown = {}
    for f in (0.97, 1.03):
        case = granular_case(Communicator(), pos, R, 2500.0, "linear", {"kn": kn, "kt": kn, "friction": 0.0},
                              np.zeros(3), np.array([6 * a, 12 * R, 12 * R]), 0.5 * dt_c, 0.2 * R,
                              velocities=vel)
        case.sim.dt = f * dt_c / np.sqrt(2.0)    # past the refusal, to see what it protects from
        try:
            case.sim.run(2000)
            grown[f] = np.abs(case.sim.elements.v[:, 0]).max()
        except InstabilityError:
            grown[f] = np.inf
    assert grown[0.97] < 1e-2
    assert grown[1.03] == np.inf            # diverged and stopped
    with pytest.raises(ValueError, match="dt = .* expected a value in"):
        granular_case(Communicator(), pos, R, 2500.0, "linear", {"kn": kn, "kt": kn}, np.zeros(3),
                       np.array([6 * a, 12 * R, 12 * R]), 1.01 * dt_c, 0.2 * R)


def test_bonded_pairs_feel_no_contact():
    """Three overlapping spheres, 0-1 bonded: the list holds 0-2 and 1-2 only, and the contact
    forces equal those of the brute-force sum over the unbonded overlapping pairs."""
    from pardem.engine.bonding import BeamMaterial, make_bonds
    from pardem.engine.contacts import Contacts
    from pardem.physics import hertz_mindlin
    from pardem.engine.state import Elements
    pos = np.array([[0.0, 0.0, 0.0], [1.9 * R, 0.0, 0.0], [0.95 * R, 1.7 * R, 0.0]])
    e = Elements.from_spheres(pos, R, 2500.0)
    bonds = make_bonds(e, [[0, 1]], BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0),
                       np.eye(3))
    bonds.relink(e.gid)
    params = hertz_mindlin.Params(young=72e9, poisson=0.2, friction=0.0)
    c = Contacts(hertz_mindlin, params, 0.1 * R)
    c.rebuild(e, bonds)
    assert sorted(map(tuple, np.stack([c.i, c.j], 1).tolist())) == [(0, 2), (1, 2)]
    c.compute(e, 1e-9)
    ref = Elements.from_spheres(pos, R, 2500.0)
    for a, b in ((0, 2), (1, 2)):
        hertz_mindlin.compute(params, ref, np.array([a], np.int32), np.array([b], np.int32),
                              np.zeros((1, 3)), 1e-9)
    np.testing.assert_allclose(e.f, ref.f, rtol=1e-14)
    c2 = Contacts(hertz_mindlin, params, 0.1 * R)
    c2.rebuild(e)                      # without the bond the pair 0-1 is a contact
    assert len(c2.i) == 3


def test_a_cell_too_short_for_the_reach_is_refused_before_any_work():
    """The period check uses the global reach 2 R_max + skin (the same on every rank)."""
    pos, L = granular.simple_cubic(4, R, spacing=2.2, jitter=0.0)
    with pytest.raises(ValueError, match="periodic axis y: period .* shorter than twice the contact reach"):
        granular_case(Communicator(), pos, R, 2500.0, "hertz_mindlin", {"young": 72e9, "poisson": 0.2},
                       np.zeros(3), np.array([L, 4.1 * R, L]), 1e-8, 0.1 * R)


def test_centres_outside_the_cell_are_wrapped_in():
    pos, L = granular.simple_cubic(4, R, spacing=2.2, jitter=0.0)
    shifted = pos + np.array([3 * L, -2 * L, 0.0])
    a = granular_case(Communicator(), pos, R, 2500.0, "hertz_mindlin", {"young": 72e9, "poisson": 0.2},
                       np.zeros(3), np.full(3, L), 1e-8, 0.1 * R)
    b = granular_case(Communicator(), shifted, R, 2500.0, "hertz_mindlin", {"young": 72e9, "poisson": 0.2},
                       np.zeros(3), np.full(3, L), 1e-8, 0.1 * R)
    np.testing.assert_allclose(b.sim.elements.x, a.sim.elements.x, rtol=0, atol=1e-15)


def _spinning_gas(orientation):
    """A frictional packing, squeezed (overlaps 2 %, jittered) with random spins: contacts turn
    the grains, so their orientations change a lot within a few hundred steps."""
    pos, radii, L = dense_packing()
    w0 = np.random.default_rng(9).normal(0.0, 2e3, (len(pos), 3))     # rad/s
    return granular_case(Communicator(), pos, radii, 2500.0, "hertz_mindlin",
                          {"young": 72e9, "poisson": 0.2, "friction": 0.5}, np.zeros(3),
                          np.full(3, L), 2e-9, 0.05 * R, angular_velocities=w0,
                          orientation=orientation)


def test_without_orientation_the_motion_is_the_same_to_the_bit(tmp_path):
    """No contact law reads q: a run that does not integrate it moves the grains exactly as one
    that does; q then keeps its initial value. Its restart keeps the choice."""
    on, off = _spinning_gas(True), _spinning_gas(False)
    q0 = off.sim.elements.q.copy()
    for case in (on, off):
        case.sim.run(300)
    a, b = on.sim, off.sim
    assert (a.orientation, b.orientation) == (True, False)
    np.testing.assert_array_equal(a.elements.gid, b.elements.gid)
    for key in ("x", "v", "w", "f", "t"):
        np.testing.assert_array_equal(getattr(a.elements, key), getattr(b.elements, key), err_msg=key)
    np.testing.assert_array_equal(a.contacts.history, b.contacts.history)
    np.testing.assert_array_equal(b.elements.q, q0)
    # not vacuous: integrated, the orientations moved by far more than round-off (w dt ~ 4e-6 rad
    # per step over 300 steps)
    assert np.abs(a.elements.q - q0).max() > 1e-4
    path = tmp_path / "off.h5"
    restart.save(off.sim, extras=off.extras, path=str(path))
    back = restart.load_case(Communicator(), str(path))
    assert back.sim.orientation is False
    back.sim.run(50)
    off.sim.run(50)
    for key in ("x", "v", "w", "q"):
        np.testing.assert_array_equal(getattr(back.sim.elements, key), getattr(off.sim.elements, key))


def test_bonded_elements_need_their_orientation():
    from pardem.engine.bonding import BeamMaterial, make_bonds
    from pardem.engine.simulation import Simulation
    from pardem.engine.state import Elements
    e = Elements.from_spheres(np.array([[0.0, 0.0, 0.0], [2 * R, 0.0, 0.0]]), R, 2500.0)
    bonds = make_bonds(e, [[0, 1]], BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0),
                       np.eye(3))
    bonds.relink(e.gid)
    with pytest.raises(ValueError, match="orientation"):
        Simulation(Communicator(), e, bonds, None, 1e-9, orientation=False)
    Simulation(Communicator(), e, bonds, None, 1e-9)     # the default integrates them
