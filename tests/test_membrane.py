"""The flexible membrane of the 2D biaxial test (``pardem.physics.membrane``), on hand-built
packings whose chain is known, and its loads against the pressure on the chord."""
import numpy as np
import pytest

from pardem.physics import membrane
from _util import granular_case

D = 2e-4        # grain diameter [m]


def grid(nx=6, ny=10, drop=(), extra=()):
    """A square array of grains (spacing D), bottom row = bottom platen, top row = top platen;
    ``drop``: (col, row) removed; ``extra``: (x, y) in units of D added."""
    pts = [(c * D, r * D) for r in range(ny) for c in range(nx) if (c, r) not in drop]
    pts += [(px * D, py * D) for px, py in extra]
    x = np.array(pts)
    return x, np.isclose(x[:, 1], 0.0), np.isclose(x[:, 1], (ny - 1) * D)


def coords(x, links):
    return [tuple(np.round(x[k] / D, 6)) for k in links]


@pytest.mark.parametrize("side, col", [("right", 5), ("left", 0)])
def test_a_straight_side_is_its_outer_column(side, col):
    x, bottom, top = grid()
    links = membrane.chain(x, bottom, top, side, r_m=1.5 * D)
    assert coords(x, links) == [(col, r) for r in range(10)]


def test_the_chain_follows_a_bay_and_wraps_a_bump():
    # a missing grain at (5, 4): the chain steps in to (4, 4) and back out; a grain sticking out at
    # (6, 7): the chain goes out to it and skips (5, 7), which is inside the membrane
    x, bottom, top = grid(drop=[(5, 4)], extra=[(6, 7)])
    links = membrane.chain(x, bottom, top, "right", r_m=1.5 * D)
    assert coords(x, links) == [(5, 0), (5, 1), (5, 2), (5, 3), (4, 4), (5, 5), (5, 6), (6, 7), (5, 8), (5, 9)]


def test_a_gap_wider_than_the_search_distance_is_refused_in_one_line():
    x, bottom, top = grid(drop=[(c, 5) for c in range(6)])
    with pytest.raises(ValueError, match="without reaching the top platen"):
        membrane.chain(x, bottom, top, "right", r_m=1.5 * D)


def test_a_straight_vertical_chain_carries_the_pressure_times_its_height():
    x, bottom, top = grid()
    links = membrane.chain(x, bottom, top, "right", r_m=1.5 * D)
    p, t = 1e6, D
    f = membrane.forces(x, links, "right", p, t)
    height = 9 * D
    assert f.sum(axis=0) == pytest.approx([-p * t * height, 0.0], abs=1e-12 * p * t * height)
    # interior grains: one spacing each, pointing in (-x); the ends half of it
    assert np.allclose(f[1:-1], [-p * t * D, 0.0], rtol=0, atol=1e-9 * p * t * D)
    assert np.allclose(f[[0, -1]], [-0.5 * p * t * D, 0.0], rtol=0, atol=1e-9 * p * t * D)
    fl = membrane.forces(x, membrane.chain(x, bottom, top, "left", 1.5 * D), "left", p, t)
    assert fl.sum(axis=0) == pytest.approx([p * t * height, 0.0], abs=1e-12 * p * t * height)


def test_any_chain_carries_the_pressure_on_its_chord_normal_to_each_segment():
    """A random chain: the total is p t R(x_last - x_first) exactly, and each grain's force is the
    sum of its two half segments' L n (independent: computed segment by segment here)."""
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.uniform([-0.5, 0.2], [0.5, 1.0], size=(30, 2)), axis=0) * D
    links = np.arange(30)
    p, t = 3e5, 1.7 * D
    f = membrane.forces(x, links, "right", p, t)
    chord = x[-1] - x[0]
    assert f.sum(axis=0) == pytest.approx(p * t * np.array([-chord[1], chord[0]]), rel=1e-12)
    seg = np.diff(x, axis=0)
    L = np.linalg.norm(seg, axis=1)
    n_in = np.column_stack([-seg[:, 1], seg[:, 0]]) / L[:, None]      # inward (-x side) normals
    ref = np.zeros_like(x)
    ref[:-1] += 0.5 * p * t * L[:, None] * n_in
    ref[1:] += 0.5 * p * t * L[:, None] * n_in
    assert np.allclose(f, ref, rtol=1e-12, atol=1e-15 * p * t * D)


# -- the one walk (physics.membrane.walk) against a brute-force walk ------------------------------

def reference_walk(x, bottom, top, side, r_m, from_top, round_tips, attempts):
    """The walk of the module docstring of ``pardem.physics.membrane``, written independently:
    pure Python over every grain at every decision (O(n) per step, no cell grid), ``math.atan2``.
    Returns (links, skipped, reached, touched) like ``membrane.walk``."""
    import math
    n = len(x)
    sign = 1.0 if side == "right" else -1.0
    xs = [sign * float(v) for v in x[:, 0]]
    ys = [-float(v) if from_top else float(v) for v in x[:, 1]]
    low, high = (top, bottom) if from_top else (bottom, top)
    skip, touched = [False] * n, [False] * n
    links, reached = [], False
    for _ in range(attempts):
        start = None
        for i in sorted((i for i in range(n) if low[i] and not skip[i]), key=lambda i: (xs[i], ys[i], i),
                        reverse=True):
            touched[i] = True
            if any(not low[j] and math.hypot(xs[i] - xs[j], ys[i] - ys[j]) <= r_m for j in range(n)):
                start = i
                break
        if start is None:
            break
        used = [bool(low[i] or skip[i]) for i in range(n)]
        used[start] = True
        links, p, d = [start], start, (0.0, 1.0)
        while True:
            touched[p] = True
            s = (d[1], -d[0])
            cand = []
            for q in range(n):
                vx, vy = xs[q] - xs[p], ys[q] - ys[p]
                d2 = vx * vx + vy * vy
                if used[q] or d2 > r_m * r_m or d2 == 0.0:
                    continue
                a = math.atan2(s[0] * vy - s[1] * vx, s[0] * vx + s[1] * vy)
                if a < -math.pi + 1e-9:
                    a = math.pi
                elif a <= -math.pi / 2:
                    if not round_tips:
                        continue
                    a += 2 * math.pi
                cand.append((a, d2, q))
            if not cand:
                break
            best = min(c[0] for c in cand)
            q = max((c for c in cand if c[0] <= best + 1e-12), key=lambda c: (c[1], -c[2]))[2]
            used[q] = True
            links.append(q)
            d = (xs[q] - xs[p], ys[q] - ys[p])
            p = q
            if high[q]:
                reached = True
                break
        if reached:
            break
        skip[links[-1]] = True
    links = links[::-1] if from_top else links
    return np.array(links, dtype=np.int64), np.nonzero(skip)[0], reached, np.array(touched)


def random_sample(nx, ny, spacing, seed, holes=0.15, jitter=0.2, slot=None):
    """A jittered triangular lattice of nx x ny centres (``spacing`` [m], jitter +- ``jitter``
    spacing), a fraction ``holes`` of the grains off the platens removed at random (bays, tips,
    dead ends), bidisperse radii (R and 0.7 R, half each: only the centres matter to the walk);
    ``slot``: (row, depth) a horizontal slot ``depth`` columns deep cut into the right side.
    Returns positions [n, 2], bottom and top masks (the first and last rows), radii [n]."""
    rng = np.random.default_rng(seed)
    X, Y = np.meshgrid(np.arange(nx) * spacing, np.arange(ny) * spacing * np.sqrt(3) / 2, indexing="xy")
    X = X + 0.5 * spacing * (np.arange(ny)[:, None] % 2)
    row = np.repeat(np.arange(ny), nx)
    col = np.tile(np.arange(nx), ny)
    x = np.column_stack([X.ravel(), Y.ravel()]) + rng.uniform(-jitter, jitter, (nx * ny, 2)) * spacing
    platen = (row == 0) | (row == ny - 1)
    keep = platen | (rng.random(nx * ny) >= holes)
    if slot is not None:
        r0, depth = slot
        keep &= ~((np.abs(row - r0) <= 1) & (col >= nx - depth) & ~platen)
    x, row = x[keep], row[keep]
    radii = np.where(rng.random(len(x)) < 0.5, 1.0, 0.7) * spacing / 2.4
    return x, row == 0, row == ny - 1, radii


WALK_CASES = [(seed, holes, r) for seed in range(4)
              for holes, r in ((0.1, 1.3), (0.25, 1.3), (0.25, 1.7), (0.3, 1.1), (0.45, 1.05))]


@pytest.mark.parametrize("seed, holes, r", WALK_CASES)
def test_the_walk_equals_a_brute_force_walk_on_random_samples(seed, holes, r):
    """Every side, from the bottom and the top, strict and with tips turned round and skips: the
    same links, skipped grains, outcome and touched grains as the O(n^2) Python walk (exact: the
    same arithmetic on the same doubles, the choices made by the same comparisons)."""
    x, bottom, top, _ = random_sample(14, 24, D, seed, holes)
    for side in membrane.SIDES:
        for from_top in (False, True):
            for tips, attempts in ((False, 1), (True, 200)):
                w = membrane.walk(x, bottom, top, side, r * D, from_top=from_top, round_tips=tips, attempts=attempts)
                links, skipped, reached, touched = reference_walk(x, bottom, top, side, r * D, from_top, tips,
                                                                  attempts)
                case = (side, from_top, tips)
                assert w.reached == reached, case
                assert np.array_equal(w.links, links), case
                assert np.array_equal(w.skipped, skipped), case
                assert np.array_equal(w.touched, touched), case


def test_the_random_samples_exercise_tips_skips_and_failures():
    """The cases above are not all straight chains: some strict walks fail where the tip-turning
    ones succeed, some walks leave grains out, and some fail outright (counted over the cases)."""
    strict_fail = skips = fail = 0
    for seed, holes, r in WALK_CASES:
        x, bottom, top, _ = random_sample(14, 24, D, seed, holes)
        for side in membrane.SIDES:
            strict = membrane.walk(x, bottom, top, side, r * D, round_tips=False, attempts=1)
            full = membrane.walk(x, bottom, top, side, r * D, round_tips=True, attempts=200)
            strict_fail += (not strict.reached) and full.reached
            skips += len(full.skipped) > 0
            fail += not full.reached
    assert strict_fail > 0 and skips > 0 and fail > 0, (strict_fail, skips, fail)


def test_the_walk_does_not_depend_on_the_order_of_the_grains_beyond_ties():
    """A permutation of the grains permutes the chain (the grid's cells are visited in another
    order; ties are broken by index, which a random jitter leaves without effect)."""
    x, bottom, top, _ = random_sample(14, 24, D, 7, 0.2)
    perm = np.random.default_rng(1).permutation(len(x))
    for side in membrane.SIDES:
        a = membrane.walk(x, bottom, top, side, 1.5 * D, round_tips=True, attempts=200)
        b = membrane.walk(x[perm], bottom[perm], top[perm], side, 1.5 * D, round_tips=True, attempts=200)
        assert a.reached and np.array_equal(perm[b.links], a.links)


def test_within_equals_all_pairs_distances():
    rng = np.random.default_rng(2)
    q = rng.uniform(0, 30 * D, (400, 2))
    p = rng.uniform(5 * D, 20 * D, (50, 2))
    dist = 1.7 * D
    want = (np.hypot(q[:, None, 0] - p[None, :, 0], q[:, None, 1] - p[None, :, 1]) <= dist).any(axis=1)
    assert np.array_equal(membrane.within(q, p, dist), want)
    assert not membrane.within(q, p[:0], dist).any()


# -- the rebuild's preselection against the full gather -------------------------------------------

R = D / 2


def sample_case(comm, seed=5, slot=None, nx=60, ny=50):
    """``random_sample`` (spacing 2.4 R: no contacts) as a 2D open case (slabs along x): the
    case, positions [n, 2] in gid order, platen masks and the MembraneLoad (r_m = 1.5 spacings)."""
    from pardem.engine.membrane_load import MembraneLoad
    a = 2.4 * R
    x, bottom, top, _ = random_sample(nx, ny, a, seed, 0.12, 0.1, slot)
    pos = np.column_stack([x + 5 * R, np.zeros(len(x))])
    L = np.array([x[:, 0].max() + 10 * R, x[:, 1].max() + 10 * R, 2 * R])
    prm = {"young": 70e9, "poisson": 0.2, "friction": 0.3, "restitution": 0.9}
    case = granular_case(comm, pos, np.full(len(x), R), 2500.0, "hertz_mindlin", prm, np.zeros(3), L, 2e-9,
                          0.05 * R, periodic=(False, False, False), dimension=2, slab_axis=0)
    gid = np.arange(len(x))
    mem = MembraneLoad(gid[bottom], gid[top], 1e6, 2 * R, 1.5 * a, rebuild_every=0)
    return case, pos[:, :2], bottom, top, mem


def rebuild_runs(comm, slot=None):
    """Two rebuilds (from the bottom, then the top) of ``sample_case``: per rebuild the chains,
    skipped gids and the gathered count. The second rebuild also uses the first's chain
    positions (as ``post_force`` leaves them)."""
    case, _, _, _, mem = sample_case(comm, slot=slot)
    out = {}
    for k in range(2):
        mem.rebuild(case.sim)
        mem.positions = mem.gather_positions(case.sim)
        for s in membrane.SIDES:
            out[f"chain{k}_{s}"] = mem.chains[s]
            out[f"skipped{k}_{s}"] = mem.skipped[s]
        out[f"gathered{k}"] = np.array([mem.gathered, mem.widened])
    return out


@pytest.mark.parametrize("slot", [None, (25, 20)])
def test_rebuild_from_candidates_equals_the_walk_over_every_grain(slot):
    """``MembraneLoad.rebuild`` gathers only candidates, yet its chains and skips are those of
    ``side_chain`` over all grains (the check and widening of the module docstring); with a slot
    20 columns deep (deeper than the preselected band) the widening is exercised."""
    from pardem.engine.membrane_load import side_chain
    from pardem.parallel.communicator import Communicator
    case, x, bottom, top, mem = sample_case(Communicator(), slot=slot)
    got = rebuild_runs(Communicator(), slot)
    for k, from_top in enumerate((False, True)):
        for s in membrane.SIDES:
            links, skipped = side_chain(x, bottom, top, s, mem.r_m, from_top)
            assert np.array_equal(got[f"chain{k}_{s}"], links), (k, s)
            assert np.array_equal(got[f"skipped{k}_{s}"], skipped), (k, s)
        gathered, widened = got[f"gathered{k}"]
        # a preselection, not everything: bands of 3 r_m = 4.5 spacings inside each side's extreme
        # (about 11 of 60 columns with the jitter) and the 2 platen rows of 50 hold ~0.2 n; the
        # slot's widenings and the previous chain's band add a few per cent
        assert gathered < 0.35 * len(x), got[f"gathered{k}"]
    if slot is not None:
        assert got["gathered0"][1] >= 1        # the slot is deeper than the bands: widened


# -- Communicator.allgatherv and the rebuild on 2 ranks -------------------------------------------

def test_allgatherv_on_one_rank_is_a_copy_and_refuses_other_dtypes():
    from pardem.parallel.communicator import Communicator
    comm = Communicator()
    a = np.arange(6.0).reshape(3, 2)
    b = comm.allgatherv(a)
    assert np.array_equal(a, b) and b is not a
    with pytest.raises(TypeError, match="float64 or int64"):
        comm.allgatherv(np.arange(3, dtype=np.int32))


@pytest.mark.mpi
def test_allgatherv_and_the_rebuild_on_2_ranks(tmp_path):
    """allgatherv on 2 ranks keeps rank order (rows of different counts, one rank empty); the
    rebuild on 2 ranks (one lateral side per rank's slab) equals the 1-rank rebuild bit for bit."""
    import os
    import shutil
    import subprocess
    import sys
    from pardem.parallel.communicator import Communicator
    mpiexec = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
    if mpiexec is None:
        pytest.skip("no mpiexec")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = tmp_path / "two.npz"
    p = subprocess.run([mpiexec, "-n", "2", sys.executable, os.path.join(root, "tests", "mpi",
                        "membrane_allgatherv.py"), str(out)], capture_output=True, text=True, timeout=600, cwd=root)
    assert p.returncode == 0, p.stderr[-3000:]
    two = dict(np.load(out))
    # what each rank sent (tests/mpi/membrane_allgatherv.py): rank r sends r + 2 int64s 10 r + i
    # and 3 r float rows [r, i]
    assert np.array_equal(two["ints"], [0, 1, 10, 11, 12])
    assert np.array_equal(two["floats"], [[1.0, 0.0], [1.0, 1.0], [1.0, 2.0]])
    assert two["same_on_both"] == 1
    for slot in (None, (25, 20)):
        one = rebuild_runs(Communicator(), slot)
        tag = "slot" if slot else "plain"
        for k in one:
            if k.startswith("gathered"):
                continue          # the candidates differ with the slabs; the chains may not
            assert np.array_equal(one[k], two[f"{tag}_{k}"]), (tag, k)


def test_a_rebuild_changes_the_outline_but_not_the_tracked_area():
    """A grain moved from inside to just outside the right chain (not a chain grain: the old
    outline's area does not change) joins the chain at the next rebuild: the polygon's area jumps
    by the triangle it adds, ``tracked_area`` (the volumetric strain's) stays the same to
    round-off, the offset being exactly the change of outline; ``state`` carries the offset."""
    from pardem.engine.membrane_load import MembraneLoad, enclosed_area
    from pardem.parallel.communicator import Communicator
    case, x, bottom, top, mem = sample_case(Communicator())
    sim, e = case.sim, case.sim.elements
    mem.rebuild(sim)
    mem.positions = mem.gather_positions(sim)
    area0 = mem.area()
    assert mem.area_offset == 0.0 and mem.tracked_area() == area0
    right = mem.chains["right"]
    c = right[len(right) // 2]
    row = lambda gid: int(np.nonzero(e.gid[:e.n_owned] == gid)[0][0])
    inside = [g for g in range(len(x)) if g not in set(right) and g not in set(mem.chains["left"])
              and not bottom[g] and not top[g]]
    moved = inside[len(inside) // 2]
    a = 2.4 * R
    e.x[row(moved), :2] = e.x[row(c), :2] + [0.6 * a, 0.0]    # outside c, within r_m of its neighbours
    mem.rebuild(sim)
    assert mem.area() == area0                       # positions of the new chain not yet gathered
    mem.positions = mem.gather_positions(sim)
    assert moved in set(mem.chains["right"])
    jump = mem.area() - area0
    assert jump > 0.1 * a * a                        # the triangle the moved grain adds
    assert mem.area_offset == -jump
    # area0 + (area1 - area0) = area1 up to the rounding of the three sums: a few ulps of the area
    assert abs(mem.tracked_area() - area0) <= 8 * np.spacing(area0)
    restored = MembraneLoad.from_state(mem.state())
    assert restored.area_offset == mem.area_offset
    assert enclosed_area(mem.positions) == mem.area()
