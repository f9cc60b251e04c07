"""Elastic solutions for a vertical point load on a 2D body: Flamant's half-plane and a periodic
layer on a rigid base (Fourier series). Pure functions over arrays (no MPI, no files).

Conventions (those of pardem's 2D stress, ``pardem.engine.plane``): a force ``F`` [N] acts on a
slab of thickness ``t`` [m] (the mean diameter), so the line load is ``P = F / t`` [N/m] and the
stresses are in Pa, tension positive. ``x`` is the horizontal distance from the load [m], ``z > 0``
the depth below it [m]; the load pushes into the body (downwards, towards +z).

**Flamant** (half-plane z > 0, load at the free surface)::

    sigma_zz = -2 P z^3 / (pi r^4),  sigma_xx = -2 P x^2 z / (pi r^4),  sigma_xz = -2 P x z^2 / (pi r^4)

with ``r^2 = x^2 + z^2``. At every depth ``int sigma_zz dx = -P`` (force balance); its
x-antiderivative is ``-(P / pi) [x z / r^2 + atan(x / z)]`` (``flamant_bin_average``). The profile
``sigma_zz(x)`` at depth z is ``(1 + x^2/z^2)^-2``: second-moment width ``z``, half width at half
maximum ``sqrt(sqrt(2) - 1) z = 0.6436 z`` (an elastic cone, against ``sqrt(2 D z)`` for a
diffusive propagation). ``images``: for a body periodic in x of period L, the load repeated at
``x + m L`` (``|m| <= images``; the terms fall as ``m^-4``).

**Layer on a rigid base** (``layer_sigma_zz``): an isotropic elastic layer ``0 < z < H``, periodic
in x with period L, free surface at z = 0 loaded by ``P delta(x)``, bonded to a rigid base at z = H
(``u = 0``). Plane (2D) elasticity with the 2D Poisson ratio ``nu = (K - mu) / (K + mu)`` (K the
2D bulk modulus, mu the shear modulus; only the ratio matters, ``lambda / mu = 2 nu / (1 - nu)``).
The load is a Fourier series ``delta(x) = 1/L + (2/L) sum_n cos(k_n x)``, ``k_n = 2 pi n / L``; for
each mode the displacements ``u_x = U(z) sin kx``, ``u_z = V(z) cos kx`` obey the Navier equations

    mu U'' - (lambda + 2 mu) k^2 U - (lambda + mu) k V' = 0
    (lambda + 2 mu) V'' - mu k^2 V + (lambda + mu) k U' = 0

whose solution from the surface values ``Z(z) = expm(A z) Z(0)``, ``Z = (U, U', V, V')``, is fitted
to the four conditions ``sigma_xz(0) = 0``, ``sigma_zz(0) = -2 P / L`` (``-P / L`` for n = 0),
``U(H) = V(H) = 0``; ``sigma_zz = lambda k U + (lambda + 2 mu) V'``. Modes with ``k H > KH_CAP``
see a bottom at ``KH_CAP / k`` instead (the bottom's effect on them is ``~ exp(-KH_CAP)``). The
n = 0 mode is ``-P / L`` at every depth: the layer's ``int sigma_zz dx = -P`` whatever H. For
``H >> L`` the series is Flamant's solution with periodic images (``tests/test_response.py``).
"""
import math

import numpy as np
from scipy.linalg import expm

KH_CAP = 18.0   # e^-18 = 1.5e-8: the bottom's relative effect on the modes it is moved for


def line_load(force, thickness):
    """``P = F / t`` [N/m] of a force ``force`` [N] on a 2D slab of thickness ``thickness`` [m]."""
    if not (thickness > 0.0 and math.isfinite(thickness)):
        raise ValueError(f"thickness must be a finite length > 0 [m], got {thickness!r}")
    return float(force) / float(thickness)


def _images(x, period, images):
    x = np.asarray(x, dtype=np.float64)
    if period is None or images == 0:
        return x[..., None]
    m = np.arange(-int(images), int(images) + 1, dtype=np.float64)
    return x[..., None] + m * float(period)


def flamant_stress(x, z, force, thickness, period=None, images=0):
    """Flamant's ``(sigma_xx, sigma_zz, sigma_xz)`` [Pa] at ``x`` [m], depth ``z > 0`` [m] (arrays,
    broadcast), for ``force`` [N] on a slab of ``thickness`` [m]; with ``period`` [m] and
    ``images`` the sum over the loads at ``x + m period``, ``|m| <= images``."""
    P = line_load(force, thickness)
    z = np.asarray(z, dtype=np.float64)
    if np.any(z <= 0.0):
        raise ValueError("z: the depths below the load must be > 0 [m]")
    xs = _images(x, period, images)
    zz = z[..., None]
    r2 = xs * xs + zz * zz
    c = -2.0 * P / (math.pi * r2 * r2)
    return ((c * xs * xs * zz).sum(-1), (c * zz ** 3).sum(-1), (c * xs * zz * zz).sum(-1))


def flamant_sigma_zz(x, z, force, thickness, period=None, images=0):
    """Flamant's vertical stress ``-2 P z^3 / (pi r^4)`` [Pa] (see ``flamant_stress``)."""
    return flamant_stress(x, z, force, thickness, period, images)[1]


def _antiderivative(x, z):
    """``x z / r^2 + atan(x / z)``: pi times the x-antiderivative of ``2 z^3 / (pi r^4)``."""
    return x * z / (x * x + z * z) + np.arctan2(x, z)


def flamant_bin_average(x_edges, z, force, thickness, period=None, images=0):
    """Flamant's ``sigma_zz`` [Pa] averaged over the x bins ``x_edges`` [nx + 1] [m] at the depths
    ``z`` [nz] [m]: [nz, nx] (exact, from the antiderivative)."""
    P = line_load(force, thickness)
    edges = np.asarray(x_edges, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64).reshape(-1, 1, 1)
    if np.any(z <= 0.0):
        raise ValueError("z: the depths below the load must be > 0 [m]")
    g = _antiderivative(_images(edges, period, images)[None, :, :], z).sum(-1)   # [nz, nx + 1]
    return -P / math.pi * np.diff(g, axis=1) / np.diff(edges)[None, :]


def lame_ratio(poisson):
    """``lambda / mu = 2 nu / (1 - nu)`` of 2D (plane) elasticity for the 2D Poisson ratio
    ``nu = (K - mu) / (K + mu)`` in ``(-1, 1)``."""
    nu = float(poisson)
    if not -1.0 < nu < 1.0:
        raise ValueError(f"poisson = {poisson!r}: the 2D Poisson ratio lies in (-1, 1)")
    return 2.0 * nu / (1.0 - nu)


def _mode_matrix(k, lam):
    """``A`` of ``Z' = A Z``, ``Z = (U, U', V, V')``, for mode ``k`` [1/m], mu = 1, lambda = lam."""
    a = lam + 2.0
    return np.array([[0.0, 1.0, 0.0, 0.0],
                     [a * k * k, 0.0, 0.0, (lam + 1.0) * k],
                     [0.0, 0.0, 0.0, 1.0],
                     [0.0, -(lam + 1.0) * k / a, k * k / a, 0.0]])


def layer_modes(depth, layer, period, poisson, n_modes):
    """Amplitudes [n_modes, nz] of ``sigma_zz`` per unit line load (``P = 1`` N/m) of the modes
    ``cos(k_n x)``, n = 0 .. n_modes - 1, at the depths ``depth`` [nz] [m] of a layer of thickness
    ``layer`` [m] on a rigid base, period ``period`` [m] (module docstring)."""
    z = np.asarray(depth, dtype=np.float64).ravel()
    H, L = float(layer), float(period)
    if not (H > 0.0 and L > 0.0):
        raise ValueError("layer and period must be > 0 [m]")
    if np.any(z < 0.0) or np.any(z > H):
        raise ValueError(f"depth must lie in [0, layer = {H:g}] m")
    lam = lame_ratio(poisson)
    out = np.zeros((int(n_modes), len(z)))
    out[0] = -1.0 / L
    for n in range(1, int(n_modes)):
        k = 2.0 * math.pi * n / L
        bottom = min(H, KH_CAP / k)
        A = _mode_matrix(k, lam)
        # scale z by 1/k: the matrix exponential of A z is that of (A / k)(k z), well conditioned
        phi = expm(A * bottom)
        # unknowns Z(0) = (U0, U0', V0, V0'): sigma_xz(0) = U0' - k V0 = 0,
        # sigma_zz(0) = lam k U0 + (lam + 2) V0' = -2 / L, U(bottom) = V(bottom) = 0
        M = np.array([[0.0, 1.0, -k, 0.0], [lam * k, 0.0, 0.0, lam + 2.0], phi[0], phi[2]])
        rhs = np.array([0.0, -2.0 / L, 0.0, 0.0])
        Z0 = np.linalg.solve(M, rhs)
        for m, zz in enumerate(z):
            if zz > bottom:
                continue       # below the moved bottom this mode is < e^-KH_CAP of its surface value
            Zz = expm(A * zz) @ Z0
            out[n, m] = lam * k * Zz[0] + (lam + 2.0) * Zz[3]
    return out


def layer_sigma_zz(x, depth, force, thickness, layer, period, poisson, n_modes=None, bin_width=None):
    """``sigma_zz`` [Pa] [nz, nx] of the layer on a rigid base (module docstring) at ``x`` [nx] [m]
    and ``depth`` [nz] [m] (> 0), for ``force`` [N] on a slab of ``thickness`` [m]. ``n_modes``:
    default enough that ``k z_min`` reaches 40 (the omitted modes are below e^-40 at the
    shallowest depth); ``bin_width`` [m]: average each mode over an x bin of that width (the
    factor ``sinc(k w / 2)``), to compare with binned data."""
    P = line_load(force, thickness)
    x = np.asarray(x, dtype=np.float64).ravel()
    z = np.asarray(depth, dtype=np.float64).ravel()
    if np.any(z <= 0.0):
        raise ValueError("depth: the depths below the load must be > 0 [m]")
    L = float(period)
    if n_modes is None:
        n_modes = int(math.ceil(40.0 * L / (2.0 * math.pi * float(z.min())))) + 1
    amp = layer_modes(z, layer, L, poisson, n_modes)            # [n, nz]
    k = 2.0 * math.pi * np.arange(n_modes) / L
    if bin_width is not None:
        h = 0.5 * k * float(bin_width)
        amp = amp * np.where(h > 0, np.sin(h) / np.where(h > 0, h, 1.0), 1.0)[:, None]
    return P * (amp.T @ np.cos(k[:, None] * x[None, :]))


HWHM_FACTOR = math.sqrt(math.sqrt(2.0) - 1.0)   # Flamant's half width at half maximum over z


__all__ = ["line_load", "flamant_stress", "flamant_sigma_zz", "flamant_bin_average", "lame_ratio",
           "layer_modes", "layer_sigma_zz", "HWHM_FACTOR", "KH_CAP"]
