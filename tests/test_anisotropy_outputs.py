"""The anisotropy study's output contract: per case a series (CSV and HDF5, with units) written by the
rank that ran it, ParaView snapshots when ``output.vtk_every`` > 0, the records, summary and plot; the
series' last row is the state the case's modulus was measured on."""
import json

import h5py
import pytest

from pardem.drivers import anisotropy
from pardem.io.series import SERIES_COLUMNS, SERIES_UNITS, read_series
from pardem.protocols import anisotropy_study as study

ARGS = ["--quick", "--kinds", "ordered", "--laws", "hankinson,linear", "--ratios", "5",
        "--xi-step", "0", "--set", "domain.box=[0.0035, 0.0035, 0.0035]", "--set", "output.vtk_every=400",
        "--quiet", "--no-plot"]


def test_series_and_paraview_per_case(tmp_path):
    out = tmp_path / "study"
    assert anisotropy.main(ARGS + ["--out", str(out)]) == 0
    data = json.loads((out / "anisotropy.json").read_text())
    cases = data["meta"]["cases"]
    assert len(cases) == 2 * 3            # 2 laws x 3 axes
    for rec in cases:
        name = study.case_name(study.Case(rec["kind"], rec["realisation"], rec["law"], rec["ratio"], rec["axis"],
                                          rec["tilt_deg"]))
        s = read_series(str(out / "series" / f"{name}.csv"))
        assert s["step"][-1] == rec["steps"]
        with h5py.File(out / "series" / f"{name}.h5") as f:
            assert list(f.attrs["columns"]) == list(SERIES_COLUMNS)
            assert [f[c].attrs["units"] for c in SERIES_COLUMNS] == list(SERIES_UNITS)
            assert f["force_fixed"][-1] == s["force_fixed"][-1]
        pvd = out / "paraview" / name / "pardem.pvd"
        assert pvd.exists() and pvd.read_text().count("<DataSet") == rec["steps"] // 400 + 2 - (rec["steps"] % 400 == 0)
    assert all(rec["status"] == "ok" for rec in cases)
    # the bonds lie along L, R, T: every law returns the axis values
    h, n = data["ordered"]["hankinson"][0], data["ordered"]["linear"][0]
    for key in ("E_L_mean", "E_R_mean", "E_T_mean"):
        assert n[key] == pytest.approx(h[key], rel=1e-9)


def test_steps_caps_every_case_and_is_part_of_the_plan(tmp_path):
    """--steps N: every case runs at most N steps (a case too short to measure is flagged, never
    reported as a modulus); the cap is part of the study plan, so a restart must repeat it."""
    out = tmp_path / "short"
    args = ["--quick", "--kinds", "ordered", "--laws", "linear", "--ratios", "5", "--xi-step", "0",
            "--set", "domain.box=[0.0035, 0.0035, 0.0035]", "--quiet", "--no-plot", "--steps", "30"]
    anisotropy.main(args + ["--out", str(out)])
    data = json.loads((out / "anisotropy.json").read_text())
    cases = data["meta"]["cases"]
    assert len(cases) == 3 and all(rec["steps"] <= 30 for rec in cases)
    assert all(rec["status"] != "ok" for rec in cases)      # 30 steps end inside the plate's ramp
    assert json.loads((out / "study.json").read_text())["plan"]["steps"] == 30
