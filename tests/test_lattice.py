"""Ordered cubic lattice (pardem.domains.ordered), docs/physics.md section 4.

The W cube (10 mm, R = 0.2381 mm) has 21^3 elements and 3 * 21 * 21 * 20 bonds; bonds join face
neighbours at distance 2R, without duplicates, with the element degrees a brute-force count gives;
small boxes (straight and tilted) match an O(N^2) neighbour search at distance 2R; tilted lattices
keep every centre at least R inside the box, run their bonds along the tilted frame axes, and
contain every site of their (infinite) grid that fits in the box.
"""
import numpy as np
import pytest

from pardem.domains.ordered import ordered_lattice
from pardem.physics.anisotropy import lrt_frame

R_W = 0.2381e-3


def pair_set(pairs):
    return {(int(min(a, b)), int(max(a, b))) for a, b in pairs}


def brute_neighbours(pos, dist, rtol=1e-6):
    d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=2)
    i, j = np.nonzero(np.abs(d - dist) < rtol * dist)
    return {(int(a), int(b)) for a, b in zip(i, j) if a < b}


@pytest.fixture(scope="module")
def w_cube():
    return ordered_lattice([0.01] * 3, R_W)


def test_w_cube_counts(w_cube):
    pos, pairs, frame = w_cube
    assert len(pos) == 21**3 == 9261
    assert len(pairs) == 3 * 21 * 21 * 20 == 26460
    np.testing.assert_allclose(frame, np.eye(3), atol=1e-15)
    # no duplicates, no self bonds
    assert len(pair_set(pairs)) == len(pairs)
    assert np.all(pairs[:, 0] != pairs[:, 1])


def test_w_cube_geometry(w_cube):
    pos, pairs, _ = w_cube
    L = np.linalg.norm(pos[pairs[:, 1]] - pos[pairs[:, 0]], axis=1)
    np.testing.assert_allclose(L, 2 * R_W, rtol=1e-12)
    # centres on the grid R + 2R k, k = 0..20; spheres inside the box within 1 % of R
    # (21 diameters are 10.0002 mm: W's cube is 0.2 um larger than 10 mm)
    k = (pos - R_W) / (2 * R_W)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    assert np.round(k).min() == 0 and np.round(k).max() == 20
    assert pos.min() >= 0.99 * R_W and pos.max() <= 0.01 - 0.99 * R_W
    # degree of each element: 2 per axis, minus one per boundary face it lies on
    ki = np.round(k).astype(int)
    expected = (2 * 3 - (ki == 0).sum(axis=1) - (ki == 20).sum(axis=1))
    degree = np.bincount(pairs.ravel(), minlength=len(pos))
    np.testing.assert_array_equal(degree, expected)
    interior = np.all((ki > 0) & (ki < 20), axis=1)
    assert interior.sum() == 19**3 and np.all(degree[interior] == 6)
    # solid fraction of touching spheres on a cubic grid: pi / 6
    phi = len(pos) * 4 / 3 * np.pi * R_W**3 / (21 * 2 * R_W) ** 3
    assert phi == pytest.approx(np.pi / 6, rel=1e-12)


@pytest.mark.parametrize("box", [[0.004, 0.003, 0.0025], [0.002, 0.002, 0.002], [0.0045, 0.001, 0.003]])
def test_small_box_matches_brute_force(box):
    R = 2.5e-4
    pos, pairs, _ = ordered_lattice(box, R)
    counts = np.floor(np.asarray(box) / (2 * R) + 1e-9).astype(int)
    assert len(pos) == np.prod(counts)
    assert pair_set(pairs) == brute_neighbours(pos, 2 * R)
    assert len(pair_set(pairs)) == len(pairs)


@pytest.mark.parametrize("tilt", [30.0, -17.0, 45.0])
def test_tilted_lattice(tilt):
    R = 2.5e-4
    box = np.array([0.004, 0.0035, 0.003])
    pos, pairs, frame = ordered_lattice(box, R, tilt)
    np.testing.assert_allclose(frame, lrt_frame(tilt), atol=1e-15)
    assert len(pos) > 50
    # every centre lies R inside the box (tolerance 1 % of R)
    assert np.all(pos >= R - 0.01 * R) and np.all(pos <= box - R + 0.01 * R)
    # bonds: length 2R, along +-L, +-R or +-T of the tilted frame, face neighbours only
    d = pos[pairs[:, 1]] - pos[pairs[:, 0]]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 2 * R, rtol=1e-12)
    c = np.abs(d / (2 * R) @ frame.T)
    np.testing.assert_allclose(np.sort(c, axis=1), np.tile([0, 0, 1], (len(d), 1)), atol=1e-12)
    assert pair_set(pairs) == brute_neighbours(pos, 2 * R)
    # all centres on one grid of spacing 2R along the frame axes
    k = (pos - pos[0]) @ frame.T / (2 * R)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    # and no site of that grid that fits in the box is missing
    span = int(np.ceil(np.linalg.norm(box) / (2 * R))) + 2
    g = np.arange(-span, span + 1)
    idx = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    sites = pos[0] + 2 * R * idx @ frame
    fits = np.all((sites >= R + 1e-9 * R) & (sites <= box - R - 1e-9 * R), axis=1)
    kept = {tuple(r) for r in np.round(k).astype(int)}
    assert {tuple(r) for r in idx[fits]} <= kept
