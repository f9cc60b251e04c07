"""Command-line plumbing shared by the drivers: options, deck loading, exit codes.

Exit codes: 0 success; 2 bad input (deck, options, time step) with one line on stderr;
3 the run became unstable; 4 the run ended but was too short to measure its result (its files are
written); 1 unexpected error (all ranks are aborted).
"""
import argparse
import datetime
import os
import sys

from pardem.config import DeckError, describe, load_deck
from pardem.parallel.communicator import report_and_abort
from pardem.engine.errors import InstabilityError

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_UNSTABLE, EXIT_NOT_MEASURED = 0, 1, 2, 3, 4


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
               "\n\nexit codes: 0 ok, 1 unexpected error, 2 bad input, 3 unstable run, "
               "4 run too short to measure its result")
    p.comm = comm
    p.add_argument("--config", metavar="FILE.toml", help="input deck (TOML); defaults fill the rest")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                   dest="overrides", help="override one deck key (repeatable, applied after --config)")
    p.add_argument("--out", metavar="DIR",
                   help="output directory" + (f" (default {out_default})" if out_default else ""))
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


def run_driver(comm, run, args):
    """``run(comm, args)`` with the drivers' failure policy: an unstable run ends with one line and
    exit code 3 on every rank; any other exception is printed and aborts every rank (none hangs)."""
    try:
        return run(comm, args)
    except SystemExit:
        raise
    except InstabilityError as err:
        if comm.is_root:
            sys.stderr.write(f"pardem: error: the run became unstable: {err}; reduce the time step or check "
                             f"the stiffness and damping; the last checkpoint (if any) is intact\n")
        raise SystemExit(EXIT_UNSTABLE)
    except Exception as exc:  # noqa: BLE001 - any other failure must end every rank
        report_and_abort(comm, exc)


def fail_usage(comm, message):
    """Print one line (rank 0 only) and exit with status 2 on every rank."""
    if comm is None or comm.is_root:
        sys.stderr.write(f"pardem: error: {message}\n")
    raise SystemExit(EXIT_USAGE)


def read_deck(comm, schema, args, base=None):
    """The checked deck of ``--config`` (or ``base``) and ``--set``; exits 2 on bad input."""
    try:
        steps = getattr(args, "steps", None)
        if steps is not None and steps < 1:
            raise DeckError(f"--steps {steps}: expected an integer >= 1")
        return load_deck(schema, args.config, args.overrides, base=base)
    except DeckError as err:
        fail_usage(comm, str(err))


def default_out(comm, driver, restart):
    """``runs/<driver>-<timestamp>``, or the run directory of the checkpoint being continued."""
    if restart:
        parent = os.path.dirname(os.path.abspath(restart))
        if os.path.basename(parent) == "checkpoints":
            return os.path.dirname(parent)
    stamp = comm.bcast(datetime.datetime.now().strftime("%Y%m%d-%H%M%S"))
    return os.path.join("runs", f"{driver}-{stamp}")
