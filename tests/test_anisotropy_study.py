"""The anisotropy study driver (python -m pardem.drivers.anisotropy) on small domains.

Checks: on the axis-aligned ordered lattice with equal bond radii every direction gives
E^D = pi/4 E r^2, so the domain ratios equal the bond ratios (1 %) and all four laws agree (each law
returns exactly E_L, E_R, E_T along the axes); the off-axis point at 90 deg (a tilted lattice loaded
along x) equals the untilted lattice loaded along y; the 45 deg point lies between E(90) and
Hankinson's value, as the orthotropic beam lattice predicts; a domain that rotates between the
frictionless plates is flagged, not averaged; compact realisation k uses seed base + k, each packing
is built once, and the rows are the statistics of the per-case records; the JSON layout; 1 rank and
2 ranks give the same numbers; bad options exit with code 2 and one line.
"""
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from pardem.protocols import anisotropy_study as study
from pardem.config import load_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.drivers import anisotropy
from pardem.io.records import read_records

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RATIOS = (1.0, 5.0, 25.0)
SMALL = "domain.box=[0.0035, 0.0035, 0.0035]"      # 7^3 ordered elements
QUICK = ["--quick", "--kinds", "ordered", "--ratios", "1,5,25", "--xi-step", "45", "--set", SMALL, "--quiet"]
ROW_KEYS = {"bond_LR", "bond_LT", "LR_mean", "LR_std", "LT_mean", "LT_std"}
XI_KEYS = {"xi_deg", "E_mean", "E_std", "E_hankinson"}


def run_driver(out, argv):
    assert anisotropy.main(argv + ["--out", str(out)]) == 0
    return json.loads((out / "anisotropy.json").read_text())


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """The quick study on a 7^3 ordered lattice, all laws, ratios 1, 5, 25, xi = 0, 45, 90."""
    out = tmp_path_factory.mktemp("quick")
    return run_driver(out, QUICK), out


def test_ordered_domain_ratios_equal_bond_ratios(quick):
    data, _ = quick
    E_R, E_T = 100e6, 20e6        # the study deck's bonds.young[1:], r = 1
    for law in study.LAWS:
        rows = data["ordered"][law]
        assert [r["bond_LR"] for r in rows] == list(RATIOS)
        for r in rows:
            q = r["bond_LR"]
            assert r["bond_LT"] == pytest.approx(q * E_R / E_T, rel=1e-12)
            assert r["LR_mean"] == pytest.approx(q, rel=0.01)
            assert r["LT_mean"] == pytest.approx(q * E_R / E_T, rel=0.01)
            for axis, E in zip("LRT", (q * E_R, E_R, E_T)):
                assert r[f"E_{axis}_mean"] == pytest.approx(math.pi / 4 * E, rel=0.01)
            assert r["LR_std"] == r["LT_std"] == 0.0 and r["n_failed"] == 0 and r["n_realisations"] == 1
    # bonds along L, R, T get exactly E_L, E_R, E_T from every law: the laws agree
    ref = data["ordered"]["TOR"]
    for law in study.LAWS[1:]:
        for a, b in zip(ref, data["ordered"][law]):
            for key in ("E_L_mean", "E_R_mean", "E_T_mean"):
                assert b[key] == pytest.approx(a[key], rel=1e-6)


def test_off_axis_end_points_and_hankinson(quick):
    """E(0) is the L compression; E(90), a lattice tilted by 90 deg loaded along x, equals the untilted
    lattice loaded along y (another computation); E_hankinson follows the closed form."""
    data, _ = quick
    for law in study.LAWS:
        rows = {r["xi_deg"]: r for r in data["off_axis"]["ordered"][law]}
        assert sorted(rows) == [0.0, 45.0, 90.0]
        ratio_row = data["ordered"][law][-1]          # the off-axis sweep runs at the largest ratio
        assert ratio_row["bond_LR"] == data["meta"]["plan"]["offaxis_ratio"] == 25.0
        assert rows[0.0]["E_mean"] == ratio_row["E_L_mean"]
        assert rows[90.0]["E_mean"] == pytest.approx(ratio_row["E_R_mean"], rel=1e-3)
        E0, E90 = rows[0.0]["E_mean"], rows[90.0]["E_mean"]
        for xi, r in rows.items():
            s, c = np.sin(np.radians(xi)), np.cos(np.radians(xi))
            assert r["E_hankinson"] == pytest.approx(1.0 / (s * s / E90 + c * c / E0), rel=1e-12)


def test_off_axis_45_between_e90_and_hankinson(quick):
    """The orthotropic beam lattice (nu = 0, shear modulus from bond bending
    G = 3 pi r^4 / 16 E_L E_R / (E_L + E_R)) gives 1/E(45) = (1/E0 + 1/E90 + 1/G) / 4: above E90 for
    E_L/E_R > 1.4, below Hankinson's 2 E0 E90 / (E0 + E90) for r < 1.15; the finite lattice's loose
    surface elements only soften it. The 45 deg lattice is mirror-symmetric enough not to rotate."""
    data, _ = quick
    q, r = 25.0, 1.0
    EL, ER = q * 100e6, 100e6
    G = 3 * math.pi * r**4 / 16 * EL * ER / (EL + ER)
    for law in study.LAWS:
        row = {x["xi_deg"]: x for x in data["off_axis"]["ordered"][law]}[45.0]
        assert row["n_failed"] == 0 and row["statuses"] == ["ok"]
        E0, E90 = (math.pi / 4 * EL * r**2, math.pi / 4 * ER * r**2)
        orthotropic = 4.0 / (1 / E0 + 1 / E90 + 1 / G)
        assert E90 < orthotropic < 2 * E0 * E90 / (E0 + E90)     # the theory's ordering at this ratio
        assert row["E_mean"] > 1.1 * E90
        assert row["E_mean"] < row["E_hankinson"]
        assert row["E_mean"] <= 1.01 * orthotropic


def test_json_layout(quick):
    data, out = quick
    assert set(data) == {"meta", "ordered", "off_axis"}
    assert set(data["ordered"]) == set(study.LAWS) and set(data["off_axis"]) == {"ordered"}
    for law in study.LAWS:
        rows = data["ordered"][law]
        assert len(rows) == len(RATIOS) and all(ROW_KEYS <= set(r) for r in rows)
        xi_rows = data["off_axis"]["ordered"][law]
        assert len(xi_rows) == 3 and all(XI_KEYS <= set(r) for r in xi_rows)
    meta = data["meta"]
    # 4 laws x 3 ratios x 3 axes, plus xi = 45 and 90 per law (xi = 0 is the L compression)
    assert meta["n_cases"] == len(meta["cases"]) == 4 * 3 * 3 + 4 * 2
    assert meta["plan"]["kinds"] == ["ordered"] and meta["n_ranks"] >= 1 and meta["wall_seconds"] > 0
    assert meta["deck"]["domain"]["box"] == [0.0035, 0.0035, 0.0035]
    keys = {(c["law"], c["ratio"], c["axis"], c["tilt_deg"]) for c in meta["cases"]}
    assert len(keys) == meta["n_cases"]                 # every compression once
    for c in meta["cases"]:                             # raw moduli to recompute the rows
        assert c["status"] == "ok" and c["E"] > 0 and c["seed"] is None and c["realisation"] == 0
    if (out / "anisotropy.png").exists() or _has_matplotlib():
        assert (out / "anisotropy.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _has_matplotlib():
    try:
        import matplotlib  # noqa: F401
        return True
    except ImportError:
        return False


def test_rotating_domain_is_flagged_not_averaged():
    """An ordered lattice tilted by 20 deg rests on one row of spheres per frictionless plate and rotates
    (or slides out); the case is flagged and its row holds no number."""
    deck = load_deck(COMPRESS_SCHEMA, None, study.QUICK_SET + [SMALL], base=study.STUDY_DECK)
    plan = study.StudyPlan(kinds=("ordered",), laws=("TOR",), ratios=(5.0,), E_R=100e6, E_T=20e6,
                           xi_step=45.0, offaxis_ratio=5.0)
    rec = study.run_case(_self_comm(), deck, plan, study.Case("ordered", 0, "TOR", 5.0, "x", 20.0))
    assert rec["status"] in ("rotated", "lost_contact")
    assert rec["face_tilt"] > study.FACE_TILT_MAX
    fake = dict(rec, tilt_deg=45.0)                     # summarise treats it as the 45 deg point
    others = [dict(rec, tilt_deg=t, status="ok", E=e) for t, e in ((0.0, 4e8), (90.0, 8e7))]
    data = study.summarise([fake] + others + _ratio_records(5.0), plan)
    row = {r["xi_deg"]: r for r in data["off_axis"]["ordered"]["TOR"]}[45.0]
    assert row["E_mean"] is None and row["E_std"] is None and row["n_failed"] == 1
    assert row["statuses"] == [rec["status"]]
    assert row["E_hankinson"] == pytest.approx(study.hankinson(4e8, 8e7, 45.0))


def _ratio_records(q):
    return [{"kind": "ordered", "law": "TOR", "ratio": q, "axis": a, "tilt_deg": 0.0, "realisation": 0,
             "status": "ok", "E": E} for a, E in zip("xyz", (q * 1e8, 1e8, 2e7)) if a != "x"]


def _self_comm():
    from mpi4py import MPI
    from pardem.parallel.communicator import Communicator
    return Communicator(MPI.COMM_SELF)


MIXED = ["--quick", "--kinds", "ordered,compact", "--laws", "hankinson", "--ratios", "1", "--xi-step", "0",
         "--quiet", "--no-plot"]


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    """A small study on one rank, both kinds (2 compact realisations); the compact builder's calls
    (as the engine and the study make them) are recorded."""
    from pardem.domains import compact
    built = []
    with pytest.MonkeyPatch.context() as mp:
        for module in (compact, study):
            original = module.compact_packing
            mp.setattr(module, "compact_packing", lambda *a, _f=original, **k: built.append(a) or _f(*a, **k))
        data = run_driver(tmp_path_factory.mktemp("mixed"), list(MIXED))
    return data, built


@pytest.mark.mpi
def test_two_ranks_give_the_same_numbers(mixed, tmp_path):
    one, _ = mixed
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.anisotropy", *MIXED,
                        "--out", str(tmp_path / "two")], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    two = json.loads((tmp_path / "two" / "anisotropy.json").read_text())
    assert two["meta"]["n_ranks"] == 2
    # both ranks worked, one compact realisation each (a realisation's cases stay on one rank)
    assert {c["rank"] for c in two["meta"]["cases"]} == {0, 1}
    assert sorted(len({c["rank"] for c in two["meta"]["cases"] if c["kind"] == "compact" and c["realisation"] == k})
                  for k in (0, 1)) == [1, 1]
    assert {c["rank"] for c in two["meta"]["cases"] if c["kind"] == "compact"} == {0, 1}
    assert p.stdout.count("anisotropy study,") == p.stdout.count("wrote ") == 1   # rank 0 alone prints
    for kind in ("ordered", "compact"):
        assert two[kind] == one[kind]
    drop = {"seconds", "rank"}
    assert ([{k: v for k, v in c.items() if k not in drop} for c in two["meta"]["cases"]]
            == [{k: v for k, v in c.items() if k not in drop} for c in one["meta"]["cases"]])


@pytest.mark.parametrize("argv, names", [
    (["--ratios", "0"], "--ratios"),
    (["--ratios", "1,x"], "--ratios"),
    (["--laws", "TOR,elliptic"], "--laws"),
    (["--kinds", "granular"], "--kinds"),
    (["--xi-step", "7"], "--xi-step"),
    (["--realisations", "0"], "--realisations"),
    (["--transits", "0.5"], "--transits"),
    (["--offaxis-ratio", "-2"], "--offaxis-ratio"),
    (["--set", "bonds.poisson=0.7"], "bonds.poisson"),
    (["--set", "domain.box=[0.0003, 0.0003, 0.0003]"], "domain.box"),
    (["--kinds", "compact", "--set", "domain.box=[0.001, 0.001, 0.001]"], "domain.box"),
    (["--frobnicate"], "--frobnicate"),
])
def test_bad_input_exits_2_with_one_line(argv, names, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        anisotropy.main(["--quick", "--kinds", "ordered", "--out", str(tmp_path / "x")] + argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and names in err[0] and err[0].startswith("pardem: error:")
    assert not (tmp_path / "x").exists()          # nothing ran


def test_compact_realisations_seeds_one_packing_each_and_statistics(mixed):
    """Realisation k uses seed base + k; each of its packings (one per loading axis) is built once for
    all its cases; the rows are the mean and sample std of the per-realisation ratios of the
    successful cases (recomputed here)."""
    data, built = mixed
    assert sorted((a[3], a[4]) for a in built) == [(s, ax) for s in (0, 1) for ax in (0, 1, 2)]
    cases = [c for c in data["meta"]["cases"] if c["kind"] == "compact"]
    assert len(cases) == 2 * 3
    for c in cases:
        assert c["seed"] == c["realisation"]
        assert c["status"] in ("ok", "rotated", "lost_contact", "dynamic", "unstable")
    same = {(c["ratio"], c["axis"], c["tilt_deg"]): [] for c in cases}
    for c in cases:                       # two realisations: two different domains
        same[c["ratio"], c["axis"], c["tilt_deg"]].append(c["E"])
    assert all(len(v) == 2 and v[0] != v[1] for v in same.values())
    for row in data["compact"]["hankinson"]:
        q = row["bond_LR"]
        E = {(c["realisation"], c["axis"]): c["E"] for c in cases
             if c["ratio"] == q and c["tilt_deg"] == 0 and c["status"] == "ok"}
        ok = [k for k in (0, 1) if all((k, a) in E for a in "xyz")]
        assert row["n_realisations"] == 2 and row["n_failed"] == 2 - len(ok)
        LR = [E[k, "x"] / E[k, "y"] for k in ok]
        if len(ok) == 0:
            assert row["LR_mean"] is None and row["LR_std"] is None
        else:
            assert row["LR_mean"] == pytest.approx(np.mean(LR), rel=1e-12)
            assert row["LR_std"] == pytest.approx(np.std(LR, ddof=1) if len(ok) > 1 else 0.0, abs=1e-12)


def test_realisation_k_uses_base_seed_plus_k():
    deck = load_deck(COMPRESS_SCHEMA, None, ["domain.seed=7"], base=study.STUDY_DECK)
    plan = anisotropy.make_plan(anisotropy.parser().parse_args([]), deck)
    assert plan.base_seed == 7
    for k in (0, 3):
        d = study.case_deck(deck, plan, study.Case("compact", k, "linear", 5.0, "y", 30.0))
        assert d["domain"]["seed"] == 7 + k and d["domain"]["kind"] == "compact"
        assert d["domain"]["tilt_deg"] == 30.0 and d["bonds"]["law"] == "linear" and d["loading"]["axis"] == "y"
        assert d["bonds"]["young"] == (500e6, 100e6, 20e6)


def test_study_deck_file_is_the_builtin_default():
    from_file = load_deck(COMPRESS_SCHEMA, os.path.join(ROOT, "drivers", "anisotropy_study.toml"))
    assert from_file == load_deck(COMPRESS_SCHEMA, base=study.STUDY_DECK)


def test_plan_groups_realisations_and_balances_ranks():
    plan = study.StudyPlan(kinds=("ordered", "compact"), laws=study.LAWS, ratios=(1.0, 5.0, 25.0),
                           E_R=100e6, E_T=20e6, realisations=5, xi_step=30.0, offaxis_ratio=25.0)
    groups = study.plan_cases(plan)
    ordered = [g for g in groups if g[0].kind == "ordered"]
    compact = [g for g in groups if g[0].kind == "compact"]
    per_realisation = 4 * 3 * 3 + 4 * 3           # xi = 30, 60, 90 are new, xi = 0 is the L case
    assert all(len(g) == 1 for g in ordered) and len(ordered) == per_realisation
    assert len(compact) == 5
    for k, g in enumerate(compact):                  # one packing per realisation, all its cases
        assert {c.realisation for c in g} == {k} and len(set(g)) == len(g) == per_realisation
    for n in (1, 2, 3, 7):
        parts = study.assign(groups, n, plan)
        assert sorted(i for p in parts for i in p) == list(range(len(groups)))
        assert parts == study.assign(groups, n, plan)
        if n == 2:
            cost = [sum(sum(study.estimated_cost(c, plan) for c in groups[i]) for i in p) for p in parts]
            assert max(cost) <= 1.1 * min(cost)


def test_a_killed_study_continues_where_it_stopped(quick, tmp_path):
    """A study killed after its third case (the fourth record cut mid-line) and continued with
    --restart runs only the missing cases and gives the uninterrupted study's numbers exactly; the
    continued study is written into a new folder (the killed one is left as it was) that holds every
    record."""
    ref, ref_out = quick
    d = tmp_path / "s"
    shutil.copytree(ref_out, d)
    log = d / "records" / "rank-0.jsonl"
    lines = log.read_text().splitlines(keepends=True)
    assert len(lines) == ref["meta"]["n_cases"]           # one record per case, written as it ends
    log.write_text("".join(lines[:3]) + lines[3][:25])
    (d / "anisotropy.json").unlink()
    before = log.read_text()
    data = run_driver(tmp_path / "continued", QUICK + ["--restart", str(d)])
    assert data["meta"]["cases_reused"] == 3 and data["meta"]["restarted_from"] == str(d)
    assert log.read_text() == before
    assert len(read_records(str(tmp_path / "continued"))) == ref["meta"]["n_cases"]
    assert data["ordered"] == ref["ordered"]
    drop = {"seconds", "rank"}
    assert ([{k: v for k, v in c.items() if k not in drop} for c in data["meta"]["cases"]]
            == [{k: v for k, v in c.items() if k not in drop} for c in ref["meta"]["cases"]])


def test_restart_refuses_another_study_and_new_study_refuses_a_used_dir(quick, capsys, tmp_path):
    """--restart with other options, or a new study into a directory holding one, exit 2 with one
    line and run nothing."""
    _, ref_out = quick
    d = tmp_path / "s"
    shutil.copytree(ref_out, d)
    for argv, words in ((QUICK[:3] + ["--ratios", "1,5", "--xi-step", "45", "--set", SMALL, "--quiet",
                                       "--restart", str(d)], "another plan"),
                        (QUICK, "holds the results of another run")):
        with pytest.raises(SystemExit) as exc:
            anisotropy.main(argv + ["--out", str(d)])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err
