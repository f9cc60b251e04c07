"""The compact domain's off-axis curve (issue 15, item 4): compact packings compressed along x with
their LRT frame tilted by xi = 0, 10, ..., 90 deg about z (bonds E_L/E_R = 25, hankinson and linear
laws), against Hankinson's E0 E90 / (E0 sin^2 xi + E90 cos^2 xi) from the measured E(0), E(90).

References: the study's dynamic compression (``anisotropy_study.run_case``) is compared with the
static linear response of the same bonds between the same plates
(``pardem.protocols.compression.static_modulus``) at three tilts; the curve is the mean over four
realisations (seeds 0-3) of the static moduli, reduced by the study's own ``summarise``. Domain:
``_compact_domains.DOMAIN`` (about 725 elements).

Shape. Every law depends on the absolute direction cosines and the packings' fabric is statistically
isotropic, so the ensemble is orthotropic in the tilted frame (as far as the flat loaded faces between
frictionless plates leave the stress uniaxial): 1/E(xi) = c^4/E0 + s^4/E90 + K s^2 c^2
(c, s = cos xi, sin xi) for one K [1/Pa]. d(1/E)/d(s^2) is linear in s^2 with end values K - 2/E0 and
2/E90 - K, so E falls from E0 to E90 at every angle if and only if 2/E0 <= K <= 2/E90: a monotone
curve lies in the band between those two orthotropic curves (``band``). Hankinson's curve is
K = 1/E0 + 1/E90, inside. Nothing makes a network of beams follow Hankinson exactly; how close each law
comes is measured, within the realisation scatter below.

Realisation scatter (measured 2026-12 on this domain, 16 seeds 0-15, static solves): the standard
deviation over seeds of one realisation's E(xi)/Hankinson - 1 at xi = 10, 20, ..., 80 deg, rounded up
to 0.1 %. A mean over n = 4 seeds has a standard error SIGMA / 2.
  hankinson law: 0.49 0.82 1.01 1.07 0.98 0.78 0.52 0.26 %  (16-seed mean within 0.12 % of Hankinson)
  linear law:    0.57 1.23 2.06 2.69 3.40 3.55 2.35 1.49 %  (16-seed mean 0.9 2.7 4.4 5.0 4.8 3.5 2.5 1.2 %
                                                             above Hankinson)
"""
import math

import numpy as np
import pytest

import _compact_domains as cd
from pardem.parallel.communicator import Communicator
from pardem.protocols import anisotropy_study as study

RATIO = 25.0                                    # E_L / E_R of the bonds
XI = tuple(10.0 * k for k in range(10))         # deg
INNER = XI[1:-1]
SEEDS = (0, 1, 2, 3)
SIGMA = {"hankinson": (0.5, 0.9, 1.1, 1.1, 1.0, 0.8, 0.6, 0.3),
         "linear": (0.6, 1.3, 2.1, 2.7, 3.4, 3.6, 2.4, 1.5)}      # % per inner angle, see the docstring
LAWS = tuple(SIGMA)

# The study's slope (8 axial wave transits) against the static response, measured on seed 0: linear
# 40 deg -1.3 %, hankinson 30 and 60 deg -0.7 %, -0.4 %. Mostly the loading rate (the linear case at 16
# transits: +0.05 %), some geometric non-linearity of a domain that shears as it shortens (at strain
# 5e-4 instead of 2e-3: -0.9 %); the plates' contact set adds 0.05 % (tests/test_compact.py). The
# study's own figure for 8 transits, 0.7 %, is exceeded by the tilted compact case; allowed 2 %.
DYNAMIC_VS_STATIC = 0.02


def hankinson(E0, E90, xi):
    """Hankinson's off-axis modulus [Pa], written out here (the study's ``hankinson`` is checked)."""
    s2 = math.sin(math.radians(xi)) ** 2
    return E0 * E90 / (E0 * s2 + E90 * (1.0 - s2))


def orthotropic(E0, E90, K, xi):
    """1 / (c^4/E0 + s^4/E90 + K s^2 c^2) [Pa]: uniaxial modulus of an orthotropic solid at ``xi`` deg."""
    c2 = math.cos(math.radians(xi)) ** 2
    return 1.0 / (c2 * c2 / E0 + (1 - c2) ** 2 / E90 + K * c2 * (1 - c2))


def band(E0, E90, xi):
    """(lowest, highest) modulus [Pa] at ``xi`` of an orthotropic solid whose E falls monotonically from
    ``E0`` to ``E90`` (K = 2/E90 and 2/E0; see the module docstring)."""
    return orthotropic(E0, E90, 2.0 / E90, xi), orthotropic(E0, E90, 2.0 / E0, xi)


@pytest.fixture(scope="module")
def curves():
    """{law: (the study's off-axis rows, static moduli [seed, xi] in Pa)}: the static moduli of every
    seed and tilt, and the rows ``study.summarise`` makes of them (mean over the seeds per tilt)."""
    out = {}
    for law in LAWS:
        E = np.array([[cd.static(s, law, RATIO, xi) for xi in XI] for s in SEEDS])
        recs = [{"kind": "compact", "law": law, "ratio": RATIO, "axis": "x", "tilt_deg": xi, "realisation": s,
                 "status": "ok", "E": E[k, i]} for k, s in enumerate(SEEDS) for i, xi in enumerate(XI)]
        plan = study.StudyPlan(kinds=("compact",), laws=(law,), ratios=(RATIO,), E_R=cd.E_R, E_T=cd.E_T,
                               realisations=len(SEEDS), xi_step=10.0, offaxis_ratio=RATIO)
        rows = study.summarise(recs, plan)["off_axis"]["compact"][law]
        out[law] = rows, E
        dev = np.array([r["E_mean"] / r["E_hankinson"] - 1 for r in rows])
        print(f"{law}: E(xi) [MPa] {np.round(E.mean(axis=0) / 1e6, 2)}, E/Hankinson - 1 [%] {np.round(100 * dev, 2)}")
    return out


@pytest.mark.slow
@pytest.mark.parametrize("law, xi", [("hankinson", 30.0), ("hankinson", 60.0), ("linear", 40.0)])
def test_study_compression_is_the_static_response(law, xi):
    """The study's compression of a tilted compact domain (seed 0) passes its own checks on the first
    attempt and its quasi-static slope is the static response of the same bonds within DYNAMIC_VS_STATIC."""
    rec = study.run_case(Communicator(), cd.study_deck(), cd.plan(RATIO),
                         study.Case("compact", 0, law, RATIO, "x", xi), cd.packing(0))
    assert rec["status"] == "ok" and rec["attempts"] == 1, rec
    assert rec["E"] == pytest.approx(cd.static(0, law, RATIO, xi), rel=DYNAMIC_VS_STATIC)


@pytest.mark.slow
@pytest.mark.parametrize("law", LAWS)
def test_curve_is_monotone_and_orthotropic(law, curves):
    """The mean curve falls at every step from E(0) to E(90) and lies in the monotone orthotropic band
    at every inner angle (the physics of the module docstring); the study's rows hold that mean and
    Hankinson's formula of its ends (1e-12: rounding)."""
    rows, E = curves[law]
    assert [r["xi_deg"] for r in rows] == list(XI)
    mean = E.mean(axis=0)
    E0, E90 = mean[0], mean[-1]
    for r, m in zip(rows, mean):
        assert r["E_mean"] == pytest.approx(m, rel=1e-12) and r["n_failed"] == 0
        assert r["E_hankinson"] == pytest.approx(hankinson(E0, E90, r["xi_deg"]), rel=1e-12)
    # Hankinson's smallest step (80 to 90 deg) is 1.1 % (hankinson law, E0/E90 = 1.5) and 1.6 % (linear,
    # 2.2): 7 and 2 standard errors of the 4-seed mean at 80 deg (the smallest step of the linear law's
    # 4-seed means over seeds 0-15 in groups of four: 2.3 %)
    assert np.all(np.diff(mean) < 0), mean
    for xi, m in zip(INNER, mean[1:-1]):
        low, high = band(E0, E90, xi)
        assert low < m < high, (xi, low, m, high)


@pytest.mark.slow
def test_hankinson_law_follows_hankinson(curves):
    """With the hankinson law the mean curve is Hankinson's at every inner angle within 4 standard
    errors of the 4-seed mean (2 SIGMA; the 16-seed mean's own deviation, 0.12 % at most, is inside)."""
    rows, _ = curves["hankinson"]
    for r, sigma in zip(rows[1:-1], SIGMA["hankinson"]):
        assert abs(r["E_mean"] / r["E_hankinson"] - 1) < 4 * sigma / 100 / math.sqrt(len(SEEDS)), r


@pytest.mark.slow
def test_linear_law_lies_above_hankinson(curves):
    """The linear law gives another tilted domain: its bonds keep more of E_L off the L axis than the
    hankinson law's, and its mean curve lies above Hankinson's at 20-40 deg by more than 2 standard
    errors of the 4-seed mean (the 16-seed mean is 4.4, 4.3, 3.7 standard errors of a 4-seed mean above
    there; at the other angles 1.6-3.2, not asserted), and above the hankinson law's curve by more than
    2 standard errors of the difference."""
    rows, _ = curves["linear"]
    hank, _ = curves["hankinson"]
    for k, xi in enumerate(INNER):
        if 20.0 <= xi <= 40.0:
            dev = rows[k + 1]["E_mean"] / rows[k + 1]["E_hankinson"] - 1
            dev_h = hank[k + 1]["E_mean"] / hank[k + 1]["E_hankinson"] - 1
            se = SIGMA["linear"][k] / 100 / math.sqrt(len(SEEDS))
            se_h = SIGMA["hankinson"][k] / 100 / math.sqrt(len(SEEDS))
            assert dev > 2 * se, (xi, dev, se)
            assert dev - dev_h > 2 * math.hypot(se, se_h), (xi, dev, dev_h)
