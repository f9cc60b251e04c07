"""Granular cases: spheres interacting by contact in a periodic cell, and what protocols do with
them between runs.

A ``GranularCase`` is a ``Simulation`` built from a ``pardem.engine.system.System`` (the one
builder, ``pardem.engine.system.build``) plus the protocol's facts about it (``extras``: cemented
pairs, the triaxial reference, how the cell was opened or replicated), which its checkpoints store
(``pardem.restart.payload``). Between steps a protocol may switch the contact parameters
(``pardem.engine.system.set_contact_params``: e.g. friction after a frictionless preparation, or
cemented Hertz-Mindlin contacts, whose history is wider) and the global damping
(``sim.viscous_damping``); checkpoints store the system as it is then (``describe``).
"""
from dataclasses import dataclass, field

import numpy as np

from pardem.engine.simulation import Simulation
from pardem.engine.system import build


def simple_cubic(n, radius, spacing=1.998, jitter=0.0002, seed=12345):
    """Centres [n^3, 3] of a simple cubic lattice of spacing ``spacing * radius`` jittered by
    ``+-jitter * radius`` per axis (uniform, seeded), and the periodic box edge [m]."""
    rng = np.random.default_rng(seed)
    a = spacing * radius
    g = np.arange(n) * a + 0.5 * a
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    pos += rng.uniform(-jitter * radius, jitter * radius, size=pos.shape)
    return pos, n * a


@dataclass
class GranularCase:
    """A granular simulation on this rank and the protocol's facts about it (JSON-able ``extras``,
    stored in its checkpoints)."""
    sim: Simulation
    extras: dict = field(default_factory=dict)

    @property
    def n_elements(self):
        """The global number of grains."""
        return self.sim.n_elements


def build_case(comm, system, extras=None):
    """A ``GranularCase`` of ``system`` (``pardem.engine.system.build``, collective)."""
    return GranularCase(build(comm, system), dict(extras or {}))


def continue_clock(sim, step, time):
    """Let a freshly built ``sim`` (step 0) continue the step count ``step`` and time ``time`` [s]
    of the run it belongs to (series, checkpoints and snapshots count steps from the run's start:
    a case rebuilt after opening or replicating a packing): the forces of its first state are
    computed first, as ``Simulation.run`` does at step 0."""
    if int(step) == 0:
        return                  # the first run computes them (``Simulation.run`` at step 0)
    if sim.step_count == 0:
        sim.run(0)
    sim.step_count, sim.time = int(step), float(time)
    sim.set_dt(sim.dt)          # the clock counts from here
