"""Random loose packings without overlap (LIGGGHTS' ``fix insert/pack``, Yade's ``makeCloud``).

``random_pack(region, distribution, n=... | volume_fraction=..., seed=...)`` draws the radii from a
size distribution (``pardem.domains.distributions``), then places the spheres one by one, largest
first, each at uniform random points of the region shrunk by its radius until one is found where
it overlaps neither an ``existing`` sphere nor one placed before (random sequential addition),
with at most ``attempts`` tries per sphere. The result (``Cloud``) lists the spheres in the order
their radii were drawn; spheres that found no room are left out and counted (``missing``): then
the radii are no longer a sample of the distribution (the small ones, placed last, are missing
first). Random sequential addition of equal spheres jams near a volume fraction of 0.38 (Torquato,
Uche and Stillinger, Phys. Rev. E 74, 061308 (2006)); a denser packing needs a compaction (pour,
servo) afterwards.

Pure NumPy and deterministic: the same arguments and ``seed`` give the same bits on every rank, so
every rank of a parallel run can call it and pass the result to ``sim.particles.add``.

``overlaps(x_new, r_new, x_old, r_old)`` lists the pairs (new, old) of overlapping spheres (the
check ``sim.particles.add`` makes, as the builder's ``pardem.engine.inputs.check_overlaps``
makes between the given spheres).
"""
from dataclasses import dataclass

import numpy as np

from pardem.domains.distributions import as_distribution
from pardem.domains.regions import Region
from pardem.physics.arguments import real, short

CANDIDATES = 16      # candidate points drawn at once for one sphere


@dataclass
class Cloud:
    """Spheres placed by ``random_pack``: ``positions`` [n, 3] [m], ``radii`` [n] [m] (in the order
    the radii were drawn); ``requested`` the number of radii drawn, ``missing`` those that found no
    room (``requested - n``); ``volume_fraction`` the placed solid volume over the region's volume."""
    positions: np.ndarray
    radii: np.ndarray
    requested: int
    missing: int
    volume_fraction: float

    @property
    def n(self):
        return len(self.radii)

    @property
    def complete(self):
        """Every drawn sphere was placed."""
        return self.missing == 0


class _Grid:
    """Spheres hashed in the cubic cells of edge ``cell`` [m] of the box ``[lo, hi]`` padded by one
    cell: an array [nx, ny, nz, cap] of sphere indices (-1: empty), so that the candidates of one
    sphere are checked at once against the spheres of their 27 neighbouring cells."""

    MAX_CELLS = 1 << 22

    def __init__(self, lo, hi, cell):
        span = np.asarray(hi, float) - np.asarray(lo, float)
        cell = float(cell)
        while np.prod(np.ceil(span / cell) + 2) > self.MAX_CELLS:
            cell *= 1.5                 # a huge region of small spheres: coarser cells, bounded memory
        self.cell = cell
        self.origin = np.asarray(lo, float) - cell
        self.dims = (np.ceil(span / cell).astype(np.int64) + 2)
        self.slots = np.full(tuple(self.dims) + (4,), -1, np.int64)
        self.fill = np.zeros(tuple(self.dims), np.int64)
        self.x = np.zeros((64, 3))
        self.r = np.zeros(64)
        self.n = 0
        self._stencil = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij"), -1).reshape(27, 3)

    def _cells(self, p):
        return np.clip(np.floor((p - self.origin) / self.cell).astype(np.int64), 0, self.dims - 1)

    def add(self, p, r):
        if self.n == len(self.r):
            self.x = np.concatenate([self.x, np.zeros_like(self.x)])
            self.r = np.concatenate([self.r, np.zeros_like(self.r)])
        self.x[self.n], self.r[self.n] = p, r
        c = tuple(self._cells(np.asarray(p)[None])[0])
        k = self.fill[c]
        if k == self.slots.shape[-1]:
            self.slots = np.concatenate([self.slots, np.full_like(self.slots, -1)], axis=-1)
        self.slots[c + (k,)] = self.n
        self.fill[c] = k + 1
        self.n += 1

    def first_free(self, points, r, gap):
        """Index of the first of ``points`` [m, 3] where a sphere of radius ``r`` keeps ``gap`` from
        every sphere of the grid, or -1."""
        cells = self._cells(points)[:, None, :] + self._stencil[None]            # [m, 27, 3]
        cells = np.clip(cells, 0, self.dims - 1)
        idx = self.slots[cells[..., 0], cells[..., 1], cells[..., 2]].reshape(len(points), -1)
        valid = idx >= 0
        safe = np.where(valid, idx, 0)
        d = self.x[safe] - points[:, None, :]
        clear = np.einsum("mkd,mkd->mk", d, d) >= (self.r[safe] + r + gap) ** 2
        ok = np.all(clear | ~valid, axis=1)
        return int(np.argmax(ok)) if ok.any() else -1


def random_pack(region, distribution, n=None, volume_fraction=None, seed=0, existing=None, gap=0.0,
                attempts=1000):
    """Spheres placed at random without overlap in ``region`` (module docstring).

    region : a ``pardem.domains.regions`` region; distribution : a size distribution or one radius [m];
    n : the number of spheres, or volume_fraction : radii are drawn until their solid volume reaches
    this fraction of the region's volume (in (0, 1)); seed : an int (or a ``numpy.random.Generator``,
    advanced); existing : ``(positions [m, 3] [m], radii [m] [m])`` of spheres already there (only
    those near the region are looked at); gap [m] : the least distance left between two surfaces
    (0: they may touch); attempts : tries per sphere. Returns a ``Cloud``.
    """
    if not isinstance(region, Region):
        raise ValueError(f"region = {short(region)}: expected a pardem region (Box, Cylinder, Sphere)")
    dist = as_distribution(distribution)
    if (n is None) == (volume_fraction is None):
        raise ValueError("random_pack: give either n (a number of spheres) or volume_fraction (in (0, 1)), not both")
    gap = real("gap", gap, lo=0.0, lo_open=False, unit="[m]")
    if isinstance(attempts, bool) or not isinstance(attempts, (int, np.integer)) or attempts < 1:
        raise ValueError(f"attempts = {short(attempts)}: expected an integer >= 1 (tries per sphere)")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"n = {short(n)}: expected an integer >= 0 (number of spheres)")
        radii = dist.sample(int(n), rng)
    else:
        phi = real("volume_fraction", volume_fraction, lo=0.0, hi=1.0)
        radii = _radii_for_volume(dist, phi * region.volume, rng)
    region._check_room(float(radii.max()) if len(radii) else 0.0)

    x_old, r_old = _existing(existing)
    lo, hi = region.bounds
    r_new = float(radii.max()) if len(radii) else 0.0
    r_top = max(r_new, float(r_old.max()) if len(r_old) else 0.0)
    grid = _Grid(lo, hi, 2.0 * r_top + gap if r_top > 0.0 else float(np.max(hi - lo)))
    reach = r_top + r_new + gap
    near = np.all((x_old >= lo - reach) & (x_old <= hi + reach), axis=1)
    for p, r in zip(x_old[near], r_old[near]):
        grid.add(p, r)

    pos = np.full((len(radii), 3), np.nan)
    placed = np.zeros(len(radii), bool)
    for k in np.argsort(-radii, kind="stable"):
        tries = 0
        while tries < attempts:
            m = min(CANDIDATES, attempts - tries)
            cand = region.sample(m, rng, margin=radii[k])
            tries += m
            first = grid.first_free(cand, radii[k], gap)
            if first >= 0:
                pos[k], placed[k] = cand[first], True
                grid.add(cand[first], radii[k])
                break
    x, r = pos[placed], radii[placed]
    return Cloud(positions=x, radii=r, requested=len(radii), missing=int(len(radii) - placed.sum()),
                 volume_fraction=float(np.sum(4.0 / 3.0 * np.pi * r**3) / region.volume))


def _radii_for_volume(dist, volume, rng):
    """Radii drawn in blocks until their solid volume reaches ``volume`` [m^3] (the last one
    crossing it included)."""
    block = max(16, int(np.ceil(volume / dist.mean_volume() * 1.05)))
    parts, total = [], 0.0
    while total < volume:
        r = dist.sample(block, rng)
        v = np.cumsum(4.0 / 3.0 * np.pi * r**3) + total
        stop = np.searchsorted(v, volume)
        if stop < block:
            parts.append(r[:stop + 1])
            break
        parts.append(r)
        total = float(v[-1])
    return np.concatenate(parts) if parts else np.zeros(0)


def _existing(existing):
    if existing is None:
        return np.zeros((0, 3)), np.zeros(0)
    try:
        x, r = existing
    except (TypeError, ValueError):
        raise ValueError("existing must be (positions [m, 3] [m], radii [m] [m])") from None
    x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    r = np.broadcast_to(np.asarray(r, dtype=np.float64), (len(x),))
    return x, r


def overlaps(x_new, r_new, x_old, r_old, box_lo=None, box_length=None, periodic=(False, False, False)):
    """Pairs ``(i, j)`` of a new sphere ``i`` (rows of ``x_new`` [k, 3] [m], ``r_new`` [k]) and an
    old one ``j`` (``x_old`` [m, 3], ``r_old`` [m]) that overlap, with the depth
    ``r_i + r_j - d`` [m] of each: ``(i [p], j [p], depth [p])`` sorted by (i, j). With a box
    (``box_lo``, ``box_length`` [3] [m], ``periodic`` [3]) distances are minimum images along the
    periodic axes."""
    from scipy.spatial import cKDTree

    x_new, x_old = np.asarray(x_new, float).reshape(-1, 3), np.asarray(x_old, float).reshape(-1, 3)
    r_new, r_old = np.asarray(r_new, float), np.asarray(r_old, float)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(x_new) == 0 or len(x_old) == 0:
        return empty
    edge = None
    boxsize = None
    a, b = x_new, x_old
    if box_length is not None and np.any(periodic):
        per = np.asarray(periodic, bool)
        edge = np.where(per, np.asarray(box_length, float), np.inf)
        lo = np.asarray(box_lo, float)
        wrap = lambda y: np.where(per, np.mod(y - lo, np.where(per, edge, 1.0)), y - lo)  # noqa: E731
        a, b = wrap(x_new), wrap(x_old)
        a = np.where(per & (a >= edge), a - np.where(per, edge, 0.0), a)
        b = np.where(per & (b >= edge), b - np.where(per, edge, 0.0), b)
        boxsize = np.where(per, edge, 0.0)
    tree = cKDTree(b, boxsize=boxsize)
    found = tree.query_ball_point(a, r_new + float(r_old.max()))
    i = np.repeat(np.arange(len(a)), [len(f) for f in found]).astype(np.int64)
    j = np.concatenate([np.asarray(f, np.int64) for f in found]) if len(i) else np.zeros(0, np.int64)
    if len(i) == 0:
        return empty
    d = x_old[j] - x_new[i]
    if edge is not None:
        d -= np.where(np.isfinite(edge), edge, 0.0) * np.round(d / edge)
    depth = r_new[i] + r_old[j] - np.sqrt(np.einsum("kd,kd->k", d, d))
    hit = depth > 0.0
    order = np.lexsort((j[hit], i[hit]))
    return i[hit][order], j[hit][order], depth[hit][order]


__all__ = ["Cloud", "random_pack", "overlaps"]
