"""Walls for any ``Simulation``: planes (static, at constant velocity, on a prescribed motion or
force-controlled), cylinders and triangle meshes, in one set sharing one law.

``Walls`` is a set of infinite planes sharing one element-wall law (``pardem.physics.walls.Params``,
linear or Hertz, optional friction and restitution). It has the interface ``Simulation`` uses for
``sim.plates`` (``planes(time)``, ``move_to(time)``, ``law``, ``wall_force``, ``force_local``), so the
time loop and the compiled wall kernel (``pardem.physics.walls.compute``) are the same as for the
compression test's plates (``pardem.engine.state.Plates``). A Simulation holds one wall set.

A wall is given by a point ``p`` on it and its unit normal ``n`` pointing **into** the domain (towards
the elements): the plane is ``{x : n . x = n . p}``. An element of radius R touches it when its centre
is closer than R to the plane. A wall may translate at a constant velocity ``V`` [m/s]: its plane at
time t is ``n . x = n . p + n . V (t - t_add)`` (``t_add`` = the simulation time when it was added); the
tangential part of ``V`` moves the surface in its own plane (a conveyor: it drags the elements through
friction). Walls do not rotate.

``add_walls(sim, normals, points, ...)`` builds the set, gives the elements their wall history
(``elements.wall_h``, [n_rows, n_walls, 3] with friction, [n_rows, 0, 3] without; it migrates with the
elements between ranks), attaches it as ``sim.plates`` and checks ``sim.dt`` against the critical time
step with the walls' stiffness (``pardem.engine.critical_step.critical_time_step_of``).

Beyond planes at constant velocity (docs/physics.md, section 8, walls): ``motions`` gives a plane
a prescribed translation of ``pardem.physics.wall_motion`` (ramp, sinusoid, table) or makes it
force-controlled (``Servo``: its speed along the normal follows the force error, updated every
``period`` steps by ``ServoOperation``, one operation of ``sim.operations``); ``Cylinder`` and
``Mesh`` are curved and triangulated surfaces (``pardem.physics.curved_walls``), each with a
translation motion, a cylinder also with a spin about its axis. All share the set's law and the
elements' wall history (one column per plane, cylinder and mesh, in that order); the rows of
``force`` follow the same order; ``triangle_force`` / ``triangle_forces(comm)`` are per triangle.
The description (``pardem.engine.system.WallModel``) stores every motion and the servo's state, so
that a restored set moves the same bits.

``walls.force`` [n_walls, 3] [N] is the total force of the elements **on** each wall and
``walls.normal_force`` [n_walls] [N] its compressive part ``-F . n`` (positive when the elements
push the wall): plain arrays, the same on every rank, as of the last step after which an operation
ran, or the end of the last ``sim.run`` (``Simulation._reduce_globals`` reduces them there, one
allreduce with the fixes' reactions; ``pardem.engine.particles.reduce_globals``). Reading them
needs no collective, so a script may do it on one rank. ``walls.forces(comm)`` and
``normal_forces(comm)`` are the same sums of the last step, collective. Each element's wall load
depends on that element alone, so the trajectories are the same bits on any number of ranks (with
reproducible contacts); the total is a floating-point sum over the rows, then over the ranks, so it
agrees between decompositions to the round-off of that sum (about ``n eps sum_k |F_k|``), not bit
for bit.

Domain (``check_domain``, at ``add_walls``): in a cell no wall normal may have a component along a
periodic axis (elements would wrap through the wall). In the 2D mode (``pardem.engine.plane``) a
wall is a line of the plane z = 0: its normal and its velocity have no z component. The kernel is
the 3D one; for grains in the plane (``v_z = w_x = w_y = 0``) the contact point, the relative
velocity, the friction force lie in the plane and the torque is along z, so a 2D run with walls is
the 3D run of the same planar configuration bit for bit (``tests/test_two_d_walls_cement.py``).
"""
import math

import numpy as np

from pardem.engine.critical_step import critical_time_step_of
from pardem.parallel.exact_sum import exact_sum
from pardem.physics import curved_walls, wall_motion
from pardem.physics import walls as wall_kernels
from pardem.physics.arguments import array, keywords, real, short
from pardem.triggers import Periodic

WALL_OVERLAP_BOUND = 0.05   # Hertz walls: the critical time step holds up to this overlap / R
MESH_REACH = 1.5            # default mesh reach [largest radius]: room for larger inserted grains


class Cylinder:
    """A cylindrical wall (``pardem.physics.curved_walls``): axis through ``point`` [3] [m] along
    ``axis`` [3] (normalised here), ``radius`` [m]; ``inside`` True for elements inside it (a drum,
    a silo), False outside (a pillar); ``angular_velocity`` [rad/s] its spin about ``axis`` (right
    hand; the surface drags the elements through friction, it does not move them otherwise);
    ``extent`` ``(lo, hi)`` [m] along the axis from ``point`` (default infinite); ``motion`` a
    translation of ``pardem.physics.wall_motion`` (default static)."""

    def __init__(self, point, axis, radius, inside=True, angular_velocity=0.0, extent=None, motion=None):
        self.point = _vec3("Cylinder.point", point, "[m]")
        a = _vec3("Cylinder.axis", axis, "")
        norm = float(np.linalg.norm(a))
        if not norm > 0.0:
            raise ValueError(f"Cylinder.axis must be a non-zero vector, got {a.tolist()}")
        self.axis = a / norm
        self.radius = real("Cylinder.radius", radius, lo=0.0, unit="[m]")
        if not isinstance(inside, (bool, np.bool_)):
            raise ValueError(f"Cylinder.inside must be True (elements inside) or False, got {inside!r}")
        self.inside = bool(inside)
        self.angular_velocity = real("Cylinder.angular_velocity", angular_velocity, unit="[rad/s]")
        lo, hi = (-math.inf, math.inf) if extent is None else extent
        if not (isinstance(lo, (int, float, np.floating)) and isinstance(hi, (int, float, np.floating))
                and lo < hi and not math.isnan(lo) and not math.isnan(hi)):
            raise ValueError(f"Cylinder.extent must be (lo, hi) [m] along the axis with lo < hi, got {extent!r}")
        self.extent = (float(lo), float(hi))
        self.motion = wall_motion.Constant() if motion is None else wall_motion.motion_from_dict(motion)

    def row(self, shift=np.zeros(3)):
        """The kernel's 10 numbers (``pardem.physics.curved_walls``) with the axis point moved by
        ``shift`` [3] [m]."""
        p = self.point + shift
        return np.array([p[0], p[1], p[2], *self.axis, self.radius, 1.0 if self.inside else -1.0,
                         *self.extent])

    def to_dict(self):
        return {"kind": "cylinder", "point": self.point.tolist(), "axis": self.axis.tolist(),
                "radius": self.radius, "inside": self.inside, "angular_velocity": self.angular_velocity,
                "extent": [_finite_or_text(v) for v in self.extent], "motion": self.motion.to_dict()}

    @classmethod
    def from_dict(cls, d):
        c = cls(d["point"], d["axis"], d["radius"], d["inside"], d["angular_velocity"],
                tuple(float(v) for v in d["extent"]), d["motion"])
        c.axis = np.asarray(d["axis"], dtype=np.float64)    # the stored unit axis, bit for bit
        return c


class Mesh:
    """A triangle-mesh wall (``pardem.physics.curved_walls``): ``triangles`` [n_tri, 3, 3] [m]
    (``pardem.io.stl.read_stl``), one contact per element (the nearest point of the mesh);
    ``motion`` a translation of ``pardem.physics.wall_motion`` (default static); ``rotation``
    ``(centre [3] [m], axis [3], angular_velocity [rad/s])``: a steady turn of the mesh about the
    axis through ``centre`` (a point of the mesh's frame, carried by the translation), by
    ``angular_velocity (t - time0)`` (default none); ``reach`` [m] the largest element radius the
    candidate grid serves (default: set by ``add_walls`` to 1.5 times the largest radius of the
    system); ``name`` for the user."""

    def __init__(self, triangles, motion=None, reach=None, name="", rotation=None):
        tris = array("Mesh.triangles", triangles, "[m]")
        if tris.ndim != 3 or tris.shape[1:] != (3, 3) or tris.shape[0] < 1 or not np.all(np.isfinite(tris)):
            raise ValueError(f"Mesh.triangles must be finite [n_tri >= 1, 3, 3] [m], got shape {tris.shape}")
        self.triangles = np.ascontiguousarray(tris, dtype=np.float64)
        area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
        bad = np.nonzero(~(area2 > 0.0))[0]
        if len(bad):
            raise ValueError(f"Mesh.triangles[{int(bad[0])}] is degenerate (zero area): "
                             f"{tris[int(bad[0])].tolist()}")
        self.motion = wall_motion.Constant() if motion is None else wall_motion.motion_from_dict(motion)
        self.reach = None if reach is None else real("Mesh.reach", reach, lo=0.0, unit="[m]")
        self.name = str(name)
        self._grid = None
        self.rotation = None
        if rotation is not None:
            try:
                centre, axis, rate = rotation
            except (TypeError, ValueError):
                raise ValueError(f"Mesh.rotation must be (centre [3] [m], axis [3], angular_velocity [rad/s]), "
                                 f"got {rotation!r}") from None
            a = _vec3("Mesh.rotation axis", axis, "")
            if not np.linalg.norm(a) > 0.0:
                raise ValueError(f"Mesh.rotation axis must be a non-zero vector, got {a.tolist()}")
            self.rotation = (_vec3("Mesh.rotation centre", centre, "[m]"), a / np.linalg.norm(a),
                             real("Mesh.rotation angular_velocity", rate, unit="[rad/s]"))

    def turn(self, tau):
        """``(rotating, centre [3], rot [3, 3], spin [3])`` at ``tau`` [s] after ``time0``."""
        if self.rotation is None:
            return False, np.zeros(3), np.eye(3), np.zeros(3)
        centre, a, rate = self.rotation
        angle = rate * tau
        k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        rot = np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)   # Rodrigues
        return True, centre, rot, rate * a

    @property
    def n_triangles(self):
        return self.triangles.shape[0]

    def grid(self):
        if self._grid is None:
            self._grid = curved_walls.mesh_grid(self.triangles, self.reach)
        return self._grid

    def to_dict(self):
        d = {"kind": "mesh", "triangles": self.triangles.tolist(), "motion": self.motion.to_dict(),
             "reach": self.reach, "name": self.name}
        if self.rotation is not None:
            d["rotation"] = [self.rotation[0].tolist(), self.rotation[1].tolist(), self.rotation[2]]
        return d

    @classmethod
    def from_dict(cls, d):
        m = cls(d["triangles"], d["motion"], d["reach"], d.get("name", ""), d.get("rotation"))
        if m.rotation is not None:      # the stored unit axis, bit for bit
            m.rotation = (m.rotation[0], np.asarray(d["rotation"][1], dtype=np.float64), m.rotation[2])
        return m


class Servo:
    """A force-controlled plane wall: the wall moves along its normal at
    ``v_n = gain (F_target - F_n)`` [m/s], capped at ``max_speed``, with ``F_n`` the global
    compressive force of the elements on it [N] (``Walls.normal_force``) and ``F_target = force``
    or ``stress * area`` [N]; the speed is updated every ``period`` steps (a collective of the
    run's operations, ``ServoOperation``) and held between. ``F_n`` is the elastic normal force of
    the wall's contacts at the end of the step (the dashpots left out: they average out at a steady
    state, and the measure is then a function of the positions, summed exactly over the ranks, so
    that a servo run is the same bits on any number of ranks); ``measured`` holds its last value. ``gain`` [m/(N s)]: with the wall's
    contacts of total stiffness ``k_w`` [N/m] the force error shrinks by ``1 - gain k_w period dt``
    per update, so the servo is stable for ``gain < 2 / (k_w period dt)`` and reaches the target
    without overshoot for ``gain <= 1 / (k_w period dt)`` (docs/physics.md, walls);
    ``add_walls`` refuses a gain above the bound of one contact (``k_w = kn``).
    State (set by the run, stored by checkpoints): ``speed`` [m/s] the current normal speed,
    ``offset_ref`` [m] and ``time_ref`` [s] the plane's offset at the last update."""
    kind = "servo"

    def __init__(self, gain, force=None, stress=None, area=None, max_speed=math.inf, period=1,
                 speed=0.0, offset_ref=None, time_ref=None):
        if (force is None) == (stress is None):
            raise ValueError("Servo: give either force [N] or stress [Pa] with area [m^2], not both")
        if force is not None:
            self.target = real("Servo.force", force, unit="[N]")
        else:
            self.target = real("Servo.stress", stress, unit="[Pa]") * real("Servo.area", area, lo=0.0, unit="[m^2]")
        self.force, self.stress, self.area = force, stress, area
        self.gain = real("Servo.gain", gain, lo=0.0, unit="[m/(N s)]")
        self.max_speed = real("Servo.max_speed", max_speed, lo=0.0, unit="[m/s]", inf=True)
        if isinstance(period, bool) or not isinstance(period, (int, np.integer)) or period < 1:
            raise ValueError(f"Servo.period must be an integer >= 1 [steps], got {period!r}")
        self.period = int(period)
        self.speed = float(speed)
        self.offset_ref = None if offset_ref is None else float(offset_ref)
        self.time_ref = None if time_ref is None else float(time_ref)
        self.measured = math.nan

    def gain_bound(self, stiffness, dt):
        """The largest stable gain [m/(N s)] for contacts of total stiffness [N/m] at step dt [s]."""
        return 2.0 / (float(stiffness) * self.period * float(dt))

    def to_dict(self):
        return {"kind": self.kind, "gain": self.gain, "force": self.force, "stress": self.stress,
                "area": self.area, "max_speed": _finite_or_text(self.max_speed), "period": self.period,
                "speed": self.speed, "offset_ref": self.offset_ref, "time_ref": self.time_ref}


def _finite_or_text(v):
    """JSON has no infinity: +-inf as the strings "inf", "-inf"."""
    return v if math.isfinite(v) else ("inf" if v > 0 else "-inf")


def _plane_motion(d):
    if d is None or isinstance(d, Servo):
        return d
    if isinstance(d, dict) and d.get("kind") == "servo":
        args = {k: v for k, v in d.items() if k != "kind"}
        args["max_speed"] = float(args.get("max_speed", math.inf))
        return Servo(**args)
    return wall_motion.motion_from_dict(d)


def _vec3(name, value, unit):
    v = array(name, value, unit)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers {unit}, got {np.asarray(value).tolist()}")
    return np.array(v, dtype=np.float64)


@keywords("Walls")
class Walls:
    """One wall set (see the module docstring): planes, cylinders and meshes sharing one law.

    normals [n, 3] : inward unit normals of the planes (normalised here; must be non-zero; n may be
    0 when there are other walls); points [n, 3] [m] : a point on each plane; velocities [n, 3]
    [m/s] : constant translation velocities (default 0); law : ``pardem.physics.walls.Params``;
    time0 [s] : the time at which the walls are at ``points``; motions : one per plane, None (the
    constant velocity) or a motion of ``pardem.physics.wall_motion`` (its dict too) or a ``Servo``
    (that plane's velocity must then be 0); cylinders : ``Cylinder`` list; meshes : ``Mesh`` list.
    Columns of ``wall_force``, ``force`` and the history: planes, then cylinders, then meshes.
    """

    def __init__(self, normals, points, law, velocities=None, time0=0.0, motions=None, cylinders=(),
                 meshes=()):
        cylinders = [c if isinstance(c, Cylinder) else Cylinder.from_dict(c) for c in (cylinders or ())]
        meshes = [m if isinstance(m, Mesh) else Mesh.from_dict(m) for m in (meshes or ())]
        others = len(cylinders) + len(meshes)
        normals = array("normals", np.zeros((0, 3)) if normals is None else normals).copy()
        if normals.ndim == 1:
            normals = normals.reshape(1, -1)
        if normals.size == 0 and others:
            normals = np.zeros((0, 3))
        if normals.ndim != 2 or normals.shape[1] != 3 or normals.shape[0] < (0 if others else 1):
            raise ValueError(f"normals must have shape (n_walls, 3) with n_walls >= 1, got {normals.shape}")
        n = normals.shape[0]
        with np.errstate(over="ignore"):   # an overflowing norm is refused below
            length = np.linalg.norm(normals, axis=1)
        if not np.all(np.isfinite(length)) or np.any(length <= 0.0):
            raise ValueError(f"normals must be finite non-zero vectors (inward wall normals), got {normals.tolist()}")
        normals /= length[:, None]
        # exact axis-aligned normals let the kernel read one coordinate per row
        aligned = np.isclose(np.abs(normals), 1.0, rtol=0, atol=1e-15)
        normals[aligned] = np.sign(normals[aligned])
        points = array("points", np.zeros((0, 3)) if points is None else points, "[m]").copy()
        if points.shape == (3,) and n == 1:
            points = points.reshape(1, 3)
        if n == 0 and points.size == 0:
            points = np.zeros((0, 3))
        if points.shape != (n, 3) or not np.all(np.isfinite(points)):
            raise ValueError(f"points must be finite with shape ({n}, 3) (one point per wall) [m], got "
                             f"shape {np.shape(points)}")
        vel = np.zeros((n, 3)) if velocities is None else array("velocities", velocities, "[m/s]").copy()
        if vel.shape == (3,):
            vel = np.tile(vel, (n, 1))
        if n == 0 and vel.size == 0:
            vel = np.zeros((0, 3))
        if vel.shape != (n, 3) or not np.all(np.isfinite(vel)):
            raise ValueError(f"velocities must be finite with shape (3,) or ({n}, 3) [m/s], got shape "
                             f"{vel.shape}")
        if not isinstance(law, wall_kernels.Params):
            raise ValueError(f"law must be a pardem.physics.walls.Params, got {type(law).__name__}")
        real("time0", time0, unit="[s]")
        if motions is not None:
            if len(motions) != n:
                raise ValueError(f"motions must hold one entry per plane wall ({n}), got {len(motions)}")
            motions = [_plane_motion(m) for m in motions]
            for w, m in enumerate(motions):
                if m is not None and np.any(vel[w] != 0.0):
                    raise ValueError(f"velocities[{w}] = {vel[w].tolist()} [m/s]: a wall with a motion "
                                     "(motions[{w}]) takes its velocity from it; give 0")
            if all(m is None for m in motions):
                motions = None
        self.law = law
        self.normals = np.ascontiguousarray(normals)
        self.offsets0 = np.einsum("wd,wd->w", normals, points)
        self.velocities = np.ascontiguousarray(vel)
        self.time0 = float(time0)
        self.motions = motions
        self.cylinders = cylinders
        self.meshes = meshes
        self.shapes = bool(others)
        self._velocities_now = self.velocities if motions is None else self.velocities.copy()
        self.offsets = self.offsets0.copy()
        n_all = n + others
        self.wall_force = np.zeros((n_all, 3))    # this rank's share of the last step [N]
        self.force = np.zeros((n_all, 3))         # the global total, reduced by ``sim.run`` [N]
        n_tri = sum(m.n_triangles for m in meshes)
        self.triangle_force = np.zeros((n_tri, 3))   # this rank's force on each triangle [N]
        self._shifts = np.zeros((others, 3))
        self._time_now = self.time0
        # Simulation stores the compressive force of the first two planes here (Plates' interface)
        self.force_local = np.zeros(min(n, 2))

    @property
    def n_planes(self) -> int:
        return self.normals.shape[0]

    @property
    def n_walls(self) -> int:
        """Planes, cylinders and meshes: the rows of ``force`` and the history's columns."""
        return self.normals.shape[0] + len(self.cylinders) + len(self.meshes)

    def _servo_init(self):
        for w, m in enumerate(self.motions or ()):
            if isinstance(m, Servo) and m.offset_ref is None:
                m.offset_ref, m.time_ref = float(self.offsets0[w]), self.time0

    def offsets_at(self, time):
        """Plane offsets [n_walls] [m] at ``time`` [s] (``n . x = offset``)."""
        off = self.offsets0 + np.einsum("wd,wd->w", self.normals, self.velocities) * (time - self.time0)
        if self.motions is not None:
            self._servo_init()
            for w, m in enumerate(self.motions):
                if isinstance(m, Servo):
                    off[w] = m.offset_ref + m.speed * (time - m.time_ref)
                elif m is not None:
                    off[w] = self.offsets0[w] + float(self.normals[w] @ m.displacement(time - self.time0))
        return off

    def velocities_at(self, time):
        """Plane velocities [n_walls, 3] [m/s] at ``time`` [s]."""
        vel = self.velocities.copy()
        for w, m in enumerate(self.motions or ()):
            if isinstance(m, Servo):
                vel[w] = m.speed * self.normals[w]
            elif m is not None:
                vel[w] = m.velocity_at(time - self.time0)
        return vel

    def move_to(self, time):
        self.offsets[:] = self.offsets_at(time)
        self._time_now = float(time)
        for i, s in enumerate(self.cylinders + self.meshes):
            self._shifts[i] = s.motion.displacement(time - self.time0)

    def planes(self, time):
        """``(normals [n, 3], offsets [n], velocities [n, 3])`` for ``pardem.physics.walls``;
        the velocities at ``time`` [s] (the middle of the step)."""
        if self.motions is not None:
            self._velocities_now[:] = self.velocities_at(time)
        return self.normals, self.offsets, self._velocities_now

    def compute_shapes(self, elements, time, dt):
        """Add the loads of the cylinders and meshes to the owned rows of ``elements`` (after the
        planes: their rows of ``wall_force`` and columns of the history), their surfaces where
        ``move_to`` put them and moving at their velocities at ``time`` [s] (the middle of the
        step); returns the elastic energy [J]. ValueError (on this rank) for an element larger
        than a mesh's reach."""
        e, p = elements, self.law
        energy = 0.0
        col = self.n_planes
        tau = time - self.time0
        if self.cylinders:
            rows = np.array([c.row(self._shifts[i]) for i, c in enumerate(self.cylinders)])
            spins = np.array([c.angular_velocity for c in self.cylinders])
            vel = np.array([c.motion.velocity_at(tau) for c in self.cylinders])
            loop = curved_walls.cylinder_loop(p.law, p.damped, p.frictional)
            energy += loop(e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, e.n_owned, rows, spins, vel, col,
                           e.wall_h, float(dt), p.stiff_n, p.stiff_t, p.friction, p.damp_n, p.damp_t,
                           self.wall_force)
            col += len(self.cylinders)
        if self.meshes:
            loop = curved_walls.mesh_loop(p.law, p.damped, p.frictional)
            self.triangle_force[:] = 0.0
            tri0 = 0
            for i, m in enumerate(self.meshes):
                lo, h, dims, start, items = m.grid()
                # the turn where move_to put the surfaces (the end of the step), the spin steady
                rotating, centre, rot, spin = m.turn(self._time_now - self.time0)
                en, too_big = loop(e.x, e.v, e.w, e.radius, e.mass, e.f, e.t, e.n_owned, m.triangles, tri0,
                                   lo, h, dims, start, items, m.reach,
                                   self._shifts[len(self.cylinders) + i], m.motion.velocity_at(tau),
                                   rotating, centre, rot, spin, col, e.wall_h, float(dt), p.stiff_n, p.stiff_t, p.friction, p.damp_n,
                                   p.damp_t, self.wall_force, self.triangle_force)
                if too_big:
                    raise ValueError(f"{too_big} element(s) are larger than mesh {i}'s reach "
                                     f"{m.reach:.6g} m: give Mesh(reach=) at least the largest radius")
                energy += en
                tri0 += m.n_triangles
                col += 1
        return energy

    def positions(self):
        """A point on each wall now [n_walls, 3] [m] (the foot of the origin's normal)."""
        return self.normals * self.offsets[:, None]

    @property
    def normal_force(self):
        """Compressive normal force on each plane [n_planes] [N] (``-force . n``) from ``self.force``:
        global, as of the last reduction (module docstring); no collective."""
        return -np.einsum("wd,wd->w", self.force[:self.n_planes], self.normals)

    def forces(self, comm):
        """Total force of the elements on each wall [n_walls, 3] [N] at the last step (collective;
        a float sum, so decompositions agree to its round-off: module docstring)."""
        return np.asarray(comm.sum(self.wall_force)).reshape(-1, 3)

    def normal_forces(self, comm):
        """Compressive normal force on each plane [n_planes] [N] (``-F . n``; collective)."""
        return -np.einsum("wd,wd->w", self.forces(comm)[:self.n_planes], self.normals)

    def triangle_forces(self, comm):
        """Force of the elements on each triangle of the meshes [n_tri_total, 3] [N] (meshes in
        order; collective)."""
        return np.asarray(comm.sum(self.triangle_force)).reshape(-1, 3)

    def stiffness(self, radius):
        """Normal stiffness [N/m] used for the critical time step of elements of ``radius`` [m]
        (Hertz: the tangent stiffness at an overlap of ``WALL_OVERLAP_BOUND`` R)."""
        if self.law.law == "hertz":
            return max(wall_kernels.stiffness(self.law, radius, WALL_OVERLAP_BOUND * radius))
        return max(wall_kernels.stiffness(self.law, radius, 0.0))


class ServoOperation:
    """The operation that updates the servo walls' speeds every ``period`` steps from the global
    wall forces (reduced by the run on the steps an operation runs). Added by ``add_walls``."""

    def __init__(self, walls, period):
        self.walls = walls
        self.trigger = Periodic(int(period))

    def __call__(self, sim):
        w = self.walls
        if sim.plates is not w:
            return
        t = sim.time
        e = sim.elements
        due = [k for k, m in enumerate(w.motions or ())
               if isinstance(m, Servo) and sim.step_count % m.period == 0]
        if not due:
            return
        off = w.offsets_at(t)
        hertz = w.law.law == "hertz"
        terms = np.stack([wall_kernels.elastic_normal_terms(e.x, e.radius, e.n_owned, *w.normals[k],
                                                             float(off[k]), hertz, w.law.stiff_n)
                          for k in due], axis=1)
        fn = np.atleast_1d(exact_sum(sim.comm, terms))
        for i, k in enumerate(due):
            m = w.motions[k]
            m.offset_ref = float(off[k])
            m.time_ref = float(t)
            m.measured = float(fn[i])
            m.speed = float(np.clip(m.gain * (m.target - fn[i]), -m.max_speed, m.max_speed))


def attach_servos(sim, walls):
    """Add the servo update to ``sim.operations`` when ``walls`` has servo planes (build, restore)."""
    periods = [m.period for m in (walls.motions or ()) if isinstance(m, Servo)]
    if periods:
        walls._servo_init()
        sim.operations.append(ServoOperation(walls, math.gcd(*periods)))


@keywords("wall_law")
def wall_law(law="linear", stiffness=None, young=None, poisson=None, restitution=1.0, friction=0.0,
             wall_young=None, **extra):
    """``pardem.physics.walls.Params`` from keywords: linear law with ``stiffness`` [N/m], or Hertz
    with the elements' ``young`` [Pa] and ``poisson`` against a wall of ``wall_young`` [Pa] (None:
    ``math.inf``, rigid). ``extra``: the other keywords of ``walls.Params`` (``kt``, ``tangential_damping`` for the
    linear law, ``wall_poisson`` for Hertz). ValueError naming the argument for a bad value, an
    unknown keyword or one of the other law."""
    if not isinstance(law, str) or law not in ("linear", "hertz"):
        raise ValueError(f"law = {short(law)}: expected 'linear' or 'hertz' (or a pardem.physics.walls.Params)")
    own = {"linear": ("stiffness", "kt", "tangential_damping"),
           "hertz": ("young", "poisson", "wall_young", "wall_poisson")}
    names = ("law", "stiffness", "young", "poisson", "restitution", "friction", "wall_young",
             "kt", "wall_poisson", "tangential_damping")
    for key in extra:
        if key not in names:
            raise ValueError(f"wall_law() got an unexpected keyword {key!r}: valid names are {', '.join(names)}")
    given = {"stiffness": stiffness, "young": young, "poisson": poisson, "wall_young": wall_young, **extra}
    other = own["hertz" if law == "linear" else "linear"]
    for key in other:
        if given.get(key) is not None:
            raise ValueError(f"{key} = {short(given[key])} applies to law = "
                             f"{'hertz' if law == 'linear' else 'linear'!r} only, not to law = {law!r}")
    if law == "linear":
        try:
            real("stiffness", stiffness, lo=0.0, unit="[N/m]")
        except ValueError:
            raise ValueError(f"stiffness must be a positive number [N/m] for a linear wall law (in (0, inf)), "
                             f"got {short(stiffness)}") from None
        return wall_kernels.Params(law="linear", kn=stiffness, restitution=restitution, friction=friction,
                                   **extra)
    return wall_kernels.Params(law="hertz", young=young, poisson=poisson,
                               wall_young=math.inf if wall_young is None else wall_young,
                               restitution=restitution, friction=friction, **extra)


def add_walls(sim, normals=None, points=None, velocities=None, law="linear", check_dt=True, motions=None,
              cylinders=(), meshes=(), **law_keywords):
    """Add a set of walls to ``sim`` (every rank, same arguments) and return it (``Walls``).

    normals [n, 3] (inward), points [n, 3] [m], velocities [3] or [n, 3] [m/s] (default static) of
    the planes; motions : one per plane (None, a ``pardem.physics.wall_motion`` motion or a
    ``Servo``); cylinders : ``Cylinder`` list; meshes : ``Mesh`` list (a mesh without ``reach``
    gets 1.5 times the largest radius of ``sim``); law : a ``pardem.physics.walls.Params``, or
    ``"linear"`` / ``"hertz"`` with the keywords of ``wall_law`` (``stiffness=``, ``young=``,
    ``poisson=``, ``restitution=``, ``friction=``).
    ``check_dt``: raise ValueError when ``sim.dt`` is above the critical time step with the walls
    (and when a servo's gain is above its stability bound, ``Servo``).
    ValueError if ``sim`` already has walls or plates (one wall set per Simulation).
    """
    if sim.plates is not None:
        raise ValueError("this Simulation already has walls (sim.plates): put every wall in one "
                         "add_walls call (one wall set, one law)")
    params = law if isinstance(law, wall_kernels.Params) else wall_law(law, **law_keywords)
    if isinstance(law, wall_kernels.Params) and law_keywords:
        raise ValueError(f"law is already a walls.Params: the keywords {sorted(law_keywords)} are not used")
    w = Walls(normals, points, params, velocities, time0=sim.step_count * sim.dt, motions=motions,
              cylinders=cylinders, meshes=meshes)
    if any(m.reach is None for m in w.meshes):
        r_max = _max_radius(sim)
        for m in w.meshes:
            if m.reach is None:
                m.reach = MESH_REACH * r_max
    check_domain(sim, w)
    if check_dt:
        dt_c = critical_time_step_of(sim, walls=w)
        if not sim.dt <= dt_c:
            raise ValueError(f"sim.dt = {sim.dt:.6g} s is above the critical time step {dt_c:.6g} s with "
                             f"these walls (stiffness {w.stiffness(_max_radius(sim)):.4g} N/m): lower the "
                             f"wall stiffness or the time step (sim.set_dt) to at most {dt_c:.6g} s")
        check_servos(sim, w)
    e = sim.elements
    e.wall_h = wall_kernels.new_history(params, e.n_total, w.n_walls)
    w.move_to(sim.step_count * sim.dt)
    sim.plates = w
    attach_servos(sim, w)
    return w


def check_servos(sim, walls):
    """ValueError naming the wall when a servo's gain is above the stability bound of one contact
    of the wall's stiffness at ``sim.dt`` (``Servo``)."""
    k = walls.stiffness(_max_radius(sim))
    for i, m in enumerate(walls.motions or ()):
        if isinstance(m, Servo) and not m.gain < m.gain_bound(k, sim.dt):
            raise ValueError(f"motions[{i}]: Servo.gain = {m.gain:.6g} m/(N s) is above the stability "
                             f"bound 2 / (k period dt) = {m.gain_bound(k, sim.dt):.6g} m/(N s) of one "
                             f"contact (k = {k:.4g} N/m, period {m.period}, dt = {sim.dt:.4g} s): expected "
                             f"a gain in (0, {m.gain_bound(k, sim.dt):.6g}), at most half of it for no "
                             "overshoot")


def check_domain(sim, walls):
    """ValueError (naming the wall) unless every wall of ``walls`` fits ``sim``'s domain: no normal
    component along a periodic axis of ``sim.cell``; in the 2D mode, normals and velocities with no
    z component (a wall is a line of the plane z = 0)."""
    from pardem.engine.plane import dimension_of
    n, v = walls.normals, walls.velocities
    if dimension_of(sim) == 2:
        for name, arr, unit in (("normals", n, ""), ("velocities", v, " [m/s]")):
            bad = np.nonzero(arr[:, 2] != 0.0)[0]
            if len(bad):
                k = int(bad[0])
                raise ValueError(f"{name}[{k}] = {arr[k].tolist()}{unit}: in 2D a wall is a line of the "
                                 "plane z = 0, its z component must be 0")
    if dimension_of(sim) == 2:
        moving = [(f"motions[{i}]", m) for i, m in enumerate(walls.motions or ()) if m is not None]
        moving += [(f"cylinders[{i}].motion", c.motion) for i, c in enumerate(walls.cylinders)]
        for name, m in moving:
            if _moves_along_z(m):
                raise ValueError(f"{name}: in 2D a wall moves in the plane z = 0, its motion must have no "
                                 "z component")
    if walls.meshes and dimension_of(sim) == 2:
        raise ValueError("meshes: mesh walls are 3D only (in 2D a wall is a line of the plane z = 0: "
                         "use planes or a cylinder along z)")
    for i, c in enumerate(walls.cylinders):
        if dimension_of(sim) == 2 and abs(c.axis[2]) != 1.0:
            raise ValueError(f"cylinders[{i}].axis = {c.axis.tolist()}: in 2D a cylinder is a circle of the "
                             "plane z = 0, its axis must be z")
    cell = getattr(sim, "cell", None)
    if cell is not None and np.any(cell.periodic) and walls.meshes:
        raise ValueError("meshes: a mesh wall cannot be used in a cell with periodic axes (elements "
                         "would wrap through it)")
    if cell is not None and np.any(cell.periodic):
        for i, c in enumerate(walls.cylinders):
            off_axis = np.abs(c.axis[cell.periodic]) != 1.0
            if np.any(off_axis) or np.count_nonzero(cell.periodic) > 1:
                raise ValueError(f"cylinders[{i}].axis = {c.axis.tolist()}: in a periodic cell a cylinder's "
                                 "axis must be the one periodic axis")
    if cell is not None and np.any(cell.periodic):
        bad = np.nonzero(np.any(n[:, cell.periodic] != 0.0, axis=1))[0]
        if len(bad):
            k = int(bad[0])
            axes = "".join("xyz"[a] for a in range(3) if cell.periodic[a])
            raise ValueError(f"normals[{k}] = {n[k].tolist()}: a wall normal must have no component "
                             f"along the cell's periodic axes ({axes}): elements would wrap through it")


def _moves_along_z(m):
    """Whether a plane's or a cylinder's motion has a z component (a servo moves along its normal)."""
    if isinstance(m, Servo):
        return False
    if isinstance(m, wall_motion.Table):
        return bool(np.any(m.displacements[:, 2] != 0.0))
    vec = m.amplitude if isinstance(m, wall_motion.Sinusoid) else m.velocity
    return bool(vec[2] != 0.0)


def _max_radius(sim):
    e = sim.elements
    return float(sim.comm.max(float(e.radius[:e.n_owned].max()) if e.n_owned else 0.0))


__all__ = ["Walls", "Cylinder", "Mesh", "Servo", "add_walls", "wall_law", "check_domain", "check_servos",
           "attach_servos"]
