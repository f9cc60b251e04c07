"""Euler-Bernoulli beam bond (GranOO style) with viscous bond damping. docs/physics.md section 2.

Kinematics of one bond joining ends 1 and 2 (ordered by global id):

* ``n`` = unit chord 1 -> 2, ``L`` its length, ``dL = L - L0``;
* each end carries the bond axis ``a_k = R_k u_k`` and a reference normal ``r_k = R_k p_k``
  (body-frame vectors stored at creation, ``R_k`` the end's rotation matrix);
* bending rotation of section k relative to the chord: the rotation vector ``th_k`` that takes ``n``
  to ``a_k`` (normal to ``n``);
* twist ``tw = th2x - th1x``: signed angle about ``n`` from ``r1`` to ``r2``, each first carried onto
  the chord by the smallest rotation ``a_k -> n`` so that bending does not leak into twist.

Generalised forces (vector form of the local-frame formulas, frame independent)::

    F1 = (E S / L0) dL n + 6 E I / (L0 L) n x (th1 + th2),   F2 = -F1
    M1 = (G I0 / L0) tw n - (2 E I / L0)(2 th1 + th2)
    M2 = -(G I0 / L0) tw n - (2 E I / L0)(th1 + 2 th2)

The shear force uses ``L0 L`` instead of ``L0^2``: it is then exactly the force that balances the end
moments, ``M1 + M2 + L n x F2 = 0`` at any stretch, and agrees with the textbook beam to first order.

Damping: every generalised displacement is replaced by ``d + tau * d'`` with the rates of the same
measures (``dL' = (v2 - v1).n``; bending ``th_k' = (w_k - w_chord)`` normal to ``n`` with
``w_chord = n x (v2 - v1) / L``; twist ``tw' = (w2 - w1).n``) and ``tau = c / k = 2 zeta sqrt(m/k)``
per mode, ``k`` and ``m`` that mode's stiffness and inertia (axial: ``ka``, ``m*``; twist: ``kt``,
``I*``). The two end rotations ``th1``, ``th2`` carry two coupled modes of the free pair, bending
(the ends turning opposite ways, no shear force) and transverse (the same way, carrying the shear
force); they are damped together by ``th_k + sum_l D_kl th_l'`` with the Rayleigh matrix of
``rotation_damping``, which gives both the ratio ``zeta`` for any pair of elements. ``D`` is constant
per bond: it is computed once (``rotation_damping_table``, stored in ``Bonds.rot_damping``) with the
very expression of ``rotation_damping``, so the forces are bitwise those of a per-step evaluation. (One constant
``tau_b`` for both, as before, gave the transverse mode ``2.05 zeta`` for touching identical spheres
and, for R2 = 1.5 R1, 0.69 and 2.10 zeta; ``tests/test_damping_modes.py``.) The damping forces
balance like the elastic ones and vanish for any rigid motion.

Rupture (``rupture_mode``) tests the elastic axial and shear forces, damping excluded.
"""
import numpy as np
from numba import njit

from pardem.physics.pair_loads import scatter_pair


@njit(cache=True, inline="always", error_model="numpy")
def _angle_over_sine(s2, c):
    """``atan2(s, c) / s`` with ``s = sqrt(s2)``: turns ``sin(angle) * axis`` into a rotation vector."""
    if s2 < 0.01 and c > 0.0:
        # asin(s)/s series; truncation error below 3e-10 relative at s = 0.1
        return 1.0 + s2 * (1.0 / 6.0 + s2 * (3.0 / 40.0 + s2 * (5.0 / 112.0)))
    if s2 == 0.0:
        return 1.0
    s = np.sqrt(s2)
    return np.arctan2(s, c) / s


@njit(cache=True, inline="always")
def _bending_rotation(n0, n1, n2, a0, a1, a2):
    """Rotation vector taking the unit chord n to the unit end axis a (angle about n x a)."""
    c0 = n1 * a2 - n2 * a1
    c1 = n2 * a0 - n0 * a2
    c2 = n0 * a1 - n1 * a0
    k = _angle_over_sine(c0 * c0 + c1 * c1 + c2 * c2, n0 * a0 + n1 * a1 + n2 * a2)
    return c0 * k, c1 * k, c2 * k


@njit(cache=True, inline="always", error_model="numpy")
def _carry_twist_ref(ax, ay, az, nx, ny, nz, rx, ry, rz):
    """Apply the smallest rotation taking unit ``a`` to unit ``n`` to ``r``, for ``r`` normal to ``a``.

    Rodrigues' rotation about ``a x n`` reduces, for ``r . a = 0``, to
    ``r - (r . n) / (1 + a . n) * (a + n)``.
    """
    k = (rx * nx + ry * ny + rz * nz) / (1.0 + ax * nx + ay * ny + az * nz)
    return rx - k * (ax + nx), ry - k * (ay + ny), rz - k * (az + nz)


@njit(cache=True, inline="always", error_model="numpy")
def densified_extension(dL, l0, ka, f_yield, p0, plastic, b):
    """Elastic extension [m] of a densifying bond (docs/physics.md section 7); updates ``plastic[b]``.

    The plastic strain p >= 0 shortens the rest length to ``L0 (1 - p)``, so the trial axial force
    is ``F = ka (dL + L0 p)`` (tension positive, ``ka = E S / L0``). In compression, if the trial
    magnitude reaches the threshold ``Fy(p) = f_yield exp(p / p0)``, one Newton step on
    ``g(p) = -ka (dL + L0 p) - Fy(p)`` updates p and the force is set to ``-Fy(p)``; otherwise the
    bond is elastic (unloading follows ``ka`` at fixed p). Tension is always elastic.
    """
    p = plastic[b]
    ext = dL + l0 * p
    fy = f_yield * np.exp(p / p0)
    if -ka * ext >= fy:
        g = -ka * ext - fy
        dg = -ka * l0 - fy / p0
        p -= g / dg
        plastic[b] = p
        ext = -f_yield * np.exp(p / p0) / ka
    return ext


@njit(cache=True, inline="always", error_model="numpy")
def rotation_damping(tau_a, ka, kb, l0, m1, m2, i1, i2):
    """Damping of the two end rotations of a bond: ``(D11, D12, D21, D22)`` [s], the section
    rotations being damped as ``th_k + sum_l D_kl th_l'`` (the same for both bending planes).

    The two rotation modes of the free pair (ends turning opposite ways: bending; the same way:
    transverse, carrying the shear force) have, on ``(th1, th2)`` and with zero angular momentum,
    the stiffness ``K = (2 kb / L0) [[2, 1], [1, 2]]`` and the inertia
    ``M = diag(I1, I2) - [I1, I2]^T [I1, I2] / J``, ``J = I1 + I2 + m* L0^2``. Rayleigh damping
    ``C = beta K + alpha M`` with ``beta = 2 zeta / (w1 + w2)``, ``alpha = 2 zeta w1 w2 / (w1 + w2)``
    (``w1, w2`` the two modes' frequencies) gives both modes the ratio ``zeta`` exactly, for any
    pair; ``D = K^-1 C = beta + alpha K^-1 M``. ``2 zeta = tau_a sqrt(ka / m*)``.
    """
    m_red = m1 * m2 / (m1 + m2)
    two_zeta = tau_a * np.sqrt(ka / m_red)
    inv_j = 1.0 / (i1 + i2 + m_red * l0 * l0)
    M11 = i1 - i1 * i1 * inv_j
    M22 = i2 - i2 * i2 * inv_j
    M12 = -i1 * i2 * inv_j
    det_m = i1 * i2 * m_red * l0 * l0 * inv_j
    k0 = 2.0 * kb / l0
    w_sq_sum = 2.0 * k0 * (i1 + i2 - (i1 * i1 - i1 * i2 + i2 * i2) * inv_j) / det_m
    w_prod = k0 * np.sqrt(3.0 / det_m)
    w_sum = np.sqrt(w_sq_sum + 2.0 * w_prod)
    beta = two_zeta / w_sum
    c = two_zeta * w_prod / w_sum / (3.0 * k0)     # alpha / (3 k0): K^-1 = [[2, -1], [-1, 2]] / (3 k0)
    return (beta + c * (2.0 * M11 - M12), c * (2.0 * M12 - M22),
            c * (2.0 * M12 - M11), beta + c * (2.0 * M22 - M12))


ROT_DAMPING_WIDTH = 4   # columns of ``rotation_damping_table``: D11, D12, D21, D22


@njit(cache=True, error_model="numpy")
def rotation_damping_table(bi, bj, L0, ka, kb, tau_a, mass, inertia):
    """``rotation_damping`` of every bond: [n, ROT_DAMPING_WIDTH] (D11, D12, D21, D22) [s].

    bi, bj [n] : rows of the ends in ``mass`` [kg] and ``inertia`` [kg m^2]; L0 [m], ka [N/m],
    kb [N m^2], tau_a [s] : [n] bond constants. Each row depends on the bond's constants and its
    ends' mass and inertia only, all fixed during a run, so the force loop reads it instead of
    evaluating it (three square roots) every step; the expression is the one the loop used, so
    the forces keep their bits.
    """
    n = bi.shape[0]
    out = np.empty((n, ROT_DAMPING_WIDTH))
    for b in range(n):
        i = bi[b]
        j = bj[b]
        d11, d12, d21, d22 = rotation_damping(tau_a[b], ka[b], kb[b], L0[b], mass[i], mass[j],
                                              inertia[i], inertia[j])
        out[b, 0] = d11
        out[b, 1] = d12
        out[b, 2] = d21
        out[b, 3] = d22
    return out


# layout of ``beam_bond``'s ``out`` row (module constants: Numba compiles them in)
OUT_FORCE_1 = 0     # [3] force on end 1 [N] (end 2 gets its opposite)
OUT_MOMENT_1 = 3    # [3] moment on end 1 [N m]
OUT_MOMENT_2 = 6    # [3] moment on end 2 [N m]
OUT_AXIAL = 9       # elastic axial force, tension positive [N] (damping excluded)
OUT_SHEAR = 10      # elastic shear force magnitude [N] (damping excluded)
OUT_WIDTH = 11


@njit(cache=True, inline="always", error_model="numpy")
def beam_bond(b, i, j, x, v, w, rot, L0, ka, kb, kt, tau_a, tau_t, rot_damping, u1, p1, u2, p2, out,
              damped, densify=False, f_yield=None, plastic=None, p0=0.0, breakable=True):
    """Force on end 1 and moments on ends 1 and 2 of bond ``b``; writes ``out`` [OUT_WIDTH]: F1, M1, M2
    (``OUT_FORCE_1``, ``OUT_MOMENT_1``, ``OUT_MOMENT_2``) and, for the rupture test (only with
    ``breakable``: a loop of unbreakable bonds skips their square root), the axial force
    ``out[OUT_AXIAL]`` (tension positive) and the shear force magnitude ``out[OUT_SHEAR]`` [N]
    (both elastic: damping excluded, the strength criterion of docs/physics.md section 7).

    ``rot_damping`` [n, ROT_DAMPING_WIDTH] : the damping matrix of the two rotation modes of each
    bond (``rotation_damping_table``; read only when ``damped``).
    ``damped``, ``densify`` and ``breakable`` must be compile-time constants at the call site (True or False
    literals): a loop without them carries no trace of their terms. With ``densify``, a bond with
    ``f_yield[b] > 0`` yields in compression and updates ``plastic[b]`` (``densified_extension``).
    Returns the elastic energy of the bond [J] (damping excluded).
    """
    dx0 = x[j, 0] - x[i, 0]
    dx1 = x[j, 1] - x[i, 1]
    dx2 = x[j, 2] - x[i, 2]
    L = np.sqrt(dx0 * dx0 + dx1 * dx1 + dx2 * dx2)
    inv_L = 1.0 / L
    n0 = dx0 * inv_L
    n1 = dx1 * inv_L
    n2 = dx2 * inv_L
    R1 = rot[i]
    R2 = rot[j]
    # world-frame bond axes and twist references at both ends
    a10 = R1[0, 0] * u1[b, 0] + R1[0, 1] * u1[b, 1] + R1[0, 2] * u1[b, 2]
    a11 = R1[1, 0] * u1[b, 0] + R1[1, 1] * u1[b, 1] + R1[1, 2] * u1[b, 2]
    a12 = R1[2, 0] * u1[b, 0] + R1[2, 1] * u1[b, 1] + R1[2, 2] * u1[b, 2]
    r10 = R1[0, 0] * p1[b, 0] + R1[0, 1] * p1[b, 1] + R1[0, 2] * p1[b, 2]
    r11 = R1[1, 0] * p1[b, 0] + R1[1, 1] * p1[b, 1] + R1[1, 2] * p1[b, 2]
    r12 = R1[2, 0] * p1[b, 0] + R1[2, 1] * p1[b, 1] + R1[2, 2] * p1[b, 2]
    a20 = R2[0, 0] * u2[b, 0] + R2[0, 1] * u2[b, 1] + R2[0, 2] * u2[b, 2]
    a21 = R2[1, 0] * u2[b, 0] + R2[1, 1] * u2[b, 1] + R2[1, 2] * u2[b, 2]
    a22 = R2[2, 0] * u2[b, 0] + R2[2, 1] * u2[b, 1] + R2[2, 2] * u2[b, 2]
    r20 = R2[0, 0] * p2[b, 0] + R2[0, 1] * p2[b, 1] + R2[0, 2] * p2[b, 2]
    r21 = R2[1, 0] * p2[b, 0] + R2[1, 1] * p2[b, 1] + R2[1, 2] * p2[b, 2]
    r22 = R2[2, 0] * p2[b, 0] + R2[2, 1] * p2[b, 1] + R2[2, 2] * p2[b, 2]

    # bending rotations th_k = rotation vector taking n to a_k
    t10, t11, t12 = _bending_rotation(n0, n1, n2, a10, a11, a12)
    t20, t21, t22 = _bending_rotation(n0, n1, n2, a20, a21, a22)

    # twist: both references carried onto the chord, then the signed angle between them about n
    s10, s11, s12 = _carry_twist_ref(a10, a11, a12, n0, n1, n2, r10, r11, r12)
    s20, s21, s22 = _carry_twist_ref(a20, a21, a22, n0, n1, n2, r20, r21, r22)
    st = n0 * (s11 * s22 - s12 * s21) + n1 * (s12 * s20 - s10 * s22) + n2 * (s10 * s21 - s11 * s20)
    ct = s10 * s20 + s11 * s21 + s12 * s22
    tw = st * _angle_over_sine(st * st, ct)

    l0 = L0[b]
    dL = L - l0
    if densify:
        if f_yield[b] > 0.0:
            dL = densified_extension(dL, l0, ka[b], f_yield[b], p0, plastic, b)
    kbL = 2.0 * kb[b] / l0
    energy = 0.5 * ka[b] * dL * dL + 0.5 * kt[b] * tw * tw + kbL * (
        t10 * t10 + t11 * t11 + t12 * t12 + t10 * t20 + t11 * t21 + t12 * t22
        + t20 * t20 + t21 * t21 + t22 * t22)

    # elastic axial and shear forces: the rupture test's (damping excluded, docs/physics.md 7)
    fs = 3.0 * kbL * inv_L
    g0 = t10 + t20
    g1 = t11 + t21
    g2 = t12 + t22
    if breakable:
        out[OUT_AXIAL] = ka[b] * dL
        out[OUT_SHEAR] = fs * np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)   # th_k are normal to n: |n x g| = |g|

    # rates (damping)
    if damped:
        ta = tau_a[b]
        tt = tau_t[b]
        dv0 = v[j, 0] - v[i, 0]
        dv1 = v[j, 1] - v[i, 1]
        dv2 = v[j, 2] - v[i, 2]
        dL += ta * (dv0 * n0 + dv1 * n1 + dv2 * n2)
        wc0 = (n1 * dv2 - n2 * dv1) * inv_L
        wc1 = (n2 * dv0 - n0 * dv2) * inv_L
        wc2 = (n0 * dv1 - n1 * dv0) * inv_L
        # the two rotation modes damped at ratio zeta each (rotation_damping, tabulated)
        d11 = rot_damping[b, 0]
        d12 = rot_damping[b, 1]
        d21 = rot_damping[b, 2]
        d22 = rot_damping[b, 3]
        e0 = w[i, 0] - wc0
        e1 = w[i, 1] - wc1
        e2 = w[i, 2] - wc2
        en = e0 * n0 + e1 * n1 + e2 * n2
        y10 = e0 - en * n0
        y11 = e1 - en * n1
        y12 = e2 - en * n2
        e0 = w[j, 0] - wc0
        e1 = w[j, 1] - wc1
        e2 = w[j, 2] - wc2
        en = e0 * n0 + e1 * n1 + e2 * n2
        y20 = e0 - en * n0
        y21 = e1 - en * n1
        y22 = e2 - en * n2
        t10 += d11 * y10 + d12 * y20
        t11 += d11 * y11 + d12 * y21
        t12 += d11 * y12 + d12 * y22
        t20 += d21 * y10 + d22 * y20
        t21 += d21 * y11 + d22 * y21
        t22 += d21 * y12 + d22 * y22
        tw += tt * ((w[j, 0] - w[i, 0]) * n0 + (w[j, 1] - w[i, 1]) * n1 + (w[j, 2] - w[i, 2]) * n2)

    fa = ka[b] * dL
    if damped:
        g0 = t10 + t20
        g1 = t11 + t21
        g2 = t12 + t22
    out[0] = fa * n0 + fs * (n1 * g2 - n2 * g1)
    out[1] = fa * n1 + fs * (n2 * g0 - n0 * g2)
    out[2] = fa * n2 + fs * (n0 * g1 - n1 * g0)
    mt = kt[b] * tw
    out[3] = mt * n0 - kbL * (2.0 * t10 + t20)
    out[4] = mt * n1 - kbL * (2.0 * t11 + t21)
    out[5] = mt * n2 - kbL * (2.0 * t12 + t22)
    out[6] = -mt * n0 - kbL * (t10 + 2.0 * t20)
    out[7] = -mt * n1 - kbL * (t11 + 2.0 * t21)
    out[8] = -mt * n2 - kbL * (t12 + 2.0 * t22)
    return energy


def _bond_loop(damped, breakable, densify):
    """The loop over all bonds with damping, rupture and densification compiled in or out (the
    flags are frozen as constants)."""
    @njit(cache=True, error_model="numpy")
    def loop(bi, bj, x, v, w, rot, f, t, L0, ka, kb, kt, tau_a, tau_t, rot_damping, u1, p1, u2, p2,
             state, f_tensile, f_shear, f_yield, plastic, p0, n_owned):
        out = np.empty(OUT_WIDTH)
        energy = 0.0
        broken = 0
        counted = 0
        for b in range(bi.shape[0]):
            if breakable:
                if state[b] != 0:
                    continue
            i = bi[b]
            j = bj[b]
            e = beam_bond(b, i, j, x, v, w, rot, L0, ka, kb, kt, tau_a, tau_t, rot_damping, u1, p1,
                          u2, p2, out, damped, densify, f_yield, plastic, p0, breakable)
            if breakable:
                mode = rupture_mode(out[OUT_AXIAL], out[OUT_SHEAR], f_tensile[b], f_shear[b])
                if mode != 0:
                    # a broken bond stops acting at once: its force of this step is not applied
                    state[b] = mode
                    broken += 1
                    if i < n_owned:
                        counted += 1
                    continue
            energy += e
            scatter_pair(i, j, f, t, out)
        return energy, broken, counted
    return loop


@njit(cache=True, inline="always")
def rupture_mode(axial, shear, f_tensile, f_shear):
    """0 if the bond holds, 1 if its tension ``axial`` [N] exceeds ``f_tensile``, 2 if its shear
    force ``shear`` [N] exceeds ``f_shear`` (tension is tested first)."""
    if axial > f_tensile:
        return 1
    if shear > f_shear:
        return 2
    return 0


# One compiled loop per combination of (damped, breakable, densify), built on first use.
_LOOPS = {}


def bond_loop(damped, breakable, densify):
    """The bond force loop for these switches: adds the forces and moments of all intact bonds to
    f and t (rows owned or ghost) and returns (elastic energy [J], bonds broken in this call, those
    of them whose first end is owned)."""
    key = (bool(damped), bool(breakable), bool(densify))
    if key not in _LOOPS:
        _LOOPS[key] = _bond_loop(*key)
    return _LOOPS[key]


def compute_bonds(bonds, elements):
    """Add all bond forces of ``bonds`` to ``elements.f``/``elements.t``.

    Returns (elastic energy [J], number of bonds that broke in this call, how many of them this
    rank counts: those whose first end it owns). Damping, rupture and densification are compiled out of the loop when
    no bond uses them. Damped bonds without their ``rot_damping`` table (restored from a
    checkpoint, which does not store it) get it here, from the ends' mass and inertia.
    """
    b, e = bonds, elements
    if b.damped and b.rot_damping.shape[1] != ROT_DAMPING_WIDTH:
        b.rot_damping = rotation_damping_table(b.i, b.j, b.L0, b.ka, b.kb, b.tau_a, e.mass, e.inertia)
    densify = b.densify_p0 > 0.0
    kernel = bond_loop(b.damped, b.breakable, densify)
    return kernel(b.i, b.j, e.x, e.v, e.w, e.rot, e.f, e.t, b.L0, b.ka, b.kb, b.kt, b.tau_a, b.tau_t,
                  b.rot_damping, b.u1, b.p1, b.u2, b.p2, b.state, b.f_tensile, b.f_shear, b.f_yield,
                  b.plastic, b.densify_p0 if densify else 1.0, e.n_owned)
