"""A compression test written with the Python API only: lattice, bonds, two walls, E vs analytic.

A simple cubic lattice of touching spheres (``ordered_lattice``) bonded to its face neighbours sits
between two frictionless walls normal to z; the top wall moves down at constant speed. Young's
modulus is the slope of the mean wall stress ``(F_bottom + F_top) / 2 / A`` against the axial strain
of the lattice (distance between the top and bottom element layers, so the element-wall contact
springs do not enter), over the second half of the run. The analytic modulus of this lattice
along a lattice axis is ``pi/4 E r^2`` (docs/physics.md section 6: each bond of stiffness
E pi (r R)^2 / (2R) carries a (2R)^2 share of the section, with r the bond radius ratio).

Tolerance 1 % (as the compress driver's own test): the mean of the two wall forces cancels the
lattice's inertial force to first order and the slope removes the constant viscous stress of the
bond damping; what remains is the second-order dynamic error of a loading that lasts a few tens of
axial wave transits (the compression protocol's QUASI_STATIC_TRANSITS is 4), well below 1 %.

Run:  python examples/custom_compression.py [--quick]     (or: mpiexec -n 2 python ...)
Exit status 1 if the modulus differs from the analytic one by more than 1 %.
"""
import argparse
import sys

import numpy as np

import pardem

TOLERANCE = 0.01


def layer_mean_z(sim, gids):
    """Mean z [m] of the elements of global ids ``gids`` (read by gid on every rank; collective)."""
    return float(sim.particles.get("positions", gids)[:, 2].mean())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 x 3 x 5 elements, shorter loading")
    args = ap.parse_args(argv)
    R, E, ratio, rho = 1e-3, 100e6, 1.0, 1000.0      # m, Pa, -, kg/m^3
    nx, nz = (3, 5) if args.quick else (4, 8)
    strain_end = 1e-3

    comm = pardem.Communicator()
    box = [2 * R * nx, 2 * R * nx, 2 * R * nz]
    x, pairs, frame = pardem.ordered_lattice(box, R)
    material = pardem.BeamMaterial(young=E, radius_ratio=ratio, poisson=0.3, damping=0.2)
    # the walls' linear stiffness: the bonds' axial stiffness E S / L0 (the compress deck's "auto")
    k_wall = E * np.pi * (ratio * R) ** 2 / (2 * R)
    z_lo, z_hi = x[:, 2].min() - R, x[:, 2].max() + R
    length = z_hi - z_lo
    mass = rho * 4 / 3 * np.pi * R**3
    transit = length / (2 * R * np.sqrt(k_wall / mass))        # axial wave crossing time [s]
    duration = (25 if args.quick else 40) * transit
    speed = strain_end * length / duration
    walls = pardem.WallModel(normals=[[0, 0, 1], [0, 0, -1]], points=[[0, 0, z_lo], [0, 0, z_hi]],
                             velocities=[[0, 0, 0], [0, 0, -speed]], law=pardem.wall_law("linear", stiffness=k_wall))
    sim = pardem.build(comm, pardem.System(pardem.Particles(x, R, rho), bonds=pardem.BondModel(material, pairs, frame),
                                           walls=walls))
    walls = sim.plates
    bottom = np.nonzero(np.isclose(x[:, 2], x[:, 2].min()))[0]
    top = np.nonzero(np.isclose(x[:, 2], x[:, 2].max()))[0]
    gap0 = x[top, 2].mean() - x[bottom, 2].mean()

    n_samples = 40
    steps = int(np.ceil(duration / sim.dt / n_samples))
    strain, stress = [], []
    area = box[0] * box[1]
    log = pardem.Log(trigger=steps)            # thermo line (rank 0 prints), every 10th sample
    for i in range(n_samples):
        sim.run(steps, operations=[log] if (i + 1) % 10 == 0 else [])
        f = walls.normal_force                   # compressive force on each wall [N], end of this run
        strain.append(1.0 - (layer_mean_z(sim, top) - layer_mean_z(sim, bottom)) / gap0)
        stress.append(0.5 * (f[0] + f[1]) / area)
    strain, stress = np.array(strain), np.array(stress)
    half = slice(n_samples // 2, None)
    young = float(np.polyfit(strain[half], stress[half], 1)[0])
    analytic = np.pi / 4 * E * ratio**2
    error = young / analytic - 1.0
    ok = abs(error) <= TOLERANCE
    if comm.is_root:
        print(f"compression: {len(x)} elements, {len(pairs)} bonds, {comm.size} rank(s), "
              f"{sim.step_count} steps of {sim.dt:.3e} s, loading {duration / transit:.0f} wave transits")
        print(f"final strain {strain[-1]:.4e}, stress {stress[-1]:.4e} Pa")
        print(f"Young's modulus {young:.6e} Pa, analytic pi/4 E r^2 = {analytic:.6e} Pa, "
              f"relative error {error:+.3e} (tolerance {TOLERANCE:g})")
        print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
