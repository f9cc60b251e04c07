"""Cell list + Verlet list (pardem.physics.neighbours), docs/physics.md section 9.

Every build is compared with a brute-force O(N^2) NumPy oracle (all pairs within R_i + R_j + skin,
minimum image along periodic axes, at least one owned row) as sets of global-id pairs, which must be
exactly equal, and the branch vector ``(x[j] - x[i]) + shift * L`` of each pair must equal the oracle's
minimum-image vector. Configurations: polydisperse radii (+-10 %, +-50 %), dense (overlapping) to very
sparse, N from 10 to 5000, boxes periodic along none, x, xy and xyz, positions left unwrapped by
several periods, owned/ghost splits with shuffled gids, periods of one and two cells, a tiny initial
capacity (overflow and reallocation). Also: pair orientation and uniqueness, determinism, two
"ranks" that split a periodic system agree on their shared pairs bitwise, and the rebuild criterion
(strictly more than skin / 2) together with the Verlet guarantee it protects.
"""
import inspect

import numpy as np
import pytest

from pardem.physics import neighbours
from pardem.physics.neighbours import (VerletList, build_pairs, max_displacement2,
                                       max_displacement_exceeds)

PER = {"none": (False, False, False), "x": (True, False, False), "xy": (True, True, False),
       "xyz": (True, True, True)}


# -- oracle and helpers ---------------------------------------------------------------------------

def oracle(x, radius, gid, n_owned, n_total, skin, lo, hi, periodic):
    """{(gid_low, gid_high): minimum-image vector from the low-gid row to the other} by brute force."""
    x = x[:n_total]
    L = np.where(periodic, np.asarray(hi, float) - np.asarray(lo, float), 0.0)
    out = {}
    block = 512
    for a in range(0, n_total, block):
        rows = np.arange(a, min(a + block, n_total))
        d = x[None, :, :] - x[rows, None, :]                      # [block, n, 3], from i to j
        for k in range(3):
            if periodic[k]:
                d[..., k] -= L[k] * np.round(d[..., k] / L[k])
        hit = np.einsum("ijk,ijk->ij", d, d) < (radius[rows, None] + radius[None, :n_total] + skin) ** 2
        hit &= np.arange(n_total)[None, :] > rows[:, None]       # each unordered pair once
        hit &= (rows[:, None] < n_owned) | (np.arange(n_total)[None, :] < n_owned)
        bi, j = np.nonzero(hit)
        i = rows[bi]
        vec = d[bi, j]
        flip = gid[i] > gid[j]
        vec[flip] *= -1.0
        for gi, gj, v in zip(np.minimum(gid[i], gid[j]), np.maximum(gid[i], gid[j]), vec):
            out[(int(gi), int(gj))] = v
    return out


def found(pairs, shifts, x, gid, lo, hi, periodic):
    """{(gid_i, gid_j): (x[j] - x[i]) + shift * L} of a build; checks orientation and uniqueness."""
    L = np.where(periodic, np.asarray(hi, float) - np.asarray(lo, float), 0.0)
    assert pairs.dtype == np.int32 and shifts.dtype == np.int8
    assert pairs.shape[0] == shifts.shape[0]
    i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
    assert np.all(gid[i] < gid[j]), "pairs must be ordered by gid"
    assert np.all(shifts[:, ~np.asarray(periodic)] == 0), "no shift along non-periodic axes"
    vec = (x[j] - x[i]) + shifts * L
    out = {(int(a), int(b)): v for a, b, v in zip(gid[i], gid[j], vec)}
    assert len(out) == len(pairs), "each pair must appear once"
    return out


def assert_same(got, want, scale):
    assert got.keys() == want.keys(), (f"missing {sorted(want.keys() - got.keys())[:5]}, "
                                       f"extra {sorted(got.keys() - want.keys())[:5]}")
    if want:
        keys = list(want)
        np.testing.assert_allclose(np.array([got[k] for k in keys]), np.array([want[k] for k in keys]),
                                   rtol=0, atol=1e-12 * scale)


def config(rng, n, spread, phi, periodic, unwrap=0, shape=(1.0, 0.8, 1.25), r0=1e-3):
    """n spheres, radii uniform in r0 (1 +- spread), uniform in a box of solid fraction ``phi``
    (overlaps allowed); rows along periodic axes moved by up to +-``unwrap`` periods."""
    radius = r0 * rng.uniform(1.0 - spread, 1.0 + spread, n)
    volume = (4.0 / 3.0 * np.pi * radius**3).sum() / phi
    side = np.asarray(shape) * (volume / np.prod(shape)) ** (1.0 / 3.0)
    lo = rng.uniform(-0.01, 0.01, 3)
    hi = lo + side
    x = lo + rng.uniform(0.0, 1.0, (n, 3)) * side
    if unwrap:
        x += rng.integers(-unwrap, unwrap + 1, (n, 3)) * np.where(periodic, side, 0.0)
    gid = rng.permutation(np.arange(100, 100 + 3 * n, 3)).astype(np.int64)   # shuffled, not rows
    return x, radius, gid, lo, hi


def check(x, radius, gid, n_owned, skin, lo, hi, periodic, **kw):
    """Build with ``build_pairs`` and compare with the oracle; returns (pairs, shifts)."""
    n_total = x.shape[0]
    pairs, shifts = build_pairs(x, radius, gid, n_owned, n_total, skin, lo, hi, periodic, **kw)
    want = oracle(x, radius, gid, n_owned, n_total, skin, lo, hi, periodic)
    got = found(pairs, shifts, x, gid, lo, hi, periodic)
    assert_same(got, want, float(np.max(np.abs(x))) + 1.0)
    i, j = pairs[:, 0], pairs[:, 1]
    assert np.all((i < n_owned) | (j < n_owned)), "ghost-ghost pair"
    return pairs, shifts


# -- comparisons with the oracle ------------------------------------------------------------------

@pytest.mark.parametrize("spread", [0.0, 0.1, 0.5])
@pytest.mark.parametrize("n, phi", [(10, 0.3), (300, 0.6), (2000, 0.64), (2000, 0.05)])
def test_non_periodic_matches_oracle(spread, n, phi):
    rng = np.random.default_rng(n + int(100 * spread))
    per = PER["none"]
    x, radius, gid, lo, hi = config(rng, n, spread, phi, per)
    pairs, _ = check(x, radius, gid, n, 0.2e-3, lo, hi, per)
    if phi > 0.5 and n > 100:
        assert len(pairs) > 2 * n   # dense: the test is not vacuous


@pytest.mark.parametrize("axes", ["x", "xy", "xyz"])
@pytest.mark.parametrize("spread", [0.0, 0.1, 0.5])
def test_periodic_matches_oracle(axes, spread):
    rng = np.random.default_rng(len(axes) + int(10 * spread))
    per = PER[axes]
    x, radius, gid, lo, hi = config(rng, 1500, spread, 0.55, per, unwrap=2)
    pairs, shifts = check(x, radius, gid, 1500, 0.3e-3, lo, hi, per)
    crossing = np.any(shifts != 0, axis=1)
    assert crossing.sum() > 10   # pairs across the periodic faces are exercised


@pytest.mark.parametrize("axes", ["none", "x", "xyz"])
@pytest.mark.parametrize("owned_fraction", [0.0, 0.3, 0.9])
def test_owned_ghost_split(axes, owned_fraction):
    """Only pairs with an owned row; ghosts rows are never scanned, owned-ghost pairs found once."""
    rng = np.random.default_rng(7 + int(10 * owned_fraction))
    per = PER[axes]
    x, radius, gid, lo, hi = config(rng, 1200, 0.5, 0.6, per, unwrap=1)
    n_owned = int(owned_fraction * len(x))
    pairs, _ = check(x, radius, gid, n_owned, 0.2e-3, lo, hi, per)
    if n_owned == 0:
        assert pairs.shape == (0, 2)


def test_large_polydisperse_split():
    rng = np.random.default_rng(5000)
    per = PER["xy"]
    x, radius, gid, lo, hi = config(rng, 5000, 0.5, 0.62, per, unwrap=3)
    check(x, radius, gid, 4000, 0.15e-3, lo, hi, per)


@pytest.mark.parametrize("axes", ["none", "xyz"])
def test_very_sparse(axes):
    """A few elements in a huge box: the cell count is capped (O(N) memory), result unchanged."""
    rng = np.random.default_rng(3)
    per = PER[axes]
    for n, phi in ((10, 1e-6), (400, 1e-5)):
        x, radius, gid, lo, hi = config(rng, n, 0.5, phi, per)
        # plant a few close pairs so that the sparse case still finds something
        x[1] = x[0] + [0.9 * (radius[0] + radius[1]), 0.0, 0.0]
        x[3] = x[2] + np.array([0.0, -0.6, 0.8]) * (radius[2] + radius[3] + 0.4e-3)
        pairs, _ = check(x, radius, gid, n, 0.5e-3, lo, hi, per)
        assert len(pairs) >= 2
        vl = VerletList(0.5e-3, per, lo, hi).rebuild(x, radius, gid, n)
        assert vl.grid.n_cells <= 2 * n + 64


def test_degenerate_inputs():
    rng = np.random.default_rng(11)
    per = PER["none"]
    # one element; no owned element; all centres in a plane and on a line (zero extents)
    x, radius, gid, lo, hi = config(rng, 1, 0.1, 0.1, per)
    assert len(build_pairs(x, radius, gid, 1, 1, 1e-4, lo, hi, per)[0]) == 0
    x, radius, gid, lo, hi = config(rng, 300, 0.3, 0.5, per)
    assert len(build_pairs(x, radius, gid, 0, 300, 1e-4, lo, hi, per)[0]) == 0
    x[:, 2] = 0.5
    check(x, radius, gid, 300, 1e-4, lo, hi, per)
    x[:, 1] = -0.25
    check(x, radius, gid, 200, 1e-4, lo, hi, per)
    # zero skin, and elements exactly on cell faces of a lattice (touching spheres excluded: strict <)
    g = np.arange(6) * 2.0e-3
    xl = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    n = len(xl)
    rl = np.full(n, 1.0e-3)
    check(xl, rl, np.arange(n, dtype=np.int64), n, 1e-9, xl.min(0), xl.max(0) + 2e-3, PER["xyz"])
    check(xl, rl, np.arange(n, dtype=np.int64), n, 0.0, xl.min(0), xl.max(0) + 2e-3, PER["xyz"])


def test_bad_inputs_raise():
    rng = np.random.default_rng(12)
    x, radius, gid, lo, hi = config(rng, 50, 0.1, 0.3, PER["xyz"])
    bad = x.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        build_pairs(bad, radius, gid, 50, 50, 1e-4, lo, hi, PER["none"])
    far = x.copy()
    far[3, 0] += 64 * (hi[0] - lo[0])
    with pytest.raises(ValueError, match="periods outside"):
        build_pairs(far, radius, gid, 50, 50, 1e-4, lo, hi, PER["x"])
    with pytest.raises(ValueError, match="n_owned"):
        build_pairs(x, radius, gid, 60, 50, 1e-4, lo, hi, PER["none"])


# -- periodic images -------------------------------------------------------------------------------

def test_period_too_short_raises():
    rng = np.random.default_rng(4)
    x, radius, gid, lo, hi = config(rng, 100, 0.1, 0.3, PER["xyz"])
    cut = 2.0 * radius.max() + 1e-4
    hi = hi.copy()
    hi[1] = lo[1] + 1.99 * cut
    with pytest.raises(ValueError, match="periodic axis y"):
        build_pairs(x, radius, gid, 100, 100, 1e-4, lo, hi, PER["xy"])
    build_pairs(x, radius, gid, 100, 100, 1e-4, lo, hi, PER["x"])   # y not periodic: fine


@pytest.mark.parametrize("max_cells", [1, 2, 8, 27, None])
def test_short_periods_one_or_two_cells(max_cells):
    """Periods of 1 and 2 cells (the stencil visits one cell under several shifts) and coarsened
    grids give the oracle's result with the minimum image."""
    rng = np.random.default_rng(21)
    per = PER["xyz"]
    n = 120
    radius = 1e-3 * rng.uniform(0.5, 1.5, n)
    skin = 0.2e-3
    cut = 2.0 * radius.max() + skin
    lo = np.zeros(3)
    hi = np.array([2.0, 2.5, 3.5]) * cut     # 2, 2 and 3 cells of at least cut
    x = lo + rng.uniform(0.0, 1.0, (n, 3)) * hi + rng.integers(-1, 2, (n, 3)) * hi
    gid = rng.permutation(n).astype(np.int64)
    pairs, _ = check(x, radius, gid, 90, skin, lo, hi, per, max_cells=max_cells)
    assert len(pairs) > n


def test_unwrapped_positions_give_same_pairs():
    """Moving rows by whole periods changes the shifts, never the pairs or the branch vectors."""
    rng = np.random.default_rng(8)
    per = PER["xyz"]
    x, radius, gid, lo, hi = config(rng, 800, 0.3, 0.5, per)
    p0, s0 = build_pairs(x, radius, gid, 800, 800, 0.2e-3, lo, hi, per)
    moved = x + rng.integers(-5, 6, x.shape) * (hi - lo)
    p1, s1 = build_pairs(moved, radius, gid, 800, 800, 0.2e-3, lo, hi, per)
    a = found(p0, s0, x, gid, lo, hi, per)
    b = found(p1, s1, moved, gid, lo, hi, per)
    assert_same(b, a, 10.0)
    # the vector with the shift is the minimum image: no component beyond half a period
    v = np.array(list(b.values()))
    assert np.all(np.abs(v) <= 0.5 * (hi - lo))


# -- buffers, determinism, ranks ------------------------------------------------------------------

def test_overflow_reallocates_and_gives_same_result():
    rng = np.random.default_rng(9)
    per = PER["xy"]
    x, radius, gid, lo, hi = config(rng, 1000, 0.5, 0.6, per, unwrap=1)
    ref = build_pairs(x, radius, gid, 700, 1000, 0.2e-3, lo, hi, per)
    for cap in (1, 17, 1000):
        got = build_pairs(x, radius, gid, 700, 1000, 0.2e-3, lo, hi, per, capacity=cap)
        np.testing.assert_array_equal(got[0], ref[0])
        np.testing.assert_array_equal(got[1], ref[1])
    vl = VerletList(0.2e-3, per, lo, hi, capacity_per_row=0.0)   # starts at 16 pairs
    vl.rebuild(x, radius, gid, 700, 1000)
    assert vl.reallocations == 1 and vl.capacity >= vl.n_pairs
    np.testing.assert_array_equal(vl.pairs, ref[0])
    np.testing.assert_array_equal(vl.shifts, ref[1])
    vl.rebuild(x, radius, gid, 700, 1000)   # buffers kept: no new overflow
    assert vl.reallocations == 1 and vl.builds == 2
    np.testing.assert_array_equal(vl.pairs, ref[0])


def test_kernel_arrays():
    rng = np.random.default_rng(16)
    for axes in ("none", "xz"):
        per = PER.get(axes, (True, False, True))
        x, radius, gid, lo, hi = config(rng, 600, 0.3, 0.6, per, unwrap=1)
        vl = VerletList(0.2e-3, per, lo, hi).rebuild(x, radius, gid, 600)
        i, j, shift = vl.kernel_arrays()
        assert i.flags.c_contiguous and j.flags.c_contiguous and i.dtype == np.int32
        np.testing.assert_array_equal(np.stack([i, j], 1), vl.pairs)
        if axes == "none":
            assert shift is None
        else:
            assert shift.dtype == np.float64 and shift.shape == (len(i), 3)
            np.testing.assert_array_equal(shift, vl.shifts * np.where(per, hi - lo, 0.0))


def test_deterministic():
    rng = np.random.default_rng(10)
    per = PER["xyz"]
    x, radius, gid, lo, hi = config(rng, 1500, 0.5, 0.6, per, unwrap=1)
    a = build_pairs(x, radius, gid, 1000, 1500, 0.2e-3, lo, hi, per)
    b = build_pairs(x.copy(), radius.copy(), gid.copy(), 1000, 1500, 0.2e-3, lo, hi, per, capacity=3)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_two_ranks_agree_on_shared_pairs():
    """A periodic system cut into two slabs along x: each "rank" owns one slab and holds the other
    as ghosts, in its own row order. The union of the pairs is the one-rank list and every pair seen
    by both ranks has the same orientation and the same shift."""
    rng = np.random.default_rng(13)
    per = PER["xyz"]
    x, radius, gid, lo, hi = config(rng, 2000, 0.5, 0.6, per, unwrap=1)
    skin = 0.2e-3
    one = found(*build_pairs(x, radius, gid, 2000, 2000, skin, lo, hi, per), x, gid, lo, hi, per)
    wrapped_x = lo[0] + np.mod(x[:, 0] - lo[0], hi[0] - lo[0])
    left = wrapped_x < lo[0] + 0.4 * (hi[0] - lo[0])
    ranks = []
    for mine in (left, ~left):
        rows = np.concatenate([rng.permutation(np.nonzero(mine)[0]), rng.permutation(np.nonzero(~mine)[0])])
        p, s = build_pairs(x[rows], radius[rows], gid[rows], int(mine.sum()), len(rows), skin, lo, hi, per)
        g = gid[rows]
        ranks.append({(int(g[a]), int(g[b])): tuple(t) for (a, b), t in zip(p, s)})
    union = ranks[0].keys() | ranks[1].keys()
    assert union == one.keys()
    shared = ranks[0].keys() & ranks[1].keys()
    assert len(shared) > 20
    assert all(ranks[0][k] == ranks[1][k] for k in shared)


# -- rebuild criterion ----------------------------------------------------------------------------

def test_rebuild_criterion_is_strictly_half_skin():
    rng = np.random.default_rng(14)
    per = PER["xyz"]
    x, radius, gid, lo, hi = config(rng, 400, 0.3, 0.5, per)
    skin = 0.4e-3
    vl = VerletList(skin, per, lo, hi)
    assert vl.needs_rebuild(x)   # never built
    vl.rebuild(x, radius, gid, 300, 400)
    assert not vl.needs_rebuild(x)
    for row in (0, 299, 350):    # an owned row and a ghost row
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        for factor, expect in ((1.0 - 1e-6, False), (1.0 + 1e-6, True)):
            y = x.copy()
            y[row] += factor * 0.5 * skin * u
            assert vl.needs_rebuild(y) is expect
            assert max_displacement_exceeds(y, vl.x_build, 400, 0.5 * skin) is expect
            assert np.isclose(np.sqrt(vl.max_displacement2(y)), factor * 0.5 * skin, rtol=1e-12)
    # all rows moving just under the limit: still valid
    u = rng.normal(size=x.shape)
    u *= (0.5 * skin * 0.999) / np.linalg.norm(u, axis=1)[:, None]
    assert not vl.needs_rebuild(x + u)
    y = x.copy()
    y[5, 0] = np.nan
    assert vl.needs_rebuild(y) and max_displacement2(y, vl.x_build, 400) == np.inf


def test_verlet_guarantee_under_half_skin():
    """After arbitrary moves of less than skin / 2 each, every pair now in contact (or within any
    distance the list was built for, minus the skin) is already in the list."""
    rng = np.random.default_rng(15)
    per = PER["xy"]
    x, radius, gid, lo, hi = config(rng, 1500, 0.5, 0.6, per)
    skin = 0.3e-3
    vl = VerletList(skin, per, lo, hi).rebuild(x, radius, gid, 1000, 1500)
    listed = set(found(vl.pairs, vl.shifts, x, gid, lo, hi, per))
    for _ in range(3):
        u = rng.normal(size=x.shape)
        u *= (0.5 * skin * rng.uniform(0.0, 0.9999, len(x)))[:, None] / np.linalg.norm(u, axis=1)[:, None]
        y = x + u
        assert not vl.needs_rebuild(y)
        contacts = oracle(y, radius, gid, 1000, 1500, 0.0, lo, hi, per)
        assert len(contacts) > 500 and set(contacts) <= listed
        # and the stored shifts still give the minimum image at the new positions
        L = np.where(per, hi - lo, 0.0)
        index = {g: r for r, g in enumerate(gid)}
        for (a, b), v in list(contacts.items())[:200]:
            k = np.nonzero((gid[vl.pairs[:, 0]] == a) & (gid[vl.pairs[:, 1]] == b))[0][0]
            np.testing.assert_allclose((y[index[b]] - y[index[a]]) + vl.shifts[k] * L, v, atol=1e-15)


def test_kernels_stay_free_of_mpi_and_files():
    src = inspect.getsource(neighbours)
    assert "mpi4py" not in src and "h5py" not in src and "open(" not in src
