"""The output folder belongs to one run (issue 16, item 3): ``pardem.io.run_folder.claim`` checks
the path, creates it, locks it for the run, refuses another run's results unless ``overwrite``
(then removes exactly those), and a restart never writes into the original run's folder; the
command-line side (``cli.output_dir``, ``--steps`` bounds, exit codes) too.
"""
import argparse
import errno
import os
import pathlib
import subprocess
import sys
import textwrap

import pytest

from pardem.config import DeckError
from pardem.drivers import cli
from pardem.errors import OutputError
from pardem.io import run_folder
from tests._util import FakeComm

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _release():
    yield
    run_folder.release_all()


def refused(out, **kw):
    with pytest.raises(DeckError) as exc:
        run_folder.claim(FakeComm(), out, **kw)
    message = str(exc.value)
    assert "\n" not in message
    return message


def test_claim_creates_the_folder_and_its_lock(tmp_path):
    out = tmp_path / "a" / "b"
    path = run_folder.claim(FakeComm(), str(out))
    assert path == str(out) and out.is_dir()
    assert f"pid {os.getpid()}" in (out / run_folder.LOCK_NAME).read_text()


@pytest.mark.parametrize("case", ["empty", "blank", "file", "under_file", "devnull", "proc", "sys", "long_name",
                                  "long_path"])
def test_bad_paths_are_refused_in_one_line_before_anything_is_created(tmp_path, case):
    f = tmp_path / "file"
    f.write_text("x")
    out, expect = {
        "empty": ("", "empty"),
        "blank": ("  ", "empty"),
        "file": (str(f), "not a directory"),
        "under_file": (str(f / "sub"), f"{f} is not a directory"),
        "devnull": ("/dev/null", "/dev"),
        "proc": ("/proc/self/x", "/proc"),
        "sys": ("/sys/kernel/x", "/sys"),
        "long_name": (str(tmp_path / ("n" * 318)), "318 bytes"),
        "long_path": (str(tmp_path / "/".join(["d" * 200] * 25)), "path of"),
    }[case]
    before = sorted(os.listdir(tmp_path))
    assert expect in refused(out)
    assert sorted(os.listdir(tmp_path)) == before


def test_a_folder_with_another_runs_results_is_refused_unless_overwrite(tmp_path):
    out = tmp_path / "run"
    (out / "checkpoints").mkdir(parents=True)
    (out / "checkpoints" / "checkpoint-0000000100.h5").write_bytes(b"old")
    (out / "summary.json").write_text("{}")
    (out / "series.csv").write_text("old")
    (out / "paraview").mkdir()
    (out / "my_notes.txt").write_text("keep me")        # not a pardem result
    (out / "deck.toml").write_text("keep me too")
    message = refused(str(out))
    assert "checkpoints, paraview, series.csv, summary.json" in message and "--overwrite" in message
    assert (out / "summary.json").exists()              # refusing touches nothing
    run_folder.release_all()
    run_folder.claim(FakeComm(), str(out), overwrite=True)
    assert sorted(os.listdir(out)) == sorted([run_folder.LOCK_NAME, "my_notes.txt", "deck.toml"])


def test_the_2d_drivers_results_are_results_too(tmp_path):
    """The biaxial and response drivers' files (their --help lists them) and numbered maps count as
    a run's results: refused without --overwrite, removed with it; look-alikes a user may keep
    (another extension, no numbers) stay."""
    out = tmp_path / "run"
    out.mkdir()
    ours = ["biaxial.csv", "biaxial.json", "localisation-0-2.png", "localisation-1-0.vtu", "cements-0.png",
            "cements-3.vtu", "response.json", "response.h5"]
    for name in ours:
        (out / name).write_text("old")
    (out / "response_vtk").mkdir()
    theirs = ["localisation.png", "cements-notes.txt", "biaxial.ods"]
    for name in theirs:
        (out / name).write_text("keep")
    message = refused(str(out))
    assert all(name in message for name in ours + ["response_vtk"]) and "--overwrite" in message
    run_folder.release_all()
    run_folder.claim(FakeComm(), str(out), overwrite=True)
    assert sorted(os.listdir(out)) == sorted([run_folder.LOCK_NAME] + theirs)


def test_an_empty_or_unrelated_folder_is_accepted(tmp_path):
    (tmp_path / "notes.txt").write_text("x")
    run_folder.claim(FakeComm(), str(tmp_path))
    assert (tmp_path / "notes.txt").read_text() == "x"


def test_a_restart_may_not_write_where_its_checkpoint_lives(tmp_path):
    ck = tmp_path / "run" / "checkpoints" / "checkpoint-0000000100.h5"
    ck.parent.mkdir(parents=True)
    ck.write_bytes(b"x")
    assert "own folder" in refused(str(tmp_path / "run"), restart=str(ck), overwrite=True)
    assert ck.exists()


def test_the_default_folder_of_a_restart_is_a_new_sibling(tmp_path):
    ck = tmp_path / "run" / "checkpoints" / "checkpoint-0000000100.h5"
    out = cli.default_out(FakeComm(), "compress", str(ck))
    assert os.path.dirname(out) == str(tmp_path) and os.path.basename(out).startswith("run-restart-")
    loose = tmp_path / "saved.h5"
    assert os.path.basename(cli.default_out(FakeComm(), "compress", str(loose))).startswith("saved-restart-")


def test_a_folder_the_file_system_refuses_is_an_output_error(tmp_path, monkeypatch):
    """The tests run as root (permission bits do not bind root), so the refusal is the file
    system's EACCES/EROFS raised by makedirs."""
    for code, text in ((errno.EACCES, "Permission denied"), (errno.EROFS, "Read-only file system")):
        def makedirs(path, exist_ok=False, code=code, text=text):
            raise OSError(code, text, path)
        monkeypatch.setattr(run_folder.os, "makedirs", makedirs)
        with pytest.raises(OutputError) as exc:
            run_folder.claim(FakeComm(), str(tmp_path / "sub"))
        assert text in str(exc.value) and exc.value.all_ranks and "\n" not in str(exc.value)


LOCKER = textwrap.dedent("""
    import sys, time
    from pardem.io import run_folder
    from tests._util import FakeComm
    run_folder.claim(FakeComm(), sys.argv[1])
    print("claimed", flush=True)
    time.sleep(float(sys.argv[2]))
""")


def test_a_second_concurrent_run_into_the_same_folder_is_refused(tmp_path):
    out = tmp_path / "shared"
    first = subprocess.Popen([sys.executable, "-c", LOCKER, str(out), "60"], cwd=ROOT, stdout=subprocess.PIPE,
                             text=True)
    try:
        assert first.stdout.readline().strip() == "claimed"
        message = refused(str(out))
        assert "in use by another run" in message and f"pid {first.pid}" in message
    finally:
        first.kill()
        first.wait()
    # the lock ends with its process: the folder is free again
    run_folder.claim(FakeComm(), str(out))


def test_the_lock_is_released_for_a_later_run_of_the_same_process(tmp_path):
    run_folder.claim(FakeComm(), str(tmp_path / "x"))
    run_folder.release_all()
    run_folder.claim(FakeComm(), str(tmp_path / "x"))


def args(**kw):
    base = dict(out=None, restart=None, overwrite=False, steps=None, config=None, overrides=[])
    base.update(kw)
    return argparse.Namespace(**base)


def test_output_dir_refuses_in_one_line_with_exit_2(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(SystemExit) as exc:
        cli.output_dir(FakeComm(), args(out=str(f)), "compress")
    assert exc.value.code == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pardem: error: --out ")


def test_output_dir_uses_the_default_only_without_out(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = cli.output_dir(FakeComm(), args(), "compress")
    assert os.path.dirname(path) == str(tmp_path / "runs") and os.path.basename(path).startswith("compress-")
    with pytest.raises(SystemExit):
        cli.output_dir(FakeComm(), args(out=""), "compress")


@pytest.mark.parametrize("steps", [0, -3, 10 ** 10 + 1, 99999999999999999999])
def test_steps_out_of_range_are_refused(steps, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.read_deck(FakeComm(), {}, args(steps=steps))
    assert exc.value.code == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--steps {steps}" in err and "1e+10" in err


def _failing(exc):
    def run(comm, a):
        raise exc
    return run


@pytest.mark.parametrize("exc, text", [
    (OSError(errno.ENOSPC, "No space left on device", "/x/series.csv"), "No space left on device (/x/series.csv)"),
    (OSError(errno.EACCES, "Permission denied"), "Permission denied"),
    (OSError(errno.EROFS, "Read-only file system"), "Read-only file system"),
    (OSError(errno.EDQUOT, "Disk quota exceeded"), "Disk quota exceeded"),
    # h5py: errno only in the message
    (OSError("Can't write data (file write failed: time = x, errno = 28, error message = 'No space left on "
             "device', buf = 0x0)"), "No space left on device"),
    (OutputError("--out x: cannot write there: Permission denied"), "cannot write there"),
])
def test_full_disk_and_permission_errors_end_with_one_line_and_exit_4(exc, text, capsys):
    with pytest.raises(SystemExit) as ended:
        cli.run_driver(FakeComm(), _failing(exc), args())
    assert ended.value.code == cli.EXIT_OUTPUT == 4
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and text in err and "Traceback" not in err, err


def test_other_os_errors_are_unexpected(capsys):
    with pytest.raises(SystemExit) as ended:
        cli.run_driver(FakeComm(), _failing(OSError(errno.EIO, "Input/output error")), args())
    assert ended.value.code == cli.EXIT_ERROR
    assert "unexpected error" in capsys.readouterr().err


def test_exit_codes_are_distinct_and_documented():
    codes = [cli.EXIT_OK, cli.EXIT_ERROR, cli.EXIT_USAGE, cli.EXIT_UNSTABLE, cli.EXIT_OUTPUT, cli.EXIT_NOT_MEASURED]
    assert codes == [0, 1, 2, 3, 4, 5]
    p = cli.driver_parser("x", "d", {})
    assert "4 results could not be written" in p.epilog and "5 run too short" in p.epilog
    assert "--overwrite" in p.format_help()
