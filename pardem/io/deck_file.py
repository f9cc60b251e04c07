"""Deck files: read a TOML deck, apply the command line's overrides, check it (``pardem.config``
holds the schema toolkit; this module is where a deck file is opened)."""
import copy
import os
import stat

from pardem.config import DeckError, _one_line, apply_overrides, check_deck, parse_toml


def load_deck(schema, path=None, overrides=(), base=None, checks=()):
    """Read ``path`` (TOML, may be None; else start from the deck ``base``), apply overrides, check
    every field, then the schema's cross-field checks and ``checks`` (see ``check_deck``); returns a
    nested dict. ``path`` must be a regular file: a FIFO, directory or device is refused without
    opening it (opening a FIFO would block)."""
    raw = copy.deepcopy(base) if base is not None and path is None else {}
    if path is not None:
        raw = _read_toml(path)
    return check_deck(schema, apply_overrides(raw, overrides), checks)


_FILE_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
               (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
               (stat.S_ISSOCK, "a socket"))


def _read_toml(path):
    """The TOML table of the regular file ``path``; DeckError (one line) for anything else."""
    where = f"--config {path}"
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise DeckError(f"{where}: no such file") from None
    except (OSError, ValueError) as err:   # ValueError: a path with a NUL byte
        raise DeckError(f"{where}: cannot be read ({_one_line(err)})") from None
    if not stat.S_ISREG(mode):
        kind = next((text for test, text in _FILE_KINDS if test(mode)), "not a regular file")
        raise DeckError(f"{where}: cannot be read: it is {kind}, expected a regular TOML file")
    try:
        with open(path, "rb") as fh:
            text = fh.read().decode("utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise DeckError(f"{where}: cannot be read ({_one_line(err)})") from None
    return parse_toml(text, where)
