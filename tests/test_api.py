"""The scripting API: top-level exports, builders, walls, the thermo log."""
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import pardem
from _util import bonded_sim
from pardem.engine.walls import add_walls

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
R, RHO = 0.01, 2500.0


def material(**kw):
    return pardem.BeamMaterial(**{"young": 1e8, "radius_ratio": 0.5, "poisson": 0.3, "damping": 0.0, **kw})


@pytest.fixture(scope="module")
def comm():
    return pardem.Communicator()


def sphere(comm, z=R, v=(0.0, 0.0, 0.0), **kw):
    return bonded_sim(comm, [[0.0, 0.0, z]], R, RHO, np.zeros((0, 2), int), material(),
                                velocities=[v], **kw)


# -- top level ------------------------------------------------------------------------------

def test_import_is_lazy_and_exports_resolve():
    code = ("import sys, pardem; assert 'numba' not in sys.modules and 'mpi4py' not in sys.modules, "
            "sorted(m for m in sys.modules if m.startswith(('numba', 'mpi4py', 'pardem.')));"
            "from pardem import Simulation, build, System, Clamp, Log, save;"
            "assert Simulation.__module__ == 'pardem.engine.simulation';"
            "assert set(pardem.__all__) <= set(dir(pardem)); print(pardem.__version__)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "0.1.0"


def test_every_export_exists():
    for name in pardem.__all__:
        assert getattr(pardem, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        pardem.nothing


# -- builders -------------------------------------------------------------------------------

def test_dt_above_the_critical_step_is_refused(comm):
    x = [[0, 0, 0], [2 * R, 0, 0]]
    sim = bonded_sim(comm, x, R, RHO, [[0, 1]], material())
    # two equal masses on one axial spring: omega^2 = 2 k / m, the stability limit is 2 / omega;
    # the Gershgorin bound of the builder may only be more conservative (smaller)
    k = 1e8 * np.pi * (0.5 * R) ** 2 / (2 * R)
    m = RHO * 4 / 3 * np.pi * R**3
    assert sim.dt_critical <= 2.0 / np.sqrt(2 * k / m) * (1 + 1e-12)
    assert sim.dt == pytest.approx(0.3 * sim.dt_critical, rel=1e-15)
    with pytest.raises(ValueError, match="above the critical time step"):
        bonded_sim(comm, x, R, RHO, [[0, 1]], material(), dt=1.01 * sim.dt_critical)


@pytest.mark.parametrize("kw, message", [
    ({"positions": [[0, 0]]}, "positions must be finite with shape \\(n, 3\\)"),
    ({"radii": [R, R, R]}, "radii must be a scalar or have shape"),
    ({"radii": -R}, "radii must be finite and > 0"),
    ({"density": 0.0}, "density must be"),
    ({"pairs": [[0, 2]]}, "pairs must index elements 0 .. 1"),
    ({"pairs": [[0, 0]]}, "two different elements"),
    ({"pairs": [[0, 1], [1, 0]]}, "same bond twice"),
    ({"pairs": [[0.0, 1.0]]}, "pairs must be integer"),
    ({"frame": np.ones((3, 3))}, "frame must be a \\(3, 3\\) orthonormal"),
    ({"dt_fraction": 1.5}, "dt_fraction must be a number in"),
    ({"dt": -1.0}, "dt must be a finite number > 0"),
    ({"material": {"young": 1}}, "material must be a pardem BeamMaterial"),
])
def test_builder_inputs_are_checked(comm, kw, message):
    args = {"positions": [[0, 0, 0], [2 * R, 0, 0]], "radii": R, "density": RHO, "pairs": [[0, 1]],
            "material": material(), **kw}
    with pytest.raises(ValueError, match=message):
        bonded_sim(comm, **args)


def test_frame_picks_the_material_axis_of_each_bond(comm):
    x = [[0, 0, 0], [2 * R, 0, 0]]                 # one bond along world x
    aniso = material(young=(3e8, 2e8, 1e8))        # (E_L, E_R, E_T), law TOR
    default = bonded_sim(comm, x, R, RHO, [[0, 1]], aniso)
    assert default.bonds.young[0] == 3e8           # identity frame: x is L
    turned = bonded_sim(comm, x, R, RHO, [[0, 1]], aniso,
                                  frame=[[0, 1, 0], [1, 0, 0], [0, 0, 1]])   # L = y, R = x
    assert turned.bonds.young[0] == 2e8


def test_granular_system_head_on_collision_has_the_contact_restitution(comm):
    k, e_req, v = 1e5, 0.6, 0.1
    pos = [[0.0, 0.0, 0.0], [2 * R + 0.002, 0.0, 0.0]]
    system = pardem.System(pardem.Particles(pos, R, RHO, velocities=[[v, 0, 0], [-v, 0, 0]]),
                           contacts=pardem.ContactModel("linear", {"kn": k, "kt": k, "friction": 0.0,
                                                                   "restitution": e_req}),
                           cell=pardem.Cell(lo=[-0.2, -0.2, -0.2], length=[0.4, 0.4, 0.4]),
                           integration=pardem.Integration(dt_fraction=0.02))
    sim = pardem.build(comm, system)
    # the builder's dt is its fraction of the law's own critical step, which critical_time_step
    # (used for bonded systems and walls) finds again from the simulation
    assert sim.dt == pytest.approx(0.02 * sim.dt_critical, rel=1e-15)
    assert pardem.critical_time_step(sim) == pytest.approx(sim.dt_critical, rel=1e-12)
    m = RHO * 4 / 3 * np.pi * R**3
    omega = np.sqrt(k / (0.5 * m))                    # the pair's relative motion, m* = m / 2
    sim.run(int((0.002 / (2 * v) + 4.0 / omega) / sim.dt))
    e = sim.elements
    rel = e.v[e.gid == 1][0, 0] - e.v[e.gid == 0][0, 0]
    # exact restitution of the clipped dashpot (damping_ratio), up to the first-order time
    # discretisation bound omega dt / 2 (the same as for the walls, examples/drop.py)
    assert rel / (2 * v) == pytest.approx(e_req, abs=0.5 * omega * sim.dt)
    assert rel > 0.0
    # momentum is conserved exactly by the pair forces (equal and opposite), to rounding
    assert abs(e.v[:, 0].sum()) < 1e-15


# -- walls ----------------------------------------------------------------------------------

def test_sphere_resting_on_a_wall_compresses_it_by_mg_over_k(comm):
    k, g = 1e5, 9.81
    m = RHO * 4 / 3 * np.pi * R**3
    omega = np.sqrt(k / m)
    # global drag C = omega (damping ratio 1/2 on the wall spring, plus the wall's own dashpot at
    # e = 0.5, ratio 0.215): underdamped, every motion decays at least as exp(-0.7 omega t)
    sim = sphere(comm, z=R, viscous_damping=omega, dt_fraction=0.05,
                 walls=dict(normals=[[0, 0, 1]], points=[[0, 0, 0]], stiffness=k, restitution=0.5))
    pardem.add_fixes(sim, pardem.Gravity((0, 0, -g)))
    sim.run(int(40.0 / omega / sim.dt))
    overlap = R - sim.elements.x[0, 2]
    # static equilibrium k delta = m g; what is left of the motion is ~exp(-0.7 * 40) = 1e-12 of
    # the initial overlap error, far below the 1e-9 relative asked
    assert overlap == pytest.approx(m * g / k, rel=1e-9)
    assert sim.plates.normal_forces(comm)[0] == pytest.approx(m * g, rel=1e-9)
    assert pardem.energies(sim)["wall"] == pytest.approx(0.5 * k * overlap**2, rel=1e-12)


def test_moving_wall_kicks_a_resting_sphere_to_twice_its_speed(comm):
    k, V = 1e5, 0.2
    m = RHO * 4 / 3 * np.pi * R**3
    omega = np.sqrt(k / m)
    sim = sphere(comm, z=R + 1e-3, dt_fraction=0.025,
                 walls=dict(normals=[[0, 0, 1]], points=[[0, 0, 0]], velocities=[0, 0, V], stiffness=k))
    walls = sim.plates
    sim.run(int((1e-3 / V + 10.0 / omega) / sim.dt))
    # the plane moved exactly V t
    assert walls.offsets[0] == pytest.approx(V * sim.step_count * sim.dt, rel=1e-12)
    # elastic impact of an immovable wall at V on a sphere at rest: 2 V afterwards. Verlet is
    # symplectic: the energy of the contact oscillation in the wall frame comes back to within
    # O((omega dt)^2) = 2.5e-3 relative
    assert sim.elements.v[0, 2] == pytest.approx(2 * V, rel=(omega * sim.dt) ** 2)
    assert sim.elements.x[0, 2] - R > walls.offsets[0]        # separated again


def test_add_walls_checks_the_time_step_and_its_inputs(comm):
    sim = sphere(comm, dt=1e-4)
    m = RHO * 4 / 3 * np.pi * R**3
    k_max = m * (2.0 / 1e-4) ** 2           # the wall spring's own limit dt < 2 sqrt(m / k)
    with pytest.raises(ValueError, match="above the critical time step"):
        add_walls(sim, [[0, 0, 1]], [[0, 0, 0]], stiffness=1.01 * k_max)
    assert sim.plates is None
    with pytest.raises(ValueError, match="normals must be finite non-zero"):
        add_walls(sim, [[0, 0, 0]], [[0, 0, 0]], stiffness=1.0)
    with pytest.raises(ValueError, match=r"points must be finite with shape \(1, 3\)"):
        add_walls(sim, [[0, 0, 1]], [[0, 0]], stiffness=1.0)
    with pytest.raises(ValueError, match="stiffness must be a positive number"):
        add_walls(sim, [[0, 0, 1]], [[0, 0, 0]])
    w = add_walls(sim, [[0, 0, 2]], [[0, 0, 0]], stiffness=0.99 * k_max)
    assert np.array_equal(w.normals, [[0.0, 0.0, 1.0]])     # normalised
    with pytest.raises(ValueError, match="already has walls"):
        add_walls(sim, [[0, 0, 1]], [[0, 0, 0]], stiffness=1.0)


def test_frictional_walls_get_a_history_per_element(comm):
    sim = sphere(comm, dt=1e-5)
    add_walls(sim, [[0, 0, 1], [1, 0, 0]], [[0, 0, 0], [-R, 0, 0]], stiffness=1e4, friction=0.5)
    assert sim.elements.wall_h.shape == (1, 2, 3)
    sim.run(10)


# -- log ------------------------------------------------------------------------------------

def test_log_writes_energies_and_user_columns(comm, tmp_path):
    v = np.array([0.3, 0.0, -0.4])
    sim = sphere(comm, z=1.0, v=v, dt=1e-4)
    log = pardem.Log(tmp_path, trigger=10, columns={"z": lambda s: s.elements.x[0, 2]}, stream=None,
                     energies="all")
    sim.run(30, operations=[log])
    data = np.loadtxt(tmp_path / "log.txt")
    assert data.shape == (3, 9)
    assert list(data[:, 0]) == [10, 20, 30]
    m = RHO * 4 / 3 * np.pi * R**3
    # free flight: kinetic energy 1/2 m |v|^2 (printed with 10 significant digits)
    assert np.allclose(data[:, 2], 0.5 * m * v @ v, rtol=1e-9)
    assert np.all(data[:, 3:7] == 0.0)
    assert np.allclose(data[:, 8], 1.0 + v[2] * data[:, 1], rtol=1e-9)
    log.close()
    # append (the default): a restart continues the same file
    again = pardem.Log(tmp_path, trigger=10, stream=None, energies="all")
    sim.run(10, operations=[again])
    again.close()
    text = (tmp_path / "log.txt").read_text()
    assert "# continued at step 40" in text and text.count("\n") == 1 + 3 + 2 + 1
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        sim.run(10, operations=[pardem.Log(tmp_path, stream=None, mode="new")])
    fresh = pardem.Log(tmp_path, trigger=5, stream=None, mode="overwrite", energies="all")
    sim.run(5, operations=[fresh])
    fresh.close()
    assert np.loadtxt(tmp_path / "log.txt").shape == (8,)


def test_log_inputs_are_checked():
    with pytest.raises(ValueError, match="trigger = 0: expected a period, an integer >= 1"):
        pardem.Log(trigger=0)
    with pytest.raises(ValueError, match="mode must be one of"):
        pardem.Log(mode="w")
    with pytest.raises(ValueError, match="column names"):
        pardem.Log(columns={"kinetic": lambda s: 0.0})


LOG_SCRIPT = textwrap.dedent("""
    import sys, numpy as np, pardem
    comm = pardem.Communicator()
    n, R = 12, 0.01
    x = np.zeros((n, 3)); x[:, 0] = 2 * R * np.arange(n)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    mat = pardem.BeamMaterial(young=1e8, radius_ratio=0.5, poisson=0.3, damping=0.0)
    sim = pardem.build(comm, pardem.System(pardem.Particles(x, R, 1000.0), bonds=pardem.BondModel(mat, pairs),
                                           integration=pardem.Integration(dt=2e-6)))
    pardem.add_fixes(sim, pardem.ExternalForce([0, 11], [(0, 0, 1e-2), (0, 0, -1e-2)]))
    log = pardem.Log(sys.argv[1], trigger=500, stream=None)
    sim.run(2000, operations=[log])
""")


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_log_counts_each_bond_once_on_two_ranks(tmp_path):
    script = tmp_path / "run.py"
    script.write_text(LOG_SCRIPT)
    data = {}
    for k in (1, 2):
        out = tmp_path / f"r{k}"
        res = subprocess.run([MPIEXEC, "-n", str(k), sys.executable, str(script), str(out)],
                             capture_output=True, text=True, timeout=600, cwd=ROOT)
        assert res.returncode == 0, res.stderr
        data[k] = np.loadtxt(out / "log.txt")
    assert data[1].shape == (4, 5)     # step time kinetic bond total: no contacts, walls, gravity
    assert np.all(data[1][:, 3] > 0.0)
    # the bond crossing the slab boundary is computed on both ranks; summing each rank's kernel
    # energy would count it twice (about 1/11 of the total here). Same state on both runs to
    # rounding: equal to the 10 printed digits
    assert np.allclose(data[2], data[1], rtol=1e-9, atol=0)


def test_log_prints_on_stdout_by_default(comm, capsys):
    sim = sphere(comm, z=1.0, v=(0.0, 0.0, 1.0), dt=1e-4)
    sim.run(4, operations=[pardem.Log(trigger=2, columns={"vz": lambda s: s.elements.v[0, 2]})])
    lines = capsys.readouterr().out.splitlines()
    # the energies a lone sphere can have: kinetic only (the zero columns are not printed)
    assert lines[0].split() == ["step", "time", "kinetic", "total", "vz"]
    assert [ln.split()[0] for ln in lines[1:]] == ["2", "4"]
    assert float(lines[-1].split()[-1]) == 1.0
