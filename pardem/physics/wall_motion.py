"""Prescribed rigid translations of walls as functions of time (LIGGGHTS ``move/mesh``, Yade's
``Engine`` kinematics).

A motion gives the displacement ``d(tau)`` [m] and velocity ``v(tau) = d'(tau)`` [m/s] of a wall,
both [3], at the time ``tau = t - time0`` [s] since the wall was added (``time0``); a wall at the
point ``p`` at ``time0`` is at ``p + d(tau)``. Every motion is a plain value: ``to_dict`` gives a
JSON-able dict (with ``"kind"``) and ``motion_from_dict`` makes it back, so checkpoints store it
and a restored wall moves the same bits.

* ``Constant(velocity)``: ``d = V tau``, ``v = V`` (the walls' default);
* ``Ramp(velocity, ramp_time)``: the speed grows linearly from 0 to ``V`` over ``T = ramp_time``,
  then stays: ``d = V tau^2 / (2 T)`` for ``tau < T``, ``d = V (tau - T / 2)`` after;
* ``Sinusoid(amplitude, frequency, phase=0)``: ``d = A (sin(omega tau + phi) - sin(phi))``,
  ``v = A omega cos(omega tau + phi)``, ``omega = 2 pi frequency``;
* ``Table(times, displacements)``: piecewise-linear ``d`` through the points ``(t_i, d_i)``
  (``t_0 = 0`` and ``d_0 = 0``: the wall starts where it was put), the velocity the slope of the
  segment holding ``tau`` (at a knot, the next segment's); after the last point the wall stays.

Nothing here knows of walls or ranks: ``pardem.engine.walls`` evaluates the motion of each wall at
the times of the step (positions at the end of the step, velocities at its middle).
"""
import math

import numpy as np

from pardem.physics.arguments import array, real


def _vector(name, value, unit):
    v = array(name, value, unit)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers {unit}, got {np.asarray(value).tolist()}")
    return v.copy()


class Constant:
    """Translation at the constant velocity ``velocity`` [3] [m/s]."""
    kind = "constant"

    def __init__(self, velocity=(0.0, 0.0, 0.0)):
        self.velocity = _vector("velocity", velocity, "[m/s]")

    def displacement(self, tau):
        return self.velocity * tau

    def velocity_at(self, tau):
        return self.velocity.copy()

    def to_dict(self):
        return {"kind": self.kind, "velocity": self.velocity.tolist()}


class Ramp:
    """Speed ramped linearly from 0 to ``velocity`` [3] [m/s] over ``ramp_time`` [s], then held."""
    kind = "ramp"

    def __init__(self, velocity, ramp_time):
        self.velocity = _vector("velocity", velocity, "[m/s]")
        self.ramp_time = real("ramp_time", ramp_time, lo=0.0, unit="[s]")

    def displacement(self, tau):
        T = self.ramp_time
        if tau < T:
            return self.velocity * (0.5 * tau * tau / T)
        return self.velocity * (tau - 0.5 * T)

    def velocity_at(self, tau):
        return self.velocity * min(max(tau, 0.0) / self.ramp_time, 1.0)

    def to_dict(self):
        return {"kind": self.kind, "velocity": self.velocity.tolist(), "ramp_time": self.ramp_time}


class Sinusoid:
    """Oscillation ``d = A (sin(2 pi f tau + phase) - sin(phase))``: amplitude [3] [m],
    frequency [Hz] > 0, phase [rad]."""
    kind = "sinusoid"

    def __init__(self, amplitude, frequency, phase=0.0):
        self.amplitude = _vector("amplitude", amplitude, "[m]")
        self.frequency = real("frequency", frequency, lo=0.0, unit="[Hz]")
        self.phase = real("phase", phase, unit="[rad]")

    def displacement(self, tau):
        w = 2.0 * math.pi * self.frequency
        return self.amplitude * (math.sin(w * tau + self.phase) - math.sin(self.phase))

    def velocity_at(self, tau):
        w = 2.0 * math.pi * self.frequency
        return self.amplitude * (w * math.cos(w * tau + self.phase))

    def to_dict(self):
        return {"kind": self.kind, "amplitude": self.amplitude.tolist(), "frequency": self.frequency,
                "phase": self.phase}


class Table:
    """Piecewise-linear displacement through ``times`` [k] [s] (strictly increasing, from 0) and
    ``displacements`` [k, 3] [m] (the first row 0); the wall stays at the last point after it."""
    kind = "table"

    def __init__(self, times, displacements):
        t = array("times", times, "[s]").reshape(-1).copy()
        d = array("displacements", displacements, "[m]").copy()
        if t.size < 2 or not np.all(np.isfinite(t)) or t[0] != 0.0 or not np.all(np.diff(t) > 0.0):
            raise ValueError(f"times must hold >= 2 finite, strictly increasing times [s] starting at 0, "
                             f"got {t.tolist()}")
        if d.shape != (t.size, 3) or not np.all(np.isfinite(d)) or np.any(d[0] != 0.0):
            raise ValueError(f"displacements must be finite [{t.size}, 3] [m] (one row per time) with the "
                             f"first row 0, got shape {d.shape}")
        self.times, self.displacements = t, d

    def _segment(self, tau):
        return int(np.searchsorted(self.times, tau, side="right")) - 1

    def displacement(self, tau):
        t, d = self.times, self.displacements
        if tau <= 0.0:
            return d[0].copy()
        i = self._segment(tau)
        if i >= t.size - 1:
            return d[-1].copy()
        s = (tau - t[i]) / (t[i + 1] - t[i])
        return d[i] + s * (d[i + 1] - d[i])

    def velocity_at(self, tau):
        t, d = self.times, self.displacements
        i = self._segment(tau)
        if tau < 0.0 or i >= t.size - 1:
            return np.zeros(3)
        return (d[i + 1] - d[i]) / (t[i + 1] - t[i])

    def to_dict(self):
        return {"kind": self.kind, "times": self.times.tolist(), "displacements": self.displacements.tolist()}


MOTIONS = {m.kind: m for m in (Constant, Ramp, Sinusoid, Table)}


def motion_from_dict(d):
    """The motion of ``to_dict`` (ValueError naming the kind for an unknown one)."""
    if isinstance(d, (Constant, Ramp, Sinusoid, Table)):
        return d
    if not isinstance(d, dict) or d.get("kind") not in MOTIONS:
        raise ValueError(f"a wall motion must be one of {', '.join(MOTIONS)} (or its dict with 'kind'), "
                         f"got {d!r}")
    args = {k: v for k, v in d.items() if k != "kind"}
    return MOTIONS[d["kind"]](**args)


__all__ = ["Constant", "Ramp", "Sinusoid", "Table", "MOTIONS", "motion_from_dict"]
