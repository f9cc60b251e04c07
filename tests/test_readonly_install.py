"""A read-only install: ``import pardem`` and a compiled kernel when neither the package's folder
nor ``$HOME`` can be written (a cluster's software tree), so Numba's own cache places are closed.

The package is copied to a folder made read-only for the user running it (as root, who writes
anywhere, the folder and ``HOME`` are read-only bind mounts in a private mount namespace,
``unshare -m``), ``HOME`` points to a folder it cannot write and ``NUMBA_CACHE_DIR`` /
``XDG_CACHE_HOME`` are unset. Before ``pardem.io.numba_cache`` Numba
refused to decorate the kernels ("cannot cache function ...: no locator available").
"""
import os
import shutil
import stat
import subprocess
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SCRIPT = r"""
import os, sys
import numpy as np
import pardem
assert pardem.__file__.startswith(sys.argv[1]), pardem.__file__
from pardem.physics.finite import first_nonfinite      # decorated with cache=True, compiled here
assert first_nonfinite([np.zeros(3), np.array([0.0, np.nan])]) == 1
print(os.environ.get("NUMBA_CACHE_DIR"))
"""


def _read_only(cmd, folders):
    """``cmd`` with ``folders`` read-only: as root, read-only bind mounts in a private mount
    namespace (None if ``unshare`` cannot make one); else the permissions already bind."""
    if os.geteuid() != 0:
        return cmd
    if not shutil.which("unshare") or subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode:
        return None
    mounts = " && ".join(f"mount --bind '{f}' '{f}' && mount -o remount,ro,bind '{f}'" for f in folders)
    return ["unshare", "-m", "sh", "-c", f'{mounts} && exec "$0" "$@"', *cmd]


def test_import_and_a_kernel_on_a_read_only_install():
    base = tempfile.mkdtemp(prefix="pardem-ro-")
    try:
        os.chmod(base, 0o755)
        site = os.path.join(base, "site")
        shutil.copytree(os.path.join(ROOT, "pardem"), os.path.join(site, "pardem"),
                        ignore=shutil.ignore_patterns("__pycache__"))
        home = os.path.join(base, "home")
        tmp = os.path.join(base, "tmp")
        os.makedirs(home)
        os.makedirs(tmp)
        os.chmod(tmp, 0o1777)          # the job's TMPDIR: writable by everyone, as /tmp
        for folder, dirs, names in os.walk(site):    # read-only for every user but the (root) owner
            for d in dirs:
                os.chmod(os.path.join(folder, d), 0o555)
            for n in names:
                os.chmod(os.path.join(folder, n), 0o444)
        os.chmod(site, 0o555)
        os.chmod(home, 0o555)
        env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "PYTHONPATH")}
        env.update(HOME=home, TMPDIR=tmp, PYTHONPATH=site, PYTHONDONTWRITEBYTECODE="1")
        cmd = _read_only([sys.executable, "-c", SCRIPT, site], [site, home])
        if cmd is None:
            pytest.skip("root without a private mount namespace (unshare -m): cannot make a folder read-only")
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, cwd=tmp)
        assert p.returncode == 0, p.stderr[-3000:]
        cache = os.path.join(tmp, f"pardem-numba-cache-{os.getuid()}")
        assert p.stdout.split() == [cache], p.stdout
        assert stat.S_IMODE(os.stat(cache).st_mode) == 0o700
        written = [n for _, _, names in os.walk(cache) for n in names]
        assert any(n.endswith(".nbi") for n in written), written     # the kernel's cache index
        assert not any(d == "__pycache__" for _, dirs, _ in os.walk(site) for d in dirs)
    finally:
        for folder, dirs, _ in os.walk(base):
            for d in dirs:
                os.chmod(os.path.join(folder, d), 0o755)
        shutil.rmtree(base, ignore_errors=True)


def test_a_writable_tree_or_a_set_cache_dir_is_left_to_numba(tmp_path):
    """Where Numba can cache (the tree's __pycache__, the user cache) or the user chose
    ``NUMBA_CACHE_DIR``, nothing is set: the caching stays Numba's own."""
    from pardem.io import numba_cache
    assert numba_cache.choose(str(tmp_path), {"NUMBA_CACHE_DIR": "/somewhere"}) is None
    assert numba_cache.choose(str(tmp_path), {}) is None            # tmp_path/__pycache__ is writable
