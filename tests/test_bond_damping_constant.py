"""The bonds' rotation damping matrix is computed once per bond (``Bonds.rot_damping``, issue 14),
not every step: it must be exactly ``rotation_damping`` of the bond's constants and its ends'
masses and inertias, survive migration (pack/unpack) and checkpoints (not stored: recomputed on
restore) bit for bit, and cost nothing for undamped bonds.

Independent computation: ``rotation_damping.py_func``, the same expression evaluated by the Python
interpreter (IEEE double arithmetic, no compiler), bond by bond. Equality is bitwise everywhere:
the table only moves the evaluation of one expression from the step to the bond's creation.
"""
import numpy as np
import pytest

import pardem
from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.engine.state import BOND_FIELDS, Bonds, Elements
from pardem.io.checkpoint import BOND_DATASETS
from pardem.physics.beam import ROT_DAMPING_WIDTH, compute_bonds, rotation_damping
from _util import bonded_sim


def _chain(damping=0.2, n=12, seed=3):
    """A zig-zag chain of touching spheres of unequal radii (so that D12 != D21), at rest, with
    random velocities and angular velocities (so that the damping loads are not zero)."""
    rng = np.random.default_rng(seed)
    radii = 1e-3 * rng.uniform(0.6, 1.4, n)
    x = np.zeros((n, 3))
    for k in range(1, n):
        d = np.array([1.0, 0.3 * (-1) ** k, 0.2 * rng.uniform(-1, 1)])
        x[k] = x[k - 1] + (radii[k - 1] + radii[k]) * d / np.linalg.norm(d)
    e = Elements.from_spheres(x, radii, 1200.0)
    pairs = np.array([[k, k + 1] for k in range(n - 1)] + [[0, 2], [3, 5]])
    b = make_bonds(e, pairs, BeamMaterial(young=5e8, radius_ratio=0.7, poisson=0.25, damping=damping), np.eye(3))
    e.v[:] = rng.normal(scale=0.3, size=e.v.shape)
    e.w[:] = rng.normal(scale=200.0, size=e.w.shape)
    e.x[:] += rng.normal(scale=2e-6, size=e.x.shape)
    return e, b


def _loads(b, e):
    e.f[:] = 0.0
    e.t[:] = 0.0
    energy = compute_bonds(b, e)[0]
    return e.f.copy(), e.t.copy(), energy


def test_table_is_the_damping_formula_of_each_bond_bitwise():
    e, b = _chain()
    assert b.rot_damping.shape == (b.n, ROT_DAMPING_WIDTH)
    ref = np.array([rotation_damping.py_func(b.tau_a[k], b.ka[k], b.kb[k], b.L0[k], e.mass[b.i[k]], e.mass[b.j[k]],
                                             e.inertia[b.i[k]], e.inertia[b.j[k]]) for k in range(b.n)])
    np.testing.assert_array_equal(b.rot_damping, ref)
    # unequal ends: the matrix is not symmetric, so a swapped column would be seen
    assert np.all(b.rot_damping[:, 1] != b.rot_damping[:, 2])


def test_bonds_restored_without_the_table_recompute_it_bitwise():
    """A checkpoint stores ``BOND_DATASETS`` (no table): the restored bonds get it back at their
    first force evaluation, and the loads are those of the bonds that never lost it."""
    assert "rot_damping" not in BOND_DATASETS and "rot_damping" in BOND_FIELDS
    e, b = _chain()
    f0, t0, u0 = _loads(b, e)
    stored = {k: v for k, v in b.pack(slice(None)).items() if k in BOND_DATASETS}
    r = Bonds.unpack([stored], damped=True)
    r.relink(e.gid)
    assert r.rot_damping.shape == (b.n, 0)
    f1, t1, u1 = _loads(r, e)
    np.testing.assert_array_equal(r.rot_damping, b.rot_damping)
    np.testing.assert_array_equal(f1, f0)
    np.testing.assert_array_equal(t1, t0)
    assert u1 == u0
    assert np.abs(t0).max() > 0.0


def test_migrating_parts_keep_or_drop_the_table_together():
    """Parts that all carry the table keep it (empty parts of any width join them); a part
    without it makes the whole set recompute it (never a mix of stale and fresh rows)."""
    e, b = _chain()
    a, c = b.pack(np.arange(0, 6)), b.pack(np.arange(6, b.n))
    empty = Bonds.empty().pack(slice(None))
    kept = Bonds.unpack([a, empty, c], damped=True)
    np.testing.assert_array_equal(kept.rot_damping, b.rot_damping)
    without = {k: v for k, v in c.items() if k != "rot_damping"}
    mixed = Bonds.unpack([a, without], damped=True)
    assert mixed.rot_damping.shape == (b.n, 0)
    mixed.relink(e.gid)
    _loads(mixed, e)
    np.testing.assert_array_equal(mixed.rot_damping, b.rot_damping)


def test_undamped_bonds_hold_no_table():
    e, b = _chain(damping=0.0)
    assert not b.damped and b.rot_damping.shape == (b.n, 0) and b.rot_damping.nbytes == 0
    _loads(b, e)
    assert b.rot_damping.shape == (b.n, 0)    # the undamped loop never reads it


def test_save_load_of_a_damped_system_with_unequal_ends_continues_bit_for_bit(tmp_path):
    """pardem.save / pardem.load (one rank): the run continued from the file is the uninterrupted
    one, bit for bit (the table is rebuilt from the stored masses and constants)."""
    e, b = _chain(n=10, seed=5)
    comm = pardem.Communicator()
    pairs = np.stack([b.gid_i, b.gid_j], axis=1)
    x0 = e.x.copy()
    mat = BeamMaterial(young=5e8, radius_ratio=0.7, poisson=0.25, damping=0.2)

    def system():
        return bonded_sim(comm, x0, e.radius, 1200.0, pairs, mat, velocities=e.v)

    whole = system()
    whole.run(300)
    part = system()
    part.run(120)
    path = str(tmp_path / "state.h5")
    pardem.save(part, path)
    back = pardem.load(comm, path)
    assert back.bonds.rot_damping.shape[1] == 0      # not stored: recomputed at the first step
    back.run(180)
    np.testing.assert_array_equal(back.bonds.rot_damping, whole.bonds.rot_damping)
    for k in ("x", "v", "w", "q"):
        np.testing.assert_array_equal(getattr(back.elements, k), getattr(whole.elements, k))
    assert np.abs(whole.elements.w).max() > 0.0


def _compiled_signatures():
    """Number of compiled signatures of every Numba dispatcher held by a pardem module (module
    attributes and module-level dicts of dispatchers, e.g. the bond loops by switches)."""
    import sys
    from numba.core.registry import CPUDispatcher
    seen, total = set(), 0
    for name, mod in list(sys.modules.items()):
        if not name.startswith("pardem") or mod is None:
            continue
        for value in list(vars(mod).values()):
            items = value.values() if isinstance(value, dict) else (value,)
            for d in items:
                if isinstance(d, CPUDispatcher) and id(d) not in seen:
                    seen.add(id(d))
                    total += len(d.signatures)
    return total


@pytest.mark.parametrize("extra", [{}, {"bonds": {"tensile_strength": 1e6, "shear_strength": 1e6}}],
                         ids=["damped", "breakable with contacts"])
def test_a_built_case_runs_without_compiling_and_untouched(extra):
    """``compile_step_kernels`` (called when a compression case is assembled) compiles every
    kernel of a step, the stability check and a sample, so the run's timing counts no
    compilation (issue 14), and leaves the case's state as it was."""
    from pardem.config import check_deck
    from pardem.protocols.compression import build_case, compile_step_kernels
    from pardem.protocols.compression_deck import COMPRESS_SCHEMA
    deck = check_deck(COMPRESS_SCHEMA, {"domain": {"box": [0.003, 0.003, 0.003], "radius": 0.25e-3},
                                        **extra})
    case = build_case(pardem.Communicator(), deck)
    sim = case.sim
    before = {k: getattr(sim.elements, k).copy() for k in ("x", "v", "w", "q", "f", "t", "wall_h")}
    bonds = {k: v.copy() for k, v in sim.bonds.pack(slice(None)).items()}
    plates = sim.plates.positions.copy(), sim.plates.wall_force.copy()
    compile_step_kernels(sim)
    for k, v in before.items():
        np.testing.assert_array_equal(getattr(sim.elements, k), v)
    for k, v in sim.bonds.pack(slice(None)).items():
        np.testing.assert_array_equal(v, bonds[k])
    np.testing.assert_array_equal(sim.plates.positions, plates[0])
    np.testing.assert_array_equal(sim.plates.wall_force, plates[1])
    assert sim.step_count == 0 and case.compile_seconds > 0.0
    n0 = _compiled_signatures()
    sim.run(sim.check_every)
    case.reducer.sample(sim)
    assert _compiled_signatures() == n0
