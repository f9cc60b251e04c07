"""Cantilever: a straight chain of bonded spheres, clamped at one end, bent by a tip load.

The chain's beam bonds join the element centres and are exact Euler-Bernoulli frame elements
(docs/physics.md section 2: end forces 6EI/L^2, moments 4EI/L and 2EI/L), so under a nodal load the
discrete static tip deflection is the continuum one, d = F L^3 / (3 E I), with L the distance from
the clamped centre to the loaded centre and I = pi r^4 / 4 the bond section's moment (r = bond
radius). Global viscous damping (critical for the first bending mode) brings the chain to rest; the
static state does not depend on it (the drag vanishes at rest).

Tolerance (relative, 1e-6): the only departures from the linear answer are the geometric
nonlinearity, of order (d / L)^2 ~ 1e-9 for the load used here, and the residual motion: the run
continues until the tip deflection changes by less than 1e-8 of itself over one chunk of steps,
and every mode decays at least geometrically between chunks (the factor measured on the last two
chunks bounds what is left), so the remaining error is far below 1e-6.

Run:  python examples/cantilever.py [--quick]      (or: mpiexec -n 2 python examples/cantilever.py)
Exit status 1 if the deflection is off by more than the tolerance.
"""
import argparse
import sys

import numpy as np

import pardem

TOLERANCE = 1e-6


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="6 elements instead of 11 (a few seconds)")
    ap.add_argument("--elements", type=int, default=None)
    args = ap.parse_args(argv)
    n = args.elements or (6 if args.quick else 11)
    R, E, ratio, rho, F = 0.01, 1e9, 0.5, 1000.0, 1e-3     # m, Pa, -, kg/m^3, N

    comm = pardem.Communicator()
    x = np.zeros((n, 3))
    x[:, 0] = 2.0 * R * np.arange(n)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    material = pardem.BeamMaterial(young=E, radius_ratio=ratio, poisson=0.3, damping=0.0)

    L = 2.0 * R * (n - 1)
    EI = E * np.pi * (ratio * R) ** 4 / 4.0
    mass = rho * 4.0 / 3.0 * np.pi * R**3
    omega1 = 1.875**2 * np.sqrt(EI / (mass / (2.0 * R) * L**4))   # first bending mode [rad/s]
    system = pardem.System(pardem.Particles(x, R, rho), bonds=pardem.BondModel(material, pairs),
                           integration=pardem.Integration(viscous_damping=2.0 * omega1))
    sim = pardem.build(comm, system)
    clamp = pardem.Clamp([0])                                      # all 6 DOFs of element 0
    pardem.add_fixes(sim, clamp, pardem.ExternalForce([n - 1], force=(0.0, 0.0, -F)))

    expected = F * L**3 / (3.0 * EI)
    chunk = max(1, int(5.0 / omega1 / sim.dt))
    history = []
    for _ in range(40):
        sim.run(chunk)
        # the tip's vertical displacement, read by global id on every rank (collective)
        history.append(-float(sim.particles.get("positions", [n - 1])[0, 2] - x[n - 1, 2]))
        if len(history) >= 3 and abs(history[-1] - history[-2]) < 1e-8 * abs(history[-1]):
            break
    reaction = float(clamp.global_reaction[2])     # the total over ranks, as of the end of the run
    error = history[-1] / expected - 1.0
    if comm.is_root:
        print(f"cantilever: {n} elements, L = {L:.4g} m, E I = {EI:.4g} N m^2, F = {F:g} N, "
              f"{comm.size} rank(s), {sim.step_count} steps of {sim.dt:.3e} s")
        print(f"tip deflection {history[-1]:.16e} m, Euler-Bernoulli F L^3/(3 E I) = {expected:.10e} m, "
              f"relative error {error:+.3e} (tolerance {TOLERANCE:g})")
        print(f"clamp reaction {reaction:+.6e} N (load {F:g} N)")
    ok = abs(error) <= TOLERANCE and abs(reaction - F) <= 1e-6 * F
    if comm.is_root:
        print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
