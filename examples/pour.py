"""Pour: polydisperse spheres poured under gravity into a box settle; floor load = weight, packing.

A few thousand spheres (``--quick``: 500) with radii uniform in [0.9, 1.1] <R> (seeded) start at
rest on a loose jittered grid above the floor of a box of five planar walls (a floor and four side
walls) and fall under gravity. Grain contacts are Hertz-Mindlin with friction 0.5 and restitution
0.3; the walls (one element-wall law for all five) are Hertz, frictionless, with restitution 0.3. A
global viscous damping speeds up the settling. The run goes on, in chunks, until the kinetic energy
is below ``SETTLED`` (1e-7) times the potential energy the grains have lost.

Checks:

(a) The floor carries the weight. Every wall is frictionless, so a wall pushes along its normal
    only: the side walls exert no vertical force (no Janssen effect, which frictional side walls
    would cause: they would carry part of the weight and the floor less than m g), the grain-grain
    forces cancel in pairs, and the vertical momentum balance of the whole bed is
    dP_z/dt = N - M g, with N the floor's normal force and M g the total weight. Over a window of
    length T (the global damping switched off for it, so it adds no force), velocity Verlet
    satisfies it exactly in the discrete sense: the trapezoidal time mean of N over the window's
    steps equals M g + (P_z(end) - P_z(start)) / T. By Cauchy-Schwarz |P_z| <= sqrt(2 M K) with K
    the kinetic energy, hence the tolerance (in newtons)

        |<N> - M g| <= 2 sqrt(2 M K_max) / T,    K_max the larger of K at the window's two ends,

    plus the round-off of the force sums (1e-9 relative, far below). With K ~ 1e-7 of the lost
    potential energy this is about 1e-3 of the weight (frictional walls, friction 0.5, make the floor
    carry 6 % less with --quick: the check fails, as it should).

(b) The packing fraction of the settled bed lies between random loose packing, 0.55 (the loosest
    stable packing of frictional spheres, phi_RLP = 0.555, Onoda and Liniger, Phys. Rev. Lett. 64,
    2727 (1990)), and random close packing, 0.64 (phi_RCP = 0.637, Scott and Kilgour, J. Phys. D 2,
    863 (1969)); the small size dispersion here (radii +-10 %, standard deviation 6 % of the mean)
    shifts phi_RCP by less than 0.01 (Desmond and Weeks, Phys. Rev. E 90, 022204 (2014)). What is
    measured: the volume fraction of the bulk, i.e. the fraction of a regular grid of points (spacing
    <R> / 8) in an interior box that lies inside some sphere. The box leaves out 1.5 mean diameters
    next to each side wall and 2 mean diameters above the floor and below the highest centre (the
    layering at flat walls and the rough free surface lower the local fraction there; they are not
    the bulk packing the range refers to). The whole-bed fraction (total sphere volume over the box
    section times the height of the highest centre plus a mean radius) is printed for comparison:
    it is lower, by those wall and surface layers.

Run:  python examples/pour.py [--quick]      (or: mpiexec -n 2 python examples/pour.py --quick)
Exit status 1 if a check fails (or the bed does not settle within the time limit).
"""
import argparse
import sys

import numpy as np

import pardem

SETTLED = 1e-7                      # kinetic energy / potential energy lost: settled below this
PHI_RLP, PHI_RCP = 0.55, 0.64       # range of a poured random packing (module docstring)


def initial_grid(n, per_row, spacing, r_max, rng):
    """``n`` centres [n, 3] [m] on a grid of ``per_row`` x ``per_row`` columns and ``spacing`` [m],
    its lowest layer just above the floor z = 0, each centre moved at random by less than half the
    free gap ``spacing - 2 r_max`` along each axis, so no two spheres of radius <= ``r_max`` touch."""
    k = np.arange(n)
    ix, iy, iz = k % per_row, (k // per_row) % per_row, k // per_row**2
    x = np.stack([ix, iy, iz], axis=1) * spacing + 0.5 * spacing
    jitter = 0.5 * (spacing - 2.0 * r_max) * 0.99
    return x + rng.uniform(-jitter, jitter, size=(n, 3))


def bulk_fraction(x, r, lo, hi, h):
    """Fraction of the grid points of spacing ``h`` [m] in the box [lo, hi] [3] [m] that lie
    inside at least one sphere (centres ``x`` [n, 3], radii ``r`` [n])."""
    axes = [np.arange(a + 0.5 * h, b, h) for a, b in zip(lo, hi)]
    inside = np.zeros(tuple(len(a) for a in axes), dtype=bool)
    for c, rad in zip(x, r):
        sl = [slice(np.searchsorted(a, c[d] - rad), np.searchsorted(a, c[d] + rad, side="right"))
              for d, a in enumerate(axes)]
        if any(s.start >= s.stop for s in sl):
            continue
        gx, gy, gz = (axes[d][sl[d]] - c[d] for d in range(3))
        inside[tuple(sl)] |= (gx[:, None, None]**2 + gy[None, :, None]**2 + gz[None, None, :]**2) <= rad**2
    return float(inside.mean()), inside.size


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="500 spheres in a narrower box instead of 3000")
    ap.add_argument("--spheres", type=int, default=None)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    n = args.spheres or (500 if args.quick else 3000)
    per_row = 6 if args.quick else 10
    R, rho, g = 1e-3, 2500.0, 9.81                     # mean radius [m], density [kg/m^3], [m/s^2]
    young, poisson = 1e7, 0.3                          # soft grains: overlaps under the weight < 1e-2 R
    damping = 10.0                                     # global viscous damping while pouring [1/s]

    comm = pardem.Communicator()
    rng = np.random.default_rng(args.seed)
    r = rng.uniform(0.9 * R, 1.1 * R, n)
    spacing = 2.2 * 1.1 * R
    x0 = initial_grid(n, per_row, spacing, 1.1 * R, rng)
    width = per_row * spacing                          # the box is [0, width]^2 in x, y
    walls = pardem.WallModel(
        normals=[[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]],
        points=[[0, 0, 0], [0, 0, 0], [width, 0, 0], [0, 0, 0], [0, width, 0]],
        law=pardem.wall_law("hertz", young=young, poisson=poisson, restitution=0.3, friction=0.0))
    contacts = pardem.ContactModel("hertz_mindlin", dict(young=young, poisson=poisson, friction=0.5,
                                                         restitution=0.3))
    system = pardem.System(pardem.Particles(x0, r, rho), contacts=contacts, walls=walls,
                           integration=pardem.Integration(viscous_damping=damping, orientation=False),
                           decomposition=pardem.Decomposition(slab_axis=0))
    sim = pardem.build(comm, system)
    pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -g)))

    masses = sim.particles.masses
    M = float(masses.sum())
    z0 = x0[:, 2]
    chunk = max(1, int(0.01 / sim.dt))                 # 10 ms of pouring between checks
    t_max = 3.0                                        # [s]; the quick bed settles in about 0.5 s
    ratio = np.inf
    while sim.time < t_max:
        sim.run(chunk)
        kinetic = sim.kinetic_energy()          # exact sum: the same bits on any rank count
        lost = g * float(np.dot(masses, z0 - sim.particles.positions[:, 2]))
        ratio = kinetic / lost
        if ratio < SETTLED:
            break
    settled = ratio < SETTLED

    # (a) the floor force over a window without global damping (module docstring)
    sim.viscous_damping = 0.0
    sim.run(1)                                         # every force of the window is undamped
    floor = sim.plates
    window = max(2, int(0.02 / sim.dt))
    k_start = sim.kinetic_energy()
    normal = [floor.normal_forces(comm)[0]]
    for _ in range(window):
        sim.run(1)
        normal.append(floor.normal_forces(comm)[0])
    k_end = sim.kinetic_energy()
    normal = np.array(normal)
    mean_normal = float((normal.sum() - 0.5 * (normal[0] + normal[-1])) / window)
    T = window * sim.dt
    weight = M * g
    tol_force = 2.0 * np.sqrt(2.0 * M * max(k_start, k_end)) / T + 1e-9 * weight

    # (b) packing fraction of the bulk (module docstring)
    x, radii = sim.particles.positions, sim.particles.radii
    d = 2.0 * R
    z_top = float(x[:, 2].max())
    lo = np.array([1.5 * d, 1.5 * d, 2.0 * d])
    hi = np.array([width - 1.5 * d, width - 1.5 * d, z_top - 2.0 * d])
    phi, points = bulk_fraction(x, radii, lo, hi, R / 8.0) if hi[2] > lo[2] else (np.nan, 0)
    volume = float(np.sum(4.0 / 3.0 * np.pi * radii**3))
    phi_bed = volume / (width**2 * (z_top + R))

    ok_force = settled and abs(mean_normal - weight) <= tol_force
    ok_phi = PHI_RLP <= phi <= PHI_RCP
    if comm.is_root:
        print(f"pour: {n} spheres, radii {radii.min():.4g}-{radii.max():.4g} m, box {width:.4g} m wide, "
              f"{comm.size} rank(s), {sim.step_count} steps of {sim.dt:.3e} s ({sim.time:.3f} s)")
        print(f"settled: kinetic / potential energy lost {ratio:.3e} (threshold {SETTLED:g})"
              + ("" if settled else f" NOT SETTLED within {t_max} s"))
        print(f"floor force {mean_normal:.15e} N, weight M g {weight:.15e} N, difference "
              f"{mean_normal - weight:+.3e} N, relative {mean_normal / weight - 1.0:+.3e} "
              f"(tolerance {tol_force / weight:.3e} relative, window {T:.4f} s)")
        print(f"bulk packing fraction {phi:.4f} in [{lo[0]:.4g}, {hi[0]:.4g}] x [{lo[1]:.4g}, {hi[1]:.4g}] x "
              f"[{lo[2]:.4g}, {hi[2]:.4g}] m ({points} points); range [{PHI_RLP}, {PHI_RCP}]")
        print(f"whole-bed packing fraction {phi_bed:.4f} (bed height {z_top + R:.4g} m)")
        print("PASS" if ok_force and ok_phi else "FAIL")
    return 0 if ok_force and ok_phi else 1


if __name__ == "__main__":
    sys.exit(main())
