"""Neighbour search: cell list plus Verlet list with a skin. docs/physics.md section 9.

A Verlet list holds every candidate pair ``(i, j)`` of rows whose surfaces are closer than the skin,
``|x_j + s L - x_i| < R_i + R_j + skin``. It stays valid, with no pair missed, until some element
has moved more than ``skin / 2`` since the build: two elements each moving less than half the skin
cannot close a gap larger than the skin. The list is built in O(N) time and memory with a cell list.

Conventions
-----------
* Units are SI: positions ``x`` [m], radii and skin [m]. Arrays follow ``pardem.engine.state``: rows
  ``[0, n_owned)`` are owned, rows ``[n_owned, n_total)`` are ghost copies; ``gid`` [n_total] int64
  global ids, unique among the rows.
* Only pairs with at least one owned row are kept (a rank computes every interaction that acts on
  one of its elements; ghost-ghost pairs belong to other ranks).
* Each unordered pair appears once and is oriented by global id, ``gid[i] < gid[j]`` (STYLE pattern
  7), so a pair crossing a slab boundary has the same orientation and the same shift on both ranks.
  Both ranks also take the same accept/reject decision, bitwise: the test evaluates
  ``d = (x[j] - x[i]) + s L``, which is exactly antisymmetric in (i, j) (IEEE rounding is symmetric
  under negation), against ``(R_i + R_j) + skin``, which is commutative.
* ``shifts`` int8 [n_pairs, 3] is the periodic image of j seen from i: the branch vector is
  ``(x[j] - x[i]) + shifts * L``, with ``L = box_hi - box_lo`` along the periodic axes and shift 0
  along the others (contact kernels should use the same grouping to keep the antisymmetry). It is
  the minimum image, so positions along periodic axes need not be wrapped into the box (up to 63
  periods away); they must not be re-wrapped between two builds, since that would invalidate the
  stored shifts (the displacement test of ``VerletList`` sees such a jump and asks for a rebuild).
* Along non-periodic axes the grid spans the extent of the data, so ``box_lo`` and ``box_hi``
  matter only along periodic axes, and elements outside any box are handled.
* Periodic axes need ``L >= 2 (2 R_max + skin)``; shorter periods raise ``ValueError`` because an
  element could then reach two images of the same neighbour, which one shift cannot describe.
  Periods of one or two cells are handled (the stencil visits the same cell under different
  shifts; at most one image passes the distance test).
* A tilted (triclinic) cell, ``tilt = (xy, xz, yz)`` [m] (LAMMPS' convention, edge vectors the
  columns of ``H = [[L_x, xy, xz], [0, L_y, yz], [0, 0, L_z]]``): the image of j is at
  ``x_j + H shifts``, so the branch vector is ``(x[j] - x[i]) + ((s_x L_x + s_y xy) + s_z xz,
  s_y L_y + s_z yz, s_z L_z)``; rows are binned by their fractional coordinates ``H^-1 (x - lo)``
  with as many cells per axis as the distance between opposite faces holds (LAMMPS bins in
  lamda coordinates alike), which must be ``>= 2 (2 R_max + skin)``. A zero tilt gives the
  rectangular cell's bits (each added product is a signed zero).

Algorithm
---------
1. Grid: cell edge ``h >= cut = 2 R_max + skin`` per axis (periodic axes: ``n = floor(L / cut)``
   cells of edge ``L / n``). The number of cells is capped at about twice the number of rows, by
   coarsening, so that memory stays O(N) for very sparse systems.
2. Counting sort of the rows into cells (one counting pass, a prefix sum, one scatter pass); the
   sort is stable, so rows within a cell keep their order and the result is deterministic. The
   positions, radii, gids and images are then copied in cell order, so that the scan reads
   contiguous memory even when the rows are in no spatial order.
3. Full-shell scan: for each owned row ``i``, the 27 cells around its own. An owned-owned pair is
   met from both ends and kept only from the end with the lower slot in the cell order; an
   owned-ghost pair is met once, from the owned end, because ghost rows are never scanned. We
   chose the full shell over the half shell (13 cells + own cell) because one simple rule then
   covers the owned/ghost split, periodic wrap with short periods and the gid orientation; the
   price is about twice the distance tests of a half shell, still small next to one force
   evaluation per build. Along the last axis, the three neighbouring cells are consecutive in
   memory away from the ends and are scanned as one run (9 runs instead of 27 cells).

Buffers have a fixed capacity (STYLE pattern 9): the scan kernel writes while there is room and
keeps counting past it; the Python wrapper sees ``count > capacity``, reallocates and redoes the
scan. The kernels are pure functions over arrays: no MPI, no files.

References
----------
Allen & Tildesley, *Computer Simulation of Liquids*, 2nd ed., sections 5.3.1 (Verlet list) and
5.3.2 (cell list); G 2.4.1.
"""
import numpy as np
from numba import njit

# Largest |image| of a row along a periodic axis: shifts are int8, and a shift is an image
# difference plus one, so |image| <= 63 keeps it in range.
MAX_IMAGE = 63


# -- kernels --------------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def _extents(x, radius, n_total, lo, hi):
    """Bounding box of rows ``[0, n_total)`` into ``lo``, ``hi``; returns the largest radius, or
    NaN when a position or radius is NaN (the caller checks; infinities show in ``lo``, ``hi``).

    One pass: a NumPy ``min(axis=0)`` over [n, 3] costs several times more.
    """
    rmax = 0.0
    bad = False
    for d in range(3):
        lo[d] = np.inf
        hi[d] = -np.inf
    for k in range(n_total):
        for d in range(3):
            v = x[k, d]
            if v < lo[d]:
                lo[d] = v
            if v > hi[d]:
                hi[d] = v
            bad |= v != v
        r = radius[k]
        if r > rmax:
            rmax = r
        bad |= r != r
    return np.nan if bad else rmax


@njit(cache=True, error_model="numpy")
def _bin_rows(x, n_total, lo, inv_h, nc, period, periodic, cell_of, image):
    """Cell of each row (linear index, axis 0 slowest) and its periodic image; returns max |image|.

    Along a periodic axis the row is first wrapped into ``[lo, lo + L)``: ``image`` is the number of
    periods it was moved by. Indices are clamped into the grid, which also covers a wrapped value
    that rounds up to ``lo + L`` and, along non-periodic axes, points exactly on the upper edge.
    """
    worst = 0
    for k in range(n_total):
        c = 0
        for d in range(3):
            xd = x[k, d]
            w = 0
            if periodic[d]:
                w = int(np.floor((xd - lo[d]) / period[d]))
                xd = xd - w * period[d]
                if abs(w) > worst:
                    worst = abs(w)
            m = int((xd - lo[d]) * inv_h[d])
            if m < 0:
                m = 0
            elif m >= nc[d]:
                m = nc[d] - 1
            image[k, d] = w
            c = c * nc[d] + m
        cell_of[k] = c
    return worst


@njit(cache=True, error_model="numpy")
def _bin_rows_tilted(x, n_total, lo, inv_h, nc, period, periodic, tilt, cell_of, image):
    """``_bin_rows`` in a tilted cell: fractional coordinates ``s = H^-1 (x - lo)`` along the periodic
    axes (z first: H is upper triangular), each image the floor of ``s`` and the cell that of the
    wrapped ``s`` times the cells per axis; non-periodic axes as ``_bin_rows``. Returns max |image|."""
    worst = 0
    for k in range(n_total):
        c = 0
        s2 = 0.0
        s1 = 0.0
        if periodic[2]:
            s2 = (x[k, 2] - lo[2]) / period[2]
        if periodic[1]:
            s1 = ((x[k, 1] - lo[1]) - tilt[2] * s2) / period[1]
        s0 = 0.0
        if periodic[0]:
            s0 = ((x[k, 0] - lo[0]) - tilt[0] * s1 - tilt[1] * s2) / period[0]
        for d in range(3):
            w = 0
            if periodic[d]:
                sd = s0 if d == 0 else (s1 if d == 1 else s2)
                w = int(np.floor(sd))
                if abs(w) > worst:
                    worst = abs(w)
                m = int((sd - w) * nc[d])
            else:
                m = int((x[k, d] - lo[d]) * inv_h[d])
            if m < 0:
                m = 0
            elif m >= nc[d]:
                m = nc[d] - 1
            image[k, d] = w
            c = c * nc[d] + m
        cell_of[k] = c
    return worst


@njit(cache=True, error_model="numpy")
def _counting_sort(cell_of, n_total, n_cells, cell_start, cell_rows):
    """Rows grouped by cell: rows of cell c are ``cell_rows[cell_start[c]:cell_start[c + 1]]``."""
    for c in range(n_cells + 1):
        cell_start[c] = 0
    for k in range(n_total):
        cell_start[cell_of[k] + 1] += 1
    for c in range(n_cells):
        cell_start[c + 1] += cell_start[c]
    cursor = cell_start[:n_cells].copy()
    for k in range(n_total):   # increasing k: stable, so rows stay ordered within a cell
        c = cell_of[k]
        cell_rows[cursor[c]] = k
        cursor[c] += 1


@njit(cache=True, error_model="numpy")
def _gather(x, radius, gid, image, cell_rows, n_total, xs, rs, gs, ims):
    """Copies of the per-row data in cell order, so that the scan reads neighbouring cells from
    contiguous memory whatever the row order (3x faster for randomly ordered rows)."""
    for b in range(n_total):
        k = cell_rows[b]
        for d in range(3):
            xs[b, d] = x[k, d]
            ims[b, d] = image[k, d]
        rs[b] = radius[k]
        gs[b] = gid[k]


@njit(cache=True, error_model="numpy")
def _scan_run(b0, b1, a, i, gi, ri, xi0, xi1, xi2, t0i, t1i, t2i, xs, rs, gs, ims, cell_rows,
              n_owned, skin, L0, L1, L2, pairs, shifts, count, XY=0.0, XZ=0.0, YZ=0.0):
    """Test owned row ``i`` (slot ``a``) against slots ``[b0, b1)`` (one or more consecutive cells
    seen under the same cell shift); ``t*i`` = cell shift + image of i; ``XY, XZ, YZ`` [m] the
    tilt. Returns the updated count."""
    cap = pairs.shape[0]
    for b in range(b0, b1):
        # an owned-owned pair is met from both ends: keep it from the lower slot only (comparing
        # slots, not rows, keeps this branch predictable when rows are in random order); an
        # owned-ghost pair is met once, since ghost rows are never scanned as i
        j = cell_rows[b]
        if b <= a and (b == a or j < n_owned):
            continue
        # shift of j next to i in raw (unwrapped) coordinates
        t0 = t0i - ims[b, 0]
        t1 = t1i - ims[b, 1]
        t2 = t2i - ims[b, 2]
        # (x_j - x_i) + t L is exactly antisymmetric in (i, j) (IEEE rounding is symmetric under
        # negation) and R_i + R_j is commutative, so both ranks of a boundary pair decide alike
        d0 = (xs[b, 0] - xi0) + ((t0 * L0 + t1 * XY) + t2 * XZ)
        d1 = (xs[b, 1] - xi1) + (t1 * L1 + t2 * YZ)
        d2 = (xs[b, 2] - xi2) + t2 * L2
        reach = (ri + rs[b]) + skin
        if d0 * d0 + d1 * d1 + d2 * d2 < reach * reach:
            if count < cap:
                if gi < gs[b]:
                    pairs[count, 0] = i
                    pairs[count, 1] = j
                else:   # orient by gid: then the shift is that of i seen from j
                    pairs[count, 0] = j
                    pairs[count, 1] = i
                    t0, t1, t2 = -t0, -t1, -t2
                shifts[count, 0] = t0
                shifts[count, 1] = t1
                shifts[count, 2] = t2
            count += 1
    return count



@njit(cache=True, inline="always")
def _neighbour_cell(e, n, periodic):
    """Cell index ``e`` along an axis of ``n`` cells, brought back into range on a periodic axis:
    ``(cell, image)`` with image -1, 0 or +1 (the copy of that cell next to the current one), or
    ``(-1, 0)`` past the end of a non-periodic axis."""
    if 0 <= e < n:
        return e, 0
    if not periodic:
        return -1, 0
    s = -1 if e < 0 else 1
    return e - s * n, s


@njit(cache=True, error_model="numpy")
def _scan_pairs(xs, rs, gs, ims, n_owned, skin, period, periodic, nc, cell_start, cell_rows,
                pairs, shifts, tilt):
    """Full-shell scan of the 27 cells around each owned row; returns the number of pairs found.

    Works on the cell-ordered copies of ``_gather`` (slot ``b`` holds row ``cell_rows[b]``).

    Writes pairs while there is room in ``pairs`` / ``shifts`` and keeps counting after that, so a
    return value above the capacity is the exact size needed.
    """
    count = 0
    n0, n1, n2 = nc[0], nc[1], nc[2]
    L0, L1, L2 = period[0], period[1], period[2]
    XY, XZ, YZ = tilt[0], tilt[1], tilt[2]
    p0, p1, p2 = periodic[0], periodic[1], periodic[2]
    for c0 in range(n0):
        for c1 in range(n1):
            for c2 in range(n2):
                c = (c0 * n1 + c1) * n2 + c2
                # away from the ends of axis 2, cells c2 - 1, c2, c2 + 1 are consecutive in the
                # linear index: one run of rows instead of three cells (cells hold ~1 row, so the
                # per-cell overhead is what costs)
                interior2 = 1 <= c2 and c2 + 1 < n2
                for a in range(cell_start[c], cell_start[c + 1]):
                    i = cell_rows[a]
                    if i >= n_owned:
                        continue
                    gi = gs[a]
                    ri = rs[a]
                    xi0, xi1, xi2 = xs[a, 0], xs[a, 1], xs[a, 2]
                    for o0 in range(-1, 2):
                        e0, s0 = _neighbour_cell(c0 + o0, n0, p0)
                        if e0 < 0:
                            continue
                        for o1 in range(-1, 2):
                            e1, s1 = _neighbour_cell(c1 + o1, n1, p1)
                            if e1 < 0:
                                continue
                            t0i = s0 + ims[a, 0]
                            t1i = s1 + ims[a, 1]
                            row = (e0 * n1 + e1) * n2
                            if interior2:
                                count = _scan_run(cell_start[row + c2 - 1], cell_start[row + c2 + 2],
                                                  a, i, gi, ri, xi0, xi1, xi2, t0i, t1i, ims[a, 2],
                                                  xs, rs, gs, ims, cell_rows, n_owned, skin,
                                                  L0, L1, L2, pairs, shifts, count, XY, XZ, YZ)
                                continue
                            for o2 in range(-1, 2):
                                e2, s2 = _neighbour_cell(c2 + o2, n2, p2)
                                if e2 < 0:
                                    continue
                                e = row + e2
                                count = _scan_run(cell_start[e], cell_start[e + 1],
                                                  a, i, gi, ri, xi0, xi1, xi2, t0i, t1i,
                                                  s2 + ims[a, 2], xs, rs, gs, ims, cell_rows,
                                                  n_owned, skin, L0, L1, L2, pairs, shifts, count,
                                                  XY, XZ, YZ)
    return count


@njit(cache=True, error_model="numpy")
def max_displacement2(x, x_ref, n):
    """Largest squared displacement [m^2] of rows ``[0, n)`` from ``x_ref`` (NaN counts as huge).

    The value to reduce with a max over ranks before deciding on a rebuild.
    """
    m = 0.0
    for k in range(n):
        m = larger_displacement2(m, x, x_ref, k)
    return m


@njit(cache=True, inline="always", error_model="numpy")
def larger_displacement2(m, x, x_ref, k):
    """``max(m, |x[k] - x_ref[k]|^2)`` [m^2] with a NaN counted as infinite: one row of
    ``max_displacement2`` (``verlet.kick_drift`` runs it as it drifts)."""
    d = (x[k, 0] - x_ref[k, 0]) ** 2 + (x[k, 1] - x_ref[k, 1]) ** 2 + (x[k, 2] - x_ref[k, 2]) ** 2
    if not d <= m:
        return d if d == d else np.inf
    return m


@njit(cache=True, error_model="numpy")
def max_displacement_exceeds(x, x_ref, n, half_skin):
    """True when some row in ``[0, n)`` moved strictly more than ``half_skin`` [m] from ``x_ref``.

    Stops at the first such row. A NaN position also returns True (rebuilding then fails loudly).
    """
    lim = half_skin * half_skin
    for k in range(n):
        d = (x[k, 0] - x_ref[k, 0]) ** 2 + (x[k, 1] - x_ref[k, 1]) ** 2 + (x[k, 2] - x_ref[k, 2]) ** 2
        if not d <= lim:
            return True
    return False


# -- Python layer ---------------------------------------------------------------------------------

class CellGrid:
    """Cell grid of one build: origin ``lo`` [m], cells per axis ``nc``, inverse edge ``inv_h`` [1/m],
    ``period`` [m] (0 along non-periodic axes) and the periodic flags; ``tilt`` [3] [m] (xy, xz, yz)
    of a tilted cell (zeros: rectangular), ``tilted``."""

    def __init__(self, x, radius, n_total, skin, box_lo, box_hi, periodic, max_cells=None, tilt=None):
        self.periodic = np.array([bool(p) for p in periodic], dtype=np.bool_)
        if self.periodic.shape != (3,):
            raise ValueError("periodic must hold 3 booleans")
        self.tilt = np.zeros(3) if tilt is None else np.array(tilt, dtype=np.float64).reshape(3)
        self.tilted = bool(np.any(self.tilt != 0.0))
        if self.tilted and not (np.all(np.isfinite(self.tilt)) and all(
                self.tilt[c] == 0.0 or (self.periodic[a] and self.periodic[b])
                for c, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))))):
            raise ValueError(f"tilt {self.tilt.tolist()}: each tilt (xy, xz, yz) needs finite values and "
                             "both axes it couples periodic")
        width = None
        if self.tilted:
            L = [float(box_hi[d]) - float(box_lo[d]) if self.periodic[d] else 1.0 for d in range(3)]
            H = np.array([[L[0], self.tilt[0], self.tilt[1]], [0.0, L[1], self.tilt[2]], [0.0, 0.0, L[2]]])
            width = 1.0 / np.linalg.norm(np.linalg.inv(H), axis=1)   # distances between opposite faces
        xmin, xmax = np.empty(3), np.empty(3)
        rmax = _extents(x, radius, n_total, xmin, xmax)
        cut = 2.0 * rmax + skin
        self.cut = cut
        # cells a hair larger than the range: a row binned across a cell face by rounding (wrap,
        # clamp) can then never hide a pair at a distance just below the range
        h_min = cut * (1.0 + 1e-10)
        if not (np.all(np.isfinite(xmin)) and np.all(np.isfinite(xmax)) and np.isfinite(rmax)):
            raise ValueError("positions and radii must be finite")
        self.lo = np.empty(3)
        self.period = np.zeros(3)
        extent = np.empty(3)
        nc = np.empty(3, dtype=np.int64)
        for d in range(3):
            if self.periodic[d]:
                if box_lo is None or box_hi is None:
                    raise ValueError("box_lo and box_hi are needed along periodic axes")
                L = float(box_hi[d]) - float(box_lo[d])
                W = L if width is None else float(width[d])
                if not W >= 2.0 * cut:
                    raise ValueError(
                        f"periodic axis {'xyz'[d]}: period {W:.6g} m is shorter than twice the "
                        f"interaction range 2 R_max + skin = {cut:.6g} m; an element could reach two "
                        "images of a neighbour (enlarge the box or disable periodicity)")
                if not (box_lo[d] - MAX_IMAGE * L <= xmin[d] and xmax[d] < box_hi[d] + MAX_IMAGE * L):
                    raise ValueError(f"a position lies more than {MAX_IMAGE} periods outside the "
                                     f"periodic box along {'xyz'[d]} (shifts are int8); wrap "
                                     "positions into the box at a rebuild")
                self.lo[d] = float(box_lo[d])
                self.period[d] = L
                extent[d] = L
                nc[d] = max(1, int(W // h_min)) if h_min > 0.0 else 1
            else:
                self.lo[d] = float(xmin[d])
                extent[d] = float(xmax[d] - xmin[d])
                nc[d] = max(1, int(extent[d] // h_min)) if h_min > 0.0 else 1
        # O(N) memory: coarsen sparse systems to at most ~2 cells per row (cells only grow, so the
        # edge stays >= cut; a periodic axis then needs nothing more since 1 cell is handled)
        if max_cells is None:
            max_cells = 2 * n_total + 64
        total = float(np.prod(nc.astype(np.float64)))
        if total > max_cells:
            f = (max_cells / total) ** (1.0 / 3.0)
            nc = np.maximum(1, np.floor(nc * f)).astype(np.int64)
            while np.prod(nc) > max_cells:
                nc[np.argmax(nc)] -= 1
        self.nc = nc
        self.inv_h = np.where(extent > 0.0, nc / np.where(extent > 0.0, extent, 1.0), 0.0)
        if self.tilted:   # periodic axes are binned by fractional coordinates: cells per unit
            self.inv_h = np.where(self.periodic, nc.astype(np.float64), self.inv_h)

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.nc))


def _check_inputs(x, radius, gid, n_owned, n_total, skin):
    if not (0 <= n_owned <= n_total <= x.shape[0]):
        raise ValueError(f"need 0 <= n_owned ({n_owned}) <= n_total ({n_total}) <= len(x) ({x.shape[0]})")
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError("x must have shape [n, 3]")
    if radius.shape[0] < n_total or gid.shape[0] < n_total:
        raise ValueError("radius and gid need at least n_total rows")
    if not skin >= 0.0:
        raise ValueError(f"skin must be >= 0, got {skin}")


class _Workspace:
    """Per-row and per-cell scratch arrays, reused across builds while they are large enough."""

    def __init__(self):
        self.cell_of = np.empty(0, dtype=np.int64)
        self.image = np.empty((0, 3), dtype=np.int64)
        self.cell_rows = np.empty(0, dtype=np.int64)
        self.cell_start = np.empty(1, dtype=np.int64)
        self.xs = np.empty((0, 3))
        self.rs = np.empty(0)
        self.gs = np.empty(0, dtype=np.int64)
        self.ims = np.empty((0, 3), dtype=np.int64)

    def ensure(self, n_total, n_cells):
        if self.cell_of.shape[0] < n_total:
            self.cell_of = np.empty(n_total, dtype=np.int64)
            self.image = np.empty((n_total, 3), dtype=np.int64)
            self.cell_rows = np.empty(n_total, dtype=np.int64)
            self.xs = np.empty((n_total, 3))
            self.rs = np.empty(n_total)
            self.gs = np.empty(n_total, dtype=np.int64)
            self.ims = np.empty((n_total, 3), dtype=np.int64)
        if self.cell_start.shape[0] < n_cells + 1:
            self.cell_start = np.empty(n_cells + 1, dtype=np.int64)


def _fill(x, radius, gid, n_owned, n_total, skin, box_lo, box_hi, periodic, pairs, shifts, work,
          max_cells=None, tilt=None):
    """Bin, sort and scan once; returns ``(count, grid)``. ``count > len(pairs)`` means overflow."""
    grid = CellGrid(x, radius, n_total, skin, box_lo, box_hi, periodic, max_cells, tilt)
    work.ensure(n_total, grid.n_cells)
    if grid.tilted:
        worst = _bin_rows_tilted(x, n_total, grid.lo, grid.inv_h, grid.nc, grid.period, grid.periodic,
                                 grid.tilt, work.cell_of, work.image)
    else:
        worst = _bin_rows(x, n_total, grid.lo, grid.inv_h, grid.nc, grid.period, grid.periodic,
                          work.cell_of, work.image)
    if worst > MAX_IMAGE:
        raise ValueError(f"a position lies {worst} periods outside the periodic box (at most "
                         f"{MAX_IMAGE} fit the int8 shifts); wrap positions into the box at a rebuild")
    _counting_sort(work.cell_of, n_total, grid.n_cells, work.cell_start, work.cell_rows)
    _gather(x, radius, gid, work.image, work.cell_rows, n_total, work.xs, work.rs, work.gs, work.ims)
    count = _scan_pairs(work.xs, work.rs, work.gs, work.ims, n_owned, float(skin), grid.period,
                        grid.periodic, grid.nc, work.cell_start, work.cell_rows, pairs, shifts,
                        grid.tilt)
    return count, grid


def _grown(capacity, needed, growth):
    return max(int(np.ceil(growth * capacity)), int(np.ceil(1.1 * needed)), 1)


def build_pairs(x, radius, gid, n_owned, n_total, skin, box_lo=None, box_hi=None,
                periodic=(False, False, False), capacity=None, growth=1.5, max_cells=None, tilt=None):
    """Candidate pairs within ``R_i + R_j + skin``, each once, at least one end owned.

    Parameters
    ----------
    x : [n, 3] float64, positions [m]; rows ``[0, n_total)`` are used.
    radius : [n] float64, radii [m].
    gid : [n] int64, global ids (unique among the rows); each pair is ordered so that
        ``gid[i] < gid[j]``.
    n_owned, n_total : owned rows are ``[0, n_owned)``, ghosts ``[n_owned, n_total)``.
    skin : float, extra distance [m] beyond contact (>= 0).
    box_lo, box_hi : [3] box corners [m]; only read along periodic axes.
    periodic : 3 booleans, periodic axes (period ``box_hi - box_lo``).
    capacity : int, initial buffer size in pairs (default ``8 * n_owned``); grown on overflow.
    growth : capacity multiplier on overflow (the new size is also >= 1.1 x the size needed).
    max_cells : cap on the number of cells (default ``2 n_total + 64``).
    tilt : None or [3] (xy, xz, yz) [m] of a tilted periodic cell (module conventions).

    Returns
    -------
    pairs : [n_pairs, 2] int32, rows (i, j) with ``gid[i] < gid[j]``.
    shifts : [n_pairs, 3] int8, image of j: branch vector ``(x[j] - x[i]) + shifts * L`` (``+ H
        shifts`` in a tilted cell).
    Both are views into buffers of ``capacity`` rows.

    Raises
    ------
    ValueError : non-finite positions, a periodic period shorter than ``2 (2 R_max + skin)``, or a
        position more than 63 periods outside the box.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    radius = np.ascontiguousarray(radius, dtype=np.float64)
    gid = np.ascontiguousarray(gid, dtype=np.int64)
    n_owned, n_total = int(n_owned), int(n_total)
    _check_inputs(x, radius, gid, n_owned, n_total, skin)
    if n_owned == 0:
        return np.empty((0, 2), dtype=np.int32), np.empty((0, 3), dtype=np.int8)
    capacity = max(1, int(8 * n_owned if capacity is None else capacity))
    work = _Workspace()
    while True:
        pairs = np.empty((capacity, 2), dtype=np.int32)
        shifts = np.empty((capacity, 3), dtype=np.int8)
        count, _ = _fill(x, radius, gid, n_owned, n_total, skin, box_lo, box_hi, periodic,
                         pairs, shifts, work, max_cells, tilt)
        if count <= capacity:
            return pairs[:count], shifts[:count]
        capacity = _grown(capacity, count, growth)


class VerletList:
    """Verlet list with a skin, rebuilt by the caller when ``needs_rebuild`` says so.

    Holds ``pairs`` [n_pairs, 2] int32 and ``shifts`` [n_pairs, 3] int8 (see ``build_pairs``), the
    positions at the last build ``x_build`` [n_total, 3] [m], the box and ``skin`` [m]. The buffers
    keep their capacity between builds and grow by ``growth`` on overflow; ``reallocations``
    counts the overflows. There is no MPI here: in parallel, each rank evaluates
    ``max_displacement2`` (or ``needs_rebuild``), the parallel layer reduces the result over the
    ranks, and every rank rebuilds together.

    ``periodic``, ``box_lo`` and ``box_hi`` may be given at construction and overridden at each
    rebuild (a periodic cell whose size changes between builds). Note that with a changing period,
    pairs across the boundary change distance without any element moving; the skin / 2 test alone
    then does not cover that change.
    """

    def __init__(self, skin, periodic=(False, False, False), box_lo=None, box_hi=None,
                 capacity_per_row=8.0, growth=1.5):
        if not skin >= 0.0:
            raise ValueError(f"skin must be >= 0, got {skin}")
        self.skin = float(skin)
        self.periodic = tuple(bool(p) for p in periodic)
        self.box_lo = None if box_lo is None else np.asarray(box_lo, dtype=np.float64).copy()
        self.box_hi = None if box_hi is None else np.asarray(box_hi, dtype=np.float64).copy()
        self.tilt = None
        self.capacity_per_row = float(capacity_per_row)
        self.growth = float(growth)
        self._pairs = np.empty((0, 2), dtype=np.int32)
        self._shifts = np.empty((0, 3), dtype=np.int8)
        self._work = _Workspace()
        self.n_pairs = 0
        self.n_owned = 0
        self.n_total = 0
        self.x_build = np.empty((0, 3))
        self.grid = None
        self.builds = 0
        self.reallocations = 0

    @property
    def pairs(self):
        return self._pairs[:self.n_pairs]

    @property
    def shifts(self):
        return self._shifts[:self.n_pairs]

    @property
    def capacity(self) -> int:
        return self._pairs.shape[0]

    @property
    def period(self):
        """Period per axis [m] of the last build (0 along non-periodic axes)."""
        return np.zeros(3) if self.grid is None else self.grid.period

    def rebuild(self, x, radius, gid, n_owned, n_total=None, box_lo=None, box_hi=None,
                periodic=None, tilt=None):
        """Build the list from the current rows and remember ``x`` as the reference positions;
        ``tilt`` [3] [m]: that of a tilted cell (module conventions; None: rectangular)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        radius = np.ascontiguousarray(radius, dtype=np.float64)
        gid = np.ascontiguousarray(gid, dtype=np.int64)
        n_total = x.shape[0] if n_total is None else int(n_total)
        n_owned = int(n_owned)
        if box_lo is not None:
            self.box_lo = np.asarray(box_lo, dtype=np.float64).copy()
        if box_hi is not None:
            self.box_hi = np.asarray(box_hi, dtype=np.float64).copy()
        if periodic is not None:
            self.periodic = tuple(bool(p) for p in periodic)
        self.tilt = None if tilt is None else np.array(tilt, dtype=np.float64).reshape(3)
        _check_inputs(x, radius, gid, n_owned, n_total, self.skin)
        self.n_owned, self.n_total = n_owned, n_total
        self.x_build = x[:n_total].copy()
        self.builds += 1
        if n_owned == 0:
            self.n_pairs = 0
            self.grid = None
            return self
        want = max(16, int(self.capacity_per_row * n_owned))
        if self.capacity < want:
            self._allocate(want)
        while True:
            count, self.grid = _fill(x, radius, gid, n_owned, n_total, self.skin, self.box_lo,
                                     self.box_hi, self.periodic, self._pairs, self._shifts, self._work,
                                     tilt=self.tilt)
            if count <= self.capacity:
                self.n_pairs = count
                return self
            self.reallocations += 1
            self._allocate(_grown(self.capacity, count, self.growth))

    def _allocate(self, capacity):
        self._pairs = np.empty((capacity, 2), dtype=np.int32)
        self._shifts = np.empty((capacity, 3), dtype=np.int8)

    def kernel_arrays(self):
        """``(i, j, shift)`` for the contact kernels: contiguous int32 rows [n_pairs] and the image
        shift of j in metres, float64 [n_pairs, 3] (``shifts * period``), or None without any
        periodic axis. Fresh arrays: compute once per build."""
        i = np.ascontiguousarray(self.pairs[:, 0])
        j = np.ascontiguousarray(self.pairs[:, 1])
        if not any(self.periodic) or self.grid is None:
            return i, j, None
        s = self.shifts * self.grid.period
        if self.grid.tilted:   # + H shifts, grouped as the scan
            xy, xz, yz = self.grid.tilt
            s[:, 0] = (s[:, 0] + self.shifts[:, 1] * xy) + self.shifts[:, 2] * xz
            s[:, 1] = s[:, 1] + self.shifts[:, 2] * yz
        return i, j, s

    def _current(self, x):
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < self.n_total:
            raise ValueError(f"x must have shape [>= {self.n_total}, 3], got {x.shape}")
        return x

    def max_displacement2(self, x):
        """Largest squared displacement [m^2] since the build over the rows of the build."""
        if self.n_total == 0:
            return 0.0
        return max_displacement2(self._current(x), self.x_build, self.n_total)

    def needs_rebuild(self, x):
        """True when some row moved more than ``skin / 2`` since the build (or none was done).

        Checks every row the list refers to, owned and ghost; ghosts are also checked by their
        owners, so the reduced flag is the same either way.
        """
        if self.builds == 0:
            return True
        if self.n_total == 0:
            return False
        return bool(max_displacement_exceeds(self._current(x), self.x_build, self.n_total,
                                             0.5 * self.skin))
