"""The contact network writer (pardem.io.contact_writer.ContactWriter).

Independent checks: the written pair forces, added to grain i and subtracted from grain j (Newton's
third law), give each grain's contact force ``elements.f`` (no other load: no walls, no damping,
an undamped law), and the tangential forces with the arms ``R - delta/2`` give ``elements.t``; the
normal force is along the branch vector and the tangential one across it; the number of pairs is
the loop's own count of touching pairs and a brute-force count over all grains (minimum image);
1 and 2 ranks write the same pairs with the same forces (tests/mpi/contact_writer_run.py).
"""
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

import pardem
from pardem.io.contact_writer import ContactWriter, group_name

HERE = os.path.dirname(__file__)
sys.path.insert(0, os.path.join(HERE, "mpi"))
from contact_writer_run import EVERY, STEPS, system  # noqa: E402

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")


def read(path, step):
    with h5py.File(path, "r") as fh:
        g = fh[group_name(step)]
        out = {k: g[k][()] for k in g}
        out.update(dict(g.attrs))
    return out


def test_written_network_gives_the_grains_contact_forces(tmp_path):
    sim = pardem.build(pardem.Communicator(), system())
    n = sim.n_elements
    path = tmp_path / "out" / "contacts.h5"
    seen = {}

    class Keep:   # the grains' loads and the loop's count at the writer's steps
        trigger = EVERY

        def __call__(self, s):
            e = s.elements
            order = np.argsort(e.gid[:e.n_owned])
            seen[s.step_count] = (e.f[order].copy(), e.t[order].copy(), e.x[order].copy(),
                                  e.radius[order].copy(), s.contacts.n_touching)

    writer = ContactWriter(path, trigger=EVERY)
    sim.run(STEPS, operations=[writer, Keep()])
    assert writer.steps == [EVERY, 2 * EVERY] == sorted(seen)
    sliding_seen = sticking_seen = 0
    for step, (f, t, x, radius, n_touching) in seen.items():
        data = read(path, step)
        assert data["step"] == step and data["time"] == pytest.approx(step * sim.dt, rel=1e-12)
        assert data["law"] == "hertz_mindlin"
        gid = data["gid"]
        m = len(gid)
        # each pair once, lower gid first, sorted
        keys = gid[:, 0] * n + gid[:, 1]
        assert np.all(gid[:, 0] < gid[:, 1]) and np.all(np.diff(keys) > 0)
        # the count: the loop's own, and a brute force over all pairs (minimum image)
        assert m == n_touching
        box = sim.cell.length
        i, j = np.triu_indices(n, 1)
        dx = x[j] - x[i]
        dx -= box * np.round(dx / box)
        touching = np.linalg.norm(dx, axis=1) < radius[i] + radius[j]
        np.testing.assert_array_equal(np.sort(i[touching] * n + j[touching]), keys)
        assert m > 100
        # the branch vector and overlap of the pair
        np.testing.assert_allclose(data["branch"], dx[touching][np.argsort(i[touching] * n + j[touching])],
                                   rtol=0, atol=1e-15)
        np.testing.assert_allclose(data["overlap"], radius[gid[:, 0]] + radius[gid[:, 1]]
                                   - np.linalg.norm(data["branch"], axis=1), rtol=0, atol=1e-16)
        assert np.all(data["overlap"] > 0.0)
        # directions: normal force along -n (repulsive), tangential across n
        d = data["branch"]
        nrm = d / np.linalg.norm(d, axis=1)[:, None]
        fn = -np.sum(data["normal_force"] * nrm, axis=1)
        assert np.all(fn > 0.0)
        np.testing.assert_allclose(np.cross(data["normal_force"], nrm), 0.0, atol=1e-14 * fn.max())
        ft = data["tangential_force"]
        np.testing.assert_allclose(np.sum(ft * nrm, axis=1), 0.0, atol=1e-14 * fn.max())
        # per grain: forces and torques (arms R - delta/2 along +n for i, -n for j)
        scale = np.abs(f).max()
        g_f = np.zeros((n, 3))
        np.add.at(g_f, gid[:, 0], data["normal_force"] + ft)
        np.add.at(g_f, gid[:, 1], -(data["normal_force"] + ft))
        np.testing.assert_allclose(g_f, f, rtol=0, atol=1e-13 * scale)   # ~10 terms' round-off
        c = np.cross(nrm, ft)
        g_t = np.zeros((n, 3))
        np.add.at(g_t, gid[:, 0], (radius[gid[:, 0]] - 0.5 * data["overlap"])[:, None] * c)
        np.add.at(g_t, gid[:, 1], (radius[gid[:, 1]] - 0.5 * data["overlap"])[:, None] * c)
        np.testing.assert_allclose(g_t, t, rtol=0, atol=1e-13 * scale * 1e-3)   # arms ~1e-3 m
        # sliding: on the Coulomb cap mu fn, the others below it
        slide = data["sliding"].astype(bool)
        ratio = np.linalg.norm(ft, axis=1) / (0.3 * fn)
        np.testing.assert_allclose(ratio[slide], 1.0, rtol=1e-12)
        assert np.all(ratio[~slide] < 1.0 - 1e-9)
        sliding_seen += slide.sum()
        sticking_seen += (~slide).sum()
    assert sliding_seen > 10 and sticking_seen > 10


def test_never_overwrites_unasked(tmp_path):
    path = tmp_path / "contacts.h5"
    path.write_bytes(b"user data")
    sim = pardem.build(pardem.Communicator(), system())
    with pytest.raises(FileExistsError, match="refusing"):
        sim.run(1, operations=[ContactWriter(path, trigger=1)])
    assert path.read_bytes() == b"user data"
    sim.run(1, operations=[ContactWriter(path, trigger=1, mode="overwrite")])
    sim.run(1, operations=[ContactWriter(path, trigger=1, mode="append")])
    with h5py.File(path, "r") as fh:
        assert sorted(fh) == [group_name(2), group_name(3)]
    with pytest.raises(FileExistsError, match="already holds"):   # the same step twice
        ContactWriter(path, trigger=1, mode="append")(sim)
    for bad in (0, -1, 2.5, True, "10"):
        with pytest.raises(ValueError, match="trigger"):
            ContactWriter(path, trigger=bad)
    with pytest.raises(ValueError, match="mode"):
        ContactWriter(path, mode="replace")


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_one_and_two_ranks_write_the_same_network(tmp_path):
    out = {}
    for ranks in (1, 2):
        d = tmp_path / f"n{ranks}"
        d.mkdir()
        p = subprocess.run([MPIEXEC, "-n", str(ranks), sys.executable,
                            os.path.join(HERE, "mpi", "contact_writer_run.py"), str(d)],
                           capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stderr
        out[ranks] = d
    n = 6 * 4 * 4
    for step in (EVERY, STEPS):
        a, b = read(out[1] / "contacts.h5", step), read(out[2] / "contacts.h5", step)
        np.testing.assert_array_equal(a["gid"], b["gid"])
        assert len(a["gid"]) > 100
        # reproducible contacts: the same bits on 1 and 2 ranks (pardem.engine.contacts)
        for k in ("branch", "normal_force", "tangential_force", "overlap", "sliding"):
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    # on 2 ranks too the written network gives every grain its contact force
    states = [np.load(out[2] / f"state-r{r:04d}.npz") for r in range(2)]
    gid = np.concatenate([s["gid"] for s in states])
    assert sorted(gid) == list(range(n))
    f = np.zeros((n, 3))
    f[gid] = np.concatenate([s["f"] for s in states])
    # ParaView: the contact lines are the same on 1 and 2 ranks; the owned points' coordination
    # of the two pieces is the number of pairs of each grain in the written network
    import meshio
    from test_paraview import read_point_data
    a, b = (meshio.read(out[k] / "pv" / f"contacts-{STEPS:08d}.vtu") for k in (1, 2))
    np.testing.assert_array_equal(a.points, b.points)
    for k in a.cell_data:
        np.testing.assert_array_equal(a.cell_data[k][0], b.cell_data[k][0], err_msg=k)
    net = read(out[2] / "contacts.h5", STEPS)["gid"]
    z = np.bincount(net.ravel(), minlength=n)
    seen = np.zeros(n, dtype=int)
    for r in range(2):
        _, pd = read_point_data(out[2] / "pv" / f"snapshot-{STEPS:08d}-r{r:04d}.vtu")
        owned = pd["vtkGhostType"] == 0
        np.testing.assert_array_equal(pd["coordination"][owned], z[pd["gid"][owned]])
        seen[pd["gid"][owned]] += 1
    assert np.all(seen == 1)
    data = read(out[2] / "contacts.h5", STEPS)
    F = data["normal_force"] + data["tangential_force"]
    g_f = np.zeros((n, 3))
    np.add.at(g_f, data["gid"][:, 0], F)
    np.add.at(g_f, data["gid"][:, 1], -F)
    np.testing.assert_allclose(g_f, f, rtol=0, atol=1e-13 * np.abs(f).max())


@pytest.mark.parametrize("rate", [(0.0, 0.0, 0.0), (-200.0, 100.0, 0.0)])
def test_damped_law_written_parts_sum_to_the_applied_force(tmp_path, rate):
    """A damped linear law at step 0 (``run(0)``: the forces of the current velocities, no half
    step between): elastic plus dashpot parts, added to i and subtracted from j, are each grain's
    force; with a deforming cell the dashpots see the affine motion across the boundary."""
    import dataclasses
    base = system()
    s = dataclasses.replace(base, contacts=pardem.ContactModel(
        "linear", {"kn": 2e4, "kt": 1.5e4, "friction": 0.3, "restitution": 0.4}),
        cell=dataclasses.replace(base.cell, rate=rate))
    sim = pardem.build(pardem.Communicator(), s)
    path = tmp_path / "contacts.h5"
    sim.run(0, operations=[ContactWriter(path, trigger=pardem.triggers.Never(), at_end=True)])
    e = sim.elements
    n = e.n_owned
    f = np.zeros((n, 3))
    f[e.gid[:n]] = e.f[:n]
    data = read(path, 0)
    dn, dt = data["normal_damping"], data["tangential_damping"]
    d = data["branch"]
    nrm = d / np.linalg.norm(d, axis=1)[:, None]
    # the shares' directions: normal along n, tangential across it; both present
    np.testing.assert_allclose(np.cross(dn, nrm), 0.0, atol=1e-14 * np.abs(f).max())
    np.testing.assert_allclose(np.sum(dt * nrm, axis=1), 0.0, atol=1e-14 * np.abs(f).max())
    assert np.abs(dn).max() > 1e-3 * np.abs(data["normal_force"]).max()
    assert np.abs(dt).max() > 0.0
    F = data["normal_force"] + data["tangential_force"] + dn + dt
    g_f = np.zeros((n, 3))
    np.add.at(g_f, data["gid"][:, 0], F)
    np.add.at(g_f, data["gid"][:, 1], -F)
    # ~10 pairs a grain, each a few terms' round-off of the largest force
    np.testing.assert_allclose(g_f, f, rtol=0, atol=1e-13 * np.abs(f).max())
