"""Drop: a sphere falls under gravity onto a wall and bounces; rebound / impact speed vs restitution.

The wall uses the linear element-wall law of ``pardem.physics.walls`` with restitution e: its normal
dashpot ratio is ``zeta = linear_contact.damping_ratio(e)``, the exact inverse of the restitution of a
no-tension (clipped) linear spring-dashpot against an immovable wall (Schwager and Poeschel 2007), so
without gravity during the contact and with an exact integrator the speed ratio would be e exactly.

Tolerance, sum of two bounds:
* gravity during the contact: it shifts the oscillator's equilibrium by m g / k against an amplitude
  v_in / omega (omega = sqrt(k / m)), which changes the ratio by at most ~ 2 g / (omega v_in) (first
  order in that ratio; 4e-4 here);
* time discretisation: velocity Verlet evaluates the dashpot with the half-step velocity, which lags
  the velocity by dt / 2, i.e. by a phase omega dt / 2 of the contact oscillation; the dissipated
  impulse, hence the ratio, is then off by a relative amount of first order, bounded by
  omega dt / 2 (the errors measured at e = 0.1, 0.5, 0.9 are 3 to 10 times smaller).

Run:  python examples/drop.py [--quick] [--restitution E]   (or under mpiexec -n 2)
Exit status 1 if |ratio - e| exceeds the tolerance.
"""
import argparse
import sys

import numpy as np

import pardem


def vertical(sim, name):
    """The z component of the sphere's (gid 0) ``name`` (``sim.particles``: "positions" [m],
    "velocities" [m/s]), on every rank (collective)."""
    return float(sim.particles.get(name, [0])[0, 2])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="lower drop, coarser step (about a second)")
    ap.add_argument("--restitution", type=float, default=0.5)
    args = ap.parse_args(argv)
    e_req = args.restitution
    R, rho, k, g = 0.01, 2500.0, 1e7, 9.81            # m, kg/m^3, N/m, m/s^2
    h = 0.005 if args.quick else 0.02                 # gap under the sphere at the start [m]
    omega_dt = 0.05 if args.quick else 0.02           # steps per contact ~ pi / omega_dt

    comm = pardem.Communicator()
    mass = rho * 4.0 / 3.0 * np.pi * R**3
    omega = np.sqrt(k / mass)
    # the critical step of a single sphere on a linear wall is 2 / omega: dt = omega_dt / omega
    floor = pardem.WallModel(normals=[[0, 0, 1]], points=[[0, 0, 0]],
                             law=pardem.wall_law("linear", stiffness=k, restitution=e_req))
    sim = pardem.build(comm, pardem.System(pardem.Particles([[0.0, 0.0, R + h]], R, rho), walls=floor,
                                           integration=pardem.Integration(dt_fraction=0.5 * omega_dt)))
    pardem.add_fixes(sim, pardem.Gravity((0.0, 0.0, -g)))

    # free fall to just above the wall in one go (exact parabola for Verlet), then step by step
    t_hit = np.sqrt(2.0 * h / g)
    sim.run(max(0, int(t_hit / sim.dt) - 3))
    v_in = v_out = None
    for _ in range(100000):
        v_before = vertical(sim, "velocities")
        sim.run(1)
        z = vertical(sim, "positions")
        if v_in is None and z < R:
            v_in = v_before                               # last velocity before the contact
        elif v_in is not None and z >= R:
            v_out = vertical(sim, "velocities")           # first velocity after it
            break
    if v_out is None:
        raise SystemExit("the sphere did not leave the wall")
    ratio = -v_out / v_in
    tolerance = 2.0 * g / (omega * abs(v_in)) + 0.5 * omega * sim.dt
    ok = abs(ratio - e_req) <= tolerance
    if comm.is_root:
        print(f"drop: R = {R} m, wall stiffness {k:g} N/m, omega dt = {omega * sim.dt:.3g}, "
              f"{comm.size} rank(s), {sim.step_count} steps")
        print(f"impact speed {abs(v_in):.6f} m/s (free fall {np.sqrt(2 * g * h):.6f}), rebound {v_out:.6f} m/s")
        print(f"rebound ratio {ratio:.6f}, restitution e = {e_req}, difference {ratio - e_req:+.2e} "
              f"(tolerance {tolerance:.2e})")
        print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
