"""Cylinder and triangle-mesh walls: the plane walls' contact law on curved and finite surfaces.

docs/physics.md section 5 (walls). Each kernel finds, for every owned element, its contact with a
surface: a unit normal ``n`` pointing from the surface to the element's centre (into the domain),
an overlap ``delta = R - d > 0`` [m] (``d`` the distance from the centre to the surface) and the
surface's velocity at the contact point; the loads then come from ``pardem.physics.walls.wall_contact``,
the plane walls' own function (linear or Hertz normal law, restitution, friction with the history
carried in the frame of the wall): the same law, the surface taken as locally plane (``R* = R``;
the curvature of the wall is neglected, as LIGGGHTS and Yade do for their walls, good when the
element is much smaller than the radius of curvature).

Cylinders (``cylinders[c]``, 10 numbers): axis point ``p`` [3] [m], unit axis ``a`` [3], radius
``Rc`` [m], side ``s`` (+1: elements inside, -1: outside), extent ``lo, hi`` [m] along ``a`` from
``p`` (an element whose centre projects outside ``[lo, hi]`` does not touch; +-inf: infinite). With
``r = x - p``, the radial vector ``r_perp = r - (r . a) a`` of length ``rho``: inside, ``delta = R +
rho - Rc`` and ``n = -r_perp / rho``; outside, ``delta = R - (rho - Rc)`` and ``n = r_perp / rho``.
The surface velocity is ``V + Omega a x (x_c - p)`` with ``V`` [3] [m/s] the translation and
``Omega`` [rad/s] the spin about the axis (a rotating drum).

Meshes (triangles ``[n_tri, 3, 3]`` [m] in the mesh's own frame, placed at the translation
``shift`` [3] [m], moving at ``V`` [3] [m/s], optionally turned by a rotation ``rot`` about a point
``centre`` of its frame and spinning at ``spin`` [3] [rad/s]: the surface velocity at the contact
point is ``V + spin x (x_c - centre - shift)``): **one contact per element and mesh**, at the point
of the mesh nearest to the centre (over all candidate triangles: a face, an edge or a vertex, by
Ericson's closest-point regions; a tie, such as the shared edge of two coplanar triangles, goes to
the lower triangle index). ``n = (x - c) / |x - c|``; a centre exactly on the surface takes the
triangle's face normal. On a flat or convex surface this is the one contact a sphere has with it,
with no double count where it touches two triangles; a sphere in a concave corner of one mesh
touches only its nearest face: give each face of such a corner its own mesh. Candidate
triangles come from a uniform grid over the mesh's bounding box (``mesh_grid``): a triangle is listed
in every cell its box, inflated by ``reach`` [m], overlaps, so an element of radius ``R <= reach``
finds every triangle it may touch in the cell of its centre. The loop flags an element larger than
``reach``.

History: one column per cylinder and per mesh of the elements' wall history (``walls.new_history``),
after the plane walls' columns; column ``col0 + c``. Forces: ``wall_force[col0 + c]`` is
overwritten with this rank's force of the elements on the surface [N]; meshes also add to
``tri_force`` [n_tri_total, 3] [N] per triangle (the triangle holding the contact point).
"""
import numpy as np
from numba import njit

from pardem.physics.walls import LAWS, _forget, _touch

CYLINDER_WIDTH = 10


def _cylinder_loop(hertz, damped, friction):
    @njit(cache=True, error_model="numpy")
    def loop(x, v, w, radius, mass, f, t, n_owned, cylinders, spins, velocities, col0, hist, dt,
             stiff_n, stiff_t, mu, damp_n, damp_t, wall_force):
        out = np.empty(6)
        vel = np.zeros((col0 + cylinders.shape[0], 3))   # the surface velocity, row of the column
        energy = 0.0
        for c in range(cylinders.shape[0]):
            wl = col0 + c
            p0, p1, p2 = cylinders[c, 0], cylinders[c, 1], cylinders[c, 2]
            a0, a1, a2 = cylinders[c, 3], cylinders[c, 4], cylinders[c, 5]
            rc, side, lo, hi = cylinders[c, 6], cylinders[c, 7], cylinders[c, 8], cylinders[c, 9]
            om = spins[c]
            wall_force[wl, 0] = 0.0
            wall_force[wl, 1] = 0.0
            wall_force[wl, 2] = 0.0
            for k in range(n_owned):
                r0 = x[k, 0] - p0
                r1 = x[k, 1] - p1
                r2 = x[k, 2] - p2
                s = r0 * a0 + r1 * a1 + r2 * a2
                q0 = r0 - s * a0
                q1 = r1 - s * a1
                q2 = r2 - s * a2
                rho = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
                rk = radius[k]
                delta = rk - side * (rc - rho)
                if delta > 0.0 and lo <= s <= hi and rho > 0.0:
                    # inward normal: towards the axis inside, away from it outside
                    n0 = -side * q0 / rho
                    n1 = -side * q1 / rho
                    n2 = -side * q2 / rho
                    # surface velocity at the contact point x_c = x - arm n (radius rho_c)
                    rho_c = rho + side * (rk - 0.5 * delta)
                    e0 = q0 / rho
                    e1 = q1 / rho
                    e2 = q2 / rho
                    vel[wl, 0] = velocities[c, 0] + om * rho_c * (a1 * e2 - a2 * e1)
                    vel[wl, 1] = velocities[c, 1] + om * rho_c * (a2 * e0 - a0 * e2)
                    vel[wl, 2] = velocities[c, 2] + om * rho_c * (a0 * e1 - a1 * e0)
                    energy += _touch(k, wl, delta, n0, n1, n2, x, v, w, radius, mass, f, t, vel, hist, dt,
                                     stiff_n, stiff_t, mu, damp_n, damp_t, out, wall_force, hertz,
                                     damped, friction)
                elif friction:
                    _forget(hist, k, wl)
        return energy
    return loop


_CYL = {}
_MESH = {}


def cylinder_loop(law, damped, friction):
    """The compiled cylinder kernel of one sub-model choice: ``loop(x, v, w, radius, mass, f, t,
    n_owned, cylinders [nc, 10], spins [nc] [rad/s], velocities [nc, 3] [m/s], col0, history, dt,
    stiff_n, stiff_t, mu, damp_n, damp_t, wall_force)`` -> elastic energy [J]."""
    if law not in LAWS:
        raise ValueError(f"walls.law must be one of {', '.join(LAWS)}, got {law!r}")
    key = (law == "hertz", bool(damped), bool(friction))
    if key not in _CYL:
        _CYL[key] = _cylinder_loop(*key)
    return _CYL[key]


# ---------------------------------------------------------------------------------------------
# triangles

@njit(cache=True, inline="always", error_model="numpy")
def closest_on_triangle(y0, y1, y2, tri):
    """The point of triangle ``tri`` [3, 3] nearest to ``y`` (Ericson, Real-Time Collision
    Detection, 5.1.5): ``(c0, c1, c2, region)``, region 0 the face, 1-3 an edge, 4-6 a vertex."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    abx, aby, abz = tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az
    acx, acy, acz = tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az
    apx, apy, apz = y0 - ax, y1 - ay, y2 - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az, 4
    bpx, bpy, bpz = y0 - tri[1, 0], y1 - tri[1, 1], y2 - tri[1, 2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return tri[1, 0], tri[1, 1], tri[1, 2], 5
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        s = d1 / (d1 - d3)
        return ax + s * abx, ay + s * aby, az + s * abz, 1
    cpx, cpy, cpz = y0 - tri[2, 0], y1 - tri[2, 1], y2 - tri[2, 2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return tri[2, 0], tri[2, 1], tri[2, 2], 6
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        s = d2 / (d2 - d6)
        return ax + s * acx, ay + s * acy, az + s * acz, 3
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        s = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        bx, by, bz = tri[1, 0], tri[1, 1], tri[1, 2]
        return bx + s * (tri[2, 0] - bx), by + s * (tri[2, 1] - by), bz + s * (tri[2, 2] - bz), 2
    den = 1.0 / (va + vb + vc)
    s = vb * den
    u = vc * den
    return ax + s * abx + u * acx, ay + s * aby + u * acy, az + s * abz + u * acz, 0


@njit(cache=True, error_model="numpy")
def _grid_counts(tris, lo, h, dims, reach, cell_of):
    """Cells of each triangle's inflated box: per triangle [6] (i0, j0, k0, i1, j1, k1)."""
    nt = tris.shape[0]
    counts = np.zeros(dims[0] * dims[1] * dims[2] + 1, dtype=np.int64)
    for t in range(nt):
        for d in range(3):
            mn = min(tris[t, 0, d], tris[t, 1, d], tris[t, 2, d]) - reach
            mx = max(tris[t, 0, d], tris[t, 1, d], tris[t, 2, d]) + reach
            cell_of[t, d] = max(0, min(dims[d] - 1, int(np.floor((mn - lo[d]) / h))))
            cell_of[t, 3 + d] = max(0, min(dims[d] - 1, int(np.floor((mx - lo[d]) / h))))
        for i in range(cell_of[t, 0], cell_of[t, 3] + 1):
            for j in range(cell_of[t, 1], cell_of[t, 4] + 1):
                for kk in range(cell_of[t, 2], cell_of[t, 5] + 1):
                    counts[(i * dims[1] + j) * dims[2] + kk + 1] += 1
    return counts


@njit(cache=True, error_model="numpy")
def _grid_fill(cell_of, dims, start):
    nt = cell_of.shape[0]
    fill = start[:-1].copy()
    items = np.empty(start[-1], dtype=np.int64)
    for t in range(nt):
        for i in range(cell_of[t, 0], cell_of[t, 3] + 1):
            for j in range(cell_of[t, 1], cell_of[t, 4] + 1):
                for kk in range(cell_of[t, 2], cell_of[t, 5] + 1):
                    c = (i * dims[1] + j) * dims[2] + kk
                    items[fill[c]] = t
                    fill[c] += 1
    return items


MAX_CELLS = 1 << 21


def mesh_grid(triangles, reach):
    """The candidate grid of a mesh: ``(lo [3] [m], h [m], dims [3] int64, start [n_cells + 1],
    items)``: the triangles of cell ``c`` are ``items[start[c]:start[c + 1]]`` (in increasing
    order). Cells of edge ``h >= reach`` over the box of the triangles inflated by ``reach`` [m]."""
    tris = np.ascontiguousarray(triangles, dtype=np.float64)
    lo = tris.reshape(-1, 3).min(axis=0) - reach
    hi = tris.reshape(-1, 3).max(axis=0) + reach
    extent = hi - lo
    n_tri = tris.shape[0]
    # about one triangle per cell, no cell thinner than the reach, a bounded count
    h = max(float(reach), float(np.prod(extent) / max(n_tri, 1)) ** (1.0 / 3.0), float(extent.max()) / 256.0)
    dims = np.maximum(1, np.ceil(extent / h).astype(np.int64))
    while int(np.prod(dims)) > MAX_CELLS:
        h *= 1.5
        dims = np.maximum(1, np.ceil(extent / h).astype(np.int64))
    cell_of = np.empty((n_tri, 6), dtype=np.int64)
    counts = _grid_counts(tris, lo, h, dims, float(reach), cell_of)
    start = np.cumsum(counts)
    items = _grid_fill(cell_of, dims, start)
    return lo, float(h), dims, start, items


def _mesh_loop(hertz, damped, friction):
    @njit(cache=True, error_model="numpy")
    def loop(x, v, w, radius, mass, f, t, n_owned, tris, tri0, lo, h, dims, start, items, reach,
             shift, velocity, rotating, centre, rot, spin, wl, hist, dt, stiff_n, stiff_t, mu, damp_n,
             damp_t, wall_force, tri_force):
        """One mesh (column ``wl``); returns ``(energy [J], the number of owned elements larger
        than reach)``. With ``rotating``, the mesh is turned by ``rot`` [3, 3] about ``centre`` [3]
        (its frame's point, before the shift) and spins at ``spin`` [3] [rad/s]."""
        out = np.empty(6)
        vel = np.zeros((wl + 1, 3))
        vel[wl, 0] = velocity[0]
        vel[wl, 1] = velocity[1]
        vel[wl, 2] = velocity[2]
        energy = 0.0
        too_big = 0
        wall_force[wl, 0] = 0.0
        wall_force[wl, 1] = 0.0
        wall_force[wl, 2] = 0.0
        for k in range(n_owned):
            rk = radius[k]
            if rk > reach:
                too_big += 1
            y0 = x[k, 0] - shift[0]
            y1 = x[k, 1] - shift[1]
            y2 = x[k, 2] - shift[2]
            if rotating:
                # into the mesh's frame: y = rot^T (x - shift - centre) + centre
                q0 = y0 - centre[0]
                q1 = y1 - centre[1]
                q2 = y2 - centre[2]
                y0 = rot[0, 0] * q0 + rot[1, 0] * q1 + rot[2, 0] * q2 + centre[0]
                y1 = rot[0, 1] * q0 + rot[1, 1] * q1 + rot[2, 1] * q2 + centre[1]
                y2 = rot[0, 2] * q0 + rot[1, 2] * q1 + rot[2, 2] * q2 + centre[2]
            i = int(np.floor((y0 - lo[0]) / h))
            j = int(np.floor((y1 - lo[1]) / h))
            kk = int(np.floor((y2 - lo[2]) / h))
            best = -1
            bd2 = rk * rk
            b0 = b1 = b2 = 0.0
            if 0 <= i < dims[0] and 0 <= j < dims[1] and 0 <= kk < dims[2]:
                c = (i * dims[1] + j) * dims[2] + kk
                for m in range(start[c], start[c + 1]):
                    tr = items[m]
                    c0, c1, c2, region = closest_on_triangle(y0, y1, y2, tris[tr])
                    d0 = y0 - c0
                    d1 = y1 - c1
                    d2 = y2 - c2
                    dd = d0 * d0 + d1 * d1 + d2 * d2
                    # strictly nearer: a tie keeps the lower index (items are in increasing order)
                    if dd < bd2:
                        bd2 = dd
                        best = tr
                        b0, b1, b2 = d0, d1, d2
            if best >= 0:
                d = np.sqrt(bd2)
                if d > 0.0:
                    n0, n1, n2 = b0 / d, b1 / d, b2 / d
                else:
                    tri = tris[best]
                    e10 = tri[1, 0] - tri[0, 0]
                    e11 = tri[1, 1] - tri[0, 1]
                    e12 = tri[1, 2] - tri[0, 2]
                    e20 = tri[2, 0] - tri[0, 0]
                    e21 = tri[2, 1] - tri[0, 1]
                    e22 = tri[2, 2] - tri[0, 2]
                    n0 = e11 * e22 - e12 * e21
                    n1 = e12 * e20 - e10 * e22
                    n2 = e10 * e21 - e11 * e20
                    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
                    n0, n1, n2 = n0 / nn, n1 / nn, n2 / nn
                if rotating:
                    # the normal back to the world, and the surface velocity at the contact point
                    m0 = rot[0, 0] * n0 + rot[0, 1] * n1 + rot[0, 2] * n2
                    m1 = rot[1, 0] * n0 + rot[1, 1] * n1 + rot[1, 2] * n2
                    m2 = rot[2, 0] * n0 + rot[2, 1] * n1 + rot[2, 2] * n2
                    n0, n1, n2 = m0, m1, m2
                    arm = rk - 0.5 * (rk - d)
                    c0 = x[k, 0] - arm * n0 - shift[0] - centre[0]
                    c1 = x[k, 1] - arm * n1 - shift[1] - centre[1]
                    c2 = x[k, 2] - arm * n2 - shift[2] - centre[2]
                    vel[wl, 0] = velocity[0] + spin[1] * c2 - spin[2] * c1
                    vel[wl, 1] = velocity[1] + spin[2] * c0 - spin[0] * c2
                    vel[wl, 2] = velocity[2] + spin[0] * c1 - spin[1] * c0
                energy += _touch(k, wl, rk - d, n0, n1, n2, x, v, w, radius, mass, f, t, vel, hist, dt,
                                 stiff_n, stiff_t, mu, damp_n, damp_t, out, wall_force, hertz, damped,
                                 friction)
                tri_force[tri0 + best, 0] -= out[0]
                tri_force[tri0 + best, 1] -= out[1]
                tri_force[tri0 + best, 2] -= out[2]
            elif friction:
                _forget(hist, k, wl)
        return energy, too_big
    return loop


def mesh_loop(law, damped, friction):
    """The compiled mesh kernel of one sub-model choice (see ``_mesh_loop``'s arguments:
    triangles [n_tri, 3, 3] in the mesh frame, ``tri0`` the mesh's first row of ``tri_force``, the
    grid of ``mesh_grid``, ``reach`` [m], the mesh's ``shift`` [3] [m] and ``velocity`` [3] [m/s],
    its history column and force row ``wl``)."""
    if law not in LAWS:
        raise ValueError(f"walls.law must be one of {', '.join(LAWS)}, got {law!r}")
    key = (law == "hertz", bool(damped), bool(friction))
    if key not in _MESH:
        _MESH[key] = _mesh_loop(*key)
    return _MESH[key]


__all__ = ["cylinder_loop", "mesh_loop", "mesh_grid", "closest_on_triangle", "CYLINDER_WIDTH"]
