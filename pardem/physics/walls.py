"""Plane walls: element-wall contact with a linear or Hertz normal law and optional friction.

docs/physics.md sections 5 (plates) and 8 (contact laws). A wall set is any number of infinite planes
(plates, lateral walls) sharing one ``Params``; two sets with different laws are two calls.

Geometry (per call, arrays over the walls ``w`` of the set)
-----------------------------------------------------------
* ``normals[w]`` [3]: unit normal pointing **into** the domain (towards the elements);
* ``offsets[w]`` [m]: signed position of the plane along its normal, the plane is
  ``{x : normals[w] . x = offsets[w]}``; an axis-aligned plate at ``x[axis] = position`` with inward
  side ``s = +-1`` is ``normal = s e_axis``, ``offset = s position`` (``axis_planes``);
* ``velocities[w]`` [3] [m/s]: rigid translation of the wall (walls do not rotate). Pass it at the
  instant of the element velocities the kernel sees (the half step with velocity Verlet).

Element k touches wall w when ``delta = R_k - (n . x_k - offset) > 0`` [m] (an element that went
through the plane is pushed back harder). Contact point
``x_c = x_k - l n`` with the arm ``l = R_k - delta / 2`` (the middle of the overlap, as in
``contact_frame`` with the wall a sphere of infinite radius). Velocity of the element's contact point
relative to the wall ``u = v_k - V_w - l w_k x n``; ``d(delta)/dt = -u . n``; sliding velocity
``u_t = u - (u . n) n``, tangential displacement over the step ``ds = u_t dt``.

Laws (``Params.law``)
---------------------
The pair laws' own functions with the wall a sphere of infinite radius and mass (``R* = R``,
``m* = m``): ``linear_contact.linear_normal`` / ``linear_tangential`` and
``hertz_mindlin.hertz_normal`` / ``mindlin_stiffness``, with ``contact_frame.update_history``.

* ``"linear"``: ``fn = kn delta + cn d(delta)/dt``, ``cn = 2 zeta_n sqrt(kn m)``; tangential spring
  ``kt`` and dashpot ``ct = 2 zeta_t sqrt(kt m)`` exactly as ``linear_contact`` (the dashpot force
  ``-ct u_t`` is added to the stored spring force, the sum capped at ``mu fn``).
  ``zeta_n = linear_contact.damping_ratio(e)`` (exact restitution of the no-tension clipped contact).
* ``"hertz"`` (a sphere on a plane = ``R* = R``): ``fn = 4/3 E* sqrt(R) delta^(3/2)
  + gamma sqrt(m Sn) d(delta)/dt`` with ``Sn = 2 E* a``, ``a = sqrt(R delta)``; Mindlin
  ``kt = 8 G* a``; no tangential dashpot. ``E*, G*`` from ``hertz_mindlin.effective_moduli`` of the
  element and wall materials (``wall_young = inf``: rigid wall),
  ``gamma = hertz_mindlin.hertz_damping_coefficient(e)`` (exact restitution).

The wall has an infinite mass, so the reduced mass of the calibrations is the element's mass ``m``:
both calibrations then give the requested restitution for a sphere hitting the wall.
``fn`` is clipped at zero (no tension). Friction (``friction > 0``): incremental spring
``dh = -kt ds`` on the stored elastic tangential force ``h`` [N] on the element, Coulomb cap
``|h| <= mu fn`` (``contact_frame.update_history``); with the Hertz law, while the contact opens
``h`` is first scaled by ``kt(new)/kt(old)`` (``hertz_mindlin.unload_rescale``, as for pairs: no
load-unload cycle creates energy). Since walls only translate, ``h`` lives in the
wall's frame: each step it is only projected onto the current plane and rescaled (the
``contact_frame`` carry with zero spin; the pair law's turn by the mean spin of the pair would turn
it at half the element's drilling spin, which a wall that does not rotate has no reason to do).
Loads on the element: ``F = fn n + ft`` and torque about its centre ``T = -l n x ft``; the wall
receives ``-F`` at ``x_c`` (no couple), so element and wall balance about the contact point.

2D mode: nothing special here. For an element in the plane z = 0 (``v_z = w_x = w_y = 0``) and
a wall whose normal and velocity have no z component (``pardem.engine.walls.check_domain``), ``u``,
``ft`` and ``F`` lie in the plane and ``T`` is along z, so the 2D run is the 3D one bit for bit.

History
-------
``history`` [n_rows, n_walls, 3] float64 (or wider: the columns after the planes' are those of
the set's cylinders and meshes, ``pardem.physics.curved_walls``), indexed by element row (it migrates with the element
between ranks, like ``x``), zero where an element does not touch a wall (reset when a contact
opens). Frictionless sets need none: pass ``new_history(params, n_rows, n_walls)``, which is
``[n_rows, 0, 3]`` for them.

Interface
---------
``compute(params, elements, normals, offsets, velocities, history, dt, wall_force)`` adds the wall
loads to ``elements.f``/``elements.t`` of the owned rows ``[0, n_owned)`` only (ghost rows are
copies), updates ``history`` there, overwrites ``wall_force[:n_walls]`` ([>= n_walls, 3]) with this rank's force of
the elements **on** each wall [N] (the reaction; for a plate the compressive force along its inward
normal is ``-wall_force[w] . normals[w]``, the ``plates.plate_force`` value) and returns the elastic
energy ``sum 1/2 kn delta^2`` (linear) or ``2/5 fn_el delta`` (Hertz) ``+ |h|^2 / (2 kt)`` [J].
``wall_loop(law, damped, friction)`` is the compiled kernel behind it (one per sub-model choice,
chosen once at setup); ``single`` gives the loads of one element-wall pair (diagnostics);
``stiffness`` the tangent normal and tangential stiffness of a contact (for the critical time step).
"""
import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numba import njit

from pardem.physics.arguments import choice, keywords, real
from pardem.physics.contact_frame import update_history
from pardem.physics.hertz_mindlin import (effective_moduli, hertz_damping_coefficient, hertz_normal,
                                          mindlin_stiffness, unload_rescale)
from pardem.physics.linear_contact import damping_ratio, linear_normal, linear_tangential

LAWS = ("linear", "hertz")


@keywords("walls.Params")
@dataclass(frozen=True)
class Params:
    """Element-wall contact parameters of one wall set.

    law : ``"linear"`` or ``"hertz"``.
    kn, kt : normal and tangential stiffness [N/m] (linear law; ``kt`` defaults to ``kn``).
    young [Pa], poisson : the elements' material (Hertz law); wall_young [Pa] (``math.inf`` for a
        rigid wall), wall_poisson : the wall's material (default: the elements').
    friction : Coulomb coefficient ``mu >= 0`` (0: frictionless, no history).
    restitution : normal restitution coefficient in (0, 1]; 1 compiles the undamped kernel.
    tangential_damping : ratio ``zeta_t`` of the tangential dashpot (linear law; default ``zeta_n``).
    Derived (read only): stiff_n, stiff_t (kn, kt or E*, G* [N/m or Pa]), damp_n (zeta_n or gamma),
        damp_t (zeta_t, 0 for Hertz), damped, frictional.
    """
    law: str = "linear"
    kn: float = None
    kt: float = None
    young: float = None
    poisson: float = None
    wall_young: float = None
    wall_poisson: float = None
    friction: float = 0.0
    restitution: float = 1.0
    tangential_damping: float = None
    stiff_n: float = field(init=False)
    stiff_t: float = field(init=False)
    damp_n: float = field(init=False)
    damp_t: float = field(init=False)
    damped: bool = field(init=False)
    frictional: bool = field(init=False)

    def __post_init__(self):
        choice("walls.law", self.law, LAWS)
        mu = self.friction
        real("walls.friction", mu, lo=0.0, lo_open=False, note="Coulomb coefficient")
        e = self.restitution
        real("walls.restitution", e, lo=0.0, hi=1.0, hi_open=False)
        # a field of the other law would be silently ignored: refused instead
        other = ("young", "poisson", "wall_young", "wall_poisson") if self.law == "linear" else \
            ("kn", "kt", "tangential_damping")
        for name in other:
            if getattr(self, name) is not None:
                raise ValueError(f"walls.{name} = {getattr(self, name)!r} applies to the "
                                 f"{'hertz' if self.law == 'linear' else 'linear'} law only, not to "
                                 f"law {self.law!r} (leave it None)")
        if self.law == "linear":
            kt = self.kn if self.kt is None else self.kt
            real("walls.kn", self.kn, lo=0.0, unit="[N/m]")
            real("walls.kt", kt, lo=0.0, unit="[N/m]", note="None: kn")
            zn = damping_ratio(e)
            zt = zn if self.tangential_damping is None else self.tangential_damping
            real("walls.tangential_damping", zt, lo=0.0, lo_open=False,
                 note="damping ratio zeta_t; None: zeta_n")
            derived = (float(self.kn), float(kt), zn, float(zt), zn > 0.0 or zt > 0.0)
        else:
            wy = self.young if self.wall_young is None else self.wall_young
            wp = self.poisson if self.wall_poisson is None else self.wall_poisson
            real("walls.young", self.young, lo=0.0, unit="[Pa]")
            real("walls.wall_young", wy, lo=0.0, unit="[Pa]", inf=True, note="inf: rigid wall; None: young")
            # Poisson ratio: (-1, 0.5), the deck's range (pardem.config)
            real("walls.poisson", self.poisson, lo=-1.0, hi=0.5)
            real("walls.wall_poisson", wp, lo=-1.0, hi=0.5, note="None: poisson")
            e_star, g_star = effective_moduli(self.young, self.poisson, wy, wp)
            derived = (e_star, g_star, hertz_damping_coefficient(e), 0.0, e < 1.0)
        for name, val in zip(("stiff_n", "stiff_t", "damp_n", "damp_t", "damped"), derived):
            object.__setattr__(self, name, val)
        object.__setattr__(self, "frictional", mu > 0.0)


# ---------------------------------------------------------------------------------------------
# one element-wall contact

@njit(cache=True, inline="always", error_model="numpy")
def wall_contact(k, wl, delta, n0, n1, n2, v, w, radius, mass, velocities, hist, dt,
                 stiff_n, stiff_t, mu, damp_n, damp_t, out, hertz, damped, friction):
    """Contact of element row k with wall wl of unit inward normal ``n`` at overlap ``delta > 0``
    [m]; ``hertz``, ``damped``, ``friction`` are compile-time constants. Writes ``out[6]`` =
    (force, torque about the centre) on the element, updates ``hist[k, wl]`` (only with
    ``friction``) and returns the elastic energy [J].
    """
    r = radius[k]
    arm = r - 0.5 * delta                        # centre to contact point
    un = u0 = u1 = u2 = 0.0
    if damped or friction:
        # u = v - V_wall - arm w x n
        u0 = v[k, 0] - velocities[wl, 0] - arm * (w[k, 1] * n2 - w[k, 2] * n1)
        u1 = v[k, 1] - velocities[wl, 1] - arm * (w[k, 2] * n0 - w[k, 0] * n2)
        u2 = v[k, 2] - velocities[wl, 2] - arm * (w[k, 0] * n1 - w[k, 1] * n0)
        un = u0 * n0 + u1 * n1 + u2 * n2          # = -d(delta)/dt
    # the pair laws with the wall a sphere of infinite radius and mass: R* = R, m* = m
    if hertz:
        fn, fn_el, a = hertz_normal(r, mass[k], delta, -un, stiff_n, damp_n, damped)
        energy = 0.4 * fn_el * delta
    else:
        fn = linear_normal(stiff_n, mass[k], delta, -un, damp_n, damped)
        energy = 0.5 * (stiff_n * delta) * delta
    f0 = fn * n0
    f1 = fn * n1
    f2 = fn * n2
    t0 = t1 = t2 = 0.0
    if friction:
        cap = mu * fn
        ut0 = u0 - un * n0
        ut1 = u1 - un * n1
        ut2 = u2 - un * n2
        # zero spin: the history lives in the frame of the wall, which does not rotate
        if hertz:
            kt = mindlin_stiffness(stiff_t, a)
            # kt follows the contact radius: scale the stored force down while the contact opens
            # (-un = d(delta)/dt), or a load-unload cycle creates energy (hertz_mindlin.unload_rescale)
            unload_rescale(hist[k], wl, delta, -un, dt)
            h0, h1, h2 = update_history(hist[k], wl, n0, n1, n2, ut0, ut1, ut2, 0.0, dt, kt, cap)
            g0, g1, g2 = h0, h1, h2
        else:
            kt = stiff_t
            h0, h1, h2, g0, g1, g2 = linear_tangential(hist[k], wl, n0, n1, n2, ut0, ut1, ut2, 0.0,
                                                       dt, kt, mass[k], damp_t, cap, damped)
        energy += 0.5 * (h0 * h0 + h1 * h1 + h2 * h2) / kt
        f0 += g0
        f1 += g1
        f2 += g2
        # torque (x_c - x) x F = -arm n x ft
        t0 = -arm * (n1 * g2 - n2 * g1)
        t1 = -arm * (n2 * g0 - n0 * g2)
        t2 = -arm * (n0 * g1 - n1 * g0)
    out[0] = f0
    out[1] = f1
    out[2] = f2
    out[3] = t0
    out[4] = t1
    out[5] = t2
    return energy


# ---------------------------------------------------------------------------------------------
# the loop over owned elements and walls

@njit(cache=True, inline="always", error_model="numpy")
def _forget(hist, k, wl):
    """Zero the history of a pair not in contact; tested first, so that the sweep over rows far
    from the wall only reads it."""
    if hist[k, wl, 0] != 0.0 or hist[k, wl, 1] != 0.0 or hist[k, wl, 2] != 0.0:
        hist[k, wl, 0] = 0.0
        hist[k, wl, 1] = 0.0
        hist[k, wl, 2] = 0.0


@njit(cache=True, inline="always", error_model="numpy")
def _touch(k, wl, delta, n0, n1, n2, x, v, w, radius, mass, f, t, velocities, hist, dt, stiff_n,
           stiff_t, mu, damp_n, damp_t, out, wall_force, hertz, damped, friction):
    """``wall_contact`` and the scatter of its loads to row k and (the reaction) to wall wl."""
    energy = wall_contact(k, wl, delta, n0, n1, n2, v, w, radius, mass, velocities, hist, dt,
                          stiff_n, stiff_t, mu, damp_n, damp_t, out, hertz, damped, friction)
    f[k, 0] += out[0]
    f[k, 1] += out[1]
    f[k, 2] += out[2]
    wall_force[wl, 0] -= out[0]
    wall_force[wl, 1] -= out[1]
    wall_force[wl, 2] -= out[2]
    if friction:
        t[k, 0] += out[3]
        t[k, 1] += out[4]
        t[k, 2] += out[5]
    return energy


def _wall_loop(hertz, damped, friction):
    """Loop over walls and owned rows; the three flags are frozen as compile-time constants."""
    @njit(cache=True, error_model="numpy")
    def loop(x, v, w, radius, mass, f, t, n_owned, normals, offsets, axes, velocities, hist, dt,
             stiff_n, stiff_t, mu, damp_n, damp_t, wall_force):
        out = np.empty(6)
        energy = 0.0
        # walls outside: one sweep of the rows per wall, the plane held in registers; a wall
        # normal to a coordinate axis reads one coordinate per row (as cheap as a dedicated plate loop)
        for wl in range(offsets.shape[0]):
            n0 = normals[wl, 0]
            n1 = normals[wl, 1]
            n2 = normals[wl, 2]
            off = offsets[wl]
            ax = axes[wl]
            wall_force[wl, 0] = 0.0
            wall_force[wl, 1] = 0.0
            wall_force[wl, 2] = 0.0
            if ax >= 0:
                side = normals[wl, ax]
                for k in range(n_owned):
                    delta = radius[k] - (side * x[k, ax] - off)
                    if delta > 0.0:
                        energy += _touch(k, wl, delta, n0, n1, n2, x, v, w, radius, mass, f, t,
                                         velocities, hist, dt, stiff_n, stiff_t, mu, damp_n,
                                         damp_t, out, wall_force, hertz, damped, friction)
                    elif friction:
                        _forget(hist, k, wl)
            else:
                for k in range(n_owned):
                    delta = radius[k] - (n0 * x[k, 0] + n1 * x[k, 1] + n2 * x[k, 2] - off)
                    if delta > 0.0:
                        energy += _touch(k, wl, delta, n0, n1, n2, x, v, w, radius, mass, f, t,
                                         velocities, hist, dt, stiff_n, stiff_t, mu, damp_n,
                                         damp_t, out, wall_force, hertz, damped, friction)
                    elif friction:
                        _forget(hist, k, wl)
        return energy
    return loop


@lru_cache(maxsize=None)
def wall_loop(law, damped, friction):
    """The compiled kernel of one sub-model choice (built once per choice).

    ``loop(x, v, w, radius, mass, f, t, n_owned, normals, offsets, axes, velocities, history, dt,
    stiff_n, stiff_t, mu, damp_n, damp_t, wall_force)`` with the ``Params`` derived values and
    ``axes = aligned_axes(normals)``; see the module docstring. Returns the elastic energy [J].
    """
    if law not in LAWS:
        raise ValueError(f"walls.law must be one of {', '.join(LAWS)}, got {law!r}")
    return _wall_loop(law == "hertz", bool(damped), bool(friction))


@njit(cache=True, error_model="numpy")
def elastic_normal_terms(x, radius, n_owned, n0, n1, n2, offset, hertz, stiff_n):
    """Per owned row [n_owned] the elastic normal force [N] of its contact with the plane
    ``n . x = offset`` (``kn delta`` or ``4/3 E* sqrt(R delta) delta``; 0 without contact): the
    terms of a servo's measure, a function of the positions only (summed exactly over ranks)."""
    out = np.zeros(n_owned)
    for k in range(n_owned):
        delta = radius[k] - (n0 * x[k, 0] + n1 * x[k, 1] + n2 * x[k, 2] - offset)
        if delta > 0.0:
            if hertz:
                out[k] = 4.0 / 3.0 * stiff_n * np.sqrt(radius[k] * delta) * delta
            else:
                out[k] = stiff_n * delta
    return out


# ---------------------------------------------------------------------------------------------
# model interface (STYLE pattern 3)

def axis_planes(axis, positions, sides):
    """``(normals [n, 3], offsets [n])`` of planes ``x[axis] = positions`` [m] with inward sides +-1."""
    if axis not in (0, 1, 2):
        raise ValueError(f"walls axis must be 0, 1 or 2, got {axis}")
    pos = np.asarray(positions, dtype=np.float64).reshape(-1)
    s = np.asarray(sides, dtype=np.float64).reshape(-1)
    if s.shape != pos.shape or not np.all(np.abs(s) == 1.0):
        raise ValueError(f"walls sides must be +1 or -1, one per position, got {sides}")
    normals = np.zeros((pos.size, 3))
    normals[:, axis] = s
    return normals, s * pos


def new_history(params, n_rows, n_walls):
    """Zero history ``[n_rows, n_walls, 3]``, or ``[n_rows, 0, 3]`` for a frictionless set."""
    return np.zeros((int(n_rows), int(n_walls) if params.frictional else 0, 3))


@njit(cache=True, error_model="numpy")
def _plane_axes(normals):
    """``(axes, bad)``: per wall the coordinate axis its normal lies along (-1 if none), and the
    first wall whose normal is not a unit vector (-1 if none)."""
    n_walls = normals.shape[0]
    axes = np.full(n_walls, -1, dtype=np.int64)
    bad = -1
    for wl in range(n_walls):
        n0 = normals[wl, 0]
        n1 = normals[wl, 1]
        n2 = normals[wl, 2]
        if not abs(n0 * n0 + n1 * n1 + n2 * n2 - 1.0) <= 1e-12 and bad < 0:
            bad = wl
        for ax in range(3):
            if abs(normals[wl, ax]) == 1.0 and n0 * n0 + n1 * n1 + n2 * n2 == 1.0:
                axes[wl] = ax
    return axes, bad


def aligned_axes(normals):
    """Per wall [n_walls] int64: the coordinate axis its unit normal lies along, or -1 (the kernel
    then reads one coordinate per row instead of three). Raises if a normal is not a unit vector."""
    axes, bad = _plane_axes(normals)
    if bad >= 0:
        raise ValueError(f"walls normals[{bad}] must be a unit vector, got {normals[bad]}")
    return axes


def check_walls(params, normals, offsets, velocities, history, wall_force, n_owned):
    """Check the arrays of one call (O(n_walls), no scan of the element rows) and return
    ``aligned_axes(normals)``."""
    n_walls = offsets.shape[0] if offsets.ndim == 1 else -1
    if n_walls < 0 or offsets.dtype != np.float64:
        raise ValueError(f"walls offsets must be float64 [n_walls], got {offsets.dtype} {offsets.shape}")
    for name, arr in (("normals", normals), ("velocities", velocities)):
        if arr.shape != (n_walls, 3) or arr.dtype != np.float64:
            raise ValueError(f"walls {name} must be float64 [{n_walls}, 3], got {arr.dtype} {arr.shape}")
    # rows and columns after the planes' belong to the set's curved walls and meshes
    if wall_force.ndim != 2 or wall_force.shape[0] < n_walls or wall_force.shape[1] != 3 \
            or wall_force.dtype != np.float64:
        raise ValueError(f"walls wall_force must be float64 [>= {n_walls}, 3], got {wall_force.dtype} "
                         f"{wall_force.shape}")
    if (history.ndim != 3 or history.shape[0] < n_owned or history.shape[2] != 3
            or history.dtype != np.float64 or history.shape[1] < (n_walls if params.frictional else 0)
            or (history.shape[1] and not params.frictional)):
        width = n_walls if params.frictional else 0
        raise ValueError(f"walls history must be float64 [n_rows >= {n_owned}, "
                         f"{'>= ' if width else ''}{width}, 3] (new_history), got {history.dtype} {history.shape}")
    return aligned_axes(normals)


def compute(params, elements, normals, offsets, velocities, history, dt, wall_force):
    """Add the wall loads to the owned rows of ``elements.f``/``elements.t``.

    normals [n_walls, 3] (unit, inward), offsets [n_walls] [m], velocities [n_walls, 3] [m/s];
    history : see ``new_history``, updated in place; dt [s] : step; wall_force : [n_walls, 3]
    output, this rank's force on each wall [N]. Returns the elastic energy [J].
    """
    e, p = elements, params
    axes = check_walls(p, normals, offsets, velocities, history, wall_force, e.n_owned)
    loop = wall_loop(p.law, p.damped, p.frictional)
    return loop(e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, e.n_owned, normals, offsets, axes,
                velocities, history, float(dt), p.stiff_n, p.stiff_t, p.friction, p.damp_n,
                p.damp_t, wall_force)


def single(params, elements, k, normal, offset, velocity=(0.0, 0.0, 0.0), history_row=(0.0, 0.0, 0.0),
           dt=0.0):
    """Diagnostics of element row k against one wall, nothing modified: dict with ``touching``,
    ``force``, ``torque`` (about the centre) on the element, ``history`` (the value the step would
    store), ``contact_point`` [m] and ``energy`` [J]."""
    e, p = elements, params
    rows = slice(k, k + 1)
    nrm = np.array(normal, dtype=np.float64).reshape(1, 3)
    off = np.array([offset], dtype=np.float64)
    vel = np.array(velocity, dtype=np.float64).reshape(1, 3)
    hist = np.zeros((1, 1 if p.frictional else 0, 3))
    if p.frictional:
        hist[0, 0] = history_row
    f = np.zeros((1, 3))
    t = np.zeros((1, 3))
    wall_force = np.zeros((1, 3))
    axes = check_walls(p, nrm, off, vel, hist, wall_force, 1)
    energy = wall_loop(p.law, p.damped, p.frictional)(
        e.x[rows], e.v[rows], e.w[rows], e.radius[rows], e.mass[rows], f, t, 1, nrm, off, axes, vel,
        hist,
        float(dt), p.stiff_n, p.stiff_t, p.friction, p.damp_n, p.damp_t, wall_force)
    delta = e.radius[k] - (nrm[0] @ e.x[k] - offset)
    return {"touching": bool(delta > 0.0), "force": f[0], "torque": t[0],
            "history": hist[0, 0].copy() if p.frictional else np.zeros(3), "energy": float(energy),
            "contact_point": e.x[k] - (e.radius[k] - 0.5 * delta) * nrm[0]}


def stiffness(params, radius, overlap):
    """Tangent normal stiffness ``d fn_el / d delta`` and tangential stiffness [N/m] of a contact of
    an element of radius [m] at ``overlap`` [m] (for the critical time step; Hertz grows with it)."""
    p = params
    if p.law == "linear":
        return p.stiff_n, (p.stiff_t if p.frictional else 0.0)
    a = math.sqrt(float(radius) * max(float(overlap), 0.0))
    return 2.0 * p.stiff_n * a, (8.0 * p.stiff_t * a if p.frictional else 0.0)
