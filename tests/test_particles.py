"""``sim.particles`` (pardem/engine/particles.py): global arrays by gid, get/set, custom arrays,
and the global wall forces and fix reactions; 1 rank here, 1 vs 2 ranks through
``tests/mpi/particles_run.py``."""
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import pardem
from _util import bonded_sim, granular_case
from pardem.engine.state import Elements
from pardem.engine import granular

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
EPS = np.finfo(float).eps
R = 0.1e-3
HM = {"young": 72e9, "poisson": 0.2, "friction": 0.5, "restitution": 0.9}


@pytest.fixture(scope="module")
def comm():
    return pardem.Communicator()


def gas(comm, seed=7, params=HM, **kw):
    pos, L = granular.simple_cubic(4, R, spacing=2.1, jitter=0.02, seed=seed)
    return granular_case(comm, pos, R, 2500.0, "hertz_mindlin", params, np.zeros(3), np.full(3, L),
                                  skin=None, dt=1e-8, **kw).sim, pos


def shuffled(comm):
    """A gas whose owned rows are not in gid order (as after a migration)."""
    sim, pos = gas(comm)
    e = sim.elements
    rev = np.arange(e.n_owned)[::-1]
    sim.elements = Elements.unpack([e.pack(rev)], e.n_owned)
    sim.run(0)
    return sim, pos


# -- reading ---------------------------------------------------------------------------------

def test_global_views_are_in_gid_order_whatever_the_rows(comm):
    sim, pos = shuffled(comm)
    p = sim.particles
    assert sim.elements.gid[0] == len(pos) - 1         # row 0 holds the last gid
    assert np.array_equal(p.gids, np.arange(len(pos)))
    assert np.array_equal(p.positions, pos)            # the builder's input, row k = gid k
    assert np.array_equal(p.radii, np.full(len(pos), R))
    assert np.array_equal(p.masses, np.full(len(pos), 2500.0 * 4.0 / 3.0 * np.pi * R**3))
    e = sim.elements
    order = np.argsort(e.gid)
    for name, field in (("velocities", "v"), ("angular_velocities", "w"), ("orientations", "q"),
                        ("forces", "f"), ("torques", "t")):
        assert np.array_equal(getattr(p, name), getattr(e, field)[order]), name
    assert p.n == len(pos)
    assert p.positions.shape == (len(pos), 3) and p.orientations.shape == (len(pos), 4)


def test_get_a_subset_in_the_given_order(comm):
    sim, pos = shuffled(comm)
    p = sim.particles
    gids = [5, 0, 5, 17]
    assert np.array_equal(p.get("positions", gids), pos[gids])
    assert np.array_equal(p.get("radii", np.array(3)), [R])
    assert p.get("forces", []).shape == (0, 3)


def test_local_view_is_the_owned_rows(comm):
    sim, _ = shuffled(comm)
    loc = sim.particles.local
    e = sim.elements
    assert loc.n == e.n_owned
    assert np.shares_memory(loc.positions, e.x) and loc.positions.shape == (e.n_owned, 3)
    assert np.array_equal(loc.gids, e.gid[:e.n_owned])
    with pytest.raises(AttributeError, match="no particle array 'x'"):
        loc.x


# -- writing ---------------------------------------------------------------------------------

def test_set_then_get_round_trip_by_gid(comm):
    sim, pos = shuffled(comm)
    p = sim.particles
    rng = np.random.default_rng(0)
    v = rng.normal(size=(len(pos), 3))
    p.set("velocities", v)
    assert np.array_equal(p.velocities, v)
    p.set("angular_velocities", [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], gids=[9, 2])
    w = p.angular_velocities
    assert np.array_equal(w[[9, 2]], [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    assert np.array_equal(w[0], [0.0, 0.0, 0.0])
    q = rng.normal(size=(len(pos), 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    p.set("orientations", q)
    assert np.array_equal(p.orientations, q)
    # the cached rotation matrices follow (the bond kernels' frames at bond creation read them)
    e = sim.elements
    k = int(np.nonzero(e.gid == 4)[0][0])
    w0, x0, y0, z0 = q[4]
    assert e.rot[k][0, 0] == pytest.approx(1 - 2 * (y0 * y0 + z0 * z0), abs=1e-15)


@pytest.mark.parametrize("call, message", [
    (lambda p: p.get("temperature"), "particle array 'temperature': expected one of 'positions'"),
    (lambda p: p.get("positions", [0, 64]), r"gids 64: not a particle of this simulation; valid global ids: 0 \.\. 63 \(64 particles\)"),
    (lambda p: p.get("positions", [[0, 1]]), "gids must be a 1-D sequence"),
    (lambda p: p.get("positions", [-1]), "gids must be >= 0"),
    (lambda p: p.get("positions", [0.5]), "gids must be integer"),
    (lambda p: p.set("forces", np.zeros((64, 3))), "'forces' cannot be written: expected one of 'positions'"),
    (lambda p: p.set("radii", np.ones(64)), r"read-only: 'forces', 'torques', 'radii', 'masses', 'gids'"),
    (lambda p: p.set("velocities", np.zeros((63, 3))), r"values of shape \(63, 3\), expected \(64, 3\)"),
    (lambda p: p.set("velocities", np.zeros((2, 3)), gids=[1, 1]), "gids must not repeat"),
    (lambda p: p.set("velocities", np.zeros((1, 3)), gids=[99]), "gids 99: not a particle"),
    (lambda p: p.set("velocities", np.full((1, 3), np.nan), gids=[0]), "values must be finite"),
    (lambda p: p.set("velocities", "fast"), "values must be an array of numbers"),
    (lambda p: p.set("orientations", np.ones((1, 4)), gids=[0]), "not a unit quaternion"),
    (lambda p: p.add_property("positions"), "name 'positions' is taken"),
    (lambda p: p.add_property("get"), "name 'get' is taken"),
    (lambda p: p.add_property("2x"), "must be an identifier"),
    (lambda p: p.add_property("h", shape=(2, 2)), r"shape must be \(\) or \(k,\)"),
    (lambda p: p.add_property("h", shape=(0,)), r"shape must be \(\) or \(k,\)"),
    (lambda p: p.add_property("h", shape=(3,), default=[1.0, 2.0]), "default must be a number or an array of shape"),
    (lambda p: p.add_property("h", default=np.inf), "default must be finite"),
    (lambda p: p.remove_property("h"), "no custom array 'h'"),
])
def test_bad_input_is_one_value_error(comm, call, message):
    sim, _ = gas(comm)
    before = sim.particles.positions
    with pytest.raises(ValueError, match=message):
        call(sim.particles)
    assert np.array_equal(sim.particles.positions, before)   # nothing written


def test_set_positions_and_velocities_then_run_equals_the_built_system(comm):
    """Before the first run: bit for bit the system built with those values (the MPI script
    checks it on 2 ranks, and after a run)."""
    a, pos0 = gas(comm, seed=7)
    b_pos, L = granular.simple_cubic(4, R, spacing=2.1, jitter=0.02, seed=8)
    # squeezed about the centre (spacing 2.0 R: pairs in contact from the first force evaluation)
    # and shuffled (every element elsewhere): a stale contact list would miss them
    b_pos = 0.5 * L + (b_pos - 0.5 * L) * (2.0 / 2.1)
    b_pos = b_pos[np.random.default_rng(2).permutation(len(b_pos))]
    v = np.random.default_rng(1).normal(0.0, 5.0, b_pos.shape)
    a.particles.set("positions", b_pos)
    a.particles.set("velocities", v)
    a.run(300)
    b = granular_case(comm, b_pos, R, 2500.0, "hertz_mindlin", HM, np.zeros(3), np.full(3, L),
                               skin=None, dt=1e-8, velocities=v).sim
    b.run(300)
    for name in ("positions", "velocities", "angular_velocities", "forces", "torques"):
        assert np.array_equal(a.particles.get(name), b.particles.get(name)), name
    assert b.contacts.n_touching > 0


def test_set_velocities_after_a_run_recomputes_the_forces(comm):
    """The forces the next first half kick uses are those of the new velocities: with only
    viscous drag (C, no contact), f = -C m v exactly."""
    C = 1e3
    x = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    sim = bonded_sim(comm, x, 0.1, 1000.0, np.zeros((0, 2), int),
                               pardem.BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0),
                               dt=1e-4, viscous_damping=C, velocities=[[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    sim.run(5)
    v = np.array([[0.0, 0.0, 3.0], [-1.0, 0.0, 0.0]])
    sim.particles.set("velocities", v)
    m = sim.particles.masses
    assert np.array_equal(sim.particles.forces, -C * m[:, None] * v)


# -- custom arrays ---------------------------------------------------------------------------

def test_custom_array_by_gid_and_through_a_checkpoint(comm, tmp_path):
    sim, pos = shuffled(comm)
    p = sim.particles
    p.add_property("temperature", default=293.15)
    p.add_property("tag", shape=(2,), default=[1.0, -1.0])
    assert np.array_equal(p.temperature, np.full(len(pos), 293.15))
    assert np.array_equal(p.get("tag", [3]), [[1.0, -1.0]])
    t = 300.0 + np.arange(len(pos))
    p.set("temperature", t)
    p.set("tag", [[5.0, 6.0]], gids=[10])
    assert np.array_equal(p.temperature, t)
    sim.run(20)
    assert np.array_equal(p.temperature, t)      # steps do not touch it
    path = str(tmp_path / "gas.h5")
    pardem.save(sim, path)
    back = pardem.load(comm, path)
    assert back.particles.names == p.names
    assert np.array_equal(back.particles.temperature, t)
    tag = back.particles.tag
    assert np.array_equal(tag[10], [5.0, 6.0]) and np.array_equal(tag[11], [1.0, -1.0])
    assert np.array_equal(back.particles.positions, p.positions)
    p.remove_property("tag")
    assert "tag" not in p.names


def test_a_checkpoint_without_custom_arrays_loads_without_them(comm, tmp_path):
    sim, _ = gas(comm)
    path = str(tmp_path / "plain.h5")
    pardem.save(sim, path)
    assert pardem.load(comm, path).elements.properties == {}


# -- global reactions and wall forces ----------------------------------------------------------

def test_clamp_reaction_balances_the_loads_of_a_static_cantilever(comm):
    n, Rc, F = 5, 0.01, 1e-3
    x = np.zeros((n, 3))
    x[:, 0] = 2.0 * Rc * np.arange(n)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    E, ratio, rho = 1e9, 0.5, 1000.0
    L = 2.0 * Rc * (n - 1)
    EI = E * np.pi * (ratio * Rc) ** 4 / 4.0
    m = rho * 4.0 / 3.0 * np.pi * Rc**3
    omega1 = 1.875**2 * np.sqrt(EI / (m / (2.0 * Rc) * L**4))
    sim = bonded_sim(comm, x, Rc, rho, pairs, pardem.BeamMaterial(young=E, radius_ratio=ratio,
                               poisson=0.3, damping=0.0), viscous_damping=2.0 * omega1)
    clamp = pardem.Clamp([0])
    tip = np.array([1e-4, 2e-4, -F])
    mid = np.array([0.0, 0.0, -0.5 * F])
    pardem.add_fixes(sim, clamp, pardem.ExternalForce([n - 1, 2], force=[tip, mid]))
    assert np.array_equal(clamp.global_reaction, np.zeros(3))      # nothing reduced before a run
    chunk = max(1, int(5.0 / omega1 / sim.dt))
    last = None
    for _ in range(60):
        sim.run(chunk)
        now = sim.particles.positions
        if last is not None and np.max(np.abs(now - last)) < 1e-12 * L:
            break
        last = now
    # static equilibrium of the whole chain: the clamp holds minus the loads, and minus their
    # moments about the clamped centre (arms from the deformed positions). Round-off bound: the
    # residual of the stiffest (axial) bond springs at rest, k_a ~ ulp(x) per bond, ~ 1e-10 N here
    k_axial = E * np.pi * (ratio * Rc) ** 2 / (2.0 * Rc)
    tol = 10.0 * n * k_axial * EPS * L
    assert np.allclose(clamp.global_reaction, -(tip + mid), rtol=0.0, atol=tol)
    moment = np.cross(now[n - 1] - now[0], tip) + np.cross(now[2] - now[0], mid)
    assert np.allclose(clamp.global_reaction_torque, -moment, rtol=0.0, atol=tol * L)
    assert np.array_equal(clamp.global_reaction, clamp.reaction)   # one rank: its share is the total


def rest_bound(C, mass, z, dt, weight):
    """How far from the weight [N] the wall force of spheres settled by a drag C [1/s] may stay:
    the drift ``z + dt v`` stops moving ``z`` once ``|v| dt`` is below half an ulp of z, and the
    drag ``C m v`` of that speed then holds the rest (measured: 2.9e-13 N of 0.33 N); the drag's
    decay ``exp(-t omega^2 / C)`` of the slowest sphere is far below it after 3000 steps."""
    return float(np.sum(C * mass * np.spacing(np.max(z)) / dt)) + 4 * EPS * weight


def test_wall_force_is_the_weight_of_resting_spheres(comm):
    Rs, rho, k, g = 0.01, 2500.0, 1e4, 9.81
    radii = Rs * np.array([1.0, 0.8, 1.2])
    overlap = 1e-4                                     # pressed into the wall at the start [m]
    x = np.stack([3.0 * Rs * np.arange(3), np.zeros(3), radii - overlap], axis=1)
    mass = rho * 4.0 / 3.0 * np.pi * radii**3
    omega = np.sqrt(k / mass.min())
    sim = bonded_sim(comm, x, radii, rho, np.zeros((0, 2), int),
                               pardem.BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0),
                               viscous_damping=2.0 * omega,
                               walls=dict(normals=[[0, 0, 1]], points=[[0, 0, 0]], stiffness=k))
    pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -g)))
    walls = sim.plates
    assert np.array_equal(walls.force, np.zeros((1, 3)))     # nothing reduced before a run
    sim.run(0)
    # run(0) computes the forces of the initial state (at rest: the linear spring k * overlap per
    # sphere, the overlap R - z rounded once) and ends the run with their reduction
    assert walls.force[0] == pytest.approx([0.0, 0.0, -3 * k * overlap], rel=1e-12, abs=0.0)
    sim.run(3000)
    # at rest the wall carries the weight
    weight = mass.sum() * g
    tol = rest_bound(2.0 * omega, mass, x[:, 2], sim.dt, weight)
    assert walls.force[0] == pytest.approx([0.0, 0.0, -weight], rel=0.0, abs=tol)
    assert walls.normal_force[0] == pytest.approx(weight, rel=0.0, abs=tol)
    assert tol < 1e-11 * weight        # the bound itself is tight
    assert np.array_equal(walls.force, walls.forces(comm))      # the collective sum of the same step


def test_wall_force_is_reduced_on_the_steps_an_operation_runs(comm):
    """An operation reads the wall force of its own step, not of the end of the last run."""
    sim = bonded_sim(comm, [[0.0, 0.0, 0.01 + 0.005]], 0.01, 2500.0, np.zeros((0, 2), int),
                               pardem.BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0),
                               walls=dict(normals=[[0, 0, 1]], points=[[0, 0, 0]], stiffness=1e4))
    pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -9.81)))
    seen = []

    class Probe:
        trigger, at_end = 3, True

        def __call__(self, s):
            seen.append((s.step_count, s.plates.force.copy(), s.plates.forces(s.comm)))

    sim.run(400, operations=[Probe()])
    assert len(seen) == 134 and sum(f[0, 2] != 0.0 for _, f, _ in seen) > 2     # steps 3 .. 399, end; it hit the wall
    for step, force, collective in seen:
        assert np.array_equal(force, collective), step


def test_prescribed_velocity_reaction_is_the_drag_it_overcomes(comm):
    C, V, spin = 50.0, np.array([0.3, -0.2, 0.1]), 2.0
    x = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    radii = np.array([0.1, 0.2])
    sim = bonded_sim(comm, x, radii, 1000.0, np.zeros((0, 2), int),
                               pardem.BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0),
                               dt=1e-4, viscous_damping=C, velocities=np.tile(V, (2, 1)))
    drive = pardem.PrescribedVelocity([0, 1], V, angular_velocity=(0.0, 0.0, spin))
    pardem.add_fixes(sim, drive)
    sim.run(10)
    m = sim.particles.masses
    inertia = 0.4 * m * radii**2
    # the drag -C m V (-C I w) is what the drive removes each step; float sums of two terms
    assert drive.global_reaction == pytest.approx(C * m.sum() * V, rel=4 * EPS)
    assert drive.global_reaction_torque == pytest.approx([0.0, 0.0, C * inertia.sum() * spin], rel=4 * EPS)


# -- 1 rank against 2 ranks ------------------------------------------------------------------

def _run_script(ranks, out):
    cmd = [sys.executable, os.path.join(ROOT, "tests", "mpi", "particles_run.py"), str(out)]
    if ranks > 1:
        cmd = [MPIEXEC, "-n", str(ranks)] + cmd
    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, cwd=ROOT, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    return dict(np.load(os.path.join(out, "particles.npz")))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    if MPIEXEC is None:
        pytest.skip("no mpiexec")
    one, two = tmp_path_factory.mktemp("one"), tmp_path_factory.mktemp("two")
    return _run_script(1, one), _run_script(2, two), two


# float sums over ranks (reactions of elements on both ranks): agree to their round-off only
ROUND_OFF_ONLY = {"drive_reaction", "drive_reaction_torque", "rest_wall_force", "rest_wall_normal_force",
                  "rest_wall_forces_collective", "cantilever_local_sum"}
PER_RUN = {"ranks", "owner_before", "owner_after", "ghost_count", "ghosts_hold_properties"}


@pytest.mark.mpi
def test_one_and_two_ranks_read_the_same_bits(runs):
    one, two, _ = runs
    assert int(one["ranks"]) == 1 and int(two["ranks"]) == 2
    for name in sorted(one):
        if name in PER_RUN:
            continue
        if name in ROUND_OFF_ONLY:
            assert np.allclose(one[name], two[name], rtol=1e-14, atol=0.0), name
        else:
            assert np.array_equal(one[name], two[name]), name


@pytest.mark.mpi
@pytest.mark.parametrize("which", [0, 1])
def test_set_then_run_equals_built_on_one_and_two_ranks(runs, which):
    out = runs[which]
    for name in ("positions", "velocities", "angular_velocities", "orientations", "forces", "torques"):
        assert np.array_equal(out[f"set_{name}"], out[f"built_{name}"]), name
    # set after a run (frictionless: no tangential spring carries the old state over)
    assert np.array_equal(out["late_forces_at_set"], out["fresh_forces_at_start"])
    for name in ("positions", "velocities", "angular_velocities", "orientations", "forces"):
        assert np.array_equal(out[f"late_{name}"], out[f"fresh_{name}"]), name


@pytest.mark.mpi
def test_custom_arrays_migrate_with_their_elements(runs):
    one, two, _ = runs
    n = len(one["set_gids"])
    assert np.array_equal(two["set_gids"], np.arange(n)) and int(two["set_n"]) == n
    moved = np.count_nonzero(two["owner_before"] != two["owner_after"])
    assert moved > 0 and set(two["owner_after"]) == {0, 1}            # elements crossed the slab cut
    assert float(two["ghost_count"]) > 0 and np.all(two["ghosts_hold_properties"])
    assert np.array_equal(two["set_temperature"], 300.0 + np.arange(n))
    assert np.array_equal(two["set_tag"], np.stack([np.arange(n), -np.arange(n)], axis=1).astype(float))
    assert np.array_equal(two["set_subset"], two["set_positions"][[7, 3, 7]])
    for name in ("positions", "velocities", "temperature", "tag"):
        assert np.array_equal(two[f"loaded_{name}"], two[f"set_{name}"]), name


@pytest.mark.mpi
def test_a_two_rank_checkpoint_with_custom_arrays_loads_on_one_rank(runs, comm):
    _, two, where = runs
    back = pardem.load(comm, os.path.join(where, "gas.h5"))
    assert np.array_equal(back.particles.temperature, two["set_temperature"])
    assert np.array_equal(back.particles.tag, two["set_tag"])
    assert np.array_equal(back.particles.velocities, two["set_velocities"])


@pytest.mark.mpi
@pytest.mark.parametrize("which", [0, 1])
def test_reactions_are_global_on_every_rank(runs, which):
    out = runs[which]
    load = out["cantilever_load"]
    # the clamp's total balances the tip load: the round-off bound of the axial springs at rest of
    # test_clamp_reaction_balances_the_loads_of_a_static_cantilever (the script's n = 6, R = 0.01 m,
    # E = 1e9 Pa, ratio 0.5, L = 0.1 m)
    tol = 10.0 * 6 * 1e9 * np.pi * 0.005**2 / 0.02 * EPS * 0.1
    assert np.allclose(out["cantilever_reaction"], -load, rtol=0.0, atol=tol)
    x = out["cantilever_positions"]
    assert np.allclose(out["cantilever_reaction_torque"], -np.cross(x[-1] - x[0], load), rtol=0.0, atol=tol * 0.1)
    # read on the last rank alone, and the sum of the per-rank shares: the same total
    assert np.array_equal(out["cantilever_last_rank"], out["cantilever_reaction"])
    assert np.allclose(out["cantilever_local_sum"][:3], out["cantilever_reaction"], rtol=1e-15, atol=0.0)
    weight = out["rest_masses"].sum() * 9.81
    tol = rest_bound(float(out["rest_C"]), out["rest_masses"], out["rest_z"], float(out["rest_dt"]), weight)
    assert out["rest_wall_force"][0] == pytest.approx([0.0, 0.0, -weight], rel=0.0, abs=tol)
    assert np.array_equal(out["rest_wall_force"], out["rest_wall_forces_collective"])
    m, r = out["drive_masses"], out["drive_radii"]
    assert out["drive_reaction"] == pytest.approx(50.0 * m.sum() * np.array([0.3, -0.2, 0.1]), rel=8 * EPS)
    assert out["drive_reaction_torque"][2] == pytest.approx(50.0 * (0.4 * m * r**2).sum() * 2.0, rel=8 * EPS)
