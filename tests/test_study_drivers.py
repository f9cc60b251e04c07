"""The study drivers (calibrate, anisotropy, mixture) run through ``drivers.runner.run_protocol``
as ``StudyDriver``s: a bad ``--out`` is refused before their build (the anisotropy study built its
first packings before it looked at its output folder), a good one reaches the build with nothing
created, and a stop signal during the cases ends the study with one line naming its folder of
records (what ``--restart`` continues from) and no summary written."""
import os

import pytest

from pardem.drivers import anisotropy, calibrate, cli, mixture, runner
from pardem.errors import Interrupted
from pardem.parallel.communicator import Communicator

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BEECH = os.path.join(ROOT, "drivers", "calibrate_beech.toml")
STUDIES = {
    "anisotropy": (anisotropy, anisotropy.Anisotropy, ["--quick", "--kinds", "ordered", "--laws", "hankinson",
                                                       "--ratios", "1", "--xi-step", "0"], "anisotropy.json"),
    "mixture": (mixture, mixture.Mixture, ["--quick", "--ratios", "1", "--realisations", "1"], "mixture.json"),
    "calibrate": (calibrate, calibrate.Calibrate, ["--config", BEECH, "--verify", "--quick"], "calibration.json"),
}


class Built(Exception):
    pass


def run_with(name, out, hook="build", extra=()):
    module, driver, options, _ = STUDIES[name]

    class Probe(driver):
        pass

    def refuse(self, run):
        raise Built(run.args.out)
    setattr(Probe, hook, refuse)
    comm = Communicator()
    args = module.parser(comm).parse_args([*options, "--quiet", "--out", str(out), *extra])
    return runner.run_protocol(comm, args, Probe())


@pytest.mark.parametrize("name", sorted(STUDIES))
def test_a_bad_out_is_refused_before_the_build(name, tmp_path, capsys):
    results = tmp_path / "results"
    results.mkdir()
    summary = STUDIES[name][3]
    (results / summary).write_text("{}")
    with pytest.raises(SystemExit) as err:
        run_with(name, results)
    assert err.value.code == cli.EXIT_USAGE
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "holds the results" in lines[0] and summary in lines[0], lines
    assert sorted(os.listdir(results)) == [summary]          # nothing created, nothing removed
    with pytest.raises(SystemExit) as err:
        run_with(name, "/proc/pardem")
    assert err.value.code == cli.EXIT_USAGE


@pytest.mark.parametrize("name", sorted(STUDIES))
def test_a_good_out_reaches_the_build_with_nothing_created(name, tmp_path):
    out = tmp_path / "new" / "study"
    with pytest.raises(Built):
        run_with(name, out)
    assert not (tmp_path / "new").exists()


def test_a_stop_signal_ends_a_study_with_its_records_and_no_summary(tmp_path):
    """``execute`` interrupted (as ``Simulation.run`` raises it on a case's rank): ``run_protocol``
    re-raises it with the folder of records, writes no summary, and the one line names the folder."""
    out = tmp_path / "study"

    def stopped(self, run):
        raise Interrupted(15, 1234)
    module, driver, options, summary = STUDIES["mixture"]
    Probe = type("Probe", (driver,), {"execute": stopped})
    comm = Communicator()
    args = module.parser(comm).parse_args([*options, "--quiet", "--no-plot", "--out", str(out)])
    with pytest.raises(Interrupted) as err:
        runner.run_protocol(comm, args, Probe())
    assert err.value.records == str(out)
    assert not (out / summary).exists() and (out / "study.json").exists()
    line = cli.interrupted_line(err.value)
    assert line == (f"pardem: stopped by SIGTERM at step 1234; the finished cases are recorded in {out}; "
                    f"restart with --restart {out}")
