"""Fixes (pardem.engine.fixes) against independent computations.

Velocity Verlet with a constant force is exact for the trajectory x0 + v0 t + a t^2 / 2 (the
position update is the second-order Taylor polynomial, and constant acceleration has no higher
terms), so free motion checks are limited by floating-point rounding only.
"""
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import pardem
from pardem.engine.state import Elements
from pardem.engine.fixes import ElementSelection, add
from _util import bonded_sim

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
R, RHO = 0.01, 1000.0


def chain(comm, n=6, damping=0.0, **kw):
    x = np.zeros((n, 3))
    x[:, 0] = 2.0 * R * np.arange(n)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    mat = pardem.BeamMaterial(young=1e8, radius_ratio=0.5, poisson=0.3, damping=damping)
    return bonded_sim(comm, x, R, RHO, pairs, mat, **kw)


def free_sphere(comm, v0=(0.0, 0.0, 0.0), dt=1e-4):
    return bonded_sim(comm, np.zeros((1, 3)), R, RHO, np.zeros((0, 2), int), 
                                pardem.BeamMaterial(young=1e8, radius_ratio=0.5, poisson=0.3, damping=0.0),
                                dt=dt, velocities=[v0])


@pytest.fixture(scope="module")
def comm():
    return pardem.Communicator()


def test_gravity_free_fall_is_the_parabola(comm):
    v0, g, dt, n = np.array([0.3, -0.2, 1.5]), np.array([0.0, 0.0, -9.81]), 1e-4, 2000
    sim = free_sphere(comm, v0, dt)
    sim.fixes.append(pardem.Gravity(g))
    sim.run(n)
    t = n * dt
    expected = v0 * t + 0.5 * g * t**2
    # exact but for rounding: ~n additions of relative error 1e-16 each on values of size |x|
    assert np.allclose(sim.elements.x[0], expected, rtol=0, atol=n * 4e-16 * np.abs(expected).max())
    assert np.allclose(sim.elements.v[0], v0 + g * t, rtol=0, atol=n * 4e-16 * 10.0)
    assert sim.time == pytest.approx(t, rel=1e-15)


def test_gravity_acts_on_every_element_with_its_own_mass(comm):
    # two unbonded spheres of different radii fall together: f = m g, a = g for both
    sim = bonded_sim(comm, [[0, 0, 0], [1, 0, 0]], [R, 2 * R], RHO, np.zeros((0, 2), int),
                               pardem.BeamMaterial(young=1e8, radius_ratio=0.5, poisson=0.3, damping=0.0),
                               dt=1e-4)
    sim.fixes.append(pardem.Gravity((0, 0, -9.81)))
    sim.run(100)
    e = sim.elements
    assert e.mass[1] == pytest.approx(8 * e.mass[0])
    # identical arithmetic on both rows: same acceleration to rounding of m g / m
    assert np.allclose(e.v[0], e.v[1], rtol=1e-14, atol=0)
    assert e.v[0, 2] == pytest.approx(-9.81 * 100 * 1e-4, rel=1e-13)


def test_external_force_gives_acceleration_f_over_m_and_torque_over_inertia(comm):
    F, T, dt, n = np.array([1e-3, -2e-3, 5e-4]), np.array([1e-6, 0.0, -3e-6]), 1e-4, 500
    sim = free_sphere(comm, dt=dt)
    sim.fixes.append(pardem.ExternalForce([0], F, torque=T))
    sim.run(n)
    e = sim.elements
    m, inertia = e.mass[0], e.inertia[0]
    # independent mass and inertia of a solid sphere
    assert m == pytest.approx(RHO * 4 / 3 * np.pi * R**3, rel=1e-15)
    assert inertia == pytest.approx(0.4 * m * R**2, rel=1e-15)
    # constant force: v = F t / m, x = F t^2 / (2 m), exact but for rounding
    t = n * dt
    assert np.allclose(e.v[0], F / m * t, rtol=1e-12, atol=0)
    assert np.allclose(e.x[0], 0.5 * F / m * t**2, rtol=1e-12, atol=0)
    assert np.allclose(e.w[0], T / inertia * t, rtol=1e-12, atol=0)


def test_external_force_per_element_rows_follow_the_gids(comm):
    sim = bonded_sim(comm, [[0, 0, 0], [1, 0, 0], [2, 0, 0]], R, RHO, np.zeros((0, 2), int),
                               pardem.BeamMaterial(young=1e8, radius_ratio=0.5, poisson=0.3, damping=0.0),
                               dt=1e-4)
    # gids given out of order: row m of force belongs to gids[m]
    sim.fixes.append(pardem.ExternalForce([2, 0], [[0, 0, 2e-3], [0, 0, -1e-3]]))
    sim.run(10)
    e = sim.elements
    a = e.v[:, 2] / (10 * 1e-4)
    assert a[e.gid == 2][0] == pytest.approx(2e-3 / e.mass[0], rel=1e-12)
    assert a[e.gid == 0][0] == pytest.approx(-1e-3 / e.mass[0], rel=1e-12)
    assert a[e.gid == 1][0] == 0.0


def test_clamp_keeps_the_clamped_element_bitwise_in_place(comm):
    sim = chain(comm)
    x0, q0 = sim.elements.x[0].copy(), sim.elements.q[0].copy()
    clamp = pardem.Clamp([0])
    # added in the wrong order on purpose: add() puts the loads before the constraint
    add(sim, clamp, pardem.ExternalForce([5], (0.0, 1e-2, -1e-2), torque=(1e-4, 0, 0)), pardem.Gravity())
    assert [type(f).__name__ for f in sim.fixes] == ["ExternalForce", "Gravity", "Clamp"]
    sim.run(2000)
    e = sim.elements
    assert np.array_equal(e.x[0], x0) and np.array_equal(e.q[0], q0)
    assert np.all(e.v[0] == 0.0) and np.all(e.w[0] == 0.0)
    # the free end did move (the test could otherwise pass with a frozen chain)
    assert abs(e.x[5, 2] - e.x0[5, 2]) > 1e-7


def test_a_load_after_a_constraint_is_refused(comm):
    sim = chain(comm, n=2)
    sim.fixes += [pardem.Clamp([0]), pardem.Gravity()]
    with pytest.raises(ValueError, match="before the load Gravity"):
        sim.run(1)


def test_clamp_holds_only_the_chosen_dofs(comm):
    sim = chain(comm, n=2)
    x0 = sim.elements.x[1].copy()
    add(sim, pardem.Clamp([1], dofs="z", rotations=""), pardem.ExternalForce([1], (1e-2, 0.0, 1e-2)))
    sim.run(500)
    e = sim.elements
    assert e.x[1, 2] == x0[2]                     # held: bitwise
    assert e.x[1, 0] != x0[0]                     # free: stretched the bond


def test_prescribed_velocity_moves_exactly_v_dt_per_step(comm):
    V = np.array([1e-3, 0.0, -2e-3])
    sim = chain(comm, n=4)
    sim.fixes += [pardem.Clamp([0]), pardem.PrescribedVelocity([3], V)]
    x = sim.elements.x[3].copy()
    for _ in range(20):
        sim.run(5)
        for _ in range(5):                      # the integrator's own arithmetic: x <- x + dt v
            x = x + sim.dt * V
        assert np.array_equal(sim.elements.x[3], x)
        assert np.array_equal(sim.elements.v[3], V)
    # the bonds pull back on the driven element: the drive's reaction is not zero
    fix = sim.fixes[1]
    assert np.linalg.norm(fix.reaction) > 0.0


def test_prescribed_angular_velocity(comm):
    W = np.array([0.0, 0.0, 2.0])
    sim = free_sphere(comm)
    sim.fixes.append(pardem.PrescribedVelocity([0], (0, 0, 0), angular_velocity=W))
    sim.run(1000)
    e = sim.elements
    angle = 2.0 * np.arctan2(np.linalg.norm(e.q[0, 1:]), e.q[0, 0])
    # exact quaternion exponential per step: the angle is n dt |W| to rounding
    assert angle == pytest.approx(1000 * sim.dt * 2.0, rel=1e-12)
    assert np.array_equal(e.w[0], W)


@pytest.mark.parametrize("make, message", [
    (lambda: pardem.Gravity((0, -9.81)), "g must be"),
    (lambda: pardem.ExternalForce([0], (1, 2)), "force must have shape"),
    (lambda: pardem.ExternalForce([0, 1], np.zeros((3, 3))), r"\(2, 3\)"),
    (lambda: pardem.ExternalForce([0], (np.nan, 0, 0)), "force must be finite"),
    (lambda: pardem.Clamp([0], dofs="xw"), "dofs must be a string"),
    (lambda: pardem.Clamp([0, 0]), "must not repeat"),
    (lambda: pardem.Clamp([-1]), ">= 0"),
    (lambda: pardem.Clamp([0.5]), "integer"),
    (lambda: pardem.Clamp([]), "non-empty"),
    (lambda: pardem.PrescribedVelocity([0], (0, 0, 0), rotations="z"), "needs angular_velocity"),
])
def test_bad_inputs_raise_value_errors_naming_the_argument(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_unknown_gid_raises_at_the_first_step(comm):
    sim = chain(comm, n=3)
    sim.fixes.append(pardem.Clamp([7]))
    with pytest.raises(ValueError, match=r"\[7\] are not element global ids"):
        sim.run(1)


def test_selection_cache_follows_new_elements_objects(comm):
    sim = chain(comm, n=4)
    sel = ElementSelection([3, 1])
    rows, idx = sel.rows(sim.elements, comm)
    assert list(sim.elements.gid[rows]) == [3, 1][0:0] + list(np.array([3, 1])[idx])
    # a new Elements object with reversed rows (as a migration would build): resolved again
    e = sim.elements
    rev = np.arange(e.n_total)[::-1]
    e2 = Elements.unpack([e.pack(rev)], e.n_owned)
    rows2, idx2 = sel.rows(e2, comm)
    assert np.array_equal(e2.gid[rows2], np.array([3, 1])[idx2]) and len(rows2) == 2
    assert not np.array_equal(rows, rows2)
    # rows permuted in place in the same object: caught by the O(k) check
    e2.gid[:] = e2.gid[::-1].copy()
    rows3, idx3 = sel.rows(e2, comm)
    assert np.array_equal(e2.gid[rows3], np.array([3, 1])[idx3])


RANKS_SCRIPT = textwrap.dedent("""
    import sys, numpy as np, pardem
    comm = pardem.Communicator()
    n, R = 12, 0.01
    x = np.zeros((n, 3)); x[:, 0] = 2 * R * np.arange(n)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    mat = pardem.BeamMaterial(young=1e8, radius_ratio=0.5, poisson=0.3, damping=0.1)
    sim = pardem.build(comm, pardem.System(pardem.Particles(x, R, 1000.0), bonds=pardem.BondModel(mat, pairs),
                                           integration=pardem.Integration(dt=2e-6)))
    pardem.add_fixes(sim, pardem.Clamp([0]), pardem.Gravity(), pardem.ExternalForce([11, 6], (0, 1e-3, 0)),
                     pardem.PrescribedVelocity([5], (0, 0, 1e-3), dofs="z"))
    sim.run(3000)
    e = sim.elements
    rows = comm.gather((e.gid[:e.n_owned].copy(), e.x[:e.n_owned].copy(), e.v[:e.n_owned].copy()))
    if comm.is_root:
        g = np.concatenate([r[0] for r in rows]); order = np.argsort(g)
        np.savez(sys.argv[1], gid=g[order], x=np.concatenate([r[1] for r in rows])[order],
                 v=np.concatenate([r[2] for r in rows])[order], n_ranks=comm.size)
""")


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_fixes_give_the_same_motion_on_one_and_two_ranks(tmp_path):
    script = tmp_path / "run.py"
    script.write_text(RANKS_SCRIPT)
    out = {}
    for k in (1, 2):
        path = tmp_path / f"r{k}.npz"
        cmd = [MPIEXEC, "-n", str(k), sys.executable, str(script), str(path)]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
        assert res.returncode == 0, res.stderr
        out[k] = np.load(path)
    assert int(out[2]["n_ranks"]) == 2
    assert np.array_equal(out[1]["gid"], out[2]["gid"])
    # same arithmetic per element on both decompositions: ghosts are exact copies and each bond is
    # computed in the same orientation; only the order in which an element's bond forces are summed
    # may differ, which rounds at 1e-16 relative per step
    scale = np.abs(out[1]["x"]).max()
    assert np.allclose(out[1]["x"], out[2]["x"], rtol=0, atol=1e-12 * scale)
    for k in (1, 2):
        x = out[k]["x"]
        assert np.array_equal(x[0], [0.0, 0.0, 0.0])             # clamped: bitwise
        assert x[11, 1] > 1e-7                                   # the loaded end did move
        # the driven element: 3000 steps of dt v along z, to rounding
        assert x[5, 2] == pytest.approx(3000 * 2e-6 * 1e-3, rel=1e-12)


MIGRATION_SCRIPT = textwrap.dedent("""
    import sys, numpy as np, pardem
    comm = pardem.Communicator()
    R, dt, V, n = 0.01, 1e-3, 2.5, 1000
    x = [[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]]     # far apart: no bonds, no contacts
    mat = pardem.BeamMaterial(young=1e8, radius_ratio=0.5, poisson=0.3, damping=0.0)
    sim = pardem.build(comm, pardem.System(pardem.Particles(x, R, 1000.0), bonds=pardem.BondModel(mat),
                                           integration=pardem.Integration(dt=dt),
                                           decomposition=pardem.Decomposition(slab_axis=0)))
    drive = pardem.PrescribedVelocity([0], (V, 0, 0))
    push = pardem.ExternalForce([3], (1e-3, 0, 0))
    pardem.add_fixes(sim, drive, push)
    owner0 = comm.allgather(bool(np.any(sim.elements.gid[:sim.elements.n_owned] == 0)))
    sim.run(n)
    e = sim.elements
    mine = e.gid[:e.n_owned] == 0
    owner1 = comm.allgather(bool(np.any(mine)))
    ref = 0.0
    for _ in range(n):
        ref = ref + dt * V          # the integrator's arithmetic
    if np.any(mine):
        assert e.x[:e.n_owned][mine][0, 0] == ref, (e.x[:e.n_owned][mine][0, 0], ref)
    m3 = e.gid[:e.n_owned] == 3
    if np.any(m3):
        t = n * dt
        a = 1e-3 / e.mass[0]
        assert abs(e.x[:e.n_owned][m3][0, 0] - (3.0 + 0.5 * a * t * t)) < 1e-12
    if comm.is_root:
        print("owners", owner0.index(True), owner1.index(True), "rebuilds", sim.domain.rebuilds)
""")


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_fixes_follow_an_element_migrating_to_another_rank(tmp_path):
    script = tmp_path / "migrate.py"
    script.write_text(MIGRATION_SCRIPT)
    res = subprocess.run([MPIEXEC, "-n", "2", sys.executable, str(script)], capture_output=True,
                         text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stdout + res.stderr
    words = res.stdout.split()
    # the driven element started on rank 0 and ended on rank 1, through many rebuilds, and kept
    # moving exactly dt V per step (asserted in the script, bitwise)
    assert words[:3] == ["owners", "0", "1"], res.stdout
    assert int(words[4]) > 100


def test_fixes_added_between_runs_act_from_the_next_step(comm):
    sim = free_sphere(comm, v0=(0.5, 0.0, 0.0), dt=1e-4)
    sim.run(10)
    V = np.array([0.0, 0.0, 0.25])
    add(sim, pardem.PrescribedVelocity([0], V))
    x = sim.elements.x[0].copy()
    sim.run(7)
    for _ in range(7):
        x = x + sim.dt * V                     # exactly as if driven from the start
    assert np.array_equal(sim.elements.x[0], x)
    # a load added under an existing constraint does not break it
    add(sim, pardem.ExternalForce([0], (1.0, 1.0, 1.0)))
    assert [type(f).__name__ for f in sim.fixes] == ["ExternalForce", "PrescribedVelocity"]
    sim.run(3)
    for _ in range(3):
        x = x + sim.dt * V
    assert np.array_equal(sim.elements.x[0], x)


def test_fixes_added_again_after_load_continue_the_saved_run_exactly(comm, tmp_path):
    """A script that saves, loads and adds its gravity again continues bit for bit: the stored
    forces already hold the saved run's gravity (applying it again doubled g in the first kick)."""
    g = (0.0, 0.0, -9.81)
    ref = free_sphere(comm, v0=(0.1, 0.0, 0.3))
    add(ref, pardem.Gravity(g))
    ref.run(12)
    path = str(tmp_path / "fall.h5")
    pardem.save(ref, path)
    ref.run(9)
    back = pardem.load(comm, path)
    add(back, pardem.Gravity(g))
    back.run(9)
    assert back.step_count == ref.step_count
    assert np.array_equal(back.elements.x[0], ref.elements.x[0])
    assert np.array_equal(back.elements.v[0], ref.elements.v[0])
