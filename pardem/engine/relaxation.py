"""Relaxation to static equilibrium by FIRE: an operation of a ``Simulation`` (every step); and
``ServoStiffness``, the operation that keeps a pressure servo's gain cap up to date.

Replaces global viscous damping during sample preparation: viscous damping removes energy from
every mode at the same rate, so the soft modes of a packing near jamming relax over very many
steps; FIRE keeps the inertial motion while it goes downhill and steers it along the force, and
stops everything when the power turns negative (Bitzek et al. 2006; the time-step rules of FIRE 2.0,
Guenole et al. 2020). The mixing ``a`` starts at ``alpha_start`` and is multiplied by ``f_alpha``
after ``n_min`` consecutive downhill steps.

Adaptive time step (``dt_max`` given): after ``n_min`` consecutive downhill steps the step grows by
``f_inc`` per step, up to ``dt_max`` and to ``safety`` times the Verlet limit ``2 / omega`` of the
current contacts (``Contacts.stiffness``, the block Gershgorin bound of their normal springs,
recomputed every ``bound_every`` steps); an uphill step multiplies it by ``f_dec`` (not below
``dt_min``, unless the bound is lower). A fixed step (the contact law's) is kept otherwise. The Gershgorin bound is exact for
frictionless contacts only, so the adaptive step refuses contacts with friction.
"""
import numpy as np

from pardem.triggers import Periodic, as_trigger
from pardem.parallel import exact_sum
from pardem.physics import exact_accumulate, fire


class Fire:
    """The FIRE operation; call it after every step (``trigger = Periodic(1)``). Collective (one allreduce of
    three numbers per step, and one of the stiffness bound every ``bound_every`` steps when the
    step adapts). ``dt_max``, ``dt_min`` [s]; the caller restores its own step afterwards."""
    trigger = Periodic(1)

    def __init__(self, alpha_start=0.1, f_alpha=0.99, n_min=5, dt_max=None, dt_min=None, f_inc=1.1,
                 f_dec=0.5, safety=0.5, bound_every=10):
        self.alpha_start = float(alpha_start)
        self.f_alpha = float(f_alpha)
        self.n_min = int(n_min)
        self.alpha = self.alpha_start
        self.downhill = 0
        self.restarts = 0
        self.dt_max = None if dt_max is None else float(dt_max)
        self.dt_min = 0.0 if dt_min is None else float(dt_min)
        self.f_inc, self.f_dec, self.safety = float(f_inc), float(f_dec), float(safety)
        self.bound_every = int(bound_every)
        self.dt_stable = np.inf   # safety * 2 / omega_max of the last bound [s]
        self.calls = 0

    def stable_step(self, sim):
        """``safety * 2 / omega_max`` [s] of the current contacts (collective)."""
        c = sim.contacts
        if c.params.friction != 0.0:
            raise ValueError("FIRE's adaptive time step needs frictionless contacts (its stability "
                             f"bound covers the normal springs only), got friction = {c.params.friction}")
        w2 = sim.comm.max(c.stiffness(sim.elements)[0])
        return self.safety * 2.0 / np.sqrt(w2) if w2 > 0.0 else np.inf

    @staticmethod
    def power(sim):
        """Global ``(F . v, |v|^2, |F|^2)`` (collective): summed exactly, the same bits on any
        number of ranks, when the contacts are ``reproducible`` (FIRE's decisions feed back)."""
        e = sim.elements
        if sim.contacts is not None and sim.contacts.reproducible:
            acc = exact_accumulate.zeros(3)
            ok = exact_accumulate.power_terms(e.v, e.f, e.n_owned, acc)
            return tuple(float(v) for v in exact_sum.total(sim.comm, acc, ok))
        return tuple(float(v) for v in sim.comm.sum(np.array(fire.power_sums(e.v, e.f, e.n_owned))))

    def __call__(self, sim):
        e = sim.elements
        adaptive = self.dt_max is not None
        if adaptive and self.calls % self.bound_every == 0:
            self.dt_stable = self.stable_step(sim)
            if sim.dt > self.dt_stable:   # stiffer contacts: stability first, dt_min or not
                sim.set_dt(self.dt_stable)
        self.calls += 1
        p, vv, ff = self.power(sim)
        if p > 0.0:
            if ff > 0.0:
                fire.mix(e.v, e.f, self.alpha, np.sqrt(vv / ff), e.n_owned)
            self.downhill += 1
            if self.downhill > self.n_min:
                self.alpha *= self.f_alpha
                if adaptive:
                    sim.set_dt(min(sim.dt * self.f_inc, self.dt_max, self.dt_stable))
        else:
            fire.stop(e.v, e.w, e.n_owned)
            self.alpha = self.alpha_start
            self.downhill = 0
            self.restarts += 1
            if adaptive:
                sim.set_dt(max(sim.dt * self.f_dec, self.dt_min))


class ServoStiffness:
    """Operation keeping the cell's ``servo_stiffness`` ``S = -dp/de = kd2 / (3 V) + 2 p`` [Pa] (in 2D
    ``kd2 / (2 V) + p``, with V = L_x L_y t and the in-plane p; the
    frictionless network's affine stiffness, ``Contacts.stiffness``) up to date, so that the
    pressure servo caps its gain at ``1 / (2 S dt)`` (``PeriodicCell``), on the steps of ``trigger``
    and after the last step of every run (``at_end``: the next run starts from an up-to-date S).
    Collective."""
    at_end = True

    def __init__(self, trigger=10):
        self.trigger = as_trigger(trigger)

    def __call__(self, sim):
        kd2 = sim.contacts.global_affine_stiffness(sim.comm, sim.elements)
        p = max(sim.cell.pressure(sim.stress), 0.0)
        # d dimensions (d = 2: the in-plane strain of a 2D cell): S = kd2 / (d V) + (d - 1) p
        d = sim.cell.dimension
        sim.cell.servo_stiffness = kd2 / (d * sim.cell.volume) + (d - 1) * p
