"""Mixture study: bidisperse packings against size ratio and concentration of small grains at one pressure.

    python -m pardem.drivers.mixture [--config deck.toml] [--set section.key=value ...]
        [--ratios 1,1.2,1.4,2] [--concentrations 0.25,0.5,0.75] [--basis number|volume]
        [--realisations 3] [--pressure 1e5] [--mean-radius 1e-4] [--quick] [--out DIR]
    mpiexec -n 2 python -m pardem.drivers.mixture ...      (the cases are spread over the ranks)

Each case prepares a frictionless packing of ``sample.n`` grains of two radii (number-mean radius
``--mean-radius``) by the isotropic protocol at ``--pressure`` and measures coordination (with and
without rattlers), solid fraction, fabric, order (psi6 in 2D, Q6 in 3D), g(r), the normal-force
distribution and the moduli K and mu (``pardem.protocols.mixture_study``). ``--set
domain.dimension=2`` runs the study in 2D.

Writes ``DIR/mixture.json`` (``points``: per (ratio, concentration) the mean and standard
deviation of every measure over the realisations, the mean g(r) and force density; ``cases``: every
case's record; ``meta``), ``DIR/mixture.png`` and ``DIR/mixture_structure.png`` (with matplotlib),
the record of each finished case in ``DIR/records/rank-<r>.jsonl`` (``--restart DIR`` continues
from them), and prints the table. Results do not depend on the number of ranks (each case runs
alone on one rank).

The deck: ``drivers/mixture_study.toml`` is the built-in default (the isotropic deck's keys).
Runtime: a 3D case of 1,000 grains takes a few minutes on one core; ``--quick`` (100 grains,
ratios 1 and 1.4, c = 0.5, 2 realisations) about a minute.

Exit codes: 0 done (cases whose preparation did not converge are flagged and left out of the
means), 1 unexpected error (all ranks stop), 2 bad input (one line naming the option or deck field).
"""
import os
import sys
import time

import pardem
from pardem.config import check_deck
from pardem.drivers import cli
from pardem.drivers.cli import (add_study_options, driver_parser, option_number, option_numbers, plain_json,
                                study_restart)
from pardem.drivers.runner import StudyDriver, protocol_main
from pardem.io.records import RecordLog, start_study_folder
from pardem.parallel import task_farm
from pardem.protocols import isotropic as iso
from pardem.protocols import stages
from pardem.protocols import mixture_study as study

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STUDY_DECK = os.path.join(ROOT, "drivers", "mixture_study.toml")
DEFAULTS = {"ratios": "1,1.2,1.4,2", "concentrations": "0.25,0.5,0.75", "basis": "number",
            "realisations": "3", "pressure": "1e5", "mean_radius": "1e-4"}
QUICK = {"ratios": "1,1.4", "concentrations": "0.5", "realisations": "2"}
QUICK_SET = ["sample.n=100"]


def parser(comm=None):
    p = driver_parser("python -m pardem.drivers.mixture", __doc__.split("\n\n")[0], iso.SCHEMA,
                      run_options=False, comm=comm, out_default="runs/mixture-<timestamp>",
                      deck_title="deck keys and defaults of the isotropic deck (the study's own defaults are "
                                 "in drivers/mixture_study.toml; sample.radii, sample.fractions and "
                                 "preparation.pressures are set by the study)")
    p.add_argument("--ratios", metavar="LIST", help=f"size ratios R_large / R_small, each in [1, 10] "
                                                     f"(default {DEFAULTS['ratios']})")
    p.add_argument("--concentrations", metavar="LIST",
                   help=f"concentrations of the small grains, each in [0, 1] (default {DEFAULTS['concentrations']})")
    p.add_argument("--basis", choices=("number", "volume"),
                   help="the concentrations are by number or by volume (area in 2D) (default number)")
    p.add_argument("--realisations", metavar="N", help="packings per point, in [1, 1000] (default 3)")
    p.add_argument("--pressure", metavar="PA", help="the pressure p0 [Pa], in [1, 1e9] (default 1e5)")
    p.add_argument("--mean-radius", metavar="M", dest="mean_radius",
                   help="number-mean radius of the grains [m], in [1e-9, 1] (default 1e-4)")
    return add_study_options(
        p, quick_help="a small study for tests: 100 grains, ratios 1,1.4, c = 0.5, 2 realisations",
        plot_help="do not draw the figures",
        restart_help="continue the study whose output is DIR: the cases recorded in DIR/records are not run "
                     "again; the same deck and options are required; the results go to a new folder (--out, "
                     "default DIR-restart-<time>)")


def make_plan(args, deck):
    """The plan from the options and the checked deck; DeckError on a bad option."""
    opt = {**DEFAULTS, **(QUICK if args.quick else {})}
    for k in DEFAULTS:
        if getattr(args, k) is not None:
            opt[k] = getattr(args, k)
    return study.Plan(ratios=option_numbers("--ratios", opt["ratios"], 1.0, 10.0),
                      concentrations=option_numbers("--concentrations", opt["concentrations"], 0.0, 1.0),
                      basis=opt["basis"],
                      realisations=option_number("--realisations", opt["realisations"], 1, 1000, integer=True),
                      pressure=option_number("--pressure", opt["pressure"], 1.0, 1e9),
                      mean_radius=option_number("--mean-radius", opt["mean_radius"], 1e-9, 1.0),
                      n=int(deck["sample"]["n"]), dimension=stages.dimension(deck), seed=int(deck["sample"]["seed"]))


class Mixture(StudyDriver):
    """The mixture study: a task farm of isotropic preparations over (ratio, concentration,
    realisation); summary ``mixture.json``."""
    name = "mixture"
    schema = iso.SCHEMA
    summary_name = "mixture.json"

    def read_deck(self, run):
        """The deck and the plan; on ``--restart DIR``, the cases recorded there (the same deck and
        plan required)."""
        comm, args = run.comm, run.args
        deck = cli.read_deck(comm, iso.SCHEMA, args, overrides=QUICK_SET if args.quick else [],
                             default_config=STUDY_DECK, check=lambda deck: self.plan_of(run, deck))
        self.header = plain_json({"deck": deck, "plan": self.plan.__dict__})
        self.finished = ({r["id"]: r for r in study_restart(comm, args.restart, self.header, "a mixture study")
                          if "id" in r} if args.restart else {})
        return deck

    def plan_of(self, run, deck):
        """The plan and its cases from the options and the deck; DeckError if a case's deck fails
        the isotropic checks (sizes, memory)."""
        self.plan = make_plan(run.args, deck)
        self.cases = self.plan.cases()
        for case in self.cases:
            check_deck(iso.SCHEMA, study.case_deck(deck, self.plan, case))

    def build(self, run):
        comm, args = run.comm, run.args
        self.plot = not args.no_plot and _have_matplotlib(comm)
        return self.plan

    def start(self, run):
        comm, plan, cases, finished, out = run.comm, self.plan, self.cases, self.finished, run.out
        if comm.is_root:
            start_study_folder(out, self.header, finished)
            print(f"pardem {pardem.__version__}: mixture study, {len(cases)} packings of {plan.n} grains "
                  f"({plan.dimension}D) on {comm.size} rank(s) at p0 = {plan.pressure:g} Pa: R_l/R_s "
                  f"{','.join(f'{r:g}' for r in plan.ratios)}, {plan.basis} concentration of small grains "
                  f"{','.join(f'{c:g}' for c in plan.concentrations)}, {plan.realisations} realisation(s); "
                  f"output {out}", flush=True)
            if finished:
                print(f"restart: {len(finished)} of {len(cases)} cases recorded in {run.args.restart} are not "
                      f"run again", flush=True)
        comm.barrier()

    def execute(self, run):
        comm, args, deck, plan = run.comm, run.args, run.deck, self.plan
        log = RecordLog(run.out, comm.rank)
        case_comm = comm.split_self()
        done = [0]

        def run_one(case):
            rec = study.run_case(case_comm, deck, plan, case)
            done[0] += 1
            if not args.quiet and comm.is_root:
                print(f"[rank 0, case {done[0]}] {rec['id']}: {rec['status']}, Z = {rec['Z']:.3f}, "
                      f"phi = {rec['solid_fraction']:.4f}, {rec['order_name']} = {rec['order']:.3f} "
                      f"({rec['seconds']:.1f} s, {time.perf_counter() - run.t_start:.0f} s elapsed)", flush=True)
            return rec

        self.records = task_farm.run_cases(comm, self.cases, run_one, finished=self.finished, key=study.case_id,
                                           on_record=log.append)

    def summary(self, run):
        if not run.comm.is_root:
            return {}
        records = self.records
        summary = study.summarise(records, self.plan)
        summary["meta"] = {"pardem_version": pardem.__version__, "driver": "mixture", "n_ranks": run.comm.size,
                           "wall_seconds": time.perf_counter() - run.t_start, "restarted_from": run.args.restart,
                           "cases_reused": len(self.finished), "failed_cases": self.failed(),
                           "statistics": "mean and sample standard deviation (ddof = 1) over the realisations "
                                         "whose preparation converged", "deck": run.deck}
        summary["cases"] = records
        return summary

    def failed(self):
        return [r["id"] for r in self.records if r["status"] != "ok"]

    def finish(self, run, summary):
        out, records, failed = run.out, self.records, self.failed()
        print(study.format_table(summary))
        written = ["mixture.json"]
        if self.plot:
            from pardem.io.mixture_plot import plot_structure, plot_summary
            plot_summary(summary, os.path.join(out, "mixture.png"))
            plot_structure(summary, os.path.join(out, "mixture_structure.png"))
            written += ["mixture.png", "mixture_structure.png"]
        if failed:
            print(f"warning: {len(failed)} of {len(records)} preparations did not converge ({', '.join(failed)}); "
                  f"they are left out of the means", file=sys.stderr)
        print(f"wrote {', '.join(os.path.join(out, w) for w in written)} in "
              f"{summary['meta']['wall_seconds']:.1f} s", flush=True)
        return cli.EXIT_OK


def _have_matplotlib(comm):
    try:
        import matplotlib  # noqa: F401
        return True
    except ImportError:
        if comm.is_root:
            sys.stderr.write("pardem: note: matplotlib is not installed, so no figures (pip install 'pardem[plot]')\n")
        return False


def main(argv=None):
    return protocol_main(Mixture, parser, argv)


if __name__ == "__main__":
    sys.exit(main())
