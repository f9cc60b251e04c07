"""Simple shear in the periodic cell (tilted cell, Lees-Edwards images): the neighbour list across
a tilted boundary against brute force over all images, the cell's affine map and flips, the affine
relative motion of the contact kernels across the boundary, stress symmetry, restarts bit for bit
(1 against 2 ranks: tests/mpi/simple_shear_ranks.py)."""
import itertools

import numpy as np
import pytest

from pardem.engine.periodic_cell import PeriodicCell
from pardem.physics.neighbours import build_pairs


def edges(L, tilt):
    return np.array([[L[0], tilt[0], tilt[1]], [0.0, L[1], tilt[2]], [0.0, 0.0, L[2]]])


def brute_pairs(x, radius, gid, n_owned, skin, L, tilt, periodic):
    """Every (gid_i, gid_j, image) within reach: for each pair, the images n0 + m of j, n0 the
    rounded fractional offset and m in -2..2 per periodic axis (an independent O(N^2) search: no
    cells, no wrap, the image vector H n for each n)."""
    H = edges(L, tilt)
    per = np.asarray(periodic)
    Hinv = np.linalg.inv(np.where(np.eye(3, dtype=bool) & ~per[None, :], 1.0, H))
    rng = [range(-2, 3) if p else range(0, 1) for p in periodic]
    around = np.array(list(itertools.product(*rng)), dtype=np.int64)
    out = set()
    n = len(x)
    for i in range(n):
        for j in range(n):
            if gid[i] >= gid[j] or (i >= n_owned and j >= n_owned):
                continue
            d0 = x[j] - x[i]
            base = np.where(per, -np.round(Hinv @ d0), 0.0).astype(np.int64)
            images = base[None, :] + around
            d = d0[None, :] + images @ H.T
            reach = radius[i] + radius[j] + skin
            hit = np.nonzero(np.einsum("ij,ij->i", d, d) < reach * reach)[0]
            assert len(hit) <= 1, "two images in reach: the cell is too small for the test"
            for h in hit:
                out.add((int(gid[i]), int(gid[j]), tuple(int(v) for v in images[h])))
    return out


def listed(pairs, shifts, gid):
    return {(int(gid[a]), int(gid[b]), tuple(int(v) for v in s)) for (a, b), s in zip(pairs, shifts)}


@pytest.mark.parametrize("tilt", [(0.3, 0.0, 0.0), (-0.5, 0.0, 0.0), (0.41, -0.27, 0.33), (0.5, 0.5, -0.5)])
@pytest.mark.parametrize("owned_fraction", [1.0, 0.6])
def test_tilted_list_matches_brute_force(tilt, owned_fraction):
    rng = np.random.default_rng(7)
    L = np.array([1.0, 1.1, 0.9])
    t = np.array(tilt) * np.array([L[0], L[0], L[1]])       # fractions of the edge they shift
    n = 260
    s = rng.uniform(0.0, 1.0, (n, 3))
    x = (s @ edges(L, t).T) + 0.3                              # inside the tilted cell at lo = 0.3
    x += rng.integers(-2, 3, (n, 3)) @ edges(L, t).T           # and unwrapped by a few periods
    radius = rng.uniform(0.03, 0.06, n)
    gid = rng.permutation(n).astype(np.int64) * 3 + 1
    skin = 0.02
    n_owned = int(owned_fraction * n)
    periodic = (True, True, True)
    pairs, shifts = build_pairs(x, radius, gid, n_owned, n, skin, box_lo=np.full(3, 0.3),
                                box_hi=0.3 + L, periodic=periodic, tilt=t)
    want = brute_pairs(x, radius, gid, n_owned, skin, L, t, periodic)
    got = listed(pairs, shifts, gid)
    assert len(got) == len(pairs)          # each pair once
    assert got == want
    assert len(want) > 150                 # the case has pairs, many across the tilted y faces
    row = {int(g): k for k, g in enumerate(gid)}
    assert sum(1 for a, b, _ in want if abs(s[row[a], 1] - s[row[b], 1]) > 0.5) >= 3


def test_tilted_list_with_a_non_periodic_axis():
    """xy shear between planes normal to z (z not periodic): the tilt couples x and y only."""
    rng = np.random.default_rng(3)
    t = np.array([-0.37, 0.0, 0.0])
    n = 200
    x = rng.uniform(0.0, 1.0, (n, 3))
    x[:, 0] += t[0] * x[:, 1]
    x[:, 2] *= 0.7
    radius = rng.uniform(0.03, 0.06, n)
    gid = np.arange(n, dtype=np.int64)
    periodic = (True, True, False)
    pairs, shifts = build_pairs(x, radius, gid, n, n, 0.02, box_lo=np.zeros(3), box_hi=np.ones(3),
                                periodic=periodic, tilt=t)
    assert listed(pairs, shifts, gid) == brute_pairs(x, radius, gid, n, 0.02, [1.0, 1.0, 1.0], t, periodic)


def test_tilted_list_refuses_a_cell_thinner_than_twice_the_reach():
    # a tilt of half the edge shrinks the distance between the faces normal to y... of x: the
    # x faces are 1 / sqrt(1 + 0.5^2) = 0.894 apart; a reach of 0.46 needs 0.92
    x = np.array([[0.1, 0.1, 0.1], [0.5, 0.5, 0.5]])
    r = np.full(2, 0.2)
    build_pairs(x, r, np.arange(2), 2, 2, 0.04, box_lo=np.zeros(3), box_hi=np.ones(3),
                periodic=(True,) * 3)
    with pytest.raises(ValueError, match="axis x"):
        build_pairs(x, r, np.arange(2), 2, 2, 0.06, box_lo=np.zeros(3), box_hi=np.ones(3),
                    periodic=(True,) * 3, tilt=(0.5, 0.0, 0.0))


# -- the engine: a simple cubic lattice sheared affinely ------------------------------------------

import pardem  # noqa: E402
from pardem.physics.contact_frame import pair_geometry  # noqa: E402

R = 1e-3
A = 2.0 * R * (1.0 - 0.01)        # lattice spacing: every neighbour overlaps by 1 % of a diameter
KN = 1e5


def lattice(m=4, friction=1.0, shear_rate=(0.0, 0.0, 0.0), dt=1e-6, velocities=None, density=2500.0):
    g = (np.arange(m) + 0.5) * A
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    system = pardem.System(
        pardem.Particles(x, R, density, velocities=velocities),
        contacts=pardem.ContactModel("linear", {"kn": KN, "kt": 0.5 * KN, "friction": friction}),
        cell=pardem.Cell((0.0, 0.0, 0.0), (m * A,) * 3, (True, True, True), shear_rate=shear_rate),
        integration=pardem.Integration(dt=dt),
        decomposition=pardem.Decomposition(skin=0.1 * R))
    return pardem.build(pardem.Communicator(), system), x


def contacts_by_axis(sim):
    """The branch vectors [n, 3] and histories [n, 3] of the touching pairs, with the axis of each
    (0, 1, 2: the lattice direction of its branch vector)."""
    c, e = sim.contacts, sim.elements
    d, _, _, delta = pair_geometry(c.i, c.j, c.shift, e.x, e.radius)
    touching = delta > 0.0
    d, h = d[touching], c.history[touching, :3]
    return d, h, np.argmax(np.abs(d) / np.linalg.norm(d, axis=1)[:, None] > 0.7, axis=1), delta[touching]


def test_affine_shear_of_a_lattice_has_no_peculiar_motion_and_the_analytic_tangential_force():
    """Every grain of a simple cubic lattice, at rest in the cell's frame, stays so under simple
    shear xy (each is a translate of every other, across the periodic faces too): the contacts
    along x and z see no affine motion (d_y = 0), those along y, a quarter of them across the y
    faces where the image moves with the tilt, all the same sliding ``g a`` [m/s]: after a strain
    gamma their tangential force is ``kt a gamma`` (to O(gamma): the normal turns by gamma) and the
    shear stress ``sigma_yx = gamma (kt a - fn) / a^2`` (one y contact per grain, V = a^3). The
    tangential forces turn every grain alike (the vorticity); a density of 2.5e7 kg/m^3 keeps that
    spin's share of the sliding below 1e-3 of ``g a`` over the run (torque 2 R kt a gamma on
    I = 0.4 m R^2)."""
    g, dt, steps = 2000.0, 1e-8, 250          # gamma = 0.005
    sim, _ = lattice(shear_rate=(g, 0.0, 0.0), dt=dt, density=2.5e7)
    sim.run(steps)
    gamma = g * dt * steps
    assert sim.cell.shear_strain[0] == pytest.approx(gamma, rel=1e-12)
    assert sim.cell.tilt[0] == pytest.approx(gamma * sim.cell.length[1], rel=1e-12)
    # no peculiar velocity: the net force on every grain cancels to rounding (forces ~ kn 0.02 R =
    # 2 N, rounding 1e-16 of it per step, against the affine scale g a = 4 m/s)
    v = sim.particles.velocities
    assert np.abs(v).max() < 1e-9 * g * A
    w = sim.particles.angular_velocities
    assert np.abs(w - w[0]).max() <= 1e-9 * np.abs(w[0]).max()      # every grain turns alike
    d, h, axis, delta = contacts_by_axis(sim)
    assert np.bincount(axis, minlength=3).tolist() == [64, 64, 64]
    # x and z contacts: the same overlap (no affine motion along them), one tangential force each
    # (from the common spin only)
    assert np.allclose(delta[axis != 1], 0.02 * R, rtol=1e-9)
    # (a pair is oriented by gid: across a face its i end is the upper one, its force the opposite)
    h = h * np.sign(d[np.arange(len(d)), axis])[:, None]
    for a in (0, 2):
        ha = h[axis == a]
        assert np.abs(ha - ha[0]).max() <= 1e-9 * np.abs(h).max()
    # y contacts, inside the cell and across its y faces alike: the same history to rounding
    hy = h[axis == 1]
    across = d[axis == 1, 1] < 0.0
    assert across.sum() == 16                 # the i end above: the pairs across the y faces
    assert np.abs(hy - hy[0]).max() < 1e-9 * np.abs(hy[0]).max()
    assert np.abs(h[axis != 1]).max() < 1e-2 * np.abs(hy[0]).max()
    kt = 0.5 * KN
    # |h| = kt a gamma to O(gamma) (the normal turns by gamma) and 1 / steps (the step-0 state's
    # force evaluation increments the spring too): tolerance 2 gamma + 1 / steps
    tol = 2 * gamma + 1.0 / steps
    assert np.linalg.norm(hy[0]) == pytest.approx(kt * A * gamma, rel=tol)
    assert hy[0][0] > 0.0                     # on the lower grain, along +x (the upper one moves +x)
    sigma = sim.global_stress()
    # one y contact per grain of volume a^3, its force on the lower grain (kt a gamma - fn gamma, 0)
    # to O(gamma) (the normal force turned with the branch vector, fn = kn 0.02 R)
    fn = KN * 0.02 * R
    assert sigma[1, 0] == pytest.approx(gamma * (kt * A - fn) / A ** 2, rel=tol)


def test_a_frictionless_lattice_sheared_through_flips_stays_affine():
    """Frictionless, the lattice stays a translate of itself through strain 1.2 (a flip of the
    tilt, list rebuilds and wraps), also while it drifts through the y faces at a uniform
    peculiar velocity (Galilean invariance: every grain crosses a face, wrapped with the tilt's x
    shift): no other peculiar velocity, positions relative to grain 0 the affine map of the start
    modulo the cell's lattice, the x and z contacts as they were."""
    g, dt, steps, vy = 4000.0, 1e-6, 300, 10.0      # gamma = 1.2, drift 3 mm = 1.5 spacings along y
    v0 = np.zeros((64, 3))
    v0[:, 1] = vy
    sim, x0 = lattice(friction=0.0, shear_rate=(g, 0.0, 0.0), dt=dt, velocities=v0)
    sim.run(steps)
    gamma = g * dt * steps
    cell = sim.cell
    assert cell.flips == 1
    assert cell.tilt[0] == pytest.approx(gamma * cell.length[1] - cell.length[0], rel=1e-9)
    assert abs(cell.tilt[0]) <= 0.5 * cell.length[0]
    assert np.abs(sim.particles.velocities - v0).max() < 1e-9 * g * A
    x = sim.particles.positions
    assert x[:, 1].min() < x0[:, 1].min()      # all drift up: the lowest were wrapped across the y faces
    rel0 = x0 - x0[0]
    affine = rel0.copy()
    affine[:, 0] += gamma * rel0[:, 1]
    frac = np.linalg.solve(cell.edges, ((x - x[0]) - affine).T).T
    assert np.abs(frac - np.round(frac)).max() < 1e-9
    _, h, axis, delta = contacts_by_axis(sim)
    assert np.abs(h).max() == 0.0            # frictionless: no tangential history
    xz = axis != 1
    assert xz.sum() == 128 and np.allclose(delta[xz], 0.02 * R, rtol=1e-9)


def test_stress_is_symmetric_without_torques_in_a_tilted_flowing_packing():
    """Frictionless grains (no contact torque) flowing in simple shear through flips: the
    Love-Weber stress, with the tilted branch vectors, is symmetric to rounding."""
    import _shear_case as sc
    sim = pardem.build(pardem.Communicator(), sc.system(friction=0.0))
    for _ in range(3):
        sim.run(300)
        s = sim.global_stress()
        assert abs(s[0, 1] - s[1, 0]) < 1e-12 * np.abs(s).max()
        assert abs(s[0, 1]) > 1e-3 * np.abs(s).max()     # a shear stress, not a zero
    assert sim.cell.flips >= 2


def test_restart_of_a_sheared_cell_is_bit_for_bit(tmp_path):
    import _shear_case as sc
    comm = pardem.Communicator()
    ref = pardem.build(comm, sc.system())
    ref.run(700)
    sim = pardem.build(comm, sc.system())
    sim.run(450)
    assert sim.cell.flips >= 1 and abs(sim.cell.tilt[0]) > 0.0
    pardem.save(sim, str(tmp_path / "s.h5"))
    back = pardem.load(comm, str(tmp_path / "s.h5"))
    assert back.cell.tilt.tolist() == sim.cell.tilt.tolist()
    assert back.cell.shear_rate.tolist() == [2000.0, 0.0, 0.0]
    back.run(250)
    a, b = sc.state(ref), sc.state(back)
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    assert back.cell.flips == ref.cell.flips


def test_shear_description_round_trips_and_bad_input():
    import _shear_case as sc
    from pardem.engine.system import System
    s = sc.system(shear_rate=(100.0, 0.0, 0.0))
    assert System.from_dict(s.to_dict()).cell.shear_rate == [100.0, 0.0, 0.0] or \
        tuple(System.from_dict(s.to_dict()).cell.shear_rate) == (100.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="periodic along x and y"):
        PeriodicCell((0, 0, 0), (1, 1, 1), (True, False, True), shear_rate=(1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="shear_rate"):
        PeriodicCell((0, 0, 0), (1, 1, 1), (True,) * 3, shear_rate=(1.0, float("nan"), 0.0))
    with pytest.raises(ValueError, match="half"):
        PeriodicCell((0, 0, 0), (1, 1, 1), (True,) * 3, tilt=(0.6, 0.0, 0.0))
    # one process: the description's slab axis (a restart on more ranks cuts along it) is one the
    # shear does not move, although x is the longest extent here
    x, r, side = sc.packing(n=60)
    x[:, 0] *= 1.5
    sim = pardem.build(pardem.Communicator(), pardem.System(
        pardem.Particles(x, r, 2500.0, allow_overlaps=True),
        contacts=pardem.ContactModel("linear", {"kn": 1e5, "kt": 1e5}),
        cell=pardem.Cell((0, 0, 0), (1.5 * side, side, side), (True,) * 3, shear_rate=(1.0, 0.0, 0.0))))
    assert sim.system.decomposition.slab_axis in (1, 2)
    with pytest.raises(ValueError, match="slab_axis = 0"):
        from pardem.engine.system import _slab_axis
        _slab_axis(0, np.zeros((2, 3)), np.ones(2), 3,
                   PeriodicCell((0, 0, 0), (1, 1, 1), (True,) * 3, shear_rate=(1.0, 0.0, 0.0)))


@pytest.mark.mpi
def test_one_and_two_ranks_give_the_same_bits(tmp_path):
    """The sheared packing through flips on 1 and 2 ranks (slabs along y or z, never x: the xy
    shear moves x with y; the ghosts across the y faces carry their raw positions, the list finds
    their tilted image): the same bits (reproducible lists and exact sums)."""
    import os
    import shutil
    import subprocess
    import sys
    mpiexec = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
    if mpiexec is None:
        pytest.skip("no mpiexec")
    script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "mpi", "simple_shear_ranks.py")
    got = {}
    for n in (1, 2):
        path = tmp_path / f"r{n}.npz"
        p = subprocess.run([mpiexec, "-n", str(n), sys.executable, script, str(path)],
                           capture_output=True, text=True, timeout=1200)
        assert p.returncode == 0, p.stderr[-3000:]
        got[n] = dict(np.load(path))
    assert int(got[2]["axis"]) in (1, 2) and int(got[2]["flips"]) >= 2
    for k in got[1]:
        if k != "axis":
            assert np.array_equal(got[1][k], got[2][k]), k


def test_normal_servo_moves_its_axis_only():
    """``g_a = gain (-sigma_aa - p0)`` capped at ``max_rate``: the cell opens along y when the
    packing presses harder than p0, closes when it presses less; x and z keep their edges."""
    servo = PeriodicCell.normal_servo(axis=1, pressure=1e5, gain=1e-4, max_rate=5.0)
    cell = PeriodicCell((0, 0, 0), (1, 1, 1), (True,) * 3, servo=servo, shear_rate=(10.0, 0.0, 0.0))
    cell.control(np.diag([-3e5, -1.2e5, -9e5]))
    assert cell.rate.tolist() == [0.0, pytest.approx(1e-4 * 2e4), 0.0]
    cell.control(np.diag([0.0, -0.2e5, 0.0]))
    assert cell.rate.tolist() == [0.0, -5.0, 0.0]          # 1e-4 * -8e4 = -8, capped
    back = PeriodicCell.from_state(cell.state())
    assert back.servo == servo and back.shear_rate.tolist() == [10.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="normal-stress servo"):
        PeriodicCell((0, 0, 0), (1, 1, 1), (True, False, True), servo=servo)
    with pytest.raises(ValueError, match="axis"):
        PeriodicCell.normal_servo(axis=3, pressure=1e5, gain=1e-4, max_rate=5.0)


def brute_touching(x, r, H):
    """Pairs in contact over all images of the tilted cell (minimum image by fractional rounding,
    then the 27 neighbours of it)."""
    n = len(x)
    i, j = np.triu_indices(n, 1)
    d0 = x[j] - x[i]
    base = -np.round(np.linalg.solve(H, d0.T).T)
    best = np.full(len(i), np.inf)
    for m in itertools.product((-1, 0, 1), repeat=3):
        d = d0 + (base + np.array(m)) @ H.T
        best = np.minimum(best, np.einsum("ij,ij->i", d, d))
    return int(np.count_nonzero(best < (r[i] + r[j]) ** 2))


def test_contacts_stay_complete_through_a_flip():
    """Step by step across the first flip of the tilt (which relabels the images: the list must be
    rebuilt at once), the contacts the kernels see are those of a brute-force search over all
    images of the current cell."""
    import _shear_case as sc
    comm = pardem.Communicator()
    sim = pardem.build(comm, sc.system(n=300))
    sim.run(100)
    _, r, _ = sc.packing(n=300)
    checked = 0
    while sim.cell.flips < 1 or checked < 5:
        sim.run(1)
        if sim.cell.flips >= 1:
            checked += 1
        assert float(sim.contacts.n_touching) == brute_touching(sim.particles.positions, r, sim.cell.edges)
        assert sim.step_count < 400
