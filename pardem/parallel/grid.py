"""A brick grid of px x py x pz subdomains: choice, ownership, cuts and their balance, and the
staged ghost selection. Pure bookkeeping over arrays (docs/decomposition.md); the messages are the
caller's (the communication layer), the sums over ranks a callable it passes (``Communicator.sum``).

Grid and ranks (LAMMPS ``processors``): rank ``r = ix + px (iy + py iz)`` (x fastest) owns the
positions ``x`` with ``cuts[a][i_a] <= x_a < cuts[a][i_a + 1]`` on every axis ``a``. ``cuts[a]``
holds ``p_a + 1`` planes [m]: on a periodic axis the first and last are the cell's faces (positions
are wrapped into ``[lo, hi)`` for ownership); on an open axis they are ``-inf`` and ``+inf`` (an
element outside the box still has an owner). Cuts are the same across a slice of the grid (a brick,
LAMMPS ``balance shift``); slabs are the grid ``[p, 1, 1]``. With global ids, an interior cut is a
key ``(c, g)`` as the slabs' (``pardem.parallel.slabs``): an element exactly on the plane ``c`` lies
above it when its gid is at least ``g``, so a lattice plane can be split and the counts balanced to
within one element (the default ``g``, the smallest int64, puts the whole plane above).

Ghosts (LAMMPS ``comm_style brick``): rank ``r`` holds every image ``x + shift * L`` (``shift`` in
{-1, 0, 1} per periodic axis, ``L`` the cell's edges; orthogonal cells) of a position owned
elsewhere, or of its own with a non-zero shift, that lies in its subdomain grown by
``ghost_range`` on every side. Staged exchange: in stage ``d`` (x, then y, then z) every rank sends
to its lower and upper neighbour along ``d`` the rows it holds (owned, and ghosts received in the
earlier stages) within ``ghost_range`` of that face, with the image shift of a message that crosses
the periodic face; so 6 messages bring the 26 neighbours' rows, corners through two or three
hops. One hop per stage needs every subdomain (but an open axis' two outer ones) at least
``ghost_range`` wide (``check_widths``). Migration goes the same way, one axis at a time
(``migration_sends``).
"""
import itertools

import numpy as np

from pardem.errors import DecompositionError
from pardem.parallel.slabs import _from_ordered_int, _ordered_int

GRID_FIELD = "[parallel] grid (Decomposition.grid)"


_TOP = np.uint64(1 << 63)


def _unsigned(s):
    """Order-preserving map float64 -> uint64."""
    return _ordered_int(s).view(np.uint64) ^ _TOP


def _from_unsigned(u):
    return _from_ordered_int((np.asarray(u, dtype=np.uint64) ^ _TOP).view(np.int64))


def _ints3(grid):
    try:
        vals = list(grid)
    except TypeError:
        return None
    if len(vals) != 3 or any(isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer))
                             for v in vals):
        return None
    return tuple(int(v) for v in vals)


def check_grid(grid, n_ranks, dimension=3):
    """The explicit grid ``[px, py, pz]`` as a tuple; ValueError (one line) unless three integers
    >= 1 whose product is ``n_ranks``, with ``pz = 1`` in 2D."""
    g = _ints3(grid)
    need = f"expected three integers >= 1 whose product is the {n_ranks} ranks" + (
        ", pz = 1 in 2D" if dimension == 2 else "") + ", or \"auto\""
    if g is None or min(g) < 1:
        raise ValueError(f"{GRID_FIELD} = {grid!r}: {need}")
    if g[0] * g[1] * g[2] != n_ranks:
        raise ValueError(f"{GRID_FIELD} = {list(g)}: the product {g[0] * g[1] * g[2]} is not the "
                         f"{n_ranks} ranks; {need}")
    if dimension == 2 and g[2] != 1:
        raise ValueError(f"{GRID_FIELD} = {list(g)}: pz = {g[2]} in 2D; {need}")
    return g


def _faces(p, periodic):
    """Faces of a subdomain along one axis that exchange ghosts with another rank (the busiest rank)."""
    if p == 1:
        return 0
    return 2 if (periodic or p >= 3) else 1


def choose_grid(n_ranks, box_lengths, periodic=(False, False, False), dimension=3, grid="auto",
                min_width=0.0):
    """``(px, py, pz)`` for ``n_ranks`` ranks in a box of edges ``box_lengths`` [3] [m].

    ``grid = "auto"`` (LAMMPS ``processors * * *``): the factorisation that minimises the surface of
    one subdomain, ``sum_a prod_{b != a} L_b / p_b`` over the decomposed axes (in 2D the perimeter,
    ``L_x / p_x + L_y / p_y``, and ``pz = 1``), so the ghost volume, among the grids whose
    subdomains are at least ``min_width`` [m] wide where cut (one-hop staged exchange; 0: any);
    ties go to the grid whose busiest rank exchanges over the smaller area (an open axis cut in two
    has one exchanging face, a periodic one two), then to the smallest px, then py (LAMMPS' loop
    order). An explicit ``[px, py, pz]`` is checked (``check_grid``) and returned.
    """
    if isinstance(n_ranks, (bool, np.bool_)) or not isinstance(n_ranks, (int, np.integer)) or n_ranks < 1:
        raise ValueError(f"n_ranks = {n_ranks!r}: expected an integer >= 1")
    if dimension not in (2, 3) or isinstance(dimension, bool):
        raise ValueError(f"dimension = {dimension!r}: expected 2 or 3")
    if not (isinstance(grid, str) and grid == "auto"):
        return check_grid(grid, int(n_ranks), dimension)
    L = np.asarray(box_lengths, dtype=float)
    if L.shape != (3,) or not np.all(np.isfinite(L)) or np.any(L[:dimension] <= 0):
        raise ValueError(f"box_lengths = {np.asarray(box_lengths).tolist()}: expected 3 finite edges > 0 [m]")
    per = [bool(p) for p in periodic]
    if len(per) != 3:
        raise ValueError(f"periodic = {periodic!r}: expected 3 booleans")
    axes = range(dimension)
    scale = float(L[:dimension].max())     # ties compared on the box's shape, whatever its units
    best, best_key = None, None
    P = int(n_ranks)
    for px in range(1, P + 1):
        if P % px:
            continue
        for py in range(1, P // px + 1):
            if (P // px) % py:
                continue
            pz = P // px // py
            if dimension == 2 and pz != 1:
                continue
            p = (px, py, pz)
            w = L / np.array(p)
            if any(p[a] > 1 and w[a] < min_width for a in axes):
                continue
            w = w / scale
            surface = sum(np.prod([w[b] for b in axes if b != a]) for a in axes)
            busiest = sum(_faces(p[a], per[a]) * np.prod([w[b] for b in axes if b != a]) for a in axes)
            key = (round(float(surface), 9), round(float(busiest), 9))
            if best_key is None or key < best_key:
                best, best_key = p, key
    if best is None:
        raise ValueError(f"{GRID_FIELD}: no grid of {P} ranks has subdomains at least {min_width:.6g} m "
                         f"wide in the box {L.tolist()} m: use fewer ranks")
    return best


def imbalance(values):
    """``max / min - 1`` of per-rank loads (0 = perfect; inf if a rank is idle), as the slabs'."""
    v = np.asarray(values, dtype=float)
    if v.max() <= 0:
        return 0.0
    return float(v.max() / v.min() - 1.0) if v.min() > 0 else float("inf")


_NO_GID = np.iinfo(np.int64).min     # a cut gid that puts the whole plane above the cut


class GridDecomposition:
    """A brick grid over a box (module docstring).

    grid : (px, py, pz); lo, hi : the box [3] [m] (the cell on its periodic axes); periodic : [3]
    bools; cuts : per axis the ``p_a - 1`` interior planes [m] (default: even spacing); cut_gids :
    per axis the ``p_a - 1`` gids that split elements lying exactly on a plane (default: none).
    """

    def __init__(self, grid, lo, hi, periodic, cuts=None, cut_gids=None):
        self.shape = tuple(int(p) for p in grid)
        if len(self.shape) != 3 or min(self.shape) < 1:
            raise ValueError(f"{GRID_FIELD} = {list(grid)}: expected three integers >= 1")
        self.lo = np.array(lo, dtype=float)
        self.hi = np.array(hi, dtype=float)
        self.periodic = np.array([bool(p) for p in periodic])
        self.length = self.hi - self.lo
        if cuts is None:
            cuts = [self.lo[a] + self.length[a] * np.arange(1, p) / p for a, p in enumerate(self.shape)]
        self.cuts = []
        for a, p in enumerate(self.shape):
            inner = np.asarray(cuts[a], dtype=float)
            if inner.shape != (p - 1,) or np.any(np.diff(inner) < 0):
                raise ValueError(f"cuts[{a}] = {inner.tolist()}: expected {p - 1} increasing planes [m]")
            ends = (self.lo[a], self.hi[a]) if self.periodic[a] else (-np.inf, np.inf)
            self.cuts.append(np.concatenate([[ends[0]], inner, [ends[1]]]))
        self.cut_gids = []
        for a, p in enumerate(self.shape):
            g = np.full(p - 1, _NO_GID, dtype=np.int64) if cut_gids is None else np.asarray(cut_gids[a], dtype=np.int64)
            if g.shape != (p - 1,):
                raise ValueError(f"cut_gids[{a}]: expected {p - 1} gids, got {g.shape}")
            self.cut_gids.append(g)

    def _copy(self, cuts=None, cut_gids=None):
        return GridDecomposition(self.shape, self.lo, self.hi, self.periodic,
                                 [c[1:-1].copy() for c in self.cuts] if cuts is None else cuts,
                                 [g.copy() for g in self.cut_gids] if cut_gids is None else cut_gids)

    # -- ranks and ownership --------------------------------------------------------------------

    @property
    def size(self):
        return self.shape[0] * self.shape[1] * self.shape[2]

    def rank_of(self, index):
        """Rank of the grid index ``(ix, iy, iz)`` (x fastest)."""
        px, py, _ = self.shape
        ix, iy, iz = (int(i) for i in index)
        return ix + px * (iy + py * iz)

    def index_of(self, rank):
        """Grid index ``(ix, iy, iz)`` of ``rank``."""
        px, py, _ = self.shape
        r = int(rank)
        return r % px, (r // px) % py, r // (px * py)

    def wrapped(self, x):
        """Positions [n, 3] [m] brought into ``[lo, hi)`` along the periodic axes (a copy; the rows
        already inside keep their bits, so ownership is that of the cell's own wrap)."""
        x = np.array(x, dtype=float, copy=True)
        for a in np.nonzero(self.periodic)[0]:
            out = (x[:, a] < self.lo[a]) | (x[:, a] >= self.hi[a])
            if np.any(out):
                x[out, a] = self.lo[a] + np.mod(x[out, a] - self.lo[a], self.length[a])
                x[out & (x[:, a] >= self.hi[a]), a] = self.lo[a]     # round-off of mod onto the upper face
        return x

    def indices(self, x, gid=None):
        """Grid index of the owner of each position [n, 3] [m]: [n, 3] int64. ``gid`` [n]: the
        elements' global ids, needed where a cut splits a plane (without them an element on a cut
        plane lies above it)."""
        x = self.wrapped(np.asarray(x, dtype=float).reshape(-1, 3))
        out = np.empty(x.shape, dtype=np.int64)
        g = None if gid is None else np.asarray(gid, dtype=np.int64)
        for a in range(3):
            c = self.cuts[a][1:-1]
            # the number of interior cut keys at or below (x, gid), lexicographically
            lo = np.searchsorted(c, x[:, a], side="left")
            hi = np.searchsorted(c, x[:, a], side="right")
            out[:, a] = hi
            tied = np.nonzero(hi > lo)[0] if g is not None else ()
            if len(tied):
                for k in np.unique(lo[tied]):       # at most p_a - 1 distinct cut planes
                    rows = tied[lo[tied] == k]
                    b = hi[rows[0]]
                    out[rows, a] = k + np.searchsorted(self.cut_gids[a][k:b], g[rows], side="right")
        return out

    def owner(self, x, gid=None):
        """Rank owning each position [n, 3] [m] (and gid [n]; vectorised): [n] int64."""
        i = self.indices(x, gid)
        px, py, _ = self.shape
        return i[:, 0] + px * (i[:, 1] + py * i[:, 2])

    def bounds(self, rank):
        """``(lo, hi)`` [3] [m] of ``rank``'s subdomain (infinite at an open axis' outer ends)."""
        idx = self.index_of(rank)
        return (np.array([self.cuts[a][idx[a]] for a in range(3)]),
                np.array([self.cuts[a][idx[a] + 1] for a in range(3)]))

    def widths(self, axis):
        """Widths [p_a] [m] of the subdomains along ``axis`` (inf at an open axis' ends)."""
        return np.diff(self.cuts[axis])

    def check_widths(self, ghost_range):
        """DecompositionError unless every subdomain that a ghost layer may cross is at least
        ``ghost_range`` [m] wide (one hop per stage; an open axis' outer subdomains excepted)."""
        for a, p in enumerate(self.shape):
            if p == 1 and not self.periodic[a]:
                continue
            w = self.widths(a)
            if p == 1 and self.length[a] < 2.0 * ghost_range:
                raise DecompositionError(f"periodic axis {'xyz'[a]}: period {self.length[a]:.6g} m shorter "
                                         f"than twice the ghost range {ghost_range:.6g} m")
            split = np.any(self.cut_gids[a] != _NO_GID)
            # an element on a split plane lies on both neighbours' faces: strictly wider, so the
            # plane two subdomains away is farther than the range
            if not (np.min(w) > ghost_range if split else np.min(w) >= ghost_range):     # NaN too
                k = int(np.argmin(w))
                raise DecompositionError(
                    f"subdomain {k} of {p} along {'xyz'[a]} is {w[k]:.4g} m thin, less than the ghost range "
                    f"{ghost_range:.4g} m: use fewer ranks along {'xyz'[a]} ({GRID_FIELD})")

    # -- neighbours -----------------------------------------------------------------------------

    def neighbour(self, rank, axis, side):
        """``(rank, shift)`` of the neighbour of ``rank`` along ``axis`` on ``side`` (-1 lower, +1
        upper), or None past an open axis' end. ``shift`` [3] int: the image, in cell edges, at
        which that neighbour's rows appear next to ``rank`` (-1 across the lower periodic face)."""
        idx = list(self.index_of(rank))
        p = self.shape[axis]
        j = idx[axis] + side
        shift = np.zeros(3, dtype=np.int64)
        if j < 0 or j >= p:
            if not self.periodic[axis]:
                return None
            shift[axis] = -1 if j < 0 else 1
            j %= p
        idx[axis] = j
        return self.rank_of(idx), shift

    def stencil(self, rank):
        """The 26-neighbour stencil: a list of ``(offset, rank, shift)``, ``offset`` in
        {-1, 0, 1}^3 without (0, 0, 0) (only ``offset[2] = 0`` when ``pz = 1`` on an open z), the
        neighbour's rank (several offsets may name one rank, or ``rank`` itself, with p_a <= 2 on a
        periodic axis) and the image ``shift`` [3] int of its rows next to ``rank``."""
        out = []
        idx = self.index_of(rank)
        for off in itertools.product((-1, 0, 1), repeat=3):
            if off == (0, 0, 0):
                continue
            nb, shift = list(idx), np.zeros(3, dtype=np.int64)
            ok = True
            for a in range(3):
                j = idx[a] + off[a]
                if 0 <= j < self.shape[a]:
                    nb[a] = j
                elif self.periodic[a]:
                    shift[a] = -1 if j < 0 else 1
                    nb[a] = j % self.shape[a]
                else:
                    ok = False
            if ok:
                out.append((off, self.rank_of(nb), shift))
        return out

    # -- ghosts -----------------------------------------------------------------------------------

    def stage_sends(self, rank, axis, x_held, ghost_range):
        """What ``rank`` sends in stage ``axis`` of the staged exchange, from the positions it holds
        now ``x_held`` [n, 3] [m] (owned rows, then the ghosts of the earlier stages, at their
        images): a list of ``(side, neighbour, rows, shift)`` (at most 2; none past an open axis'
        end, nothing along an open axis with p_a = 1): the rows within ``ghost_range`` [m] of the
        lower face go to the lower neighbour (``side`` -1), those within it of the upper face to the
        upper one (+1), and the receiver adds ``shift`` [3] int (cell edges) to their image. A rank
        receives its lower neighbour's +1 message and its upper neighbour's -1 message (with p_a = 2
        on a periodic axis, both from one rank: tell them apart by side). On a periodic axis with
        ``p_a = 1`` the neighbour is ``rank`` itself (a copy, no message)."""
        lo, hi = self.bounds(rank)
        s = np.asarray(x_held, dtype=float)[:, axis]
        out = []
        for side, rows in ((-1, np.nonzero(s < lo[axis] + ghost_range)[0]),
                           (1, np.nonzero(s >= hi[axis] - ghost_range)[0])):
            nb = self.neighbour(rank, axis, side)
            if nb is None:
                continue
            # the neighbour sees this rank's rows at the opposite image of this rank's view of it
            out.append((side, nb[0], rows.astype(np.int64), -nb[1]))
        return out

    def migration_sends(self, rank, axis, x_owned, gid=None):
        """Migration along ``axis`` (one pass of ``exchange``, x, then y, then z): the rows of
        ``x_owned`` [n, 3] [m] (with ``gid`` [n]) whose owner's grid index along ``axis`` differs
        from ``rank``'s, as ``[(side, neighbour, rows)]``: -1 toward lower indices, +1 toward
        higher ones, the short way round on a periodic axis (as the slabs'). Rows move one
        subdomain per pass; between rebuilds an element moves less than one, so one pass per axis
        places everything, and a re-cut repeats the passes until nothing is misplaced."""
        mine = self.index_of(rank)[axis]
        target = self.indices(x_owned, gid)[:, axis]
        p = self.shape[axis]
        if self.periodic[axis]:
            d = (target - mine) % p
            up, down = (d > 0) & (d <= p // 2), d > p // 2
        else:
            up, down = target > mine, target < mine
        out = []
        for side, mask in ((-1, down), (1, up)):
            nb = self.neighbour(rank, axis, side)
            if nb is not None and np.any(mask):
                out.append((side, nb[0], np.nonzero(mask)[0].astype(np.int64)))
            elif np.any(mask):
                raise DecompositionError(f"rank {rank}: rows owned past the open end of axis {'xyz'[axis]}")
        return out

    def staged_ghosts(self, x, ghost_range, gid=None):
        """All ranks' staged exchange in one process (bookkeeping only, no MPI): the ghosts of
        every rank of the positions ``x`` [n, 3] [m] (wrapped first) as ``{rank: (points,
        shifts)}`` (``points`` [g] indices into ``x``, ``shifts`` [g, 3] int, in arrival order),
        and the messages ``[(stage, sender, receiver, rows)]`` (self copies included, with sender
        == receiver). ``gid`` [n]: the global ids (where a cut splits a plane)."""
        x = self.wrapped(x)
        self.check_widths(ghost_range)
        owner = self.owner(x, gid)
        P = self.size
        order = np.argsort(owner, kind="stable")
        starts = np.searchsorted(owner[order], np.arange(P + 1))
        pts = {r: order[starts[r]:starts[r + 1]] for r in range(P)}
        sh = {r: np.zeros((len(pts[r]), 3), dtype=np.int64) for r in range(P)}
        n_owned = {r: len(pts[r]) for r in range(P)}
        messages = []
        for axis in range(3):
            incoming = {r: [] for r in range(P)}
            for r in range(P):
                held = x[pts[r]] + sh[r] * self.length
                for _, nb, rows, shift in self.stage_sends(r, axis, held, ghost_range):
                    incoming[nb].append((pts[r][rows], sh[r][rows] + shift))
                    messages.append((axis, r, nb, len(rows)))
            for r in range(P):   # received after every rank sent: a stage's sends read the earlier stages only
                if incoming[r]:
                    pts[r] = np.concatenate([pts[r]] + [p for p, _ in incoming[r]])
                    sh[r] = np.concatenate([sh[r]] + [s for _, s in incoming[r]])
        return {r: (pts[r][n_owned[r]:], sh[r][n_owned[r]:]) for r in range(P)}, messages

    def stencil_ghosts(self, rank, x, ghost_range, gid=None):
        """The direct selection of ``rank``'s ghosts over its 26-neighbour stencil: for each
        ``(offset, neighbour, shift)``, the positions owned by the neighbour whose image lies in
        the subdomain grown by ``ghost_range`` [m], ``[lo - r, hi + r)`` on every axis. Returns
        ``(points, shifts)`` as ``staged_ghosts``."""
        x = self.wrapped(x)
        owner = self.owner(x, gid)
        lo, hi = self.bounds(rank)
        pts, shs = [], []
        for _, nb, shift in self.stencil(rank):
            rows = np.nonzero(owner == nb)[0]
            y = x[rows] + shift * self.length
            keep = np.all((y >= lo - ghost_range) & (y < hi + ghost_range), axis=1)
            pts.append(rows[keep])
            shs.append(np.repeat(shift[None, :], int(keep.sum()), axis=0))
        if not pts:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.int64)
        return np.concatenate(pts), np.concatenate(shs)

    # -- cuts: balance and deformation ------------------------------------------------------------

    def balanced(self, x, weights=None, allsum=None, axes=(0, 1, 2), min_width=0.0, gid=None):
        """A grid of the same shape whose cuts along ``axes`` split the global weight evenly
        (LAMMPS ``balance shift``): on each axis ``a`` cut ``k`` lies just above (the next float)
        the smallest coordinate ``c`` of an element with ``W(x_a <= c) >= k / p_a`` of the total
        (a bisection on the
        coordinates' order-preserving integer image, 64 steps, each one ``allsum`` of the
        ``sum_a (p_a - 1)`` partial sums; exact). With ``gid`` [n] (the elements' global ids) the
        cut is instead the key ``(c, g)`` at that element: ``g`` the smallest gid such that the
        elements below the key weigh the target (64 more sums), so a lattice plane is split and each
        slice holds its share to within one element. ``x`` [n, 3] [m], ``weights`` [n] (default 1:
        element counts; ``time_weights`` for measured seconds): this rank's share of the elements
        (any partition); ``allsum``: the sum over ranks of a float64 array (``Communicator.sum``;
        default: this process holds every element).

        Each slice along an axis then holds its share of the weight to within one element's weight
        (without gids, elements with one coordinate, a lattice plane, are not split: to within one
        plane).
        A brick balances the marginal distributions: a load that is a product of per-axis
        densities (a pour dense along z, a band across a box) is balanced on every rank, a dense
        corner is not (that needs recursive bisection). ``min_width`` [m]: the slices are then
        widened to at least this (the ghost range) where they were thinner, moving the balance.
        """
        allsum = (lambda v: np.asarray(v, dtype=float)) if allsum is None else allsum
        same = self._copy()
        x = self.wrapped(np.asarray(x, dtype=float).reshape(-1, 3))
        w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=float)
        axes = [a for a in axes if self.shape[a] > 1]
        if not axes:
            return same
        # bisection on an unsigned image of the order (the signed range -inf..inf overflows int64)
        keys = [_unsigned(x[:, a]) for a in axes]
        orders = [np.argsort(k, kind="stable") for k in keys]
        sorted_keys = [k[o] for k, o in zip(keys, orders)]
        cum = [np.concatenate([[0.0], np.cumsum(w[o])]) for o in orders]
        total = float(allsum(np.array([w.sum()]))[0])
        if not total > 0.0:
            return same
        counts = [self.shape[a] - 1 for a in axes]
        target = np.concatenate([np.arange(1, self.shape[a]) / self.shape[a] for a in axes]) * total
        if weights is None:
            target = np.round(target)     # whole elements
        tol = 1e-12 * total
        lo = np.full(len(target), _unsigned(np.array([-np.inf]))[0] - np.uint64(1))   # W(<= lo) < target
        hi = np.full(len(target), _unsigned(np.array([np.inf]))[0])                    # W(<= hi) >= target
        bounds = np.cumsum([0] + counts)
        while np.any(hi - lo > np.uint64(1)):
            mid = lo + (hi - lo) // np.uint64(2)
            local = np.concatenate([c[np.searchsorted(k, mid[bounds[i]:bounds[i + 1]], side="right")]
                                    for i, (k, c) in enumerate(zip(sorted_keys, cum))])
            ok = allsum(local) >= target - tol
            hi = np.where(ok, mid, hi)
            lo = np.where(ok, lo, mid)
        new = [c[1:-1].copy() for c in self.cuts]
        new_g = [g.copy() for g in self.cut_gids]
        if gid is None:
            # the cut just above that element's coordinate (the next float), so the slice below
            # holds W(x_a <= c), the target, not one element less (a subdomain owns its lower plane)
            hi = np.minimum(hi + np.uint64(1), _unsigned(np.array([np.inf]))[0])
            for i, a in enumerate(axes):
                new[a] = self._widened(a, _from_unsigned(hi[bounds[i]:bounds[i + 1]]), min_width)
                new_g[a] = np.full(self.shape[a] - 1, _NO_GID, dtype=np.int64)
            return self._copy(new, new_g)
        gid = np.asarray(gid, dtype=np.int64)
        c = _from_unsigned(hi)
        col = np.concatenate([[a] * n for a, n in zip(axes, counts)])
        below = np.concatenate([c_[np.searchsorted(k, h, side="left")]
                                for k, c_, h in zip(sorted_keys, cum, np.split(hi, bounds[1:-1]))])
        strict = allsum(below)           # W(x_a < c) < target
        on = [(x[:, col[j]] == c[j]) for j in range(len(c))]
        # the smallest g with W(x_a < c) + W(x_a == c, gid < g) >= target, bisected over all int64
        g_lo = np.zeros(len(c), dtype=np.uint64)                  # int64 min: nothing below
        g_hi = np.full(len(c), np.iinfo(np.uint64).max)           # int64 max: every gid below
        while np.any(g_hi - g_lo > np.uint64(1)):
            mid = g_lo + (g_hi - g_lo) // np.uint64(2)
            m = (mid ^ _TOP).view(np.int64)
            local = np.array([w[on[j] & (gid < m[j])].sum() for j in range(len(c))])
            ok = strict + allsum(local) >= target - tol
            g_hi = np.where(ok, mid, g_hi)
            g_lo = np.where(ok, g_lo, mid)
        cut_g = (g_hi ^ _TOP).view(np.int64)
        for i, a in enumerate(axes):
            ci = c[bounds[i]:bounds[i + 1]]
            wide = self._widened(a, ci, min_width)
            new[a] = wide
            # a cut that min_width moved off its element's plane splits nothing
            new_g[a] = np.where(wide == ci, cut_g[bounds[i]:bounds[i + 1]], _NO_GID)
        return self._copy(new, new_g)

    def _widened(self, axis, inner, min_width):
        """Interior cuts moved apart (and off the periodic faces) to leave every slice
        ``min_width`` [m] wide where the slices exist between two planes."""
        c = np.array(inner, dtype=float)
        if min_width <= 0.0 or len(c) == 0:
            return c
        first, last = (self.lo[axis], self.hi[axis]) if self.periodic[axis] else (-np.inf, np.inf)
        if self.periodic[axis] and (len(c) + 1) * min_width > self.length[axis]:
            raise DecompositionError(f"{len(c) + 1} subdomains of at least {min_width:.4g} m do not fit "
                                     f"the period {self.length[axis]:.4g} m along {'xyz'[axis]}")
        prev = first
        for k in range(len(c)):          # upwards: each slice at least min_width above the previous cut
            c[k] = max(c[k], prev + min_width) if np.isfinite(prev) else c[k]
            prev = c[k]
        nxt = last
        for k in range(len(c) - 1, -1, -1):
            c[k] = min(c[k], nxt - min_width) if np.isfinite(nxt) else c[k]
            nxt = c[k]
        return c

    def follow_cell(self, factor):
        """The cuts and the box mapped by the cell's affine step ``lo + (x - lo) * factor`` [3],
        so the subdomains keep their elements and relative widths (in place)."""
        f = np.asarray(factor, dtype=float)
        for a in range(3):
            if f[a] != 1.0:
                inner = self.lo[a] + (self.cuts[a][1:-1] - self.lo[a]) * f[a]
                self.cuts[a][1:-1] = inner
                self.hi[a] = self.lo[a] + self.length[a] * f[a]
                self.length[a] = self.hi[a] - self.lo[a]
                if self.periodic[a]:
                    self.cuts[a][-1] = self.hi[a]


def time_weights(rank_seconds, n_owned):
    """Per-element weights [n_owned] from a rank's measured seconds (LAMMPS ``weight time``): its
    time spread evenly over its elements, so a balance on them moves the cuts toward equal time."""
    return np.full(int(n_owned), float(rank_seconds) / max(int(n_owned), 1))


def rank_loads(decomposition, x, weights=None, gid=None):
    """Per-rank load [P] of positions ``x`` [n, 3] (weights, default 1 each) under ``decomposition``
    (one process holding every element: a check, not an engine verb)."""
    w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=float)
    return np.bincount(decomposition.owner(x, gid), weights=w, minlength=decomposition.size)
