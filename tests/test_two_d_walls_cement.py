"""Walls and cemented contacts in the 2D mode (issue 13 items 1 and 5): grains with centres in the
plane z = 0, moving in x, y and turning about z (``pardem.engine.plane``).

Oracles:
* the 3D engine: a 2D run with walls (Hertz, friction, damping, a moving wall dragging the grains)
  or with cemented contacts (formation, tension, rupture, fading) is the 3D run of the same planar
  configuration bit for bit, and that 3D run stays planar by itself (the wall and cement kernels are
  the 3D ones; for grains in the plane their forces lie in the plane and their torques along z);
* analytic restitution: a grain bouncing obliquely on a moving wall leaves it, in the wall's frame,
  at ``e`` times its normal approach speed with its tangential velocity unchanged (frictionless);
* the cement's strength: pulled apart along the line of centres a cement breaks at the first step
  where ``1/2 Sn (delta - delta0)^2 > E_th``, i.e. when its tension reaches
  ``F* = sqrt(2 Sn E_th)`` (``pardem.engine.cement.tensile_strength``);
* the same run on 1 and 2 ranks (slabs along x and along y): equal bits for the grains, the contact
  history and the cement counts; the wall totals to the round-off of their sum;
* the uninterrupted run: a restart (``pardem.save``/``load``, walls included)
  continues bit for bit, cement state and wall history included.
"""
import os
import shutil
import subprocess
import sys

import numpy as np

from pardem import restart
import pytest

import pardem
from pardem.engine import cement, fixes
from pardem.engine.plane import PlaneConstraint, plane_of
from pardem.engine.system import set_contact_params
from pardem.engine.walls import add_walls
from pardem.parallel.communicator import Communicator
from pardem.physics import hertz_mindlin as hm
from _util import granular_case

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
R = 0.1e-3
RHO = 2500.0
HERTZ = {"young": 72e9, "poisson": 0.2, "friction": 0.3, "restitution": 0.8}
FIELDS = ("x", "v", "w", "q", "f", "t")
SKIN = 0.05 * R
DT = 1e-8
# cement springs and thresholds: the largest stretch sqrt(2 (mean + half) / Sn) = 1.2e-6 m stays
# below the skin 5e-6 m (cement.check)
CEMENT = {"cement_normal": 2e4, "cement_tangential": 1.5e4, "cement_fade_time": 2e-7}
E_MEAN, E_HALF = 1e-8, 5e-9
WALL = dict(law="hertz", young=72e9, poisson=0.2, friction=0.4, restitution=0.7)


def lattice(m, rows, seed, speed, jitter=0.005):
    """A jittered triangular lattice of ``m`` x ``rows`` spheres (R +- jitter R), neighbours
    slightly overlapping: centres [n, 3] (z = 0, jittered by +- jitter R per axis), radii [n],
    in-plane velocities (``speed`` [m/s] rms per axis) and spins about z; the lattice spans x in
    [0, m a), y from R, with a = 1.998 R."""
    rng = np.random.default_rng(seed)
    a = 2.0 * R * 0.999
    X, Y = np.meshgrid((np.arange(m) + 0.5) * a, np.arange(rows) * a * np.sqrt(3) / 2 + R, indexing="ij")
    X = X + 0.5 * a * (np.arange(rows)[None, :] % 2)
    n = m * rows
    pos = np.stack([X.ravel(), Y.ravel(), np.zeros(n)], axis=1)
    pos[:, :2] += rng.uniform(-jitter * R, jitter * R, (n, 2))
    radii = R * rng.uniform(1.0 - jitter, 1.0 + jitter, n)
    vel = np.zeros((n, 3))
    vel[:, :2] = rng.normal(0.0, speed, (n, 2))
    spin = np.zeros((n, 3))
    spin[:, 2] = rng.normal(0.0, speed * 1e4, n)
    return pos, radii, vel, spin, m * a


def build(dim, pos, radii, lo, length, periodic, vel=None, spin=None, comm=None, params=HERTZ, **kw):
    """The case in 2D, or its 3D twin: the same x, y cell with z not periodic and its z edge the 2D
    thickness (the mean diameter) centred on the plane."""
    comm = Communicator() if comm is None else comm
    if dim == 2:
        return granular_case(comm, pos, radii, RHO, "hertz_mindlin", params, lo[:2], length[:2], DT, SKIN,
                              periodic=periodic[:2], velocities=vel, angular_velocities=spin, dimension=2, **kw)
    t = 2.0 * float(np.mean(radii))
    return granular_case(comm, pos, radii, RHO, "hertz_mindlin", params, [lo[0], lo[1], -0.5 * t],
                          [length[0], length[1], t], DT, SKIN, periodic=(periodic[0], periodic[1], False),
                          velocities=vel, angular_velocities=spin, **kw)


def by_gid(sim):
    e = sim.elements
    o = np.argsort(e.gid[:e.n_owned])
    return {k: getattr(e, k)[:e.n_owned][o] for k in FIELDS}


def gathered(sim):
    """Every grain's fields by gid on rank 0 (None elsewhere), collective."""
    e = sim.elements
    parts = sim.comm.gather({k: getattr(e, k)[:e.n_owned] for k in FIELDS + ("gid",)})
    if not sim.comm.is_root:
        return None
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    o = np.argsort(cat["gid"])
    return {k: cat[k][o] for k in FIELDS}


def histories(sim):
    """The contact history rows by pair key on rank 0, each pair once (collective)."""
    c, e = sim.contacts, sim.elements
    once = c.counted_once(e.n_owned)
    parts = sim.comm.gather((c.keys[once], c.history[once]))
    if not sim.comm.is_root:
        return None
    keys = np.concatenate([p[0] for p in parts])
    hist = np.concatenate([p[1] for p in parts])
    o = np.argsort(keys)
    return keys[o], hist[o]


# -- walls -----------------------------------------------------------------------------------------

def pressed_packing(dim, comm=None, slab_axis=0, law=WALL):
    """A 2D packing (16 x 8 grains, periodic along x) between a fixed bottom wall (normal +y) and a
    top wall moving down and sideways (pressing and dragging the grains by friction); returns
    ``(case, walls)``."""
    pos, radii, vel, spin, lx = lattice(16, 8, seed=3, speed=0.5)
    bottom, top = 0.01 * R, float(pos[:, 1].max()) + 0.99 * R
    lo, length = np.array([0.0, -R]), np.array([lx, top + 2 * R])
    case = build(dim, pos, radii, lo, length, (True, False), vel, spin, comm=comm, slab_axis=slab_axis)
    walls = add_walls(case.sim, [[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]], [[0.0, bottom, 0.0], [0.0, top, 0.0]],
                      velocities=[[0.0, 0.0, 0.0], [0.3, -0.5, 0.0]], **law)
    return case, walls


def test_2d_walls_are_the_3d_walls_of_the_planar_configuration_bit_for_bit():
    """Hertz walls with friction and damping, the top one pressing and dragging a frictional 2D
    packing (2000 steps): every field, the contact and wall histories and the wall forces of the 2D
    run equal the 3D run's, which stays planar by itself."""
    (two, w2), (three, w3) = pressed_packing(2), pressed_packing(3)
    two.sim.run(2000)
    three.sim.run(2000)
    a, b = by_gid(two.sim), by_gid(three.sim)
    for k in FIELDS:
        assert np.array_equal(a[k], b[k]), k
    e2, e3 = two.sim.elements, three.sim.elements
    o2, o3 = np.argsort(e2.gid[:e2.n_owned]), np.argsort(e3.gid[:e3.n_owned])
    assert np.array_equal(e2.wall_h[:e2.n_owned][o2], e3.wall_h[:e3.n_owned][o3])
    assert np.array_equal(two.sim.contacts.history, three.sim.contacts.history)
    f2, f3 = w2.forces(two.sim.comm), w3.forces(three.sim.comm)
    assert np.array_equal(f2, f3)
    # the walls carry the load (both pushed, the moving one dragged along x) and nothing is out of plane
    assert np.all(w2.normal_forces(two.sim.comm) > 0.0) and f2[1, 0] != 0.0 and np.all(f2[:, 2] == 0.0)
    assert np.count_nonzero(np.any(e2.wall_h[:e2.n_owned] != 0.0, axis=2)) > 10   # sticking wall contacts
    assert np.all(b["x"][:, 2] == 0.0) and np.all(b["f"][:, 2] == 0.0) and np.all(b["t"][:, :2] == 0.0)
    assert np.all(b["v"][:, 2] == 0.0) and np.all(b["w"][:, :2] == 0.0)
    plane = plane_of(two.sim)
    assert plane.off_plane == 0.0 and np.all(plane.removed == 0.0)   # the constraint had nothing to remove


@pytest.mark.parametrize("law, e_target", [("hertz", 0.9), ("hertz", 0.3), ("linear", 0.5)])
def test_2d_grain_bounces_on_a_moving_tilted_wall_with_restitution_e(law, e_target):
    """One grain in the plane hits a wall tilted in the plane (normal at 30 deg) that moves in the
    plane; frictionless: in the wall's frame it leaves at ``-e`` times its normal approach speed,
    its tangential velocity unchanged, no spin. The damping calibrations are exact for the
    no-tension contact of a sphere on a plane (``linear_contact.damping_ratio``,
    ``hertz_damping_coefficient``); velocity Verlet with the dashpot at half-step velocities then
    errs by O(dt / t_c) = 5e-4 at 2000 steps per contact, times a factor of order one (3e-4 at most
    here); 2e-3 allowed."""
    ang = np.radians(30.0)
    n = np.array([np.sin(ang), np.cos(ang), 0.0])
    tau = np.array([np.cos(ang), -np.sin(ang), 0.0])
    wall_v = 0.2 * n + 0.3 * tau
    v_in = -0.8 * n + 0.1 * tau
    approach = float((wall_v - v_in) @ n)
    m = RHO * 4.0 / 3.0 * np.pi * R**3
    params = {"young": 72e9, "poisson": 0.2, "friction": 0.0, "restitution": 1.0}
    if law == "hertz":
        e_star = 1.0 / ((1 - 0.2**2) / 72e9)                     # a rigid wall
        K = 4.0 / 3.0 * e_star * np.sqrt(R)
        t_c = 3.21807 * (m / K) ** 0.4 * approach**-0.2          # elastic Hertz contact time
        wall = dict(law="hertz", young=72e9, poisson=0.2, restitution=e_target)
    else:
        kn = 1e5
        t_c = np.pi / np.sqrt(kn / m)                           # half period of the spring
        wall = dict(law="linear", stiffness=kn, restitution=e_target)
    dt = t_c / 2000
    gap = 50 * approach * dt                                    # touches after 50 steps
    x0 = np.array([[0.0, 0.0, 0.0]])
    wall_point = x0[0] - (R + gap) * n
    sim = granular_case(Communicator(), x0, [R], RHO, "hertz_mindlin", params, [-10 * R, -10 * R],
                        [20 * R, 20 * R], dt=dt, skin=SKIN, periodic=(False, False), dimension=2,
                        velocities=v_in[None, :]).sim
    walls = add_walls(sim, [n], [wall_point], velocities=[wall_v], **wall)
    sim.run(int(2000 * 1.3) + 200)     # the contact lasts ~2000 steps (less when damped)
    e = sim.elements
    assert e.radius[0] < float(n @ e.x[0]) - walls.offsets[0]   # it left the wall
    v_out = e.v[0]
    measured = float((v_out - wall_v) @ n) / approach
    print(f"\n{law} e = {e_target}: measured {measured:.6f} ({measured / e_target - 1:+.1e})")
    assert measured == pytest.approx(e_target, rel=2e-3)
    # frictionless: the tangential velocity is untouched; nothing out of the plane, no spin
    assert float(v_out @ tau) == pytest.approx(float(v_in @ tau), rel=1e-13)
    assert v_out[2] == 0.0 and e.x[0, 2] == 0.0 and np.all(e.w[0] == 0.0)


def _pressed_run(comm, steps, axis):
    case, walls = pressed_packing(2, comm=comm, slab_axis=axis)
    case.sim.run(steps)
    state = gathered(case.sim)
    f, fn = walls.forces(case.sim.comm), walls.normal_forces(case.sim.comm)
    if state is None:
        return None
    return {**state, "wall_forces": f, "normal_forces": fn}


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
@pytest.mark.parametrize("axis", [0, 1])
def test_walls_pressing_a_2d_packing_on_1_and_2_ranks(tmp_path, axis):
    """The pressed packing on 1 rank and on 2 ranks (slabs along x: both ranks touch both walls;
    along y: each rank holds one wall's grains): the grains' fields are the same bits (each
    element's wall load depends on that element only; the contacts are reproducible). The wall
    totals are float sums over the rows, then the ranks, of the same n <= 128 terms F_k in another
    order: each within (n - 1) eps/2 sum|F_k| of the exact sum, so they differ by at most
    n eps sum|F_k|, and sum|F_k| <= sqrt(1 + mu^2) sum fn_k = sqrt(1 + mu^2) (-F . n) (no tension,
    Coulomb cap |ft| <= mu fn)."""
    one = _pressed_run(Communicator(), 1500, axis)
    out = tmp_path / "two.npz"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, os.path.abspath(__file__), "walls", str(out), "1500",
                        str(axis)], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    two = dict(np.load(out))
    for k in FIELDS:
        assert np.array_equal(one[k], two[k]), k
    f1, f2, fn = one["wall_forces"], two["wall_forces"], one["normal_forces"]
    assert np.all(fn > 0.0)
    n_terms = len(one["x"])
    bound = n_terms * np.finfo(float).eps * np.sqrt(1.0 + WALL["friction"] ** 2) * fn * (1 + 1e-6)
    assert np.all(np.abs(f1 - f2) <= bound[:, None])


def test_walls_out_of_the_plane_or_across_a_periodic_axis_are_refused():
    pos, radii, vel, spin, lx = lattice(4, 3, seed=1, speed=0.0)
    lo, length = np.array([0.0, -R]), np.array([lx, 8 * R])
    case = build(2, pos, radii, lo, length, (True, False))
    with pytest.raises(ValueError, match=r"normals\[1\].*plane z = 0"):
        add_walls(case.sim, [[0, 1, 0], [0, 1, 1]], [[0, 0, 0], [0, 0, 0]], stiffness=1e3)
    with pytest.raises(ValueError, match=r"velocities\[0\].*plane z = 0"):
        add_walls(case.sim, [[0, 1, 0]], [[0, 0, 0]], velocities=[0.0, 0.0, 1.0], stiffness=1e3)
    with pytest.raises(ValueError, match=r"normals\[0\].*periodic axes \(x\)"):
        add_walls(case.sim, [[1, 0, 0]], [[0, 0, 0]], stiffness=1e3)
    with pytest.raises(ValueError, match=r"periodic axes"):
        add_walls(case.sim, [[1, 1, 0]], [[0, 0, 0]], stiffness=1e3)
    assert case.sim.plates is None
    # a 3D cell periodic along x, y, z takes no wall either
    three = build(3, pos, radii, lo, length, (True, True))
    with pytest.raises(ValueError, match=r"periodic axes \(xy\)"):
        add_walls(three.sim, [[0, 1, 0]], [[0, 0, 0]], stiffness=1e3)
    add_walls(case.sim, [[0, 1, 0]], [[0, 0, 0]], stiffness=1e3)     # in-plane, across the open axis


@pytest.mark.parametrize("writer", ["api", "granular"])
def test_restart_with_walls_in_2d_continues_bit_for_bit(tmp_path, writer):
    """``pardem.save``/``load`` and ``restart.save``/``load_case`` of the pressed 2D packing (wall
    friction history, the moving wall's clock, the plane constraint): 700 + 700 steps equal the
    uninterrupted 1400."""
    ref, wr = pressed_packing(2)
    ref.sim.run(1400)
    case, _ = pressed_packing(2)
    case.sim.run(700)
    path = str(tmp_path / "walls.h5")
    if writer == "api":
        pardem.save(case.sim, path)
        back = pardem.load(Communicator(), path)
    else:
        restart.save(case.sim, extras=case.extras, path=path)
        back = restart.load_case(Communicator(), path).sim
    assert isinstance(back.fixes[-1], PlaneConstraint) and back.plates is not None
    back.run(700)
    a, b = by_gid(ref.sim), by_gid(back)
    for k in FIELDS:
        assert np.array_equal(a[k], b[k]), k
    assert np.array_equal(wr.forces(ref.sim.comm), back.plates.forces(back.comm))
    assert np.array_equal(wr.offsets, back.plates.offsets)


# -- cemented contacts ------------------------------------------------------------------------------

def cemented_case(dim, comm=None, slab_axis=0, steps_before=100):
    """A 2D packing (10 x 10 grains, periodic along x and y) run ``steps_before`` steps frictional,
    then cemented at its contacts (``set_contact_params`` with the cement springs,
    ``cement_contacts``) and stretched along x while shortened along y (cell rates 300 and -100
    1/s): ``(case, cements made)``."""
    m = rows = 10
    pos, radii, vel, spin, lx = lattice(m, rows, seed=7, speed=0.05)
    ly = rows * (lx / m) * np.sqrt(3) / 2
    case = build(dim, pos, radii, np.zeros(2), np.array([lx, ly]), (True, True), vel, spin, comm=comm,
                 slab_axis=slab_axis, balance_every=50)
    case.sim.run(steps_before)
    set_contact_params(case.sim, {**HERTZ, **CEMENT})
    made = cement.cement_contacts(case.sim, E_MEAN, E_HALF, seed=11)
    case.sim.cell.rate = np.array([300.0, -100.0, 0.0])
    return case, made


def test_2d_cement_is_the_3d_cement_of_the_planar_configuration_bit_for_bit():
    """Cementation of a frictional 2D packing, then 2500 steps of stretching that break part of
    the cements (rupture, fading, clearing): every field and the 9-column contact history of the
    2D run equal the 3D run's, which stays planar by itself; the cement counts agree."""
    (two, made2), (three, made3) = cemented_case(2), cemented_case(3)
    assert made2 == made3 and made2 > 60
    two.sim.run(2500)
    three.sim.run(2500)
    a, b = by_gid(two.sim), by_gid(three.sim)
    for k in FIELDS:
        assert np.array_equal(a[k], b[k]), k
    assert two.sim.contacts.history.shape[1] == hm.WIDTH_CEMENTED
    assert np.array_equal(two.sim.contacts.history, three.sim.contacts.history)
    assert np.array_equal(two.sim.global_stress(), three.sim.global_stress())
    intact, fading = cement.cement_counts(two.sim)
    assert (intact, fading) == cement.cement_counts(three.sim)
    assert 0 < intact < made2 - 5                           # some cements broke, some hold
    assert np.all(b["x"][:, 2] == 0.0) and np.all(b["f"][:, 2] == 0.0) and np.all(b["t"][:, :2] == 0.0)
    plane = plane_of(two.sim)
    assert plane.off_plane == 0.0 and np.all(plane.removed == 0.0)
    assert two.sim.contacts.lost == 0                      # no intact cement dropped by a rebuild


class _Record:
    """Operation (every step): the tension carried by the pair along ``u`` (the clamp's reaction
    on grain 0, ``-reaction . u``), the cement state and the out-of-plane loads."""
    trigger = 1

    def __init__(self, clamp, u):
        self.clamp, self.u, self.rows = clamp, u, []

    def __call__(self, sim):
        h = sim.contacts.history
        state = h[0, hm.CEMENT_STATE] if len(h) else 0.0
        e = sim.elements
        self.rows.append((-float(self.clamp.reaction @ self.u), state, float(np.max(np.abs(e.f[:2, 2]))),
                          float(np.max(np.abs(e.t[:2, :2])))))


def test_cemented_pair_in_the_plane_breaks_at_the_analytic_tension():
    """Two grains in the plane, the line of centres at 30 deg to x, cemented at a small overlap
    delta0; grain 0 clamped, grain 1 pulled away along the line at v. The cement breaks at the first
    step where 1/2 Sn (delta0 - delta)^2 > E_th, the grains then apart (delta0 < sqrt(2 E_th / Sn)),
    so the tension just before is at most F* = sqrt(2 Sn E_th) and at the rupture step within one
    step's stretch of it, ``F* < T <= F* + Sn v dt``; then the force fades linearly over the fade
    time to zero (state cleared), and no out-of-plane load ever appears."""
    ang = np.radians(30.0)
    u = np.array([np.cos(ang), np.sin(ang), 0.0])
    delta0 = 2e-7
    pos = np.array([[0.0, 0.0, 0.0], (2 * R - delta0) * u])
    params = {**HERTZ, "restitution": 1.0}
    case = granular_case(Communicator(), pos, [R, R], RHO, "hertz_mindlin", params, [-5 * R, -5 * R],
                          [12 * R, 12 * R], DT, SKIN, periodic=(False, False), dimension=2)
    sim = case.sim
    sim.run(0)
    set_contact_params(case.sim, {**params, **CEMENT})
    e_th = 1e-8
    assert cement.cement_contacts(sim, e_th, 0.0, seed=3) == 1
    assert sim.contacts.history[0, hm.CEMENT_THRESHOLD] == e_th      # half_width 0: exactly the mean
    sn = CEMENT["cement_normal"]
    f_star = float(cement.tensile_strength(sim.contacts.params, e_th))
    assert f_star == np.sqrt(2 * sn * e_th) and delta0 < f_star / sn
    v = 0.05                                                     # stretch per step v dt = 5e-10 m, Sn v dt = 5e-4 F*
    clamp = fixes.Clamp([0])
    fixes.add(sim, clamp, fixes.PrescribedVelocity([1], v * u, dofs="xy"))
    rec = _Record(clamp, u)
    n_steps = int(1.2 * (f_star / sn + delta0) / (v * DT))       # past the rupture stretch
    sim.run(n_steps, operations=[rec])
    T, state, fz, txy = (np.array(c) for c in zip(*rec.rows))      # one row per step
    broke = int(np.argmax(state < 0.0))
    assert broke > 0 and np.all(state[:broke] == 1.0) and state[broke] == -1.0
    # intact: E_c = 1/2 Sn x^2 <= E_th (the tangential cement force is round-off: the pull is normal)
    assert np.max(T[:broke]) <= f_star * (1 + 1e-12)
    assert f_star < T[broke] <= f_star + sn * v * DT * (1 + 1e-9)
    # fading over cement_fade_time / dt = 20 steps: s = 1 - m dt / t_f of the stretched spring
    n_fade = int(round(CEMENT["cement_fade_time"] / DT))
    for m in range(1, n_fade):
        x = T[broke] / sn + m * v * DT          # the stretch grows by v dt per step
        assert T[broke + m] == pytest.approx((1 - m / n_fade) * sn * x, rel=1e-6)
    assert np.all(T[broke + n_fade:] == 0.0) and np.all(state[broke + n_fade:] == 0.0)
    assert np.all(fz == 0.0) and np.all(txy == 0.0)
    assert plane_of(sim).off_plane == 0.0


def _cemented_run(comm, steps, axis):
    case, made = cemented_case(2, comm=comm, slab_axis=axis)
    case.sim.run(steps)
    state = gathered(case.sim)
    counts = cement.cement_counts(case.sim)
    hist = histories(case.sim)
    stress = case.sim.global_stress()           # collective
    if state is None:
        return None
    return {**state, "counts": np.array([made, *counts]), "keys": hist[0], "history": hist[1],
            "stress": stress}


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
@pytest.mark.parametrize("axis", [0, 1])
def test_2d_cement_on_1_and_2_ranks_is_the_same_bits(tmp_path, axis):
    """Cementation and stretching of the 2D packing on 1 rank and on 2 ranks (slabs along x or y):
    the cements made, the intact and fading counts, every pair's 9-column history (by gid pair),
    the grains' fields and the stress are the same bits (thresholds are a function of the seed and
    the gid pair; the contacts are reproducible)."""
    one = _cemented_run(Communicator(), 1500, axis)
    out = tmp_path / "two.npz"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, os.path.abspath(__file__), "cement", str(out), "1500",
                        str(axis)], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    two = dict(np.load(out))
    assert set(two) == set(one)
    for k in one:
        assert np.array_equal(one[k], two[k]), k
    made, intact, _ = one["counts"]
    assert 0 < intact < made


def test_restart_of_a_cemented_2d_packing_continues_bit_for_bit(tmp_path):
    """``restart.save``/``load_case`` (the triaxial protocol's checkpoint) after cementation and
    part of the stretching: the cemented parameters, every cement's state (delta0, threshold,
    fading factor, tangential force) and the cell come back; 1000 + 1000 steps equal the
    uninterrupted 2000."""
    ref, _ = cemented_case(2)
    ref.sim.run(2000)
    case, _ = cemented_case(2)
    case.sim.run(1000)
    path = str(tmp_path / "cement.h5")
    restart.save(case.sim, extras=case.extras, path=path)
    back = restart.load_case(Communicator(), path)
    assert back.sim.contacts.params.cemented and isinstance(back.sim.fixes[-1], PlaneConstraint)
    back.sim.run(1000)
    a, b = by_gid(ref.sim), by_gid(back.sim)
    for k in FIELDS:
        assert np.array_equal(a[k], b[k]), k
    ka, ha = histories(ref.sim)
    kb, hb = histories(back.sim)
    assert np.array_equal(ka, kb) and np.array_equal(ha, hb)
    assert cement.cement_counts(ref.sim) == cement.cement_counts(back.sim)
    assert np.any(ha[:, hm.CEMENT_STATE] == 1.0)


if __name__ == "__main__":       # the 2-rank halves of the tests above
    comm = Communicator()
    kind, out = sys.argv[1], sys.argv[2]
    if kind == "walls":
        state = _pressed_run(comm, int(sys.argv[3]), int(sys.argv[4]))
    else:
        state = _cemented_run(comm, int(sys.argv[3]), int(sys.argv[4]))
    if comm.is_root:
        np.savez(out, **state)
