"""Anisotropy study: domain anisotropy degrees against bond ratios, four laws, ordered and compact domains.

    python -m pardem.drivers.anisotropy [--config deck.toml] [--set section.key=value ...]
        [--kinds ordered,compact] [--laws TOR,hankinson,linear,spherical] [--ratios 1,5,10,15,20,25]
        [--realisations 10] [--xi-step 10] [--offaxis-ratio Q] [--transits 4] [--quick] [--out DIR]
    mpiexec -n 2 python -m pardem.drivers.anisotropy ...      (cases are spread over the ranks)

Writes ``DIR/anisotropy.json``, ``DIR/anisotropy.png`` (with matplotlib), per case
``DIR/series/<case>.csv`` and ``.h5`` (compress's columns, with units) and, when the deck's
``output.vtk_every`` > 0, ``DIR/paraview/<case>/pardem.pvd``, the record of each finished case in
``DIR/records/rank-<r>.jsonl`` (``--restart DIR`` continues from them), and prints the table; see
``pardem.protocols.anisotropy_study`` for what is run and how. JSON layout: ``data[kind][law]`` = one row per
bond ratio with ``bond_LR``, ``bond_LT`` (bond ratios), ``LR_mean``, ``LR_std``, ``LT_mean``, ``LT_std``
(the domain's E_L^D/E_R^D and E_L^D/E_T^D over the realisations), ``E_{L,R,T}_{mean,std}`` [Pa],
``n_realisations``, ``n_failed``; ``data["off_axis"][kind][law]`` = one row per tilt with ``xi_deg``,
``E_mean``, ``E_std``, ``E_hankinson``, ``E_orthotropic_fit``, ``E_orthotropic_lattice`` (ordered) [Pa]
(``anisotropy_study.summarise``), ``n_failed``, ``statuses``; ``data["meta"]`` = the deck,
the plan, ranks, wall time and every case's record (``cases``: moduli per realisation, status,
diagnostics). A failed measurement is null in the rows and counted in ``n_failed``.

The deck: ``drivers/anisotropy_study.toml`` is the built-in default (used when ``--config`` is not
given; ``--set`` applies on top). Its ``bonds.young`` gives E_R and E_T; E_L = ratio * E_R.

Runtime of the full default (4 laws x 6 ratios x 3 axes, off-axis 0..90 by 10 deg: 108 compressions
per domain, 8 transits each), measured on the shared 2-core development machine before the off-axis
ordered cases were loaded by their shear wave: the ordered lattice (1,331 elements) about 2.5 min on
one core (2.2 min on 2 ranks; its off-axis cases now take about 6 times longer each,
``anisotropy_study.transit_factor``); one compact realisation (about 1,480
elements, its 3 packings included) about 17 min on one core, 60 % of it the spherical law's cases: W's
spherical law scales the study's isotropic bond radius ratio too (a scalar is the equal triple under
every law, ``pardem.physics.anisotropy``), by up to sqrt(3), which makes those bonds up to 15 times
stiffer in bending and the step shorter (``--laws TOR,hankinson,linear,spherical_normalised``: about
8 min). The full default with 10 realisations: estimated 1.5 h on 2 ranks. ``--quick`` (boxes of 18 radii, ratios 1 and 5, 2
realisations, xi = 0, 45, 90) takes about 10 s for the ordered lattice and a few minutes for the
compact domains; restrict it further (``--laws hankinson --ratios 1 --xi-step 0``: 10 s) for a smoke
test.

Exit codes: 0 done (failed measurements are flagged in the output, not errors), 1 unexpected error
(all ranks stop), 2 bad input (one line naming the option or deck field and the allowed values).
"""
import contextlib
import os
import sys
import time
from dataclasses import asdict

import numpy as np

import pardem
from pardem.protocols import anisotropy_study as study
from pardem.drivers import cli
from pardem.drivers.cli import (add_study_options, driver_parser, option_names, option_number, option_numbers,
                                plain_json, study_restart)
from pardem.drivers.runner import StudyDriver, protocol_main
from pardem.protocols.compression import build_case
from pardem.config import DeckError
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.io.paraview import ParaViewWriter
from pardem.io.records import RecordLog, start_study_folder
from pardem.io.series import SeriesCSV
from pardem.io.series_h5 import SeriesH5


def parser(comm=None):
    p = driver_parser("python -m pardem.drivers.anisotropy", __doc__.split("\n\n")[0], COMPRESS_SCHEMA,
                      run_options=False, comm=comm, out_default="runs/anisotropy-<timestamp>",
                      deck_title="deck keys and defaults of the compress deck (the study's own defaults "
                                 "are in drivers/anisotropy_study.toml)")
    p.add_argument("--kinds", metavar="LIST", help="domain kinds, comma-separated: ordered, compact "
                                                    "(default: both)")
    p.add_argument("--laws", metavar="LIST", help=f"anisotropy laws, comma-separated: "
                                                  f"{', '.join(study.ALL_LAWS)} (default: {','.join(study.LAWS)})")
    p.add_argument("--ratios", metavar="LIST", help="bond ratios E_L/E_R, each > 0 "
                                                     "(default: 1,5,10,15,20,25)")
    p.add_argument("--realisations", metavar="N", help="compact realisations (default 10; the ordered "
                                                        "lattice runs once)")
    p.add_argument("--xi-step", metavar="DEG", dest="xi_step",
                   help="off-axis tilt step dividing 90 (default 10; 0 = no off-axis sweep)")
    p.add_argument("--offaxis-ratio", metavar="Q", dest="offaxis_ratio",
                   help="E_L/E_R of the off-axis sweep (default: the largest of --ratios)")
    p.add_argument("--transits", metavar="N", help=f"loading time in axial wave transits, in [1, 1000] "
                                                   f"(default {study.DEFAULT_TRANSITS:g})")
    p.add_argument("--steps", metavar="N",
                   help="run each case for at most N steps (smoke tests: a case too short to measure is "
                        "flagged, not reported; default: the case's loading from --transits)")
    return add_study_options(
        p, quick_help="a small study for tests: boxes of 18 radii, ratios 1,5, 2 realisations, xi step 45",
        plot_help="do not write anisotropy.png",
        restart_help="continue the study whose output is DIR (killed or stopped): the cases recorded in "
                     "DIR/records are not run again; the same deck and options are required; the results go "
                     "to a new folder (--out, default DIR-restart-<time>) that holds every record")


def make_plan(args, deck):
    """The study plan from the options and the checked deck; DeckError on a bad option."""
    kinds = study.KINDS if args.kinds is None else option_names("--kinds", args.kinds, study.KINDS)
    laws = study.LAWS if args.laws is None else option_names("--laws", args.laws, study.ALL_LAWS)
    quick = study.QUICK_PLAN if args.quick else {}
    if args.ratios is not None:
        ratios = option_numbers("--ratios", args.ratios, 1e-3, 1e4)
    else:
        ratios = quick.get("ratios", study.DEFAULT_RATIOS)
    realisations = (option_number("--realisations", args.realisations, 1, 1000, integer=True)
                    if args.realisations is not None else quick.get("realisations", 10))
    xi_step = option_number("--xi-step", args.xi_step, 0, 90) if args.xi_step is not None else quick.get("xi_step", 10.0)
    if xi_step and abs(90.0 / xi_step - round(90.0 / xi_step)) > 1e-9:
        raise DeckError(f"--xi-step {args.xi_step}: expected 0 or a step in (0, 90] dividing 90 (e.g. 5, 10, 15, 45)")
    q_off = (option_number("--offaxis-ratio", args.offaxis_ratio, 1e-3, 1e4) if args.offaxis_ratio is not None
             else max(ratios))
    transits = (option_number("--transits", args.transits, 1, 1000) if args.transits is not None
                else study.DEFAULT_TRANSITS)
    steps = option_number("--steps", args.steps, 1, 1e10, integer=True) if args.steps is not None else None
    E_R, E_T = study.bond_moduli(deck)
    return study.StudyPlan(kinds=kinds, laws=laws, ratios=ratios, E_R=E_R, E_T=E_T,
                           realisations=realisations, xi_step=xi_step, offaxis_ratio=q_off,
                           transits=transits, base_seed=int(deck["domain"].get("seed", 0)), steps=steps)


def main(argv=None):
    return protocol_main(Anisotropy, parser, argv)


def _finite_or_none(obj):
    """JSON without NaN/inf: undefined numbers become null."""
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_none(v) for v in obj]
    if isinstance(obj, (float, np.floating)) and not np.isfinite(obj):
        return None
    return obj


class Anisotropy(StudyDriver):
    """The anisotropy study: a task farm of compressions over (kind, law, ratio, axis or tilt,
    realisation); summary ``anisotropy.json``."""
    name = "anisotropy"
    schema = COMPRESS_SCHEMA
    summary_name = "anisotropy.json"

    def read_deck(self, run):
        """The deck and the plan; on ``--restart DIR``, the cases recorded there (the same deck and
        plan required)."""
        comm, args = run.comm, run.args
        deck = cli.read_deck(comm, COMPRESS_SCHEMA, args, overrides=study.QUICK_SET if args.quick else [],
                             base=None if args.config else study.STUDY_DECK,
                             check=lambda deck: setattr(self, "plan", make_plan(args, deck)))
        self.header = plain_json({"deck": deck, "plan": asdict(self.plan)})
        self.finished = {}
        if args.restart:
            self.finished = {study.case_id(r): r for r in study_restart(comm, args.restart, self.header,
                                                                        "an anisotropy study")}
        return deck

    def build(self, run):
        """Refuse an unusable deck before any case runs: the rank that will run realisation 0 of
        each kind builds its domains (loaded along x, y, z) and keeps the packings for it."""
        comm, deck, plan, args = run.comm, run.deck, self.plan, run.args
        self.case_comm = comm.split_self()
        self.packings = {}
        for kind in plan.kinds:
            root, problem = study.owner(plan, comm.size, kind, 0), None
            if comm.rank == root:
                try:
                    for axis in study.AXES:
                        first = study.Case(kind, 0, plan.laws[0], plan.ratios[0], axis)
                        self.packings[kind, 0, axis] = study.realisation_packing(deck, plan, first)
                        build_case(self.case_comm, study.case_deck(deck, plan, first),
                                   packing=self.packings[kind, 0, axis])
                except DeckError as err:
                    problem = str(err)
            problem = comm.bcast(problem, root=root)
            if problem:
                raise DeckError(problem)
        self.plot = not args.no_plot
        if self.plot and comm.is_root:
            try:
                import matplotlib  # noqa: F401
            except ImportError:
                self.plot = False
                sys.stderr.write("pardem: note: matplotlib is not installed, so no anisotropy.png "
                                 "(pip install 'pardem[plot]')\n")
        return plan

    def start(self, run):
        comm, plan, out, finished = run.comm, self.plan, run.out, self.finished
        self.n_cases = n_cases = sum(len(g) for g in study.plan_cases(plan))
        if comm.is_root:
            start_study_folder(out, self.header, finished)
        comm.barrier()
        if comm.is_root:
            print(f"pardem {pardem.__version__}: anisotropy study, {n_cases} compressions on {comm.size} "
                  f"rank(s): kinds {','.join(plan.kinds)}, laws {','.join(plan.laws)}, E_L/E_R "
                  f"{','.join(f'{q:g}' for q in plan.ratios)} (E_R = {plan.E_R / 1e6:g} MPa, E_T = "
                  f"{plan.E_T / 1e6:g} MPa), off-axis xi {','.join(f'{x:g}' for x in plan.xis()) or 'none'} "
                  f"at E_L/E_R = {plan.offaxis_ratio:g}; output {out}", flush=True)

    def execute(self, run):
        comm, args, out = run.comm, run.args, run.out
        log = RecordLog(out, comm.rank)
        progress = None if args.quiet else _progress(time.perf_counter())
        if self.finished and comm.is_root:
            print(f"restart: {len(self.finished)} of {self.n_cases} cases recorded in {args.restart} are not run "
                  f"again", flush=True)
        self.records = study.run_study(comm, self.case_comm, run.deck, self.plan, progress, self.packings,
                                       finished=self.finished, on_record=log.append,
                                       outputs=_case_outputs(out, self.case_comm, run.deck["output"]["vtk_every"]))

    def summary(self, run):
        if not run.comm.is_root:
            return {}
        records, plan, deck = self.records, self.plan, run.deck
        data = study.summarise(records, plan, deck)
        failed = [r for r in records if r["status"] != "ok"]
        data["meta"] = {
            "pardem_version": pardem.__version__, "driver": "anisotropy", "n_ranks": run.comm.size,
            "wall_seconds": time.perf_counter() - run.t_start, "plan": asdict(plan), "xi_deg": plan.xis(),
            "n_cases": len(records), "n_failed_cases": len(failed),
            "restarted_from": run.args.restart, "cases_reused": len(self.finished),
            "ordered": "the ordered lattice is deterministic: each of its cases ran once, so its std is 0",
            "statistics": "mean and sample standard deviation (ddof = 1) over the realisations whose L, R "
                          "and T compressions all succeeded; ratios are taken per realisation",
            "off_axis": "every law at bond ratio offaxis_ratio, compression along x with the LRT frame "
                        "tilted by xi about z (ordered: the grid tilts, its faces under the plates made flat); "
                        "E_hankinson from the E_mean of xi = 0 and xi = 90; E_orthotropic_fit: 1/E = c^4/E0 + "
                        "s^4/E90 + K s^2 c^2 with K fitted (least squares of 1/E) to the inner angles; E_orthotropic_lattice (ordered): the "
                        "same with E_L, E_R, K = 1/G_LR of the infinite lattice's beam theory (nu_LR = 0)",
            "status": "ok, or lost_contact (a plate stopped pushing), rotated (the loaded faces did not stay "
                      "normal to the load: the domain turned or slid between the frictionless plates), dynamic (the plate "
                      "forces, or the slopes over the two halves of the fitted phase, still disagree after "
                      "the slower retries), unstable, bad_input (e.g. a packing the builder refused)",
            "deck": deck, "cases": records,
        }
        self.data = data
        return _finite_or_none(data)

    def finish(self, run, summary):
        records, plan, out, data = self.records, self.plan, run.out, self.data
        failed = [r for r in records if r["status"] != "ok"]
        print(study.format_table(data, plan))
        written = ["anisotropy.json"]
        if self.plot:
            from pardem.io.anisotropy_plot import plot_study
            plot_study(data, plan, os.path.join(out, "anisotropy.png"))
            written.append("anisotropy.png")
        if failed:
            kinds = sorted({r["status"] for r in failed})
            print(f"warning: {len(failed)} of {len(records)} compressions are not valid measurements "
                  f"({', '.join(kinds)}); they are left out of the statistics", file=sys.stderr)
        print(f"wrote {' and '.join(os.path.join(out, w) for w in written)} in "
              f"{data['meta']['wall_seconds']:.1f} s", flush=True)
        return cli.EXIT_OK


def _case_outputs(out, case_comm, vtk_every):
    """``outputs`` of ``anisotropy_study.run_case``: per case ``DIR/series/<case>.csv`` and ``.h5``
    (compress's columns and units) written by the rank running it, and ``DIR/paraview/<case>/``
    when ``output.vtk_every`` > 0."""
    @contextlib.contextmanager
    def outputs(case, name, sim):
        folder = os.path.join(out, "series")
        os.makedirs(folder, exist_ok=True)
        with contextlib.ExitStack() as files:
            csv = SeriesCSV(os.path.join(folder, f"{name}.csv"))
            files.callback(csv.close)
            h5 = SeriesH5(os.path.join(folder, f"{name}.h5"))
            files.callback(h5.close)
            # one sim.run per case: its last step too
            ops = [ParaViewWriter(os.path.join(out, "paraview", name), case_comm, vtk_every, dt=sim.dt,
                                  at_end=True)] if vtk_every else []
            yield [csv.append, h5.append], ops
    return outputs


def _progress(t0):
    def report(done, total, rec):
        E = rec["E"] / 1e6 if np.isfinite(rec["E"]) else float("nan")
        print(f"[rank 0 {done:>4d}/{total}] {rec['kind']} {rec['law']} E_L/E_R = {rec['ratio']:g} "
              f"along {rec['axis']}, tilt {rec['tilt_deg']:g}, realisation {rec['realisation']}: "
              f"E = {E:.4g} MPa {rec['status']} ({rec['seconds']:.2f} s, {time.perf_counter() - t0:.0f} s "
              f"elapsed)", flush=True)
    return report


if __name__ == "__main__":
    sys.exit(main())
