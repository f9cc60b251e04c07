"""Flexible membrane of a 2D biaxial test (issue 13, item 3): a chain of the outermost grains of
one lateral side, loaded by the confining pressure.

Construction (``chain``): from the outermost grain of the bottom platen, repeatedly take, among the
grains within ``r_m`` of the current one that are neither in the chain nor in the bottom platen,
the one furthest outward by angle, then by distance, until a grain of the top platen is reached.
"By angle": the direction ``v = x_q - x_p`` is measured counter-clockwise from the outward normal
of the last segment (``s``: the segment's direction turned clockwise by 90 degrees, for the right
side), ``alpha = atan2(s x v, s . v)`` in (-pi, pi]; the smallest alpha wins, among candidates
with ``alpha > -pi/2`` (none pointing back along the chain). The first segment's direction is
+y. This is a gift-wrapping walk restricted to a neighbourhood: it follows concave bays of the
boundary down to the size ``r_m`` (about 2.5 mean radii keeps it on the grains that touch). The
left side is the mirror image (x -> -x).

Loads (``forces``): membrane grain k carries ``f_k = p t (L1 n1 + L2 n2) / 2`` with L1, L2 the
lengths of its two segments and n1, n2 their inward normals; ``L n`` is the segment vector turned
by 90 degrees inward, so ``f_k = (p t / 2) R (x_{k+1} - x_{k-1})`` and the two end grains get half
of their one segment. The total is exactly ``p t R (x_last - x_first)``: the pressure on the chord
(a straight vertical chain of height H carries p t H). ``t`` is the thickness of the 2D stress
convention (the mean diameter). Pure functions over arrays: positions [n, 2 or 3] (x, y used) [m].
"""
import numpy as np
from numba import njit

SIDES = ("left", "right")


@njit(cache=True)
def _walk(x, y, start, bottom, top, r_m, max_links):
    n = x.shape[0]
    used = np.zeros(n, dtype=np.bool_)
    used[start] = True
    out = np.empty(max_links + 1, dtype=np.int64)
    out[0] = start
    k = 1
    p = start
    dx, dy = 0.0, 1.0                   # direction of the last segment (up)
    r2 = r_m * r_m
    while k <= max_links:
        sx, sy = dy, -dx                # outward: the segment direction turned clockwise
        best, best_a, best_d = -1, 0.0, 0.0
        for q in range(n):
            if used[q] or bottom[q]:
                continue
            vx, vy = x[q] - x[p], y[q] - y[p]
            d2 = vx * vx + vy * vy
            if d2 > r2 or d2 == 0.0:
                continue
            a = np.arctan2(sx * vy - sy * vx, sx * vx + sy * vy)
            if a < -np.pi + 1e-9:
                a = np.pi               # straight inward: +pi, whatever the sign of a round-off zero
            elif a <= -0.5 * np.pi:
                continue
            if best < 0 or a < best_a - 1e-12 or (abs(a - best_a) <= 1e-12 and d2 > best_d):
                best, best_a, best_d = q, a, d2
        if best < 0:
            return out[:k], False
        used[best] = True
        out[k] = best
        k += 1
        dx, dy = x[best] - x[p], y[best] - y[p]
        p = best
        if top[best]:
            return out[:k], True
    return out[:k], False


def chain(x, bottom, top, side, r_m):
    """The membrane chain of ``side`` ("left" or "right"): indices [m] into ``x`` [n, >= 2], from a
    bottom-platen grain to a top-platen grain. ``bottom``, ``top``: masks [n] of the platens'
    grains; ``r_m`` [m]: the search distance. ValueError if no chain reaches the top (a gap wider
    than ``r_m`` in the side, or platens without grains)."""
    if side not in SIDES:
        raise ValueError(f"side {side!r}: expected 'left' or 'right'")
    x = np.asarray(x, dtype=np.float64)
    bottom = np.asarray(bottom, dtype=np.bool_)
    top = np.asarray(top, dtype=np.bool_)
    if not bottom.any() or not top.any():
        raise ValueError("the membrane needs grains in both platens")
    if not r_m > 0.0:
        raise ValueError(f"r_m = {r_m}: expected a search distance > 0 [m]")
    sign = 1.0 if side == "right" else -1.0
    xs = np.ascontiguousarray(sign * x[:, 0])
    ys = np.ascontiguousarray(x[:, 1])
    candidates = np.nonzero(bottom)[0]
    # the outermost bottom grain; of equal ones the highest (the platen's top row)
    start = candidates[np.lexsort((ys[candidates], xs[candidates]))[-1]]
    links, reached = _walk(xs, ys, int(start), bottom, top, float(r_m), len(x))
    if not reached:
        raise ValueError(f"the {side} membrane stopped after {len(links)} grains without reaching the top "
                         f"platen: no grain within r_m = {r_m:g} m further up the side")
    return links


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
