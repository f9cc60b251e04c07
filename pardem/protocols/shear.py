"""Simple-shear test of an ordered domain: measures the domain shear modulus G^D of one plane.

Method (chosen for the calibration's verification, docs/physics.md section 6). Plane (a, b): the shear
displacement is along axis a, its gradient along axis b (``LT``: a = x, b = z). The engine's compression
case builds the domain (lattice, bonds, slabs, ghosts, time step); its plates are removed. The elements
of the two outer layers normal to b *and* of the two outer layers normal to a are driven kinematically
through the affine simple shear ``u_a = gamma(t) (X_b - c_b)`` with the lattice's element rotation
``omega = w_b gamma`` about ``e_b x e_a``, ``w_b = x_b / (x_a + x_b)``, ``x_k = E_k r_k^4`` of the
bonds along k (``element_rotation``; ``1/2``, the continuum's rotation, for equal bonds): they get infinite mass and inertia (``inv_mass = inv_inertia
= 0``) and, before every step, the velocity and spin that carry them exactly to the prescribed state
of the next step (velocity Verlet then drifts them there; the quaternion update is exact for a fixed
axis). ``gamma(t)`` rises smoothly (half-cosine ramp of its rate), then grows at a constant rate.

Why the faces normal to a too: a cube sheared by its two faces normal to b alone is not in uniform
shear, because its free faces normal to a cannot carry the traction ``sigma_ab``. Measured on the
calibrated beech lattice (``drive="layers"``, the two layers not turning): G 18 % below the lattice's
beam-theory value on 8^3 elements, 20 % below on 21^3 (the end effects scale with the cube, not with
the element size), against 2e-6 with the faces driven. Driving every face that carries a shear
traction leaves an interior whose uniform state is in equilibrium, so the measured modulus is the
lattice's (the faces normal to the third axis stay free: they carry no traction in this state). The
interior elements are free (translation and rotation) and find that state through the dynamics, with
the bond damping.

Measurement (global sums, the same on any number of ranks): the shear strain ``gamma = H_ab + H_ba``
from the least-squares displacement gradient of the free elements (``pardem.engine.reducer``), and the shear
stress ``sigma_ab = -F_a / A`` with ``F_a`` the sum of the forces on every element above the mid-plane
between the two central layers normal to b (the internal forces of that set cancel, so it is the
force of the bonds crossing the plane), ``A`` the represented section normal to b. ``shear_modulus``
is the slope of ``sigma_ab`` against ``gamma`` over the constant-rate phase (it removes the constant
viscous stress of the bond damping, like ``pardem.protocols.compression.measure``); ``shear_modulus_secant`` is
``sigma_ab / gamma`` at the end.

Why ``w_b``: the bonds along b turn with the shear (chord rotation gamma), those along a do not; the
free rotation of an interior element minimises ``x_b (omega - gamma)^2 + x_a omega^2`` (the bending
energy of the two bond families), hence ``omega = x_b / (x_a + x_b) gamma``. Driving the outer layers
with the continuum's ``gamma / 2`` instead perturbs the layers next to them when ``x_a != x_b``
(measured before this drive: 13 % below the lattice value for ``x`` ten times larger along L than along
T, plane LT, 8^3 elements).
"""
import copy
import math

import numpy as np

from pardem.protocols.calibration import SHEAR_PLANES, as_lrt, lattice_shear_modulus
from pardem.protocols.compression import build_case
from pardem.config import DeckError, check_deck, raw_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.engine.reducer import gradient_from_sums, strain_sums
from pardem.engine.state import FLAG_NEAR_PLATE
from pardem.triggers import Periodic, as_trigger


def shear_history(t, rate, ramp):
    """Shear strain gamma(t) [-] of a rate rising from 0 to ``rate`` [1/s] over ``ramp`` [s] along a
    half cosine, then constant."""
    if t >= ramp:
        return rate * (t - 0.5 * ramp)
    return 0.5 * rate * (t - ramp / math.pi * math.sin(math.pi * t / ramp))


class ShearDrive:
    """Operation (every step): speeds of the driven elements for the next step (owned rows).

    Driven rows are those with ``inv_mass == 0`` (the field travels with migrating elements).
    """
    trigger = Periodic(1)

    def __init__(self, a, b, centre_b, rate, ramp, turn=0.5):
        self.a, self.b = a, b
        self.centre_b = float(centre_b)
        self.rate, self.ramp = float(rate), float(ramp)
        spin = np.cross(np.eye(3)[b], np.eye(3)[a])      # omega = turn gamma (e_b x e_a)
        self.spin = float(turn) * spin

    def __call__(self, sim):
        e = sim.elements
        n = e.n_owned
        driven = np.nonzero(e.inv_mass[:n] == 0.0)[0]
        t0 = sim.step_count * sim.dt
        dg = (shear_history(t0 + sim.dt, self.rate, self.ramp) - shear_history(t0, self.rate, self.ramp)) / sim.dt
        e.v[driven] = 0.0
        e.v[driven, self.a] = dg * (e.x0[driven, self.b] - self.centre_b)
        e.w[driven] = dg * self.spin


class ShearSampler:
    """Operation: samples (time, gamma, sigma_ab) with one collective on the steps of ``trigger``
    (an int period [steps] or a ``Trigger``) and after the last step of every run (``at_end``)."""
    at_end = True

    def __init__(self, comm, a, b, plane_b, area, origin, trigger, sinks=()):
        self.comm, self.a, self.b = comm, a, b
        self.sinks = list(sinks)
        self.plane_b, self.area = float(plane_b), float(area)
        self.origin = np.asarray(origin, dtype=np.float64)
        self.trigger = as_trigger(trigger)
        self.samples = []
        self._local = np.empty(26)

    def __call__(self, sim):
        if self.samples and self.samples[-1]["step"] == sim.step_count:
            return
        e = sim.elements
        n = e.n_owned
        strain_sums(e.x, e.x0, e.flags, n, self.origin, self._local[:25])
        upper = e.x0[:n, self.b] > self.plane_b
        self._local[25] = e.f[:n, self.a][upper].sum()
        g = self.comm.sum(self._local)
        H = gradient_from_sums(g[:25])
        self.samples.append({"step": sim.step_count, "time": sim.time,
                             "gamma": float(H[self.a, self.b] + H[self.b, self.a]),
                             "stress": float(-g[25] / self.area), "H": H})
        for sink in self.sinks:
            sink(self.samples[-1])


# the series of a shear test (``ShearSampler`` samples): columns and units
SERIES_COLUMNS = ("step", "time", "gamma", "stress")
SERIES_UNITS = ("1", "s", "1", "Pa")
SERIES_DESCRIPTION = ("pardem simple-shear series: one row per sample of the engineering shear strain gamma "
                      "(least-squares fit of the free elements) and the shear stress sigma_ab [Pa] across the "
                      "mid-plane; one dataset per column with its unit in the 'units' attribute")


def element_rotation(young, radius_ratio, plane):
    """``w_b = x_b / (x_a + x_b)``, ``x_k = E_k r_k^4`` of the (L, R, T) bond triples: the interior
    element's rotation per unit shear strain of ``plane`` (module docstring)."""
    a, b = SHEAR_PLANES[plane]
    x = [E * r**4 for E, r in zip(young, radius_ratio)]
    return x[b] / (x[a] + x[b])


def shear_deck(deck, plane):
    """The compress deck of the shear test: ``deck`` with its plates normal to the gradient axis."""
    raw = raw_deck(copy.deepcopy(deck))
    raw["loading"]["axis"] = "xyz"[SHEAR_PLANES[plane][1]]
    return check_deck(COMPRESS_SCHEMA, raw)


def run_shear(comm, deck, plane="LT", strain=0.002, transits=8.0, shear_estimate=None, drive="faces",
              sinks=(), operations=(), every=None, steps=None):
    """Simple shear of the ordered domain of the checked compress ``deck`` in ``plane`` (LR, LT, RT)
    up to the engineering strain ``strain``; collective. Returns a dict (same on every rank):

    ``shear_modulus`` [Pa] (slope over the constant-rate phase), ``shear_modulus_secant`` [Pa],
    ``gamma`` (final measured strain), ``stress`` [Pa] (final sigma_ab), ``steps``, ``dt`` [s],
    ``n_elements``, ``n_driven``, ``plane``, ``transit_time`` [s], ``samples`` (count).

    The loading lasts ``transits`` shear-wave transits across the domain along b, the wave speed from
    ``shear_estimate`` [Pa] (default: the beam-theory value of the deck's bonds) and the domain's
    density. ``drive``: "faces" (the method above) or "layers" (only the two layers normal to b, not
    turning: the naive test, kept to show its end effects). DeckError unless the deck's domain is an
    ordered lattice with its frame untilted (the lattice axes are the test axes).
    ``sinks``: callables given each sample (dict: step, time, gamma, stress [Pa], H); ``operations``:
    more operations of the run (e.g. a ParaView writer), called after the drive and the sampler;
    ``every``: steps between samples (default about 200 per run); ``steps``: run only that many steps
    (the rate stays that of the full loading: a shorter run may be too short to measure, slope NaN).
    The result also holds ``samples_after_ramp`` and ``curve`` (the sampled gamma and stress [Pa]).
    """
    if deck["domain"]["kind"] != "ordered" or deck["domain"]["tilt_deg"] != 0.0:
        raise DeckError(f"domain.kind = {deck['domain']['kind']!r}, domain.tilt_deg = {deck['domain']['tilt_deg']}: "
                        f"the shear test expects an ordered domain with tilt_deg = 0")
    if plane not in SHEAR_PLANES or drive not in ("faces", "layers"):
        raise ValueError(f"plane {plane!r}, drive {drive!r}: expected one of {', '.join(SHEAR_PLANES)} and "
                         f"'faces' or 'layers'")
    a, b = SHEAR_PLANES[plane]
    case = build_case(comm, shear_deck(deck, plane), plates=False)
    sim = case.sim
    e = sim.elements
    R = deck["domain"]["radius"]
    n_tot = e.n_total
    lo = np.array([comm.min(float(e.x0[:e.n_owned, d].min()) if e.n_owned else math.inf) for d in range(3)])
    hi = np.array([comm.max(float(e.x0[:e.n_owned, d].max()) if e.n_owned else -math.inf) for d in range(3)])
    tol = 0.5 * R
    driven = np.zeros(n_tot, dtype=bool)
    for d in ((a, b) if drive == "faces" else (b,)):
        driven |= (e.x0[:, d] < lo[d] + tol) | (e.x0[:, d] > hi[d] - tol)
    e.inv_mass[driven] = 0.0
    e.inv_inertia[driven] = 0.0
    e.flags[:] &= ~FLAG_NEAR_PLATE
    e.flags[driven] |= FLAG_NEAR_PLATE         # left out of the strain fit
    extent = hi - lo + 2.0 * R
    layers_b = int(round((hi[b] - lo[b]) / (2.0 * R))) + 1
    plane_b = lo[b] + 2.0 * R * (layers_b // 2) - R     # between the two central layers
    centre_b = 0.5 * (lo[b] + hi[b])
    c = 3 - a - b
    area = float(extent[a] * extent[c])
    n_el = int(comm.sum(float(e.n_owned)))
    n_driven = int(comm.sum(float(driven[:e.n_owned].sum())))
    # loading time: shear wave speed sqrt(G / rho_D), rho_D = total mass / represented volume
    mass = float(comm.sum(float(e.mass[:e.n_owned].sum())))
    rho_D = mass / float(np.prod(extent))
    G = shear_estimate or lattice_shear_modulus(as_lrt(deck["bonds"]["young"]),
                                                as_lrt(deck["bonds"]["radius_ratio"]), plane)
    transit = extent[b] / math.sqrt(G / rho_D)
    ramp = 2.0 * transit
    duration = transits * transit + 0.5 * ramp
    rate = strain / (duration - 0.5 * ramp)
    n_steps = max(1, math.ceil(duration / sim.dt - 1e-9))
    turn = element_rotation(as_lrt(deck["bonds"]["young"]), as_lrt(deck["bonds"]["radius_ratio"]), plane)
    mover = ShearDrive(a, b, centre_b, rate, ramp, turn=turn if drive == "faces" else 0.0)
    n_steps = n_steps if steps is None else int(steps)
    sampler = ShearSampler(comm, a, b, plane_b, area, case.constants.origin, every or max(1, n_steps // 200), sinks)
    mover(sim)
    sampler(sim)
    for op in operations:
        op(sim)        # the initial state
    sim.run(n_steps, operations=[mover, sampler, *operations])
    s = sampler.samples
    t = np.array([x["time"] for x in s])
    g = np.array([x["gamma"] for x in s])
    tau = np.array([x["stress"] for x in s])
    keep = t >= ramp
    slope = float(np.polyfit(g[keep], tau[keep], 1)[0]) if keep.sum() >= 3 and np.ptp(g[keep]) > 0 else math.nan
    return {"plane": plane, "shear_modulus": slope,
            "shear_modulus_secant": float(tau[-1] / g[-1]) if g[-1] != 0 else math.nan,
            "gamma": float(g[-1]), "gamma_imposed": float(shear_history(sim.time, rate, ramp)),
            "stress": float(tau[-1]), "steps": n_steps, "dt": sim.dt, "n_elements": n_el,
            "n_driven": n_driven, "transit_time": float(transit), "ramp_time": float(ramp), "samples": len(s),
            "samples_after_ramp": int(keep.sum()), "element_rotation": turn,
            "curve": {"gamma": g.tolist(), "stress": tau.tolist()}}
