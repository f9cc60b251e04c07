"""A disk filled by another process while a checkpoint is written (issue 16, item 6). The space
probe before the write (``checkpoint._reserve``) is not enough: HDF5 1.10 crashed (segmentation
fault, every mode) when the disk filled between the probe and its writes. The space is now held
in the ``.tmp`` right after HDF5 creates it (``checkpoint._hold``, FALLOC_FL_KEEP_SIZE). Real full
disks: a 4 MiB tmpfs mounted in a private mount namespace (``unshare -m``; it needs root, which CI
and the development machines have, and vanishes with the process)."""
import os
import re
import shutil
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
SCRIPT = os.path.join(HERE, "mpi", "disk_race.py")


def _can_mount():
    if os.geteuid() != 0 or not shutil.which("unshare"):
        return False
    return subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode == 0


def race(tmp_path, when, mode):
    disk, ref = tmp_path / "disk", tmp_path / "ref"
    disk.mkdir()
    ref.mkdir()
    run = [sys.executable, SCRIPT, str(disk), str(ref), when, mode]
    if mode != "one":
        run = [MPIEXEC, "-n", "2", *run]
    cmd = " ".join(f"'{a}'" for a in run)
    p = subprocess.run(["unshare", "-m", "sh", "-c", f"mount -t tmpfs -o size=4m tmpfs '{disk}' && exec {cmd}"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr[-3000:]
    return p.stdout.splitlines()


MODES = ["one"] + (["serial", "mpio"] if MPIEXEC else [])
pytestmark = pytest.mark.skipif(not _can_mount(), reason="needs root to mount a small tmpfs (unshare -m)")


@pytest.mark.parametrize("mode", MODES)
def test_a_disk_filled_after_the_probe_ends_the_write_in_one_line(tmp_path, mode):
    """Filled before HDF5 writes more than its superblock: the reservation in the file fails, every
    rank raises the same one-line OutputError, the .tmp is removed and checkpoint 1 still verifies."""
    lines = race(tmp_path, "after_probe", mode)
    errors = [ln.split(":", 1)[1] for ln in lines if "OutputError" in ln]
    assert len(errors) == (1 if mode == "one" else 2) and len(set(errors)) == 1, lines
    assert "No space left on device" in errors[0] and "checkpoint-0000000002.h5" in errors[0], lines
    assert "files checkpoint-0000000001.h5 filler" in lines, lines
    assert "verified checkpoint-0000000001.h5 step 1" in lines, lines


@pytest.mark.parametrize("mode", MODES)
def test_a_disk_filled_after_the_reservation_does_not_fail_the_write(tmp_path, mode):
    """Filled to the last byte right after the space was held in the file: the write ends normally,
    the checkpoint verifies and is byte for byte the one written on a disk with room, and the held
    blocks it did not use were given back (allocated = its size rounded up to the file system's
    4 KiB pages, plus at most one page)."""
    lines = race(tmp_path, "after_hold", mode)
    assert sum("no error" in ln for ln in lines) == (1 if mode == "one" else 2), lines
    assert "verified checkpoint-0000000002.h5 step 2" in lines, lines
    size, allocated, identical = re.search(r"size (\d+) allocated (\d+) identical (\w+)", "\n".join(lines)).groups()
    assert identical == "True", lines
    assert int(size) <= int(allocated) <= int(size) + 8192, lines
