"""One checkpoint payload and one restore for any system (``pardem.engine.snapshot``): a system
built with the Python API, walls and contacts included, continues bit for bit after save/load on
the rank count that wrote it, and loads on another rank count with the same state."""
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np

from pardem import restart
import pytest

import pardem
from _util import granular_case

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")

# a bonded column of 3 x 3 x 6 spheres falling onto a frictional wall, touching a loose sphere
# (element-element contacts) and bouncing: bonds, walls (with history), contacts and their
# history all evolve during the 400 steps
SYSTEM = textwrap.dedent("""
    import numpy as np, pardem

    def system(comm):
        R = 0.01
        g = np.arange(3) * 2 * R
        X, Y, Z = np.meshgrid(g, g, np.arange(6) * 2 * R + 1.05 * R, indexing="ij")
        x = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
        n = len(x)
        d = np.linalg.norm(x[:, None] - x[None], axis=2)
        pairs = np.argwhere(np.triu(np.isclose(d, 2 * R)))
        x = np.vstack([x, [[6.5 * R, 2 * R, 1.2 * R]]])       # a loose sphere beside the column
        v = np.zeros_like(x); v[:n, 2] = -0.5; v[:n, 0] = 0.2
        mat = pardem.BeamMaterial(young=1e7, radius_ratio=0.5, poisson=0.3, damping=0.05)
        walls = pardem.WallModel(normals=[[0, 0, 1]], points=[[0, 0, 0]],
                                 law=pardem.wall_law("linear", stiffness=2e4, friction=0.4))
        contacts = pardem.ContactModel("hertz_mindlin", {"young": 1e7, "poisson": 0.3, "friction": 0.3})
        return pardem.build(comm, pardem.System(pardem.Particles(x, R, 1000.0, velocities=v),
                                                bonds=pardem.BondModel(mat, pairs), contacts=contacts,
                                                walls=walls, decomposition=pardem.Decomposition(slab_axis=0)))

    def state(sim):
        e = sim.elements
        n = e.n_owned
        rows = {k: getattr(e, k)[:n] for k in ("gid", "x", "v", "w", "q", "f", "t")}
        return {k: np.concatenate([p[k] for p in sim.comm.allgather(rows)]) for k in rows}
""")


def _by_gid(s):
    order = np.argsort(s["gid"])
    return {k: v[order] for k, v in s.items()}


def _run_script(tmp_path, body, n):
    script = tmp_path / f"run{n}.py"
    script.write_text(SYSTEM + textwrap.dedent(body))
    res = subprocess.run([MPIEXEC, "-n", str(n), sys.executable, str(script), str(tmp_path)],
                         capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-3000:]


def test_save_load_continues_bit_for_bit_on_one_rank(tmp_path):
    ns = {}
    exec(SYSTEM, ns)
    comm = pardem.Communicator()
    ref = ns["system"](comm)
    ref.run(400)
    sim = ns["system"](comm)
    sim.run(200)
    path = str(tmp_path / "state.h5")
    pardem.save(sim, path)
    back = pardem.load(comm, path)
    assert back.step_count == 200 and back.time == sim.time and back.dt == sim.dt
    before = ns["state"](sim)
    for k, v in ns["state"](back).items():     # the stored state, exactly
        assert np.array_equal(v, before[k]), k
    back.run(200)
    a, b = _by_gid(ns["state"](ref)), _by_gid(ns["state"](back))
    assert np.any(np.abs(a["v"][:, 2]) > 0.0)
    assert ref.plates.normal_forces(comm)[0] >= 0.0
    for k in a:       # the continued run is the uninterrupted one, bit for bit
        assert np.array_equal(a[k], b[k]), k
    assert np.array_equal(ref.elements.wall_h[:ref.elements.n_owned], back.elements.wall_h[:back.elements.n_owned])


def test_one_restore_reads_a_protocol_case_and_its_extras(tmp_path):
    """A granular case saved with its protocol's facts is read back by the one restore: ``load``
    gives its simulation (continuing bit for bit), ``load_case`` also its extras."""
    from pardem.engine import granular
    comm = pardem.Communicator()
    pos, L = granular.simple_cubic(3, 1e-3)
    case = granular_case(comm, pos, 1e-3, 2500.0, "linear", {"kn": 1e3, "kt": 1e3, "friction": 0.3},
                          [0, 0, 0], [L, L, L], 1e-6, 1e-4, velocities=np.full((27, 3), 1e-3))
    case.extras["cemented_pairs"] = 7
    case.sim.run(20)
    path = str(tmp_path / "g.h5")
    restart.save(case.sim, extras=case.extras, path=path)
    sim = pardem.load(comm, path)
    back = restart.load_case(comm, path)
    assert back.extras == {"cemented_pairs": 7}
    for s in (case.sim, sim, back.sim):
        s.run(30)
    for k in ("x", "v", "w", "f"):
        assert np.array_equal(getattr(case.sim.elements, k), getattr(sim.elements, k)), k
        assert np.array_equal(getattr(case.sim.elements, k), getattr(back.sim.elements, k)), k


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_save_load_on_two_ranks_and_on_another_rank_count(tmp_path):
    # 2 ranks: the reference 400 steps, and 200 steps saved
    _run_script(tmp_path, """
        import sys
        comm = pardem.Communicator()
        out = sys.argv[1]
        ref = system(comm); ref.run(400)
        s = state(ref)
        sim = system(comm); sim.run(200)
        pardem.save(sim, out + "/two.h5")
        s200 = state(sim)
        if comm.is_root:
            np.savez(out + "/ref.npz", **s)
            np.savez(out + "/at200.npz", **s200)
    """, 2)
    # continued on 2 ranks (the same count: bit for bit) and loaded on 1 rank (the same stored state)
    _run_script(tmp_path, """
        import sys
        comm = pardem.Communicator()
        out = sys.argv[1]
        sim = pardem.load(comm, out + "/two.h5")
        s = state(sim)
        if comm.size == 1:
            np.savez(out + "/loaded1.npz", **s)
        else:
            sim.run(200)
            s = state(sim)
            if comm.is_root:
                np.savez(out + "/cont2.npz", **s)
    """, 2)
    _run_script(tmp_path, """
        import sys
        comm = pardem.Communicator()
        out = sys.argv[1]
        sim = pardem.load(comm, out + "/two.h5")
        np.savez(out + "/loaded1.npz", **state(sim))
    """, 1)
    load = lambda name: _by_gid(dict(np.load(tmp_path / name)))
    ref, cont = load("ref.npz"), load("cont2.npz")
    for k in ref:
        assert np.array_equal(ref[k], cont[k]), k
    at200, one = load("at200.npz"), load("loaded1.npz")
    for k in at200:
        assert np.array_equal(at200[k], one[k]), k
