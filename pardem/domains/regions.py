"""Regions of space for inserting and deleting particles (LIGGGHTS' ``region``, Yade's box of
``makeCloud``): a box, an upright cylinder, a sphere.

Every region has ``volume`` [m^3], ``bounds`` (``lo`` [3], ``hi`` [3] [m]), ``contains(points,
margin=0)`` (bool [n]: the point lies inside with at least ``margin`` [m] (a scalar or [n]) to the
boundary, so a sphere of radius ``margin`` centred there lies wholly inside) and
``sample(n, rng, margin=0)`` (``n`` points [n, 3] [m] uniformly distributed in the region shrunk
by ``margin``; pure NumPy: the same generator state gives the same bits on every rank). ValueError
when the region shrunk by ``margin`` is empty.
"""
import math

import numpy as np

from pardem.physics.arguments import real, short, vector3


def _points(points):
    x = np.asarray(points, dtype=np.float64)
    if x.ndim == 1 and x.shape == (3,):
        x = x.reshape(1, 3)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3) [m], got shape {x.shape}")
    return x


def _margin(margin):
    m = np.asarray(margin, dtype=np.float64)
    if not np.all(np.isfinite(m) & (m >= 0.0)):
        raise ValueError(f"margin = {short(margin)}: expected finite distances >= 0 [m]")
    return m


class Region:
    """Base of the regions (module docstring)."""
    volume: float

    @property
    def bounds(self):
        """``(lo [3], hi [3])`` [m] of the region's bounding box."""
        raise NotImplementedError

    def contains(self, points, margin=0.0):
        raise NotImplementedError

    def _check_room(self, margin):
        raise NotImplementedError


class Box(Region):
    """The axis-aligned box ``[lo, hi]`` [3] [m]."""

    def __init__(self, lo, hi):
        self.lo = vector3("Box.lo", lo, "[m]")
        self.hi = vector3("Box.hi", hi, "[m]")
        if not np.all(self.hi > self.lo):
            raise ValueError(f"Box: hi = {self.hi.tolist()} must exceed lo = {self.lo.tolist()} along every axis [m]")
        self.volume = float(np.prod(self.hi - self.lo))

    @property
    def bounds(self):
        return self.lo.copy(), self.hi.copy()

    def contains(self, points, margin=0.0):
        x, m = _points(points), _margin(margin)
        m = m[:, None] if m.ndim == 1 else m
        return np.all((x >= self.lo + m) & (x <= self.hi - m), axis=1)

    def _check_room(self, margin):
        if not np.all(self.hi - self.lo > 2.0 * margin):
            raise ValueError(f"Box {self.lo.tolist()} .. {self.hi.tolist()} m has no room for a sphere of radius "
                             f"{margin:g} m")

    def sample(self, n, rng, margin=0.0):
        m = float(margin)
        self._check_room(m)
        return (self.lo + m) + (self.hi - self.lo - 2.0 * m) * rng.random((int(n), 3))

    def __repr__(self):
        return f"Box(lo={self.lo.tolist()}, hi={self.hi.tolist()})"


class Cylinder(Region):
    """A cylinder of radius ``radius`` [m] around an axis parallel to ``axis`` (0, 1, 2 = x, y, z),
    from the point ``base`` [3] [m] on the axis up to ``base + height`` along it."""

    def __init__(self, base, radius, height, axis=2):
        self.base = vector3("Cylinder.base", base, "[m]")
        self.radius = real("Cylinder.radius", radius, lo=0.0, unit="[m]")
        self.height = real("Cylinder.height", height, lo=0.0, unit="[m]")
        if isinstance(axis, bool) or axis not in (0, 1, 2):
            raise ValueError(f"Cylinder.axis = {short(axis)}: expected 0, 1 or 2 (x, y, z)")
        self.axis = int(axis)
        self._plane = [a for a in range(3) if a != self.axis]
        self.volume = math.pi * self.radius**2 * self.height

    @property
    def bounds(self):
        lo, hi = self.base.copy(), self.base.copy()
        lo[self._plane] -= self.radius
        hi[self._plane] += self.radius
        hi[self.axis] += self.height
        return lo, hi

    def contains(self, points, margin=0.0):
        x, m = _points(points), _margin(margin)
        d = x - self.base
        rho2 = d[:, self._plane[0]] ** 2 + d[:, self._plane[1]] ** 2
        h = d[:, self.axis]
        inner = np.maximum(self.radius - m, 0.0)
        return (rho2 <= inner**2) & (self.radius >= m) & (h >= m) & (h <= self.height - m)

    def _check_room(self, margin):
        if not (self.radius > margin and self.height > 2.0 * margin):
            raise ValueError(f"Cylinder (radius {self.radius:g} m, height {self.height:g} m) has no room for a "
                             f"sphere of radius {margin:g} m")

    def sample(self, n, rng, margin=0.0):
        m = float(margin)
        self._check_room(m)
        u = rng.random((int(n), 3))
        rho = (self.radius - m) * np.sqrt(u[:, 0])      # uniform over the disc's area
        phi = 2.0 * math.pi * u[:, 1]
        x = np.empty((int(n), 3))
        x[:, self._plane[0]] = self.base[self._plane[0]] + rho * np.cos(phi)
        x[:, self._plane[1]] = self.base[self._plane[1]] + rho * np.sin(phi)
        x[:, self.axis] = self.base[self.axis] + m + (self.height - 2.0 * m) * u[:, 2]
        return x

    def __repr__(self):
        return (f"Cylinder(base={self.base.tolist()}, radius={self.radius:g}, height={self.height:g}, "
                f"axis={self.axis})")


class Sphere(Region):
    """The ball of centre ``centre`` [3] [m] and radius ``radius`` [m]."""

    def __init__(self, centre, radius):
        self.centre = vector3("Sphere.centre", centre, "[m]")
        self.radius = real("Sphere.radius", radius, lo=0.0, unit="[m]")
        self.volume = 4.0 / 3.0 * math.pi * self.radius**3

    @property
    def bounds(self):
        return self.centre - self.radius, self.centre + self.radius

    def contains(self, points, margin=0.0):
        x, m = _points(points), _margin(margin)
        d2 = np.einsum("kd,kd->k", x - self.centre, x - self.centre)
        inner = np.maximum(self.radius - m, 0.0)
        return (d2 <= inner**2) & (self.radius >= m)

    def _check_room(self, margin):
        if not self.radius > margin:
            raise ValueError(f"Sphere of radius {self.radius:g} m has no room for a sphere of radius {margin:g} m")

    def sample(self, n, rng, margin=0.0):
        m = float(margin)
        self._check_room(m)
        d = rng.normal(size=(int(n), 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        rho = (self.radius - m) * np.cbrt(rng.random(int(n)))    # uniform over the volume
        return self.centre + rho[:, None] * d

    def __repr__(self):
        return f"Sphere(centre={self.centre.tolist()}, radius={self.radius:g})"


__all__ = ["Region", "Box", "Cylinder", "Sphere"]
