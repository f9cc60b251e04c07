"""The calibration of docs/physics.md section 6 and the calibrate driver (deck, report, verification on 2 ranks)."""
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from pardem.protocols import calibration as calib
from pardem.config import DeckError, load_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.drivers import calibrate
from pardem.parallel.communicator import Communicator
from pardem.protocols.shear import run_shear

MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BEECH = os.path.join(ROOT, "drivers", "calibrate_beech.toml")

# W's calibrated beech bonds (docs/physics.md section 6)
W_L = (1.1072e11, 0.33)
W_T = (7.73e8, 1.14)


def beech_targets():
    deck = load_deck(calib.CALIBRATE_SCHEMA, BEECH)
    return deck, calib.Targets.from_deck(deck)


def test_beech_deck_reproduces_W_bond_set():
    """The beech targets give back W's E^mu and r within the rounding of W's published set."""
    deck, t = beech_targets()
    # the deck's moduli are W's bonds through E^D = pi/4 E^mu r^2 (written with 5 digits)
    assert t.young_L == pytest.approx(math.pi / 4 * W_L[0] * W_L[1] ** 2, rel=1e-4)
    assert t.young_T == pytest.approx(math.pi / 4 * W_T[0] * W_T[1] ** 2, rel=1e-4)
    cal = calib.calibrate(t)
    # W's two pairs imply G = 7.735e8 and 7.690e8 Pa; the deck's one G^D = 7.7e8 sits between them
    assert cal.radius_ratio[0] == pytest.approx(W_L[1], rel=0.005)
    assert cal.radius_ratio[2] == pytest.approx(W_T[1], rel=0.005)
    assert cal.young[0] == pytest.approx(W_L[0], rel=0.01)
    assert cal.young[2] == pytest.approx(W_T[0], rel=0.01)
    assert cal.young[1] == cal.young[2] and cal.radius_ratio[1] == cal.radius_ratio[2]   # E_R^D = "same"
    assert cal.element_density == pytest.approx(6 / math.pi * 720.0)


def test_section6_relations_hold_exactly():
    """Both section 6 equations hold per direction; thresholds scale by 4 / (pi r^2)."""
    t = calib.Targets(young_L=12e9, young_R=1.1e9, young_T=0.6e9, shear=0.5e9, density=650.0,
                      tensile_strength=(100e6, 8e6, 5e6), shear_strength=(12e6, 12e6, 12e6),
                      densification_stress=6e6, densification_p0=0.1)
    cal = calib.calibrate(t)
    for k, E_D in enumerate(t.young()):
        E, r = cal.young[k], cal.radius_ratio[k]
        assert E * r**2 == pytest.approx(4 / math.pi * E_D, rel=1e-12)
        assert E * r**4 == pytest.approx(16 / (3 * math.pi) * t.shear, rel=1e-12)
        assert calib.lattice_young(E, r) == pytest.approx(E_D, rel=1e-12)
        assert calib.section6_shear_modulus(E, r) == pytest.approx(t.shear, rel=1e-12)
        area_ratio = math.pi * r**2 / 4          # bond section over the represented face (2R)^2
        assert cal.tensile_strength[k] * area_ratio == pytest.approx(t.tensile_strength[k], rel=1e-12)
        assert cal.shear_strength[k] * area_ratio == pytest.approx(t.shear_strength[k], rel=1e-12)
    assert cal.densification_stress * math.pi * cal.radius_ratio[2] ** 2 / 4 == pytest.approx(6e6, rel=1e-12)
    assert cal.densification_p0 == 0.1
    # beam theory of the lattice: (3 pi / 32) E r^4 for equal bonds, half of section 6
    pred = calib.predictions(cal, "LT")
    assert pred["shear_beam"] == pytest.approx(3 * math.pi / 32 * 16 / (3 * math.pi) * t.shear, rel=1e-12)
    assert pred["shear_section6"] == pytest.approx(t.shear, rel=1e-12)


def test_lattice_shear_modulus_by_hand():
    """Independent derivation for unequal bonds: a bond along b of length l = 2R carries the shear
    force 12 beta_a beta_b / (beta_a + beta_b) gamma / l^2 (beta = E pi (r R)^4 / 4), one per l^2."""
    R = 1e-3
    young, ratio = (2e9, 1e8, 3e8), (0.4, 1.2, 0.9)
    beta = [E * math.pi * (r * R) ** 4 / 4 for E, r in zip(young, ratio)]
    l = 2 * R
    for plane, (a, b) in calib.SHEAR_PLANES.items():
        force_per_strain = 12 * beta[a] * beta[b] / (beta[a] + beta[b]) / l**2
        assert calib.lattice_shear_modulus(young, ratio, plane) == pytest.approx(force_per_strain / l**2, rel=1e-12)


def test_shear_test_measures_the_lattice_modulus_one_rank():
    """One rank, 6^3 calibrated elements, planes LT and LR: the face-driven simple shear gives the beam
    value (1 %, as in the 2-rank test), the naive test (two layers driven, not turning) is far below it
    (measured -18 % on 8^3): the free faces normal to the shear direction carry no shear traction."""
    _, t = beech_targets()
    cal = calib.calibrate(t)
    R = 0.25e-3
    deck = load_deck(COMPRESS_SCHEMA, None, [
        f"domain.box=[{12 * R}, {12 * R}, {12 * R}]", f"domain.radius={R}", f"domain.density={cal.element_density}",
        f"bonds.young={list(cal.young)}", f"bonds.radius_ratio={list(cal.radius_ratio)}"])
    comm = Communicator()
    for plane in ("LT", "LR"):
        beam = calib.lattice_shear_modulus(cal.young, cal.radius_ratio, plane)
        r = run_shear(comm, deck, plane, strain=0.002, transits=8.0)
        assert r["n_elements"] == 6**3 and r["n_driven"] == (6**2 - 4**2) * 6    # the ring of the (a, b) faces
        assert r["shear_modulus"] == pytest.approx(beam, rel=0.01)
        assert r["gamma"] == pytest.approx(0.002, rel=0.01)
    naive = run_shear(comm, deck, "LT", strain=0.002, transits=8.0, drive="layers")
    assert naive["shear_modulus"] < 0.9 * calib.lattice_shear_modulus(cal.young, cal.radius_ratio, "LT")


@pytest.mark.parametrize("override, field", [
    ("targets.shear=1e12", "targets.shear"),                 # r_T would exceed R_MAX
    ("targets.young_L=-5e9", "targets.young_L"),
    ("targets.young_R=\"other\"", "targets.young_R"),
    ("targets.tensile_strength=[1e8, 0, 5e6]", "targets.tensile_strength"),
    ("targets.densification_p0=0", "targets.densification_p0"),
    ("verify.shear_plane=\"XY\"", "verify.shear_plane"),
    ("targets.colour=1", "targets.colour"),
])
def test_bad_targets_exit_2_naming_the_field(tmp_path, capsys, override, field):
    with pytest.raises(SystemExit) as exit_info:
        calibrate.main(["--config", BEECH, "--set", override, "--out", str(tmp_path / "x"), "--quiet"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert field in err and ("expected" in err or "allowed" in err) and err.count("\n") == 1
    assert not (tmp_path / "x").exists()       # nothing was written


def test_shear_limit_message_gives_the_range():
    with pytest.raises(DeckError, match=r"targets.shear = .* expected a number in \(0, "):
        calib.calibrate(calib.Targets(young_L=1e10, young_T=1e8, shear=1e9, density=500.0))


def test_driver_writes_a_compress_deck(tmp_path):
    """Without --verify: the deck loads in the compress driver's schema and holds the calibration."""
    out = tmp_path / "cal"
    assert calibrate.main(["--config", BEECH, "--out", str(out), "--quiet"]) == 0
    deck = load_deck(COMPRESS_SCHEMA, str(out / calibrate.DECK_NAME))
    _, t = beech_targets()
    cal = calib.calibrate(t)
    assert deck["domain"]["kind"] == "ordered" and deck["bonds"]["law"] == "TOR"
    assert deck["bonds"]["young"] == pytest.approx(cal.young, rel=1e-15)
    assert deck["bonds"]["radius_ratio"] == pytest.approx(cal.radius_ratio, rel=1e-15)
    assert deck["domain"]["density"] == pytest.approx(cal.element_density, rel=1e-15)
    if calibrate.strengths_supported():
        assert deck["bonds"]["tensile_strength"] == pytest.approx(cal.tensile_strength, rel=1e-15)
        assert deck["bonds"]["densification_stress"] == pytest.approx(cal.densification_stress, rel=1e-15)
    report = json.loads((out / "calibration.json").read_text())
    assert "verification" not in report
    assert report["bonds"]["young"] == pytest.approx(list(cal.young), rel=1e-15)


def test_quick_verification_on_two_ranks(tmp_path):
    """The issue's round trip: --verify --quick on 2 ranks gives E_L^D and E_T^D within 2 % of the
    targets; the shear test measures the beam-theory G of the lattice (half of section 6's).

    Tolerance of G against beam theory, 1 %: the uniform interior state makes the lattice's G exact, and
    the measured slope was within 2e-6 of it (8^3 elements, 8 transits); 1 % leaves room only for the
    loading-rate error of a slope (0.7 % after 8 transits, ``pardem.protocols.anisotropy_study``).
    """
    out = tmp_path / "two"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.calibrate", "--config", BEECH,
                        "--verify", "--quick", "--out", str(out)], capture_output=True, text=True, timeout=300,
                       cwd=ROOT)
    assert p.returncode == 0, p.stderr
    report = json.loads((out / "calibration.json").read_text())
    v = report["verification"]
    assert report["n_ranks"] == 2 and v["domain"]["quick"]
    q = v["quantities"]
    _, t = beech_targets()
    for name, target in (("young_L", t.young_L), ("young_T", t.young_T)):
        assert q[name]["target"] == pytest.approx(target)
        assert abs(q[name]["measured"] / target - 1) < 0.02
        assert q[name]["relative_error"] == pytest.approx(q[name]["measured"] / target - 1)
    assert v["round_trip_ok"]
    G = q["shear"]
    assert G["target"] == pytest.approx(t.shear)
    assert G["beam_theory"] == pytest.approx(3 * math.pi / 32 * 16 / (3 * math.pi) * t.shear, rel=1e-9)
    assert G["section6"] == pytest.approx(2 * G["beam_theory"], rel=1e-12)
    assert G["measured"] == pytest.approx(G["beam_theory"], rel=0.01)
    assert G["relative_error"] == pytest.approx(-0.5, abs=0.01)       # section 6 is twice the lattice's G
    assert v["runs"]["shear"]["gamma"] == pytest.approx(0.002, rel=0.01)
    # rank 0 alone prints
    assert p.stdout.count(": calibration (docs/physics.md") == p.stdout.count("round trip") == 1
    assert p.stdout.count("calibration.json in") == 1
    # the written deck is the compress driver's
    deck = load_deck(COMPRESS_SCHEMA, str(out / calibrate.DECK_NAME))
    assert np.allclose(deck["domain"]["box"], [0.01] * 3)
