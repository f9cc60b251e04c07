"""The blocked bond force loop (``physics.beam._bond_loop``, issue 14) against a plain loop, one
bond at a time, bitwise.

Independent computation: the reference below, run by the Python interpreter, takes the bonds one
at a time in order, evaluates each with ``beam_bond.py_func`` in its exact form (the interpreter's
IEEE double arithmetic; the compiled kernels use no fastmath, so no contraction changes a bit),
applies the rupture test and adds the loads to the rows in bond order, as the loop before the
blocks did. The compiled loop gathers blocks of bonds, computes them with the series form of the
angles and recomputes exactly those outside the series' range, then scatters with the first end's
loads in registers. The cases make every path run: bonds turned beyond the series' range,
bonds already broken, bonds breaking in the call, densifying bonds, damping, ghost rows, bonds
in sorted (long runs of one first end) and shuffled order, more bonds than one block.
"""
import numpy as np
import pytest

from pardem.engine.bonding import BeamMaterial, make_bonds
from pardem.engine.state import Elements
from pardem.physics import beam
from pardem.physics.quaternion import quat_to_matrix_into

R = 1e-3


def _lattice(damping, seed, n=6):
    """n^3 touching spheres with their face bonds, moved and turned at random: most ends turned
    by under 3 degrees (the series' range), one in ten by up to 40 degrees (outside it)."""
    rng = np.random.default_rng(seed)
    g = np.arange(n) * 2 * R
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    e = Elements.from_spheres(x, R, 1000.0)
    d = np.linalg.norm(x[:, None] - x[None], axis=-1)
    pairs = np.argwhere(np.triu(np.abs(d - 2 * R) < 1e-9 * R))
    b = make_bonds(e, pairs, BeamMaterial(young=1e8, radius_ratio=0.8, poisson=0.3, damping=damping),
                   np.eye(3))
    e.x[:] += rng.normal(scale=0.02 * R, size=e.x.shape)
    e.v[:] = rng.normal(scale=0.1, size=e.v.shape)
    e.w[:] = rng.normal(scale=100.0, size=e.w.shape)
    big = rng.random(len(x)) < 0.1
    angle = np.where(big, np.radians(40.0), np.radians(3.0)) * rng.random(len(x))
    axis = rng.normal(size=(len(x), 3))
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    e.q[:, 0] = np.cos(angle / 2)
    e.q[:, 1:] = np.sin(angle / 2)[:, None] * axis
    for k in range(len(x)):
        quat_to_matrix_into(e.q[k], e.rot[k])
    return e, b, rng


def _gather(g, b, e, k):
    """Column 0 of ``g``: bond ``k``'s state in the ``beam.G_*`` rows."""
    i, j = b.i[k], b.j[k]
    g[beam.G_CHORD:beam.G_CHORD + 3, 0] = e.x[j] - e.x[i]
    g[beam.G_ROT_1:beam.G_ROT_1 + 9, 0] = e.rot[i].ravel()
    g[beam.G_ROT_2:beam.G_ROT_2 + 9, 0] = e.rot[j].ravel()
    for row, vec in ((beam.G_U1, b.u1), (beam.G_P1, b.p1), (beam.G_U2, b.u2), (beam.G_P2, b.p2)):
        g[row:row + 3, 0] = vec[k]
    for row, arr in ((beam.G_L0, b.L0), (beam.G_KA, b.ka), (beam.G_KB, b.kb), (beam.G_KT, b.kt),
                     (beam.G_TAU_A, b.tau_a), (beam.G_TAU_T, b.tau_t)):
        g[row, 0] = arr[k]
    if b.rot_damping.shape[1]:
        g[beam.G_ROT_DAMPING:beam.G_ROT_DAMPING + 4, 0] = b.rot_damping[k]
    g[beam.G_DV:beam.G_DV + 3, 0] = e.v[j] - e.v[i]
    g[beam.G_W_1:beam.G_W_1 + 3, 0] = e.w[i]
    g[beam.G_W_2:beam.G_W_2 + 3, 0] = e.w[j]


def _reference(b, e, damped, breakable, densify, state, plastic):
    """The plain loop: bond by bond, exact angles, loads added in bond order."""
    f = np.zeros_like(e.f)
    t = np.zeros_like(e.t)
    g = np.zeros((beam.GATHER_WIDTH, 1))
    res = np.zeros((beam.RES_WIDTH, 1))
    energy, broken, counted = 0.0, 0, 0
    p0 = b.densify_p0 if densify else 1.0
    for k in range(b.n):
        if breakable and state[k] != 0:
            continue
        i, j = b.i[k], b.j[k]
        _gather(g, b, e, k)
        beam.beam_bond.py_func(g, 0, k, res, True, damped, densify, b.f_yield, plastic, p0,
                               breakable)
        if breakable:
            mode = beam.rupture_mode(res[beam.OUT_AXIAL, 0], res[beam.OUT_SHEAR, 0], b.f_tensile[k],
                                     b.f_shear[k])
            if mode != 0:
                state[k] = mode
                broken += 1
                counted += int(i < e.n_owned)
                continue
        energy += res[beam.OUT_ENERGY, 0]
        for a in range(3):
            f[i, a] += res[a, 0]
            f[j, a] -= res[a, 0]
            t[i, a] += res[3 + a, 0]
            t[j, a] += res[6 + a, 0]
    return f, t, energy, broken, counted


@pytest.mark.parametrize("order", ["sorted", "shuffled"])
@pytest.mark.parametrize("damped,breakable,densify", [(False, False, False), (True, False, False),
                                                      (False, True, False), (True, True, True),
                                                      (False, False, True)])
def test_blocked_loop_is_the_plain_loop_bitwise(damped, breakable, densify, order):
    e, b, rng = _lattice(0.2 if damped else 0.0, seed=7)
    assert b.n > 3 * beam.BLOCK     # several blocks and a partial last one
    if order == "shuffled":
        _permute(b, rng)
    e.n_owned = len(e.x) - 20            # the last rows act as ghosts
    b.damped = damped
    b.breakable = breakable
    if breakable:
        b.f_tensile[:] = np.inf
        b.f_shear[:] = np.inf
        b.state[rng.random(b.n) < 0.1] = 1                   # already broken
        b.f_tensile[rng.random(b.n) < 0.1] = -np.inf         # break now (tension test)
        b.f_shear[rng.random(b.n) < 0.1] = 0.0               # break now (shear test)
    if densify:
        b.densify_p0 = 0.05
        yielding = rng.random(b.n) < 0.5
        b.f_yield[:] = np.where(yielding, 1e-4 * float(np.median(b.ka)) * R, 0.0)
        b.plastic[:] = np.where(yielding & (rng.random(b.n) < 0.5), 1e-3, 0.0)
    state, plastic = b.state.copy(), b.plastic.copy()
    plastic_before = b.plastic.copy()
    f_ref, t_ref, energy_ref, broken_ref, counted_ref = _reference(b, e, damped, breakable, densify,
                                                                   state, plastic)
    e.f[:] = 0.0
    e.t[:] = 0.0
    energy, broken, counted = beam.compute_bonds(b, e)
    np.testing.assert_array_equal(e.f, f_ref)
    np.testing.assert_array_equal(e.t, t_ref)
    assert energy == energy_ref and broken == broken_ref and counted == counted_ref
    np.testing.assert_array_equal(b.state, state)
    np.testing.assert_array_equal(b.plastic, plastic)
    # every path ran: bonds recomputed exactly, broken before, breaking now, yielding
    g = np.zeros((beam.GATHER_WIDTH, 1))
    res = np.zeros((beam.RES_WIDTH, 1))
    redo = 0
    for k in range(b.n):
        _gather(g, b, e, k)
        redo += beam.beam_bond.py_func(g, 0, k, res, False, False, False, b.f_yield,
                                       b.plastic.copy(), 1.0, False) == beam.REDO
    assert 0 < redo < b.n
    if breakable:
        assert broken > 0 and np.any(b.state != 0)
    if densify:
        assert np.any(b.plastic != plastic_before)


def _permute(b, rng):
    """Reorder the bonds (every per-bond array the same way): runs of one first end broken up."""
    perm = rng.permutation(b.n)
    for name, arr in vars(b).items():
        if isinstance(arr, np.ndarray) and arr.ndim >= 1 and arr.shape[0] == b.n:
            setattr(b, name, np.ascontiguousarray(arr[perm]))
