"""Shear band of a 2D sample from a per-grain shear-strain field, and the classical predictions of
its orientation.

``detect`` works on the grains' shear ranks (0 least, 1 most sheared), so that the few grains a
least-squares strain leaves with huge values (rattlers, ill-conditioned neighbourhoods) weigh no
more than any other well-sheared grain:

* the band is the straight strip (``bin_d`` mean diameters wide) whose grains have the highest mean
  rank: a scan of the strip directions by 1 degree, then by 0.1 degree around the best (a Radon
  transform of the ranks, normalised by each strip's grains, so that a long diagonal strip is not
  favoured for its length). Of two crossing bands (an X) it finds the denser one (a principal-axis
  fit of the most sheared grains would give their bisector);
* the centre is the weighted centroid of the grains in the top ``fraction`` of the shear within a
  strip of the band's line; the width is the full width at half maximum of the profile of the
  median shear of all grains binned by their signed distance to the line, above the field's median
  (the background; medians, not means, for the same reason as the ranks);
* ``contrast``: the median shear of the grains within half a width (at least one bin) of the line
  over the median shear of the others.

A line is always found, so ``detect`` also says whether the field is ``localised``, i.e. the line is
a band, when three things hold: the strip's mean rank beats the best strip of every one of
``NULL_FIELDS`` fields made by shuffling the shears among the grains (a permutation test: the chance
that a field without spatial structure gets there is 1 in NULL_FIELDS + 1 = 5 %); the profile falls
to half its height on both sides inside the sample (a ridge, not the edge of a smooth gradient);
and the contrast is at least ``LOCALISED_CONTRAST`` (a convention: the band's grains shear at least
twice as fast as the others). Only a localised band's angle is meaningful against the predictions.

Angles are from the x axis (the direction of the lateral, minor principal stress in a biaxial
test loaded along y), folded into [0, 90] degrees. The predictions of the inclination to the
minor principal stress direction: Mohr–Coulomb 45 + phi/2, Roscoe 45 + psi/2, Arthur et al.
45 + (phi + psi)/4 (phi: friction angle, psi: dilatancy angle).
"""
import numpy as np

LOCALISED_CONTRAST = 2.0   # median shear in the band over outside it (module docstring: a convention)
NULL_FIELDS = 19           # shuffled fields of the permutation test (a 5 % level)
COARSE = np.radians(np.arange(0.0, 180.0, 1.0))
FINE = np.radians(np.arange(-1.0, 1.01, 0.1))


def predictions(friction_deg, dilatancy_deg):
    """Band inclinations [deg] to the minor principal stress direction from the friction and
    dilatancy angles [deg]."""
    return {"mohr_coulomb": 45.0 + friction_deg / 2.0, "roscoe": 45.0 + dilatancy_deg / 2.0,
            "arthur": 45.0 + (friction_deg + dilatancy_deg) / 4.0}


def _half_max_edge(d, prof, k0, step, level):
    """Distance where the profile falls to ``level`` walking from bin ``k0`` by ``step`` (linear
    interpolation between bin centres), or None if it never does inside the sample."""
    k = k0
    while 0 <= k + step < len(prof) and np.isfinite(prof[k + step]) and prof[k + step] > level:
        k += step
    if not (0 <= k + step < len(prof)) or not np.isfinite(prof[k + step]):
        return None
    a, b = prof[k], prof[k + step]
    return d[k] + (d[k + step] - d[k]) * (a - level) / (a - b)


def _best_strip(x, rank, width, thetas):
    """``(score, theta, offset)``: the strip of ``width`` [m] along ``theta`` [rad] (its normal
    (-sin, cos) theta, its centre line at ``offset`` [m] along it) whose grains have the largest
    mean ``rank``, that mean being the score (strips with fewer than half the median strip's grains
    are left out: a corner's few grains would give noisy means)."""
    best = (-1.0, 0.0, 0.0)
    for theta in thetas:
        dist = x @ np.array([-np.sin(theta), np.cos(theta)])
        k = np.floor((dist - dist.min()) / width).astype(np.int64)
        counts = np.bincount(k)
        sums = np.bincount(k, weights=rank, minlength=len(counts))
        full = counts >= 0.5 * np.median(counts[counts > 0])
        mean = np.where(full, sums / np.maximum(counts, 1), -1.0)
        b = int(np.argmax(mean))
        if mean[b] > best[0]:
            best = (float(mean[b]), theta, dist.min() + (b + 0.5) * width)
    return best


def detect(x, shear, d_mean, fraction=0.1, bin_d=1.0):
    """The band of the field ``shear`` [n] at positions ``x`` [n, >= 2] [m] (``d_mean``: the mean
    grain diameter [m]). Returns a dict: ``angle_deg`` (from the x axis, in [0, 90]),
    ``direction`` and ``normal`` (unit [2]), ``centre`` [2] [m], ``width_d`` (FWHM in mean
    diameters; NaN without a ridge), ``peak`` and ``background`` (the profile's median shear at the
    band, the field's), ``score`` and ``null_score`` (the band strip's mean rank, the best of the
    shuffled fields'), ``contrast``, ``localised`` (bool; module docstring), ``profile``
    (``distance_d``, ``shear``: the median shear per bin)."""
    x = np.asarray(x, dtype=np.float64)[:, :2]
    s = np.asarray(shear, dtype=np.float64)
    good = np.isfinite(s)
    x, s = x[good], s[good]
    if len(s) < 10:
        raise ValueError("a shear band needs the shear of at least 10 grains")
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction {fraction}: expected a value in (0, 1)")
    width = d_mean * bin_d
    rank = np.argsort(np.argsort(s, kind="stable"), kind="stable") / (len(s) - 1.0)
    coarse = _best_strip(x, rank, width, COARSE)
    score, theta, offset = _best_strip(x, rank, width, coarse[1] + FINE)
    rng = np.random.default_rng(0)        # the same null fields every call: reproducible verdicts
    null_score = max(_best_strip(x, rng.permutation(rank), width, COARSE)[0] for _ in range(NULL_FIELDS))
    top = s >= np.quantile(s, 1.0 - fraction)
    sel = top & (np.abs(x @ np.array([-np.sin(theta), np.cos(theta)]) - offset) <= width)
    sel = sel if sel.any() else np.abs(x @ np.array([-np.sin(theta), np.cos(theta)]) - offset) <= width
    w = rank[sel]
    c = (w[:, None] * x[sel]).sum(axis=0) / w.sum()
    direction = np.array([np.cos(theta), np.sin(theta)])
    if direction[0] < 0 or (direction[0] == 0 and direction[1] < 0):
        direction = -direction
    normal = np.array([-direction[1], direction[0]])
    angle = np.degrees(np.arctan2(direction[1], direction[0])) % 180.0
    angle = angle if angle <= 90.0 else 180.0 - angle
    dist = (x - c) @ normal / d_mean
    edges = np.arange(np.floor(dist.min() / bin_d - 0.5), np.ceil(dist.max() / bin_d + 0.5) + 1) * bin_d
    which = np.clip(np.digitize(dist, edges) - 1, 0, len(edges) - 2)
    order = np.argsort(which, kind="stable")
    bins = np.split(s[order], np.searchsorted(which[order], np.arange(1, len(edges) - 1)))
    prof = np.array([np.median(b) if len(b) else np.nan for b in bins])
    centres = 0.5 * (edges[1:] + edges[:-1])
    near = np.abs(centres) <= 2.0 * bin_d          # the ridge's top: next to the line found
    k0 = int(np.flatnonzero(near)[np.nanargmax(prof[near])])
    peak = float(prof[k0])
    background = float(np.median(s))
    level = background + 0.5 * (peak - background)
    lo = _half_max_edge(centres, prof, k0, -1, level)
    hi = _half_max_edge(centres, prof, k0, +1, level)
    ridge = lo is not None and hi is not None
    band_width = hi - lo if ridge else float("nan")
    inside = np.abs(dist) <= max(0.5 * band_width if ridge else 0.0, bin_d)
    rest = float(np.median(s[~inside])) if np.any(~inside) else np.nan
    contrast = float(np.median(s[inside])) / rest if rest > 0 else np.nan
    localised = bool(ridge and score > null_score and contrast >= LOCALISED_CONTRAST
                     and 2 * np.count_nonzero(inside) < len(s))
    return {"angle_deg": float(angle), "direction": direction.tolist(), "normal": normal.tolist(),
            "centre": c.tolist(), "width_d": float(band_width), "peak": peak, "background": background,
            "score": score, "null_score": float(null_score), "contrast": contrast, "localised": localised,
            "profile": {"distance_d": centres.tolist(), "shear": prof.tolist()}}
