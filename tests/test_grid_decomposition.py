"""The brick grid's bookkeeping (``pardem.parallel.grid``) against brute force, without MPI.

Every rank of a grid is simulated in this one process: the staged exchange runs rank by rank,
stage by stage, over the same arrays an MPI run would send (``GridDecomposition.staged_ghosts``);
the distributed bisection of the balance is run by one thread per simulated rank whose sums over
ranks meet at a barrier. The references are computed here independently: all pairs by minimum
image, and every periodic image tested against every rank's grown subdomain.
"""
import itertools
import json
import os
import shutil
import subprocess
import sys
import threading

import numpy as np
import pytest

from pardem.errors import DecompositionError
from pardem.parallel.grid import (GridDecomposition, check_grid, choose_grid, imbalance, rank_loads,
                                  time_weights)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# -- point sets ----------------------------------------------------------------------------------

def uniform(rng, n, L, dim):
    x = rng.uniform(0.0, 1.0, (n, 3)) * L
    if dim == 2:
        x[:, 2] = 0.0
    return x


def clustered(rng, n, L, dim):
    """Three tight blobs and a thin uniform gas: most subdomains nearly empty, a few crowded."""
    centres = rng.uniform(0.2, 0.8, (3, 3)) * L
    x = centres[rng.integers(0, 3, n)] + rng.normal(0.0, 0.08, (n, 3)) * L
    gas = rng.uniform(0.0, 1.0, (n // 5, 3)) * L
    x = np.concatenate([x, gas])
    x = np.clip(x, 0.0, np.nextafter(L, 0.0))     # inside the box (open axes keep them there too)
    if dim == 2:
        x[:, 2] = 0.0
    return x


def pour(rng, n, L, dim, axis=2, dense=0.8):
    """``dense`` of the points in the lowest fifth of the box along ``axis``, the rest above."""
    x = rng.uniform(0.0, 1.0, (n, 3)) * L
    low = rng.random(n) < dense
    x[:, axis] = np.where(low, rng.uniform(0.0, 0.2, n), rng.uniform(0.2, 1.0, n)) * L[axis]
    if dim == 2:
        x[:, 2] = 0.0
    return x


def lattice(L, step):
    """A cubic lattice including points exactly on the even cuts (ties of the ownership rule)."""
    axes = [np.arange(0.0, L[a] - 1e-12, step) for a in range(3)]
    return np.array(list(itertools.product(*axes)))


# -- independent references ------------------------------------------------------------------------

def min_image_pairs(x, L, periodic, reach):
    """All pairs (i, j, shift) with |x_j + shift L - x_i| < reach, the nearest image (i < j)."""
    d = x[None, :, :] - x[:, None, :]
    shift = np.where(periodic, -np.round(d / L), 0.0).astype(np.int64)
    d = d + shift * L
    i, j = np.nonzero(np.triu(np.sum(d * d, axis=2) < reach * reach, k=1))
    return i, j, shift[i, j]


def extended_box_ghosts(g, rank, x, owner, r):
    """The definition: every image of every point inside the rank's subdomain grown by r, except
    the rank's own points unshifted."""
    lo, hi = g.bounds(rank)
    out = set()
    images = itertools.product(*[(-1, 0, 1) if g.periodic[a] else (0,) for a in range(3)])
    for s in images:
        y = x + np.array(s) * g.length
        inside = np.all((y >= lo - r) & (y < hi + r), axis=1)
        for p in np.nonzero(inside)[0]:
            if s != (0, 0, 0) or owner[p] != rank:
                out.add((int(p), s))
    return out


def as_set(points, shifts):
    return {(int(p), tuple(int(v) for v in s)) for p, s in zip(points, shifts)}


CASES = [  # grid, periodic, dimension
    ((2, 2, 1), (True, True, False), 2),
    ((3, 2, 1), (False, True, False), 2),
    ((2, 2, 1), (True, True, True), 3),
    ((1, 2, 2), (True, False, True), 3),
    ((2, 2, 2), (True, True, True), 3),
    ((2, 2, 2), (False, False, False), 3),
    ((3, 1, 2), (True, True, False), 3),
    ((3, 1, 2), (False, True, True), 3),
    ((1, 1, 3), (True, True, True), 3),
]
SETS = {"uniform": uniform, "clustered": clustered, "pour": pour}


def box(dim):
    L = np.array([1.0, 0.8, 0.9])
    if dim == 2:
        L[2] = 0.05
    return L


@pytest.mark.parametrize("grid, periodic, dim", CASES)
@pytest.mark.parametrize("kind", sorted(SETS))
def test_every_pair_in_range_is_held_by_the_owner_of_each_end(grid, periodic, dim, kind):
    rng = np.random.default_rng(sum(grid) * 7 + dim + len(kind))
    L = box(dim)
    x = SETS[kind](rng, 400, L, dim)
    per = np.array(periodic)
    if dim == 2:
        per[2] = False
    r = 0.12            # interaction range + skin [m]; every subdomain below is at least this wide
    g = GridDecomposition(grid, [0, 0, 0], L, per)
    if kind != "uniform":
        # moved cuts (balance shift), kept at least r wide for the one-hop stages
        g = g.balanced(x, min_width=r)
    ghosts, messages = g.staged_ghosts(x, r)
    owner = g.owner(x)

    # owners partition the points, and each point lies inside its owner's subdomain
    assert np.bincount(owner, minlength=g.size).sum() == len(x)
    inside = np.array([[np.all((x[p] >= g.bounds(q)[0]) & (x[p] < g.bounds(q)[1])) for q in range(g.size)]
                       for p in range(len(x))])
    np.testing.assert_array_equal(inside.sum(axis=1), 1)
    np.testing.assert_array_equal(np.argmax(inside, axis=1), owner)

    held = {}
    for q in range(g.size):
        pts, shs = ghosts[q]
        entries = [(int(p), tuple(int(v) for v in s)) for p, s in zip(pts, shs)]
        assert len(entries) == len(set(entries)), f"rank {q} holds a ghost twice"
        own = set(np.nonzero(owner == q)[0].tolist())
        assert not any(s == (0, 0, 0) and p in own for p, s in entries), "an owned row came back as a ghost"
        # the staged selection (6 messages) is the direct 26-neighbour one and the definition
        assert set(entries) == as_set(*g.stencil_ghosts(q, x, r))
        assert set(entries) == extended_box_ghosts(g, q, x, owner, r)
        held[q] = set(entries) | {(p, (0, 0, 0)) for p in own}

    i, j, s = min_image_pairs(x, L, per, r)
    assert len(i) > 50     # the check is not empty
    for a, b, sh in zip(i, j, s):
        assert (int(b), tuple(int(v) for v in sh)) in held[owner[a]], f"pair ({a}, {b}) missed on rank {owner[a]}"
        assert (int(a), tuple(int(-v) for v in sh)) in held[owner[b]], f"pair ({b}, {a}) missed on rank {owner[b]}"

    # at most 2 messages (or self copies) per stage and rank: 6 carry the 26 neighbours
    per_rank = np.bincount([m[1] for m in messages], minlength=g.size)
    assert per_rank.max() <= 2 * sum(1 for a in range(3) if grid[a] > 1 or per[a])


def test_points_on_the_cuts_and_the_stencil_geometry():
    L = np.array([1.0, 1.0, 1.0])
    x = lattice(L, 0.125)      # planes at 0, 0.125, ..., 0.5: points exactly on the cuts
    for per in [(True, True, True), (False, True, False)]:
        g = GridDecomposition((2, 4, 2), [0, 0, 0], L, per)
        owner = g.owner(x)
        idx = g.indices(x)
        for a in range(3):     # a point on a cut belongs to the subdomain above it
            np.testing.assert_array_equal(idx[:, a], np.floor(x[:, a] / (L[a] / g.shape[a]) + 1e-9))
        assert [g.rank_of(g.index_of(r)) for r in range(g.size)] == list(range(g.size))
        for rank in range(g.size):
            lo, hi = g.bounds(rank)
            st = g.stencil(rank)
            assert len({(nb, tuple(s)) for _, nb, s in st}) == len(st)
            n_expected = np.prod([3 if (per[a] or 0 < g.index_of(rank)[a] < g.shape[a] - 1) else 2
                                  for a in range(3)]) - 1
            assert len(st) == n_expected
            for off, nb, s in st:      # the neighbour's box, at its image, touches ours on that side
                nlo, nhi = g.bounds(nb)
                nlo, nhi = nlo + s * L, nhi + s * L
                for a in range(3):
                    if off[a] > 0:
                        assert nlo[a] == pytest.approx(hi[a])
                    elif off[a] < 0:
                        assert nhi[a] == pytest.approx(lo[a])
                    else:
                        assert (nlo[a], nhi[a]) == (lo[a], hi[a])
        assert np.all(np.bincount(owner, minlength=16) == len(x) // 16)


def test_a_subdomain_thinner_than_the_ghost_range_is_refused():
    g = GridDecomposition((4, 1, 1), [0, 0, 0], [1, 1, 1], (True, True, True))
    with pytest.raises(DecompositionError, match=r"0\.25 m thin.*\[parallel\] grid"):
        g.check_widths(0.3)
    g.check_widths(0.25)
    # open axis: the two outer subdomains are unbounded, only the inner ones count
    g = GridDecomposition((3, 1, 1), [0, 0, 0], [1, 1, 1], (False, True, True), cuts=[[0.45, 0.55], [], []])
    with pytest.raises(DecompositionError, match="thin"):
        g.check_widths(0.2)
    GridDecomposition((2, 1, 1), [0, 0, 0], [1, 1, 1], (False, True, True), cuts=[[0.05], [], []]).check_widths(0.2)


# -- choose_grid -----------------------------------------------------------------------------------

@pytest.mark.parametrize("n, L, per, dim, expected", [
    # cube: surfaces (2,2,2) 3/4, (1,2,4) 7/8, (1,1,8) 5/4
    (8, [1, 1, 1], (True,) * 3, 3, (2, 2, 2)),
    # long box: (4,1,1) 3, (2,2,1) 3.5, (1,2,2) 4.25, (1,4,1) 5.25 (edges 4 x 1 x 1)
    (4, [4, 1, 1], (True,) * 3, 3, (4, 1, 1)),
    # cube, 2 ranks: all surfaces 2.5, all periodic: LAMMPS' loop order gives 1 x 1 x 2
    (2, [1, 1, 1], (True, True, True), 3, (1, 1, 2)),
    # the same with x open: cutting it leaves one exchanging face per rank, not two
    (2, [1, 1, 1], (False, True, True), 3, (2, 1, 1)),
    # 2D 2 x 1: perimeters (4,2) 1, (8,1) 1.25, (2,4) 1.25, (1,8) 2.125; z never cut
    (8, [2, 1, 0.01], (True, True, False), 2, (4, 2, 1)),
    # 2D square, 6 ranks: (2,3) and (3,2) tie in perimeter and busiest face; smallest px
    (6, [1, 1, 0.01], (False, False, False), 2, (2, 3, 1)),
    # a prime number of ranks in a cube: one axis, LAMMPS order
    (7, [1, 1, 1], (True,) * 3, 3, (1, 1, 7)),
    # 64 ranks, 4 x 2 x 1 box: (8,4,2) makes cubes of 0.5, surface 0.75; (16,2,2), (8,2,4), (4,4,4)
    # and (16,4,1) all have 0.875
    (64, [4, 2, 1], (True,) * 3, 3, (8, 4, 2)),
    # units do not matter (a millimetre box, the same shape)
    (64, [4e-3, 2e-3, 1e-3], (True,) * 3, 3, (8, 4, 2)),
])
def test_choose_grid_minimises_the_subdomain_surface(n, L, per, dim, expected):
    assert choose_grid(n, L, per, dim) == expected


def test_choose_grid_brute_surface():
    """The choice has the smallest surface of all factorisations (listed here independently)."""
    rng = np.random.default_rng(3)
    for _ in range(40):
        n = int(rng.integers(1, 97))
        L = rng.uniform(0.5, 5.0, 3)
        p = choose_grid(n, L, (True,) * 3, 3)
        facts = [(a, b, n // a // b) for a in range(1, n + 1) for b in range(1, n + 1) if n % (a * b) == 0]
        surf = lambda q: (L[0] * L[1] / q[0] / q[1] + L[0] * L[2] / q[0] / q[2] + L[1] * L[2] / q[1] / q[2])
        assert np.prod(p) == n and surf(p) <= min(surf(q) for q in facts) * (1 + 1e-12)


def test_choose_grid_min_width_and_explicit_grids():
    assert choose_grid(8, [1, 1, 1], min_width=0.3) == (2, 2, 2)
    with pytest.raises(ValueError, match=r"\[parallel\] grid \(Decomposition.grid\).*0.6 m wide"):
        choose_grid(8, [1, 1, 1], min_width=0.6)
    assert choose_grid(8, [1, 1, 1], grid=[1, 2, 4]) == (1, 2, 4)
    assert check_grid(np.array([2, 2, 1]), 4, 2) == (2, 2, 1)
    for bad, n, dim, what in [([2, 2, 3], 8, 3, "product 12 is not the 8 ranks"),
                              ([2, 2, 2], 8, 2, "pz = 2 in 2D"),
                              ([0, 8, 1], 0 + 8, 3, "integers >= 1"),
                              ([2.0, 2, 2], 8, 3, "integers >= 1"),
                              ([True, 2, 4], 8, 3, "integers >= 1"),
                              ("2x2x2", 8, 3, "integers >= 1"),
                              ([2, 4], 8, 3, "integers >= 1")]:
        with pytest.raises(ValueError, match=r"\[parallel\] grid \(Decomposition.grid\)") as err:
            choose_grid(n, [1, 1, 1], dimension=dim, grid=bad)
        assert what in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(ValueError, match="n_ranks"):
        choose_grid(0, [1, 1, 1])
    with pytest.raises(ValueError, match="box_lengths"):
        choose_grid(4, [1, -1, 1])
    with pytest.raises(ValueError, match="dimension"):
        choose_grid(4, [1, 1, 1], dimension=1)


# -- balance -----------------------------------------------------------------------------------------

TARGET = 0.05   # the stated imbalance target (as the slabs' default threshold)


@pytest.mark.parametrize("grid, axis", [((2, 2, 2), 2), ((3, 1, 2), 2), ((1, 2, 2), 2), ((2, 2, 1), 0),
                                        ((4, 2, 1), 0)])
def test_balance_shift_evens_a_pour(grid, axis):
    """80 % of 200,000 points in the lowest fifth along ``axis``: even cuts leave the ranks far apart;
    after one balance every slice holds exactly its share along each axis (distinct coordinates),
    and every rank is within the target: the load is a product of per-axis densities, so only
    sampling remains, a relative sd of sqrt(P / N) = 0.6 % per rank at P = 8 (max / min - 1 about
    4 sd = 2.5 %)."""
    rng = np.random.default_rng(11)
    L = np.array([1.0, 1.0, 1.0])
    x = pour(rng, 200_000, L, 3, axis=axis)
    g = GridDecomposition(grid, [0, 0, 0], L, (True, True, False))
    assert imbalance(rank_loads(g, x)) > 1.0
    b = g.balanced(x)
    idx = b.indices(x)
    for a in range(3):
        p = grid[a]
        expected = np.diff(np.round(np.arange(p + 1) / p * len(x)))
        np.testing.assert_array_equal(np.bincount(idx[:, a], minlength=p), expected)
    assert imbalance(rank_loads(b, x)) <= TARGET


def test_balance_with_ranks_in_threads_equals_one_process():
    """The bisection's sums over ranks: 6 simulated ranks in threads, each with a random share of
    the elements, meeting at a barrier for every sum, find the same cuts as one process."""
    rng = np.random.default_rng(5)
    L = np.array([1.0, 1.0, 1.0])
    x = pour(rng, 30_000, L, 3)
    g = GridDecomposition((3, 1, 2), [0, 0, 0], L, (True, True, True))
    P = 6
    part = rng.integers(0, P, len(x))
    slots, results = [None] * P, [None] * P
    barrier = threading.Barrier(P)

    def allsum_of(k):
        def allsum(v):
            slots[k] = np.asarray(v, dtype=float)
            barrier.wait()
            total = np.sum(slots, axis=0)
            barrier.wait()
            return total
        return allsum

    def run(k):
        results[k] = g.balanced(x[part == k], allsum=allsum_of(k))

    threads = [threading.Thread(target=run, args=(k,)) for k in range(P)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    one = g.balanced(x)
    for res in results:
        for a in range(3):
            np.testing.assert_array_equal(res.cuts[a], one.cuts[a])


def test_balance_by_measured_time_converges():
    """Grains of the dense bed cost 3 times more (more contacts): balancing counts leaves the
    bottom ranks slow; balancing the measured seconds (LAMMPS ``weight time``), as a run does at
    each interval, reaches the target within a few re-cuts."""
    rng = np.random.default_rng(2)
    L = np.array([1.0, 1.0, 1.0])
    x = pour(rng, 100_000, L, 3)
    cost = np.where(x[:, 2] < 0.2, 3.0, 1.0)      # seconds per element (any unit)
    g = GridDecomposition((2, 2, 2), [0, 0, 0], L, (True, True, False)).balanced(x)
    first = imbalance(rank_loads(g, x, cost))
    assert first > 0.2
    history = [first]
    for _ in range(8):
        owner = g.owner(x)
        seconds = np.bincount(owner, weights=cost, minlength=g.size)
        counts = np.bincount(owner, minlength=g.size)
        w = np.empty(len(x))
        for r in range(g.size):       # each rank weighs its own elements by its time
            w[owner == r] = time_weights(seconds[r], counts[r])
        g = g.balanced(x, w)
        history.append(imbalance(rank_loads(g, x, cost)))
        if history[-1] <= TARGET:
            break
    assert history[-1] <= TARGET, history


def test_min_width_widens_thin_slices_and_follow_cell_keeps_owners():
    rng = np.random.default_rng(4)
    L = np.array([1.0, 1.0, 1.0])
    x = pour(rng, 20_000, L, 3, dense=0.95)
    g = GridDecomposition((1, 1, 4), [0, 0, 0], L, (True, True, True))
    thin = g.balanced(x)
    assert thin.widths(2).min() < 0.1
    wide = g.balanced(x, min_width=0.1)
    assert wide.widths(2).min() >= 0.1 - 1e-12
    assert np.all(np.diff(wide.cuts[2]) > 0)
    with pytest.raises(DecompositionError, match="do not fit"):
        g.balanced(x, min_width=0.3)
    # an affine step of the cell maps cuts and positions alike: every owner stays
    factor = np.array([1.01, 0.98, 0.95])
    owner = wide.owner(x)
    wide.follow_cell(factor)
    np.testing.assert_array_equal(wide.owner(x * factor), owner)
    assert wide.hi == pytest.approx(factor)


# -- the benchmark's model -----------------------------------------------------------------------

def test_decomposition_counts_model_matches_the_bookkeeping(tmp_path):
    """``benchmarks/decomposition_counts.py --check-only``: its exact lattice formula equals the
    staged-exchange bookkeeping rank by rank (the script stops otherwise), and its uniform-density
    model is within 10 % of them (a lattice's planes fall in or out of a layer whole: 3.7-6.3 % at
    these sizes, up to 12 % in the full table where cuts fall between planes unevenly)."""
    out = tmp_path / "counts.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "decomposition_counts.py"),
                          "--check-only", "--json", str(out)], capture_output=True, text=True, env=env,
                         timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stdout + res.stderr
    checks = json.load(open(out))["checks"]
    assert len(checks) >= 4
    for c in checks:
        assert c["exact_mean_ghosts"] > 0 and c["formula_equals_bookkeeping"] is True
        assert abs(c["model_ghosts"] / c["exact_mean_ghosts"] - 1.0) < 0.10, c


# -- lattice planes split by global id ---------------------------------------------------------------

def owner_by_keys(g, x, gid):
    """The definition: along each axis, the number of interior cut keys (c, g) <= (x_a, gid)."""
    idx = np.zeros((len(x), 3), dtype=np.int64)
    for a in range(3):
        c, cg = g.cuts[a][1:-1], g.cut_gids[a]
        for k in range(len(c)):
            idx[:, a] += (x[:, a] > c[k]) | ((x[:, a] == c[k]) & (gid >= cg[k]))
    return idx[:, 0] + g.shape[0] * (idx[:, 1] + g.shape[1] * idx[:, 2])


@pytest.mark.parametrize("grid", [(2, 1, 1), (3, 2, 2), (1, 3, 2), (2, 2, 2)])
def test_gid_cuts_split_lattice_planes_to_one_element(grid):
    """A lattice of 7 x 5 x 9 planes (odd: no coordinate cut can halve them) with gids in random
    order: cuts by (coordinate, gid) leave every slice exactly its share of elements; coordinate
    cuts alone are off by whole planes."""
    rng = np.random.default_rng(sum(grid))
    L = np.array([7.0, 5.0, 9.0])
    x = np.array(list(itertools.product(*[np.arange(0.5, L[a]) for a in range(3)])))
    gid = rng.permutation(len(x)) + 100     # consecutive: a cut gid is an element's gid
    g = GridDecomposition(grid, [0, 0, 0], L, (True, True, True))
    split = g.balanced(x, gid=gid)
    idx = split.indices(x, gid)
    np.testing.assert_array_equal(split.owner(x, gid), owner_by_keys(split, x, gid))
    for a in range(3):
        p = grid[a]
        expected = np.diff(np.round(np.arange(p + 1) / p * len(x)))
        np.testing.assert_array_equal(np.bincount(idx[:, a], minlength=p), expected)
    planes = g.balanced(x)
    off = max(np.abs(np.bincount(planes.indices(x)[:, a], minlength=grid[a])
                     - len(x) / grid[a]).max() for a in range(3))
    assert off >= len(x) / 9 / 2 - 1      # half a plane at least (the smallest plane: 7 x 5 = 35)


@pytest.mark.parametrize("grid, periodic", [((3, 2, 2), (True, True, True)), ((2, 2, 2), (False, True, False)),
                                            ((1, 3, 2), (True, False, True))])
def test_ghosts_with_split_planes(grid, periodic):
    """Lattice points on split cut planes (owned on either side by gid): the staged selection is
    still the definition, and every pair within range (nearest neighbours and diagonals) is held by
    both owners."""
    rng = np.random.default_rng(7)
    L = np.array([6.5, 6.5, 6.5])
    x = lattice(L, 0.5)                       # 2,197 points, 13 planes per axis: no even split
    gid = rng.permutation(len(x))
    per = np.array(periodic)
    r = 0.75                                  # reaches the 6 neighbours and 12 face diagonals
    g = GridDecomposition(grid, [0, 0, 0], L, per).balanced(x, gid=gid, min_width=r)
    owner = g.owner(x, gid)
    idx = g.indices(x, gid)
    # every cut lies on a lattice plane whose points are owned on both sides
    for a in range(3):
        for c in g.cuts[a][1:-1]:
            assert len(np.unique(idx[x[:, a] == c, a])) == 2
    ghosts, _ = g.staged_ghosts(x, r, gid)
    held = {}
    for q in range(g.size):
        entries = as_set(*ghosts[q])
        assert len(entries) == len(ghosts[q][0])
        assert entries == as_set(*g.stencil_ghosts(q, x, r, gid))
        assert entries == extended_box_ghosts(g, q, x, owner, r)
        held[q] = entries | {(int(p), (0, 0, 0)) for p in np.nonzero(owner == q)[0]}
    i, j, s = min_image_pairs(x, L, per, r)
    assert len(i) > 3 * len(x)
    for a, b, sh in zip(i, j, s):
        assert (int(b), tuple(int(v) for v in sh)) in held[owner[a]]
        assert (int(a), tuple(int(-v) for v in sh)) in held[owner[b]]


# -- the per-rank verbs with real messages ---------------------------------------------------------

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")


@pytest.mark.mpi
@pytest.mark.parametrize("ranks, grid, periodic", [(4, [2, 2, 1], [True, True, False]),
                                                   (2, [1, 1, 2], [True, True, True]),
                                                   (3, [3, 1, 1], [False, True, True]),
                                                   (4, [1, 2, 2], [True, False, True])])
def test_staged_exchange_under_mpi(tmp_path, ranks, grid, periodic):
    """``tests/mpi/grid_exchange.py`` (ranks oversubscribed on this machine): cuts balanced with
    ``Communicator.sum`` over stripes equal one process's, and the staged exchange run with
    ``stage_sends`` and point-to-point messages gives every rank the ghosts (gid, shift) of the
    one-process bookkeeping, none twice, with 2 messages at most per cut axis."""
    out = tmp_path / "grid.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([MPIEXEC, "-n", str(ranks), sys.executable, os.path.join(ROOT, "tests", "mpi", "grid_exchange.py"),
                          str(out), json.dumps(grid), json.dumps(periodic)],
                         capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    rows = json.load(open(out))
    assert len(rows) == ranks
    for row in rows:
        assert row["same_cuts"] and row["owned_ok"] and row["ghosts_equal"], row
        assert row["duplicates"] == 0 and row["ghosts"] > 0
        assert row["messages"] <= 2 * sum(1 for p in grid if p > 1)


def test_wrap_keeps_inside_rows_and_open_axes_own_everything():
    """Rows inside the cell keep their bits (``lo + (x - lo)`` would not: ownership on a cut must
    be the cell's own); outside, periodic axes wrap and open axes give the end subdomains."""
    rng = np.random.default_rng(8)
    lo, hi = np.array([0.1, -0.3, 0.0]), np.array([1.1, 0.7, 2.0])
    g = GridDecomposition((2, 2, 3), lo, hi, (True, True, False))
    x = lo + rng.uniform(0.0, 1.0, (5000, 3)) * (hi - lo)
    np.testing.assert_array_equal(g.wrapped(x), x)
    out = np.array([[1.1, 0.7, -5.0], [0.1 - 1e-3, -0.3, 9.0], [0.6, 0.2 + 3 * 1.0, 1.0]])
    idx = g.indices(out)
    np.testing.assert_array_equal(idx, [[0, 0, 0], [1, 0, 2], [1, 1, 1]])


@pytest.mark.parametrize("grid, periodic", [((3, 2, 2), (True, True, True)), ((2, 3, 1), (False, True, False)),
                                            ((4, 1, 3), (True, False, False))])
def test_migration_passes_bring_every_row_to_its_owner(grid, periodic):
    """Rows start on arbitrary ranks; passes of x, y, z ``migration_sends`` (each rank sends, then
    all receive) bring every row to its owner exactly once; rows that moved at most one subdomain
    per axis since the last placement need a single pass."""
    rng = np.random.default_rng(9)
    L = np.array([1.0, 1.2, 0.9])
    x = uniform(rng, 3000, L, 3)
    gid = rng.permutation(len(x))
    g = GridDecomposition(grid, [0, 0, 0], L, periodic).balanced(x, gid=gid)
    owner = g.owner(x, gid)

    def run(held):
        passes = 0
        while any(len(g.migration_sends(q, a, x[held[q]], gid[held[q]])) for q in range(g.size) for a in range(3)):
            passes += 1
            assert passes <= max(grid)
            for a in range(3):
                moved = {q: [] for q in range(g.size)}
                for q in range(g.size):
                    keep = np.ones(len(held[q]), bool)
                    for side, nb, rows in g.migration_sends(q, a, x[held[q]], gid[held[q]]):
                        moved[nb].append(held[q][rows])
                        keep[rows] = False
                    held[q] = held[q][keep]
                for q in range(g.size):
                    held[q] = np.concatenate([held[q]] + moved[q])
        return held, passes

    start = rng.integers(0, g.size, len(x))
    held, _ = run({q: np.nonzero(start == q)[0] for q in range(g.size)})
    for q in range(g.size):
        np.testing.assert_array_equal(np.sort(held[q]), np.nonzero(owner == q)[0])
    # a small displacement (less than every subdomain's width): one pass
    x_before = x.copy()
    x = g.wrapped(x + rng.normal(0.0, 0.03, x.shape)) if all(periodic) else x + rng.normal(0.0, 0.03, x.shape)
    held, passes = run(held)
    owner = g.owner(x, gid)
    assert passes == 1 and not np.array_equal(g.owner(x_before, gid), owner)
    for q in range(g.size):
        np.testing.assert_array_equal(np.sort(held[q]), np.nonzero(owner == q)[0])
