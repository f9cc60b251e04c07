"""Command-line plumbing shared by the drivers: options, deck loading, exit codes.

Exit codes: 0 success; 2 bad input (deck, options, time step) with one line on stderr;
3 the run became unstable; 1 unexpected error (all ranks are aborted).
"""
import argparse
import sys

from pardem.config import DeckError, describe, load_deck

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_UNSTABLE = 0, 1, 2, 3


def driver_parser(prog, description, schema, run_options=True):
    """The common options; ``run_options`` adds ``--steps`` and ``--restart`` (time-stepping drivers)."""
    p = argparse.ArgumentParser(
        prog=prog, description=description,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="deck keys and defaults:\n" + describe(schema) +
               "\n\nexit codes: 0 ok, 1 unexpected error, 2 bad input, 3 unstable run")
    p.add_argument("--config", metavar="FILE.toml", help="input deck (TOML); defaults fill the rest")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                   dest="overrides", help="override one deck key (repeatable, applied after --config)")
    p.add_argument("--out", metavar="DIR", help="output directory")
    if run_options:
        p.add_argument("--steps", type=int, metavar="N",
                       help="total steps of the run from its start, also on restart (default: from the deck)")
        p.add_argument("--restart", metavar="CHECKPOINT.h5",
                       help="continue the run of this checkpoint; its deck is used unless --config is "
                            "given, and --set may change run length, output, checkpoint and parallel "
                            "settings")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


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
