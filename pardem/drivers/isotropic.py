"""Isotropic preparation of a frictionless granular packing at pressures p0, then its elastic moduli.

    python -m pardem.drivers.isotropic [--config deck.toml] [--set section.key=value ...]
        [--pressures 1e5,1e6,...] [--out DIR] [--quiet]
    mpiexec -n 2 python -m pardem.drivers.isotropic --config drivers/isotropic_glass.toml

A gas of spheres in a periodic cell is compressed by a pressure servo, the kinetic energy removed
by FIRE (adaptive step) or global viscous damping, to static equilibrium at each p0 (ascending, the
same packing continued), measured (p, Z, Z without rattlers, solid fraction, normal force
distribution), then, with friction restored, probed
by small affine strain increments (isotropic and volume-preserving shear) for the bulk and shear
moduli, affine (no relaxation) and relaxed. The protocol and the equilibrium criteria are those of
``pardem.protocols.isotropic``. Default deck: ``drivers/isotropic_glass.toml`` values (10,000 glass spheres).

Writes ``DIR/isotropic.json``: ``rows`` (one per pressure: ``p0, p, Z, Z_no_rattlers,
solid_fraction, K_affine, K_relaxed, mu_affine, mu_relaxed``, SI units; a modulus is null when not
measured), ``details`` (per pressure: convergence, steps, criteria values, rattlers, the force
distribution ``f_n / <f_n>`` histogram, moduli strain and relaxations), ``criteria``, ``deck``,
``n_ranks``, ``wall_seconds``; and ``DIR/force_distribution.png`` when matplotlib is available.

Exit codes: 0 done (a pressure that did not reach equilibrium within ``preparation.max_steps`` is
flagged ``converged: false`` in ``details`` and warned about), 1 unexpected error (all ranks stop),
2 bad input (one line naming the option or deck field), 3 the run became unstable.
"""
import datetime
import os
import sys
import time

import pardem
from pardem.protocols import isotropic as iso
from pardem.drivers.cli import EXIT_OK, driver_parser, fail_usage, run_driver
from pardem.config import DeckError, load_deck
from pardem.io.summary import write_json
from pardem.parallel.communicator import Communicator


def parser(comm=None):
    p = driver_parser("python -m pardem.drivers.isotropic", __doc__.split("\n\n")[0], iso.SCHEMA,
                      run_options=False, comm=comm, out_default="runs/isotropic-<timestamp>")
    p.add_argument("--pressures", metavar="P1,P2,...",
                   help="target pressures p0 [Pa], comma-separated (overrides preparation.pressures)")
    return p


def main(argv=None):
    comm = Communicator()
    return run_driver(comm, run, parser(comm).parse_args(argv))


def _pressures(text):
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        vals = []
    if not vals or not all(v > 0.0 and v < float("inf") for v in vals):
        raise DeckError(f"--pressures {text!r}: expected comma-separated positive numbers [Pa]")
    return sorted(vals)


def run(comm, args):
    t0 = time.perf_counter()
    try:
        deck = load_deck(iso.SCHEMA, args.config, args.overrides)
        iso.check_sample(deck)
        if args.pressures is not None:
            deck["preparation"]["pressures"] = _pressures(args.pressures)
    except DeckError as err:
        fail_usage(comm, str(err))
    pressures = sorted(deck["preparation"]["pressures"])
    out = args.out or os.path.join("runs", "isotropic-" + comm.bcast(
        datetime.datetime.now().strftime("%Y%m%d-%H%M%S")))
    progress = iso.Progress(comm, deck["run"]["progress_seconds"], args.quiet)
    if comm.is_root:
        os.makedirs(out, exist_ok=True)
        progress.say(f"pardem {pardem.__version__}: isotropic preparation of {deck['sample']['n']} spheres "
                     f"on {comm.size} rank(s), p0 = {', '.join(f'{p:g}' for p in pressures)} Pa", force=True)
    rows, details, case = iso.sweep(comm, deck, pressures, progress)
    wall = time.perf_counter() - t0
    if comm.is_root:
        data = {"rows": rows, "details": details, "criteria": iso.criteria_text(deck), "deck": deck,
                "n_ranks": comm.size, "dt": case.sim.dt, "wall_seconds": wall,
                "units": {"p0": "Pa", "p": "Pa", "K_affine": "Pa", "K_relaxed": "Pa",
                          "mu_affine": "Pa", "mu_relaxed": "Pa", "Z": "1", "solid_fraction": "1"}}
        write_json(os.path.join(out, "isotropic.json"), data)
        written = ["isotropic.json"]
        if _plot(details, os.path.join(out, "force_distribution.png")):
            written.append("force_distribution.png")
        print(format_table(rows))
        bad = [d["p0"] for d in details if not d["converged"]]
        if bad:
            print(f"warning: no static equilibrium within preparation.max_steps at p0 = "
                  f"{', '.join(f'{p:g}' for p in bad)} Pa (see details in isotropic.json)")
        print(f"wrote {' and '.join(os.path.join(out, w) for w in written)} in {wall:.1f} s")
    return EXIT_OK


def format_table(rows):
    head = ("p0 [Pa]", "p [Pa]", "Z", "Z_nr", "phi", "K_aff [Pa]", "K_rel [Pa]", "mu_aff [Pa]", "mu_rel [Pa]")
    lines = ["  ".join(f"{h:>11s}" for h in head)]
    for r in rows:
        vals = [r[k] for k in iso.ROW_KEYS]
        lines.append("  ".join("       null" if v is None else f"{v:11.5g}" for v in vals))
    return "\n".join(lines)


def _plot(details, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        sys.stderr.write("pardem: note: matplotlib is not installed, so no force_distribution.png\n")
        return False
    fig, ax = plt.subplots(figsize=(6, 4))
    for d in details:
        fd = d["force_distribution"]
        e = fd["edges"]
        mid = [0.5 * (a + b) for a, b in zip(e[:-1], e[1:])]
        ax.semilogy(mid, [v if v > 0 else float("nan") for v in fd["density"]], "o-", ms=3,
                    label=f"p0 = {d['p0']:g} Pa")
    ax.set_xlabel("f_n / <f_n>")
    ax.set_ylabel("probability density")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


if __name__ == "__main__":
    sys.exit(main())
