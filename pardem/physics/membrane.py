"""Flexible membrane of a 2D biaxial test: a chain of the outermost grains of
one lateral side, loaded by the confining pressure.

Construction (``walk``, the one chain walk; ``chain`` is its strict form): from the outermost
platen grain that has a grain outside the platen within ``r_m`` (outermost: largest x on the right
side, then the highest), repeatedly take, among the grains within ``r_m`` of the current one that
are neither in the chain nor in the start platen nor left out, the one furthest outward by angle,
then by distance (then the lowest index), until a grain of the other platen is reached.
"By angle": the direction ``v = x_q - x_p`` is measured counter-clockwise from the outward normal
of the last segment (``s``: the segment's direction turned clockwise by 90 degrees, for the right
side), ``alpha = atan2(s x v, s . v)`` in (-pi, pi] (a round-off -pi counts as +pi); the smallest
alpha wins, ties within 1e-12 rad go to the furthest. A turn with ``alpha <= -pi/2`` (back along
the chain, round a sharp convex tip) is refused (``round_tips=False``) or ranked after every other
candidate (``alpha + 2 pi``, ``round_tips=True``: the walk goes round the tip instead of stopping
on it). The first segment's direction is +y. A walk that stops before the other platen ends in a
dead end; that grain is left out and the walk repeated, up to ``attempts`` walks. This is a
gift-wrapping walk restricted to a neighbourhood: it follows concave bays of the boundary down to
the size ``r_m`` (about 2.5 mean radii keeps it on the grains that touch). The left side is the
mirror image (x -> -x); the walk from the top platen is the walk of the mirror image y -> -y,
reversed.

Locality (what ``MembraneLoad.rebuild`` relies on to gather only some grains): every decision of
the walk reads the start platen's grains and, for each grain at which it decides (a start it
examines, a grain it steps from: ``Walk.touched``), the grains within ``r_m`` of that grain, in
index order; nothing else. So a subset of the grains (in the same relative order) that holds both
platens and every grain within ``r_m`` of each touched grain gives the same walk as all grains;
and if it holds them for the touched grains of the first k decisions (``Walk.order`` < k), the
two walks agree on those k decisions.

The neighbourhoods come from a cell grid (cells >= r_m, 3 x 3 cells searched): a walk costs
O(n + links x grains per cell), not O(n x links).

Loads (``forces``): membrane grain k carries ``f_k = p t (L1 n1 + L2 n2) / 2`` with L1, L2 the
lengths of its two segments and n1, n2 their inward normals; ``L n`` is the segment vector turned
by 90 degrees inward, so ``f_k = (p t / 2) R (x_{k+1} - x_{k-1})`` and the two end grains get half
of their one segment. The total is exactly ``p t R (x_last - x_first)``: the pressure on the chord
(a straight vertical chain of height H carries p t H). ``t`` is the thickness of the 2D stress
convention (the mean diameter). Pure functions over arrays: positions [n, 2 or 3] (x, y used) [m].
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

SIDES = ("left", "right")

Walk = namedtuple("Walk", "links skipped reached touched order")
Walk.__doc__ = """One side's walk: ``links`` [m] indices from the start platen to the other (bottom ->
top whatever the start), ``skipped`` [k] indices left out, ``reached`` (the other platen was
reached), ``touched`` [n] bool: the grains whose r_m-neighbourhood the walk read (module
docstring), ``order`` [n] int64: the count of decisions made before a grain's neighbourhood was
first read (-1: never)."""

_TIE = 1e-12            # rad: angles this close are equal (then the furthest grain wins)


@njit(cache=True)
def _grid(xs, ys, h):
    """Cell grid over points (xs, ys) [n] with cells of edge >= ``h`` [m] (doubled while the box
    would need more than 4 n + 64 cells: a grain flown far away costs no memory). Returns
    (x0, y0, edge, nx, ny, first [nx*ny + 1], items [n]): the points of cell c = ix * ny + iy are
    items[first[c]:first[c + 1]], in increasing index order."""
    n = xs.shape[0]
    x0, y0, x1, y1 = 0.0, 0.0, 0.0, 0.0
    if n:
        x0, y0, x1, y1 = xs.min(), ys.min(), xs.max(), ys.max()
    while ((x1 - x0) / h + 1.0) * ((y1 - y0) / h + 1.0) > 4.0 * n + 64.0:
        h *= 2.0
    nx = int((x1 - x0) / h) + 1
    ny = int((y1 - y0) / h) + 1
    cell = np.empty(n, dtype=np.int64)
    first = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n):
        cx = min(max(int((xs[i] - x0) / h), 0), nx - 1)
        cy = min(max(int((ys[i] - y0) / h), 0), ny - 1)
        cell[i] = cx * ny + cy
        first[cell[i] + 1] += 1
    for c in range(nx * ny):
        first[c + 1] += first[c]
    fill = first[:-1].copy()
    items = np.empty(n, dtype=np.int64)
    for i in range(n):
        items[fill[cell[i]]] = i
        fill[cell[i]] += 1
    return x0, y0, h, nx, ny, first, items


@njit(cache=True)
def _cell_of(x, y, x0, y0, h, nx, ny):
    return min(max(int((x - x0) / h), 0), nx - 1), min(max(int((y - y0) / h), 0), ny - 1)


@njit(cache=True)
def _angle(xs, ys, p, q, sx, sy, round_tips):
    """alpha of q seen from p (module docstring); NaN if the turn is refused."""
    vx, vy = xs[q] - xs[p], ys[q] - ys[p]
    a = np.arctan2(sx * vy - sy * vx, sx * vx + sy * vy)
    if a < -np.pi + 1e-9:
        a = np.pi                           # straight back inward: +pi, whatever the sign of a round-off zero
    elif a <= -0.5 * np.pi:
        if not round_tips:
            return np.nan
        a += 2.0 * np.pi                    # a sharp left turn: after every other candidate
    return a


@njit(cache=True)
def _walk(xs, ys, low, high, r_m, round_tips, attempts):
    """The walk over (xs, ys) [n] already mirrored so that the side is +x and the start platen
    ``low`` [n] bool is below; ``high`` [n] bool: the platen that ends it. Returns (links,
    skipped [n] bool, reached, order [n] int64)."""
    n = xs.shape[0]
    x0, y0, h, nx, ny, first, items = _grid(xs, ys, r_m * (1.0 + 1e-6))
    r2 = r_m * r_m
    skip = np.zeros(n, dtype=np.bool_)
    order = np.full(n, -1, dtype=np.int64)  # decision at which a grain's neighbourhood was first read
    tick = 0
    near = np.zeros(n, dtype=np.int8)       # start platen grains: 1 a grain off the platen within r_m, -1 none
    used = np.zeros(n, dtype=np.bool_)
    links = np.empty(n + 1, dtype=np.int64)
    cand_q = np.empty(n, dtype=np.int64)   # the unused neighbours within r_m of the current grain
    cand_a = np.empty(n)                   # their angles
    cand_d = np.empty(n)                   # their squared distances [m^2]
    k = 0
    for _ in range(attempts):
        # the start: the outermost platen grain not left out (largest x, then y, then index) that
        # has a grain off the platen within r_m (else the walk would stop at once)
        s = -1
        while True:
            s = -1
            for i in range(n):
                if low[i] and not skip[i] and near[i] >= 0:
                    if s < 0 or xs[i] > xs[s] or (xs[i] == xs[s] and ys[i] >= ys[s]):
                        s = i
            if s < 0 or near[s] == 1:
                break
            order[s] = tick
            tick += 1
            near[s] = -1
            cx, cy = _cell_of(xs[s], ys[s], x0, y0, h, nx, ny)
            for ix in range(max(cx - 1, 0), min(cx + 2, nx)):
                for iy in range(max(cy - 1, 0), min(cy + 2, ny)):
                    c = ix * ny + iy
                    for t in range(first[c], first[c + 1]):
                        j = items[t]
                        if not low[j] and math.hypot(xs[s] - xs[j], ys[s] - ys[j]) <= r_m:
                            near[s] = 1
            if near[s] == 1:
                break
        if s < 0:
            break
        for i in range(n):
            used[i] = low[i] or skip[i]
        used[s] = True
        links[0] = s
        k = 1
        p = s
        dx, dy = 0.0, 1.0                   # direction of the last segment (up)
        for _ in range(n):
            if order[p] < 0:
                order[p] = tick
            tick += 1
            sx, sy = dy, -dx                # outward: the segment direction turned clockwise
            cx, cy = _cell_of(xs[p], ys[p], x0, y0, h, nx, ny)
            # the smallest angle, then among the angles within _TIE of it the furthest, then the
            # lowest index (chosen from the gathered neighbours: independent of the cells' order)
            m = 0
            best_a = np.inf
            for ix in range(max(cx - 1, 0), min(cx + 2, nx)):
                for iy in range(max(cy - 1, 0), min(cy + 2, ny)):
                    c = ix * ny + iy
                    for t in range(first[c], first[c + 1]):
                        q = items[t]
                        if used[q]:
                            continue
                        vx, vy = xs[q] - xs[p], ys[q] - ys[p]
                        d2 = vx * vx + vy * vy
                        if d2 > r2 or d2 == 0.0:
                            continue
                        a = _angle(xs, ys, p, q, sx, sy, round_tips)
                        cand_q[m], cand_a[m], cand_d[m] = q, a, d2
                        m += 1
                        if a < best_a:
                            best_a = a
            if best_a == np.inf:
                break
            nxt, best_d = -1, -1.0
            for u in range(m):
                q, d2 = cand_q[u], cand_d[u]
                if cand_a[u] <= best_a + _TIE and (d2 > best_d or (d2 == best_d and q < nxt)):
                    nxt, best_d = q, d2
            used[nxt] = True
            links[k] = nxt
            k += 1
            dx, dy = xs[nxt] - xs[p], ys[nxt] - ys[p]
            p = nxt
            if high[nxt]:
                return links[:k].copy(), skip, True, order
        skip[links[k - 1]] = True           # a dead end: leave it out and walk again
    return links[:k].copy(), skip, False, order


@njit(cache=True)
def _within(qx, qy, px, py, dist):
    n = qx.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    if px.shape[0] == 0:
        return out
    x0, y0, h, nx, ny, first, items = _grid(px, py, dist * (1.0 + 1e-6))
    for i in range(n):
        fx, fy = (qx[i] - x0) / h, (qy[i] - y0) / h
        if fx < -1.0 or fy < -1.0 or fx > nx + 1.0 or fy > ny + 1.0:
            continue                        # outside the grid by more than a cell: no point within dist
        cx, cy = _cell_of(qx[i], qy[i], x0, y0, h, nx, ny)
        for ix in range(max(cx - 1, 0), min(cx + 2, nx)):
            for iy in range(max(cy - 1, 0), min(cy + 2, ny)):
                c = ix * ny + iy
                for t in range(first[c], first[c + 1]):
                    j = items[t]
                    if math.hypot(qx[i] - px[j], qy[i] - py[j]) <= dist:
                        out[i] = True
    return out


def within(q, p, dist):
    """Mask [nq]: the points ``q`` [nq, >= 2] with a point of ``p`` [np, >= 2] within ``dist`` [m]
    (x, y; a cell grid over ``p``: O(nq + np))."""
    q = np.asarray(q, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    if not dist > 0.0:
        raise ValueError(f"dist = {dist}: expected a distance > 0 [m]")
    return _within(np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1]),
                   np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1]), float(dist))


def walk(x, bottom, top, side, r_m, from_top=False, round_tips=True, attempts=1):
    """The walk (module docstring) of ``side`` ("left" or "right") over positions ``x`` [n, >= 2]
    [m]: from the ``bottom`` platen (``from_top``: from the ``top`` one, the result reversed so
    that it still runs bottom -> top); ``bottom``, ``top``: masks [n]; ``r_m`` [m]: the search
    distance; ``round_tips``: sharp left turns ranked last instead of refused; ``attempts``: walks
    tried (each after leaving out the previous one's dead end). Returns a ``Walk`` (indices into
    ``x``); ``reached`` False if no walk got to the other platen."""
    if side not in SIDES:
        raise ValueError(f"side {side!r}: expected 'left' or 'right'")
    if not r_m > 0.0:
        raise ValueError(f"r_m = {r_m}: expected a search distance > 0 [m]")
    if int(attempts) < 1:
        raise ValueError(f"attempts = {attempts!r}: expected >= 1")
    x = np.asarray(x, dtype=np.float64)
    if not np.isfinite(x[:, :2]).all():
        raise ValueError("the membrane walk needs finite positions")
    bottom = np.ascontiguousarray(bottom, dtype=np.bool_)
    top = np.ascontiguousarray(top, dtype=np.bool_)
    sign = 1.0 if side == "right" else -1.0
    xs = np.ascontiguousarray(sign * x[:, 0])
    ys = np.ascontiguousarray(-x[:, 1] if from_top else x[:, 1])
    low, high = (top, bottom) if from_top else (bottom, top)
    links, skip, reached, order = _walk(xs, ys, low, high, float(r_m), bool(round_tips), int(attempts))
    return Walk(links[::-1].copy() if from_top else links, np.nonzero(skip)[0], bool(reached), order >= 0, order)


def chain(x, bottom, top, side, r_m):
    """The strict membrane chain of ``side`` ("left" or "right"): one walk from the bottom, sharp
    left turns refused (``walk`` with ``round_tips=False, attempts=1``): indices [m] into ``x``
    [n, >= 2], from a bottom-platen grain to a top-platen grain. ``bottom``, ``top``: masks [n] of
    the platens' grains; ``r_m`` [m]: the search distance. ValueError if no chain reaches the top
    (a gap wider than ``r_m`` in the side, or platens without grains)."""
    bottom = np.asarray(bottom, dtype=np.bool_)
    top = np.asarray(top, dtype=np.bool_)
    if not bottom.any() or not top.any():
        raise ValueError("the membrane needs grains in both platens")
    w = walk(x, bottom, top, side, r_m, round_tips=False, attempts=1)
    if not w.reached:
        raise ValueError(f"the {side} membrane stopped after {len(w.links)} grains without reaching the top "
                         f"platen: no grain within r_m = {r_m:g} m further up the side")
    return w.links


def forces(x, links, side, pressure, thickness):
    """Forces [m, 2] [N] on the chain's grains ``links`` (``chain``) of ``side`` from the confining
    ``pressure`` [Pa] over the ``thickness`` [m] of the 2D convention (module docstring)."""
    p = np.asarray(x, dtype=np.float64)[np.asarray(links), :2]
    if len(p) < 2:
        raise ValueError("a membrane needs at least two grains")
    ahead = np.vstack([p[1:], p[-1:]])
    behind = np.vstack([p[:1], p[:-1]])
    chord = ahead - behind                     # x_{k+1} - x_{k-1}; one segment at the ends
    # inward: turned counter-clockwise on the right side (up -> -x), clockwise on the left
    if side == "right":
        inward = np.column_stack([-chord[:, 1], chord[:, 0]])
    elif side == "left":
        inward = np.column_stack([chord[:, 1], -chord[:, 0]])
    else:
        raise ValueError(f"side {side!r}: expected 'left' or 'right'")
    return 0.5 * pressure * thickness * inward
