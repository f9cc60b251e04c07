"""Particles inserted and deleted during a run: operations of ``Simulation.run`` (LIGGGHTS'
``fix insert/pack`` and ``delete_atoms region``, Yade's ``SpheresFactory``).

``Insert(region, distribution, trigger, n=... | volume_fraction=...)``: each time its trigger fires,
a batch of spheres drawn from the size distribution is placed at random in the region without
overlapping the particles there (``pardem.domains.packing.random_pack`` over the positions and
radii gathered by ``sim.particles``) and added (``sim.particles.add``), at rest or with the given
velocity. ``n`` spheres per batch, or (``volume_fraction``) as many as bring the solid volume of the
particles whose centres lie in the region up to that fraction of its volume (``fix insert/pack``'s
``volumefraction_region``). Positions where there is no room are skipped (counted in ``missing``).
A pouring rate is ``n`` per trigger period: ``rate [1/s] = n / (period dt)``.

Every batch draws from ``numpy.random.default_rng([seed, step])``: the same particles on any number
of ranks, and after a restart from a checkpoint (the step is part of the state; the operation's
counters are not: ``inserted`` counts this object's insertions, and ``total`` bounds them).

``Delete(trigger, inside=region | outside=region)``: removes the particles whose centres lie
inside a region, or outside it (grains that left the domain: a hopper's outlet, a box's open
top), with their bonds and contact histories (``sim.particles.remove``).
"""
import numpy as np

from pardem.domains.distributions import as_distribution
from pardem.domains.packing import random_pack
from pardem.domains.regions import Region
from pardem.physics.arguments import real, short


def _region(value, name):
    if not isinstance(value, Region):
        raise ValueError(f"{name} = {short(value)}: expected a pardem region (Box, Cylinder, Sphere)")
    return value


class Insert:
    """Operation: insert a batch of particles in ``region`` when ``trigger`` fires (module docstring).

    region : a ``pardem.domains.regions`` region; distribution : a size distribution
    (``pardem.domains.distributions``) or one radius [m]; n : spheres per batch, or
    volume_fraction in (0, 1): fill the region up to that solid fraction; total : the most this
    operation inserts (None: no bound); velocity [3] [m/s] of the new particles; seed : int;
    gap [m], attempts : as ``random_pack``. ``inserted``, ``missing``, ``batches``: counters;
    ``last``: the gids of the last batch [k].
    """

    def __init__(self, region, distribution, trigger, n=None, volume_fraction=None, total=None,
                 velocity=(0.0, 0.0, 0.0), seed=0, gap=0.0, attempts=1000):
        self.region = _region(region, "Insert.region")
        self.distribution = as_distribution(distribution, "Insert.distribution")
        self.trigger = trigger
        self.at_end = False
        if (n is None) == (volume_fraction is None):
            raise ValueError("Insert: give either n (spheres per batch) or volume_fraction (in (0, 1))")
        if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1):
            raise ValueError(f"Insert.n = {short(n)}: expected an integer >= 1 (spheres per batch)")
        self.n = None if n is None else int(n)
        self.volume_fraction = None if volume_fraction is None else real(
            "Insert.volume_fraction", volume_fraction, lo=0.0, hi=1.0)
        if total is not None and (isinstance(total, bool) or not isinstance(total, (int, np.integer)) or total < 0):
            raise ValueError(f"Insert.total = {short(total)}: expected an integer >= 0 or None")
        self.total = None if total is None else int(total)
        self.velocity = np.asarray(velocity, dtype=np.float64)
        if self.velocity.shape != (3,) or not np.all(np.isfinite(self.velocity)):
            raise ValueError(f"Insert.velocity = {short(velocity)}: expected 3 finite components [m/s]")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"Insert.seed = {short(seed)}: expected an integer >= 0")
        self.seed = int(seed)
        self.gap = real("Insert.gap", gap, lo=0.0, lo_open=False, unit="[m]")
        self.attempts = attempts
        self.inserted = 0
        self.missing = 0
        self.batches = 0
        self.last = np.zeros(0, np.int64)

    def __call__(self, sim):
        room = None if self.total is None else self.total - self.inserted
        if room == 0:
            self.last = np.zeros(0, np.int64)
            return
        x, r = sim.particles.positions, sim.particles.radii      # collective
        rng = np.random.default_rng([self.seed, int(sim.step_count)])
        if self.n is not None:
            cloud = random_pack(self.region, self.distribution, n=self.n if room is None else min(self.n, room),
                                seed=rng, existing=(x, r), gap=self.gap, attempts=self.attempts)
        else:
            inside = self.region.contains(x)
            have = float(np.sum(4.0 / 3.0 * np.pi * r[inside] ** 3)) / self.region.volume
            want = self.volume_fraction - have
            if want <= 0.0:
                self.last = np.zeros(0, np.int64)
                return
            cloud = random_pack(self.region, self.distribution, volume_fraction=want, seed=rng,
                                existing=(x, r), gap=self.gap, attempts=self.attempts)
            if room is not None and cloud.n > room:
                cloud.positions, cloud.radii = cloud.positions[:room], cloud.radii[:room]
        self.batches += 1
        self.missing += cloud.missing
        if cloud.n == 0:
            self.last = np.zeros(0, np.int64)
            return
        v = np.broadcast_to(self.velocity, (cloud.n, 3))
        self.last = sim.particles.add(cloud.positions, cloud.radii, velocities=v)
        self.inserted += len(self.last)


class Delete:
    """Operation: remove the particles whose centres lie ``inside`` a region, or ``outside`` one,
    when ``trigger`` fires (module docstring). ``deleted``: how many so far; ``last``: the gids
    removed by the last call [k]. A simulation keeps at least one particle: were every particle
    selected, the one of the highest gid would stay."""

    def __init__(self, trigger, inside=None, outside=None):
        if (inside is None) == (outside is None):
            raise ValueError("Delete: give either inside=region or outside=region")
        self.region = _region(inside if inside is not None else outside, "Delete.inside" if inside is not None
                              else "Delete.outside")
        self.inside = inside is not None
        self.trigger = trigger
        self.at_end = False
        self.deleted = 0
        self.last = np.zeros(0, np.int64)

    def selected(self, sim):
        """The gids [k] (increasing) of the particles to remove now, the same on every rank
        (collective: one ``allgatherv`` of each rank's choice among its owned rows)."""
        local = sim.particles.local
        hit = self.region.contains(local.positions)
        if not self.inside:
            hit = ~hit
        return np.sort(sim.comm.allgatherv(np.ascontiguousarray(local.gids[hit])))

    def __call__(self, sim):
        gids = self.selected(sim)
        n_all = sim.particles.n
        if len(gids) == n_all:        # a simulation keeps one particle: the highest gid stays
            gids = gids[:-1]
        if len(gids):
            sim.particles.remove(gids)
        self.deleted += len(gids)
        self.last = gids


__all__ = ["Insert", "Delete"]
