"""The 2D mode (issue 13 item 1): spheres with centres in the plane z = 0, moving in x, y and
turning about z (``pardem.engine.plane``, ``[domain] dimension = 2``).

Oracles:
* the 3D engine: a 2D run is the 3D run of the same planar configuration (out-of-plane components
  zero), bit for bit, also when the 2D run is given out-of-plane velocities, spins and loads (the
  plane constraint removes them);
* the same run on 1 and 2 ranks (slabs along x and along y): equal bits (the engine's sums are
  exact, ``tests/test_rank_independence.py``);
* the uninterrupted run: a restart from a checkpoint continues bit for bit;
* the virial theorem: for frictionless contacts the Love-Weber stress of the 2D cell is
  ``(1/V) dU/d eps`` of the elastic energy under an affine strain, computed here from an all-pairs
  minimum-image search in numpy, with ``V = L_x L_y t`` and ``t`` the mean diameter;
* isostaticity: a frictionless jammed 2D packing has ``Z >= 2 d (1 - 1/N')`` without rattlers.
"""
import json
import os
import shutil
import subprocess
import sys

import numpy as np

from pardem import restart
import pytest

import pardem
from pardem.engine import fixes
from pardem.engine.plane import PlaneConstraint, check_dimension, dimension_of
from pardem.engine.periodic_cell import PeriodicCell
from pardem.io.paraview import ParaViewWriter, piece_mesh
from pardem.parallel.communicator import Communicator
from pardem.physics import hertz_mindlin
from _util import granular_case

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SMALL = os.path.join(ROOT, "drivers", "isotropic_small.toml")
R = 0.1e-3
HERTZ = {"young": 72e9, "poisson": 0.2, "friction": 0.5, "restitution": 0.9}
# the linear law: stiff springs (dt = 1e-8 s is a tenth of 2 sqrt(m / kn) = 1e-7 s), normal damping
# and friction like HERTZ, no tangential dashpot (as Hertz-Mindlin: the grains keep turning)
LINEAR = {"kn": 4e6, "kt": 3e6, "friction": 0.5, "restitution": 0.9, "tangential_damping": 0.0}
LAWS = {"hertz_mindlin": HERTZ, "linear": LINEAR}
FIELDS = ("x", "v", "w", "q", "f", "t")


def planar_packing(m=8, seed=5):
    """A jittered triangular lattice of m x m spheres (R +- 2 %) slightly overlapping in a periodic
    cell: centres [n, 3] (z = 0), radii [n], cell edges [3] (z: the mean diameter), velocities and
    spins in the plane (v_z = w_x = w_y = 0)."""
    rng = np.random.default_rng(seed)
    a = 2.0 * R * 0.999
    g = (np.arange(m) + 0.5) * a
    X, Y = np.meshgrid(g, g * np.sqrt(3) / 2, indexing="ij")
    X = X + 0.5 * a * (np.arange(m)[None, :] % 2)
    n = m * m
    pos = np.stack([X.ravel(), Y.ravel(), np.zeros(n)], axis=1)
    pos[:, :2] += rng.uniform(-0.02 * R, 0.02 * R, (n, 2))
    radii = R * rng.uniform(0.98, 1.02, n)
    L = np.array([m * a, m * a * np.sqrt(3) / 2, 2.0 * float(np.mean(radii))])
    vel = np.zeros((n, 3))
    vel[:, :2] = rng.normal(0.0, 2.0, (n, 2))
    spin = np.zeros((n, 3))
    spin[:, 2] = rng.normal(0.0, 2e4, n)
    return pos, radii, L, vel, spin


def build(dim, pos, radii, L, vel, spin, comm=None, law="hertz_mindlin", **kw):
    """The case in 2D (dimension = 2) or the 3D twin: the same cell, periodic in x, y only."""
    comm = Communicator() if comm is None else comm
    kw.setdefault("rate", (-40.0, -20.0, 0.0))
    if dim == 2:
        return granular_case(comm, pos, radii, 2500.0, law, LAWS[law], np.zeros(3), L, 1e-8, 0.05 * R,
                              velocities=vel, angular_velocities=spin, dimension=2, **kw)
    return granular_case(comm, pos, radii, 2500.0, law, LAWS[law], np.array([0.0, 0.0, -0.5 * L[2]]),
                          L, 1e-8, 0.05 * R, periodic=(True, True, False), velocities=vel,
                          angular_velocities=spin, **kw)


def by_gid(sim):
    e = sim.elements
    o = np.argsort(e.gid[:e.n_owned])
    return {k: getattr(e, k)[:e.n_owned][o] for k in FIELDS}


# -- the plane constraint --------------------------------------------------------------------------

def test_plane_constraint_zeroes_the_out_of_plane_components_only():
    from pardem.engine.state import Elements
    rng = np.random.default_rng(1)
    e = Elements.from_spheres(rng.normal(size=(5, 3)), 1e-3, 2500.0)
    for k in ("v", "w", "f", "t"):
        getattr(e, k)[:] = rng.normal(size=(5, 3))
    e.n_owned = 4                                   # the last row is a ghost: untouched
    before = {k: getattr(e, k).copy() for k in ("x", "v", "w", "f", "t")}

    class Sim:
        elements = e
    fix = PlaneConstraint(0.0)
    fix.post_force(Sim)
    n = 4
    assert np.all(e.x[:n, 2] == 0.0) and np.all(e.v[:n, 2] == 0.0) and np.all(e.f[:n, 2] == 0.0)
    assert np.all(e.w[:n, :2] == 0.0) and np.all(e.t[:n, :2] == 0.0)
    for k in ("x", "v", "f"):
        assert np.array_equal(getattr(e, k)[:n, :2], before[k][:n, :2])
        assert np.array_equal(getattr(e, k)[n:], before[k][n:])
    for k in ("w", "t"):
        assert np.array_equal(getattr(e, k)[:n, 2], before[k][:n, 2])
    # what it removed: this rank's sums of f_z, t_x, t_y (a straight sum of 4 numbers: 1e-15)
    np.testing.assert_allclose(fix.removed, [before["f"][:n, 2].sum(), before["t"][:n, 0].sum(),
                                             before["t"][:n, 1].sum()], rtol=1e-14)
    assert fix.off_plane == np.max(np.abs(before["x"][:n, 2]))


def test_bad_dimensions_and_2d_arguments_are_refused():
    for bad in (1, 4, 2.5, True, "2"):
        with pytest.raises(ValueError, match="dimension"):
            check_dimension(bad)
    pos, radii, L, vel, spin = planar_packing(4)
    off = pos.copy()
    off[3, 2] = 1e-9
    with pytest.raises(ValueError, match="plane z = 0"):
        build(2, off, radii, L, vel, spin)
    with pytest.raises(ValueError, match="rate"):
        build(2, pos, radii, L, vel, spin, rate=(0.0, 0.0, -1.0))
    with pytest.raises(ValueError, match="slab_axis"):
        build(2, pos, radii, L, vel, spin, slab_axis=2)
    with pytest.raises(ValueError, match="not periodic along z"):
        PeriodicCell(np.zeros(3), np.ones(3), (True, True, True), dimension=2)


# -- 2D = the 3D run of the planar configuration --------------------------------------------------

@pytest.mark.parametrize("law", sorted(LAWS))
def test_2d_run_is_the_3d_run_of_the_planar_configuration_bit_for_bit(law):
    """Frictional, damped contacts of either law (sliding and rolling), a cell compressing at an
    imposed in-plane rate, 3000 steps: every field of the 2D run equals the 3D run's (no
    constraint), and the 3D run stays planar by itself (its z forces, x/y torques and z positions
    are exactly 0)."""
    pos, radii, L, vel, spin = planar_packing()
    two, three = build(2, pos, radii, L, vel, spin, law=law), build(3, pos, radii, L, vel, spin, law=law)
    assert dimension_of(two.sim) == 2 and dimension_of(three.sim) == 3
    two.sim.run(3000)
    three.sim.run(3000)
    a, b = by_gid(two.sim), by_gid(three.sim)
    assert two.sim.contacts.n_touching > 50                 # a contact network carries the load
    assert np.max(np.abs(np.linalg.norm(b["w"], axis=1))) > 1e3
    for k in FIELDS:
        assert np.array_equal(a[k], b[k]), k
    assert np.array_equal(two.sim.contacts.history, three.sim.contacts.history)
    assert np.all(b["x"][:, 2] == 0.0) and np.all(b["f"][:, 2] == 0.0) and np.all(b["t"][:, :2] == 0.0)
    # the same cell volume L_x L_y t, so the same stress; sigma_zz = 0 (no out-of-plane branch)
    s2, s3 = two.sim.global_stress(), three.sim.global_stress()
    assert np.array_equal(s2, s3) and s2[2, 2] == 0.0 and s2[0, 0] < 0.0
    cell = two.sim.cell
    assert cell.length[2] == L[2] and cell.volume == cell.length[0] * cell.length[1] * L[2]


def test_2d_run_removes_out_of_plane_motion_and_loads():
    """The 2D run given out-of-plane velocities, spins and an external load with a z component
    equals the 3D run of the same configuration without them, bit for bit."""
    pos, radii, L, vel, spin = planar_packing()
    rng = np.random.default_rng(9)
    noisy_v, noisy_w = vel.copy(), spin.copy()
    noisy_v[:, 2] = rng.normal(0.0, 1.0, len(pos))
    noisy_w[:, :2] = rng.normal(0.0, 1e4, (len(pos), 2))
    two = build(2, pos, radii, L, noisy_v, noisy_w, rate=(0.0, 0.0, 0.0), viscous_damping=1e3)
    three = build(3, pos, radii, L, vel, spin, rate=(0.0, 0.0, 0.0), viscous_damping=1e3)
    fixes.add(two.sim, fixes.ExternalForce([3, 17], (1e-3, -2e-3, 5e-3), torque=(1e-7, 2e-7, 3e-7)))
    fixes.add(three.sim, fixes.ExternalForce([3, 17], (1e-3, -2e-3, 0.0), torque=(0.0, 0.0, 3e-7)))
    assert isinstance(two.sim.fixes[-1], PlaneConstraint)     # the constraint after the load
    two.sim.run(2000)
    three.sim.run(2000)
    a, b = by_gid(two.sim), by_gid(three.sim)
    for k in FIELDS:
        assert np.array_equal(a[k], b[k]), k
    plane = two.sim.fixes[-1]
    assert plane.off_plane == 0.0 and plane.removed[0] == 2 * 5e-3


# -- the virial of the 2D cell --------------------------------------------------------------------

def test_love_weber_stress_of_the_2d_cell_is_the_virial():
    """Frictionless Hertz contacts, any configuration: ``sigma_ab = (1/V) dU/d eps_ab`` with U the
    elastic energy ``sum 2/5 f_n delta`` of the pairs of an all-pairs minimum-image search (numpy,
    independent of the engine's lists and sums) under the affine map ``d -> (I + eps) d``, by central
    differences, and ``V = L_x L_y t``, t the mean diameter (the 2D convention)."""
    pos, radii, L, _, _ = planar_packing(8, seed=11)
    case = build(2, pos, radii, L, None, None, rate=(0.0, 0.0, 0.0))
    sim = case.sim
    sim.contacts.params = hertz_mindlin.Params(**{**HERTZ, "friction": 0.0, "restitution": 1.0})
    sim.run(0)                                            # the forces of the configuration
    stress = sim.global_stress()
    n = len(pos)
    i, j = np.triu_indices(n, 1)
    d = pos[j] - pos[i]
    d[:, :2] -= L[:2] * np.round(d[:, :2] / L[:2])        # minimum image (L > 4 R: one image)
    touch = np.linalg.norm(d, axis=1) < radii[i] + radii[j]
    i, j, d = i[touch], j[touch], d[touch]
    assert len(i) > 100

    def energy(eps):
        dist = np.linalg.norm(d @ (np.eye(3) + eps).T, axis=1)
        delta = radii[i] + radii[j] - dist
        fn = hertz_mindlin.elastic_normal_force(sim.contacts.params, radii[i], radii[j], delta)
        return float(np.sum(0.4 * fn * delta))

    V = L[0] * L[1] * 2.0 * float(np.mean(radii))
    h = 1e-8      # strain step: 1e-5 of the mean delta / d ~ 1e-3
    virial = np.zeros((2, 2))
    for a in range(2):
        for b in range(2):
            e = np.zeros((3, 3))
            e[a, b] = h
            virial[a, b] = (energy(e) - energy(-e)) / (2.0 * h * V)
    # central differences: truncation (h / (delta/d))^2 ~ 1e-10, round-off of U differences
    # ~ 1e-16 U / (h |dU/de|) ~ 1e-16 (delta/d) / h ~ 1e-11 relative; 1e-7 of the pressure
    p = -0.5 * (virial[0, 0] + virial[1, 1])
    assert p > 1e6
    np.testing.assert_allclose(stress[:2, :2], virial, rtol=0.0, atol=1e-7 * p)
    assert np.all(stress[2] == 0.0) and np.all(stress[:, 2] == 0.0)
    assert sim.cell.pressure(stress) == -0.5 * (stress[0, 0] + stress[1, 1])


def test_servo_stiffness_of_the_2d_cell_is_minus_dp_de():
    """``ServoStiffness`` in 2D, ``S = kd2 / (2 V) + p``, against ``-dp/de`` of the in-plane
    pressure ``p = sum f_n |d| / (2 V)`` under the isotropic in-plane strain ``d -> (1 + e) d``,
    ``V -> (1 + e)^2 V`` (numpy pairs and central differences, as the virial test)."""
    from pardem.engine.relaxation import ServoStiffness
    pos, radii, L, _, _ = planar_packing(8, seed=11)
    case = build(2, pos, radii, L, None, None, rate=(0.0, 0.0, 0.0), servo=(1e6, 1e-9, 1.0))
    sim = case.sim
    sim.contacts.params = hertz_mindlin.Params(**{**HERTZ, "friction": 0.0, "restitution": 1.0})
    sim.run(0)
    sim.stress = sim.global_stress()
    ServoStiffness()(sim)
    n = len(pos)
    i, j = np.triu_indices(n, 1)
    d = pos[j] - pos[i]
    d[:, :2] -= L[:2] * np.round(d[:, :2] / L[:2])
    dist0 = np.linalg.norm(d, axis=1)
    keep = dist0 < radii[i] + radii[j]
    i, j, dist0 = i[keep], j[keep], dist0[keep]
    V0 = L[0] * L[1] * 2.0 * float(np.mean(radii))

    def pressure(e):
        dist = dist0 * (1.0 + e)
        fn = hertz_mindlin.elastic_normal_force(sim.contacts.params, radii[i], radii[j], radii[i] + radii[j] - dist)
        return float(np.sum(fn * dist)) / (2.0 * V0 * (1.0 + e) ** 2)

    h = 1e-8
    S = -(pressure(h) - pressure(-h)) / (2.0 * h)
    assert abs(pressure(0.0) / sim.cell.pressure(sim.stress) - 1.0) < 1e-12   # the same p, summed in another order
    assert S > 100.0 * pressure(0.0)
    # central differences as in the virial test: ~1e-8 relative
    assert abs(sim.cell.servo_stiffness / S - 1.0) < 1e-6


def test_2d_cell_servos_drive_the_plane_only():
    """The pressure servo uses the in-plane p = -(s_xx + s_yy) / 2 and drives x and y; the biaxial
    servo imposes one in-plane axis and holds the other at -pc; z never moves (analytic values)."""
    lo, edge = np.zeros(3), np.array([1.0, 1.0, 0.1])
    stress = np.diag([-3e6, -1e6, 0.0])
    iso = PeriodicCell(lo, edge, (True, True, False), servo=(1e6, 1e-7, 1e3), dimension=2)
    iso.control(stress)
    # 1e-7 (2e6 - 1e6), to the rounding of the product (1e-15)
    np.testing.assert_allclose(iso.rate, [0.1, 0.1, 0.0], rtol=1e-15, atol=0.0)
    bi = PeriodicCell(lo, edge, (True, True, False), dimension=2,
                      servo=PeriodicCell.triaxial_servo(1, -2.0, 2e6, 1e-7, 1e3))
    bi.control(stress)
    np.testing.assert_allclose(bi.rate, [0.1, -2.0, 0.0], rtol=1e-15, atol=0.0)   # 1e-7 (3e6 - 2e6), imposed
    back = PeriodicCell.from_state(bi.state())
    assert back.dimension == 2 and back.servo == bi.servo and back.volume == 0.1
    with pytest.raises(ValueError, match="axis 0 or 1"):
        PeriodicCell(lo, edge, (True, True, False), dimension=2,
                     servo=PeriodicCell.triaxial_servo(2, -2.0, 2e6, 1e-7, 1e3))


# -- restart, ParaView, save/load ------------------------------------------------------------------

def test_restart_continues_bit_for_bit_in_2d(tmp_path):
    """The 2D pressure servo (in-plane p, x and y driven) with friction: 300 steps, checkpoint,
    restore, 300 more equal the uninterrupted 600 steps; the plane constraint comes back."""
    pos, radii, L, vel, spin = planar_packing()
    servo = (2e6, 2e-6, 20.0)
    ref = build(2, pos, radii, L, vel, spin, rate=(0.0, 0.0, 0.0), servo=servo)
    ref.sim.run(600)
    case = build(2, pos, radii, L, vel, spin, rate=(0.0, 0.0, 0.0), servo=servo)
    case.sim.run(300)
    path = str(tmp_path / "two_d.h5")
    restart.save(case.sim, extras=case.extras, path=path)
    back = restart.load_case(Communicator(), path)
    assert back.sim.system.dimension == 2 and back.sim.cell.dimension == 2
    assert isinstance(back.sim.fixes[-1], PlaneConstraint)
    back.sim.run(300)
    a, b = by_gid(ref.sim), by_gid(back.sim)
    for k in FIELDS:
        assert np.array_equal(a[k], b[k]), k
    assert np.array_equal(ref.sim.cell.length, back.sim.cell.length)
    assert np.array_equal(ref.sim.stress, back.sim.stress)
    assert ref.sim.cell.length[2] == L[2] and ref.sim.cell.rate[2] == 0.0   # z never deforms
    assert not np.array_equal(ref.sim.cell.length[:2], L[:2])                # x, y did


def test_save_load_and_paraview_in_2d(tmp_path):
    pos, radii, L, vel, spin = planar_packing(6)
    sim = granular_case(Communicator(), pos, radii, 2500.0, "hertz_mindlin", HERTZ, np.zeros(3), L,
                        dt=1e-8, skin=None, dimension=2, velocities=vel, angular_velocities=spin).sim
    sim.run(100)
    path = str(tmp_path / "s.h5")
    pardem.save(sim, path)
    back = pardem.load(Communicator(), path)
    assert dimension_of(back) == 2 and any(isinstance(f, PlaneConstraint) for f in back.fixes)
    sim.run(100)
    back.run(100)
    for k, v in by_gid(sim).items():
        assert np.array_equal(v, by_gid(back)[k]), k
    pv = ParaViewWriter(str(tmp_path / "pv"), sim.comm, 1)
    pv(sim)
    names = sorted(os.listdir(tmp_path / "pv"))
    assert names == ["cell-00000200.vtu", "cell.pvd", "contacts-00000200.vtu", "contacts.pvd",
                     "pardem.pvd", "snapshot-00000200-r0000.vtu", "snapshot-00000200.pvtu"]
    # the piece's content (meshio cannot read back a piece without bonds: its reader fails on the
    # empty compressed line arrays, which VTK reads)
    mesh = piece_mesh(sim.elements, sim.bonds, 0)
    assert len(mesh.points) == len(pos) and np.all(mesh.points[:, 2] == 0.0)
    assert np.all(mesh.point_data["velocity"][:, 2] == 0.0)
    assert np.array_equal(np.sort(mesh.point_data["gid"]), np.arange(len(pos)))


# -- the isotropic protocol in 2D: bad input, isostaticity, 1 vs 2 ranks ---------------------------

def _driver(tmp_path, *sets):
    cmd = [sys.executable, "-m", "pardem.drivers.isotropic", "--quiet", "--out", str(tmp_path / "o")]
    for s in sets:
        cmd += ["--set", s]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)


@pytest.mark.parametrize("sets, field", [(("domain.dimension=4",), "domain.dimension"),
                                         (("domain.dimension=2", 'run.slab_axis="z"'), "run.slab_axis")])
def test_bad_dimension_is_one_line_and_exit_2(tmp_path, sets, field):
    res = _driver(tmp_path, *sets)
    assert res.returncode == 2, res.stderr[-2000:]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and field in lines[0], res.stderr
    assert not (tmp_path / "o").exists()


def _sweep(tmp_path, ranks):
    out = tmp_path / f"r{ranks}.npz"
    script = os.path.join(ROOT, "tests", "mpi", "rank_independence_isotropic.py")
    cmd = ([MPIEXEC, "-n", str(ranks)] if ranks > 1 else []) + [
        sys.executable, script, SMALL, str(out), "domain.dimension=2", "sample.n=64",
        "preparation.pressures=[1e6]", 'preparation.relaxation="fire"']
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    return dict(np.load(out))


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_isotropic_2d_sweep_is_isostatic_and_bitwise_equal_on_1_and_2_ranks(tmp_path):
    """FIRE preparation of 64 disks at 1 MPa and the moduli, on 1 rank and on 2 ranks (slabs along
    x): equal bits. The packing is a frictionless jammed 2D packing: p = p0 within the deck's 1e-3,
    centres at z = 0, Z without rattlers at least the isostatic 2 d (1 - 1/N') (N_c >= d (N' - 1)
    + 1 for a rigid frictionless network, d = 2), solid fraction of disks between the 2D random
    loose packing and the hexagonal one (0.77, pi / sqrt 12 = 0.9069)."""
    one = _sweep(tmp_path, 1)
    res = json.loads(str(one["results"]))
    row, det = res["rows"][0], res["details"][0]
    assert det["converged"] and abs(row["p"] / 1e6 - 1.0) < 1e-3
    assert np.all(one["x"][:, 2] == 0.0) and np.all(one["v"][:, 2] == 0.0) and np.all(one["w"][:, :2] == 0.0)
    n_kept = 64 - det["rattlers"]
    assert row["Z_no_rattlers"] >= 4.0 * (1.0 - 1.0 / n_kept)
    assert 0.77 < row["solid_fraction"] < np.pi / np.sqrt(12.0)
    assert row["K_affine"] > row["K_relaxed"] > 0.0 and row["mu_affine"] > row["mu_relaxed"] > 0.0
    other = _sweep(tmp_path, 2)
    for k in one:
        assert np.array_equal(one[k], other[k]), k


def servo_run(comm, steps, slab_axis):
    """The frictional 2D servo case on ``comm`` with slabs along ``slab_axis``: the state by gid
    (rank 0; None elsewhere) after ``steps`` steps."""
    pos, radii, L, vel, spin = planar_packing()
    case = build(2, pos, radii, L, vel, spin, comm=comm, rate=(0.0, 0.0, 0.0), servo=(2e6, 2e-6, 20.0),
                 slab_axis=slab_axis, balance_every=50)
    case.sim.run(steps)
    e = case.sim.elements
    parts = comm.gather({k: getattr(e, k)[:e.n_owned] for k in FIELDS + ("gid",)})
    if not comm.is_root:
        return None
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    o = np.argsort(cat["gid"])
    return {**{k: cat[k][o] for k in FIELDS}, "length": case.sim.cell.length, "stress": case.sim.stress}


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
@pytest.mark.parametrize("axis", [0, 1])
def test_2d_servo_run_is_bitwise_equal_on_1_and_2_ranks_with_slabs_along_x_or_y(tmp_path, axis):
    one = servo_run(Communicator(), 800, axis)
    out = tmp_path / "two.npz"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, os.path.abspath(__file__), str(out), "800", str(axis)],
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-3000:]
    two = dict(np.load(out))
    assert set(two) == set(one)
    for k in one:
        assert np.array_equal(one[k], two[k]), k


if __name__ == "__main__":       # the 2-rank half of the test above: OUT.npz STEPS SLAB_AXIS
    comm = Communicator()
    state = servo_run(comm, int(sys.argv[2]), int(sys.argv[3]))
    if comm.is_root:
        np.savez(sys.argv[1], **state)
