"""Effective medium theory (affine, Voigt) of Hertz-Mindlin sphere packings. docs/physics.md 8, 11.

Two levels, so that what is compared is exact or has a stated origin:

1. ``affine_sums`` -- the affine (no relaxation) moduli of a given contact list written as sums
   over its contacts, with no assumption on the fabric or the force distribution: the orientation
   averages (invariants ``C_aabb / 9`` and ``(C_abab - C_aabb / 3) / 10``) of the affine stiffness
   tensor of ``pardem.physics.linear_response`` are exactly::

       K_aff  = sum kn r^2 / (9 V) + 2 p / 3
       mu_aff = sum (2 kn + 3 kt) r^2 / (30 V) - 4 p / 5

   (``r`` branch length, ``p = sum fn r / (3 V)``; the ``p`` terms are the pre-stress: the volume
   factor of the Cauchy stress and the normal forces turning with the contacts). For the bulk
   mode the first line is also the exact affine K of the isotropic compression itself (every
   contact sees ``n . eps . n = -e``), fabric or not.

2. ``hertz_mindlin_emt`` -- Walton (1987) / Digby (1981) closed form: the central sums above
   (pre-stress terms dropped) for identical spheres of radius R, every contact carrying the mean
   force ``f = 4 pi R^2 p / (Z phi)`` (from ``sum fn r = 3 p V``, ``r = 2 R``), an isotropic contact
   fabric and no-slip Mindlin springs (``kt / kn = 2 (1 - nu) / (2 - nu)``)::

       K_EMT  = [ Z^2 phi^2 G^2 p / (18 pi^2 (1 - nu)^2) ]^(1/3)
       mu_EMT = (5 - 4 nu) / (5 (2 - nu)) [ 3 Z^2 phi^2 G^2 p / (2 pi^2 (1 - nu)^2) ]^(1/3)

   (``mu_EMT / K_EMT = 3 (5 - 4 nu) / (5 (2 - nu))``; frictionless: ``mu = 3 K / 5``). R drops out.
   ``Z phi = 2 N_c v / V`` with v the mean sphere volume must count the same contacts and volume
   as the sums (all force-carrying contacts, sphere volumes without overlap correction).

   Between 1 and 2 only the force and size distributions differ. Per contact ``kn = 2 (3/4)^(1/3)
   E*^(2/3) R*^(1/3) fn^(1/3)``, so for equal spheres (``r = 2 R`` up to the overlap)
   ``K_sum / K_EMT = mu_sum / mu_EMT = <fn^(1/3)> / <fn>^(1/3)`` (``heterogeneity``): below 1 by
   Jensen's inequality, e.g. ``Gamma(4/3) = 0.893`` for an exponential force distribution. This is
   why EMT overestimates the affine moduli of a real packing; the relaxation lowers them further
   (mostly mu).
"""
import numpy as np


def hertz_mindlin_emt(Z, phi, pressure, shear_modulus, poisson):
    """Walton / Digby affine moduli ``(K, mu)`` [Pa] of identical Hertz-Mindlin spheres (module
    docstring): coordination Z, solid fraction phi, pressure [Pa], grain shear modulus G [Pa] and
    Poisson ratio nu; also ``mu_smooth`` (frictionless, ``kt = 0``). Returns a dict."""
    g, nu, p = float(shear_modulus), float(poisson), float(pressure)
    if not (Z > 0 and 0 < phi < 1 and p > 0 and g > 0 and -1 < nu < 0.5):
        raise ValueError(f"hertz_mindlin_emt: need Z > 0, 0 < phi < 1, pressure > 0, G > 0, -1 < nu < 0.5; "
                         f"got {Z}, {phi}, {p}, {g}, {nu}")
    zp2 = (Z * phi) ** 2 * g * g / (1.0 - nu) ** 2
    K = (zp2 * p / (18.0 * np.pi ** 2)) ** (1.0 / 3.0)
    mu = (5.0 - 4.0 * nu) / (5.0 * (2.0 - nu)) * (3.0 * zp2 * p / (2.0 * np.pi ** 2)) ** (1.0 / 3.0)
    return {"K": float(K), "mu": float(mu), "mu_smooth": float(0.6 * K)}


def affine_sums(r, fn, kn, kt, volume):
    """Affine moduli as sums over the contacts [Pa] (module docstring, level 1): branch lengths
    ``r`` [m], normal forces ``fn`` [N], stiffnesses ``kn``, ``kt`` [N/m] [nc], cell volume
    [m^3]. Returns ``K_central``, ``mu_central`` (no pre-stress), ``K``, ``mu`` (with it) and
    ``pressure``."""
    r, fn, kn, kt = (np.asarray(a, dtype=float) for a in (r, fn, kn, kt))
    p = float(np.sum(fn * r) / (3.0 * volume))
    kc = float(np.sum(kn * r * r) / (9.0 * volume))
    mc = float(np.sum((2.0 * kn + 3.0 * kt) * r * r) / (30.0 * volume))
    return {"K_central": kc, "mu_central": mc, "K": kc + 2.0 * p / 3.0, "mu": mc - 0.8 * p, "pressure": p}


def heterogeneity(fn):
    """``<fn^(1/3)> / <fn>^(1/3)`` of the normal forces [nc]: the ratio of the affine sums to the
    EMT closed form for equal spheres (module docstring)."""
    fn = np.asarray(fn, dtype=float)
    return float(np.mean(np.cbrt(fn)) / np.cbrt(np.mean(fn)))


def packing_Z_phi(n_grains, n_contacts, sphere_volume, volume):
    """``(Z, phi)`` as the EMT needs them: ``Z = 2 N_c / N`` and ``phi = sum v / V`` (sphere volumes
    [m^3] summed, no overlap correction), so that ``Z phi = 2 N_c <v> / V``."""
    return 2.0 * n_contacts / n_grains, float(np.sum(sphere_volume)) / volume
