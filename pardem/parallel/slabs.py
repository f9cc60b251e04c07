"""Slab boundaries along one axis and their load balancing. docs/physics.md section 13.

Rank ``r`` owns the elements whose key ``(s, gid)`` (``s`` = centre coordinate along the slab axis)
lies in ``[cut[r-1], cut[r])`` in lexicographic order, with ``cut[-1] = -inf`` and ``cut[P-1] = +inf``.
The global id breaks ties, so a plane of elements with one coordinate (a lattice plane) can be split
between two ranks: the counts can then be balanced to within one element.

Cuts are found by distributed bisection on the cumulative weight (element count, or measured
seconds per element): at most 64 steps on the coordinate (bisected through its order-preserving
integer image, so the search is exact) and 64 on the gid, each one ``Allreduce`` of ``P - 1`` numbers.
Nothing is gathered, so it scales to any number of elements.
"""
import numpy as np

_SIGN = np.int64(-(2**63))


def _ordered_int(s):
    """Order-preserving map from float64 to int64 (``-0.0`` and ``0.0`` map to 0)."""
    i = np.ascontiguousarray(s, dtype=np.float64).view(np.int64)
    return np.where(i >= 0, i, _SIGN - i)


def _from_ordered_int(o):
    o = np.asarray(o, dtype=np.int64)
    return np.where(o >= 0, o, _SIGN - o).view(np.float64)


class Slabs:
    """Cuts ``(cut_s[k], cut_g[k])``, k = 0..P-2, between the slabs of ``size`` ranks along ``axis``."""

    def __init__(self, axis, cut_s, cut_g):
        self.axis = int(axis)
        self.cut_s = np.asarray(cut_s, dtype=np.float64)
        self.cut_g = np.asarray(cut_g, dtype=np.int64)

    @property
    def size(self):
        return len(self.cut_s) + 1

    def owner(self, s, gid):
        """Rank owning each key ``(s, gid)``: the number of cuts at or below it (lexicographically).

        O(N log P) time and O(N) memory: a binary search on the cut coordinates, then, for the keys
        lying exactly on a cut coordinate (a lattice plane split between ranks), one on the cut
        gids of that coordinate.
        """
        s = np.asarray(s, dtype=np.float64)
        g = np.asarray(gid, dtype=np.int64)
        lo = np.searchsorted(self.cut_s, s, side="left")
        hi = np.searchsorted(self.cut_s, s, side="right")
        owner = lo.astype(np.int64)
        tied = np.nonzero(hi > lo)[0]
        if len(tied):
            for a in np.unique(lo[tied]):          # at most P - 1 distinct cut coordinates
                rows = tied[lo[tied] == a]
                b = hi[rows[0]]
                owner[rows] += np.searchsorted(self.cut_g[a:b], g[rows], side="right")
        return owner

    def bounds(self, rank):
        """Lower and upper slab coordinates of ``rank`` (infinite at the ends)."""
        lo = self.cut_s[rank - 1] if rank > 0 else -np.inf
        hi = self.cut_s[rank] if rank < self.size - 1 else np.inf
        return lo, hi

    def narrowest_interior(self):
        """Smallest width of the slabs that have two neighbours (inf when there are none)."""
        if self.size < 3:
            return np.inf
        return float(np.min(np.diff(self.cut_s)))

    @classmethod
    def balanced(cls, comm, axis, s, gid, weights=None, fractions=None):
        """Cuts splitting the global weight (default: one per element) by ``fractions``.

        s, gid, weights : this rank's share of the elements (any partition of all elements).
        fractions : cumulative weight fractions of the P - 1 cuts (default k / P).
        """
        P = comm.size
        if P == 1:
            return cls(axis, [], [])
        s = np.asarray(s, dtype=np.float64)
        gid = np.asarray(gid, dtype=np.int64)
        w = np.ones(len(s)) if weights is None else np.asarray(weights, dtype=np.float64)
        f = np.arange(1, P) / P if fractions is None else np.asarray(fractions, dtype=np.float64)
        total = float(comm.sum(w.sum()))
        target = f * total
        if weights is None:
            target = np.round(target)     # whole elements: balanced to within one
        o = _ordered_int(s)
        order = np.argsort(o, kind="stable")
        o_sorted, cw = o[order], np.concatenate([[0.0], np.cumsum(w[order])])
        big = np.iinfo(np.int64).max
        lo_o = comm.min(int(o.min()) if len(o) else big)
        hi_o = comm.max(int(o.max()) if len(o) else -big)
        # smallest coordinate c (as ordered int) with W(s <= c) >= target
        lo = np.full(P - 1, lo_o - 1, dtype=np.int64)   # W(s <= lo) < target
        hi = np.full(P - 1, hi_o, dtype=np.int64)       # W(s <= hi) >= target
        tol = 1e-9 * total
        while np.any(hi - lo > 1):
            mid = lo + (hi - lo) // 2
            below = comm.sum(cw[np.searchsorted(o_sorted, mid, side="right")])
            ok = below >= target - tol
            hi = np.where(ok, mid, hi)
            lo = np.where(ok, lo, mid)
        cut_s = _from_ordered_int(hi)
        # among elements at exactly cut_s, the smallest g with W(s < c) + W(s == c, gid < g) >= target
        strict = comm.sum(cw[np.searchsorted(o_sorted, hi, side="left")])
        g_lo = np.full(P - 1, -1, dtype=np.int64)
        g_max = comm.max(int(gid.max()) if len(gid) else 0)
        g_hi = np.full(P - 1, g_max + 1, dtype=np.int64)
        while np.any(g_hi - g_lo > 1):
            mid = g_lo + (g_hi - g_lo) // 2
            local = np.array([w[(s == c) & (gid < g)].sum() for c, g in zip(cut_s, mid)])
            ok = strict + comm.sum(local) >= target - tol
            g_hi = np.where(ok, mid, g_hi)
            g_lo = np.where(ok, g_lo, mid)
        return cls(axis, cut_s, g_hi)


def choose_axis(extent, avoid=None):
    """Slab axis: the longest extent; among (near) ties, not ``avoid`` (the loading axis).

    Slabs normal to the loading direction see little migration, as the elements move mostly along it.
    """
    extent = np.asarray(extent, dtype=float)
    longest = extent.max()
    candidates = [a for a in range(3) if extent[a] >= longest * (1 - 1e-6)]
    preferred = [a for a in candidates if a != avoid]
    return (preferred or candidates)[0]


def imbalance(values):
    """How much per-rank loads differ: ``max / min - 1`` (0 = perfect; inf if a rank is idle)."""
    v = np.asarray(values, dtype=float)
    if v.max() <= 0:
        return 0.0
    return float(v.max() / v.min() - 1.0) if v.min() > 0 else float("inf")
