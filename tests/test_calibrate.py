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
from pardem.config import DeckError
from pardem.io.deck_file import load_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.drivers import calibrate
from pardem.drivers.cli import EXIT_NOT_MEASURED
from pardem.parallel.communicator import Communicator
from pardem.protocols.shear import run_shear
from _util import has_matplotlib

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


@pytest.mark.slow
def test_shear_test_with_three_unequal_directions_measures_the_lattice_modulus_in_every_plane():
    """E r^4 different along L, R and T (x_L : x_R : x_T = 10 : 2.5 : 1 with unequal radius
    ratios): the simulated simple shear in LR, LT and RT gives each plane's beam-theory energy
    modulus (the harmonic mean of its two directions' x, ``shear_modulus_by_energy``) within 1 %
    (the bound of the test above: the loading-rate error of a slope after 8 transits, 0.7 %), and
    the three moduli differ from each other by more than that (the planes are told apart)."""
    R = 0.25e-3
    young, ratio = (2e8, 0.5e8 / 0.8**4, 0.2e8 / 1.1**4), (1.0, 0.8, 1.1)
    x = [e * r**4 for e, r in zip(young, ratio)]
    assert x == pytest.approx([2e8, 0.5e8, 0.2e8], rel=1e-12)
    deck = _lattice_deck(young, ratio, R=R)
    comm = Communicator()
    measured = {}
    for plane in ("LR", "LT", "RT"):
        G = shear_modulus_by_energy(young, ratio, plane, R)
        assert G == pytest.approx(calib.lattice_shear_modulus(young, ratio, plane), rel=1e-9)
        r = run_shear(comm, deck, plane, strain=0.002, transits=8.0)
        assert r["shear_modulus"] == pytest.approx(G, rel=0.01), plane
        measured[plane] = r["shear_modulus"]
    g = sorted(measured.values())
    assert g[1] > 1.05 * g[0] and g[2] > 1.05 * g[1]


def refused(tmp_path, capsys, *args):
    """The driver run in-process with ``args`` and ``--out tmp_path/x`` exits 2 with one line on
    stderr (returned) and writes nothing."""
    with pytest.raises(SystemExit) as exit_info:
        calibrate.main(["--out", str(tmp_path / "x"), "--quiet", *args])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert not (tmp_path / "x").exists()       # nothing was written
    return err


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
    err = refused(tmp_path, capsys, "--config", BEECH, "--set", override)
    assert field in err and ("expected" in err or "allowed" in err)


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
    if has_matplotlib():
        assert (out / "calibration.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the written deck is the compress driver's
    deck = load_deck(COMPRESS_SCHEMA, str(out / calibrate.DECK_NAME))
    assert np.allclose(deck["domain"]["box"], [0.01] * 3)


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


# ---- compact domains: calibration by measurement (pardem.protocols.compact_calibration) ----------------

from pardem.protocols import compact_calibration as cc          # noqa: E402
from pardem.domains.compact import compact_packing               # noqa: E402

# A small compact domain: a cube of 18 radii (about 716 elements; the builder needs the wide size range to
# jam above 0.63 in so small a box), two realisations. Targets: an orthotropic material whose G is within
# reach of a compact beam network (its G / E is nearly fixed, G ~ E / 2: module docstring of
# compact_calibration): the mean moduli of these two realisations with the bonds E^mu = (80, 40, 40) MPa,
# r = 0.9 (TOR), measured once while writing this test and rounded to 4 digits; the iteration does not
# know those bonds (it starts from the closed form with unequal radii) and finds its own. The start is far
# on purpose: the closed-form bonds times 3, 1/3 and 2 on E_L, E_R, E_T and 0.75 on the radii.
COMPACT = ["domain.kind=\"compact\"", "domain.box=[0.0045, 0.0045, 0.0045]", "domain.radius=0.25e-3",
           "domain.dispersity=0.45", "targets.young_L=34.07e6", "targets.young_R=23.60e6",
           "targets.young_T=23.07e6", "targets.shear=13.32e6",
           "targets.density=700", "compact.realisations=2", "compact.transits=4",
           "compact.start_factors=[3.0, 0.3333333333333333, 2.0]", "compact.start_radius_factor=0.75",
           "compact.max_iterations=8"]


def _compact_args(*sets):
    return [a for s in COMPACT + list(sets) for a in ("--set", s)]


def test_law_weights_are_the_laws_log_derivatives():
    """w_bj = d ln v_b / d ln v_j: TOR's is 1 for the nearest axis and 0 otherwise; the spherical law
    v_b = sum_k c_k v_k has w_bj = c_j v_j / v_b; every law is homogeneous of degree 1, so every row sums
    to 1 (Euler). Tolerances: 1e-9 for TOR (the difference's rounding, ~1e-16 / 1e-4), 1e-7 for the smooth
    laws (its truncation, of order h^2 = 1e-8 times the third log-derivative)."""
    rng = np.random.default_rng(0)
    u = rng.normal(size=(50, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    frame = np.eye(3)
    v = (5e8, 1e8, 2e7)
    tor = cc.law_weights("TOR", u, frame, v)
    assert np.allclose(tor, np.eye(3)[np.argmax(np.abs(u), axis=1)], rtol=0, atol=1e-9)
    c = np.abs(u)
    sph = cc.law_weights("spherical", u, frame, v)
    assert np.allclose(sph, c * np.array(v) / (c @ np.array(v))[:, None], rtol=1e-7, atol=0)
    for law in ("hankinson", "linear", "spherical_normalised"):
        w = cc.law_weights(law, u, frame, v)
        assert np.allclose(w.sum(axis=1), 1.0, atol=1e-7)


def test_energy_shares_of_a_lattice_compressed_along_L():
    """An ordered lattice compressed along x = L: only the bonds along L deform, axially (the lattice has
    Poisson ratio 0 and its elements do not turn), so d ln E / d ln E_L = 1, 0 for R and T, and the radius
    share is 2 (axial energy ~ r^2). Tolerance 1e-3: the plate contacts bend the surface bonds a little."""
    raw = {"domain": {"kind": "ordered", "box": [0.003] * 3, "radius": 0.25e-3, "density": 1400.0},
           "bonds": {"young": [4e8, 1e8, 2e8], "radius_ratio": [0.8, 1.0, 0.9], "law": "TOR"}}
    rec = cc.compression_test(Communicator(), raw, "x", None, 0.002, 4.0, "TOR", (4e8, 1e8, 2e8), (0.8, 1.0, 0.9))
    assert rec["modulus"] == pytest.approx(math.pi / 4 * 4e8 * 0.8**2, rel=0.01)     # E^D = pi/4 E r^2
    assert rec["share_E"] == pytest.approx([1.0, 0.0, 0.0], abs=1e-3)
    assert sum(rec["share_r"]) == pytest.approx(2.0, abs=2e-3)


@pytest.mark.slow
def test_energy_shares_predict_the_measured_sensitivity():
    """The envelope theorem: d ln E_x / d ln E_L^mu of a compact domain equals the share of its energy in
    the bonds' E_L part (TOR). Checked against a finite difference of two measurements (E_L^mu x 1.2);
    tolerance 0.03 absolute: the plates' contacts and the loading rate are outside the bonds' energy, and
    the secant over 20 % differs from the tangent (the share moves by 0.005 over it); measured 0.012
    (0.690 against 0.678)."""
    deck = load_deck(calib.CALIBRATE_SCHEMA, None, COMPACT)
    packing = compact_packing(deck["domain"]["box"], 0.25e-3, 0.45, 0, 0)
    y, r = (60e6, 40e6, 40e6), (1.0, 1.0, 1.0)
    recs = []
    for f in (1.0, 1.2):
        yy = (y[0] * f, y[1], y[2])
        raw = cc.compress_raw(deck, yy, r, seed=0)
        recs.append(cc.compression_test(Communicator(), raw, "x", packing, 0.002, 4.0, "TOR", yy, r))
    slope = math.log(recs[1]["modulus"] / recs[0]["modulus"]) / math.log(1.2)
    share = 0.5 * (recs[0]["share_E"][0] + recs[1]["share_E"][0])
    assert 0.3 < share < 0.95                 # a real test: L bonds carry most, not all, of it
    assert slope == pytest.approx(share, abs=0.03)
    assert sum(recs[0]["share_E"]) == pytest.approx(1.0, abs=1e-9)    # Euler: homogeneous in the moduli


@pytest.fixture(scope="module")
def compact_runs(tmp_path_factory):
    """The compact calibration from the far start on 2 ranks (one realisation each) and on 1 rank."""
    base = tmp_path_factory.mktemp("compact")
    two = base / "two"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.calibrate", "--out", str(two),
                        *_compact_args()], capture_output=True, text=True, timeout=900, cwd=ROOT)
    one = base / "one"
    code = calibrate.main(["--out", str(one), "--quiet", *_compact_args()])
    return p, two, code, one


@pytest.mark.slow
@pytest.mark.mpi
def test_compact_calibration_converges_from_a_far_start_on_two_ranks(compact_runs):
    """From bonds 3x off, the iteration meets every target (E_L, E_R, E_T, G_LT) within 2 % (the issue's
    tolerance) on the mean of the two realisations, one per rank; the first measurement was far off; the
    history is in JSON (every iteration, sensitivity rows summing to 1: scaling all bond moduli scales all
    domain moduli) and in a PNG."""
    p, two, _, _ = compact_runs
    assert p.returncode == 0, p.stderr[-3000:]
    rep = json.loads((two / "calibration.json").read_text())
    res = rep["compact"]
    assert rep["n_ranks"] == 2 and res["converged"] and res["seeds"] == [0, 1]
    hist = json.loads((two / calibrate.HISTORY_NAME).read_text())["history"]
    assert len(hist) == res["iterations"] >= 2
    assert max(abs(e) for e in hist[0]["relative_error"].values()) > 0.3          # a far start
    assert all(h["ranks"] == [0, 1] for h in hist)                                # a task farm
    for name, target in res["targets"].items():
        assert abs(hist[-1]["measured"][name] / target - 1) <= 0.02
        assert hist[-1]["measured"][name] == pytest.approx(np.mean([r[name] for r in hist[-1]["per_realisation"]]),
                                                           rel=1e-12)
    for h in hist:
        assert h["sensitivity_E_row_sums"] == pytest.approx([1.0] * 4, abs=1e-9)
    assert (two / calibrate.HISTORY_PLOT).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" or not has_matplotlib()
    assert "calibrated: every mean modulus within 2 %" in p.stdout


@pytest.mark.slow
@pytest.mark.mpi
def test_compact_calibration_is_the_same_on_one_rank(compact_runs):
    """The same realisations on 1 rank give the same iterations, bit for bit (each realisation runs
    alone on a single-rank communicator, whatever the job's size)."""
    _, two, code, one = compact_runs
    assert code == 0
    h2 = json.loads((two / calibrate.HISTORY_NAME).read_text())["history"]
    h1 = json.loads((one / calibrate.HISTORY_NAME).read_text())["history"]
    assert all(h["ranks"] == [0, 0] for h in h1)
    drop = {"ranks"}
    assert [{k: v for k, v in h.items() if k not in drop} for h in h1] == \
        [{k: v for k, v in h.items() if k not in drop} for h in h2]


@pytest.mark.slow
@pytest.mark.mpi
def test_compact_calibrated_deck_measures_the_targets_independently(compact_runs):
    """An independent final measurement: the bonds read back from the written compress deck, the domain
    rebuilt from fresh packings (the deck's seeds), compressed along x, y, z and sheared in LT by this
    test's own calls: every mean modulus within 2 % of its target."""
    _, two, _, _ = compact_runs
    written = load_deck(COMPRESS_SCHEMA, str(two / calibrate.DECK_NAME))
    assert written["domain"]["kind"] == "compact" and written["bonds"]["law"] == "TOR"
    targets = json.loads((two / "calibration.json").read_text())["compact"]["targets"]
    young, ratio = tuple(written["bonds"]["young"]), tuple(written["bonds"]["radius_ratio"])
    dom = written["domain"]
    comm = Communicator().split_self()
    got = {name: [] for name in targets}
    for seed in (0, 1):
        raw = {"domain": dict(dom, seed=seed), "bonds": {k: written["bonds"][k] for k in
                                                          ("young", "radius_ratio", "law", "poisson", "damping")}}
        raw = json.loads(json.dumps(raw))                     # tuples to lists, as a TOML deck holds them
        for k, axis in (("L", "x"), ("R", "y"), ("T", "z")):
            packing = compact_packing(dom["box"], dom["radius"], dom["dispersity"], seed, "xyz".index(axis))
            got[f"young_{k}"].append(cc.compression_test(comm, raw, axis, packing, 0.002, 4.0, "TOR", young,
                                                         ratio)["modulus"])
        packing = compact_packing(dom["box"], dom["radius"], dom["dispersity"], seed, 2)
        E = np.mean([got[f"young_{k}"][-1] for k in "LRT"])
        got["shear_LT"].append(cc.compact_shear(comm, raw, "LT", packing, 0.002, 4.0, 0.4 * E, "TOR", young,
                                                ratio)["modulus"])
    for name, target in targets.items():
        assert abs(np.mean(got[name]) / target - 1) <= 0.02, (name, got[name], target)


@pytest.mark.parametrize("override, field", [
    ("compact.realisations=0", "compact.realisations"),
    ("compact.shear_plane=\"XY\"", "compact.shear_plane"),
    ("compact.tolerance=0", "compact.tolerance"),
    ("compact.max_iterations=0", "compact.max_iterations"),
    ("compact.max_step=0.5", "compact.max_step"),
    ("compact.start_factors=[1, 1]", "compact.start_factors"),
    ("compact.start_radius_factor=20", "compact.start_radius_factor"),
    ("compact.transits=0.5", "compact.transits"),
    ("domain.kind=\"random\"", "domain.kind"),
    ("domain.bond_gap=0", "domain.bond_gap"),
    ("domain.box=[0.001, 0.0045, 0.0045]", "domain.box"),
])
def test_bad_compact_keys_exit_2_naming_the_field(tmp_path, capsys, override, field):
    err = refused(tmp_path, capsys, *_compact_args(override))
    assert field in err and "expected" in err, err


def test_verify_is_refused_for_a_compact_domain(tmp_path, capsys):
    err = refused(tmp_path, capsys, "--verify", *_compact_args())
    assert "--verify" in err and "compact" in err


@pytest.mark.slow
def test_compact_calibration_that_does_not_converge_exits_6(tmp_path, capsys):
    """One measurement allowed from the far start: the targets are missed, exit code 6 (as the ordered
    verification's miss), the history and the deck of the last measured bonds are written."""
    out = tmp_path / "cap"
    code = calibrate.main(["--out", str(out), "--quiet",
                           *_compact_args("compact.max_iterations=1", "compact.realisations=1")])
    assert code == calibrate.EXIT_VERIFY_FAILED == 6
    rep = json.loads((out / "calibration.json").read_text())["compact"]
    assert not rep["converged"] and rep["iterations"] == 1
    assert "did not converge" in capsys.readouterr().err
    assert load_deck(COMPRESS_SCHEMA, str(out / calibrate.DECK_NAME))["domain"]["kind"] == "compact"
