"""Where Numba caches pardem's compiled kernels: a place this process can write.

Every kernel is compiled with ``cache=True``. Numba keeps the cache beside the source
(``__pycache__`` of each module), else in the user's cache folder (``$XDG_CACHE_HOME/numba`` or
``~/.cache/numba``), and refuses to decorate the function ("cannot cache function ...: no locator
available") when it can write to neither, so ``import pardem`` failed on an install that is
read-only for its user (a cluster's software tree) with an unwritable ``$HOME``. Imported first by
``pardem``, before Numba: when ``NUMBA_CACHE_DIR`` is unset and neither of Numba's own places is
writable, it sets ``NUMBA_CACHE_DIR`` to ``<temp dir>/pardem-numba-cache-<uid>`` (``TMPDIR``, else
/tmp), created for this user alone. A ``NUMBA_CACHE_DIR`` set by the user is always kept. Where
the source tree or the user cache is writable nothing changes (the kernels and their results are
the same wherever the cache is).
"""
import os
import sys
import tempfile

CACHE_NAME = "pardem-numba-cache"


def _writable(path):
    """True when this process can create ``path`` (if missing) and a file in it (Numba's own test)."""
    try:
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        return True
    except OSError:
        return False


def _user_cache():
    """Numba's user-wide cache folder on Linux and macOS (``numba.misc.appdirs.user_cache_dir``)."""
    if sys.platform == "darwin":
        return os.path.expanduser("~/Library/Caches/numba")
    return os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "numba")


def _private_temp():
    """``<temp dir>/pardem-numba-cache-<uid>``, created with mode 0700 and owned by this user (a
    folder another user made there is not used: its kernels could be anything); None if impossible."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    path = os.path.join(tempfile.gettempdir(), f"{CACHE_NAME}-{uid}")
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        st = os.lstat(path)
    except OSError:
        return None
    if hasattr(os, "getuid") and (st.st_uid != uid or not os.path.isdir(path) or os.path.islink(path)):
        return None
    return path if _writable(path) else None


def choose(package_dir, environ=os.environ):
    """The folder to give Numba as ``NUMBA_CACHE_DIR``, or None to leave Numba's choice (the
    variable is set, or the source tree's ``__pycache__`` or the user cache is writable)."""
    if environ.get("NUMBA_CACHE_DIR"):
        return None
    if _writable(os.path.join(package_dir, "__pycache__")) or _writable(_user_cache()):
        return None
    return _private_temp()


def configure():
    """Set ``NUMBA_CACHE_DIR`` when Numba could cache nowhere (see the module's docstring); also
    in Numba's live configuration when Numba was imported before pardem."""
    path = choose(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))   # the pardem package
    if path is None:
        return None
    os.environ["NUMBA_CACHE_DIR"] = path
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = path
    return path


configure()
