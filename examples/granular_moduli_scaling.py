"""Pressure scaling of the elastic moduli of a Hertz-Mindlin packing, measured two ways.

What it runs (one process, or ``mpiexec -n 2``; nothing is written to disk):

1. the isotropic protocol (``pardem.protocols.isotropic``) on ``drivers/isotropic_small.toml`` with
   ``sample.n = --n`` bidisperse glass spheres (radii 0.105 / 0.095 mm, G = 30 GPa, nu = 0.2),
   ``sample.seed = --seed``, FIRE preparation and ``material.friction = --friction``: the
   frictionless gas is compressed by the pressure servo to static equilibrium at each p0 of
   ``--pressures`` (ascending, each continuing the previous packing; the deck's three criteria);
2. at each pressure, before any strain, the **static** moduli of the contact network
   (``pardem.protocols.moduli_check.static_moduli``: stiffness matrix, sparse solve for the
   non-affine relaxation; ``tangent`` = at zero strain, ``protocol`` = the protocol's secant at its
   strain e to second order), Walton's effective medium theory (EMT) with the packing's Z, phi, p,
   and the affine sums over the contacts;
3. then the **dynamic** moduli of the protocol (``isotropic.moduli``, as the driver measures them):
   an isotropic, then a volume-preserving strain increment e = 0.01 <delta / d>, each ramped over
   ``moduli.ramp_steps`` = 2000 steps (affine moduli from the ramp's first step), then relaxed at
   fixed cell to the deck's kinetic and force criteria.

Prints (every modulus in Pa, p in Pa): one row per pressure with p, Z, Z without rattlers, the
relaxed K and mu dynamic and static (protocol secant) and ``rel`` = dynamic / static - 1 (the sign
of the summary's ``moduli.static``), the affine K and mu (static secant) beside Walton's K and mu,
and J = <f_n^(1/3)> / <f_n>^(1/3) (the force heterogeneity factor that relates the affine sums to
EMT for equal spheres); then the log-log slopes d ln M / d ln p between successive pressures;
``--json`` adds every row's full record (dynamic, static tangent and protocol secant, EMT,
convergence, seconds) as JSON.

Physics: Hertz contacts on a fixed network give M ~ p^(1/3) (EMT's slope, exactly 1/3). A real
packing gains contacts with pressure (Z rises from the isostatic 6), so the affine moduli scale a
little faster, and the relaxed shear modulus, which vanishes at jamming with Z - 6, much faster at
low pressure.

Cost (one rank, measured on the shared 2-core machine under a load of 5 to 13): the defaults
(n = 200; 1e5, 1e6, 1e7 Pa) 25 s of CPU (154 s wall), mostly the 1e5 Pa preparation; ``--quick``
(100 spheres; 1e6, 1e7 Pa) 9 s of CPU (38 s wall), plus the Numba compilation of a first run.
Measured with the defaults: relaxed / static - 1 below 1e-4 (K) and 1e-3 (mu); slopes 0.356 (K
relaxed), 0.388 and 0.375 (mu relaxed), 0.353 and 0.357 (Walton); J = 0.929, 0.938, 0.934.

Run:  python examples/granular_moduli_scaling.py [--n 200] [--pressures 1e5,1e6,1e7] [--friction 0.3]
                                                 [--seed 1] [--json] [--quick]
      python examples/granular_moduli_scaling.py --checkpoint DIR/checkpoints/checkpoint-N.h5 [--strain E]
      (the static moduli of one isotropic checkpoint, printed as JSON; meaningful for a checkpoint
      written at the end of a preparation, see ``moduli_check.from_checkpoint``)
"""
import argparse
import json
import os
import time

import numpy as np

from pardem.io.deck_file import load_deck
from pardem.parallel.communicator import Communicator
from pardem.protocols import isotropic as iso
from pardem.engine import packing
from pardem.protocols import stages
from pardem.protocols import moduli_check

DECK = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "drivers", "isotropic_small.toml")
KEYS = ("K_relaxed", "mu_relaxed", "K_affine", "mu_affine")
QUICK = {"n": 100, "pressures": "1e6,1e7"}


def study(n, pressures, friction, seed=1, comm=None):
    """Rows (one per pressure, ascending) of the dynamic and static moduli [Pa] of an ``n``-sphere
    packing (module docstring). Collective; every rank returns the same rows."""
    comm = Communicator() if comm is None else comm
    deck = load_deck(iso.SCHEMA, DECK,
                     [f"sample.n={n}", f"sample.seed={seed}", 'preparation.relaxation="fire"',
                      f"material.friction={friction}"])
    case, rows = None, []
    for p0 in sorted(pressures):
        t0 = time.perf_counter()
        case, info = stages.prepare(comm, deck, p0, case)
        sim = case.sim
        sim.elements.v[:] = 0.0
        sim.elements.w[:] = 0.0
        net = packing.network(sim)
        e = 0.01 * net["mean_overlap_ratio"]          # the protocol's "auto" strain (isotropic.strain_of)
        # the static response first: it linearises the frictionless equilibrium, before any increment
        static = moduli_check.static_moduli(sim, deck["material"], e)
        dyn = iso.moduli(sim, deck, e)
        rows.append({"p0": p0, "p": net["p"], "Z": net["Z"], "Z_no_rattlers": net["Z_no_rattlers"],
                     "solid_fraction": net["solid_fraction"], "converged": info["converged"],
                     "prepare_steps": info["steps"], "strain": e, "ramp_steps": dyn["ramp_steps"],
                     "relax_converged": bool(dyn["K_relax_converged"] and dyn["mu_relax_converged"]),
                     "dynamic": {k: dyn[k] for k in KEYS},
                     "static_tangent": {k: static["tangent"][k] for k in KEYS},
                     "static_protocol": {k: static["protocol"][k] for k in KEYS},
                     "iso_average": {k: static["tangent"][k] for k in ("K_iso_relaxed", "mu_iso_relaxed",
                                                                      "K_iso_affine", "mu_iso_affine")},
                     "emt": static["emt"], "seconds": time.perf_counter() - t0})
    return rows


def slopes(rows, group, key):
    """d ln M / d ln p between successive rows of ``rows[k][group][key]``."""
    p = np.array([r["p"] for r in rows])
    v = np.array([r[group][key] for r in rows])
    return (np.diff(np.log(v)) / np.diff(np.log(p))).tolist()


def report(rows):
    """The printed table and slopes (module docstring)."""
    print(f"{'p [Pa]':>10} {'Z':>6} {'Z_nr':>6} | {'K dyn':>10} {'K static':>10} {'rel':>9} | "
          f"{'mu dyn':>10} {'mu static':>10} {'rel':>9} | "
          f"{'K_aff':>10} {'K_EMT':>10} {'mu_aff':>10} {'mu_EMT':>10} {'J':>6}")
    for r in rows:
        d, s = r["dynamic"], r["static_protocol"]
        print(f"{r['p']:10.4g} {r['Z']:6.3f} {r['Z_no_rattlers']:6.3f} | {d['K_relaxed']:10.5g} {s['K_relaxed']:10.5g} "
              f"{d['K_relaxed'] / s['K_relaxed'] - 1:9.2e} | {d['mu_relaxed']:10.5g} {s['mu_relaxed']:10.5g} "
              f"{d['mu_relaxed'] / s['mu_relaxed'] - 1:9.2e} | {s['K_affine']:10.5g} {r['emt']['K_EMT']:10.5g} "
              f"{s['mu_affine']:10.5g} {r['emt']['mu_EMT']:10.5g} {r['emt']['heterogeneity']:6.3f}")
        if not (r["converged"] and r["relax_converged"]):
            print(f"  p0 = {r['p0']:.3g} Pa: NOT converged (preparation {r['converged']}, "
                  f"moduli relaxations {r['relax_converged']}): raise the deck's max_steps")
    if len(rows) < 2:
        return
    print("log-log slopes d ln M / d ln p between successive pressures (Hertz, fixed network: 1/3):")
    for group, key in (("dynamic", "K_relaxed"), ("static_tangent", "K_relaxed"), ("dynamic", "mu_relaxed"),
                       ("static_tangent", "mu_relaxed"), ("static_tangent", "K_affine"),
                       ("static_tangent", "mu_affine"), ("emt", "K_EMT")):
        print(f"  {group:15s} {key:11s} " + "  ".join(f"{x:.4f}" for x in slopes(rows, group, key)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="Every modulus and pressure printed is in Pa. See the module docstring.")
    ap.add_argument("--n", type=int, default=200, help="spheres (default 200)")
    ap.add_argument("--pressures", default="1e5,1e6,1e7", help="p0 list [Pa], comma-separated (default 1e5,1e6,1e7)")
    ap.add_argument("--friction", type=float, default=0.3, help="contact friction of the moduli (default 0.3)")
    ap.add_argument("--seed", type=int, default=1, help="gas seed (default 1)")
    ap.add_argument("--quick", action="store_true",
                    help=f"{QUICK['n']} spheres at {QUICK['pressures']} Pa (about 10 s of CPU): a smoke run")
    ap.add_argument("--json", action="store_true", help="print the rows as JSON too")
    ap.add_argument("--checkpoint", help="only the static moduli of this isotropic checkpoint (JSON)")
    ap.add_argument("--strain", type=float, default=None, help="with --checkpoint: the protocol's strain e")
    a = ap.parse_args(argv)
    if a.quick:
        a.n, a.pressures = QUICK["n"], QUICK["pressures"]
    if a.checkpoint:
        comm = Communicator()
        out = moduli_check.from_checkpoint(comm, a.checkpoint, None, a.strain)   # the checkpoint's grains
        if comm.is_root:
            print(json.dumps(out, indent=1))
        return
    comm = Communicator()
    t0 = time.perf_counter()
    rows = study(a.n, [float(x) for x in a.pressures.split(",")], a.friction, seed=a.seed, comm=comm)
    if comm.is_root:
        print(f"{a.n} spheres, friction {a.friction:g}, seed {a.seed}, {comm.size} rank(s), "
              f"{time.perf_counter() - t0:.0f} s")
        report(rows)
        if a.json:
            print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
