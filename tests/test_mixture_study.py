"""The mixture study (issue 13, item 2): bidisperse packings against size ratio and concentration.

Checked against independent computations: the realised sizes against the bidisperse formulas
worked by hand, the statistics against numpy on the records, the contacts against a geometric
overlap search, the coordination against Maxwell's count, the relaxed moduli against the affine
bound, the g(r) peaks against the contact distances of the two sizes, and a case of the 2-rank task
farm against the same case run alone in this process (bit for bit).
"""
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from pardem.io.deck_file import load_deck
from pardem.parallel.communicator import Communicator
from pardem.physics import structure
from pardem.protocols import isotropic as iso
from pardem.domains.gas import species_radii
from pardem.protocols import mixture_study as study

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DECK = os.path.join(ROOT, "drivers", "mixture_study.toml")
N = 100          # the --quick study's grains


def plan(**kw):
    base = dict(ratios=(1.0, 1.4), concentrations=(0.5,), basis="number", realisations=2, pressure=1e5,
                mean_radius=1e-4, n=N, dimension=3, seed=1)
    base.update(kw)
    return study.Plan(**base)


def test_the_plan_keeps_ratio_one_once_and_the_cases_realise_the_sizes():
    p = plan(ratios=(1.0, 2.0), concentrations=(0.25, 0.75))
    assert p.points() == [(1.0, 0.0), (2.0, 0.25), (2.0, 0.75)]
    assert len(p.cases()) == 3 * 2
    deck = load_deck(iso.SCHEMA, DECK, [f"sample.n={N}"])
    case = {"ratio": 2.0, "concentration": 0.25, "realisation": 1}
    d = study.case_deck(deck, p, case)
    # by hand: 25 small grains of R_s and 75 of 2 R_s with number mean 1e-4 m: R_s (0.25 + 0.75 * 2) = 1e-4
    rs = 1e-4 / 1.75
    assert d["sample"]["radii"] == pytest.approx([rs, 2 * rs], rel=1e-15)
    r = species_radii(N, d["sample"]["radii"], d["sample"]["fractions"], np.random.default_rng(0))
    assert np.sum(r < 1.5 * rs) == 25 and r.mean() == pytest.approx(1e-4, rel=1e-14)
    assert d["sample"]["seed"] == deck["sample"]["seed"] + 1 and d["preparation"]["pressures"] == [1e5]
    # by volume: c_v = 0.5 at R_l/R_s = 2 means 8 small grains per large one (x = 8/9): 89 of 100
    pv = plan(ratios=(2.0,), concentrations=(0.5,), basis="volume")
    dv = study.case_deck(deck, pv, {"ratio": 2.0, "concentration": 0.5, "realisation": 0})
    assert dv["sample"]["fractions"] == [89.0, 11.0]
    # a concentration of 1 leaves the large species out (no zero fraction in the deck)
    d1 = study.case_deck(deck, plan(ratios=(2.0,), concentrations=(1.0,)),
                         {"ratio": 2.0, "concentration": 1.0, "realisation": 0})
    assert d1["sample"]["radii"] == [pytest.approx(1e-4)] and d1["sample"]["fractions"] == [float(N)]


def test_summarise_gives_numpys_mean_and_sample_std_over_the_converged_cases():
    p = plan(ratios=(1.4,), realisations=3)
    rng = np.random.default_rng(5)
    records = []
    for s, status in enumerate(("ok", "ok", "not_converged")):
        rec = {"ratio": 1.4, "concentration": 0.5, "realisation": s, "status": status,
               "number_concentration": 0.5, "volume_concentration": 0.27,
               "g_r": {"r_over_d": [0.5, 1.5], "g": list(rng.uniform(size=2))},
               "forces": {"edges": [0, 1, 2], "density": list(rng.uniform(size=2))}}
        rec.update({k: float(rng.uniform()) for k in study.MEASURES})
        records.append(rec)
    (row,) = study.summarise(records, p)["points"]
    ok = records[:2]
    assert row["n_realisations"] == 2 and row["n_failed"] == 1
    for k in study.MEASURES:
        v = [q[k] for q in ok]
        assert row[f"{k}_mean"] == pytest.approx(np.mean(v), rel=1e-15)
        assert row[f"{k}_std"] == pytest.approx(np.std(v, ddof=1), rel=1e-12)
    assert row["g_r"]["g"] == pytest.approx(np.mean([q["g_r"]["g"] for q in ok], axis=0))


def mixture(*args, n=2, timeout=1500):
    cmd = ([MPIEXEC, "-n", str(n)] if n > 1 else []) + [sys.executable, "-m", "pardem.drivers.mixture", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)


@pytest.fixture(scope="module")
def quick_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("mix") / "run"
    p = mixture("--quick", "--quiet", "--out", str(out))
    assert p.returncode == 0, p.stderr[-3000:]
    return out, json.loads((out / "mixture.json").read_text())


@pytest.mark.mpi
@pytest.mark.slow
def test_quick_study_on_two_ranks_writes_its_results(quick_study):
    out, data = quick_study
    assert (out / "mixture.png").stat().st_size > 0 and (out / "mixture_structure.png").stat().st_size > 0
    assert [(q["ratio"], q["concentration"]) for q in data["points"]] == [(1.0, 0.0), (1.4, 0.5)]
    assert data["meta"]["n_ranks"] == 2 and len(data["cases"]) == 4
    assert all(c["status"] == "ok" for c in data["cases"])
    assert sorted(os.listdir(out / "records")) == ["rank-0.jsonl", "rank-1.jsonl"]   # both ranks ran cases


@pytest.mark.mpi
@pytest.mark.slow
def test_packings_obey_maxwell_counting_and_the_affine_bound(quick_study):
    _, data = quick_study
    for c in data["cases"]:
        n_alive = c["n"] - c["rattlers"]
        # Maxwell: a rigid frictionless periodic packing of N' grains has N_c >= d (N' - 1) + 1 contacts
        assert c["Z_no_rattlers"] >= (2 * 3 * (n_alive - 1) + 2) / n_alive - 1e-12, c["id"]
        # near jamming Z' - 2d ~ 7.8 (phi - phi_c)^(1/2) (O'Hern et al. 2003, 3D) with phi - phi_c
        # ~ 3 phi <delta/d> (affine overlap): 2x that as the bound at N = 100
        assert c["Z_no_rattlers"] <= 6.0 + 2 * 7.8 * math.sqrt(3 * 0.64 * c["mean_overlap_ratio"]), c["id"]
        # relaxing the non-affine motions can only lower the elastic energy of a strain (the affine
        # modulus is an upper bound); 1e-3: the relaxation's residual energy
        for m in ("K", "mu"):
            assert 0.0 < c[f"{m}_relaxed"] <= c[f"{m}_affine"] * (1 + 1e-3), (c["id"], m)
        assert 0.0 <= c["fabric_anisotropy"] < 1.0 and np.trace(c["fabric"]) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.mpi
@pytest.mark.slow
def test_a_farm_case_equals_the_case_run_alone_and_its_contacts_are_the_overlaps(quick_study):
    """The case that rank 1 ran (index 1: ratio 1, realisation 1) again in this process: the same
    record bit for bit (the farm runs each case alone on its rank); its touching contacts are exactly
    the overlapping pairs that a geometric search finds; g(r) of the bidisperse case peaks where
    small-small, small-large and large-large grains touch."""
    _, data = quick_study
    p = study.Plan(**{k: tuple(v) if isinstance(v, list) else v for k, v in data["plan"].items()})
    deck = load_deck(iso.SCHEMA, DECK, [f"sample.n={N}"])
    case = p.cases()[1]
    assert case == {"ratio": 1.0, "concentration": 0.0, "realisation": 1}
    d = study.case_deck(deck, p, case)
    comm = Communicator().split_self()
    rows, details, packing = iso.sweep(comm, d, d["preparation"]["pressures"])
    rec = study.measure(packing.sim, 3)
    farm = next(c for c in data["cases"] if c["id"] == study.case_id(case))
    for k in ("Z", "Z_no_rattlers", "fabric", "order", "g_r", "forces"):
        assert json.loads(json.dumps(rec[k])) == farm[k], k
    assert rows[0]["K_relaxed"] == farm["K_relaxed"] and rows[0]["solid_fraction"] == farm["solid_fraction"]
    x, radius, *_ = study.state_arrays(packing.sim)
    i, j, _ = structure.overlapping_pairs(x, radius, box=packing.sim.cell.length)
    assert len(i) == rec["n_contacts"]
    bi = next(c for c in data["cases"] if c["ratio"] == 1.4)
    r, g00 = np.array(bi["g_r"]["r_over_d"]), np.array(bi["g_r"]["partial"]["00"])
    width = r[1] - r[0]
    d_mean = 2 * (bi["n_small"] * bi["r_small"] + bi["n_large"] * bi["r_large"]) / bi["n"]
    first = r[np.nonzero(g00)[0][0]]
    assert abs(first - 2 * bi["r_small"] / d_mean) <= width, (first, 2 * bi["r_small"] / d_mean)
    g11 = np.array(bi["g_r"]["partial"]["11"])
    assert abs(r[np.nonzero(g11)[0][0]] - 2 * bi["r_large"] / d_mean) <= width


@pytest.mark.mpi
@pytest.mark.slow
def test_a_restart_reuses_every_recorded_case(quick_study, tmp_path):
    out, data = quick_study
    p = mixture("--quick", "--quiet", "--restart", str(out), "--out", str(tmp_path / "again"), n=1)
    assert p.returncode == 0, p.stderr[-2000:]
    again = json.loads((tmp_path / "again" / "mixture.json").read_text())
    assert again["meta"]["cases_reused"] == 4 and again["points"] == data["points"]
    p = mixture("--quick", "--quiet", "--restart", str(out), "--out", str(tmp_path / "other"),
                "--pressure", "2e5", n=1)
    assert p.returncode == 2 and "another plan" in p.stderr


@pytest.mark.parametrize("args, field", [(["--ratios", "0.5"], "--ratios 0.5"),
                                         (["--concentrations", "0.2,1.5"], "--concentrations 0.2,1.5"),
                                         (["--realisations", "0"], "--realisations 0"),
                                         (["--set", "sample.n=2"], "sample.n")])
def test_bad_options_are_refused_in_one_line(args, field, tmp_path):
    p = mixture(*args, "--out", str(tmp_path / "x"), n=1, timeout=120)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pardem: error: ") and field in lines[0], p.stderr
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_in_2d_the_monodisperse_packing_orders_and_the_mixture_does_not(tmp_path):
    """The quick study in the 2D mode (one rank): Maxwell's count in 2D, the affine bound, and the
    hexatic order: monodisperse frictionless disks jammed by compression form hexagonal crystallites,
    while the 50:50 mixture at size ratio 1.4 is the standard 2D glass former (O'Hern et al. 2003),
    so the local order <|psi_6|> of the monodisperse packing is the higher in each realisation
    (the same gas draws; measured 0.85 and 0.69 against 0.59 and 0.53)."""
    out = tmp_path / "mix2d"
    p = mixture("--quick", "--quiet", "--no-plot", "--set", "domain.dimension=2", "--out", str(out), n=1)
    assert p.returncode == 0, p.stderr[-3000:]
    data = json.loads((out / "mixture.json").read_text())
    cases = {c["id"]: c for c in data["cases"]}
    assert data["order_parameter"] == "psi6"
    for c in cases.values():
        n_alive = c["n"] - c["rattlers"]
        assert c["Z_no_rattlers"] >= (2 * 2 * (n_alive - 1) + 2) / n_alive - 1e-12, c["id"]
        for m in ("K", "mu"):
            assert 0.0 < c[f"{m}_relaxed"] <= c[f"{m}_affine"] * (1 + 1e-3), (c["id"], m)
    for s in range(2):
        mono, mix = cases[f"r1-c0-s{s}"], cases[f"r1.4-c0.5-s{s}"]
        assert mono["order_local"] > mix["order_local"], (s, mono["order_local"], mix["order_local"])
