"""Command-line plumbing shared by the drivers: options, deck loading, output folder, signals,
exit codes.

Exit codes: 0 success; 2 bad input (deck, options, time step, output path) with one line on
stderr; 3 the run became unstable; 4 a result could not be written (disk full, permission denied,
read-only or over quota), one line; 5 the run ended but was too short to measure its result (its
files are written); 128 + N stopped by signal N (143 SIGTERM, 130 SIGINT, 138 SIGUSR1); 1 unexpected
error or a silent rank (the watchdog), all ranks are aborted. A rank killed by SIGKILL (``kill -9``,
the kernel's out-of-memory killer) can say nothing: mpiexec.mpich then kills the other ranks at once
with SIGKILL too (no handler runs; it prints its own "BAD TERMINATION ... EXIT CODE: 9" banner) and
exits 9 (srun: 137); the checkpoints written before are intact (atomic writes). Under
``mpiexec.mpich -disable-auto-cleanup`` the other ranks live on and the watchdog names the dead
rank after its limit, then aborts the job.

Signals (``stop_signals``): SIGTERM, SIGINT and SIGUSR1 only record a stop request
(``pardem.engine.stop``); the time loop reduces it over ranks every ``check_every`` steps and
raises ``Interrupted`` on every rank at the same step, so the driver can write a final checkpoint
and its summary. A signal before this run's first time step (building the case: nothing to save)
ends the process at once, as does the same signal again while stopping (after ``REPEAT_SECONDS``,
so that one signal delivered twice counts once). mpiexec (hydra) forwards SIGTERM, SIGINT and
SIGUSR1 to every rank; Slurm sends SIGTERM to every task at ``scancel`` and at the time limit, then
SIGKILL after ``KillWait`` (30 s by default), and ``#SBATCH --signal=TERM@300`` sends it 300 s early.
"""
import argparse
import datetime
import errno
import json
import os
import signal
import sys
import time

from pardem.config import DeckError, choice, describe
from pardem.io.deck_file import load_deck
from pardem.engine import stop
from pardem.errors import InstabilityError, Interrupted, OutputError
from pardem.io import checkpoint_writer, progress, run_folder
from pardem.io.records import header_difference, read_records, read_study_header
from pardem.parallel import layout, watchdog
from pardem.parallel.communicator import exit_now, report_and_abort
from pardem.protocols import deck_checks
from pardem.protocols import granular_output as gout

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_UNSTABLE, EXIT_OUTPUT, EXIT_NOT_MEASURED = 0, 1, 2, 3, 4, 5
EXIT_SIGNAL = 128              # + the signal number
MAX_STEPS = 10 ** 10           # --steps above this is refused (a typo, not a run)
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1)
REPEAT_SECONDS = 1.0           # the same signal again after this long while stopping ends at once
OUTPUT_ERRNOS = {errno.ENOSPC: "No space left on device", errno.EACCES: "Permission denied",
                 errno.EROFS: "Read-only file system", errno.EDQUOT: "Disk quota exceeded"}


class DriverParser(argparse.ArgumentParser):
    """Bad options end with one line on rank 0 and exit code 2 on every rank."""
    comm = None

    def error(self, message):
        fail_usage(self.comm, f"{message} (see --help)")


def driver_parser(prog, description, schema, run_options=True, comm=None,
                  deck_title="deck keys and defaults", out_default="", epilog="", steps_help=None,
                  restart_help=None):
    """The common options (``--config``, ``--set``, ``--out``, ``--quiet``, ``--help``);
    ``run_options`` adds ``--steps`` and ``--restart`` (drivers of one restartable run; their help
    text may be the driver's own). ``schema`` is described in the epilog under ``deck_title``,
    then ``epilog``."""
    p = DriverParser(
        prog=prog, description=description,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"{deck_title}:\n" + describe(schema) + (f"\n\n{epilog}" if epilog else "") +
               "\n\nexit codes: 0 ok, 1 unexpected error or a silent rank, 2 bad input, 3 unstable run, "
               "4 results could not be written (disk full, no permission), 5 run too short to measure its "
               "result, 128 + N stopped by signal N (143 SIGTERM, 130 SIGINT); mpiexec's 9 (srun's 137): a "
               "rank was killed (kill -9, out of memory), the earlier checkpoints are intact")
    p.comm = comm
    p.add_argument("--config", metavar="FILE.toml", help="input deck (TOML); defaults fill the rest")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                   dest="overrides", help="override one deck key (repeatable, applied after --config)")
    p.add_argument("--out", metavar="DIR",
                   help="output directory, of this run alone" + (f" (default {out_default})" if out_default else ""))
    p.add_argument("--overwrite", action="store_true",
                   help="replace the results of an earlier run found in --out (otherwise refused)")
    if run_options:
        p.add_argument("--steps", type=int, metavar="N",
                       help=steps_help or "total steps of the run from its start, also on restart "
                                          "(default: from the deck)")
        p.add_argument("--restart", metavar="CHECKPOINT.h5",
                       help=restart_help or "continue the run of this checkpoint; its deck is used unless "
                                            "--config is given, and --set may change run length, output, "
                                            "checkpoint and parallel settings")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def granular_parser(name, doc, schema, restart_may_change, outputs, comm=None,
                    deck_title="deck keys and defaults", steps_note=""):
    """``driver_parser`` of the granular driver ``name`` (``python -m pardem.drivers.<name>``, the
    first paragraph of its ``doc``, output ``runs/<name>-<timestamp>``): the granular ``--steps``
    help (then ``steps_note``), the ``--restart`` help of ``restart_may_change``, and ``outputs``
    listed in the epilog."""
    return driver_parser(f"python -m pardem.drivers.{name}", doc.split("\n\n")[0], schema, comm=comm,
                         steps_help=gout.STEPS_HELP + steps_note,
                         restart_help=gout.restart_help(restart_may_change),
                         out_default=f"runs/{name}-<timestamp>", deck_title=deck_title,
                         epilog=f"outputs: {outputs}")


def run_driver(comm, run, args):
    """``run(comm, args)`` with the drivers' failure policy, stop signals (``stop_signals``) and
    the watchdog (``pardem.parallel.watchdog``; the deck's ``run.watchdog_seconds`` via
    ``read_deck``). An unstable run ends with one line and exit code 3 on every rank; a stop signal
    with one line and 128 + N; a result that cannot be written with one line and 4; any other
    exception is printed and aborts every rank (none hangs)."""
    stop.clear()
    checkpoint_writer.forget()
    previous = stop_signals(comm)
    watchdog.start(comm, watchdog.DEFAULT_SECONDS)
    try:
        code = run(comm, args)
        if stop.requested() and comm.is_root:
            sys.stderr.write(f"pardem: {_signal_name(stop.requested())} arrived after the last time step; "
                             f"the run is complete\n")
        return code
    except SystemExit:
        raise
    except Interrupted as err:
        code = EXIT_SIGNAL + err.signum
        if comm.is_root:
            sys.stderr.write(interrupted_line(err) + "\n")
        if comm.size > 1:
            # every rank is here (Interrupted is raised on all at one step). mpiexec.mpich reported
            # a job whose ranks all exited 128 + N normally as exit 0 in about half of the tries
            # after forwarding the signal; MPI_Abort(128 + N) always gave 128 + N. srun reports
            # the ranks' own codes (and an abort as 137): there every rank exits normally
            watchdog.stop()
            comm.barrier()
            if not comm.started_by_srun():
                if comm.is_root:
                    comm.abort(code)
                time.sleep(30.0)     # rank 0's abort ends this rank
        raise SystemExit(code)
    except InstabilityError as err:
        if comm.is_root:
            sys.stderr.write(f"pardem: error: the run became unstable: {err}; reduce the time step or check "
                             f"the stiffness and damping; {checkpoints_line(args)}\n")
        raise SystemExit(EXIT_UNSTABLE)
    except (OutputError, OSError) as err:
        reason = output_failure(err)
        if reason is None:
            report_and_abort(comm, err)
        # a write every rank failed together (a checkpoint, ParaView, the output folder) raises on
        # every rank: rank 0 writes the line and all exit; a write of one rank alone (rank 0's
        # series, summary, plots) leaves the others waiting in their next collective: that rank
        # writes the line and ends the job
        everywhere = getattr(err, "all_ranks", False) or comm.size == 1
        if comm.is_root or not everywhere:
            who = "" if comm.is_root else f"rank {comm.rank}: "
            sys.stderr.write(f"pardem: error: {who}cannot write the results: {reason}; "
                             f"{checkpoints_line(args)}\n")
        if not everywhere:
            quiet_abort(comm, EXIT_OUTPUT)
        raise SystemExit(EXIT_OUTPUT)
    except Exception as exc:  # noqa: BLE001 - any other failure must end every rank
        report_and_abort(comm, exc)
    finally:
        watchdog.stop()
        run_folder.release_all()
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def checkpoints_line(args):
    """What a user can restart from, truly: the newest checkpoint this run wrote
    (``pardem.io.checkpoint_writer.newest``), else the one it restarted from, else that there is
    none (said by the drivers that write checkpoints)."""
    writer, newest = checkpoint_writer.newest()
    writer = writer or hasattr(args, "steps")     # a driver of one restartable run, before its writer exists
    restart = getattr(args, "restart", None)
    if newest:
        return f"the last checkpoint written, {newest}, is intact: restart with --restart {newest}"
    if restart and writer:
        return f"this run wrote no checkpoint; the one it restarted from, {restart}, is intact"
    if writer:
        return "no checkpoint was written (nothing to restart from)"
    return "the files written before are kept"


def quiet_abort(comm, code):
    """End every rank with ``code`` (``MPI_Abort``) after this rank's line, without MPICH's own
    "Abort(code) on node ..." line: stderr is pointed at /dev/null once the line is out."""
    progress.silence_stderr()
    comm.abort(code)     # waits ABORT_GRACE_SECONDS: the launcher forwards the line meanwhile


def output_failure(err):
    """The one-line reason of a failed write (disk full, no permission, read-only, over quota), or
    None if ``err`` is another kind of error. h5py reports the errno only in its message."""
    if isinstance(err, OutputError):
        return str(err)
    if err.errno in OUTPUT_ERRNOS:
        return f"{err.strerror or OUTPUT_ERRNOS[err.errno]}" + (f" ({err.filename})" if err.filename else "")
    text = str(err)
    for code, message in OUTPUT_ERRNOS.items():
        if message in text or f"errno = {code}," in text:
            return f"{message} ({text.splitlines()[0][:200]})"
    return None


def interrupted_line(err):
    """The one line that ends an interrupted run. The driver's stop protocol may set
    ``err.checkpoint`` (the newest checkpoint) and ``err.final`` (it was written at the stop), or
    ``err.records`` (a study's output folder, whose records a restart continues from)."""
    head = f"pardem: stopped by {_signal_name(err.signum)} at step {err.step}"
    records = getattr(err, "records", None)
    if records:
        return f"{head}; the finished cases are recorded in {records}; restart with --restart {records}"
    ck = getattr(err, "checkpoint", None)
    if ck and getattr(err, "final", False):
        return f"{head}; final checkpoint {ck}; restart with --restart {ck}"
    if ck:
        return f"{head}; no final checkpoint (checkpoint.at_stop = false); restart with --restart {ck}"
    return f"{head}; no checkpoint written, nothing to restart from"


def _signal_name(signum):
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def stop_signals(comm):
    """Install the handlers of ``STOP_SIGNALS`` (main thread only); returns the previous ones.

    The handler only records the request (no exception raised at a random place: a
    KeyboardInterrupt inside a weakref callback or an MPI wait was lost, "Exception ignored").
    Before this run's first time step it ends the process at once (exit 128 + N, one line on rank
    0): building a case saves nothing, and waiting for the time loop could take minutes. The
    same signal again while stopping (``REPEAT_SECONDS`` after the first) also ends it at once.
    """
    first_step = watchdog.beats()

    def on_signal(signum, frame):
        first = stop.requested()
        if not first:
            stop.request(signum)
            if watchdog.beats() == first_step:
                _exit_now(comm, signum, "before the first time step; nothing to save")
        elif signum == first and stop.seconds_since() > REPEAT_SECONDS:
            _exit_now(comm, signum, "again while stopping; ended at once, the last checkpoint written is intact")

    previous = {}
    for signum in STOP_SIGNALS:
        try:
            previous[signum] = signal.signal(signum, on_signal)
        except ValueError:       # not the main thread: leave the signals alone
            break
    return previous


def _exit_now(comm, signum, why):
    exit_now(EXIT_SIGNAL + signum, comm.rank, f"stopped by {_signal_name(signum)} {why}")


def check_output(comm, args, driver):
    """Collective, before any work: the output folder this run will take (``--out``, or
    ``default_out``), checked as ``output_dir`` checks it but not created
    (``pardem.io.run_folder.probe``); a bad path or a folder in use or holding another run's
    results (without ``--overwrite``) ends with one line and exit 2. Pass the path returned to
    ``output_dir``."""
    restart = getattr(args, "restart", None)
    out = args.out if args.out is not None else default_out(comm, driver, restart)
    try:
        run_folder.probe(comm, out, overwrite=getattr(args, "overwrite", False), restart=restart)
    except DeckError as err:
        fail_usage(comm, str(err))
    return out


def output_dir(comm, args, driver, out=None):
    """Collective: the output folder of this run, checked, created and locked
    (``pardem.io.run_folder.claim``): ``out`` (from ``check_output``), else ``--out``, or
    ``default_out``. A bad path or a folder in use or holding another run's results (without
    ``--overwrite``) ends with one line and exit 2."""
    restart = getattr(args, "restart", None)
    if out is None:
        out = args.out if args.out is not None else default_out(comm, driver, restart)
    try:
        return run_folder.claim(comm, out, overwrite=getattr(args, "overwrite", False), restart=restart)
    except DeckError as err:
        fail_usage(comm, str(err))


def fail_usage(comm, message):
    """Print one line (rank 0 only) and exit with status 2 on every rank."""
    if comm is None or comm.is_root:
        sys.stderr.write(f"pardem: error: {message}\n")
    raise SystemExit(EXIT_USAGE)


def agree(comm, problem):
    """Collective: end every rank with exit 2 if any rank found a ``problem`` (a one-line message,
    or None). Rank 0 prints the first rank's message (``rank R: ...`` when the ranks disagree, e.g.
    a memory check on nodes with different free memory), so no rank goes on to wait for one that
    left."""
    problems = comm.allgather(problem) if comm is not None and comm.size > 1 else [problem]
    bad = [(r, m) for r, m in enumerate(problems) if m is not None]
    if bad:
        rank, message = bad[0]
        same = len(bad) == len(problems) and all(m == message for _, m in bad)
        fail_usage(comm, message if same else f"rank {rank}: {message}")


def read_deck(comm, schema, args, base=None, overrides=None, check=None, default_config=None):
    """Collective: the checked deck of ``--config`` (or ``default_config``, a deck file, or
    ``base``) and ``--set`` (after
    ``overrides``, e.g. a study's ``--quick`` settings); exits 2 on every rank if any rank finds bad
    input, also a DeckError of ``check(deck)`` (a driver's checks of the deck with its options;
    ``--steps`` is then the driver's to check). Its ``run.watchdog_seconds``, if the schema has it,
    sets the watchdog's limit."""
    deck, problem = None, None
    deck_checks.set_ranks_per_node(layout.ranks_on_node(comm))   # the memory check is per node
    try:
        steps = getattr(args, "steps", None)
        if check is None and steps is not None and not 1 <= steps <= MAX_STEPS:
            raise DeckError(f"--steps {steps}: expected an integer from 1 to {MAX_STEPS:.0e}")
        deck = load_deck(schema, args.config or default_config, list(overrides or []) + list(args.overrides),
                         base=base)
        if check is not None:
            check(deck)
    except DeckError as err:
        problem = str(err)
    agree(comm, problem)
    seconds = deck["run"].get("watchdog_seconds") if isinstance(deck.get("run"), dict) else None
    if seconds is not None:
        watchdog.configure(seconds)
    return deck


def default_out(comm, driver, restart):
    """``runs/<driver>-<timestamp>``; on restart a new sibling of the run being continued,
    ``<run>-restart-<timestamp>`` (``<run>`` the folder holding ``checkpoints/``, or the
    checkpoint's path without ``.h5``): a restart never writes into the original run's folder."""
    stamp = comm.bcast(datetime.datetime.now().strftime("%Y%m%d-%H%M%S"))
    if restart:
        path = os.path.abspath(restart)
        parent = os.path.dirname(path)
        run = os.path.dirname(parent) if os.path.basename(parent) == "checkpoints" else os.path.splitext(path)[0]
        return f"{run}-restart-{stamp}"
    return os.path.join("runs", f"{driver}-{stamp}")


def restarted_run(restart):
    """The output folder of the run checkpoint ``restart`` belongs to (the folder holding its
    ``checkpoints/``), or None for a checkpoint kept elsewhere: a restart continues that run's
    ParaView collections."""
    parent = os.path.dirname(os.path.abspath(restart))
    return os.path.dirname(parent) if os.path.basename(parent) == "checkpoints" else None


def option_number(name, text, lo, hi, integer=False):
    """The number of a command-line option ``name`` (text) in [lo, hi]; DeckError naming the
    option and the range otherwise."""
    try:
        v = int(text) if integer else float(text)
    except ValueError:
        v = None
    if v is None or not (v == v and abs(v) != float("inf")) or not lo <= v <= hi:
        kind = "an integer" if integer else "a number"
        raise DeckError(f"{name} {text}: expected {kind} in [{lo:g}, {hi:g}]")
    return v


def option_numbers(name, text, lo, hi):
    """Distinct numbers of a comma-separated option, each in [lo, hi], in the order given."""
    return _option_list(name, text, lambda t: option_number(name, t, lo, hi), f"numbers in [{lo:g}, {hi:g}]")


def option_names(name, text, allowed):
    """Distinct names of a comma-separated option, each one of ``allowed`` in any case (returned as
    ``allowed`` spells it), in the order given."""
    one = choice(*allowed)
    return _option_list(name, text, lambda t: one(name, t.strip()), ", ".join(allowed))


def _option_list(name, text, one, expected):
    """``one(item)`` of every item of a comma-separated option, repeats dropped; a DeckError of any
    item becomes one naming the whole option and ``expected``."""
    try:
        return tuple(dict.fromkeys(one(t) for t in text.split(",")))
    except DeckError:
        raise DeckError(f"{name} {text}: expected a comma-separated list of {expected}") from None


def add_study_options(p, quick_help, plot_help, restart_help):
    """The options of a study driver (cases spread over the ranks by ``pardem.parallel.task_farm``):
    ``--quick`` (a small study), ``--no-plot`` (``args.no_plot``) and ``--restart DIR`` (continue the
    study whose output is DIR, ``study_restart``), each with the driver's help text."""
    p.add_argument("--quick", action="store_true", help=quick_help)
    p.add_argument("--no-plot", action="store_true", dest="no_plot", help=plot_help)
    p.add_argument("--restart", metavar="DIR", help=restart_help)
    return p


def plain_json(obj):
    """``obj`` as JSON gives it back (tuples as lists, keys sorted, NaN kept): a study header as
    ``study_restart`` compares it with the stored one."""
    return json.loads(json.dumps(obj, sort_keys=True))


def study_restart(comm, directory, header, what, parts=("plan", "deck"), driver=None):
    """The records of an earlier run of the same study (a task farm) in ``directory`` (read by rank
    0, every rank gets them); exits 2 with one line if ``directory`` holds no study of ``what`` (e.g.
    "a mixture study"; with ``driver``, none whose header names that driver) or its ``parts`` of the
    header (e.g. deck and plan) differ from ``header``'s."""
    old = comm.bcast(read_study_header(directory) if comm.is_root else None)
    if old is None or (driver is not None and old.get("driver") != driver):
        of = f" of the {driver} driver" if driver is not None else ""
        fail_usage(comm, f"--restart {directory}: no study.json{of} there: not the output of {what}")
    diff = header_difference(old, header, parts)
    if diff:
        part, first, was, now = diff
        fail_usage(comm, f"--restart {directory}: the study there has another {part} ({first}: "
                         f"{was!r} there, {now!r} now): repeat its options and deck to continue it")
    return comm.bcast(read_records(directory) if comm.is_root else None)
