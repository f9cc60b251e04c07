"""Bad API input is refused before any work, by one ValueError naming the argument and its range.

The parameter classes (contact laws, walls, beam material, fixes, periodic cell) and the particle
array checks of ``pardem.engine.inputs``; a property test feeds them arbitrary values. The overlap
check is compared with a brute-force O(n^2) count, and the domain builders' own geometries (ordered
lattices with flat faces, compact packings, the granular start lattice) must pass it.
"""
import math
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pardem.engine import inputs
from pardem.engine.bonding import BeamMaterial
from pardem.engine.fixes import Clamp, ExternalForce, Gravity, PrescribedVelocity
from pardem.engine.periodic_cell import PeriodicCell
from pardem.engine.walls import Walls, wall_law
from pardem.physics import contact_laws
from pardem.physics import hertz_mindlin as hm
from pardem.physics import linear_contact as lc
from pardem.physics import walls as W

NAN, INF = float("nan"), float("inf")
HM = {"young": 1e9, "poisson": 0.3}
LC = {"kn": 1e5, "kt": 1e5}
BM = {"young": 1e8, "radius_ratio": 0.5, "poisson": 0.3, "damping": 0.1}


def refused(make, *fragments):
    """``make()`` raises one ValueError whose message holds every fragment (plain text)."""
    with pytest.raises(ValueError) as info:
        make()
    text = str(info.value)
    for fragment in fragments:
        assert fragment in text, (fragment, text)
    return text


# ------------------------------------------------------------------------------------------------
# contact laws

def test_hertz_mindlin_unknown_keyword_lists_the_valid_names():
    refused(lambda: hm.Params(E=5e6), "hertz_mindlin.Params() got an unexpected keyword 'E'",
            "valid names are young, poisson, friction, restitution")
    refused(lambda: hm.Params(young=1e9), "missing 'poisson'")
    refused(lambda: hm.Params(1e9, 0.3, young=2e9), "'young' twice")


@pytest.mark.parametrize("key, value, allowed", [
    ("young", -1.0, "(0, inf) [Pa]"), ("young", 0.0, "(0, inf) [Pa]"), ("young", NAN, "(0, inf) [Pa]"),
    ("young", INF, "(0, inf) [Pa]"), ("young", "1e9", "(0, inf) [Pa]"), ("young", None, "(0, inf) [Pa]"),
    ("young", [1e9], "(0, inf) [Pa]"), ("young", 5e-324, "subnormal"),
    ("poisson", NAN, "(-1, 0.5)"), ("poisson", -1.0, "(-1, 0.5)"), ("poisson", 0.5, "(-1, 0.5)"),
    ("poisson", True, "(-1, 0.5)"),
    ("friction", -0.1, "[0, inf)"), ("friction", NAN, "[0, inf)"), ("friction", 10**400, "too large"),
    ("restitution", 0.0, "(0, 1]"), ("restitution", 1.5, "(0, 1]"), ("restitution", NAN, "(0, 1]"),
    ("young2", -1.0, "(0, inf) [Pa]"), ("poisson2", 0.6, "(-1, 0.5)"),
    ("cement_normal", -1.0, "[0, inf) [N/m]"), ("cement_tangential", NAN, "[0, inf) [N/m]"),
    ("cement_fade_time", INF, "[0, inf) [s]"),
])
def test_hertz_mindlin_bad_values_name_the_argument_and_range(key, value, allowed):
    refused(lambda: hm.Params(**{**HM, key: value}), f"hertz_mindlin.{key} = ", allowed)


@pytest.mark.parametrize("key, value, allowed", [
    ("kn", -1.0, "(0, inf) [N/m]"), ("kt", NAN, "(0, inf) [N/m]"), ("kn", "stiff", "(0, inf) [N/m]"),
    ("friction", -1.0, "[0, inf)"), ("restitution", 0.0, "(0, 1]"),
    ("tangential_damping", -0.1, "[0, inf)"), ("tangential_damping", NAN, "[0, inf)"),
])
def test_linear_contact_bad_values_name_the_argument_and_range(key, value, allowed):
    refused(lambda: lc.Params(**{**LC, key: value}), f"linear_contact.{key} = ", allowed)
    refused(lambda: lc.Params(k=1.0), "unexpected keyword 'k'", "valid names are kn, kt, friction")


def test_law_params_lists_laws_and_keywords():
    refused(lambda: contact_laws.law_params("hertz", HM), "contact law 'hertz'",
            "expected one of hertz_mindlin, linear")
    refused(lambda: contact_laws.law_params(["linear"], LC), "expected one of hertz_mindlin, linear")
    refused(lambda: contact_laws.law_params("hertz_mindlin", {**HM, "E": 5e6}),
            "unexpected keyword 'E'", "valid names are young, poisson")
    refused(lambda: contact_laws.law_params("linear", [1e5, 1e5]), "params of contact law 'linear'",
            "dict of linear_contact.Params keywords")
    refused(lambda: contact_laws.law_params("linear", {**LC, "kn": -1.0}), "linear_contact.kn")


# ------------------------------------------------------------------------------------------------
# walls

@pytest.mark.parametrize("kw, fragments", [
    ({"law": "linear", "kn": 1.0, "E": 1.0}, ("walls.Params() got an unexpected keyword 'E'",
                                               "valid names are law, kn, kt, young")),
    ({"law": 3, "kn": 1.0}, ("walls.law = 3", "'linear', 'hertz'")),
    ({"law": "linear", "kn": 1.0, "young": 1e9}, ("walls.young", "hertz law only")),
    ({"law": "hertz", "young": 1e9, "poisson": 0.3, "kn": 1.0}, ("walls.kn", "linear law only")),
    ({"law": "linear", "kn": NAN}, ("walls.kn = nan", "(0, inf) [N/m]")),
    ({"law": "linear", "kn": 1.0, "friction": "0.3"}, ("walls.friction", "[0, inf)")),
    ({"law": "hertz", "young": 1e9, "poisson": 0.3, "wall_young": NAN}, ("walls.wall_young", "(0, inf] [Pa]")),
    ({"law": "hertz", "young": 1e9, "poisson": NAN}, ("walls.poisson", "(-1, 0.5)")),
])
def test_wall_params_bad_values(kw, fragments):
    refused(lambda: W.Params(**kw), *fragments)


def test_wall_law_and_walls_name_their_arguments():
    refused(lambda: wall_law("linear", stiffness=1.0, stifness=2.0), "wall_law() got an unexpected keyword "
            "'stifness'", "valid names are law, stiffness, young")
    refused(lambda: wall_law("linear", stiffness=1.0, young=1e9), "young = 1000000000.0 applies to law = "
            "'hertz' only")
    refused(lambda: wall_law("hertz", stiffness=1.0, young=1e9, poisson=0.3), "stiffness", "'linear' only")
    refused(lambda: wall_law("linear", stiffness=1.0, wall_young=1e9), "wall_young", "'hertz' only")
    assert wall_law("hertz", young=1e9, poisson=0.3).wall_young == math.inf     # rigid by default
    refused(lambda: wall_law("plastic"), "law = 'plastic'", "'linear' or 'hertz'")
    refused(lambda: wall_law("linear", stiffness=-1.0), "stiffness must be a positive number [N/m]")
    law = wall_law("linear", stiffness=1.0)
    refused(lambda: Walls([[0, 0, 1], [1, 0]], [[0, 0, 0]], law), "normals must be an array of numbers")
    refused(lambda: Walls([[0, 0, 1]], [[0, 0, 0]], law, time0=NAN), "time0 = nan")
    refused(lambda: Walls([[0, 0, 1]], [[0, 0, 0]], law, velocity=(0, 0, 1)),
            "Walls() got an unexpected keyword 'velocity'", "velocities")


# ------------------------------------------------------------------------------------------------
# beam material

@pytest.mark.parametrize("key, value, fragments", [
    ("young", -1.0, ("BeamMaterial.young = -1.0", "(0, inf) [Pa]")),
    ("young", (1e8, 2e8), ("BeamMaterial.young = (100000000.0, 200000000.0)", "(L, R, T) triple")),
    ("young", (1e8, NAN, 1e8), ("BeamMaterial.young[1] = nan", "(0, inf) [Pa]")),
    ("young", "1e8", ("BeamMaterial.young = '1e8'",)),
    ("radius_ratio", 0.0, ("BeamMaterial.radius_ratio = 0.0", "(0, inf)")),
    ("poisson", NAN, ("BeamMaterial.poisson = nan", "(-1, 0.5)")),
    ("poisson", -1.0, ("BeamMaterial.poisson", "(-1, 0.5)")),
    ("damping", -0.1, ("BeamMaterial.damping = -0.1", "[0, inf)")),
    ("damping", NAN, ("BeamMaterial.damping = nan", "[0, inf)")),
    ("tensile_strength", -1.0, ("BeamMaterial.tensile_strength = -1.0", "[0, inf) [Pa]")),
    ("shear_strength", (1e6, 0.0, 1e6), ("BeamMaterial.shear_strength", "all three values > 0")),
    ("law", "TORR", ("BeamMaterial.law = 'TORR'", "'TOR', 'hankinson', 'linear', 'spherical'")),
    ("densification_stress", -1.0, ("BeamMaterial.densification_stress", "[0, inf) [Pa]")),
    ("densification_p0", NAN, ("BeamMaterial.densification_p0", "[0, inf)")),
])
def test_beam_material_bad_values(key, value, fragments):
    refused(lambda: BeamMaterial(**{**BM, key: value}), *fragments)


def test_beam_material_keywords_and_valid_triples():
    refused(lambda: BeamMaterial(**BM, E=1.0), "BeamMaterial() got an unexpected keyword 'E'",
            "valid names are young, radius_ratio, poisson, damping, law")
    m = BeamMaterial(**{**BM, "young": (3e8, 2e8, 1e8), "tensile_strength": np.array([1e6, 2e6, 3e6])})
    assert m.young == (3e8, 2e8, 1e8) and m.breakable   # kept as given


# ------------------------------------------------------------------------------------------------
# fixes

@pytest.mark.parametrize("make, fragments", [
    (lambda: Gravity(gravity=(0, 0, -9.81)), ("Gravity() got an unexpected keyword 'gravity'", "valid names are g")),
    (lambda: Gravity((0, "down", 0)), ("g must be an array of numbers [m/s^2]",)),
    (lambda: Gravity((0, 0, NAN)), ("g must be a finite vector of shape (3,) [m/s^2]",)),
    (lambda: ExternalForce([0], [[1, 2, 3], [4]]), ("force must be an array of numbers [N]",)),
    (lambda: ExternalForce(gids=[0], forces=(1, 0, 0)), ("unexpected keyword 'forces'", "gids, force, torque")),
    (lambda: ExternalForce([0], (1, 0, 0), torque=(INF, 0, 0)), ("torque must be finite [N m]",)),
    (lambda: Clamp([[0, 1], [2]]), ("gids must be a non-empty 1-D sequence",)),
    (lambda: Clamp([1e300]), ("gids must be integer global ids",)),
    (lambda: Clamp([0], dof="x"), ("Clamp() got an unexpected keyword 'dof'", "dofs, rotations")),
    (lambda: PrescribedVelocity([0], "fast"), ("velocity must be an array of numbers [m/s]",)),
    (lambda: PrescribedVelocity([0]), ("PrescribedVelocity() is missing 'velocity'",)),
])
def test_fix_constructors_name_their_arguments(make, fragments):
    refused(make, *fragments)


# ------------------------------------------------------------------------------------------------
# periodic cell and global damping

@pytest.mark.parametrize("kw, fragments", [
    ({"length": (1.0, 0.0, 1.0)}, ("cell.length must be positive", "(0, inf) [m]")),
    ({"length": (1.0, NAN, 1.0)}, ("cell.length = ", "3 finite numbers [m]")),
    ({"length": (1.0, 1.0)}, ("cell.length = ", "got shape (2,)")),
    ({"lo": (0.0, INF, 0.0)}, ("cell.lo = ", "finite")),
    ({"rate": (NAN, 0.0, 0.0)}, ("cell.rate = ", "[1/s]")),
    ({"periodic": ("yes", "no", "no")}, ("cell.periodic", "3 booleans")),
    ({"servo": (1e5, 0.0, 1.0)}, ("cell.servo gain = 0.0", "(0, inf) [1/(Pa s)]")),
    ({"servo": (NAN, 1e-6, 1.0)}, ("cell.servo p0 = nan", "[Pa]")),
    ({"servo": (1e5, 1e-6, -1.0)}, ("cell.servo max_rate", "(0, inf) [1/s]")),
    ({"servo": (1e5, 1e-6)}, ("cell.servo = (100000.0, 1e-06)", "(p0 [Pa], gain [1/(Pa s)], max_rate [1/s])")),
    ({"servo": {"axis": 2, "axial_rate": -1.0, "pressure": 1e5, "gain": 1e-6, "max_rte": 1.0}},
     ("PeriodicCell.triaxial_servo() got an unexpected keyword 'max_rte'", "valid names are axis")),
    ({"servo": {"axis": "z", "axial_rate": -1.0, "pressure": 1e5, "gain": 1e-6, "max_rate": 1.0}},
     ("axis = 'z'", "0, 1 or 2")),
    ({"servo": {"axis": 2, "axial_rate": -1.0, "pressure": -1e5, "gain": 1e-6, "max_rate": 1.0}},
     ("triaxial servo: pressure = -100000.0", "[0, inf) [Pa]")),
    ({"box": 1.0}, ("PeriodicCell() got an unexpected keyword 'box'", "valid names are lo, length, periodic")),
])
def test_periodic_cell_arguments(kw, fragments):
    args = {"lo": np.zeros(3), "length": np.ones(3), "periodic": (True, True, True), **kw}
    refused(lambda: PeriodicCell(**args), *fragments)


@pytest.mark.parametrize("value", [-1.0, NAN, INF, "fast", None])
def test_viscous_damping_is_a_finite_rate(value):
    refused(lambda: inputs.check_viscous_damping(value), "viscous_damping = ", "[0, inf) [1/s]")


def test_valid_arguments_pass_unchanged():
    """The checks keep what they are given: same derived constants as the formulas, same fields."""
    p = hm.Params(young=np.float64(1e9), poisson=0.3)
    assert p.young == 1e9 and p.e_star == hm.Params(1e9, 0.3).e_star
    # E* = E / (2 (1 - nu^2)) for identical grains, to the rounding of the two formulas
    assert p.e_star == pytest.approx(1e9 / (2 * (1 - 0.3**2)), rel=1e-15)
    assert W.Params(law="hertz", young=1e9, poisson=0.3, wall_young=math.inf).stiff_n == \
        pytest.approx(1e9 / (1 - 0.09), rel=1e-15)      # rigid wall: E* = E / (1 - nu^2)
    cell = PeriodicCell([0, 0, 0], [1, 2, 3], [1, 1, 0], rate=(0.1, 0, 0), servo=(1e5, 1e-6, 1.0))
    assert cell.periodic.tolist() == [True, True, False] and cell.servo == (1e5, 1e-6, 1.0)
    assert inputs.check_viscous_damping(0) == 0.0


# ------------------------------------------------------------------------------------------------
# particle arrays (pardem.engine.inputs)

X2 = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]


@pytest.mark.parametrize("make, fragments", [
    (lambda: inputs.check_positions([[0.0, 0.0], [1.0, 0.0]]), ("positions must be finite with shape (n, 3)",)),
    (lambda: inputs.check_positions([[0, 0, 0], [1, NAN, 0]]), ("positions[1] = [1.0, nan, 0.0]",)),
    (lambda: inputs.check_positions([[0, 0, 0], [1, 0]]), ("positions must be an array of numbers [m]",)),
    (lambda: inputs.check_positions([[0, 0, 0.1]], dimension=2), ("plane z = 0", "positions[0]")),
    (lambda: inputs.check_radii([1.0, 1.0, 1.0], 2), ("radii must be a scalar or have shape (2,)",
                                                      "3 radii for 2 positions")),
    (lambda: inputs.check_radii([1.0, -1.0], 2), ("radii must be finite and > 0 [m]", "got radii[1] = -1.0")),
    (lambda: inputs.check_radii(NAN, 2), ("radii must be finite and > 0 [m]", "got nan")),
    (lambda: inputs.check_density(0.0, 2), ("density", "(0, inf) [kg/m^3]")),
    (lambda: inputs.check_density([1.0, 2.0, 3.0], 2), ("density", "shape (2,)")),
    (lambda: inputs.check_density([1.0, NAN], 2), ("density[1] = nan",)),
    (lambda: inputs.check_vectors([[0, 0, 0]], 2, "velocities", "[m/s]"), ("velocities", "(2, 3) [m/s]")),
    (lambda: inputs.check_vectors([[0, 0, 0], [0, INF, 0]], 2, "angular_velocities", "[rad/s]"),
     ("angular_velocities[1]",)),
    (lambda: inputs.check_pairs([[0, 2]], 2), ("pairs must index elements 0 .. 1", "pairs[0] = [0, 2]")),
    (lambda: inputs.check_pairs([[0, 1], [1, 1]], 2), ("two different elements", "pairs[1] = [1, 1]")),
    (lambda: inputs.check_pairs([[0, 1], [1, 2], [1, 0]], 3), ("same bond twice", "rows 0 and 2")),
    (lambda: inputs.check_pairs([[0.0, 1.0]], 2), ("pairs must be integer",)),
    (lambda: inputs.check_pairs([[0, 1], [1]], 2), ("pairs must be integer indices",)),
    (lambda: inputs.check_frame(np.ones((3, 3))), ("frame must be a (3, 3) orthonormal",)),
    (lambda: inputs.check_frame([[1, 0, 0], [0, 1, 0]]), ("frame must be a (3, 3) orthonormal",)),
])
def test_particle_arrays_name_argument_and_entry(make, fragments):
    refused(make, *fragments)


def test_check_arrays_is_the_builders_check():
    """Same results as the builders' ``_check_arrays`` for good input; a 2D input is padded."""
    x, r, p = inputs.check_arrays(X2, 1.0, 1000.0, [[1, 0]])
    assert x.dtype == np.float64 and x.flags.c_contiguous and x.tolist() == X2
    assert r.tolist() == [1.0, 1.0] and p.tolist() == [[0, 1]] and p.dtype == np.int64
    assert inputs.check_arrays(X2, [1.0, 1.0], [1.0, 2.0], [])[2].shape == (0, 2)
    assert inputs.check_positions([[1.0, 2.0]], dimension=2).tolist() == [[1.0, 2.0, 0.0]]


def test_coincident_centres_are_named_by_index():
    x = np.column_stack([np.arange(10.0) * 2.0, np.zeros(10), np.zeros(10)])
    x[7] = x[3]
    refused(lambda: inputs.check_arrays(x, 1.0, 1000.0, []), "positions: elements 3 and 7 coincide (distance 0 m")
    # a bond does not make coincident centres acceptable (a bond needs a length)
    refused(lambda: inputs.check_arrays(x, 1.0, 1000.0, [[3, 7]]), "elements 3 and 7 coincide")
    x[7, 0] += 0.02     # 0.02 R apart: no longer coincident, but bonded: a deep overlap allowed
    inputs.check_arrays(x, 1.0, 1000.0, [[3, 7]])


def test_deep_overlaps_are_counted_and_bonded_pairs_exempt():
    # pairs (0, 1), (4, 5): overlap 0.6 R > 0.5 R; pair (2, 3): overlap 0.4 R (allowed)
    x = np.array([[0, 0, 0], [1.4, 0, 0], [10, 0, 0], [11.6, 0, 0], [20, 0, 0], [21.4, 0, 0]], float)
    text = refused(lambda: inputs.check_arrays(x, 1.0, 1000.0, []), "positions: 2 pairs of unbonded elements "
                   "overlap by more than 0.5 of the smaller radius", "first: elements 0 and 1")
    assert "overlap 0.6 of the smaller" in text
    refused(lambda: inputs.check_arrays(x, 1.0, 1000.0, [[1, 0]]), "positions: 1 pair", "elements 4 and 5")
    inputs.check_arrays(x, 1.0, 1000.0, [[1, 0], [4, 5]])
    # diameters given as radii: touching spheres overlap by the whole given radius
    refused(lambda: inputs.check_arrays(X2, 2.0, 1000.0, []), "radii are not diameters")


def test_periodic_box_uses_minimum_images():
    x = [[0.1, 0.5, 0.5], [9.5, 0.5, 0.5]]       # 0.6 apart through the x faces of a 10 m box
    inputs.check_overlaps(np.array(x), np.ones(2))                         # no box: 9.4 apart
    refused(lambda: inputs.check_overlaps(np.array(x), np.ones(2), box_lo=[0, 0, 0], box_length=[10, 10, 10]),
            "periodic images included", "elements 0 and 1")
    inputs.check_overlaps(np.array(x), np.ones(2), box_lo=[0, 0, 0], box_length=[10, 10, 10],
                          periodic=np.array([False, True, True]))
    # outside the box (unwrapped) along a periodic axis: wrapped for the check
    refused(lambda: inputs.check_overlaps(np.array([[10.1, 0.5, 0.5], [9.5, 0.5, 0.5]]), np.ones(2),
                                          box_lo=[0, 0, 0], box_length=[10, 10, 10]), "elements 0 and 1")
    refused(lambda: inputs.check_overlaps(np.array([[0.5, 0.5, 0.5]]), np.ones(1), box_length=[1.2, 10, 10]),
            "element 0", "its own periodic image along x")


def _brute_force_deep(x, r, edge=None, f=inputs.MAX_OVERLAP):
    d = x[None, :, :] - x[:, None, :]
    if edge is not None:
        d -= edge * np.round(d / edge)
    dist = np.linalg.norm(d, axis=2)
    small = np.minimum(r[:, None], r[None, :])
    i, j = np.nonzero(np.triu(r[:, None] + r[None, :] - dist > f * small, 1))
    return len(i), (i[0], j[0]) if len(i) else None


@pytest.mark.parametrize("seed", range(6))
def test_overlap_count_equals_brute_force(seed):
    """The tree search with radius classes finds exactly the pairs of an O(n^2) sweep (count and the
    first pair), with radii spanning a factor 30 (five classes), periodic or not."""
    rng = np.random.default_rng(seed)
    n = 300
    x = rng.uniform(0.0, 10.0, (n, 3))
    r = 0.05 * np.exp(rng.uniform(0.0, np.log(30.0), n))
    edge = np.full(3, 10.0) if seed % 2 else None
    count, first = _brute_force_deep(x, r, edge)
    assert count > 3      # the case tests something
    text = refused(lambda: inputs.check_overlaps(x, r, box_length=edge))
    assert text.startswith(f"positions: {count} pairs") and f"elements {first[0]} and {first[1]}," in text


@pytest.mark.parametrize("tilt, flat_axis, depth", [(0.0, None, 1.0), (30.0, 0, 1.0), (45.0, 0, 1.5),
                                                    (20.0, 1, 1.5), (45.0, 2, 1.0)])
def test_ordered_lattices_pass(tilt, flat_axis, depth):
    """Every lattice of ``ordered_lattice`` passes with its bonds. Without them it is refused exactly
    when a brute-force sweep finds a deep pair: at 45 degrees with 1.5 R flat layers the bonded
    neighbours end sqrt(2) R apart (overlap 0.59 R), so only the bond exemption lets it pass."""
    from pardem.domains.ordered import ordered_lattice
    R = 1e-3
    x, pairs, _ = ordered_lattice([0.02, 0.014, 0.012], R, tilt, flat_axis=flat_axis, flat_depth=depth)
    inputs.check_arrays(x, R, 1000.0, pairs)
    count, _ = _brute_force_deep(x, np.full(len(x), R))
    assert (count > 0) == (tilt == 45.0 and depth == 1.5)
    if count:
        refused(lambda: inputs.check_arrays(x, R, 1000.0, []), f"positions: {count} pairs of unbonded")


def test_granular_start_lattice_and_compact_packing_pass():
    from pardem.domains.compact import compact_packing
    from pardem.engine.granular import simple_cubic
    x, L = simple_cubic(6, 1e-3)
    inputs.check_arrays(x, 1e-3, 2500.0, [], box_lo=np.zeros(3), box_length=np.full(3, L))
    pk = compact_packing((6e-3, 6e-3, 6e-3), 0.5e-3, dispersity=0.3, seed=1)   # periodic on all axes
    inputs.check_arrays(pk.positions, pk.radii, 2500.0, [], box_lo=np.zeros(3), box_length=pk.box)


# ------------------------------------------------------------------------------------------------
# property test: any value gives a result or one ValueError/TypeError naming an argument

_SCALARS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),           # NaN, inf, huge, tiny, subnormal, negative
    st.integers(min_value=-(2**70), max_value=2**70), st.just(10**400),
    st.booleans(), st.none(), st.text(max_size=4),
    st.sampled_from([0.0, 0.3, 0.5, 1.0, 1e9, -1.0, 3, np.float64(0.2), np.int64(2), np.array(0.4)]),
)
_WEIRD = st.recursive(_SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                         st.tuples(inner, inner, inner),
                                                         st.dictionaries(st.text(max_size=3), inner, max_size=2)),
                      max_leaves=8)
_ARRAYS = st.builds(lambda shape, fill: np.full(shape, fill),
                    st.lists(st.integers(0, 4), max_size=3).map(tuple),
                    st.sampled_from([0.0, 1.0, -1.0, NAN, INF, 1e300, 5e-324]))
_ANY = st.one_of(_WEIRD, _ARRAYS)

# valid values of each argument (so that the other arguments get tested too); restitution kept to a
# few values: each new one costs a Hertz calibration
_VALID = {
    "young": st.sampled_from([1e9, 2e7, (3e8, 2e8, 1e8)]), "poisson": st.sampled_from([0.3, -0.5, 0.0]),
    "friction": st.sampled_from([0.0, 0.5]), "restitution": st.sampled_from([1.0, 0.5]),
    "kn": st.just(1e5), "kt": st.just(1e5), "radius_ratio": st.just(0.5), "damping": st.just(0.1),
    "law": st.sampled_from(["TOR", "linear", "hertz", "hertz_mindlin"]), "stiffness": st.just(1e5),
    "g": st.just((0.0, 0.0, -9.81)), "gids": st.just([0, 1]), "force": st.just((1.0, 0.0, 0.0)),
    "velocity": st.just((0.0, 0.0, 1.0)), "lo": st.just((0.0, 0.0, 0.0)), "length": st.just((1.0, 1.0, 1.0)),
    "periodic": st.just((True, True, True)), "normals": st.just([[0.0, 0.0, 1.0]]),
    "points": st.just([[0.0, 0.0, 0.0]]),
}

_CONSTRUCTORS = {
    "hertz_mindlin.Params": (hm.Params, ["young", "poisson", "friction", "restitution", "young2", "poisson2",
                                         "cement_normal", "cement_tangential", "cement_fade_time"]),
    "linear_contact.Params": (lc.Params, ["kn", "kt", "friction", "restitution", "tangential_damping"]),
    "walls.Params": (W.Params, ["law", "kn", "kt", "young", "poisson", "wall_young", "wall_poisson",
                                "friction", "restitution", "tangential_damping"]),
    "wall_law": (wall_law, ["law", "stiffness", "young", "poisson", "restitution", "friction", "wall_young"]),
    "law_params": (lambda law, params: contact_laws.law_params(law, params), ["law", "params"]),
    "BeamMaterial": (BeamMaterial, ["young", "radius_ratio", "poisson", "damping", "law", "tensile_strength",
                                    "shear_strength", "densification_stress", "densification_p0"]),
    "Gravity": (Gravity, ["g"]),
    "ExternalForce": (ExternalForce, ["gids", "force", "torque"]),
    "Clamp": (Clamp, ["gids", "dofs", "rotations"]),
    "PrescribedVelocity": (PrescribedVelocity, ["gids", "velocity", "angular_velocity", "dofs", "rotations"]),
    "PeriodicCell": (PeriodicCell, ["lo", "length", "periodic", "rate", "servo", "dimension"]),
    "Walls": (lambda normals, points, law=None, velocities=None, time0=0.0:
              Walls(normals, points, wall_law("linear", stiffness=1.0) if law is None else law, velocities, time0),
              ["normals", "points", "velocities", "time0"]),
    "viscous_damping": (lambda viscous_damping: inputs.check_viscous_damping(viscous_damping),
                        ["viscous_damping"]),
}


_PARAMS_DICTS = st.dictionaries(st.sampled_from(["young", "poisson", "kn", "kt", "E"]), _ANY, max_size=4)
_HOW = st.sampled_from(["valid", "weird", "absent"])
_LABELS = st.sampled_from(sorted(_CONSTRUCTORS))


@st.composite
def _calls(draw):
    label = draw(_LABELS)
    make, names = _CONSTRUCTORS[label]
    kwargs = {}
    for name in names:
        how = draw(_HOW)
        if how == "valid" and name in _VALID:
            kwargs[name] = draw(_VALID[name])
        elif how == "weird":
            kwargs[name] = draw(_ANY)
    if label == "law_params" and draw(st.booleans()):
        kwargs["params"] = draw(_PARAMS_DICTS)
    if draw(st.integers(0, 9)) == 0:
        kwargs["unknown_name"] = 1.0
    return label, make, names, kwargs


# arguments a law_params message may name: the laws' own
_LAW_NAMES = ["young", "poisson", "friction", "restitution", "young2", "poisson2", "cement_normal",
              "cement_tangential", "cement_fade_time", "kn", "kt", "tangential_damping"]


def _cheap_calibration(e):
    return 0.1   # stands for the Hertz restitution calibration (~1 s per new value), run after the checks


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_calls())
def test_parameter_classes_accept_or_name_the_argument(call):
    label, make, names, kwargs = call
    if label == "law_params":
        names = names + _LAW_NAMES
    with mock.patch.object(hm, "hertz_damping_coefficient", _cheap_calibration), \
            mock.patch.object(W, "hertz_damping_coefficient", _cheap_calibration):
        try:
            make(**kwargs)
        except (ValueError, TypeError) as exc:
            text = str(exc)
            assert text and any(name in text for name in names + ["unknown_name", "contact law"]), (label, text)


_ARRAY_CHECKS = st.sampled_from(["positions", "radii", "density", "vectors", "pairs", "frame", "arrays"])
_ARRAY_VALUES = st.one_of(_ANY, st.builds(lambda a: a.tolist(), _ARRAYS))


@st.composite
def _arrays(draw):
    return draw(st.integers(1, 6)), draw(_ARRAY_CHECKS), draw(_ARRAY_VALUES)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_arrays())
def test_array_checks_accept_or_name_the_argument(case):
    n, check, value = case
    calls = {
        "positions": (lambda: inputs.check_positions(value), "positions"),
        "radii": (lambda: inputs.check_radii(value, n), "radii"),
        "density": (lambda: inputs.check_density(value, n), "density"),
        "vectors": (lambda: inputs.check_vectors(value, n, "velocities", "[m/s]"), "velocities"),
        "pairs": (lambda: inputs.check_pairs(value, n), "pairs"),
        "frame": (lambda: inputs.check_frame(value), "frame"),
        "arrays": (lambda: inputs.check_arrays(value, 1.0, 1.0, []), "positions"),
    }
    make, name = calls[check]
    try:
        make()
    except ValueError as exc:
        assert name in str(exc), (check, str(exc))


@settings(max_examples=150, deadline=None)
@given(st.integers(2, 25), st.integers(0, 2**32 - 1), st.floats(0.05, 0.6), st.booleans())
def test_overlap_verdict_equals_brute_force(n, seed, size, periodic):
    """Random centres in a unit box, radii up to ``size``: refused exactly when the O(n^2) sweep finds
    a coincident or deep pair (minimum image in the periodic case)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 1.0, (n, 3))
    r = rng.uniform(0.1, 1.0, n) * size
    edge = np.ones(3) if periodic else None
    count, _ = _brute_force_deep(x, r, edge)
    own = periodic and (2.0 - inputs.MAX_OVERLAP) * r.max() > 1.0
    if count or own:
        with pytest.raises(ValueError, match="positions"):
            inputs.check_overlaps(x, r, box_length=edge)
    else:
        inputs.check_overlaps(x, r, box_length=edge)
