"""Velocity Verlet for translation and rotation of spheres. docs/physics.md section 10.

One step is ``kick_drift`` (half kick, drift, orientation update, force reset), then the force
kernels, then ``kick`` (second half kick). Spheres have isotropic inertia, so the world-frame angular
velocity obeys ``I dw/dt = torque`` and the orientation follows the exact quaternion exponential.
"""
import numpy as np
from numba import njit

from pardem.physics.neighbours import larger_displacement2
from pardem.physics.quaternion import (SERIES_ANGLE2, matrix_entries, quat_to_matrix_into,
                                      rotate_world, series_factors, turned)


BLOCK = 64   # rows per block of kick_drift (the scratch blocks stay in L1)


@njit(cache=True, error_model="numpy")
def kick_drift(x, v, w, q, rot, f, t, inv_mass, inv_inertia, dt, n_owned, with_rot=True, x_ref=None,
               with_q=True):
    """Half kick with the forces of the previous step, drift by ``dt``, then zero ``f`` and ``t``.
    ``with_rot``: also refresh the cached rotation matrices ``rot`` from ``q`` (only the bond
    kernels read them; a run without bonds skips it and refreshes on demand,
    ``Elements.refresh_rotations``). ``with_q`` False: the orientations ``q`` are not advanced
    (nor ``rot``): a run whose kernels and outputs never read them (``Simulation.orientation``).

    ``x_ref`` [>= n_owned, 3] [m]: the positions of the last neighbour-list build; returns then the
    owned rows' largest squared displacement from them after the drift (``neighbours.
    max_displacement2``, the same bits), measured while x is at hand instead of in a pass of its
    own (its 400 us per step were 4 % of a GRAN step on 2 ranks at n = 60). Without it returns 0.0.

    Blocked as the pair loops: per block of ``BLOCK`` rows, a pass updates v, w, x and
    gathers q and ``w dt``; a pass over the block alone (vectorised) applies
    ``quaternion.rotate_world``'s series branch and the rotation matrix of the result; a last pass
    stores them, or runs ``rotate_world`` itself for the rows whose angle leaves the series'
    range (``w dt`` above 0.01 rad, or not finite). Same operations, same bits as one row at a
    time (``tests/test_integrator.py``); 10-15 % faster in the GRAN benchmark at n = 40 (the
    rest is memory traffic).
    """
    h = 0.5 * dt
    moved2 = 0.0
    B = BLOCK
    g = np.empty((7, B))     # per row: q (4), w dt (3)
    r = np.empty((14, B))    # per row: the new q (4), the squared angle, the new rot (9)
    for k0 in range(0, n_owned, B):
        m = min(B, n_owned - k0)
        for kk in range(m):      # kick and drift; gather q and the rotation vector
            k = k0 + kk
            im = inv_mass[k] * h
            ii = inv_inertia[k] * h
            for d in range(3):
                v[k, d] += im * f[k, d]
                w[k, d] += ii * t[k, d]
                x[k, d] += dt * v[k, d]
                f[k, d] = 0.0
                t[k, d] = 0.0
            if x_ref is not None:
                moved2 = larger_displacement2(moved2, x, x_ref, k)
            if not with_q:
                continue
            g[0, kk] = q[k, 0]
            g[1, kk] = q[k, 1]
            g[2, kk] = q[k, 2]
            g[3, kk] = q[k, 3]
            g[4, kk] = w[k, 0] * dt
            g[5, kk] = w[k, 1] * dt
            g[6, kk] = w[k, 2] * dt
        if not with_q:
            continue
        for kk in range(m):      # the series branch of rotate_world, no call: vectorised
            ax = g[4, kk]
            ay = g[5, kk]
            az = g[6, kk]
            ang2 = ax * ax + ay * ay + az * az
            s, c = series_factors(ang2)
            w0, x0, y0, z0 = g[0, kk], g[1, kk], g[2, kk], g[3, kk]
            if ang2 != 0.0:      # rotate_world leaves q as it is
                w0, x0, y0, z0 = turned(c, s, ax, ay, az, w0, x0, y0, z0)
            r[0, kk] = w0
            r[1, kk] = x0
            r[2, kk] = y0
            r[3, kk] = z0
            r[4, kk] = ang2
            if with_rot:
                (r[5, kk], r[6, kk], r[7, kk], r[8, kk], r[9, kk], r[10, kk], r[11, kk], r[12, kk],
                 r[13, kk]) = matrix_entries(w0, x0, y0, z0)
        for kk in range(m):      # store, or the exact exponential where the series does not hold
            k = k0 + kk
            if r[4, kk] < SERIES_ANGLE2:
                q[k, 0] = r[0, kk]
                q[k, 1] = r[1, kk]
                q[k, 2] = r[2, kk]
                q[k, 3] = r[3, kk]
                if with_rot:
                    for a in range(3):
                        for b in range(3):
                            rot[k, a, b] = r[5 + 3 * a + b, kk]
            else:
                rotate_world(q[k], w[k], dt)
                if with_rot:
                    quat_to_matrix_into(q[k], rot[k])
    for k in range(n_owned, x.shape[0]):
        for d in range(3):
            f[k, d] = 0.0
            t[k, d] = 0.0
    return moved2


@njit(cache=True, error_model="numpy")
def kick(v, w, f, t, inv_mass, inv_inertia, dt, n_owned):
    """Second half kick; returns the largest squared speed (a NaN or blow-up shows here)."""
    h = 0.5 * dt
    vmax2 = 0.0
    for k in range(n_owned):
        im = inv_mass[k] * h
        ii = inv_inertia[k] * h
        s = 0.0
        for d in range(3):
            v[k, d] += im * f[k, d]
            w[k, d] += ii * t[k, d]
            s += v[k, d] * v[k, d]
        if s > vmax2 or s != s:   # a NaN, once seen, stays: a later finite row must not hide it
            vmax2 = s
    return vmax2


@njit(cache=True, error_model="numpy")
def kinetic_energy(v, w, mass, inertia, n_owned):
    """Translational plus rotational kinetic energy of the owned elements [J]."""
    e = 0.0
    for k in range(n_owned):
        e += 0.5 * mass[k] * (v[k, 0] ** 2 + v[k, 1] ** 2 + v[k, 2] ** 2)
        e += 0.5 * inertia[k] * (w[k, 0] ** 2 + w[k, 1] ** 2 + w[k, 2] ** 2)
    return e


@njit(cache=True, error_model="numpy")
def enforce_plane(x, v, w, f, t, z0, n_owned, removed):
    """Plane constraint of the owned rows (2D mode, ``pardem.engine.plane``): zero ``f_z``,
    ``t_x``, ``t_y``, ``v_z``, ``w_x``, ``w_y`` and put ``x_z = z0`` [m].

    removed [3]: set to this rank's sum of the removed ``f_z`` [N], ``t_x``, ``t_y`` [N m]. Returns
    the largest ``|x_z - z0|`` [m] found before the reset (0 when the plane held, as it does under
    velocity Verlet once ``v_z = f_z = 0``).
    """
    removed[0] = 0.0
    removed[1] = 0.0
    removed[2] = 0.0
    off = 0.0
    for k in range(n_owned):
        removed[0] += f[k, 2]
        removed[1] += t[k, 0]
        removed[2] += t[k, 1]
        dz = abs(x[k, 2] - z0)
        if dz > off or dz != dz:    # a NaN, once seen, stays
            off = dz
        x[k, 2] = z0
        v[k, 2] = 0.0
        w[k, 0] = 0.0
        w[k, 1] = 0.0
        f[k, 2] = 0.0
        t[k, 0] = 0.0
        t[k, 1] = 0.0
    return off
