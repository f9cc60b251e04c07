"""Relaxation to static equilibrium by FIRE: an operation of a ``Simulation`` (every step).

Replaces global viscous damping during sample preparation: viscous damping removes energy from
every mode at the same rate, so the soft modes of a packing near jamming relax over very many
steps; FIRE keeps the inertial motion while it goes downhill and steers it along the force, and
stops everything when the power turns negative. Standard parameters (Bitzek et al. 2006) with the
time step kept fixed (it is the contact law's): mixing ``a`` starts at ``alpha_start`` and is
multiplied by ``f_alpha`` after ``n_min`` consecutive downhill steps.
"""
import numpy as np

from pardem.physics import fire


class Fire:
    """The FIRE operation; call it after every step (``every = 1``). Collective (one allreduce of
    three numbers per step)."""
    every = 1

    def __init__(self, alpha_start=0.1, f_alpha=0.99, n_min=5):
        self.alpha_start = float(alpha_start)
        self.f_alpha = float(f_alpha)
        self.n_min = int(n_min)
        self.alpha = self.alpha_start
        self.downhill = 0
        self.restarts = 0

    def __call__(self, sim):
        e = sim.elements
        p, vv, ff = sim.comm.sum(np.array(fire.power_sums(e.v, e.f, e.n_owned)))
        if p > 0.0:
            if ff > 0.0:
                fire.mix(e.v, e.f, self.alpha, np.sqrt(vv / ff), e.n_owned)
            self.downhill += 1
            if self.downhill > self.n_min:
                self.alpha *= self.f_alpha
        else:
            fire.stop(e.v, e.w, e.n_owned)
            self.alpha = self.alpha_start
            self.downhill = 0
            self.restarts += 1
