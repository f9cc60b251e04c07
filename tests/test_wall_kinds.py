"""Prescribed wall motions, the force servo, cylinders and triangle meshes (pardem.engine.walls,
pardem.physics.wall_motion, pardem.physics.curved_walls, pardem.io.stl) against analytic cases,
an independent brute-force computation, restarts and rank counts."""
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import pardem
from pardem.engine.walls import Cylinder, Mesh, Servo
from pardem.physics import wall_motion

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
G = 9.81
R, RHO = 0.01, 2500.0
MASS = RHO * 4.0 / 3.0 * math.pi * R**3


@pytest.fixture(scope="module")
def comm():
    return pardem.Communicator()


def one_sphere(comm, x, walls, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0), dt_fraction=0.1, gravity=True):
    sim = pardem.build(comm, pardem.System(pardem.Particles([x], R, RHO, velocities=[v],
                                                            angular_velocities=[w]),
                                           walls=walls, integration=pardem.Integration(dt_fraction=dt_fraction)))
    if gravity:
        pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -G)))
    return sim


def state(sim, name):
    return sim.particles.get(name, [0])[0]


# -- prescribed motions ------------------------------------------------------------------------

MOTIONS = [wall_motion.Constant((0.1, -0.2, 0.3)),
           wall_motion.Ramp((0.2, 0.0, -0.1), 0.3),
           wall_motion.Sinusoid((1e-3, 0.0, 2e-3), 5.0, 0.4),
           wall_motion.Table([0.0, 0.1, 0.25, 0.4], [[0, 0, 0], [1e-3, 0, 0], [1e-3, -2e-3, 0], [0, 0, 5e-4]])]


@pytest.mark.parametrize("motion", MOTIONS, ids=lambda m: m.kind)
def test_motion_displacement_is_the_integral_of_its_velocity(motion):
    # an independent check of each pair of formulas: the composite midpoint rule over 20000
    # intervals of [0, 0.5] s; its error is h^2 T max|v''| / 24 (~1e-11 m for the sinusoid), and
    # exact for the piecewise-constant and linear velocities except the kinks, where each interval
    # straddling one costs at most h |jump in v| (1e-9 m)
    t = np.linspace(0.0, 0.5, 20001)
    h = t[1] - t[0]
    vel = np.array([motion.velocity_at(s) for s in 0.5 * (t[1:] + t[:-1])])
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum(vel, axis=0) * h])
    disp = np.array([motion.displacement(s) for s in t])
    assert np.allclose(disp, integral, rtol=0.0, atol=5e-9)


def test_motion_formulas_at_their_known_points():
    ramp = wall_motion.Ramp((2.0, 0.0, 0.0), 0.5)
    assert ramp.displacement(0.5)[0] == pytest.approx(0.5)           # V T / 2
    assert ramp.displacement(1.0)[0] == pytest.approx(1.5)           # V (t - T / 2)
    assert ramp.velocity_at(0.25)[0] == pytest.approx(1.0)
    sine = wall_motion.Sinusoid((0.0, 0.0, 3e-3), 2.0)
    assert sine.displacement(0.125)[2] == pytest.approx(3e-3)        # a quarter period: A
    assert sine.velocity_at(0.0)[2] == pytest.approx(3e-3 * 4.0 * math.pi)
    table = wall_motion.Table([0.0, 1.0, 3.0], [[0, 0, 0], [1.0, 0, 0], [0, 2.0, 0]])
    assert np.allclose(table.displacement(2.0), [0.5, 1.0, 0.0])
    assert np.allclose(table.displacement(10.0), [0.0, 2.0, 0.0])    # held after the last point
    assert np.allclose(table.velocity_at(10.0), 0.0)


def test_plane_walls_follow_their_motions_in_a_run(comm):
    f, amp, v0, T = 4.0, 2e-3, 0.3, 0.05
    walls = pardem.WallModel(
        normals=[[0, 0, 1], [1, 0, 0], [0, -1, 0]], points=[[0, 0, -0.1], [-0.1, 0, 0], [0, 0.1, 0]],
        law=pardem.wall_law("linear", stiffness=1e4),
        motions=[pardem.Sinusoid((0, 0, amp), f), pardem.Ramp((v0, 0, 0), T),
                 pardem.MotionTable([0.0, 0.02, 0.06], [[0, 0, 0], [0, -1e-3, 0], [0, -1e-3, 0]])])
    sim = one_sphere(comm, (0, 0, 0), walls, gravity=False)
    w = sim.plates
    for _ in range(3):
        sim.run(250)
        t = sim.time
        # offsets n . x of each plane at the end of the step, by the formulas written out here
        ramp = v0 * (0.5 * t * t / T if t < T else t - 0.5 * T)
        table = -1e-3 * min(t / 0.02, 1.0)
        want = [-0.1 + amp * math.sin(2 * math.pi * f * t), -0.1 + ramp, -(0.1 + table)]
        assert np.allclose(w.offsets, want, rtol=0, atol=1e-15)
        # and the kernel's velocities at the middle of the next step
        tm = t + 0.5 * sim.dt
        vel = w.planes(tm)[2]
        assert vel[0, 2] == pytest.approx(amp * 2 * math.pi * f * math.cos(2 * math.pi * f * tm), rel=1e-12)
        assert vel[1, 0] == pytest.approx(v0 * min(tm / T, 1.0), rel=1e-12)


def test_a_sphere_rides_a_shaking_floor(comm):
    # floor z = A sin(omega t) with A omega^2 = 0.5 g: the sphere never leaves it and sits at the
    # floor's height plus R minus the spring's compression m (g + a_floor) / k (quasi-static:
    # omega^2 / omega_contact^2 ~ 1e-5 of it), after the impact transient has been damped
    k, amp, f = 1e5, 5e-4, 0.5 / (2 * math.pi) * math.sqrt(0.5 * G / 5e-4)
    floor = pardem.WallModel([[0, 0, 1]], [[0, 0, 0]], pardem.wall_law("linear", stiffness=k, restitution=0.3),
                             motions=[pardem.Sinusoid((0, 0, amp), f)])
    sim = one_sphere(comm, (0, 0, R - MASS * G / k), floor)
    sim.run(int(0.2 / sim.dt))
    omega = 2 * math.pi * f
    worst = 0.0
    for _ in range(200):
        sim.run(5)
        t = sim.time
        a_floor = -amp * omega**2 * math.sin(omega * t)
        want = amp * math.sin(omega * t) + R - MASS * (G + a_floor) / k
        worst = max(worst, abs(state(sim, "positions")[2] - want))
    # the residual: the contact oscillation excited by the floor's jerk, about
    # m |jerk| / k omega_c ... bounded here by 2 % of the static compression m g / k
    assert worst < 0.02 * MASS * G / k


# -- servo ----------------------------------------------------------------------------------

def servo_sphere(comm, target, gain, period=1, law=None):
    law = law or pardem.wall_law("linear", stiffness=1e5, restitution=0.5)
    walls = pardem.WallModel([[0, 0, 1], [0, 0, -1]], [[0, 0, 0], [0, 0, 2 * R + 1e-3]], law,
                             motions=[None, Servo(gain=gain, force=target, max_speed=0.05, period=period)])
    return one_sphere(comm, (0, 0, R), walls, gravity=False)


def test_servo_brings_the_lid_to_its_target_force(comm):
    target, k = 2.0, 1e5
    # the lid sees the floor and the lid contacts in series: k_w = k / 2; a gain of half the
    # no-overshoot bound 1 / (k_w period dt)
    sim = servo_sphere(comm, target, gain=1e-9, period=4)       # for its time step
    gain = 0.5 / (0.5 * k * 4 * sim.dt)
    sim = servo_sphere(comm, target, gain=gain, period=4)
    sim.run(int(0.3 / sim.dt) // 4 * 4)
    lid = sim.plates.motions[1]
    # at rest the elastic force on the lid is the target, and so the floor's reaction: the error
    # left after n updates is (1 - gain k_w period dt)^n of the initial one (n ~ 400 here, nothing
    # left) plus the step-to-step wobble of the damped sphere (below 1e-9 N measured)
    assert lid.measured == pytest.approx(target, rel=1e-6)
    assert sim.plates.normal_force[0] == pytest.approx(target, rel=1e-6)
    # the overlaps: two springs at the target force each
    z_lid = -sim.plates.offsets[1]
    assert z_lid - 2 * R == pytest.approx(-2 * target / k, rel=1e-5)


def test_servo_gain_above_its_stability_bound_is_refused(comm):
    sim = servo_sphere(comm, 1.0, gain=1e-6)
    bound = 2.0 / (1e5 * 1 * sim.dt)
    with pytest.raises(ValueError, match="Servo.gain"):
        servo_sphere(comm, 1.0, gain=1.01 * bound)
    servo_sphere(comm, 1.0, gain=0.99 * bound)


# -- meshes -----------------------------------------------------------------------------------

def tilted_square(theta, half=0.1):
    """Two triangles of a square of side 2 half in the plane through 0 of normal
    (-sin theta, 0, cos theta); its diagonal, the shared edge, passes through 0."""
    t1 = np.array([math.cos(theta), 0.0, math.sin(theta)])
    t2 = np.array([0.0, 1.0, 0.0])
    c = [-half * t1 - half * t2, half * t1 - half * t2, half * t1 + half * t2, -half * t1 + half * t2]
    n = np.array([-math.sin(theta), 0.0, math.cos(theta)])
    return np.array([[c[0], c[1], c[2]], [c[0], c[2], c[3]]]), n, t1


def mesh_sphere(comm, theta, friction, clamp_spin, k=1e5):
    tris, n, t1 = tilted_square(theta)
    law = pardem.wall_law("linear", stiffness=k, restitution=0.3, friction=friction)
    walls = pardem.WallModel(np.zeros((0, 3)), np.zeros((0, 3)), law, meshes=[Mesh(tris)])
    delta = MASS * G * math.cos(theta) / k
    # on the shared edge of the two triangles, at the equilibrium overlap
    sim = one_sphere(comm, tuple(n * (R - delta)), walls)
    if clamp_spin:
        pardem.add_fixes(sim, pardem.Clamp([0], dofs="", rotations="xyz"))
    return sim, n, t1


THETA = math.radians(20.0)


def test_sphere_resting_on_a_tilted_mesh_plane(comm):
    # friction 0.6 > tan 20 deg = 0.364 and no rolling: the sphere stays; the force on the mesh is
    # the weight, straight down; the overlap that of ONE contact, m g cos(theta) / k, although the
    # sphere sits on the edge shared by the two triangles
    k = 1e5
    sim, n, _ = mesh_sphere(comm, THETA, 0.6, clamp_spin=True, k=k)
    sim.run(int(0.1 / sim.dt))
    force = sim.plates.force[0]
    # static equilibrium reached: the transient decays as exp(-zeta omega t), zeta = 0.36 at
    # e = 0.3, omega = 3e3 /s, t = 0.1 s: nothing left; round-off of the force sums ~1e-16 relative
    assert np.allclose(force, [0.0, 0.0, -MASS * G], rtol=0, atol=1e-9 * MASS * G)
    gap = float(n @ state(sim, "positions"))
    assert R - gap == pytest.approx(MASS * G * math.cos(THETA) / k, rel=1e-6)
    # the force is carried by the triangle holding the contact point: the two add up to it
    assert np.allclose(sim.plates.triangle_forces(comm).sum(axis=0), force, rtol=0, atol=1e-12)


def test_sphere_slides_down_a_mesh_plane_steeper_than_its_friction_angle(comm):
    mu = 0.2
    sim, n, t1 = mesh_sphere(comm, THETA, mu, clamp_spin=True)
    sim.run(int(0.02 / sim.dt))
    v1, t_1 = float(state(sim, "velocities") @ t1), sim.time
    sim.run(int(0.05 / sim.dt))
    v2, t_2 = float(state(sim, "velocities") @ t1), sim.time
    # Coulomb sliding: a = -g (sin theta - mu cos theta) along t1 (downhill is -t1); the normal
    # transient is over after 0.02 s (see above): the acceleration is exact to ~1e-6
    a = (v2 - v1) / (t_2 - t_1)
    assert a == pytest.approx(-G * (math.sin(THETA) - mu * math.cos(THETA)), rel=1e-4)


def test_sphere_rolls_down_a_mesh_plane_at_five_sevenths_of_g_sin_theta(comm):
    # rolling without slip needs mu >= 2/7 tan(theta) = 0.10: with 0.6 it rolls, a = 5/7 g sin(theta)
    # (solid sphere, I = 2/5 m R^2); the tangential spring's oscillation (damped by its dashpot)
    # is over after 0.02 s
    sim, n, t1 = mesh_sphere(comm, THETA, 0.6, clamp_spin=False)
    sim.run(int(0.02 / sim.dt))
    v1, t_1 = float(state(sim, "velocities") @ t1), sim.time
    sim.run(int(0.05 / sim.dt))
    v2, t_2 = float(state(sim, "velocities") @ t1), sim.time
    assert (v2 - v1) / (t_2 - t_1) == pytest.approx(-5.0 / 7.0 * G * math.sin(THETA), rel=1e-3)


def _segment_distance(p, a, b):
    ab = b - a
    s = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[..., None] * ab), axis=-1)


def brute_distance(p, tri):
    """Distance from points p [n, 3] to a triangle by a method of its own: the projection on the
    plane when its barycentric coordinates are all >= 0, else the nearest of the three edges."""
    a, b, c = tri
    nrm = np.cross(b - a, c - a)
    nrm /= np.linalg.norm(nrm)
    h = (p - a) @ nrm
    q = p - h[:, None] * nrm
    # barycentric coordinates of q by areas
    area = np.cross(b - a, c - a) @ nrm
    l0 = np.cross(c - b, q - b) @ nrm / area
    l1 = np.cross(a - c, q - c) @ nrm / area
    l2 = 1.0 - l0 - l1
    inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
    edges = np.min([_segment_distance(p, a, b), _segment_distance(p, b, c), _segment_distance(p, c, a)], axis=0)
    return np.where(inside, np.abs(h), edges)


def test_mesh_contacts_match_a_brute_force_search(comm):
    # a random soup of triangles and spheres: the grid-filtered kernel's force on each sphere (one
    # contact, nearest point, frictionless undamped linear law F = k (R - d) n) against the
    # nearest triangle over ALL triangles found by the independent distance above
    rng = np.random.default_rng(7)
    n_tri, n_sph = 60, 400
    centres = rng.uniform(0.0, 1.0, (n_tri, 1, 3))
    tris = centres + rng.uniform(-0.15, 0.15, (n_tri, 3, 3))
    x = rng.uniform(-0.1, 1.1, (n_sph, 3))
    radii = rng.uniform(0.03, 0.09, n_sph)
    k = 1e3
    law = pardem.wall_law("linear", stiffness=k)
    walls = pardem.WallModel(np.zeros((0, 3)), np.zeros((0, 3)), law, meshes=[Mesh(tris)])
    sim = pardem.build(comm, pardem.System(pardem.Particles(x, radii, 1000.0, allow_overlaps=True), walls=walls,
                                           integration=pardem.Integration(dt=1e-6)))
    sim.run(0)
    got = sim.particles.forces
    dist = np.stack([brute_distance(x, t) for t in tris], axis=1)       # [n_sph, n_tri]
    nearest = np.argmin(dist, axis=1)
    d = dist[np.arange(n_sph), nearest]
    touching = d < radii
    assert 30 < touching.sum() < n_sph                      # faces, edges and vertices all occur
    want = np.zeros((n_sph, 3))
    for i in np.nonzero(touching)[0]:
        # the contact direction: from the nearest point; the brute force gives its distance,
        # the direction is checked through the force's magnitude and its alignment below
        want[i] = k * (radii[i] - d[i])
    mag = np.linalg.norm(got, axis=1)
    # magnitudes to round-off of d (two algorithms: ~1e-15 m relative to the 1 m box)
    assert np.allclose(mag, want[:, 0], rtol=0, atol=k * 1e-12)
    # direction: the force points from the nearest point to the centre, so the sphere moved
    # along it by a little (1e-6) ends farther from every triangle that it touches
    moved = x + 1e-6 * got / np.where(mag > 0, mag, 1.0)[:, None]
    d_after = np.min(np.stack([brute_distance(moved, t) for t in tris], axis=1), axis=1)
    assert np.all(d_after[touching] > d[touching] + 0.9e-6)
    # every force lands on the triangle that holds the nearest point
    tri_force = sim.plates.triangle_forces(comm)
    want_tri = np.zeros((n_tri, 3))
    np.add.at(want_tri, nearest[touching], -got[touching])
    assert np.allclose(tri_force, want_tri, rtol=0, atol=1e-12)


def square(half=0.1):
    """Two triangles of the square [-half, half]^2 in the plane z = 0."""
    c = np.array([[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]])
    return np.array([[c[0], c[1], c[2]], [c[0], c[2], c[3]]])


def clamped_on_mesh(comm, mesh, x, law):
    walls = pardem.WallModel(np.zeros((0, 3)), np.zeros((0, 3)), law, meshes=[mesh])
    sim = one_sphere(comm, x, walls, gravity=False)
    pardem.add_fixes(sim, pardem.Clamp([0]))     # the sphere stays: the wall force is the law's
    return sim


def test_a_turning_mesh_presents_its_rotated_plane(comm):
    # the square turns about the x axis at Omega: its normal is (0, -sin phi, cos phi), phi = Omega t;
    # a clamped sphere at (x, y0, h) is n . p = h cos phi - y0 sin phi from its plane and feels the
    # frictionless undamped force k (R - n . p) n (the force on the mesh is minus that), to round-off
    k, omega, y0, h = 1e5, 1.0, 0.01, R - 1e-4
    mesh = Mesh(square(), rotation=((0, 0, 0), (1, 0, 0), omega))
    sim = clamped_on_mesh(comm, mesh, (0.03, y0, h), pardem.wall_law("linear", stiffness=k))
    for _ in range(3):
        sim.run(int(0.05 / sim.dt))
        phi = omega * sim.time
        n = np.array([0.0, -math.sin(phi), math.cos(phi)])
        gap = h * math.cos(phi) - y0 * math.sin(phi)
        assert np.allclose(sim.plates.force[0], -k * (R - gap) * n, rtol=0, atol=1e-9)


def test_a_turntable_mesh_drags_a_sphere_at_its_surface_speed(comm):
    # the square turns about z at Omega under a clamped sphere at (r0, 0): its surface slides under
    # the sphere at Omega r0 along +y, so the tangential spring grows by kt Omega r0 dt a step
    # (undamped law, below the Coulomb cap): the force on the mesh after t is -kt Omega r0 t along
    # y, within one step's increment (the forces of step 0 add one update)
    k, omega, r0, delta = 1e5, 2.0, 0.05, 1e-3
    mesh = Mesh(square(), rotation=((0, 0, 0), (0, 0, 1), omega))
    sim = clamped_on_mesh(comm, mesh, (r0, 0.0, R - delta), pardem.wall_law("linear", stiffness=k, friction=1.0))
    sim.run(int(0.005 / sim.dt))         # the spring reaches 50 N, half the cap mu k delta
    step = k * omega * r0 * sim.dt
    assert abs(sim.plates.force[0, 1] - (-k * omega * r0 * sim.time)) <= 1.01 * step
    assert sim.plates.force[0, 2] == pytest.approx(-k * delta, rel=1e-12)


# -- cylinders --------------------------------------------------------------------------------

def cylinder_sphere(comm, friction, theta0, rc=0.1, k=1e6, spin=0.0, w0=(0.0, 0.0, 0.0)):
    law = pardem.wall_law("linear", stiffness=k, restitution=0.5, friction=friction)
    walls = pardem.WallModel(np.zeros((0, 3)), np.zeros((0, 3)), law,
                             cylinders=[Cylinder((0, 0, 0), (0, 1, 0), rc, inside=True, angular_velocity=spin)])
    rho = rc - R + MASS * G / k        # at the equilibrium overlap
    x = (rho * math.sin(theta0), 0.0, -rho * math.cos(theta0))
    return one_sphere(comm, x, walls, w=w0, dt_fraction=0.2)


def oscillation_period(sim, periods):
    """The mean period of x(t) from its upward zero crossings (linear interpolation) [s]."""
    crossings = []
    x_prev, t_prev = state(sim, "positions")[0], sim.time
    while len(crossings) < periods + 1:
        sim.run(10)
        x, t = state(sim, "positions")[0], sim.time
        if x_prev < 0.0 <= x:
            crossings.append(t_prev + (t - t_prev) * (-x_prev) / (x - x_prev))
        x_prev, t_prev = x, t
    return (crossings[-1] - crossings[0]) / periods


@pytest.mark.parametrize("friction, factor", [(1.0, 7.0 / 5.0), (0.0, 1.0)], ids=["rolling", "sliding"])
def test_sphere_oscillates_in_a_cylinder_with_the_rolling_period(comm, friction, factor):
    # small oscillations at the bottom of a cylinder of radius Rc: T = 2 pi sqrt(factor (Rc - R) / g),
    # factor 7/5 when the sphere rolls without slipping (I = 2/5 m R^2), 1 when it slides freely.
    # Tolerance 0.3 %: finite amplitude theta0 = 0.1 adds theta0^2 / 16 = 0.06 %, the crossing
    # interpolation over 10 steps ~1e-4, the overlap m g / k changes Rc - R by 1e-6 relative
    rc, theta0 = 0.1, 0.1
    sim = cylinder_sphere(comm, friction, theta0, rc=rc)
    T = oscillation_period(sim, 2)
    assert T == pytest.approx(2 * math.pi * math.sqrt(factor * (rc - R) / G), rel=3e-3)


def test_a_sphere_spinning_with_a_rotating_drum_stays_at_its_bottom(comm):
    # the drum (axis y) turns at Omega: its surface at the bottom moves at -Omega rho_c x; a sphere
    # at the bottom spinning at w_y = Omega rho_c / l (rho_c the contact point's distance from the
    # axis, l its arm) has no slip, so no friction force: it stays, spinning, to round-off. A wrong
    # surface velocity (sign, radius) makes friction act at once and the sphere climb
    omega, rc, k = 2.0, 0.1, 1e6
    delta = MASS * G / k
    arm = R - 0.5 * delta
    w_y = omega * (rc + 0.5 * delta) / arm     # the contact point: mid-overlap, rc + delta / 2
    sim = cylinder_sphere(comm, 0.5, 0.0, rc=rc, k=k, spin=omega, w0=(0.0, w_y, 0.0))
    sim.run(int(0.05 / sim.dt))
    x = state(sim, "positions")
    assert abs(x[0]) < 1e-9 * rc
    assert state(sim, "angular_velocities")[1] == pytest.approx(w_y, rel=1e-9)
    # the drum drags a sphere at rest the same way (sign): it spins up positive about y
    sim = cylinder_sphere(comm, 0.5, 0.0, rc=rc, k=k, spin=omega)
    sim.run(int(0.01 / sim.dt))
    assert state(sim, "angular_velocities")[1] > 0.1 * w_y


# -- descriptions, files, bad input -----------------------------------------------------------

def test_descriptions_round_trip_through_json_and_old_ones_keep_their_keys(comm):
    law = pardem.wall_law("hertz", young=1e7, poisson=0.3, friction=0.3)
    old = pardem.System(pardem.Particles([[0, 0, R]], R, RHO),
                        walls=pardem.WallModel([[0, 0, 1]], [[0, 0, 0]], law)).to_dict()
    assert set(old["walls"]) == {"normals", "points", "velocities", "time0", "offsets", "law"}
    tris, _, _ = tilted_square(0.3)
    model = pardem.WallModel([[0, 0, 1], [0, 0, -1]], [[0, 0, 0], [0, 0, 0.1]], law,
                             motions=[pardem.Sinusoid((0, 0, 1e-3), 3.0), Servo(1e-3, stress=1e3, area=0.01)],
                             cylinders=[Cylinder((0, 0, 0), (1, 1, 0), 0.5, extent=(-0.1, 0.2), angular_velocity=1.0)],
                             meshes=[Mesh(tris, motion=pardem.Ramp((0.1, 0, 0), 1.0), reach=0.02,
                                          rotation=((0, 0, 0.01), (0, 1, 1), 0.5))])
    sim = pardem.build(comm, pardem.System(pardem.Particles([[0, 0, 0.05]], R, RHO), walls=model))
    sim.run(3)
    d = pardem.describe(sim).to_dict()
    back = pardem.System.from_dict(json.loads(json.dumps(d))).to_dict()
    assert back == d
    assert [m["kind"] for m in d["walls"]["motions"]] == ["sinusoid", "servo"]
    assert d["walls"]["motions"][1]["time_ref"] is not None


def test_stl_files_round_trip(tmp_path):
    tris, _, _ = tilted_square(0.2)
    path = str(tmp_path / "square.stl")
    pardem.write_stl(path, tris)
    # STL stores float32
    assert np.array_equal(pardem.read_stl(path), tris.astype(np.float32).astype(np.float64))
    assert np.allclose(pardem.read_stl(path, scale=1e-3), 1e-3 * tris, rtol=1e-6)
    with pytest.raises(ValueError, match="does not exist"):
        pardem.read_stl(str(tmp_path / "missing.stl"))
    (tmp_path / "bad.stl").write_bytes(b"solid x\nnot a facet\n")
    with pytest.raises(ValueError, match="bad.stl"):
        pardem.read_stl(str(tmp_path / "bad.stl"))


@pytest.mark.parametrize("make, message", [
    (lambda: Cylinder((0, 0, 0), (0, 0, 1), -1.0), "Cylinder.radius"),
    (lambda: Cylinder((0, 0, 0), (0, 0, 0), 1.0), "Cylinder.axis"),
    (lambda: Cylinder((0, 0, 0), (0, 0, 1), 1.0, extent=(1.0, 0.0)), "Cylinder.extent"),
    (lambda: Mesh(np.zeros((1, 3, 3))), "degenerate"),
    (lambda: Mesh(np.zeros((2, 3))), "Mesh.triangles"),
    (lambda: Servo(gain=1.0), "either force"),
    (lambda: Servo(gain=-1.0, force=1.0), "Servo.gain"),
    (lambda: Servo(gain=1.0, force=1.0, period=0), "Servo.period"),
    (lambda: wall_motion.Table([0.0, 0.0], [[0, 0, 0], [1, 0, 0]]), "times"),
    (lambda: wall_motion.Sinusoid((0, 0, 1), -1.0), "frequency"),
    (lambda: wall_motion.motion_from_dict({"kind": "spiral"}), "constant, ramp"),
    (lambda: pardem.engine.walls.Walls([[0, 0, 1]], [[0, 0, 0]], pardem.wall_law("linear", stiffness=1.0),
                                       velocities=[[0, 0, 1]], motions=[pardem.Ramp((0, 0, 1), 1.0)]),
     "takes its velocity"),
    (lambda: pardem.engine.walls.Walls([[0, 0, 1]], [[0, 0, 0]], pardem.wall_law("linear", stiffness=1.0),
                                       motions=[None, None]), "one entry per plane"),
])
def test_bad_wall_input_is_one_clear_value_error(make, message):
    import pardem.engine.walls  # noqa: F401
    with pytest.raises(ValueError, match=message):
        make()


def test_a_grain_larger_than_the_mesh_reach_is_refused(comm):
    tris, n, _ = tilted_square(0.0)
    walls = pardem.WallModel(np.zeros((0, 3)), np.zeros((0, 3)), pardem.wall_law("linear", stiffness=1e5),
                             meshes=[Mesh(tris, reach=0.5 * R)])
    sim = one_sphere(comm, (0, 0, 2 * R), walls)
    with pytest.raises(ValueError, match="reach"):
        sim.run(1)


# -- restarts and rank counts ------------------------------------------------------------------

def _run(out, mode, ranks):
    cmd = [sys.executable, os.path.join(ROOT, "tests", "mpi", "wall_kinds_run.py"), str(out), mode]
    if ranks > 1:
        cmd = [MPIEXEC, "-n", str(ranks)] + cmd
    env = {**os.environ, "PYTHONPATH": ROOT}
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=900, cwd=ROOT, env=env)
    assert res.returncode == 0, res.stderr
    return dict(np.load(os.path.join(out, f"{mode}.npz")))


TRAJECTORY = ("x", "v", "w", "hist", "lid", "offsets")


@pytest.fixture(scope="module")
def kinds_one_rank(tmp_path_factory):
    out = tmp_path_factory.mktemp("kinds1")
    return out, _run(out, "full", 1)


def test_every_wall_kind_restarts_bit_for_bit(kinds_one_rank):
    out, full = kinds_one_rank
    # each kind is in contact at the end (else the test would prove little): floor, lid (servo),
    # cylinder, mesh columns of the history
    touching = np.count_nonzero(np.any(full["hist"].reshape(len(full["x"]), -1, 3) != 0, axis=2), axis=0)
    assert touching[0] > 0 and touching[1] > 0 and touching[3] > 0 and touching[4] > 0
    assert full["lid"][3] > 0.0          # the servo measured a force
    again = _run(out, "restart", 1)
    for key in TRAJECTORY + ("force", "tri"):
        assert np.array_equal(full[key], again[key]), key


@pytest.mark.mpi
@pytest.mark.skipif(MPIEXEC is None, reason="no mpiexec")
def test_every_wall_kind_gives_the_same_bits_on_two_ranks(kinds_one_rank, tmp_path):
    _, one = kinds_one_rank
    two = _run(tmp_path, "full", 2)
    for key in TRAJECTORY:
        assert np.array_equal(one[key], two[key]), key
    # the wall forces are float sums over rows then ranks: equal to their round-off
    scale = np.abs(one["force"]).max()
    assert np.allclose(one["force"], two["force"], rtol=0, atol=1e-12 * scale)


def test_two_d_walls_refuse_motions_out_of_the_plane(comm):
    # in 2D a wall is a line of the plane z = 0: a motion along z would drag the disks out of it
    def system(motion, cylinders=None):
        walls = pardem.WallModel([[0, 1, 0]], [[0, 0, 0]], pardem.wall_law("linear", stiffness=1e5),
                                 motions=[motion], cylinders=cylinders)
        return pardem.System(pardem.Particles([[0.0, 2 * R]], R, RHO), walls=walls, dimension=2,
                             cell=pardem.Cell(lo=(-1, -1), length=(2, 2), periodic=(False, False)))
    with pytest.raises(ValueError, match="motions\\[0\\].*no z component"):
        pardem.build(comm, system(pardem.Sinusoid((0, 0, 1e-3), 1.0)))
    with pytest.raises(ValueError, match="cylinders\\[0\\].axis"):
        pardem.build(comm, system(None, [Cylinder((0, 0, 0), (1, 0, 0), 0.5)]))
    # in the plane: accepted, and a cylinder along z is a circle of the plane
    pardem.build(comm, system(pardem.Sinusoid((1e-3, 0, 0), 1.0), [Cylinder((0, 0, 0), (0, 0, 1), 0.5)]))
