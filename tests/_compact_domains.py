"""The small compact domain that tests/test_compact_offaxis.py and tests/test_laws_measured.py
share, with its packings and static moduli (``pardem.protocols.compression.static_modulus``) cached,
so that a session running both builds and solves each once.
"""
import functools

from pardem.io.deck_file import load_deck
from pardem.parallel.communicator import Communicator
from pardem.protocols import anisotropy_study as study
from pardem.protocols.compression import build_case, static_modulus
from pardem.protocols.compression_deck import COMPRESS_SCHEMA


# 30 x 14 x 14 mean radii (about 725 elements), the study deck otherwise (R = 0.25 mm, E_R = 100 MPa,
# E_T = 20 MPa, strain 2e-3). 30 radii along the load and the wide size range make every seed tried
# (0-15) keep 0.63 with its unbonded elements removed; on the --quick cube (18 radii) only seeds 0, 1
# and 11 of 0-11 gave both the x- and the y-flat domain (DeckError otherwise: 0.624-0.630 after the
# removal).
DOMAIN = ["domain.box=[0.0075, 0.0035, 0.0035]", "domain.dispersity=0.45"]
E_R, E_T = 100e6, 20e6


def study_deck():
    return load_deck(COMPRESS_SCHEMA, None, DOMAIN, base=study.STUDY_DECK)


def plan(ratio, E_T=E_T):
    """The study plan of one bond ratio E_L/E_R (E_R = 100 MPa, E_T as given) [Pa]."""
    return study.StudyPlan(kinds=("compact",), laws=study.ALL_LAWS, ratios=(ratio,), E_R=E_R, E_T=E_T,
                           offaxis_ratio=ratio)


@functools.lru_cache(maxsize=None)
def packing(seed):
    """The packing of seed ``seed`` with flat faces normal to x (every case here loads along x)."""
    return study.realisation_packing(study_deck(), plan(1.0), study.Case("compact", seed, "TOR", 1.0, "x"))


def built(seed, law, ratio, xi, E_T=E_T):
    """The study's compression case (compact, realisation ``seed``, base seed 0) along x, frame tilted
    by ``xi`` [deg], bonds [ratio E_R, E_R, E_T]."""
    p = plan(ratio, E_T)
    case = study.Case("compact", seed, law, ratio, "x", xi)
    return build_case(Communicator(), study.case_deck(study_deck(), p, case), packing=packing(seed))


@functools.lru_cache(maxsize=None)
def static(seed, law, ratio, xi, E_T=E_T):
    """``static_modulus`` [Pa] of ``built``, the plates tied to every element within their travel."""
    b = built(seed, law, ratio, xi, E_T)
    return static_modulus(b, touch=b.deck["loading"]["strain"] * b.constants.length)
