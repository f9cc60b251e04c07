"""Each anisotropy law builds its own compact domain, shown on measured domain moduli (issue 15,
item 3); tests/test_anisotropy_engine.py checks the bonds themselves.

Measure: the domain anisotropy E_L^D/E_R^D of one realisation is E(0)/E(90), the x-compressions of
one packing (flat faces normal to x) with its LRT frame untilted and tilted by 90 deg (R then lies
along the load); the study compresses a second packing along y instead, the same ensemble. Moduli:
the static linear response of the engine's bonds between the plates
(``pardem.protocols.compression.static_modulus``: the bonds solved exactly, no time loop). Domain
``_compact_domains.DOMAIN`` (about 725 elements), bonds
[25 E_R, E_R, E_T], E_R = 100 MPa, E_T = 20 MPa, seeds 0-3.

Realisation scatter (measured 2026-12 on this domain, 16 seeds 0-15): E_L^D/E_R^D = TOR 4.63 +- 0.50,
hankinson 1.546 +- 0.058, linear 2.161 +- 0.089, spherical 1.827 +- 0.066, spherical_normalised
2.010 +- 0.075 (mean +- standard deviation over seeds). Some laws lie closer together than one
standard deviation (linear and spherical_normalised: 0.15 apart), so the laws are told apart on the
same packings: the law is then the only difference, and ln(E_L^D/E_R^D) of two laws differs by nearly
the same amount on every seed (over the 16 seeds the mean difference is 4.2 (hankinson, spherical) to
18 (linear, spherical_normalised) times its standard deviation).
"""
import numpy as np
import pytest

import _compact_domains as cd
from pardem.protocols.anisotropy_study import ALL_LAWS

RATIO = 25.0
SEEDS = (0, 1, 2, 3)
# |mean| of the per-seed differences over their standard deviation: above 2 is a paired t above 4 with
# 3 degrees of freedom (two-sided p < 0.03); the 16-seed ratios are 4.2 and above
SEPARATION = 2.0


@pytest.fixture(scope="module")
def anisotropy():
    """{law: E_L^D/E_R^D per seed}."""
    out = {law: np.array([cd.static(s, law, RATIO, 0.0) / cd.static(s, law, RATIO, 90.0) for s in SEEDS])
           for law in ALL_LAWS}
    print({law: f"{v.mean():.3f} +- {v.std(ddof=1):.3f}" for law, v in out.items()})
    return out


@pytest.mark.slow
@pytest.mark.parametrize("law", ALL_LAWS)
def test_law_gives_its_own_domain_anisotropy(law, anisotropy):
    """Against every other law, on the same packings: ln(E_L^D/E_R^D) differs with the same sign on
    every seed, by more than SEPARATION times the differences' scatter over the seeds."""
    mine = anisotropy[law]
    for other in ALL_LAWS:
        if other == law:
            continue
        d = np.log(mine / anisotropy[other])
        assert np.all(np.sign(d) == np.sign(d[0])), (law, other, d)
        assert abs(d.mean()) > SEPARATION * d.std(ddof=1), (law, other, d)


@pytest.mark.slow
def test_equal_triple_gives_one_domain_under_every_interpolating_law():
    """Bonds all 100 MPa: TOR, hankinson, linear and spherical_normalised return the axis value exactly
    (tests/test_anisotropy_engine.py), so they build one domain and its static modulus is bitwise the
    same; W's spherical law scales each bond's modulus and radius by s = cL + cR + cT in [1, sqrt 3],
    so the axial stiffness E r^2 by s^3 and the bending one E r^4 by s^5: its domain is stiffer, by at
    most 3^2.5 (a linear network's energy grows with each bond stiffness and is homogeneous of degree 1
    in them)."""
    E = {law: cd.static(0, law, 1.0, 0.0, E_T=cd.E_R) for law in ALL_LAWS}
    print({law: f"{v / 1e6:.3f} MPa" for law, v in E.items()})
    iso = E["TOR"]
    for law in ("hankinson", "linear", "spherical_normalised"):
        assert E[law] == iso, law
    assert 1.0 < E["spherical"] / iso <= 3.0 ** 2.5
    # and the tilt changes nothing when every bond is the same: the frame is not seen
    assert cd.static(0, "linear", 1.0, 30.0, E_T=cd.E_R) == iso
