"""Particles added and removed during a run (``sim.particles.add`` / ``remove``) and the
``Insert`` / ``Delete`` operations (pardem.engine.insertion); 1 against 2 ranks and the checkpoint
after insertions in ``tests/mpi/insertion_run.py``."""
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import pardem
from pardem.domains import distributions as D
from pardem.domains import regions as R
from pardem.domains.packing import random_pack
from pardem.engine.insertion import Delete, Insert

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
RAD = 1e-3
RHO = 2500.0
HM = dict(young=1e7, poisson=0.3, friction=0.5, restitution=0.3)


@pytest.fixture(scope="module")
def comm():
    return pardem.Communicator()


def _box_walls(width):
    return pardem.WallModel(
        normals=[[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]],
        points=[[0, 0, 0], [0, 0, 0], [width, 0, 0], [0, 0, 0], [0, width, 0]],
        law=pardem.wall_law("hertz", young=1e7, poisson=0.3, restitution=0.3, friction=0.0))


def _sim(comm, x, r, params=HM, walls=True, dt=None, skin=None):
    system = pardem.System(pardem.Particles(x, r, RHO), contacts=pardem.ContactModel("hertz_mindlin", dict(params)),
                           walls=_box_walls(0.02) if walls else None,
                           integration=pardem.Integration(dt=dt, orientation=False),
                           decomposition=pardem.Decomposition(slab_axis=0, skin=skin))
    sim = pardem.build(comm, system)
    pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -9.81)))
    return sim


def _bed(n=120, seed=1):
    c = random_pack(R.Box([0, 0, 0], [0.02, 0.02, 0.012]), D.Uniform(0.8 * RAD, 1.2 * RAD), n=n, seed=seed)
    assert c.complete
    return c.positions, c.radii


def test_add_gives_new_gids_and_keeps_the_others(comm):
    x, r = _bed()
    sim = _sim(comm, x, r)
    sim.particles.add_property("tag", default=7.0)
    sim.run(300)
    before = {k: sim.particles.get(k) for k in ("positions", "velocities", "angular_velocities", "radii", "tag")}
    n = sim.particles.n
    xn = np.array([[0.005, 0.005, 0.016], [0.012, 0.012, 0.017]])
    vn = np.array([[0.0, 0.0, -0.1], [0.1, 0.0, 0.0]])
    gids = sim.particles.add(xn, [0.9 * RAD, 1.1 * RAD], velocities=vn, properties={"tag": [1.0, 2.0]})
    assert gids.tolist() == [n, n + 1] and sim.particles.n == n + 2 == sim.n_elements
    for k, a in before.items():              # the others: the same bits
        assert np.array_equal(sim.particles.get(k, np.arange(n)), a), k
    assert np.array_equal(sim.particles.get("positions", gids), xn)
    assert np.array_equal(sim.particles.get("velocities", gids), vn)
    assert sim.particles.get("tag", gids).tolist() == [1.0, 2.0]
    m = sim.particles.get("masses", gids)
    assert np.allclose(m, RHO * 4 / 3 * np.pi * np.array([0.9 * RAD, 1.1 * RAD]) ** 3, rtol=1e-15)
    # default of a property not given: 0
    g2 = sim.particles.add([[0.01, 0.01, 0.018]], 1e-3)
    assert g2.tolist() == [n + 2] and sim.particles.get("tag", g2).tolist() == [0.0]
    # the new grains fall freely: after t, z = z0 + v t - g t^2 / 2 (Verlet is exact for constant g)
    steps = 50
    sim.run(steps)
    t = steps * sim.dt
    z = sim.particles.get("positions", gids)[:, 2]
    assert np.allclose(z, xn[:, 2] + vn[:, 2] * t - 0.5 * 9.81 * t**2, rtol=0, atol=1e-15)


def test_add_refuses_overlaps_with_a_count_and_changes_nothing(comm):
    x, r = _bed()
    sim = _sim(comm, x, r)
    sim.run(10)
    n = sim.particles.n
    deep = x[:3] + np.array([0.2 * RAD, 0, 0])        # three new centres 0.2 R from old ones
    with pytest.raises(ValueError, match=r"add: 3 pair\(s\) of a new and an existing particle overlap"):
        sim.particles.add(deep, RAD)
    with pytest.raises(ValueError, match="coincide"):
        sim.particles.add(x[5:6], RAD)
    with pytest.raises(ValueError, match="add: new particles: positions: 1 pair of unbonded elements overlap"):
        sim.particles.add([[0.01, 0.01, 0.03], [0.01, 0.01, 0.0305]], RAD)
    with pytest.raises(ValueError, match="critical time step"):
        sim.particles.add([[0.01, 0.01, 0.03]], 1e-3 * RAD)
    assert sim.particles.n == n
    # a shallow overlap (0.3 of the smaller radius, above the highest grain) is accepted, as the
    # builder accepts it
    xs = sim.particles.positions
    top = int(np.argmax(xs[:, 2]))
    sim.particles.add(xs[top:top + 1] + np.array([[0, 0, r[top] + 0.5 * RAD * 0.7]]), 0.5 * RAD)
    assert sim.particles.n == n + 1


def test_a_larger_radius_widens_the_reach(comm):
    x, r = _bed()
    sim = _sim(comm, x, r)
    sim.run(10)
    reach = sim.reach
    big = 3.0 * RAD
    top = int(np.argmax(x[:, 2]))
    # a big grain resting on the highest one, overlapping it by 1e-3 R
    c = x[top] + np.array([0.0, 0.0, r[top] + big - 1e-6])
    g = sim.particles.add([c], big)
    assert sim.reach == pytest.approx(2 * big + sim.contacts.skin) and sim.reach > reach
    keys = sim.contacts.keys
    assert (min(top, g[0]) << 31) + max(top, g[0]) in keys.tolist()   # the pair is in the list
    f = sim.particles.get("forces", [g[0]])[0]
    assert f[2] > -RHO * 4 / 3 * np.pi * big**3 * 9.81     # the contact pushes it up


def _frictionless_pair_of_beds(comm, with_far):
    """A bed in the box (gids 0 .. n-1) and, with ``with_far``, a second bed far away (gids after)."""
    x, r = _bed(80, seed=3)
    if with_far:
        xf, rf = _bed(40, seed=4)
        x = np.concatenate([x, xf + np.array([0.0, 0.0, 0.05])])
        r = np.concatenate([r, rf])
    params = dict(HM, friction=0.0)
    return _sim(comm, x, r, params=params, walls=False, dt=2e-6), len(x)


def test_removal_leaves_the_rest_on_its_trajectory(comm):
    # frictionless grains (no tangential history): removing a far cluster leaves the others'
    # trajectories those of a system built without it, bit for bit
    a, n_all = _frictionless_pair_of_beds(comm, True)
    b, n = _frictionless_pair_of_beds(comm, False)
    a.run(400)
    b.run(400)
    assert np.array_equal(a.particles.get("positions", np.arange(n)), b.particles.positions)
    a.particles.remove(np.arange(n, n_all))
    assert a.particles.n == n and a.particles.gids.tolist() == list(range(n))
    a.run(400)
    b.run(400)
    for k in ("positions", "velocities", "angular_velocities", "forces"):
        assert np.array_equal(a.particles.get(k), b.particles.get(k)), k
    assert a.kinetic_energy() == b.kinetic_energy()


def test_removal_drops_contact_histories_and_keeps_the_others(comm):
    x, r = _bed()
    sim = _sim(comm, x, r)
    sim.run(2000)           # settle: frictional contacts with a history
    c = sim.contacts
    table = c.table()
    assert len(table["gid_i"]) >= 6
    gone = np.unique(table["gid_i"][::3][:3])       # grains with a tangential history
    live = (table["gid_i"] << 31) + table["gid_j"]
    assert np.any(np.isin(table["gid_i"], gone) | np.isin(table["gid_j"], gone))     # some to drop
    keep_keys = live[~(np.isin(table["gid_i"], gone) | np.isin(table["gid_j"], gone))]
    keep_hist = table["history"][~(np.isin(table["gid_i"], gone) | np.isin(table["gid_j"], gone))]
    sim.particles.remove(gone)
    assert not np.any(np.isin(c.keys // (1 << 31), gone) | np.isin(c.keys % (1 << 31), gone))
    pos = {int(k): i for i, k in enumerate(c.keys)}
    assert all(int(k) in pos for k in keep_keys)
    got = np.array([c.history[pos[int(k)]] for k in keep_keys])
    assert np.array_equal(got, keep_hist)         # histories by gid pair, untouched
    assert sorted(set(range(len(x))) - set(sim.particles.gids.tolist())) == gone.tolist()
    with pytest.raises(ValueError, match="not a particle of this simulation"):
        sim.particles.remove(gone[:1])
    with pytest.raises(ValueError, match="keeps at least one"):
        sim.particles.remove(sim.particles.gids)
    sim.run(10)


def test_removal_recomputes_the_forces_of_those_left(comm):
    # a column of two grains resting on the floor: once the lower one is gone, the upper one
    # touches nothing and its force is its weight alone, before any step
    x = np.array([[0.01, 0.01, RAD], [0.01, 0.01, 3 * RAD]])
    sim = _sim(comm, x, RAD)
    sim.run(3000)
    f_before = sim.particles.get("forces", [1])[0]
    assert f_before[2] > -1e-3 * RHO * 4 / 3 * np.pi * RAD**3 * 9.81      # at rest on the lower grain
    sim.particles.remove([0])
    m = sim.particles.masses[0]
    assert np.array_equal(sim.particles.forces[0], np.array([0.0, 0.0, -m * 9.81]))


def test_removal_drops_the_bonds_of_removed_particles(comm):
    n = 7
    x = np.zeros((n, 3))
    x[:, 0] = 2e-2 * np.arange(n)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    material = pardem.BeamMaterial(young=1e9, radius_ratio=0.5, poisson=0.3, damping=0.0)
    sim = pardem.build(comm, pardem.System(pardem.Particles(x, 1e-2, 1000.0), bonds=pardem.BondModel(material, pairs)))
    sim.run(5)
    assert sim.bonds.n == 6
    sim.particles.remove([3])
    assert sim.bonds.n == 4
    ends = sorted(zip(sim.bonds.gid_i.tolist(), sim.bonds.gid_j.tolist()))
    assert ends == [(0, 1), (1, 2), (4, 5), (5, 6)]
    assert np.array_equal(sim.elements.gid[sim.bonds.i], sim.bonds.gid_i)     # relinked rows
    assert np.array_equal(sim.elements.gid[sim.bonds.j], sim.bonds.gid_j)
    sim.run(5)


def test_insert_operation_fills_to_a_volume_fraction_and_delete_removes_leavers(comm):
    x, r = _bed(60)
    sim = _sim(comm, x, r)
    region = R.Cylinder([0.01, 0.01, 0.02], 0.008, 0.015)
    ins = Insert(region, D.LogNormal(RAD, 0.1), trigger=50, volume_fraction=0.15, seed=5)
    sim.run(50, operations=[ins])
    xs, rs = sim.particles.positions, sim.particles.radii
    inside = region.contains(xs)
    phi = np.sum(4 / 3 * np.pi * rs[inside] ** 3) / region.volume
    v_last = 4 / 3 * np.pi * (RAD * np.exp(0.3)) ** 3 / region.volume
    assert ins.missing == 0 and 0.15 <= phi < 0.15 + v_last
    assert ins.inserted == sim.particles.n - 60 and np.array_equal(ins.last, np.arange(60, sim.particles.n))
    # the same seed at the same step: the same particles (no state in the object but its counters)
    again = _sim(comm, x, r)
    ins2 = Insert(region, D.LogNormal(RAD, 0.1), trigger=50, volume_fraction=0.15, seed=5)
    again.run(50, operations=[ins2])
    assert np.array_equal(again.particles.positions, xs)
    # delete: everything above z = 0.025 at the next call
    dele = Delete(trigger=1, outside=R.Box([-1, -1, -1], [1, 1, 0.025]))
    sim.run(1, operations=[dele])
    assert dele.deleted > 0 and np.all(sim.particles.positions[:, 2] <= 0.025)
    assert len(dele.last) == dele.deleted
    with pytest.raises(ValueError, match="either n"):
        Insert(region, RAD, trigger=1)
    with pytest.raises(ValueError, match="either inside"):
        Delete(trigger=1)


def test_checkpoint_after_insertion_restarts_bit_for_bit(comm, tmp_path):
    x, r = _bed(60)
    region = R.Cylinder([0.01, 0.01, 0.02], 0.008, 0.01)
    dist = D.Uniform(0.8 * RAD, 1.2 * RAD)
    sim = _sim(comm, x, r)
    sim.particles.add_property("tag", default=1.0)
    pour = Insert(region, dist, trigger=100, n=20, seed=2)
    sim.run(300, operations=[pour])
    path = str(tmp_path / "poured.h5")
    pardem.save(sim, path)
    sim.run(300, operations=[pour])       # the same object goes on; the restart makes a new one
    back = pardem.load(comm, path)
    # the restored forces hold gravity already: appended, not add_fixes (which applies a fix
    # added after a run to the current forces, so gravity twice in the first half kick)
    back.fixes.append(pardem.Gravity((0.0, 0.0, -9.81)))
    assert back.particles.n == 120 and back.n_elements == 120
    back.run(300, operations=[Insert(region, dist, trigger=100, n=20, seed=2)])
    assert sim.particles.n == back.particles.n > 160      # up to 3 batches of 20 (a few may find no room)
    for k in ("positions", "velocities", "angular_velocities", "forces", "gids", "radii", "tag"):
        assert np.array_equal(sim.particles.get(k), back.particles.get(k)), k


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_one_and_two_ranks_insert_and_delete_the_same_particles(tmp_path):
    runs = {}
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        out.mkdir()
        cmd = [sys.executable, os.path.join(ROOT, "tests", "mpi", "insertion_run.py"), str(out)]
        if ranks > 1:
            cmd = [MPIEXEC, "-n", str(ranks)] + cmd
        env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, cwd=ROOT, env=env)
        assert res.returncode == 0, res.stdout + res.stderr
        runs[ranks] = dict(np.load(out / "insertion.npz"))
    one, two = runs[1], runs[2]
    assert int(two["ranks"]) == 2 and int(two["owners"]) == 2      # both ranks owned grains
    assert int(one["inserted"]) > 0 and int(one["deleted"]) > 0
    for k in one:
        if k not in ("ranks", "owners"):
            assert np.array_equal(one[k], two[k]), k
    # the restart on each rank count continued as the uninterrupted run
    for run in (one, two):
        for k in ("positions", "velocities", "gids", "tag"):
            assert np.array_equal(run[k], run["restarted_" + k]), k
