"""Critical time step of velocity Verlet for bonded elements and plates. docs/physics.md section 10.

Verlet is stable while ``dt < 2 / omega_max``. The largest eigenvalue ``omega_max^2`` of the
mass-scaled stiffness ``M^-1/2 K M^-1/2`` is bounded by the block Gershgorin theorem with 3x3 blocks
and spectral norms, which are frame independent: for each element row (translation, rotation)
``omega_max^2 <= sum over its blocks ||K_ab|| / sqrt(M_a M_b)``. Per beam bond the block norms are
``max(ES/L, 12EI/L^3)`` (translation), ``6EI/L^2`` (translation-rotation), ``max(GI0/L, 4EI/L)``
(own rotation) and ``max(GI0/L, 2EI/L)`` (rotation-rotation across).

Bond damping is stiffness-proportional (damping = tau * stiffness per bond), so a mode of frequency
omega has damping ratio ``tau omega / 2``; central differences with such damping are stable for
``dt < (2/omega)(sqrt(1 + zeta^2) - zeta) = sqrt(tau^2 + 4/omega^2) - tau``, taken at the largest
``omega`` and ``tau``. The result is a sufficient bound, tighter than the per-bond ``sqrt(m/k)``
when elements have many bonds.
"""
import numpy as np
from numba import njit

from pardem.physics.contact_frame import overlap, pair_separation


@njit(cache=True, error_model="numpy")
def eigen_bound(bi, bj, L0, ka, kb, kt, mass, inertia, n_owned, plate_k_per_mass):
    """Upper bound of ``omega^2`` [1/s^2] over the owned elements' rows.

    plate_k_per_mass : [n_total] plate stiffness over mass already felt by each element (0 if none).
    """
    n = mass.shape[0]
    lam_t = plate_k_per_mass.copy()
    lam_r = np.zeros(n)
    for b in range(bi.shape[0]):
        i = bi[b]
        j = bj[b]
        L = L0[b]
        ktt = max(ka[b], 12.0 * kb[b] / L**3)
        ktr = 6.0 * kb[b] / L**2
        krr_own = max(kt[b], 4.0 * kb[b] / L)
        krr_x = max(kt[b], 2.0 * kb[b] / L)
        for a, o in ((i, j), (j, i)):
            ma, mo, ia, io = mass[a], mass[o], inertia[a], inertia[o]
            lam_t[a] += ktt / ma + ktr / np.sqrt(ma * ia) + ktt / np.sqrt(ma * mo) + ktr / np.sqrt(ma * io)
            lam_r[a] += ktr / np.sqrt(ia * ma) + krr_own / ia + ktr / np.sqrt(ia * mo) + krr_x / np.sqrt(ia * io)
    worst = 0.0
    for k in range(n_owned):
        worst = max(worst, lam_t[k], lam_r[k])
    return worst


@njit(cache=True, inline="always", error_model="numpy")
def touching_stiffness(i, j, s0, s1, s2, x, radius, k_constant, k_hertz):
    """``(k, |d|^2)`` of pair (i, j) with image shift (s0, s1, s2) [m]: its normal stiffness
    ``k_constant + k_hertz sqrt(R* delta)`` [N/m] and squared centre distance [m^2]; ``k = -1``
    when the spheres do not touch."""
    _, _, _, dist2, ri, rj, rsum = pair_separation(i, j, s0, s1, s2, x, radius)
    if dist2 >= rsum * rsum:
        return -1.0, dist2
    delta = overlap(dist2, rsum)[1]
    return k_constant + k_hertz * np.sqrt(ri * rj / rsum * delta), dist2


@njit(cache=True, error_model="numpy")
def contact_stiffness(pi, pj, shift, periodic, x, radius, mass, n_owned, k_constant, k_hertz):
    """Stiffness measures of the normal springs of the pairs ``(pi[p], pj[p])`` in contact
    (``shift`` [n_pairs, 3] [m] added to ``x_j`` when ``periodic``): ``(omega2, kd2)``.

    A touching pair's normal tangent stiffness is ``k = k_constant + k_hertz sqrt(R* delta)`` [N/m]
    (linear law: ``kn, 0``; Hertz: ``0, 2 E*``).

    * ``omega2`` [1/s^2]: upper bound of ``omega^2`` over the owned rows. The pair's 3x3 block
      ``k n n^T`` has norm ``k``, so row ``a`` gets ``k / m_a + k / sqrt(m_a m_b)`` (block Gershgorin,
      as ``eigen_bound``). Tangential springs and torques are not included: the bound is exact for
      frictionless contacts (central forces, no torque), the FIRE preparation's case. Pairs with a
      ghost end count for the owned end only, which is where the maximum is taken.
    * ``kd2`` [N m]: ``sum k |d|^2`` over the pairs whose ``i`` is owned (each pair once over the
      ranks), the network's affine stiffness: under the affine map ``x -> (1 + e) x`` of the cell
      the frictionless Love-Weber pressure changes by ``dp/de = -(kd2 / (3 V) + 2 p)``.
    """
    lam = np.zeros(x.shape[0])
    kd2 = 0.0
    s0 = s1 = s2 = 0.0
    for p in range(pi.shape[0]):
        i = pi[p]
        j = pj[p]
        if periodic:
            s0, s1, s2 = shift[p, 0], shift[p, 1], shift[p, 2]
        k, dist2 = touching_stiffness(i, j, s0, s1, s2, x, radius, k_constant, k_hertz)
        if k < 0.0:
            continue
        cross = k / np.sqrt(mass[i] * mass[j])
        lam[i] += k / mass[i] + cross
        lam[j] += k / mass[j] + cross
        if i < n_owned:
            kd2 += k * dist2
    worst = 0.0
    for a in range(n_owned):
        worst = max(worst, lam[a])
    return worst, kd2


def critical_time_step(omega2_max, tau_max=0.0):
    """``dt_c = sqrt(tau^2 + 4 / omega_max^2) - tau`` [s]; ``inf`` when nothing is stiff.

    omega2_max : bound of omega^2 [1/s^2] (``eigen_bound``); tau_max : largest bond damping time
    constant c/k [s] (0 without damping).
    """
    if omega2_max <= 0.0:
        return np.inf
    t = float(tau_max)
    return float(np.sqrt(t * t + 4.0 / omega2_max) - t)


def max_tau(bonds):
    """Largest damping time constant of ``bonds`` [s] (0 for none)."""
    if bonds.n == 0:
        return 0.0
    return float(max(bonds.tau_a.max(), bonds.tau_b.max(), bonds.tau_t.max()))


def rayleigh_time_step(radius, density, shear_modulus, poisson):
    """Rayleigh-wave time step of Hertz contacts [s]: ``pi R sqrt(rho / G) / (0.1631 nu + 0.8766)``
    with the smallest radius ``R`` [m] (the time a Rayleigh wave takes to cross a sphere).

    Hertz stiffness grows with overlap, so there is no fixed ``sqrt(m/k)``; this is the usual bound
    of granular codes (Li, Xu, Thornton 2005), independent of impact speed. Runs take a fraction of
    it (0.1-0.3).
    """
    return float(np.pi * radius * np.sqrt(density / shear_modulus) / (0.1631 * poisson + 0.8766))


def linear_contact_time_step(mass, kn, zeta=0.0):
    """Stability limit of Verlet for a linear spring-dashpot contact [s]: the pair's relative motion
    is an oscillator of frequency ``omega = sqrt(kn / m*)`` with the smallest ``m* = m / 2`` [kg]
    (two spheres of the smallest mass), damping ratio ``zeta``: ``dt < (2/omega)(sqrt(1 + zeta^2) -
    zeta)``. A sphere with several contacts at once needs a fraction of it (0.1-0.3)."""
    omega = np.sqrt(kn / (0.5 * mass))
    return float(2.0 / omega * (np.sqrt(1.0 + zeta * zeta) - zeta))
