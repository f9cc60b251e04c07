"""Ordered cubic lattice of touching spheres, optionally tilted in the LR plane. docs/physics.md section 4.

Centres sit on a cubic grid of spacing 2R whose axes are the rows of the LRT frame (tilted by ``xi``
about T = z). The grid passes through the box's lattice-aligned centre site, and every element whose
centre lies farther than R inside the box (within 1 % of R) is kept, so no sphere sticks out.
Bonds join face neighbours (grid index differing by one along one axis).

Flat loaded faces (``flat_axis``): a tilted grid cut to a box ends in staircases, and a plate normal
to ``flat_axis`` would touch one row of spheres per face (two offset lines of contact: a couple that
turns the domain between frictionless plates). With ``flat_axis`` set, the elements whose centres lie
within ``flat_depth`` R of the outermost centres along that axis are moved onto the plane of those
centres, so every plate touches a layer (as the compact builder makes its faces under the plates
flat). Bonded neighbours moved together end at least ``sqrt(4 - flat_depth^2) R`` apart (their
centres were 2R apart and differed by less than ``flat_depth R`` along the axis); non-bonded ones at
least ``sqrt(8 - flat_depth^2) R``. A grid axis along ``flat_axis`` leaves the lattice unchanged
(only the face layer lies in the band, already on the plane).
"""
import numpy as np

from pardem.physics.anisotropy import lrt_frame


FLAT_DEPTH = 1.0   # depth of the flattened layer [R]: half the untilted face density is moved, bonds >= 1.73 R


def ordered_lattice(box, radius, tilt_deg=0.0, flat_axis=None, flat_depth=FLAT_DEPTH):
    """Centres [n, 3], bonded pairs [m, 2] and the LRT frame [3, 3] of the lattice in ``box`` [3] (m).

    flat_axis : None, or 0, 1, 2: make the two faces normal to that axis flat (module docstring);
    flat_depth : depth of the flattened layer in radii, in [0, 1.5].
    """
    box = np.asarray(box, dtype=np.float64)
    R = float(radius)
    step = 2.0 * R
    frame = lrt_frame(tilt_deg)
    counts = np.floor(box / step + 1e-6).astype(np.int64)
    if np.any(counts < 1):
        raise ValueError("box is smaller than one element diameter along some axis")
    # untilted lattice: sites R + 2R k; the centre site is index floor(count/2)
    centre = R + step * np.floor(counts / 2)
    # index range along each lattice axis: the box corners projected on it
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)]) * box
    proj = (corners - centre) @ frame.T / step
    lo_i = np.floor(proj.min(axis=0)).astype(np.int64) - 1
    hi_i = np.ceil(proj.max(axis=0)).astype(np.int64) + 1
    I, J, K = np.meshgrid(*(np.arange(a, b + 1) for a, b in zip(lo_i, hi_i)), indexing="ij")
    idx = np.stack([I.ravel(), J.ravel(), K.ravel()], axis=1)
    pos = centre + step * (idx @ frame)
    tol = 0.01 * R
    inside = np.all((pos >= R - tol) & (pos <= box - R + tol), axis=1)
    idx = idx[inside]
    pos = pos[inside]
    if flat_axis is not None:
        if not 0.0 <= flat_depth <= 1.5:
            raise ValueError(f"flat_depth = {flat_depth!r}: expected a depth in [0, 1.5] radii")
        a = int(flat_axis)
        lo, hi = pos[:, a].min(), pos[:, a].max()
        band = flat_depth * R
        pos[pos[:, a] < lo + band, a] = lo
        pos[pos[:, a] > hi - band, a] = hi
    # order elements by position along x, then y, then z: gids follow space, which keeps
    # neighbours close in memory and makes slabs along x contiguous ranges of gids
    order = np.lexsort((pos[:, 2], pos[:, 1], pos[:, 0]))
    idx, pos = idx[order], pos[order]
    # face neighbours through a hash of the integer grid indices
    lo = idx.min(axis=0)
    span = idx.max(axis=0) - lo + 2
    key = ((idx[:, 0] - lo[0]) * span[1] + (idx[:, 1] - lo[1])) * span[2] + (idx[:, 2] - lo[2])
    sorter = np.argsort(key)
    pairs = []
    for axis in range(3):
        nb = idx.copy()
        nb[:, axis] += 1
        nkey = ((nb[:, 0] - lo[0]) * span[1] + (nb[:, 1] - lo[1])) * span[2] + (nb[:, 2] - lo[2])
        p = np.searchsorted(key, nkey, sorter=sorter)
        p = np.minimum(p, len(key) - 1)
        hit = key[sorter[p]] == nkey
        pairs.append(np.stack([np.nonzero(hit)[0], sorter[p[hit]]], axis=1))
    return pos, np.concatenate(pairs).astype(np.int64), frame
