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

from pardem.physics.pair_loads import next_run, store_row
from pardem.physics.quaternion import matrix_entries


@njit(cache=True, inline="always", error_model="numpy")
def _angle_factor(s2, c, exact):
    """``(atan2(s, c) / s, ok)`` with ``s = sqrt(s2)``: turns ``sin(angle) * axis`` into a rotation
    vector. ``exact`` (a compile-time constant) False gives the series branch only, which has no
    call and vectorises: ``ok`` is then False where the series does not apply (``s2 >= 0.01`` or
    ``c <= 0``) and the caller recomputes that bond with ``exact``."""
    if s2 < 0.01 and c > 0.0:
        # asin(s)/s series; truncation error below 3e-10 relative at s = 0.1
        return 1.0 + s2 * (1.0 / 6.0 + s2 * (3.0 / 40.0 + s2 * (5.0 / 112.0))), True
    if not exact:
        return 1.0, False
    if s2 == 0.0:
        return 1.0, True
    s = np.sqrt(s2)
    return np.arctan2(s, c) / s, True


@njit(cache=True, inline="always")
def _bending_rotation(n0, n1, n2, a0, a1, a2, exact):
    """Rotation vector taking the unit chord n to the unit end axis a (angle about n x a), and
    ``_angle_factor``'s ``ok``."""
    c0 = n1 * a2 - n2 * a1
    c1 = n2 * a0 - n0 * a2
    c2 = n0 * a1 - n1 * a0
    k, ok = _angle_factor(c0 * c0 + c1 * c1 + c2 * c2, n0 * a0 + n1 * a1 + n2 * a2, exact)
    return c0 * k, c1 * k, c2 * k, ok


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


BLOCK = 32   # bonds per block of the force loop (16 to 64 measured alike, 128 much slower: the
#              gathered block, 60 rows, must stay in the L1 cache)

# rows of a block's gathered state ``g`` [GATHER_WIDTH, BLOCK] (module constants: Numba compiles
# them in): the chord x_j - x_i, the two rotation matrices (row-major, computed in the block from
# the gathered quaternions), the bond's own constants, and for damping its time constants and the
# ends' rates. The block's force pass then reads ``g`` only: with a dozen arrays to read, LLVM
# would need more run-time alias checks than it makes and would not vectorise the pass.
G_CHORD = 0         # [3] x_j - x_i [m]
G_ROT_1 = 3         # [9] rotation matrix of end 1, row-major
G_ROT_2 = 12        # [9] rotation matrix of end 2
G_U1 = 21           # [3] body-frame bond axis at end 1 (u1), then p1, u2, p2
G_P1 = 24
G_U2 = 27
G_P2 = 30
G_L0 = 33           # L0 [m], ka [N/m], kb [N m^2], kt [N m / rad]
G_KA = 34
G_KB = 35
G_KT = 36
G_Q1 = 37           # [4] quaternion of end 1, then of end 2 (the matrices' source)
G_Q2 = 41
G_TAU_A = 45        # damped only: tau_a, tau_t [s], the rotation damping table [4] [s]
G_TAU_T = 46
G_ROT_DAMPING = 47
G_DV = 51           # [3] v_j - v_i [m/s]
G_W_1 = 54          # [3] w_i [rad/s]
G_W_2 = 57          # [3] w_j [rad/s]
GATHER_WIDTH = 60
GATHER_UNDAMPED = G_TAU_A

# rows of a block's results ``res`` [RES_WIDTH, BLOCK]
OUT_FORCE_1 = 0     # [3] force on end 1 [N] (end 2 gets its opposite)
OUT_MOMENT_1 = 3    # [3] moment on end 1 [N m]
OUT_MOMENT_2 = 6    # [3] moment on end 2 [N m]
OUT_AXIAL = 9       # elastic axial force, tension positive [N] (damping excluded)
OUT_SHEAR = 10      # elastic shear force magnitude [N] (damping excluded)
OUT_ENERGY = 11     # elastic energy [J] (damping excluded)
OUT_STATUS = 12     # DONE, REDO (the series did not apply: recompute exactly) or SKIP (broken)
RES_WIDTH = 13
DONE, REDO, SKIP = 0.0, 1.0, 2.0


@njit(cache=True, inline="always", error_model="numpy")
def _matrix_rows(g, k, quat, rot):
    """Rows ``rot:rot + 9`` of column ``k`` of a gathered block: the rotation matrix (row-major)
    of the quaternion in rows ``quat:quat + 4`` (``quaternion.matrix_entries``, the expression
    ``Elements.refresh_rotations`` uses: the same bits)."""
    (g[rot, k], g[rot + 1, k], g[rot + 2, k], g[rot + 3, k], g[rot + 4, k], g[rot + 5, k],
     g[rot + 6, k], g[rot + 7, k], g[rot + 8, k]) = matrix_entries(g[quat, k], g[quat + 1, k],
                                                                    g[quat + 2, k], g[quat + 3, k])


@njit(cache=True, inline="always", error_model="numpy")
def _turned(g, k, rot, vec):
    """``R u`` of column ``k`` of a gathered block: ``R`` the row-major matrix in rows
    ``rot:rot + 9``, ``u`` the vector in rows ``vec:vec + 3``."""
    u0 = g[vec, k]
    u1 = g[vec + 1, k]
    u2 = g[vec + 2, k]
    return (g[rot, k] * u0 + g[rot + 1, k] * u1 + g[rot + 2, k] * u2,
            g[rot + 3, k] * u0 + g[rot + 4, k] * u1 + g[rot + 5, k] * u2,
            g[rot + 6, k] * u0 + g[rot + 7, k] * u1 + g[rot + 8, k] * u2)


@njit(cache=True, inline="always", error_model="numpy")
def beam_bond(g, k, b, res, exact, damped, densify, f_yield, plastic, p0, breakable):
    """Forces of bond ``b`` from column ``k`` of its block's gathered state ``g`` (``G_*`` rows);
    writes column ``k`` of ``res`` (``OUT_*`` rows): F1, M1, M2, and, for the rupture test (only
    with ``breakable``: a loop of unbreakable bonds skips their square root), the elastic axial
    force (tension positive) and shear force magnitude [N] (damping excluded, the strength
    criterion of docs/physics.md section 7) and the elastic energy [J].

    Returns the status, DONE or, with ``exact`` False, REDO: the angles then use their series
    only (no call, and every store made, so the block's pass vectorises), and where the series
    does not apply the results are meaningless (with ``densify`` not written, ``plastic``
    untouched) and the caller calls again with ``exact`` True, which gives the bond the bits of
    a pass of exact calls (the series branch is the same expression in both).
    ``exact``, ``damped``, ``densify`` and ``breakable`` must be compile-time constants at the
    call site (True or False literals): a loop without them carries no trace of their terms. With
    ``densify``, a bond with ``f_yield[b] > 0`` yields in compression and updates ``plastic[b]``
    (``densified_extension``).
    """
    dx0 = g[G_CHORD, k]
    dx1 = g[G_CHORD + 1, k]
    dx2 = g[G_CHORD + 2, k]
    L = np.sqrt(dx0 * dx0 + dx1 * dx1 + dx2 * dx2)
    inv_L = 1.0 / L
    n0 = dx0 * inv_L
    n1 = dx1 * inv_L
    n2 = dx2 * inv_L
    # world-frame bond axes and twist references at both ends: a_k = R_k u_k, r_k = R_k p_k
    a10, a11, a12 = _turned(g, k, G_ROT_1, G_U1)
    r10, r11, r12 = _turned(g, k, G_ROT_1, G_P1)
    a20, a21, a22 = _turned(g, k, G_ROT_2, G_U2)
    r20, r21, r22 = _turned(g, k, G_ROT_2, G_P2)

    # bending rotations th_k = rotation vector taking n to a_k
    t10, t11, t12, ok1 = _bending_rotation(n0, n1, n2, a10, a11, a12, exact)
    t20, t21, t22, ok2 = _bending_rotation(n0, n1, n2, a20, a21, a22, exact)

    # twist: both references carried onto the chord, then the signed angle between them about n
    s10, s11, s12 = _carry_twist_ref(a10, a11, a12, n0, n1, n2, r10, r11, r12)
    s20, s21, s22 = _carry_twist_ref(a20, a21, a22, n0, n1, n2, r20, r21, r22)
    st = n0 * (s11 * s22 - s12 * s21) + n1 * (s12 * s20 - s10 * s22) + n2 * (s10 * s21 - s11 * s20)
    ct = s10 * s20 + s11 * s21 + s12 * s22
    kw, ok3 = _angle_factor(st * st, ct, exact)
    status = DONE
    if not exact:
        status = DONE if (ok1 and ok2 and ok3) else REDO
        if densify:          # the yield updates plastic[b]: once, in the exact call
            if status == REDO:
                return status
    tw = st * kw

    l0 = g[G_L0, k]
    dL = L - l0
    if densify:
        if f_yield[b] > 0.0:
            dL = densified_extension(dL, l0, g[G_KA, k], f_yield[b], p0, plastic, b)
    kbL = 2.0 * g[G_KB, k] / l0
    res[OUT_ENERGY, k] = 0.5 * g[G_KA, k] * dL * dL + 0.5 * g[G_KT, k] * tw * tw + kbL * (
        t10 * t10 + t11 * t11 + t12 * t12 + t10 * t20 + t11 * t21 + t12 * t22
        + t20 * t20 + t21 * t21 + t22 * t22)

    # elastic axial and shear forces: the rupture test's (damping excluded, docs/physics.md 7)
    fs = 3.0 * kbL * inv_L
    g0 = t10 + t20
    g1 = t11 + t21
    g2 = t12 + t22
    if breakable:
        res[OUT_AXIAL, k] = g[G_KA, k] * dL
        res[OUT_SHEAR, k] = fs * np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)   # th_k normal to n: |n x g| = |g|

    # rates (damping)
    if damped:
        ta = g[G_TAU_A, k]
        tt = g[G_TAU_T, k]
        dv0 = g[G_DV, k]
        dv1 = g[G_DV + 1, k]
        dv2 = g[G_DV + 2, k]
        dL += ta * (dv0 * n0 + dv1 * n1 + dv2 * n2)
        wc0 = (n1 * dv2 - n2 * dv1) * inv_L
        wc1 = (n2 * dv0 - n0 * dv2) * inv_L
        wc2 = (n0 * dv1 - n1 * dv0) * inv_L
        # the two rotation modes damped at ratio zeta each (rotation_damping, tabulated)
        d11 = g[G_ROT_DAMPING, k]
        d12 = g[G_ROT_DAMPING + 1, k]
        d21 = g[G_ROT_DAMPING + 2, k]
        d22 = g[G_ROT_DAMPING + 3, k]
        wi0 = g[G_W_1, k]
        wi1 = g[G_W_1 + 1, k]
        wi2 = g[G_W_1 + 2, k]
        wj0 = g[G_W_2, k]
        wj1 = g[G_W_2 + 1, k]
        wj2 = g[G_W_2 + 2, k]
        e0 = wi0 - wc0
        e1 = wi1 - wc1
        e2 = wi2 - wc2
        en = e0 * n0 + e1 * n1 + e2 * n2
        y10 = e0 - en * n0
        y11 = e1 - en * n1
        y12 = e2 - en * n2
        e0 = wj0 - wc0
        e1 = wj1 - wc1
        e2 = wj2 - wc2
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
        tw += tt * ((wj0 - wi0) * n0 + (wj1 - wi1) * n1 + (wj2 - wi2) * n2)

    fa = g[G_KA, k] * dL
    if damped:
        g0 = t10 + t20
        g1 = t11 + t21
        g2 = t12 + t22
    res[OUT_FORCE_1, k] = fa * n0 + fs * (n1 * g2 - n2 * g1)
    res[OUT_FORCE_1 + 1, k] = fa * n1 + fs * (n2 * g0 - n0 * g2)
    res[OUT_FORCE_1 + 2, k] = fa * n2 + fs * (n0 * g1 - n1 * g0)
    mt = g[G_KT, k] * tw
    res[OUT_MOMENT_1, k] = mt * n0 - kbL * (2.0 * t10 + t20)
    res[OUT_MOMENT_1 + 1, k] = mt * n1 - kbL * (2.0 * t11 + t21)
    res[OUT_MOMENT_1 + 2, k] = mt * n2 - kbL * (2.0 * t12 + t22)
    res[OUT_MOMENT_2, k] = -mt * n0 - kbL * (t10 + 2.0 * t20)
    res[OUT_MOMENT_2 + 1, k] = -mt * n1 - kbL * (t11 + 2.0 * t21)
    res[OUT_MOMENT_2 + 2, k] = -mt * n2 - kbL * (t12 + 2.0 * t22)
    return status


def _bond_loop(damped, breakable, densify):
    """The loop over all bonds with damping, rupture and densification compiled in or out (the
    flags are frozen as constants).

    Blocks of ``BLOCK`` bonds in three passes, as the contact loop (``pair_loop``): gather the
    ends' state (the only indirect reads; the ends' quaternions, whose matrices are then
    computed in the block: 10 fewer numbers gathered per bond, and the step need not keep
    ``Elements.rot`` current), the forces of the block without indirect access or calls (LLVM
    vectorises it), then in bond order the exact recomputation of the rare bonds
    whose angles left the series' range, the rupture test and the scatter, the first end's
    loads kept in registers over a run of bonds with the same first end. The sums to a row are
    made in bond order, as one bond at a time would make them: the results are bitwise those of
    a plain loop over ``beam_bond(..., exact=True)`` (``tests/test_bond_block_loop.py``).
    """
    B = BLOCK
    NG = GATHER_WIDTH if damped else GATHER_UNDAMPED

    @njit(cache=True, error_model="numpy")
    def loop(bi, bj, x, v, w, q, f, t, L0, ka, kb, kt, tau_a, tau_t, rot_damping, u1, p1, u2, p2,
             state, f_tensile, f_shear, f_yield, plastic, p0, n_owned):
        g = np.zeros((NG, B))      # zeros: a broken bond's column is never uninitialised memory
        res = np.empty((RES_WIDTH, B))
        energy = 0.0
        broken = 0
        counted = 0
        cur = -1                     # the row whose loads are in fi, ti
        fi0 = fi1 = fi2 = ti0 = ti1 = ti2 = 0.0
        n_bonds = bi.shape[0]
        for b0 in range(0, n_bonds, B):
            m = min(B, n_bonds - b0)
            for k in range(m):       # gather
                b = b0 + k
                if breakable:
                    if state[b] != 0:
                        continue
                # unsigned rows: no negative-index wrap-around code per access
                i = np.uint64(bi[b])
                j = np.uint64(bj[b])
                g[G_CHORD, k] = x[j, 0] - x[i, 0]
                g[G_CHORD + 1, k] = x[j, 1] - x[i, 1]
                g[G_CHORD + 2, k] = x[j, 2] - x[i, 2]
                for c in range(4):
                    g[G_Q1 + c, k] = q[i, c]
                    g[G_Q2 + c, k] = q[j, c]
                for d in range(3):
                    g[G_U1 + d, k] = u1[b, d]
                    g[G_P1 + d, k] = p1[b, d]
                    g[G_U2 + d, k] = u2[b, d]
                    g[G_P2 + d, k] = p2[b, d]
                g[G_L0, k] = L0[b]
                g[G_KA, k] = ka[b]
                g[G_KB, k] = kb[b]
                g[G_KT, k] = kt[b]
                if damped:
                    g[G_TAU_A, k] = tau_a[b]
                    g[G_TAU_T, k] = tau_t[b]
                    for d in range(4):
                        g[G_ROT_DAMPING + d, k] = rot_damping[b, d]
                    for d in range(3):
                        g[G_DV + d, k] = v[j, d] - v[i, d]
                        g[G_W_1 + d, k] = w[i, d]
                        g[G_W_2 + d, k] = w[j, d]
            for k in range(m):       # the ends' rotation matrices (vectorised)
                _matrix_rows(g, k, G_Q1, G_ROT_1)
                _matrix_rows(g, k, G_Q2, G_ROT_2)
            for k in range(m):       # forces, no indirect access: vectorised
                b = b0 + k
                if densify:          # (not vectorised: exp) a broken bond must not yield
                    if breakable:
                        if state[b] != 0:
                            res[OUT_STATUS, k] = SKIP
                            continue
                # a broken bond's column holds stale values: computed, then dropped (SKIP)
                status = beam_bond(g, k, b, res, False, damped, densify, f_yield, plastic, p0,
                                   breakable)
                if breakable:
                    status = SKIP if state[b] != 0 else status
                res[OUT_STATUS, k] = status
            for k in range(m):       # exact where needed, rupture, scatter in bond order
                b = b0 + k
                status = res[OUT_STATUS, k]
                if status == SKIP:
                    continue
                if status == REDO:
                    beam_bond(g, k, b, res, True, damped, densify, f_yield, plastic, p0, breakable)
                i = bi[b]
                j = bj[b]
                if breakable:
                    mode = rupture_mode(res[OUT_AXIAL, k], res[OUT_SHEAR, k], f_tensile[b],
                                        f_shear[b])
                    if mode != 0:
                        # a broken bond stops acting at once: its force of this step is not applied
                        state[b] = mode
                        broken += 1
                        if i < n_owned:
                            counted += 1
                        continue
                energy += res[OUT_ENERGY, k]
                if i != cur:         # a new run: store the last one's loads, load this one's
                    cur, fi0, fi1, fi2, ti0, ti1, ti2 = next_run(f, t, cur, i, fi0, fi1, fi2, ti0,
                                                                 ti1, ti2)
                # as pair_loads.scatter_pair (j != i: a bond never joins a row to itself)
                fi0 += res[OUT_FORCE_1, k]
                fi1 += res[OUT_FORCE_1 + 1, k]
                fi2 += res[OUT_FORCE_1 + 2, k]
                ju = np.uint64(j)
                f[ju, 0] -= res[OUT_FORCE_1, k]
                f[ju, 1] -= res[OUT_FORCE_1 + 1, k]
                f[ju, 2] -= res[OUT_FORCE_1 + 2, k]
                ti0 += res[OUT_MOMENT_1, k]
                ti1 += res[OUT_MOMENT_1 + 1, k]
                ti2 += res[OUT_MOMENT_1 + 2, k]
                t[ju, 0] += res[OUT_MOMENT_2, k]
                t[ju, 1] += res[OUT_MOMENT_2 + 1, k]
                t[ju, 2] += res[OUT_MOMENT_2 + 2, k]
        if cur >= 0:
            store_row(f, t, cur, fi0, fi1, fi2, ti0, ti1, ti2)
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
    return kernel(b.i, b.j, e.x, e.v, e.w, e.q, e.f, e.t, b.L0, b.ka, b.kb, b.kt, b.tau_a, b.tau_t,
                  b.rot_damping, b.u1, b.p1, b.u2, b.p2, b.state, b.f_tensile, b.f_shear, b.f_yield,
                  b.plastic, b.densify_p0 if densify else 1.0, e.n_owned)
