"""Pour with insertion into a cylinder: log-normal grains poured into a cylindrical wall with a
floor settle; all inside, at rest, mass conserved, walls carry the weight, packing, size law.

The particle factory of a LIGGGHTS or Yade script, with the public API: a first batch of grains is
placed at random without overlap (``pardem.random_pack``) in a cylindrical region (``pardem.
CylinderRegion``) above the floor, inside a vertical cylinder wall (``pardem.Cylinder``, radius
``Rc``, grains inside, infinite along z; ``pardem.physics.curved_walls``) standing on a planar floor
z = 0, and an ``Insert`` operation adds a batch every 20 ms in the same region during the run, each
filling the region to a solid fraction of 0.2 among the grains still there, with a downward
velocity of 0.3 m/s, until ``--spheres`` grains (default 2000; ``--quick``: 500) have been
inserted: LIGGGHTS' ``fix insert/pack``. Radii follow a log-normal law by number
(``pardem.LogNormal``: median <R> = 1 mm, sigma 0.15, truncated at +-2 sigma). Grain contacts are
Hertz-Mindlin with friction 0.5 and restitution 0.3; the walls (floor and cylinder) are Hertz,
frictionless, with restitution 0.3. A global viscous damping speeds up the settling; the run goes
on, in chunks, until the kinetic energy is below ``SETTLED`` (1e-6) times M g <R> (M the total
mass): about 1e-7 of the potential energy the grains lost, the criterion of ``examples/pour.py``.

Checks:

(a) The walls carry the weight, over a window without damping: the floor's normal force ``<N>``
    and the whole wall force (floor + cylinder, a vector) against ``(0, 0, M g)``, each component
    within ``2 sqrt(2 M K_max) / T``, the discrete momentum balance of velocity Verlet with
    ``|P| <= sqrt(2 M K)`` (derived in ``examples/pour.py``). The frictionless cylinder pushes along
    its radii only: its vertical force is zero, its horizontal forces cancel at rest.
(b) The bulk packing fraction (the grid measure of ``examples/pour.py`` in the square prism
    inscribed in the cylinder of radius ``Rc`` - 1.5 mean diameters, 2 diameters from the floor and
    from the highest centre) lies between random loose packing 0.55 (Onoda and Liniger, Phys. Rev.
    Lett. 64, 2727 (1990)) and random close packing of this size dispersion: 0.637 for equal
    spheres (Scott and Kilgour, J. Phys. D 2, 863 (1969)), raised by less than 0.015 at a relative
    radius spread of 0.15 (Desmond and Weeks, Phys. Rev. E 90, 022204 (2014)): 0.65.
(c) Every requested grain was inserted (``Insert.inserted``, none left without room), and the radii
    of the grains in the bed are a sample of the requested law: a Kolmogorov-Smirnov test against
    the truncated log-normal CDF (scipy), p > 1e-3.
(d) All grains are inside the cylinder and above the floor: ``rho + r <= Rc + 0.05 r`` and
    ``z >= 0.95 r``, 0.05 r being the largest wall overlap for which the code's time step holds
    (``engine.walls.WALL_OVERLAP_BOUND``; a settled bed overlaps the walls by ~1e-3 r); the mass in
    the cylinder at the end is the mass inserted (the first batch and every later batch, summed
    when each arrived), to the round-off of the two sums (1e-12 relative): no grain lost.
(e) The pile is at rest: the kinetic energy, below ``SETTLED`` times M g <R> at the end of the
    damped settling, stays below it over the undamped window of (a).

Run:  python examples/pour_cylinder.py [--quick]   (or: mpiexec -n 2 python examples/pour_cylinder.py --quick)
Exit status 1 if a check fails (or the bed does not settle within the time limit).
"""
import argparse
import math
import sys

import numpy as np
from scipy import stats

import pardem
from pour import bulk_fraction      # the grid measure of the bulk packing fraction

SETTLED = 1e-6                      # kinetic energy / (M g <R>): settled below this
PHI_RLP, PHI_RCP = 0.55, 0.65       # range of a poured random packing (module docstring)
OVERLAP = 0.05                      # largest wall overlap / r of a grain still inside (check (d))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="500 spheres in a narrower cylinder instead of 2000")
    ap.add_argument("--spheres", type=int, default=None)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    n_total = args.spheres or (500 if args.quick else 2000)
    R, rho, g = 1e-3, 2500.0, 9.81                       # median radius [m], density [kg/m^3], [m/s^2]
    sigma = 0.15
    young, poisson = 1e7, 0.3
    damping = 10.0                                       # global viscous damping while pouring [1/s]
    rc = (8.0 if args.quick else 12.5) * R               # the cylinder wall's radius [m]
    centre = np.array([rc, rc, 0.0])                     # its axis: x = y = rc, along z
    radii = pardem.LogNormal(R, sigma, R * math.exp(-2 * sigma), R * math.exp(2 * sigma))
    # the bed's height at a fraction 0.6, and the insertion cylinder above it
    bed = n_total * radii.mean_volume() / (0.6 * math.pi * rc**2)
    source = pardem.CylinderRegion([rc, rc, bed + 4 * R], rc - 1.5 * radii.r_max, 8.0 * R)

    comm = pardem.Communicator()
    first = pardem.random_pack(source, radii, volume_fraction=0.2, seed=args.seed)
    walls = pardem.WallModel(
        normals=[[0, 0, 1]], points=[[0, 0, 0]],
        law=pardem.wall_law("hertz", young=young, poisson=poisson, restitution=0.3, friction=0.0),
        cylinders=[pardem.Cylinder(centre, (0, 0, 1), rc, inside=True)])
    contacts = pardem.ContactModel("hertz_mindlin", dict(young=young, poisson=poisson, friction=0.5,
                                                         restitution=0.3))
    v0 = np.tile([0.0, 0.0, -0.3], (first.n, 1))
    # the time step: 0.3 of the critical step of the smallest grain the law can give
    system = pardem.System(pardem.Particles(first.positions, first.radii, rho, v0), contacts=contacts,
                           walls=walls, integration=pardem.Integration(viscous_damping=damping, orientation=False),
                           decomposition=pardem.Decomposition(slab_axis=0, skin=0.2 * R))
    probe = pardem.System(pardem.Particles([[rc, rc, R]], radii.r_min, rho), contacts=contacts,
                          walls=walls)
    system.integration.dt = pardem.build(comm, probe).dt
    sim = pardem.build(comm, system)
    pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -g)))

    period = max(1, int(0.02 / sim.dt))                 # a batch every 20 ms
    pour = pardem.Insert(source, radii, trigger=period, volume_fraction=0.2, total=n_total - first.n,
                         velocity=(0.0, 0.0, -0.3), seed=args.seed)
    chunk = period
    inserted_mass = [float(np.sum(rho * 4.0 / 3.0 * np.pi * first.radii ** 3))]

    def arrived(sim):
        """The mass of the batch just inserted [kg], from the insertion's own gids."""
        if len(pour.last):
            inserted_mass.append(float(np.sum(sim.particles.get("masses", pour.last))))
    arrived.trigger, arrived.at_end = pour.trigger, False
    t_max = 4.0                                          # [s]; the quick bed settles in about 1 s
    ratio = np.inf
    while sim.time < t_max:
        sim.run(chunk, operations=[pour, arrived])
        if first.n + pour.inserted < n_total:
            continue
        M = float(sim.particles.masses.sum())
        ratio = sim.kinetic_energy() / (M * g * R)       # exact sum: the same bits on any rank count
        if ratio < SETTLED:
            break
    settled = ratio < SETTLED
    n = sim.particles.n

    # (a) the floor force over a window without global damping (examples/pour.py)
    sim.viscous_damping = 0.0
    sim.run(1)
    M = float(sim.particles.masses.sum())
    window = max(2, int(0.02 / sim.dt))
    k_start = sim.kinetic_energy()
    k_max = k_start
    normal, total = [sim.plates.normal_forces(comm)[0]], [sim.plates.forces(comm).sum(axis=0)]
    for _ in range(window):
        sim.run(1)
        normal.append(sim.plates.normal_forces(comm)[0])
        total.append(sim.plates.forces(comm).sum(axis=0))
        k_max = max(k_max, sim.kinetic_energy())
    k_end = sim.kinetic_energy()
    normal, total = np.array(normal), np.array(total)
    # the trapezoid mean over the window: the momentum balance of velocity Verlet (examples/pour.py)
    mean_normal = float((normal.sum() - 0.5 * (normal[0] + normal[-1])) / window)
    mean_total = (total.sum(axis=0) - 0.5 * (total[0] + total[-1])) / window
    cylinder = sim.plates.forces(comm)[1]
    T = window * sim.dt
    weight = M * g
    tol_force = 2.0 * np.sqrt(2.0 * M * max(k_start, k_end)) / T + 1e-9 * weight
    # the elements push the walls: at rest the walls' total force is the weight, (0, 0, -M g)
    wall_error = float(np.max(np.abs(mean_total - np.array([0.0, 0.0, -weight]))))

    # (b) packing fraction of the bulk
    x, r = sim.particles.positions, sim.particles.radii
    d = 2.0 * R
    z_top = float(x[:, 2].max())
    half = (rc - 1.5 * d) / math.sqrt(2.0)              # the square inscribed in the inner circle
    lo = np.array([rc - half, rc - half, 2.0 * d])
    hi = np.array([rc + half, rc + half, z_top - 2.0 * d])
    phi, points = bulk_fraction(x, r, lo, hi, R / 8.0) if hi[2] > lo[2] else (np.nan, 0)
    phi_bed = float(np.sum(4.0 / 3.0 * np.pi * r**3)) / (math.pi * rc**2 * (z_top + R))

    # (d) all inside, mass conserved
    rho_c = np.hypot(x[:, 0] - centre[0], x[:, 1] - centre[1])
    outside = int(np.sum(rho_c + r > rc + OVERLAP * r)) + int(np.sum(x[:, 2] < (1.0 - OVERLAP) * r))
    depth = float(np.max((rho_c + r - rc) / r))         # the deepest reach into the cylinder wall / r
    mass_in = float(np.sum(inserted_mass))
    ok_inside = outside == 0 and abs(M - mass_in) <= 1e-12 * mass_in

    # (c) the radii against the requested law (scipy's truncated log-normal, not the code's table)
    law = stats.lognorm(sigma, scale=R)
    lo_c, hi_c = law.cdf(radii.r_min), law.cdf(radii.r_max)
    p_ks = stats.kstest(r, lambda s: (law.cdf(s) - lo_c) / (hi_c - lo_c)).pvalue

    ok_force = settled and abs(mean_normal - weight) <= tol_force and wall_error <= tol_force
    ok_rest = settled and k_max / (M * g * R) < SETTLED
    ok_phi = PHI_RLP <= phi <= PHI_RCP
    ok_insert = n == n_total and pour.missing == 0 and p_ks > 1e-3
    if comm.is_root:
        print(f"pour_cylinder: {n} spheres inserted ({first.n} at the build, {pour.inserted} in {pour.batches} "
              f"batches, {pour.missing} without room), radii {r.min():.4g}-{r.max():.4g} m, cylinder radius "
              f"{rc:.4g} m, "
              f"{comm.size} rank(s), {sim.step_count} steps of {sim.dt:.3e} s ({sim.time:.3f} s)")
        print(f"radii against the log-normal law: Kolmogorov-Smirnov p = {p_ks:.4g}")
        print(f"settled: kinetic / (M g <R>) {ratio:.3e} (threshold {SETTLED:g})"
              + ("" if settled else f" NOT SETTLED within {t_max} s"))
        print(f"floor force {mean_normal:.15e} N, weight M g {weight:.15e} N, difference "
              f"{mean_normal - weight:+.3e} N, relative {mean_normal / weight - 1.0:+.3e} "
              f"(tolerance {tol_force / weight:.3e} relative, window {T:.4f} s)")
        print(f"walls' total force ({mean_total[0]:+.3e}, {mean_total[1]:+.3e}, {mean_total[2]:.6e}) N, "
              f"largest difference from (0, 0, -M g) {wall_error:.3e} N (tolerance {tol_force:.3e} N); "
              f"cylinder ({cylinder[0]:+.3e}, {cylinder[1]:+.3e}, {cylinder[2]:+.3e}) N")
        print(f"inside the cylinder: {n - outside} of {n} grains (deepest wall overlap {max(depth, 0.0):.3e} r, "
              f"bound {OVERLAP} r); mass {M:.15e} kg, inserted {mass_in:.15e} kg")
        print(f"at rest: largest kinetic / (M g <R>) over the undamped window {k_max / (M * g * R):.3e}")
        print(f"bulk packing fraction {phi:.4f} in [{lo[0]:.4g}, {hi[0]:.4g}] x [{lo[1]:.4g}, {hi[1]:.4g}] x "
              f"[{lo[2]:.4g}, {hi[2]:.4g}] m ({points} points); range [{PHI_RLP}, {PHI_RCP}]")
        print(f"whole-bed packing fraction {phi_bed:.4f} (bed height {z_top + R:.4g} m)")
        print("PASS" if ok_force and ok_phi and ok_insert and ok_inside and ok_rest else "FAIL")
    return 0 if ok_force and ok_phi and ok_insert and ok_inside and ok_rest else 1


if __name__ == "__main__":
    sys.exit(main())
