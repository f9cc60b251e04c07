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
from pardem.drivers.cli import EXIT_NOT_MEASURED
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
    cal = calib.calibrate(t, "section6")
    # W's two pairs imply G = 7.735e8 and 7.690e8 Pa; the deck's one G^D = 7.7e8 sits between them
    assert cal.radius_ratio[0] == pytest.approx(W_L[1], rel=0.005)
    assert cal.radius_ratio[2] == pytest.approx(W_T[1], rel=0.005)
    assert cal.young[0] == pytest.approx(W_L[0], rel=0.01)
    assert cal.young[2] == pytest.approx(W_T[0], rel=0.01)
    assert cal.young[1] == cal.young[2] and cal.radius_ratio[1] == cal.radius_ratio[2]   # E_R^D = "same"
    assert cal.element_density == pytest.approx(6 / math.pi * 720.0)


# ---- independent beam-theory stiffness of the face-bonded cubic lattice (docs/physics.md section 2) ----
# Per element of a lattice of spacing l = 2R there is one bond along each axis and a volume l^3. A bond
# (E, r) has ka = E pi (r R)^2 / l, beta = E I = E pi (r R)^4 / 4, and the elastic energy
# 1/2 ka dL^2 + (2 beta / l) (th1.th1 + th1.th2 + th2.th2), th_k = end rotation relative to the chord.


def axial_modulus_by_springs(E, r, R):
    """Uniaxial strain eps along a lattice axis: each bond along it stretches by eps l, so the
    energy per volume is 1/2 ka (eps l)^2 / l^3 = 1/2 E^D eps^2."""
    l = 2 * R
    ka = E * math.pi * (r * R) ** 2 / l
    eps = 1e-4
    return 2 * (0.5 * ka * (eps * l) ** 2 / l**3) / eps**2


def shear_modulus_by_energy(young, ratio, plane, R, rotation="free"):
    """Simple shear u_a = gamma X_b of the lattice: the chords along b turn by gamma, those along a
    and c do not; every element turns by omega about e_b x e_a (both ends of a bond alike, so
    th1 = th2 = omega - chord rotation). ``rotation="free"``: omega minimises the energy (found here
    numerically: the energy is sampled at three omegas and its parabola's minimum taken);
    ``"blocked"``: omega = 0 (W's assumption). Returns G = 2 W / gamma^2 [Pa], W per volume."""
    a, b = calib.SHEAR_PLANES[plane]
    l = 2 * R
    beta = [E * math.pi * (r * R) ** 4 / 4 for E, r in zip(young, ratio)]
    gamma = 1e-4

    def energy(omega):
        bond = lambda k, th: (2 * beta[k] / l) * 3 * th**2
        return (bond(b, omega - gamma) + bond(a, omega)) / l**3

    if rotation == "blocked":
        W = energy(0.0)
    else:
        w = np.array([-gamma, 0.0, gamma])
        c2, c1, c0 = np.polyfit(w, [energy(x) for x in w], 2)
        W = c0 - c1**2 / (4 * c2)
    return 2 * W / gamma**2


def test_exact_relations_give_the_targets_by_beam_theory():
    """The exact relations' bonds give E_k^D by the springs and G^D in every plane by the lattice's
    free-rotation energy; section 6's bonds give G^D only with the rotations blocked (W's assumption)
    and half of it when the elements turn. Tolerance 1e-9: the parabola fit's rounding."""
    t = calib.Targets(young_L=12e9, young_R=1.1e9, young_T=0.6e9, shear=0.5e9, density=650.0)
    R = 0.3e-3
    exact, sec6 = calib.calibrate(t, "exact"), calib.calibrate(t, "section6")
    for cal in (exact, sec6):
        for k, E_D in enumerate(t.young()):
            assert axial_modulus_by_springs(cal.young[k], cal.radius_ratio[k], R) == pytest.approx(E_D, rel=1e-9)
    for plane in calib.SHEAR_PLANES:
        assert shear_modulus_by_energy(exact.young, exact.radius_ratio, plane, R) == pytest.approx(t.shear, rel=1e-9)
        assert shear_modulus_by_energy(sec6.young, sec6.radius_ratio, plane, R, "blocked") == pytest.approx(
            t.shear, rel=1e-9)
        assert shear_modulus_by_energy(sec6.young, sec6.radius_ratio, plane, R) == pytest.approx(
            t.shear / 2, rel=1e-9)
    # both reported, and the prediction of the code agrees with the energy for unequal bonds too
    young, ratio = (2e9, 1e8, 3e8), (0.4, 1.2, 0.9)
    for plane in calib.SHEAR_PLANES:
        assert calib.lattice_shear_modulus(young, ratio, plane) == pytest.approx(
            shear_modulus_by_energy(young, ratio, plane, R), rel=1e-9)


def test_thresholds_scale_with_the_bond_section():
    """A bond carrying sigma_k^mu over its section pi (r R)^2 carries sigma_k^D over its face (2R)^2."""
    t = calib.Targets(young_L=12e9, young_R=1.1e9, young_T=0.6e9, shear=0.5e9, density=650.0,
                      tensile_strength=(100e6, 8e6, 5e6), shear_strength=(12e6, 12e6, 12e6),
                      densification_stress=6e6, densification_p0=0.1)
    R = 1e-3
    for rel in calib.RELATIONS:
        cal = calib.calibrate(t, rel)
        for k in range(3):
            S = math.pi * (cal.radius_ratio[k] * R) ** 2
            assert cal.tensile_strength[k] * S == pytest.approx(t.tensile_strength[k] * (2 * R) ** 2, rel=1e-12)
            assert cal.shear_strength[k] * S == pytest.approx(t.shear_strength[k] * (2 * R) ** 2, rel=1e-12)
        S_T = math.pi * (cal.radius_ratio[2] * R) ** 2
        assert cal.densification_stress * S_T == pytest.approx(6e6 * (2 * R) ** 2, rel=1e-12)
        assert cal.densification_p0 == 0.1


def _lattice_deck(young, ratio, n=6, R=0.25e-3, density=1375.0):
    return load_deck(COMPRESS_SCHEMA, None, [
        f"domain.box=[{2 * n * R}, {2 * n * R}, {2 * n * R}]", f"domain.radius={R}", f"domain.density={density}",
        f"bonds.young={list(young)}", f"bonds.radius_ratio={list(ratio)}"])


@pytest.mark.slow
def test_shear_test_measures_the_lattice_modulus_one_rank():
    """One rank, 6^3 elements. Bonds of the exact calibration (equal E r^4), planes LT and LR, and
    bonds with E r^4 ten times larger along L than along T (plane LT, and RT where R = T): the
    face-driven simple shear gives the beam-theory energy's G (``shear_modulus_by_energy``) within 1 %
    (the interior is in the uniform state, measured within 1e-5 of it; 1 % leaves room only for the
    loading-rate error of a slope after 8 transits, 0.7 %). The naive test (two layers driven, not
    turning) is far below it (measured -18 % on 8^3): the free faces normal to the shear direction
    carry no shear traction."""
    _, t = beech_targets()
    cal = calib.calibrate(t, "exact")
    R = 0.25e-3
    comm = Communicator()
    deck = _lattice_deck(cal.young, cal.radius_ratio, R=R, density=cal.element_density)
    for plane in ("LT", "LR"):
        G = shear_modulus_by_energy(cal.young, cal.radius_ratio, plane, R)
        assert G == pytest.approx(t.shear, rel=1e-9)
        r = run_shear(comm, deck, plane, strain=0.002, transits=8.0)
        assert r["n_elements"] == 6**3 and r["n_driven"] == (6**2 - 4**2) * 6    # the ring of the (a, b) faces
        assert r["shear_modulus"] == pytest.approx(G, rel=0.01)
        assert r["gamma"] == pytest.approx(0.002, rel=0.01)
    naive = run_shear(comm, deck, "LT", strain=0.002, transits=8.0, drive="layers")
    assert naive["shear_modulus"] < 0.9 * t.shear
    # unequal E r^4: x_L = 10 x_T (E_L r_L^4 = 2e8 * 1.0, E_T r_T^4 = 2e8 / 10 * 1.0)
    young, ratio = (2e8, 2e7, 2e7), (1.0, 1.0, 1.0)
    deck = _lattice_deck(young, ratio, R=R)
    for plane in ("LT", "RT"):
        G = shear_modulus_by_energy(young, ratio, plane, R)
        r = run_shear(comm, deck, plane, strain=0.002, transits=8.0)
        assert r["shear_modulus"] == pytest.approx(G, rel=0.01), plane


@pytest.mark.parametrize("override, field", [
    ("targets.shear=1e12", "targets.shear"),                 # r_T would exceed R_MAX
    ("targets.young_L=-5e9", "targets.young_L"),
    ("targets.young_R=\"other\"", "targets.young_R"),
    ("targets.tensile_strength=[1e8, 0, 5e6]", "targets.tensile_strength"),
    ("targets.densification_p0=0", "targets.densification_p0"),
    ("verify.shear_plane=\"XY\"", "verify.shear_plane"),
    ("bonds.relations=\"approximate\"", "bonds.relations"),
    ("output.vtk_every=-1", "output.vtk_every"),
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
    """Without --verify: the deck loads in the compress driver's schema and holds the calibration of
    the deck's relations (default exact); the report holds both relations' bonds and predictions and
    the lattice's Poisson ratio 0."""
    out = tmp_path / "cal"
    assert calibrate.main(["--config", BEECH, "--out", str(out), "--quiet"]) == 0
    deck = load_deck(COMPRESS_SCHEMA, str(out / calibrate.DECK_NAME))
    _, t = beech_targets()
    cal = calib.calibrate(t, "exact")
    assert deck["domain"]["kind"] == "ordered" and deck["bonds"]["law"] == "TOR"
    assert deck["bonds"]["young"] == pytest.approx(cal.young, rel=1e-15)
    assert deck["bonds"]["radius_ratio"] == pytest.approx(cal.radius_ratio, rel=1e-15)
    assert deck["domain"]["density"] == pytest.approx(cal.element_density, rel=1e-15)
    if calibrate.strengths_supported():
        assert deck["bonds"]["tensile_strength"] == pytest.approx(cal.tensile_strength, rel=1e-15)
        assert deck["bonds"]["densification_stress"] == pytest.approx(cal.densification_stress, rel=1e-15)
    report = json.loads((out / "calibration.json").read_text())
    assert "verification" not in report and report["relations"] == "exact"
    assert report["bonds"]["young"] == pytest.approx(list(cal.young), rel=1e-15)
    both = report["calibrations"]
    assert both["section6"]["bonds"]["radius_ratio"][0] == pytest.approx(W_L[1], rel=0.005)   # W's set
    R = 0.2381e-3
    for rel, G_lattice in (("exact", t.shear), ("section6", t.shear / 2)):
        b = both[rel]["bonds"]
        for plane in calib.SHEAR_PLANES:
            assert both[rel]["predicted"][f"shear_{plane}"] == pytest.approx(
                shear_modulus_by_energy(b["young"], b["radius_ratio"], plane, R), rel=1e-9)
            assert both[rel]["predicted"][f"shear_{plane}"] == pytest.approx(G_lattice, rel=1e-9)
    assert report["poisson_ratio"] == 0.0 and "Poisson ratio 0" in report["poisson_note"]
    text = (out / calibrate.DECK_NAME).read_text()
    assert "Poisson ratio 0" in text and "relations = exact" in text


def _verify(out, *extra, ranks=2, timeout=600):
    cmd = [sys.executable, "-m", "pardem.drivers.calibrate", "--config", BEECH, "--verify", "--quick",
           "--out", str(out), *extra]
    if ranks > 1:
        cmd = [MPIEXEC, "-n", str(ranks), *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)


@pytest.mark.slow
def test_quick_verification_on_two_ranks(tmp_path):
    """The issue's check: --verify --quick on 2 ranks with the exact relations measures E_L, E_R, E_T
    (compressions) and G_LR, G_LT, G_RT (simple shears), each within 2 % of its target; it fails if G
    misses. Tolerance 2 %, the issue's; the lattice is exact in the uniform state, and the measured
    slopes were within 4e-4 of the targets (8^3 elements, 8 transits, loading-rate error of a slope
    about 0.7 %). Series (CSV, HDF5 with units), records, summary and plot per run."""
    out = tmp_path / "two"
    p = _verify(out, "--set", "verify.shear_plane=\"all\"")
    assert p.returncode == 0, p.stderr
    report = json.loads((out / "calibration.json").read_text())
    v = report["verification"]
    assert report["n_ranks"] == 2 and v["domain"]["quick"] and v["relations"] == "exact"
    q = v["quantities"]
    _, t = beech_targets()
    targets = {"compression_L": t.young_L, "compression_R": t.young_T, "compression_T": t.young_T,
               "shear_LR": t.shear, "shear_LT": t.shear, "shear_RT": t.shear}
    assert sorted(q) == sorted(targets)
    for name, target in targets.items():
        assert q[name]["target"] == pytest.approx(target)
        assert abs(q[name]["measured"] / target - 1) < 0.02, name
        assert q[name]["relative_error"] == pytest.approx(q[name]["measured"] / target - 1)
    assert v["verification_ok"] and v["targets_met"]
    for name in ("compression_L", "compression_T"):    # the lattice's Poisson ratio 0
        assert all(abs(nu) < 1e-6 for nu in q[name]["poisson_ratios"].values())
    assert v["runs"]["shear_LT"]["gamma"] == pytest.approx(0.002, rel=0.01)
    # rank 0 alone prints
    assert p.stdout.count(": calibration (docs/physics.md") == p.stdout.count("verification (every") == 1
    assert p.stdout.count("calibration.json") == 1
    # outputs per run
    from pardem.io.series import read_series
    from pardem.io.series_h5 import read_series_h5
    import h5py
    for name in targets:
        assert (out / "series" / f"{name}.csv").exists()
        with h5py.File(out / "series" / f"{name}.h5") as f:
            assert all("units" in f[c].attrs for c in f.attrs["columns"])
    g = read_series(str(out / "series" / "shear_LT.csv"), columns=None)
    assert g["gamma"][-1] == pytest.approx(v["runs"]["shear_LT"]["gamma"], rel=1e-12)
    assert read_series_h5(str(out / "series" / "shear_LT.h5"))["stress"][-1] == pytest.approx(g["stress"][-1])
    assert len((out / "records" / "rank-0.jsonl").read_text().splitlines()) == 6
    if _has_matplotlib():
        assert (out / "calibration.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the written deck is the compress driver's
    deck = load_deck(COMPRESS_SCHEMA, str(out / calibrate.DECK_NAME))
    assert np.allclose(deck["domain"]["box"], [0.01] * 3)


def _has_matplotlib():
    try:
        import matplotlib  # noqa: F401
        return True
    except ImportError:
        return False


@pytest.mark.slow
def test_section6_verification_states_the_shear_error(tmp_path):
    """bonds.relations = section6 (W's bonds): E within 2 % of the targets, G within 2 % of the
    lattice's beam-theory energy (``shear_modulus_by_energy``), which is G^D / 2: the report says the
    targets are not met (relative error of G about -0.5) and the verification of the lattice passes."""
    out = tmp_path / "s6"
    p = _verify(out, "--set", "bonds.relations=\"section6\"", "--set", "verify.shear_plane=\"LT\"", ranks=1)
    assert p.returncode == 0, p.stderr
    v = json.loads((out / "calibration.json").read_text())["verification"]
    _, t = beech_targets()
    cal = calib.calibrate(t, "section6")
    G_lattice = shear_modulus_by_energy(cal.young, cal.radius_ratio, "LT", 0.2381e-3)
    G = v["quantities"]["shear_LT"]
    assert G["measured"] == pytest.approx(G_lattice, rel=0.02)
    assert G["relative_error"] == pytest.approx(G_lattice / t.shear - 1, abs=0.02)
    assert v["verification_ok"] and not v["targets_met"]
    assert "targets met within 2 %: no" in p.stdout


@pytest.mark.slow
def test_restart_runs_only_what_is_missing(tmp_path):
    """A verification cut after two runs (its records file truncated mid-line, as by a kill) continues
    with --restart into a new folder: the recorded runs are not run again, the cut folder is left as
    it was, and the report equals the uninterrupted run's (the runs are deterministic on one rank:
    bitwise the same moduli)."""
    full, cut = tmp_path / "full", tmp_path / "cut"
    extra = ["--set", "verify.shear_plane=\"LT\"", "--quiet"]
    assert _verify(full, *extra, ranks=1).returncode == 0
    assert _verify(cut, *extra, ranks=1).returncode == 0
    log = cut / "records" / "rank-0.jsonl"
    lines = log.read_text().splitlines(keepends=True)
    log.write_text("".join(lines[:2]) + lines[2][:40])
    (cut / "calibration.json").unlink()
    cut_log = log.read_text()
    new = tmp_path / "continued"
    p = subprocess.run([sys.executable, "-m", "pardem.drivers.calibrate", "--restart", str(cut), "--verify",
                        "--quick", "--out", str(new), *extra[2:]], capture_output=True, text=True, timeout=600,
                       cwd=ROOT)
    assert p.returncode == 0, p.stderr
    assert log.read_text() == cut_log and not (cut / "calibration.json").exists()
    assert len((new / "records" / "rank-0.jsonl").read_text().splitlines()) == 4     # 2 copied + 2 run
    a = json.loads((full / "calibration.json").read_text())["verification"]["quantities"]
    b = json.loads((new / "calibration.json").read_text())
    assert b["runs_reused"] == ["compression_L", "compression_R"]
    for name in a:
        assert b["verification"]["quantities"][name]["measured"] == a[name]["measured"], name
    # another deck in the same directory: refused with one line, exit 2
    p = subprocess.run([sys.executable, "-m", "pardem.drivers.calibrate", "--config", BEECH, "--restart", str(cut),
                        "--verify", "--quick", "--set", "targets.shear=7e8", "--out", str(tmp_path / "other"),
                        *extra], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert p.returncode == 2 and "--restart" in p.stderr and p.stderr.count("\n") == 1
    assert not (tmp_path / "other").exists()
    # a new run into a directory holding results: refused
    p = _verify(cut, *extra, ranks=1)
    assert p.returncode == 2 and "holds the results of another run" in p.stderr


def test_too_short_to_measure_exits_5(tmp_path):
    """--steps 20 per run: no sample after the ramp, so no modulus: exit 5 (cli.EXIT_NOT_MEASURED)
    and a line saying so."""
    p = _verify(tmp_path / "short", "--steps", "20", "--set", "verify.shear=false", ranks=1, timeout=300)
    assert p.returncode == EXIT_NOT_MEASURED == 5, p.stderr
    assert "too short to measure" in p.stderr
    assert json.loads((tmp_path / "short" / "calibration.json").read_text())["verification"]["measured"] is False


def test_help_lists_choices():
    p = subprocess.run([sys.executable, "-m", "pardem.drivers.calibrate", "--help"], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert p.returncode == 0
    assert "exact" in p.stdout and "section6" in p.stdout and "--restart" in p.stdout and "--steps" in p.stdout


@pytest.mark.slow
def test_a_missed_modulus_fails_the_verification(tmp_path):
    """verify.tolerance = 1e-7, far below the measured errors (about 1e-4, loading rate and the fit):
    the verification fails, exit 6, and says so."""
    p = _verify(tmp_path / "strict", "--set", "verify.tolerance=1e-7", "--set", "verify.shear_plane=\"LT\"",
                ranks=1)
    assert p.returncode == calibrate.EXIT_VERIFY_FAILED == 6, p.stderr
    v = json.loads((tmp_path / "strict" / "calibration.json").read_text())["verification"]
    assert not v["verification_ok"] and "lattice's prediction): NO" in p.stdout
