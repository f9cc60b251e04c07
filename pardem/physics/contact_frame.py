"""Kinematics shared by the sphere-sphere contact laws (docs/physics.md section 8).

Used by the generic pair loops (``pardem.physics.pair_loop``), the contact laws
(``hertz_mindlin``, ``linear_contact``), the walls and the diagnostics that need a pair's geometry
(``pair_geometry``: cementation, contact-force reports, the packing generator); every function but
``pair_geometry`` is a small inline Numba kernel on scalars, so a contact law is written as a fixed
sequence of calls (geometry, relative motion, normal law, tangential history with Coulomb cap,
output).

Conventions (the same in every contact law of pardem)
-----------------------------------------------------
* A pair ``(i, j)`` is computed in that order; pair lists order it by global id (``gid_i < gid_j``)
  so that two ranks holding the pair get bitwise-identical results (STYLE pattern 7).
* ``d = (x_j - x_i) + s`` with ``s`` [m] the periodic image shift of the pair (zero without periodicity;
  grouped this way it is exactly antisymmetric, so two ranks computing a pair agree bitwise);
  ``dist = |d|``, unit normal ``n = d / dist`` points from i to j.
* Overlap ``delta = R_i + R_j - dist`` [m], contact when ``delta > 0``.
* Contact point: at ``l_i = R_i - delta / 2`` from the centre of i along ``+n`` and ``l_j = R_j - delta/2``
  from the centre of j along ``-n`` (the middle of the overlap lens). The arms add up to ``dist``, which
  makes the tangential slip zero for every rigid motion of the pair and conserves angular momentum
  exactly; ``l_k`` is the ``R_k`` of docs/physics.md's torque ``R n x ft`` (they differ by ``delta / 2``).
* Relative velocity of the contact point of i with respect to that of j::

      u = v_i - v_j + (l_i w_i + l_j w_j) x n

  ``u . n = d(delta)/dt`` is the approach rate (positive while the spheres close in) and
  ``u_t = u - (u . n) n`` the sliding velocity; the tangential displacement over a step is
  ``ds = u_t dt`` (translation and rotation of both spheres; with velocity Verlet the kernels see the
  half-step velocities, so for translation ``ds`` is exactly the step's displacement).
* The history ``h`` [N], one row ``[3]`` per pair, is the elastic tangential force acting on **i**
  (j feels ``-h``). Per step: ``h`` is carried into the current contact plane (its normal component
  removed, then turned about ``n`` by the mean spin ``(w_i + w_j) . n dt / 2`` of the pair, then
  rescaled to its former magnitude), incremented by ``-kt ds`` and capped at ``mu fn``.
* Output of one pair, ``out[9]`` (same layout as the beam bond): force on i ``F_i = -fn n + ft``
  (j gets ``-F_i``), torque on i ``T_i = l_i n x ft`` and on j ``T_j = l_j n x ft``. Both torques carry
  the same sign because both the arm and the force flip between i and j. Then
  ``T_i + T_j + x_i x F_i + (x_j + s) x F_j = 0`` exactly (the pair conserves angular momentum).
"""
import numpy as np
from numba import njit

from pardem.physics.pair_loads import scatter_pair  # noqa: F401  (re-exported for the laws)


@njit(cache=True, inline="always", error_model="numpy")
def pair_separation(i, j, s0, s1, s2, x, radius):
    """Branch vector ``d = x_j + s - x_i`` [m], ``|d|^2`` and the radii of pair (i, j).

    Returns ``(d0, d1, d2, dist2, ri, rj, ri + rj)``.
    """
    d0 = (x[j, 0] - x[i, 0]) + s0
    d1 = (x[j, 1] - x[i, 1]) + s1
    d2 = (x[j, 2] - x[i, 2]) + s2
    ri = radius[i]
    rj = radius[j]
    return d0, d1, d2, d0 * d0 + d1 * d1 + d2 * d2, ri, rj, ri + rj


@njit(cache=True, inline="always", error_model="numpy")
def overlap(dist2, rsum):
    """Centre distance ``dist`` [m] and overlap ``delta = rsum - dist`` [m] from ``dist^2`` [m^2]
    and the sum of the radii ``rsum`` [m]. Returns ``(dist, delta)``."""
    dist = np.sqrt(dist2)
    return dist, rsum - dist


@njit(cache=True, inline="always", error_model="numpy")
def contact_geometry(d0, d1, d2, dist2, ri, rj, rsum):
    """Unit normal ``n`` (i -> j), overlap ``delta`` [m] and the arms ``li, lj`` [m] of a pair
    (module conventions). Returns ``(n0, n1, n2, delta, li, lj)``."""
    dist, delta = overlap(dist2, rsum)
    inv = 1.0 / dist
    return d0 * inv, d1 * inv, d2 * inv, delta, ri - 0.5 * delta, rj - 0.5 * delta


@njit(cache=True, inline="always", error_model="numpy")
def relative_motion(i, j, v, w, n0, n1, n2, li, lj):
    """Approach rate ``u . n`` [m/s], sliding velocity ``u_t`` [m/s] and mean spin about ``n`` [rad/s].

    Returns ``(un, ut0, ut1, ut2, spin)``, see the module conventions for ``u``.
    """
    a0 = li * w[i, 0] + lj * w[j, 0]
    a1 = li * w[i, 1] + lj * w[j, 1]
    a2 = li * w[i, 2] + lj * w[j, 2]
    u0 = v[i, 0] - v[j, 0] + a1 * n2 - a2 * n1
    u1 = v[i, 1] - v[j, 1] + a2 * n0 - a0 * n2
    u2 = v[i, 2] - v[j, 2] + a0 * n1 - a1 * n0
    un = u0 * n0 + u1 * n1 + u2 * n2
    spin = 0.5 * ((w[i, 0] + w[j, 0]) * n0 + (w[i, 1] + w[j, 1]) * n1 + (w[i, 2] + w[j, 2]) * n2)
    return un, u0 - un * n0, u1 - un * n1, u2 - un * n2, spin


def any_rate(rate):
    """Whether a diagonal strain rate [3] [1/s] has a non-zero (or NaN) component: three scalar
    tests, not ``np.any`` (4 us a call, and it is asked several times a step)."""
    return bool(rate[0] != 0.0 or rate[1] != 0.0 or rate[2] != 0.0)


@njit(cache=True, inline="always", error_model="numpy")
def affine_motion(un, ut0, ut1, ut2, d0, d1, d2, n0, n1, n2, g0, g1, g2):
    """Add the affine part of the relative motion in a cell deforming at diagonal rate ``g`` [1/s].

    In a deforming periodic cell the positions follow the affine field ``g x`` besides the
    velocities (which are the fluctuations about it), so the contact point of i moves relative to
    that of j by the extra velocity ``-g d`` (``d`` = branch vector i -> j). Returns the corrected
    ``(un, ut0, ut1, ut2)``.
    """
    a0 = -g0 * d0
    a1 = -g1 * d1
    a2 = -g2 * d2
    an = a0 * n0 + a1 * n1 + a2 * n2
    return un + an, ut0 + a0 - an * n0, ut1 + a1 - an * n1, ut2 + a2 - an * n2


@njit(cache=True, inline="always", error_model="numpy")
def shear_motion(un, ut0, ut1, ut2, d0, d1, d2, n0, n1, n2, g0, g1, g2, gxy, gxz, gyz):
    """``affine_motion`` in a shearing cell: the velocity gradient ``Lv`` is upper triangular,
    diagonal ``g`` [1/s] and off-diagonal ``(gxy, gxz, gyz)`` = ``(dv_x/dy, dv_x/dz, dv_y/dz)``
    [1/s]; the extra relative velocity of the contact point of i is ``-Lv d`` (an image across y
    moves with the cell at ``gxy L_y`` along x: Lees-Edwards). Returns the corrected
    ``(un, ut0, ut1, ut2)``."""
    a0 = -(g0 * d0 + (gxy * d1 + gxz * d2))
    a1 = -(g1 * d1 + gyz * d2)
    a2 = -g2 * d2
    an = a0 * n0 + a1 * n1 + a2 * n2
    return un + an, ut0 + a0 - an * n0, ut1 + a1 - an * n1, ut2 + a2 - an * n2


@njit(cache=True, inline="always", error_model="numpy")
def add_love_weber(acc, a00, a01, a02, a10, a11, a12, a20, a21, a22, count):
    """Add one loop's Love-Weber sums ``a_ab = sum d_a F_i,b`` and its contact count to ``acc`` [10].

    ``d`` [m] is the branch vector i -> j and ``F_i`` the force on i, so a repulsive contact adds a
    negative diagonal: the stress ``acc[:9] / V`` is positive in tension; ``acc[9]`` counts contacts.
    """
    acc[0] += a00
    acc[1] += a01
    acc[2] += a02
    acc[3] += a10
    acc[4] += a11
    acc[5] += a12
    acc[6] += a20
    acc[7] += a21
    acc[8] += a22
    acc[9] += count


@njit(cache=True, inline="always", error_model="numpy")
def carry_history(hist, p, n0, n1, n2, spin_angle):
    """Carry the stored tangential force ``hist[p]`` into the plane normal to unit ``n``, in place.

    The normal component is removed, the remainder turned by ``spin_angle`` [rad] about ``n``
    (first order, the rescaling makes it a pure rotation) and rescaled to the magnitude it had, so
    a rigid rotation of the pair never changes the magnitude of the stored force. Returns the
    carried force ``(h0, h1, h2)``.
    """
    return carry_force(hist[p, 0], hist[p, 1], hist[p, 2], n0, n1, n2, spin_angle)


@njit(cache=True, inline="always", error_model="numpy")
def carry_force(h0, h1, h2, n0, n1, n2, spin_angle):
    """``carry_history`` on a force given as scalars ``(h0, h1, h2)`` [N] (for stores kept in other
    columns, e.g. the cement's tangential force): normal component removed, turned by
    ``spin_angle`` [rad] about unit ``n``, rescaled to its former magnitude. Returns the carried
    force."""
    mag2 = h0 * h0 + h1 * h1 + h2 * h2
    if mag2 == 0.0:
        return 0.0, 0.0, 0.0
    hn = h0 * n0 + h1 * n1 + h2 * n2
    h0 -= hn * n0
    h1 -= hn * n1
    h2 -= hn * n2
    c0 = spin_angle * (n1 * h2 - n2 * h1)
    c1 = spin_angle * (n2 * h0 - n0 * h2)
    c2 = spin_angle * (n0 * h1 - n1 * h0)
    h0 += c0
    h1 += c1
    h2 += c2
    left2 = h0 * h0 + h1 * h1 + h2 * h2
    if left2 == 0.0:
        return 0.0, 0.0, 0.0
    s = np.sqrt(mag2 / left2)
    return h0 * s, h1 * s, h2 * s


@njit(cache=True, inline="always", error_model="numpy")
def coulomb_cap(f0, f1, f2, cap):
    """``f`` scaled back to magnitude ``cap`` [N] when it exceeds it (``cap >= 0``)."""
    mag2 = f0 * f0 + f1 * f1 + f2 * f2
    if mag2 <= cap * cap:
        return f0, f1, f2
    s = cap / np.sqrt(mag2)
    return f0 * s, f1 * s, f2 * s


@njit(cache=True, inline="always", error_model="numpy")
def update_history(hist, p, n0, n1, n2, ut0, ut1, ut2, spin, dt, kt, cap):
    """Incremental elastic tangential force of pair ``p``: carry, add ``-kt u_t dt``, Coulomb cap.

    ``hist[p]`` is overwritten with the new value, which is also returned ``(h0, h1, h2)`` [N].
    """
    h0, h1, h2 = carry_history(hist, p, n0, n1, n2, spin * dt)
    k = kt * dt
    h0, h1, h2 = coulomb_cap(h0 - k * ut0, h1 - k * ut1, h2 - k * ut2, cap)
    hist[p, 0] = h0
    hist[p, 1] = h1
    hist[p, 2] = h2
    return h0, h1, h2


@njit(cache=True, inline="always", error_model="numpy")
def clear_history(hist, p):
    hist[p, 0] = 0.0
    hist[p, 1] = 0.0
    hist[p, 2] = 0.0


@njit(cache=True, inline="always", error_model="numpy")
def write_pair(out, n0, n1, n2, fn, ft0, ft1, ft2, li, lj):
    """Fill ``out[9]`` = (F_i, T_i, T_j) from the normal force ``fn`` [N] (repulsive > 0) and the
    tangential force ``ft`` on i [N]."""
    out[0] = ft0 - fn * n0
    out[1] = ft1 - fn * n1
    out[2] = ft2 - fn * n2
    c0 = n1 * ft2 - n2 * ft1
    c1 = n2 * ft0 - n0 * ft2
    c2 = n0 * ft1 - n1 * ft0
    out[3] = li * c0
    out[4] = li * c1
    out[5] = li * c2
    out[6] = lj * c0
    out[7] = lj * c1
    out[8] = lj * c2


@njit(cache=True, error_model="numpy")
def _pair_geometry(pi, pj, shift, periodic, x, radius, d, n, dist, delta):
    for p in range(pi.shape[0]):
        s0 = s1 = s2 = 0.0
        if periodic:
            s0, s1, s2 = shift[p, 0], shift[p, 1], shift[p, 2]
        d0, d1, d2, dist2, ri, rj, rsum = pair_separation(pi[p], pj[p], s0, s1, s2, x, radius)
        n0, n1, n2, dl, _, _ = contact_geometry(d0, d1, d2, dist2, ri, rj, rsum)
        d[p, 0], d[p, 1], d[p, 2] = d0, d1, d2
        n[p, 0], n[p, 1], n[p, 2] = n0, n1, n2
        dist[p], delta[p] = overlap(dist2, rsum)


def pair_geometry(i, j, shift, x, radius):
    """Geometry of the pairs ``(i[p], j[p])`` exactly as the contact kernels see it (the same bits).

    i, j : [n_pairs] rows; shift : None or [n_pairs, 3] periodic image shift of ``x_j`` [m];
    x [n, 3] [m], radius [n] [m]. Returns ``(d, n, dist, delta)``: branch vector i -> j [n_pairs, 3]
    [m], unit normal [n_pairs, 3], centre distance [n_pairs] [m] and overlap [n_pairs] [m]
    (positive in contact).
    """
    m = len(i)
    d, n, dist, delta = np.empty((m, 3)), np.empty((m, 3)), np.empty(m), np.empty(m)
    _pair_geometry(np.ascontiguousarray(i), np.ascontiguousarray(j),
                   NO_SHIFT if shift is None else shift, shift is not None, x, radius, d, n, dist,
                   delta)
    return d, n, dist, delta


def check_pairs(i, j, history, shift, width=3):
    """Check the shapes of a pair list for the Python dispatchers (O(1), no scan of the rows).

    i, j : [n_pairs] integer rows; history : [n_pairs, width] float64; shift : None or
    [n_pairs, 3].
    """
    n_pairs = len(i)
    if len(j) != n_pairs:
        raise ValueError(f"pair arrays differ in length: {len(i)} i, {len(j)} j")
    if history.shape != (n_pairs, width) or history.dtype != np.float64:
        raise ValueError(f"history must be float64 [{n_pairs}, {width}], got {history.dtype} "
                         f"{history.shape}")
    if shift is not None and (shift.shape != (n_pairs, 3) or shift.dtype != np.float64):
        raise ValueError(f"shift must be float64 [{n_pairs}, 3], got {shift.dtype} {shift.shape}")


NO_SHIFT = np.zeros((0, 3))
NO_RATE = np.zeros(3)
