"""The output folder of a run: checked, created, and held by one run at a time.

``claim`` is collective: rank 0 checks the path, creates the folder, takes an exclusive ``fcntl``
lock on ``<folder>/.pardem.lock`` (kept until the process ends, so a second concurrent run into
the same folder is refused), and refuses a folder that holds another run's results unless
``overwrite``, which first removes exactly the entries of ``RESULTS`` (and ``RESULT_PATTERNS``) found there (nothing else:
a user's own files in the folder stay). Every rank gets the same outcome: the absolute path, or
the same ``DeckError`` (a bad path, exit 2) or ``OutputError`` (the file system refused, exit 4).
"""
import errno
import fcntl
import fnmatch
import os
import shutil

from pardem.config import DeckError
from pardem.errors import OutputError

LOCK_NAME = ".pardem.lock"
# every file or folder a pardem driver writes into its output folder (a run's results)
RESULTS = ("summary.json", "series.csv", "series.h5", "series", "checkpoints", "paraview", "records",
           "force_distribution.png", "compress_calibrated.toml", "study.json", "mixture_study.toml",
           "mixture_structure.png", "response_vtk",
           *(f"{name}.{ext}" for name in ("isotropic", "triaxial", "calibration", "calibration_history",
                                          "anisotropy", "biaxial", "response", "mixture")
             for ext in ("json", "csv", "h5", "png")))
# the numbered results (fnmatch patterns): the biaxial driver's maps per pressure and window
RESULT_PATTERNS = ("localisation-*-*.png", "localisation-*-*.vtu", "cements-*.png", "cements-*.vtu")
# pseudo-filesystems and devices: never an output folder
FORBIDDEN_ROOTS = ("/proc", "/sys", "/dev")
OUTPUT_ERRNOS = (errno.ENOSPC, errno.EACCES, errno.EROFS, errno.EDQUOT, errno.EPERM)

_held = {}      # absolute folder -> open lock file of this process (kept for the whole run)


def check_path(out):
    """The absolute, normalised folder ``out`` or ``DeckError`` (one line) if it cannot be one:
    empty, in /proc, /sys or /dev, a name longer than the file system allows, an existing
    non-directory, or under a file."""
    if not isinstance(out, str) or not out.strip():
        raise DeckError(f"--out {out!r}: expected the path of an output folder (empty)")
    path = os.path.abspath(out)
    real = os.path.realpath(path)
    for root in FORBIDDEN_ROOTS:
        if real == root or real.startswith(root + os.sep):
            raise DeckError(f"--out {out}: {real} is in {root}, not a place for results; choose a folder "
                            f"on a disk")
    if len(path.encode()) >= _limit("PC_PATH_MAX", 4096):
        raise DeckError(f"--out {out[:40]}...: path of {len(path.encode())} bytes, the file system allows "
                        f"{_limit('PC_PATH_MAX', 4096) - 1}")
    longest = _limit("PC_NAME_MAX", 255)
    for part in path.split(os.sep):
        if len(part.encode()) > longest:
            raise DeckError(f"--out {out[:40]}...: a name of {len(part.encode())} bytes in the path, the file "
                            f"system allows {longest}")
    head = path
    while head != os.path.dirname(head):      # the deepest part that exists must be a directory
        if os.path.lexists(head):
            if not os.path.isdir(head):
                what = "" if head == path else f" ({head} is not a directory)"
                raise DeckError(f"--out {out}: exists and is not a directory{what}; expected a folder")
            break
        head = os.path.dirname(head)
    return path


def _limit(name, default):
    try:
        return os.pathconf("/", name)
    except (OSError, ValueError):
        return default


def results_in(path):
    """The entries of ``RESULTS`` and ``RESULT_PATTERNS`` present in folder ``path`` (sorted)."""
    found = {name for name in RESULTS if os.path.lexists(os.path.join(path, name))}
    found.update(name for name in os.listdir(path)
                 if any(fnmatch.fnmatchcase(name, pat) for pat in RESULT_PATTERNS))
    return sorted(found)


def _check_restart(out, path, restart):
    if restart:
        ck = os.path.realpath(restart)
        if ck == os.path.realpath(path) or ck.startswith(os.path.realpath(path) + os.sep):
            raise DeckError(f"--out {out}: holds the checkpoint being restarted ({restart}); a restart writes into "
                            f"its own folder and never touches the original run's files (omit --out for "
                            f"<run>-restart-<time>)")


def _in_use(out, holder):
    return DeckError(f"--out {out}: in use by another run ({holder or 'pid unknown'}); choose another --out")


def _holds_results(out, found):
    return DeckError(f"--out {out}: holds the results of another run ({', '.join(found)}); give --overwrite to "
                     f"replace them, or another --out")


def _probe_here(out, overwrite, restart):
    """``claim``'s refusals without creating, locking or removing anything: the path, the
    checkpoint being restarted, a folder locked by a live run or holding results (without
    ``overwrite``), a place this process may not write (the deepest existing folder of the path)."""
    path = check_path(out)
    _check_restart(out, path, restart)
    head = path
    while not os.path.lexists(head):
        head = os.path.dirname(head)
    if not os.access(head, os.W_OK | os.X_OK):
        raise _output_error(out, OSError(errno.EACCES, "Permission denied (or a read-only file system)", head))
    if head != path:
        return path
    try:
        lock = open(os.path.join(path, LOCK_NAME), "r")
    except FileNotFoundError:
        lock = None
    except OSError as err:
        raise _output_error(out, err) from err
    if lock is not None:
        with lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)     # released when closed
            except OSError as err:
                if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise _in_use(out, lock.read().strip()) from None
                raise _output_error(out, err) from err
    try:
        found = results_in(path)
    except OSError as err:
        raise _output_error(out, err) from err
    if found and not overwrite:
        raise _holds_results(out, found)
    return path


def _claim_here(out, overwrite, restart):
    path = check_path(out)
    _check_restart(out, path, restart)
    try:
        os.makedirs(path, exist_ok=True)
        lock = open(os.path.join(path, LOCK_NAME), "a+")
    except OSError as err:
        raise _output_error(out, err) from err
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as err:
        lock.seek(0)
        holder = lock.read().strip()
        lock.close()
        if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise _in_use(out, holder) from None
        raise _output_error(out, err) from err
    try:
        found = results_in(path)
        if found and not overwrite:
            raise _holds_results(out, found)
        for name in found:
            target = os.path.join(path, name)
            if os.path.isdir(target) and not os.path.islink(target):
                shutil.rmtree(target)
            else:
                os.remove(target)
        lock.seek(0)
        lock.truncate()
        lock.write(f"pid {os.getpid()} on {os.uname().nodename}\n")
        lock.flush()
    except OSError as err:
        lock.close()
        raise _output_error(out, err) from err
    except DeckError:
        lock.close()
        raise
    _held[path] = lock
    return path


def _output_error(out, err):
    reason = err.strerror or str(err)
    return OutputError(f"--out {out}: cannot write there: {reason}"
                       + (f" ({err.filename})" if err.filename else ""))


def probe(comm, out, overwrite=False, restart=None):
    """Collective: ``claim``'s verdict on ``out`` without touching the file system (the drivers'
    check before they build a case, so that a bad ``--out`` is refused before any work). Returns
    the absolute path, or raises the same ``DeckError`` or ``OutputError`` on every rank. ``claim``
    checks again when it takes the folder (another run may have taken it meanwhile)."""
    return _collective_verdict(comm, lambda: _probe_here(out, overwrite, restart))


def claim(comm, out, overwrite=False, restart=None):
    """Collective: the absolute output folder ``out``, checked, created and locked for this run.

    ``overwrite``: remove the previous results (``RESULTS``) found there instead of refusing.
    ``restart``: the checkpoint being continued; ``out`` must not contain it.
    Raises the same ``DeckError`` (bad path, folder in use or holding results) or
    ``OutputError`` (the file system refused) on every rank.
    """
    return _collective_verdict(comm, lambda: _claim_here(out, overwrite, restart))


def _collective_verdict(comm, here):
    """``here()`` on rank 0; its path, DeckError or OutputError on every rank."""
    outcome = None
    if comm.is_root:
        try:
            outcome = ("ok", here())
        except DeckError as err:
            outcome = ("deck", str(err))
        except OutputError as err:
            outcome = ("output", str(err))
    kind, value = comm.bcast(outcome)
    if kind == "deck":
        raise DeckError(value)
    if kind == "output":
        err = OutputError(value)
        err.all_ranks = True      # raised on every rank: no abort needed (pardem.drivers.cli)
        raise err
    return value


def release_all():
    """Drop every lock this process holds (``cli.run_driver`` at the end of a run)."""
    for path in list(_held):
        release(path)


def release(path):
    """Drop this process's lock of folder ``path`` (the end of a run in a process that goes on,
    e.g. tests calling a driver's ``main``)."""
    lock = _held.pop(os.path.abspath(path), None)
    if lock is not None:
        lock.close()
