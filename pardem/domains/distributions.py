"""Size distributions of spheres (LIGGGHTS' ``fix particledistribution/discrete``, Yade's ``psdSizes``).

A distribution is an object with a support ``[r_min, r_max]`` [m] and the meaning of its fractions,
``by``:

* ``by="number"``: the given law is the distribution of the radii over the **particles**: a fraction
  ``F(r)`` of the particles has a radius <= r (``cdf``);
* ``by="volume"``: the given law is the distribution of the **solid volume** over the radii (a sieve
  curve by mass): spheres of radius <= r make a fraction ``F_V(r)`` of the total volume
  (``volume_cdf``). The number density is then the volume density divided by ``r^3``
  (``p_N(r) ~ p_V(r) / r^3``), and that is what ``sample`` draws from.

Both CDFs are available for either meaning (``cdf``: by number, ``volume_cdf``: by volume), and
``mean_volume`` [m^3] is the mean sphere volume per particle (by number), which turns a target
solid volume into a particle count.

The laws (all truncated to their support, which is required to lie in (0, inf)):

* ``Uniform(r_min, r_max)``: constant density in r;
* ``Normal(mean, std, r_min, r_max)``: Gaussian density in r (default support ``mean +- 3 std``);
* ``LogNormal(median, sigma, r_min, r_max)``: Gaussian density of ``ln r`` with median ``median``
  [m] and standard deviation ``sigma`` (dimensionless; default support ``median exp(+-3 sigma)``);
* ``Discrete(radii, fractions)``: a mixture of sizes; ``Bidisperse(r_small, r_large,
  fraction_large)`` its two-size case.

``sample(n, rng)`` draws ``n`` radii [n] [m] with a ``numpy.random.Generator`` (pure NumPy: the
same seed gives the same bits on every rank). The continuous laws other than the uniform by
number are drawn by inverting the number CDF tabulated on a fine grid in ``ln r`` (``GRID``
points, trapezoidal rule): the CDF's error is ~1e-8, far below a Kolmogorov-Smirnov test's
resolution for any sample a DEM run holds.
"""
import math

import numpy as np

from pardem.physics.arguments import real, short

GRID = 16385           # points of the tabulated CDFs (in ln r)
BY = ("number", "volume")


def _by(by):
    if not (isinstance(by, str) and by in BY):
        raise ValueError(f"by = {short(by)}: expected 'number' (fractions of the particles) or 'volume' "
                         "(fractions of the solid volume)")
    return by


def _support(name, r_min, r_max):
    r_min = real(f"{name}.r_min", r_min, lo=0.0, unit="[m]")
    r_max = real(f"{name}.r_max", r_max, lo=0.0, unit="[m]")
    if not r_min <= r_max:
        raise ValueError(f"{name}: r_min = {r_min:g} m above r_max = {r_max:g} m: expected r_min <= r_max")
    return r_min, r_max


class SizeDistribution:
    """Base of the radius distributions (module docstring). Subclasses give ``r_min``, ``r_max``,
    ``by`` and either ``_density(r)`` (the given law's unnormalised density in r, continuous) or
    their own ``sample``, ``cdf`` and ``volume_cdf``."""
    r_min: float
    r_max: float
    by: str

    # -- the tabulated number and volume CDFs of a continuous law ------------------------------

    def _table(self):
        t = getattr(self, "_tab", None)
        if t is not None:
            return t
        if self.r_min == self.r_max:
            r = np.array([self.r_min, self.r_max])
            cn = cv = np.array([0.0, 1.0])
        else:
            r = np.exp(np.linspace(math.log(self.r_min), math.log(self.r_max), GRID))
            r[0], r[-1] = self.r_min, self.r_max
            given = self._density(r)
            pn = given if self.by == "number" else given / r**3     # number density in r
            # densities in u = ln r: p(r) r
            cn = _cumulative(pn * r, np.log(r))
            cv = _cumulative(pn * r**4, np.log(r))
        self._tab = (r, cn, cv)
        return self._tab

    def sample(self, n, rng):
        """``n`` radii [n] [m] drawn by number (``rng``: a ``numpy.random.Generator``)."""
        n = _count(n)
        r, cn, _ = self._table()
        return np.interp(rng.random(n), cn, r)

    def cdf(self, radius):
        """Fraction of the particles (by number) of radius <= ``radius`` [m]."""
        r, cn, _ = self._table()
        return np.interp(np.asarray(radius, dtype=np.float64), r, cn, left=0.0, right=1.0)

    def volume_cdf(self, radius):
        """Fraction of the solid volume in particles of radius <= ``radius`` [m]."""
        r, _, cv = self._table()
        return np.interp(np.asarray(radius, dtype=np.float64), r, cv, left=0.0, right=1.0)

    def mean_volume(self):
        """Mean sphere volume per particle, by number [m^3]."""
        r, cn, _ = self._table()
        mid = 0.5 * (r[1:] + r[:-1])
        return float(np.sum(np.diff(cn) * 4.0 / 3.0 * np.pi * mid**3))

    def __repr__(self):
        return f"{type(self).__name__}(r_min={self.r_min:g}, r_max={self.r_max:g}, by={self.by!r})"


def _cumulative(density, u):
    """Normalised cumulative trapezoidal integral of ``density`` over the grid ``u``."""
    c = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(u))])
    return c / c[-1]


def _count(n):
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n = {short(n)}: expected an integer >= 0 (number of radii)")
    return int(n)


class Uniform(SizeDistribution):
    """Radii uniform in ``[r_min, r_max]`` [m], by number (a constant density of particles in r) or
    by volume (a constant density of solid volume in r: ``p_N ~ r^-3``)."""

    def __init__(self, r_min, r_max, by="number"):
        self.r_min, self.r_max = _support("Uniform", r_min, r_max)
        self.by = _by(by)

    def _density(self, r):
        return np.ones_like(r)

    def sample(self, n, rng):
        n = _count(n)
        if self.by == "number":      # exact: no table
            return self.r_min + (self.r_max - self.r_min) * rng.random(n)
        return super().sample(n, rng)


class Normal(SizeDistribution):
    """Radii of Gaussian density (``mean`` [m], standard deviation ``std`` [m]) truncated to
    ``[r_min, r_max]`` [m] (default ``mean -+ 3 std``, which must then stay above 0)."""

    def __init__(self, mean, std, r_min=None, r_max=None, by="number"):
        self.mean = real("Normal.mean", mean, lo=0.0, unit="[m]")
        self.std = real("Normal.std", std, lo=0.0, unit="[m]")
        r_min = self.mean - 3.0 * self.std if r_min is None else r_min
        r_max = self.mean + 3.0 * self.std if r_max is None else r_max
        if not r_min > 0.0:
            raise ValueError(f"Normal: r_min = {r_min:g} m (mean - 3 std by default): expected a truncation "
                             "r_min > 0 [m]; give r_min")
        self.r_min, self.r_max = _support("Normal", r_min, r_max)
        self.by = _by(by)

    def _density(self, r):
        return np.exp(-0.5 * ((r - self.mean) / self.std) ** 2)


class LogNormal(SizeDistribution):
    """Radii whose logarithm is Gaussian: median ``median`` [m] (``exp`` of the mean of ``ln r``),
    standard deviation ``sigma`` of ``ln r`` (dimensionless), truncated to ``[r_min, r_max]`` [m]
    (default ``median exp(-+3 sigma)``)."""

    def __init__(self, median, sigma, r_min=None, r_max=None, by="number"):
        self.median = real("LogNormal.median", median, lo=0.0, unit="[m]")
        self.sigma = real("LogNormal.sigma", sigma, lo=0.0, note="standard deviation of ln r")
        r_min = self.median * math.exp(-3.0 * self.sigma) if r_min is None else r_min
        r_max = self.median * math.exp(3.0 * self.sigma) if r_max is None else r_max
        self.r_min, self.r_max = _support("LogNormal", r_min, r_max)
        self.by = _by(by)

    def _density(self, r):
        return np.exp(-0.5 * ((np.log(r) - math.log(self.median)) / self.sigma) ** 2) / r


class Discrete(SizeDistribution):
    """A mixture of sizes: ``radii`` [k] [m] (distinct, > 0) with ``fractions`` [k] (>= 0, summing
    to 1 within 1e-9; normalised) of the particles (``by="number"``) or of the solid volume
    (``by="volume"``: number fractions ``~ fraction / r^3``)."""

    def __init__(self, radii, fractions, by="number"):
        r = np.atleast_1d(np.asarray(radii, dtype=np.float64))
        f = np.atleast_1d(np.asarray(fractions, dtype=np.float64))
        if r.ndim != 1 or r.shape != f.shape or len(r) < 1:
            raise ValueError(f"Discrete: radii {short(radii)} and fractions {short(fractions)} must be two "
                             "1-D sequences of the same length >= 1")
        if not np.all(np.isfinite(r) & (r > 0.0)) or len(np.unique(r)) != len(r):
            raise ValueError(f"Discrete.radii = {short(r.tolist())}: expected distinct finite radii > 0 [m]")
        if not np.all(np.isfinite(f) & (f >= 0.0)) or abs(f.sum() - 1.0) > 1e-9:
            raise ValueError(f"Discrete.fractions = {short(f.tolist())}: expected numbers >= 0 summing to 1")
        order = np.argsort(r)
        self.radii, self.fractions = r[order], f[order] / f.sum()
        self.by = _by(by)
        self.r_min, self.r_max = float(self.radii[0]), float(self.radii[-1])
        w = self.fractions if self.by == "number" else self.fractions / self.radii**3
        self.number_fractions = w / w.sum()
        v = self.number_fractions * self.radii**3
        self.volume_fractions = v / v.sum()

    def sample(self, n, rng):
        n = _count(n)
        c = np.cumsum(self.number_fractions)
        c[-1] = 1.0
        return self.radii[np.searchsorted(c, rng.random(n), side="right")]

    def cdf(self, radius):
        c = np.concatenate([[0.0], np.cumsum(self.number_fractions)])
        return c[np.searchsorted(self.radii, np.asarray(radius, dtype=np.float64), side="right")]

    def volume_cdf(self, radius):
        c = np.concatenate([[0.0], np.cumsum(self.volume_fractions)])
        return c[np.searchsorted(self.radii, np.asarray(radius, dtype=np.float64), side="right")]

    def mean_volume(self):
        return float(np.sum(self.number_fractions * 4.0 / 3.0 * np.pi * self.radii**3))

    def __repr__(self):
        return f"Discrete(radii={self.radii.tolist()}, fractions={self.fractions.tolist()}, by={self.by!r})"


def Bidisperse(r_small, r_large, fraction_large, by="number"):
    """Two sizes [m]: a fraction ``fraction_large`` in [0, 1] of the particles (or of the volume,
    ``by="volume"``) of radius ``r_large``, the rest ``r_small`` (a ``Discrete``)."""
    f = real("Bidisperse.fraction_large", fraction_large, lo=0.0, hi=1.0, lo_open=False, hi_open=False)
    return Discrete([r_small, r_large], [1.0 - f, f], by=by)


def as_distribution(value, name="distribution"):
    """A ``SizeDistribution``, or a number (one radius [m], ``Discrete([r], [1])``)."""
    if isinstance(value, SizeDistribution):
        return value
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)):
        return Discrete([real(name, value, lo=0.0, unit="[m]")], [1.0])
    raise ValueError(f"{name} = {short(value)}: expected a size distribution (Uniform, Normal, LogNormal, "
                     "Discrete, Bidisperse) or one radius [m]")


__all__ = ["SizeDistribution", "Uniform", "Normal", "LogNormal", "Discrete", "Bidisperse", "as_distribution"]
