"""A bad ``--out`` is refused before the case is built (issue: 27 s of building before the
refusal of ``--out /proc/pardem``; the lock and "holds results" refusals came after the build
too). The driver's ``build`` is replaced by one that fails the test: a refusal must come first,
as one line and exit 2; a good ``--out`` reaches the build with nothing created yet."""
import fcntl
import os

import pytest

from pardem.drivers import isotropic as drv
from pardem.drivers import runner
from pardem.parallel.communicator import Communicator

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DECK = os.path.join(ROOT, "drivers", "isotropic_small.toml")


class Built(Exception):
    pass


class NoBuild(drv.Isotropic):
    def build(self, run):
        raise Built(run.args.out)


def run_with_out(out, *extra):
    comm = Communicator()
    args = drv.parser(comm).parse_args(["--config", DECK, "--quiet", "--out", str(out), *extra])
    return runner.run_protocol(comm, args, NoBuild())


def refused(capsys, out, *words, extra=()):
    with pytest.raises(SystemExit) as err:
        run_with_out(out, *extra)
    assert err.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    for w in words:
        assert w in lines[0], lines[0]


def test_bad_out_refused_before_the_build(tmp_path, capsys):
    refused(capsys, "/proc/pardem", "/proc")
    results = tmp_path / "results"
    results.mkdir()
    (results / "isotropic.json").write_text("{}")
    refused(capsys, results, "holds the results", "isotropic.json")
    assert sorted(os.listdir(results)) == ["isotropic.json"]        # no lock file left, nothing removed
    busy = tmp_path / "busy"
    busy.mkdir()
    with open(busy / ".pardem.lock", "a+") as lock:          # another run holds the folder
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        lock.write("pid 4242 on elsewhere\n")
        lock.flush()
        refused(capsys, busy, "in use by another run", "pid 4242")
    file_ = tmp_path / "a_file"
    file_.write_text("x")
    refused(capsys, file_ / "sub", "not a directory")


def test_good_out_reaches_the_build_with_nothing_created(tmp_path):
    out = tmp_path / "new" / "run"
    with pytest.raises(Built):
        run_with_out(out)
    assert not (tmp_path / "new").exists()
    results = tmp_path / "results"
    results.mkdir()
    (results / "isotropic.json").write_text("{}")
    with pytest.raises(Built):                          # --overwrite: the results go only when it runs
        run_with_out(results, "--overwrite")
    assert sorted(os.listdir(results)) == ["isotropic.json"]
