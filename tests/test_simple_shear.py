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
    L = np.array([1.0, 1.0, 0.0])
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
