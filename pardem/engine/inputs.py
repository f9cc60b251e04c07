"""Checks of the particle arrays a system is built from, before any work.

Each check is a small pure function (every rank calls it with the same global arrays) that returns
the cleaned array (float64 or int64, contiguous) or raises one ValueError naming the argument, its
expected shape and range with units, and the first offending entry by index:

* ``check_positions``: [n, 3] [m] (or [n, 2] in 2D, the plane z = 0), finite;
* ``check_radii``: scalar or [n] [m], finite and > 0 (a wrong length is named as such);
* ``check_density``: scalar or [n] [kg/m^3], finite and > 0;
* ``check_vectors``: [n, 3] velocities [m/s], angular velocities [rad/s], finite;
* ``check_pairs``: [b, 2] bonded element indices, in range, no self pair, no bond listed twice;
* ``check_frame``: [3, 3] the orthonormal LRT material frame;
* ``check_viscous_damping``: the global drag rate C >= 0 [1/s];
* ``check_overlaps``: no two centres coincide, no two unbonded elements overlap deeply (below).

``check_arrays`` and ``check_frame`` are the builders' former ``_check_arrays`` and ``_check_frame``
(same arguments, results and message prefixes), with the overlap check added to ``check_arrays``.

Overlaps (``check_overlaps``)
-----------------------------
Two centres closer than ``COINCIDENT`` = 0.01 of the smaller radius coincide: refused for every
pair, bonded or not (a bond needs a length, ``make_bonds``, and one 100 times shorter than the
radius is no beam). Two unbonded elements whose overlap ``R_i + R_j - d`` exceeds ``MAX_OVERLAP``
= 0.5 of the smaller radius are refused too, with the count and the first pair:

* the contact laws are small-overlap laws: at ``delta = R/2`` between equal spheres the Hertz
  contact radius ``sqrt(R* delta) = R/2`` is no longer small against ``R``, and the overlap of a
  dense packing under load stays at a few per cent of ``R`` (the compact packings of
  ``pardem.domains.compact`` jam with overlaps ~1e-4 R, the granular gases start apart);
* the usual mistake is caught: diameters given as radii make touching spheres overlap by a whole
  (given) radius, twice the bound;
* bonded pairs are exempt from the depth bound: a bond's rest length is its initial centre
  distance and bonded pairs never touch through the contact law, and the ordered lattice with
  flat faces (``pardem.domains.ordered``) legitimately brings bonded neighbours to
  ``sqrt(4 - f^2) R`` (overlap 0.27 R at the default depth f = 1, up to 0.68 R at f = 1.5). Its
  unbonded neighbours stay at least ``sqrt(8 - f^2) R >= 2.4 R`` apart: no overlap.

With a periodic box the distances are minimum-image ones, and an element overlapping its own
image (edge below ``(2 - MAX_OVERLAP) R``) is refused. The candidate pairs come from
``scipy.spatial.cKDTree`` (periodic ``boxsize`` along the periodic axes): O(n log n). Radii are
grouped in classes of a factor 2, and each pair of classes is searched within its own reach
(``max R + (1 - MAX_OVERLAP) min R``), so a wide size distribution does not make every small
element a candidate of every other within the largest radius.
"""
import numpy as np

from pardem.physics.arguments import DOUBLE_MIN, array, is_real, real, short, vector3

COINCIDENT = 0.01    # centres closer than this fraction of the smaller radius coincide
MAX_OVERLAP = 0.5    # unbonded overlap R_i + R_j - d above this fraction of the smaller radius: refused


def check_positions(values, dimension=3, name="positions"):
    """Centres [n, 3] [m], n >= 1, finite; in 2D (``dimension`` 2) [n, 2] or [n, 3] with z = 0,
    returned as [n, 3] in the plane z = 0."""
    x = array(name, values, "[m]")
    cols = (2, 3) if dimension == 2 else (3,)
    if x.ndim != 2 or x.shape[1] not in cols or len(x) < 1:
        shape = "(n, 2) or (n, 3) in 2D" if dimension == 2 else "(n, 3)"
        raise ValueError(f"{name} must be finite with shape {shape}, n >= 1 [m], got shape {x.shape}")
    bad = np.nonzero(~np.all(np.isfinite(x), axis=1))[0]
    if len(bad):
        k = int(bad[0])
        raise ValueError(f"{name} must be finite with shape (n, {x.shape[1]}), n >= 1 [m], got "
                         f"{name}[{k}] = {x[k].tolist()} ({len(bad)} rows not finite)")
    if dimension == 2:
        if x.shape[1] == 2:
            x = np.concatenate([x, np.zeros((len(x), 1))], axis=1)
        elif np.any(x[:, 2] != 0.0):
            k = int(np.nonzero(x[:, 2] != 0.0)[0][0])
            raise ValueError(f"{name}: in 2D the centres lie in the plane z = 0, got {name}[{k}] = "
                             f"{x[k].tolist()} [m]")
    return np.ascontiguousarray(x)


def check_radii(values, n, name="radii"):
    """Radii [n] [m] from a scalar or [n] values, finite and > 0."""
    r = array(name, values, "[m]")
    if r.shape not in ((), (n,)):
        count = f": {r.shape[0]} radii for {n} positions" if r.ndim == 1 else ""
        raise ValueError(f"{name} must be a scalar or have shape ({n},) (one per position) [m], got shape "
                         f"{r.shape}{count}")
    r = np.ascontiguousarray(np.broadcast_to(r, (n,)))
    # a subnormal radius (below DOUBLE_MIN) has lost precision and overflows when inverted
    bad = np.nonzero(~(np.isfinite(r) & (r >= DOUBLE_MIN)))[0]
    if len(bad):
        k = int(bad[0])
        where = "" if r.ndim == 0 or np.ndim(values) == 0 else f"{name}[{k}] = "
        raise ValueError(f"{name} must be finite and > 0 [m] (normal doubles), got {where}{float(r[k])!r}"
                         f"{f' ({len(bad)} such)' if len(bad) > 1 else ''}")
    return r


def check_density(value, n, name="density"):
    """Density [kg/m^3]: a float (scalar given) or [n] array, finite and > 0."""
    if is_real(value):
        try:
            return real(name, value, lo=0.0, unit="[kg/m^3]")
        except ValueError as exc:
            raise ValueError(f"{name} must be a finite number > 0 [kg/m^3] (or one per element): "
                             f"{exc}") from None
    rho = array(name, value, "[kg/m^3]")
    if rho.shape != (n,):
        raise ValueError(f"{name} must be a finite number > 0 [kg/m^3] or have shape ({n},) (one per "
                         f"element), got {short(value)}")
    bad = np.nonzero(~(np.isfinite(rho) & (rho > 0.0)))[0]
    if len(bad):
        k = int(bad[0])
        raise ValueError(f"{name} must be finite and > 0 [kg/m^3], got {name}[{k}] = {float(rho[k])!r}")
    return np.ascontiguousarray(rho)


def check_vectors(values, n, name, unit, dimension=3):
    """Per-element vectors [n, 3] (``velocities`` [m/s], ``angular_velocities`` [rad/s]), finite;
    None stays None. In 2D [n, 2] is also taken (z component 0)."""
    if values is None:
        return None
    v = array(name, values, unit)
    if dimension == 2 and v.ndim == 2 and v.shape[1] == 2:
        v = np.concatenate([v, np.zeros((len(v), 1))], axis=1)
    if v.shape != (n, 3):
        raise ValueError(f"{name} must be finite with shape ({n}, 3) {unit} (one row per position), got "
                         f"shape {v.shape}")
    bad = np.nonzero(~np.all(np.isfinite(v), axis=1))[0]
    if len(bad):
        k = int(bad[0])
        raise ValueError(f"{name} must be finite with shape ({n}, 3) {unit}, got {name}[{k}] = {v[k].tolist()}")
    return np.ascontiguousarray(v)


def check_pairs(values, n, name="pairs"):
    """Bonded pairs [b, 2] int64 of indices into the n positions, each row ordered (i < j) and the
    rows sorted; no self pair, no bond twice. Empty input: [0, 2]."""
    try:
        p = np.asarray(values)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be integer indices of shape (b, 2) into positions, got "
                         f"{short(values)}") from None
    if p.size == 0:
        p = np.zeros((0, 2), np.int64)
    if p.ndim != 2 or p.shape[1] != 2 or p.dtype.kind not in "iu":
        raise ValueError(f"{name} must be integer indices of shape (b, 2) into positions, got "
                         f"{p.dtype} shape {p.shape}")
    if p.dtype.kind == "u" and len(p) and p.max() > np.iinfo(np.int64).max:
        raise ValueError(f"{name} must index elements 0 .. {n - 1}, got values up to {p.max()}")
    p = p.astype(np.int64)
    bad = np.nonzero(np.any((p < 0) | (p >= n), axis=1))[0]
    if len(bad):
        k = int(bad[0])
        raise ValueError(f"{name} must index elements 0 .. {n - 1}, got values in [{p.min()}, {p.max()}] "
                         f"({name}[{k}] = {p[k].tolist()})")
    bad = np.nonzero(p[:, 0] == p[:, 1])[0]
    if len(bad):
        k = int(bad[0])
        raise ValueError(f"{name} must join two different elements (a row has twice the same index): "
                         f"{name}[{k}] = {p[k].tolist()}")
    p = np.sort(p, axis=1)
    order = np.lexsort((p[:, 1], p[:, 0]))
    p = p[order]
    same = np.nonzero(np.all(p[1:] == p[:-1], axis=1))[0] if len(p) > 1 else []
    if len(same):
        k = int(same[0])
        rows = sorted((int(order[k]), int(order[k + 1])))
        raise ValueError(f"{name} must not list the same bond twice: rows {rows[0]} and {rows[1]} both join "
                         f"elements {p[k, 0]} and {p[k, 1]}")
    return np.ascontiguousarray(p)


def check_frame(value, name="frame"):
    """The LRT material frame [3, 3] (rows: unit L, R, T in world coordinates, orthonormal to 1e-9);
    None: identity. The builders' former ``_check_frame``."""
    if value is None:
        return np.eye(3)
    f = array(name, value)
    with np.errstate(over="ignore", invalid="ignore"):   # a huge entry is refused, not warned about
        orthonormal = f.shape == (3, 3) and np.all(np.isfinite(f)) and np.allclose(f @ f.T, np.eye(3), atol=1e-9)
    if not orthonormal:
        raise ValueError(f"{name} must be a (3, 3) orthonormal matrix whose rows are the material axes L, R, T "
                         f"in world coordinates, got {short(f.tolist())}")
    return np.ascontiguousarray(f)


def check_viscous_damping(value, name="viscous_damping"):
    """The global drag rate C [1/s] (``-C m v``): a finite number >= 0."""
    return real(name, value, lo=0.0, lo_open=False, unit="[1/s]", note="global drag rate C")


def _box(box_lo, box_length, periodic):
    lo = np.zeros(3) if box_lo is None else vector3("box_lo", box_lo, "[m]")
    edge = vector3("box_length", box_length, "[m]")
    if not np.all(edge > 0.0):
        raise ValueError(f"box_length = {edge.tolist()}: expected 3 finite edges in (0, inf) [m]")
    per = np.asarray(periodic)
    if per.shape != (3,) or per.dtype != np.bool_:
        raise ValueError(f"periodic = {short(periodic)}: expected 3 booleans (one per axis x, y, z)")
    return lo, edge, per


def check_overlaps(positions, radii, pairs=None, box_lo=None, box_length=None, periodic=(True, True, True),
             coincident=COINCIDENT, max_overlap=MAX_OVERLAP):
    """``positions`` [n, 3] unchanged if no two centres coincide and no unbonded pair overlaps
    deeply, else ValueError with the count and the first offending pair (module docstring).

    positions [n, 3] [m], radii [n] [m] (already checked); pairs [b, 2]: bonded pairs, exempt from
    the depth bound; box_length [3] [m] (with box_lo [3], periodic [3] bools): minimum-image
    distances along the periodic axes (None: no box). ``coincident``, ``max_overlap``: the bounds,
    as fractions of the smaller radius of a pair.
    """
    from scipy.spatial import cKDTree

    x = np.asarray(positions, dtype=np.float64)
    r = np.asarray(radii, dtype=np.float64)
    n = len(x)
    if n == 0:
        return x
    f = float(max_overlap)
    y, boxsize, edge = x, None, None
    if box_length is not None:
        lo, edge, per = _box(box_lo, box_length, periodic)
        edge = np.where(per, edge, np.inf)
        y = x - lo
        y = np.where(per, np.mod(y, np.where(per, edge, 1.0)), y)
        y = np.where(y >= edge, y - np.where(per, edge, 0.0), y)   # mod may round up to the edge
        boxsize = np.where(per, edge, 0.0)                        # cKDTree: 0 = not periodic
        a = int(np.argmax(np.where(per, -edge, -np.inf)))
        k = int(np.argmax(r))
        if per[a] and 2.0 * r[k] - edge[a] > f * r[k]:
            raise ValueError(f"positions: element {k} (radius {r[k]:.4g} m) overlaps its own periodic image "
                             f"along {'xyz'[a]} by more than {f:g} of its radius (box_length[{a}] = "
                             f"{edge[a]:.4g} m): expected edges above {(2.0 - f) * r[k]:.4g} m")
    # radius classes of a factor 2, each pair of classes searched within its own reach
    cls = np.floor(np.log2(r / r.min())).astype(np.int64)
    members = [np.nonzero(cls == c)[0] for c in np.unique(cls)]
    trees = [cKDTree(y[m], boxsize=boxsize) for m in members]
    found_i, found_j = [], []
    for a, (ma, ta) in enumerate(zip(members, trees)):
        for b in range(a, len(members)):
            mb, tb = members[b], trees[b]
            big, small = max(r[ma].max(), r[mb].max()), min(r[ma].max(), r[mb].max())
            reach = max(big + max(1.0 - f, 0.0) * small, coincident * small)
            if a == b:
                q = ta.query_pairs(reach, output_type="ndarray")
                i, j = ma[q[:, 0]], ma[q[:, 1]]
            else:
                q = ta.sparse_distance_matrix(tb, reach, output_type="ndarray")
                i, j = ma[q["i"]], mb[q["j"]]
            found_i.append(np.minimum(i, j))
            found_j.append(np.maximum(i, j))
    i = np.concatenate(found_i).astype(np.int64)
    j = np.concatenate(found_j).astype(np.int64)
    if len(i) == 0:
        return x
    order = np.lexsort((j, i))   # the first pair reported is the smallest (i, j)
    i, j = i[order], j[order]
    d = x[j] - x[i]
    if edge is not None:
        d -= np.where(np.isfinite(edge), edge, 0.0) * np.round(d / edge)   # minimum image (inf: 0)
    dist = np.sqrt(np.einsum("kd,kd->k", d, d))
    r_small = np.minimum(r[i], r[j])
    same = dist < coincident * r_small
    if np.any(same):
        k = int(np.argmax(same))
        count = int(same.sum())
        raise ValueError(f"positions: elements {i[k]} and {j[k]} coincide (distance {dist[k]:.3g} m, under "
                         f"{coincident:g} of the smaller radius {r_small[k]:.4g} m)"
                         f"{f'; {count} such pairs' if count > 1 else ''}")
    deep = r[i] + r[j] - dist > f * r_small
    if pairs is not None and len(pairs) and np.any(deep):
        p = np.sort(np.asarray(pairs, dtype=np.int64).reshape(-1, 2), axis=1)
        bonded = np.isin(i * n + j, p[:, 0] * n + p[:, 1])
        deep &= ~bonded
    if np.any(deep):
        k = int(np.argmax(deep))
        count = int(deep.sum())
        images = " (periodic images included)" if edge is not None else ""
        raise ValueError(f"positions: {count} pair{'s' if count > 1 else ''} of unbonded elements overlap by "
                         f"more than {f:g} of the smaller radius{images}; first: elements {i[k]} and {j[k]}, "
                         f"distance {dist[k]:.4g} m, radii {r[i[k]]:.4g} and {r[j[k]]:.4g} m (overlap "
                         f"{(r[i[k]] + r[j[k]] - dist[k]) / r_small[k]:.3g} of the smaller): contact laws "
                         f"hold for small overlaps; check the units, and that radii are not diameters")
    return x


def check_mass(radii, density):
    """Mass ``4/3 pi rho r^3`` [kg] and moment of inertia ``0.4 m r^2`` [kg m^2] of each element
    finite and at least the smallest normal float (tiny radii underflow them to 0, huge ones overflow: the steps would divide by
    them)."""
    with np.errstate(over="ignore", under="ignore"):
        mass = np.asarray(density) * 4.0 / 3.0 * np.pi * np.asarray(radii) ** 3
        inertia = 0.4 * mass * np.asarray(radii) ** 2
    tiny = np.finfo(np.float64).tiny      # below it, 1 / m overflows (subnormal or zero)
    bad = np.nonzero(~(np.isfinite(inertia) & (inertia >= tiny) & np.isfinite(mass) & (mass >= tiny)))[0]
    if len(bad):
        k = int(bad[0])
        raise ValueError(f"radii and density give element {k} a mass of {float(np.ravel(mass)[k]):g} kg and a "
                         f"moment of inertia of {float(np.ravel(inertia)[k]):g} kg m^2: both must be finite and normal numbers "
                         "(SI units: radii [m], density [kg/m^3])")


def check_arrays(positions, radii, density, pairs, dimension=3, box_lo=None, box_length=None,
                 periodic=(True, True, True)):
    """``(x [n, 3], r [n], pairs [b, 2])`` checked (``check_positions``, ``check_radii``,
    ``check_density`` (scalar or [n]), ``check_pairs``, then ``check_overlaps`` with the bonded pairs
    exempt from the depth bound and the optional periodic box). The builders' former
    ``_check_arrays``, plus the overlap check."""
    x = check_positions(positions, dimension)
    n = len(x)
    r = check_radii(radii, n)
    rho = check_density(density, n)
    check_mass(r, rho)
    p = check_pairs(pairs, n)
    check_overlaps(x, r, p, box_lo=box_lo, box_length=box_length, periodic=periodic)
    return x, r, p


__all__ = ["COINCIDENT", "MAX_OVERLAP", "check_positions", "check_radii", "check_density", "check_vectors",
           "check_mass", "check_pairs", "check_frame", "check_viscous_damping", "check_overlaps", "check_arrays"]
