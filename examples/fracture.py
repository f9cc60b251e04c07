"""Fracture: a bonded bar pulled slowly at one end breaks when its bonds reach their strength.

A bar of 3 x 3 x 20 touching spheres (``--quick``: 3 x 3 x 8; ``ordered_lattice``) is bonded to
its face neighbours by breakable beam bonds (``BeamMaterial(tensile_strength=sigma_t)``). The bottom
layer is clamped (``Clamp``), the top layer moves up at a constant speed V (``PrescribedVelocity``)
until the first bond breaks.

A bond breaks in tension when its elastic axial force reaches sigma_t S, S = pi r^2 the bond section
(r = radius ratio x R; docs/physics.md section 7). Along the bar the lattice is n_s = 3 x 3 parallel
chains of axial bonds (the lateral bonds are normal to the load and carry nothing: the simple cubic
lattice has no Poisson effect), so the axial force a cross-section transmits when its bonds break is

    F_rupture = n_s sigma_t pi r^2,

whatever the length of the bar. Two measures of it are compared with this value:

* the clamp's reaction at the last step before the first rupture (the force the bar transmits to its
  clamped end);
* the applied end displacement u at the first rupture times the bar's axial stiffness
  K = n_s k_a / (n_z - 1) (k_a = E S / (2R) per bond, n_z - 1 bonds in series).

Tolerance (relative): the loading starts with a step of velocity at the top, which sends a strain
wave of amplitude V / c down the bar (c = 2R sqrt(k_a / m), the long-wave speed of the chains);
undamped, the strain anywhere stays within V / c of the quasi-static strain u / L (it steps by
2 V / c at each reflection while u / L grows by the same amount between them). The first bond breaks
when the quasi-static strain is about eps_b = sigma_t / E, at the time t_b = eps_b L / V, so the
dynamic error of either measure, relative to F_rupture, is at most (V / c) / eps_b = L / (c t_b):
the one-way axial transit time over the loading time (the fundamental axial period is 2 L / c). The
clamp and the breaking section may deviate in opposite directions, and the discrete chain rings
behind the wave front above the continuum amplitude (by less than a factor 2): hence
4 L / (c t_b). The bonds' damping (ratio 0.1 of each pair mode, time constant tau_a) adds a
viscous axial force tau_a du/dt to the reaction (the rupture tests the elastic force only): a
relative tau_a / t_b; the end moves by V dt per step: a relative V dt / u_b. The tolerance is the sum
(4 % with --quick, 2 % otherwise). It bounds the undamped case; the bond damping also makes the
wave transients decay (the fundamental axial mode has the damping ratio omega_1 tau_a / 2, about
0.03 here), so the errors measured are far smaller (1e-4).

Run:  python examples/fracture.py [--quick]      (or: mpiexec -n 2 python examples/fracture.py)
Exit status 1 if a measure differs from F_rupture by more than the tolerance.
"""
import argparse
import sys

import numpy as np

import pardem


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 x 3 x 8 elements, faster loading")
    args = ap.parse_args(argv)
    nx, nz = 3, (8 if args.quick else 20)
    transits = 100.0 if args.quick else 200.0            # loading time to rupture / axial transit time
    R, E, ratio, rho = 1e-3, 1e9, 0.5, 2500.0           # m, Pa, -, kg/m^3
    sigma_t = 1e6                                       # tensile strength of the bonds [Pa]

    comm = pardem.Communicator()
    x, pairs, frame = pardem.ordered_lattice([2 * R * nx, 2 * R * nx, 2 * R * nz], R)
    material = pardem.BeamMaterial(young=E, radius_ratio=ratio, poisson=0.3, damping=0.1,
                                   tensile_strength=sigma_t)
    bottom = np.nonzero(np.isclose(x[:, 2], x[:, 2].min()))[0]
    top = np.nonzero(np.isclose(x[:, 2], x[:, 2].max()))[0]
    # the bonds that cross the plane between the first two layers: one per chain
    z_cut = x[:, 2].min() + R
    n_s = int(np.sum((x[pairs[:, 0], 2] - z_cut) * (x[pairs[:, 1], 2] - z_cut) < 0.0))

    S = np.pi * (ratio * R) ** 2
    ka = E * S / (2 * R)
    mass = rho * 4.0 / 3.0 * np.pi * R**3
    L = x[top, 2].mean() - x[bottom, 2].mean()
    K = n_s * ka / (nz - 1)
    F_rupture = n_s * sigma_t * S
    u_b = F_rupture / K                                 # quasi-static end displacement at rupture
    c = 2 * R * np.sqrt(ka / mass)                      # long-wave axial speed [m/s]
    t_b = transits * L / c
    V = u_b / t_b

    sim = pardem.build(comm, pardem.System(pardem.Particles(x, R, rho), bonds=pardem.BondModel(material, pairs, frame)))
    clamp = pardem.Clamp(bottom)
    pardem.add_fixes(sim, clamp, pardem.PrescribedVelocity(top, (0.0, 0.0, V)))

    # up to 90 % of the quasi-static rupture time in one go, then step by step to the first break
    sim.run(int(0.9 * t_b / sim.dt))
    if comm.any(np.any(sim.bonds.state != 0)):
        if comm.is_root:
            print("fracture: a bond broke before 90 % of the quasi-static rupture time\nFAIL")
        return 1
    reaction = float(sim.comm.sum(clamp.reaction[2]))
    broken = 0
    for _ in range(int(0.5 * t_b / sim.dt)):
        before = reaction
        sim.run(1)
        reaction = float(sim.comm.sum(clamp.reaction[2]))
        broken = int(sim.comm.sum(float(sim.bonds_broken_step)))
        if broken:
            break
    if not broken:
        if comm.is_root:
            print("fracture: no bond broke by 1.4 times the quasi-static rupture time\nFAIL")
        return 1
    # the bar pulls the clamped layer up: the clamp holds it with a downward reaction
    f_clamp = -before
    u = V * sim.time                                    # the top layer moved by V dt each step
    f_disp = K * u
    tau_a = 2 * 0.1 * np.sqrt(0.5 * mass / ka)
    tolerance = 4.0 * L / (c * t_b) + tau_a / t_b + V * sim.dt / u_b
    err_clamp = f_clamp / F_rupture - 1.0
    err_disp = f_disp / F_rupture - 1.0
    ok = abs(err_clamp) <= tolerance and abs(err_disp) <= tolerance
    if comm.is_root:
        print(f"fracture: {len(x)} elements ({nx} x {nx} x {nz}), {len(pairs)} bonds, {n_s} across a section, "
              f"{comm.size} rank(s), {sim.step_count} steps of {sim.dt:.3e} s")
        print(f"pull speed {V:.4e} m/s, loading time to rupture {t_b:.4e} s = {transits:g} axial transits "
              f"(L / c = {L / c:.4e} s)")
        print(f"first rupture at step {sim.step_count} (t = {sim.time:.6e} s): {broken} bond(s)")
        print(f"F_rupture = n_s sigma_t pi r^2 = {F_rupture:.6e} N")
        print(f"clamp reaction {f_clamp:.15e} N, relative error {err_clamp:+.3e}")
        print(f"end displacement {u:.6e} m x stiffness {K:.6e} N/m = {f_disp:.6e} N, relative error "
              f"{err_disp:+.3e}")
        print(f"tolerance {tolerance:.3e}")
        print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
