"""Shear band of a 2D sample from a per-grain shear-strain field, and the classical predictions of
its orientation (issue 13, item 3).

``detect``: the grains in the top ``fraction`` of the shear field define the band: its direction
is the principal axis of their shear-weighted positions (a weighted principal-component fit), its
centre their weighted centroid. The width is the full width at half maximum of the mean shear of
all grains binned by their signed distance to that line (bins of ``bin_d`` mean diameters), above
the field's median (the background). One straight band is assumed: two crossing bands (an X)
give the direction of the stronger, or of their bisector when they are equal (look at the map).

Angles are from the x axis (the direction of the lateral, minor principal stress in a biaxial
test loaded along y), folded into [0, 90] degrees. The predictions of the inclination to the
minor principal stress direction: Mohr–Coulomb 45 + phi/2, Roscoe 45 + psi/2, Arthur et al.
45 + (phi + psi)/4 (phi: friction angle, psi: dilatancy angle).
"""
import numpy as np


def predictions(friction_deg, dilatancy_deg):
    """Band inclinations [deg] to the minor principal stress direction from the friction and
    dilatancy angles [deg]."""
    return {"mohr_coulomb": 45.0 + friction_deg / 2.0, "roscoe": 45.0 + dilatancy_deg / 2.0,
            "arthur": 45.0 + (friction_deg + dilatancy_deg) / 4.0}


def _half_max_edge(d, prof, k0, step, level):
    """Distance where the profile falls to ``level`` walking from bin ``k0`` by ``step`` (linear
    interpolation between bin centres; the last centre if it never does)."""
    k = k0
    while 0 <= k + step < len(prof) and np.isfinite(prof[k + step]) and prof[k + step] > level:
        k += step
    if not (0 <= k + step < len(prof)) or not np.isfinite(prof[k + step]):
        return d[k]
    a, b = prof[k], prof[k + step]
    return d[k] + (d[k + step] - d[k]) * (a - level) / (a - b)


def detect(x, shear, d_mean, fraction=0.1, bin_d=1.0):
    """The band of the field ``shear`` [n] at positions ``x`` [n, >= 2] [m] (``d_mean``: the mean
    grain diameter [m]). Returns a dict: ``angle_deg`` (from the x axis, in [0, 90]),
    ``direction`` and ``normal`` (unit [2]), ``centre`` [2] [m], ``width_d`` (FWHM in mean
    diameters), ``peak`` and ``background`` (shear), ``profile`` (``distance_d``, ``shear``)."""
    x = np.asarray(x, dtype=np.float64)[:, :2]
    s = np.asarray(shear, dtype=np.float64)
    good = np.isfinite(s)
    x, s = x[good], s[good]
    if len(s) < 10:
        raise ValueError("a shear band needs the shear of at least 10 grains")
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction {fraction}: expected a value in (0, 1)")
    cut = np.quantile(s, 1.0 - fraction)
    sel = s >= cut
    w = s[sel] - s.min() + 1e-300
    c = (w[:, None] * x[sel]).sum(axis=0) / w.sum()
    r = x[sel] - c
    cov = (w[:, None, None] * r[:, :, None] * r[:, None, :]).sum(axis=0) / w.sum()
    vals, vecs = np.linalg.eigh(cov)
    direction = vecs[:, -1]
    if direction[0] < 0 or (direction[0] == 0 and direction[1] < 0):
        direction = -direction
    normal = np.array([-direction[1], direction[0]])
    angle = np.degrees(np.arctan2(direction[1], direction[0])) % 180.0
    angle = angle if angle <= 90.0 else 180.0 - angle
    dist = (x - c) @ normal / d_mean
    edges = np.arange(np.floor(dist.min() / bin_d), np.ceil(dist.max() / bin_d) + 1) * bin_d
    which = np.clip(np.digitize(dist, edges) - 1, 0, len(edges) - 2)
    counts = np.bincount(which, minlength=len(edges) - 1)
    sums = np.bincount(which, weights=s, minlength=len(edges) - 1)
    prof = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    centres = 0.5 * (edges[1:] + edges[:-1])
    background = float(np.median(s))
    k0 = int(np.nanargmax(prof))
    peak = float(prof[k0])
    level = background + 0.5 * (peak - background)
    lo = _half_max_edge(centres, prof, k0, -1, level)
    hi = _half_max_edge(centres, prof, k0, +1, level)
    return {"angle_deg": float(angle), "direction": direction.tolist(), "normal": normal.tolist(),
            "centre": c.tolist(), "width_d": float(hi - lo), "peak": peak, "background": background,
            "profile": {"distance_d": centres.tolist(), "shear": prof.tolist()}}
