"""A full disk or a refused write during a run's writes: exit 4, one line from one rank, a true
word on the checkpoints, no crash at exit.

Real full disks: a small tmpfs mounted in a private mount namespace (``unshare -m``, as
``test_checkpoint_disk_race``; root only), filled by the run itself. The sizes pick the write that
fails first, for compress's 216-element case sampled every step (``series.h5`` takes about 144 KiB
at its first flush of rows, a checkpoint's reservation about 250 KiB): 160 KiB, the series;
300 KiB, the first checkpoint; 700 KiB, the second checkpoint (one intact before it). Refused
writes as root cannot be had from permissions: an ``OSError(EACCES)`` is injected at the write.
"""
import errno
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from pardem.errors import OutputError
from pardem.io import series_h5, summary
from pardem.io.series import SeriesCSV, read_series
from pardem.io.series_h5 import SeriesH5, read_series_h5

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COMPRESS = ["-m", "pardem.drivers.compress", "--set", "domain.box=[0.003,0.003,0.003]", "--steps", "3000",
            "--set", "checkpoint.every_steps=300", "--set", "output.series_every=1", "--quiet"]


def _can_mount():
    if os.geteuid() != 0 or not shutil.which("unshare"):
        return False
    return subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode == 0


def _row(k):
    return {"step": k, "time": k * 1e-7, "plate_displacement": 1e-9 * k, "force_fixed": 1.0 + k,
            "force_moving": 2.0, "eps": np.eye(3) * 1e-5 * k, "bonds_broken": 0, "bonds_broken_step": 0,
            "bonds_yielded": 0}


@pytest.mark.parametrize("flush_rows", [1, 7, 100, 2500])
def test_the_space_held_before_a_series_flush_bounds_what_the_flush_adds(tmp_path, monkeypatch, flush_rows):
    """The space ``series.h5`` holds on disk before each flush (its size then plus
    ``_flush_bytes``) is at least the file's size after the flush (measured), over 5,000 rows
    crossing several chunks, and at most 64 KiB above it (the bound's 16 KiB of metadata and 3 KiB
    a column of index slack: it must not refuse a disk with room)."""
    path = str(tmp_path / "s.h5")
    held = []
    real = series_h5.hold_space

    def spy(p, nbytes):
        held.append(nbytes)
        real(p, nbytes)
    monkeypatch.setattr(series_h5, "hold_space", spy)
    w = SeriesH5(path, flush_rows=flush_rows, flush_seconds=1e9)
    checked = 0
    for k in range(5000):
        before = len(held)
        w.append(_row(k))
        if len(held) > before:
            size = os.path.getsize(path)
            assert size <= held[-1] <= size + 64 * 1024, (k, size, held[-1])
            checked += 1
    w.close()
    assert checked == 5000 // flush_rows
    assert read_series_h5(path)["step"].tolist() == list(range(5000))


def test_a_series_write_refused_raises_one_output_error_and_the_file_keeps_its_rows(tmp_path, monkeypatch):
    """An OSError at the space reservation of a flush: ``OutputError`` naming the file and the
    reason; the file keeps the rows of the flushes before (read back exactly), takes no more, and
    closes (now and at exit) without an error."""
    path = str(tmp_path / "s.h5")
    w = SeriesH5(path, flush_rows=10, flush_seconds=1e9)
    for k in range(25):
        w.append(_row(k))

    def refuse(p, nbytes):
        raise OSError(errno.EACCES, "Permission denied")
    monkeypatch.setattr(series_h5, "hold_space", refuse)
    with pytest.raises(OutputError, match=r"cannot write .*s\.h5: Permission denied$"):
        for k in range(25, 40):
            w.append(_row(k))
    w.close()
    w.close()
    assert read_series_h5(path)["step"].tolist() == list(range(20))


def test_a_csv_write_refused_raises_one_output_error(tmp_path, monkeypatch):
    path = str(tmp_path / "s.csv")
    w = SeriesCSV(path)
    w.append(_row(0))
    real = os.write

    def refuse(fd, data):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(os, "write", refuse)
    with pytest.raises(OutputError, match=r"cannot write .*s\.csv: No space left on device$"):
        w.append(_row(1))
    monkeypatch.setattr(os, "write", real)
    with pytest.raises(OutputError):
        w.append(_row(2))        # no row after a failed one: the file is a prefix
    w.close()
    assert read_series(path)["step"] == [0.0]


def test_a_summary_write_refused_raises_one_output_error_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = str(tmp_path / "summary.json")

    def refuse(src, dst):
        raise OSError(errno.EACCES, "Permission denied")
    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(OutputError, match=r"cannot write .*summary\.json: Permission denied$"):
        summary.write_json(path, {"a": 1})
    assert os.listdir(tmp_path) == []


def test_a_refused_summary_ends_the_driver_with_exit_4_in_one_line(tmp_path, monkeypatch, capsys):
    """In process, one rank: the summary's write refused (EACCES at its rename) at the end of a
    run that wrote a checkpoint: exit 4, one line on stderr that names the last checkpoint, which
    exists."""
    from pardem.drivers import compress
    real = os.replace

    def refuse(src, dst):
        if dst.endswith("summary.json"):
            raise OSError(errno.EACCES, "Permission denied")
        return real(src, dst)
    monkeypatch.setattr(os, "replace", refuse)
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        compress.main(["--set", "domain.box=[0.003,0.003,0.003]", "--steps", "600",
                       "--set", "checkpoint.every_steps=300", "--out", str(out), "--quiet"])
    assert exc.value.code == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    ck = str(out / "checkpoints" / "checkpoint-0000000600.h5")
    assert "summary.json: Permission denied" in err[0] and f"the last checkpoint written, {ck}, is intact" in err[0]
    assert os.path.exists(ck)


needs_mount = pytest.mark.skipif(not _can_mount(), reason="needs root to mount a small tmpfs (unshare -m)")


def _full_disk_run(tmp_path, size, ranks):
    disk = tmp_path / "disk"
    disk.mkdir()
    run = [sys.executable, *COMPRESS, "--out", str(disk / "run")]
    if ranks > 1:
        run = [MPIEXEC, "-n", str(ranks), *run]
    cmd = " ".join(f"'{a}'" for a in run)
    env = dict(os.environ, PYTHONPATH=ROOT)
    p = subprocess.run(["unshare", "-m", "sh", "-c",
                        f"mount -t tmpfs -o size={size} tmpfs '{disk}' && {cmd}; code=$?; "
                        f"ls '{disk}/run/checkpoints' 2>/dev/null | sed 's/^/file /'; "
                        f"cp -r '{disk}/run' '{tmp_path}/copy'; exit $code"],
                       capture_output=True, text=True, timeout=600, env=env)
    files = [ln[5:] for ln in p.stdout.splitlines() if ln.startswith("file ")]
    return p, files


CASES = [("160k", "series.h5", 0), ("300k", "checkpoint-0000000300.h5", 0),
         ("700k", "checkpoint-0000000600.h5", 1)]


@needs_mount
@pytest.mark.parametrize("ranks", [1, 2] if MPIEXEC else [1])
@pytest.mark.parametrize("size,fails,kept", CASES)
def test_a_full_disk_ends_the_run_with_exit_4_in_one_true_line(tmp_path, size, fails, kept, ranks):
    """The run fills the disk: exit 4 (not 1, not 139), one line on stderr from one rank (no
    traceback, no MPICH "Abort" line), naming the write that failed and the reason, and saying
    truly which checkpoint a restart can use (the one on the disk, or none). The series files are
    readable prefixes of the run's rows."""
    p, files = _full_disk_run(tmp_path, size, ranks)
    assert p.returncode == 4, p.stderr[-3000:]
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1, p.stderr[-3000:]
    line = lines[0]
    assert line.startswith("pardem: error: cannot write the results: cannot write ") and fails in line, line
    assert "No space left on device" in line, line
    complete = [f for f in files if f.endswith(".h5")]
    assert len(complete) == kept and not [f for f in files if f.endswith(".tmp")], files
    if kept:
        last = re.search(r"the last checkpoint written, (\S+), is intact", line).group(1)
        assert os.path.basename(last) == complete[-1]
    else:
        assert "no checkpoint was written (nothing to restart from)" in line, line
    csv = read_series(str(tmp_path / "copy" / "series.csv"))
    h5 = read_series_h5(str(tmp_path / "copy" / "series.h5"))
    n = len(h5["step"])
    assert h5["step"].tolist() == csv["step"][:n] == list(range(n))
