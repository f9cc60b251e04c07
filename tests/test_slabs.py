"""Slab cuts without MPI: ownership by (coordinate, gid) and the bisection's balance."""
import numpy as np
import pytest

from pardem.parallel.slabs import Slabs, _from_ordered_int, _ordered_int, choose_axis, imbalance


def owner_brute(slabs, s, gid):
    """The definition: count the cuts (c, g) with (s, gid) >= (c, g) lexicographically."""
    s, g = np.asarray(s)[:, None], np.asarray(gid)[:, None]
    return ((s > slabs.cut_s) | ((s == slabs.cut_s) & (g >= slabs.cut_g))).sum(axis=1)


@pytest.mark.parametrize("seed", range(5))
def test_owner_matches_the_definition_with_ties(seed):
    rng = np.random.default_rng(seed)
    planes = rng.choice(np.linspace(-1, 1, 7), size=5000)          # many keys on cut coordinates
    gid = rng.permutation(5000)
    cut_s = np.sort(rng.choice(np.concatenate([np.linspace(-1, 1, 7), rng.uniform(-1, 1, 4)]), 9))
    cut_g = np.zeros(9, dtype=np.int64)
    for c in np.unique(cut_s):                 # cut gids sorted within equal coordinates
        k = np.nonzero(cut_s == c)[0]
        cut_g[k] = np.sort(rng.integers(0, 5000, len(k)))
    slabs = Slabs(0, cut_s, cut_g)
    # the keys themselves include every cut key exactly (an element sitting on its cut, as the
    # bisection produces) and its neighbours in gid
    planes = np.concatenate([planes, cut_s, cut_s, cut_s])
    gid = np.concatenate([gid, cut_g, cut_g - 1, cut_g + 1])
    np.testing.assert_array_equal(slabs.owner(planes, gid), owner_brute(slabs, planes, gid))


def test_ordered_int_preserves_order():
    x = np.array([-np.inf, -3.5, -1e-300, -0.0, 0.0, 1e-300, 2.0, np.inf])
    o = _ordered_int(x)
    assert np.all(np.diff(o) >= 0) and o[3] == o[4] == 0
    np.testing.assert_array_equal(_from_ordered_int(o)[[0, 1, 2, 5, 6, 7]], x[[0, 1, 2, 5, 6, 7]])


def test_imbalance_and_axis_choice():
    assert imbalance([100, 100]) == 0.0 and imbalance([110, 100]) == pytest.approx(0.1)
    assert imbalance([0, 5]) == float("inf")
    assert choose_axis([1.0, 1.0, 1.0], avoid=0) == 1
    assert choose_axis([1.0, 2.0, 1.0], avoid=1) == 1
