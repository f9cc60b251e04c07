"""Property-based fuzzing of the Python builders: ``pardem.build`` of a ``System`` whose parts
(``Particles``, ``ContactModel``, ``BondModel`` with its ``BeamMaterial``, ``WallModel`` with its
law, ``Cell``, ``Integration``, ``Decomposition``, the dimension) take valid, boundary and wild
values (0, negatives, 1e-300, 1e308, 5e-324, NaN, inf, huge integers, wrong types, strings, wrong
shapes). A build either returns a ``Simulation`` that runs a few steps (or stops with
``InstabilityError``) or raises one ``ValueError`` of one line naming the argument; never another
exception. ``benchmarks/fuzz_probe.py`` runs the same generator for longer.
"""
import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pardem.engine.bonding import BeamMaterial
from pardem.engine.system import (BondModel, Cell, ContactModel, Decomposition, Integration, Particles, System,
                                  WallModel, build)
from pardem.engine.walls import wall_law
from pardem.errors import InstabilityError
from pardem.parallel.communicator import Communicator

R = 1e-3
WILD = [0, -1, 1, 0.0, -0.0, -1.5, 1e-300, 1e308, -1e308, 5e-324, math.nan, math.inf, -math.inf, 2**63, 10**30,
        True, False, None, "", "x", "nan", "inf", "auto", [], [1.0], [1.0, 2.0, 3.0], [math.nan] * 3,
        {"a": 1}, np.array([]), np.full(3, np.inf)]
# the names a refusal may name: the parts, their fields, the law parameters
NAMED = ("Particles", "ContactModel", "BondModel", "BeamMaterial", "WallModel", "Cell", "Integration",
         "Decomposition", "System", "positions", "radii", "radius", "density", "velocit", "pairs", "frame",
         "law", "young", "poisson", "friction", "restitution", "kn", "kt", "normals", "points", "dt",
         "damping", "skin", "slab", "cell", "wall", "dimension", "servo", "rate", "length", "periodic",
         "overlap", "critical", "check_every", "max_speed", "balance", "radius_ratio", "strength", "stiffness",
         "thickness", "lo", "element", "bond", "plane", "orientation", "tangential", "rolling", "cement",
         "densification")


def lattice(n_side, dim=3):
    g = np.arange(n_side) * 2.0 * R
    if dim == 2:
        return np.array([[x, y] for x in g for y in g])
    return np.array([[x, y, z] for x in g for y in g for z in g])


def wild_or(good):
    """``good`` (a strategy) 9 times in 10, else a wild value or ``good`` scaled by 10^k (with the
    ``rarely`` fields, about one system in four has nothing wild)."""
    scaled = st.tuples(good, st.integers(-320, 320)).map(
        lambda t: t[0] * float(f"1e{t[1]}") if isinstance(t[0], float) else t[0])
    # (hypothesis draws bounded integers about uniformly; ``one_of`` of equal branches it does not)
    return st.integers(0, 19).flatmap(lambda k: scaled if k == 3 else st.sampled_from(WILD) if k == 7 else good)


def rarely(good, *odd):
    """``good`` 15 times in 16, else one of ``odd``."""
    return st.integers(0, 15).flatmap(lambda k: st.sampled_from(odd) if k == 5 else st.just(good))


def floats(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


@st.composite
def systems(draw):
    dim = draw(rarely(draw(st.sampled_from([3, 3, 2])), 1, "3"))
    n_side = draw(st.integers(1, 3))
    pos = lattice(n_side, 2 if dim == 2 else 3)
    n = len(pos)
    positions = draw(rarely(pos, *WILD, pos * 0.5, pos[:, :2], np.vstack([pos, pos[:1]])))
    particles = Particles(positions, draw(wild_or(floats(0.5 * R, 1.0 * R))),
                          draw(wild_or(floats(100.0, 1e4))),
                          draw(rarely(None, *WILD, np.full((n, 3), 0.01))),
                          None, draw(st.booleans()))
    law = draw(rarely(draw(st.sampled_from(["hertz_mindlin", "linear", "hertz_mindlin_rolling"])), "nope", 3, None))
    keys = {"hertz_mindlin": ["young", "poisson", "friction", "restitution"],
            "linear": ["kn", "kt", "friction", "restitution"],
            "hertz_mindlin_rolling": ["young", "poisson", "friction", "rolling_friction"]}.get(law, ["young"])
    good = {"young": floats(1e6, 1e11), "poisson": floats(-0.5, 0.49), "friction": floats(0.0, 1.0),
            "restitution": floats(0.05, 1.0), "kn": floats(1e2, 1e7), "kt": floats(1e2, 1e7),
            "rolling_friction": floats(0.0, 0.5)}
    params = {k: draw(wild_or(good[k])) for k in draw(st.lists(st.sampled_from(keys), unique=True))}
    contacts = draw(rarely(draw(st.sampled_from([None, "model", "model"])), "wild"))
    contacts = (ContactModel(law, params) if contacts == "model" else
                draw(st.sampled_from(WILD)) if contacts == "wild" else None)
    bonds = None
    if draw(st.booleans()) and n > 1:
        try:
            material = BeamMaterial(young=draw(wild_or(floats(1e6, 1e10))),
                                    radius_ratio=draw(wild_or(floats(0.1, 1.0))),
                                    poisson=draw(wild_or(floats(0.0, 0.49))), damping=draw(wild_or(floats(0.0, 1.0))))
        except ValueError:
            material = draw(st.sampled_from(WILD))
        pairs = draw(rarely(np.array([[0, 1]]), *WILD, np.array([[0, n]]), np.array([[0, 0]]),
                            np.array([[0, 1], [1, 0]])))
        bonds = BondModel(material, pairs, draw(rarely(None, np.eye(3), np.ones((3, 3)), "x")))
    walls = None
    if draw(st.integers(0, 3)) == 0:
        try:
            wlaw = wall_law("linear", stiffness=draw(wild_or(floats(1e2, 1e7))))
        except (ValueError, TypeError):
            wlaw = draw(st.sampled_from(WILD))
        walls = WallModel(draw(st.sampled_from([np.array([[1.0, 0, 0]]), np.array([[0.0, 0, 0]]), [1.0], "x"])),
                          draw(st.sampled_from([np.array([[-2 * R, 0, 0]]), np.array([[math.nan, 0, 0]]), 0.0])),
                          wlaw)
    cell = None
    if dim == 2 or draw(st.booleans()):     # the 2D mode needs a cell
        edge = 2.0 * R * n_side + 6.0 * R   # periods above twice the contact reach
        cell = Cell(draw(rarely((-R, -R, -R) if dim != 2 else (-R, -R), (math.nan, 0.0, 0.0), "x", (0.0, 0.0))),
                    draw(rarely((edge,) * (2 if dim == 2 else 3), *WILD, (edge, edge, 0.5 * R))),
                    draw(rarely((True,) * (2 if dim == 2 else 3), (False, True, True), (1, 2, 3), True)),
                    draw(rarely((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (math.inf, 0, 0), (0.0, 0.0),
                                (1e308, 0.0, 0.0), (0.0, -1e12, 0.0))))
    integration = Integration(dt=draw(rarely(None, 1e-9, 1.0, 0.0, -1.0, math.nan, "x")),
                              dt_fraction=draw(wild_or(floats(0.05, 1.0))),
                              viscous_damping=draw(wild_or(floats(0.0, 100.0))),
                              max_speed=draw(wild_or(floats(1.0, 1e4))),
                              check_every=draw(wild_or(st.integers(1, 100))),
                              orientation=draw(rarely(True, False, 1, "yes")))
    decomposition = Decomposition(slab_axis=draw(rarely("auto", 0, 1, 2, 3, -1, "x", 1.5)),
                                  skin=draw(rarely(None, *WILD, 0.1 * R)),
                                  balance_every=draw(wild_or(st.integers(0, 500))))
    return System(particles, contacts, bonds, walls, cell, integration, decomposition, dim)


def build_or_refuse(system, steps=3):
    """Build ``system`` and run it ``steps`` steps: "built", "unstable" or the ValueError's message
    (asserted one line naming an argument). Any other exception fails."""
    try:
        sim = build(Communicator(), system)
    except ValueError as err:
        msg = str(err)
        assert msg and "\n" not in msg and len(msg) < 700, repr(msg)
        assert any(w in msg for w in NAMED), msg
        return "refused"
    try:
        sim.run(steps)
    except InstabilityError:
        return "unstable"
    return "built"


FUZZ = settings(max_examples=250, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.filter_too_much])


@FUZZ
@given(system=systems())
def test_generated_systems_build_or_are_refused_in_one_line(system):
    build_or_refuse(system)


def test_the_generator_reaches_builds_and_refusals():
    """The generator is not all refusals: of 150 systems drawn from a fixed seed, some build and
    run, and some are refused (so the property above sees both)."""
    from hypothesis import find  # noqa: F401  (hypothesis' own draws below)
    rng_outcomes = []

    @settings(max_examples=150, deadline=None, database=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(system=systems())
    def collect(system):
        rng_outcomes.append(build_or_refuse(system, steps=1))
    collect()
    assert rng_outcomes.count("refused") >= 10 and rng_outcomes.count("built") >= 10, \
        {k: rng_outcomes.count(k) for k in set(rng_outcomes)}
