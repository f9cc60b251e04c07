"""``bonded_system`` on a rank that holds no bond: its (empty) bond set must still carry the
material's switches (damped, breakable, densify_p0), because bonds that migrate to that rank later
are unpacked with them (``SlabComm.exchange``) and a checkpoint stores them (``snapshot.system_attrs``).

The case: a damped, spinning and vibrating bonded cube of 2 x 2 x 2 spheres on the high-x side
drifting towards -x, past loose spheres (no contacts) that make the balanced cut give rank 0 only
loose spheres. On 2 ranks, rank 0 starts with no bond and owns the cube at the end. Independent
computation: the same system on 1 rank. A bond's force is computed from identical inputs on every
rank holding it and an element's forces are summed over its bonds in the same (gid) order, so the
two runs agree bit for bit (no tolerance). Before the fix rank 0 unpacked the migrating bonds as
undamped, and the checkpoint written at step 0 said ``damped = False``.
"""
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
STEPS = 3000

SYSTEM = textwrap.dedent("""
    import numpy as np, pardem

    R = 0.01

    def system(comm, damping=0.3):
        g = np.array([0.0, 2 * R])
        X, Y, Z = np.meshgrid(g + 40 * R, g, g, indexing="ij")
        cube = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
        d = np.linalg.norm(cube[:, None] - cube[None], axis=2)
        pairs = np.argwhere(np.triu(np.isclose(d, 2 * R)))
        loose = np.stack([np.arange(12) * 3 * R, np.full(12, 6 * R), np.zeros(12)], axis=1)
        x = np.vstack([cube, loose])
        rng = np.random.default_rng(7)
        v = np.zeros_like(x)
        v[:8] = rng.normal(scale=0.05, size=(8, 3))
        v[:8, 0] -= 4.0                           # the cube drifts to -x, across the slab cut
        mat = pardem.BeamMaterial(young=1e7, radius_ratio=0.5, poisson=0.3, damping=damping,
                                  tensile_strength=1e9)    # breakable (none breaks): a switch too
        w = np.zeros_like(x)
        w[:8] = rng.normal(scale=3.0, size=(8, 3))    # spinning ends: the rotation damping acts
        sim = pardem.build(comm, pardem.System(pardem.Particles(x, R, 1000.0, velocities=v),
                                               bonds=pardem.BondModel(mat, pairs),
                                               decomposition=pardem.Decomposition(slab_axis=0)))
        sim.elements.w[:] = w[sim.elements.gid]       # owned and ghost rows alike
        return sim

    def state(sim):
        e = sim.elements
        n = e.n_owned
        rows = {k: getattr(e, k)[:n] for k in ("gid", "x", "v", "w", "q", "f", "t")}
        parts = sim.comm.allgather(rows)
        s = {k: np.concatenate([p[k] for p in parts]) for k in rows}
        order = np.argsort(s["gid"])
        return {k: v[order] for k, v in s.items()}
""")


def _run(tmp_path, name, body, n):
    script = tmp_path / f"{name}.py"
    script.write_text(SYSTEM + textwrap.dedent(body))
    res = subprocess.run([MPIEXEC, "-n", str(n), sys.executable, str(script), str(tmp_path)],
                         capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-3000:]


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_rank_without_bonds_keeps_the_damping_and_equals_one_rank(tmp_path):
    body = f"""
        import json, sys
        comm = pardem.Communicator()
        out = sys.argv[1]
        sim = system(comm)
        b = sim.bonds
        facts = {{"start_bonds": comm.comm.allgather(int(b.n)),
                  "flags": comm.comm.allgather([bool(b.damped), bool(b.breakable)])}}
        if comm.size == 2:
            pardem.save(sim, out + "/start2.h5")       # rank 0 holds no bond at this step
        sim.run({STEPS})
        facts["end_bonds"] = comm.comm.allgather(int(sim.bonds.n))
        facts["end_damped"] = comm.comm.allgather(bool(sim.bonds.damped))
        s = state(sim)
        undamped = system(comm, damping=0.0)
        undamped.run({STEPS})
        s0 = state(undamped)
        if comm.is_root:
            np.savez(out + f"/end{{comm.size}}.npz", **s)
            np.savez(out + f"/undamped{{comm.size}}.npz", **s0)
            json.dump(facts, open(out + f"/facts{{comm.size}}.json", "w"))
    """
    _run(tmp_path, "one", body, 1)
    _run(tmp_path, "two", body, 2)
    import json
    facts = json.loads((tmp_path / "facts2.json").read_text())
    # the case exercises what it should: rank 0 starts without a bond and ends holding the cube
    assert facts["start_bonds"][0] == 0 and facts["start_bonds"][1] == 12, facts
    assert facts["end_bonds"][0] == 12 and facts["end_bonds"][1] == 0, facts
    load = lambda name: dict(np.load(tmp_path / name))
    one, two = load("end1.npz"), load("end2.npz")
    for k in one:
        assert np.array_equal(one[k], two[k]), k
    # every rank has the material's switches, with or without bonds
    assert facts["flags"] == [[True, True], [True, True]], facts
    assert facts["end_damped"] == [True, True], facts
    # and the damping matters here: the undamped run ends elsewhere (else the test could not fail)
    free1, free2 = load("undamped1.npz"), load("undamped2.npz")
    for k in one:
        assert np.array_equal(free1[k], free2[k]), k
    assert np.abs(free1["w"] - one["w"]).max() > 1e-3 * np.abs(free1["w"]).max()
    # the checkpoint written on 2 ranks at step 0, continued on 1 rank
    _run(tmp_path, "load", f"""
        import sys
        comm = pardem.Communicator()
        out = sys.argv[1]
        sim = pardem.load(comm, out + "/start2.h5")
        assert sim.bonds.damped and sim.bonds.breakable, sim.bonds.flags()
        sim.run({STEPS})
        np.savez(out + "/loaded1.npz", **state(sim))
    """, 1)
    loaded = load("loaded1.npz")
    for k in one:
        assert np.array_equal(one[k], loaded[k]), k


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_a_checkpoint_refuses_ranks_that_disagree_on_the_bond_switches(tmp_path):
    """``snapshot.system_attrs`` stores the switches once for all ranks; if a builder ever left one
    rank with other switches, the checkpoint would restore the wrong physics, so writing refuses
    on every rank (no rank left waiting in the collective write)."""
    _run(tmp_path, "disagree", """
        import sys
        comm = pardem.Communicator()
        out = sys.argv[1]
        sim = system(comm)
        if comm.rank == 0:
            sim.bonds.damped = False               # what the old builder did to a rank without bonds
        try:
            pardem.save(sim, out + "/bad.h5")
        except ValueError as err:
            assert "disagree on the bond switches" in str(err), err
            open(out + f"/refused{comm.rank}", "w").close()
    """, 2)
    assert (tmp_path / "refused0").exists() and (tmp_path / "refused1").exists()
    assert not (tmp_path / "bad.h5").exists()
