"""The static linear response of a beam-bond network between plates (``pardem.physics.beam_static``)
and its compression-case form (``pardem.protocols.compression.static_modulus``).

Checks: one bond's stiffness matrix is the engine kernel's linearisation (central differences of
``compute_bonds``) and gives a clamped cantilever's textbook deflections; rigid motions cost nothing;
a chain along the load between the plates is springs in series; the plate forces balance on a
disordered network; a lever on three supports flags the lifted one as pulled; an ordered lattice
loaded along a lattice axis has E^D = pi/4 E r^2 (docs/physics.md section 5); plates the static
model does not describe are refused.
"""
import numpy as np
import pytest

from _util import perpendicular, random_unit, two_elements
from test_damping_modes import linear_matrices      # the kernel's K by central differences
from pardem.io.deck_file import load_deck
from pardem.parallel.communicator import Communicator
from pardem.physics import beam_static
from pardem.protocols.compression import build_case, static_modulus
from pardem.protocols.compression_deck import COMPRESS_SCHEMA


def bond_matrix(e, b):
    """[12, 12] dense stiffness of the bonds ``b`` of the elements ``e`` (two elements)."""
    return beam_static.stiffness_matrix(e.x, b.i, b.j, b.L0, b.ka, b.kb, b.kt).toarray()


def test_one_bond_is_the_kernels_linearisation():
    """Unequal ends, a random direction and orientations: K equals the engine kernel's stiffness by
    central differences (``test_damping_modes.linear_matrices``, step 1e-7 of L0 or 1 rad), rotations
    scaled by L0 so every entry is N/m. Tolerance 1e-7 of the largest entry: the difference quotient's
    round-off is about eps / 1e-7 = 2e-9 of it (measured 1.1e-9)."""
    rng = np.random.default_rng(3)
    e, b = two_elements(n=random_unit(rng), R1=1e-3, R2=1.5e-3, young=2e9, radius_ratio=0.6,
                        q1=np.r_[np.cos(0.4), np.sin(0.4) * random_unit(rng)],
                        q2=np.r_[np.cos(1.1), np.sin(1.1) * random_unit(rng)])
    _, K_kernel, _ = linear_matrices(e, b)
    K = bond_matrix(e, b)
    scale = np.diag(np.tile(np.r_[np.ones(3), np.full(3, 1.0 / b.L0[0])], 2))
    assert np.abs(scale @ (K - K_kernel) @ scale).max() < 1e-7 * np.abs(scale @ K @ scale).max()


def test_cantilever_has_the_textbook_deflections():
    """End 1 clamped, loads on end 2 of a bond along a random direction n: a force P across n deflects
    it by P L^3 / (3 E I) and turns it by P L^2 / (2 E I) about n x P; along n it stretches by P / ka;
    a torque T about n twists it by T / kt; a bending moment M turns it by M L / (E I) and deflects
    it by M L^2 / (2 E I). Exact for the frame element: tolerance 1e-12, the round-off of a 6 x 6 solve."""
    rng = np.random.default_rng(8)
    n = random_unit(rng)
    e, b = two_elements(n=n, R1=1e-3, R2=0.8e-3, young=1e9)
    L, EI, ka, kt = b.L0[0], b.kb[0], b.ka[0], b.kt[0]
    tip = np.linalg.inv(bond_matrix(e, b)[6:, 6:])       # compliance of end 2, end 1 clamped
    d = perpendicular(n, rng)
    z = tip @ np.r_[d, 0.0, 0.0, 0.0]                    # unit force across n
    assert z[:3] == pytest.approx(L**3 / (3 * EI) * d, rel=1e-12, abs=1e-12 * L**3 / EI)
    assert z[3:] == pytest.approx(L**2 / (2 * EI) * np.cross(n, d), rel=1e-12, abs=1e-12 * L**2 / EI)
    z = tip @ np.r_[n, 0.0, 0.0, 0.0]
    assert z[:3] == pytest.approx(n / ka, rel=1e-12, abs=1e-12 / ka)
    z = tip @ np.r_[0.0, 0.0, 0.0, n]                    # unit torque about n
    assert z[3:] == pytest.approx(n / kt, rel=1e-12, abs=1e-12 / kt)
    z = tip @ np.r_[0.0, 0.0, 0.0, d]                    # unit bending moment about d
    assert z[3:] == pytest.approx(L / EI * d, rel=1e-12, abs=1e-12 * L / EI)
    assert z[:3] == pytest.approx(L**2 / (2 * EI) * np.cross(d, n), rel=1e-12, abs=1e-12 * L**2 / EI)


def jittered_network(rng, shape=(4, 3, 3), R=1e-3, jitter=0.05):
    """Elements on a cubic grid of spacing 2R moved by up to ``jitter`` R, bonds between grid
    neighbours: (x [n, 3], radius [n], i, j, L0, ka, kb, kt) of a bond modulus 1 GPa, bond radius R/2."""
    grid = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
    x = 2 * R * grid + rng.uniform(-jitter, jitter, grid.shape) * R
    index = {tuple(g): k for k, g in enumerate(grid)}
    pairs = np.array([(index[tuple(g)], index[tuple(g + s)]) for g in grid for s in np.eye(3, dtype=int)
                      if tuple(g + s) in index])
    i, j = pairs.T
    L0 = np.linalg.norm(x[j] - x[i], axis=1)
    r = 0.5 * R
    E = 1e9
    return (x, np.full(len(x), R), i, j, L0, E * np.pi * r**2 / L0, E * np.pi * r**4 / 4,
            E / 2.6 * np.pi * r**4 / 2 / L0)


def test_rigid_motions_cost_nothing_and_K_is_symmetric():
    """A rigid translation or rotation (u = w x x, theta = w) of a disordered network has no load:
    |K z| below 1e-12 of |K| |z| (round-off); K is symmetric to round-off."""
    rng = np.random.default_rng(11)
    x, _, i, j, L0, ka, kb, kt = jittered_network(rng)
    K = beam_static.stiffness_matrix(x, i, j, L0, ka, kb, kt)
    size = abs(K).max()
    assert abs(K - K.T).max() < 1e-12 * size
    for w in np.eye(3):
        for z in (np.tile(np.r_[w, 0.0, 0.0, 0.0], len(x)),
                  np.concatenate([np.cross(w, x), np.tile(w, (len(x), 1))], axis=1).ravel()):
            assert np.abs(K @ z).max() < 1e-12 * size * np.abs(z).max()


def test_chains_along_the_load_are_springs_in_series():
    """A ladder between plates of stiffness kn: two chains of N = 6 bonds along y, their elements
    joined level by level by rungs along x (a single chain's spin about the load would be free). The
    plate force per unit plate displacement is 2 / (2 / kn + N / ka), every chain bond shortens by
    half of it over ka, the rungs carry nothing, nothing turns or moves across the load (the hold
    springs carry nothing). Tolerance 1e-12: round-off."""
    N, R, ka, kb, kt, kn = 6, 1e-3, 3.0e5, 1e-3, 1e-2, 1.0e6
    level = np.arange(N + 1)
    x = np.zeros((2 * (N + 1), 3))
    x[:, 1] = 2 * R * np.tile(level, 2)
    x[N + 1:, 0] = 2 * R
    i = np.r_[level[:-1], N + 1 + level[:-1], level]
    j = np.r_[level[1:], N + 2 + level[:-1], N + 1 + level]
    m = len(i)
    r = beam_static.plate_response(x, np.full(len(x), R), i, j, np.full(m, 2 * R), np.full(m, ka),
                                   np.full(m, kb), np.full(m, kt), axis=1, plate_low=-R,
                                   plate_high=2 * R * N + R, plate_stiffness=kn, touch=1e-9 * R)
    F = 2.0 / (2.0 / kn + N / ka)
    assert r.force_low == pytest.approx(F, rel=1e-12) and r.force_high == pytest.approx(F, rel=1e-12)
    assert list(np.nonzero(r.low)[0]) == [0, N + 1] and list(np.nonzero(r.high)[0]) == [N, 2 * N + 1]
    shortening = r.u[j, 1] - r.u[i, 1]
    assert shortening[:2 * N] == pytest.approx(np.full(2 * N, -0.5 * F / ka), rel=1e-12)
    assert np.abs(shortening[2 * N:]).max() < 1e-12 * 0.5 * F / ka
    assert np.abs(r.u[:, [0, 2]]).max() < 1e-12 and np.abs(r.theta).max() < 1e-12 / R
    assert not r.pulled.any()


def test_plate_forces_balance_on_a_disordered_network():
    """A jittered grid between plates along x, its two end layers flat (every element of each touches
    its plate): the network moves across the load and turns, yet the two plate forces are equal to
    round-off (1e-10: the hold springs act across the load only, so the axial balance is exact)."""
    rng = np.random.default_rng(4)
    x, radius, i, j, L0, ka, kb, kt = jittered_network(rng, shape=(6, 4, 4))
    R = radius[0]
    layer = np.round(x[:, 0] / (2 * R))
    ends = (layer == 0) | (layer == 5)
    x[ends, 0] = 2 * R * layer[ends]
    L0 = np.linalg.norm(x[j] - x[i], axis=1)
    r = beam_static.plate_response(x, radius, i, j, L0, ka, kb, kt, 0, -R, 11 * R, float(np.mean(ka)), 1e-9 * R)
    assert r.low.sum() == r.high.sum() == 16
    assert r.force_low == pytest.approx(r.force_high, rel=1e-10) and r.force_low > 0
    assert np.abs(r.u[:, 1:]).max() > 1e-3 and np.abs(r.theta).max() > 1e-3 / R


def test_a_lever_lifts_its_far_support():
    """A stiff beam A-B-C across the load resting on the fixed plate, pressed at A through D by the
    moving plate: A sinks into its plate spring, the beam turns about B and C rises off its plate,
    which would have to pull it (``pulled``): C only."""
    R = 1e-3
    x = np.array([[0.0, 0.0, R], [0.0, 2 * R, R], [0.0, 4 * R, R], [0.0, 0.0, 3 * R]])   # A, B, C, D
    i, j = np.array([0, 1, 0]), np.array([1, 2, 3])
    m = len(i)
    # bonds 1e3 stiffer than the plate springs (12 kb / L0^3 = 1.5e6 N/m): the beam turns nearly rigidly
    r = beam_static.plate_response(x, np.full(4, R), i, j, np.full(m, 2 * R), np.full(m, 1e6), np.full(m, 1e-3),
                                   np.full(m, 1e-2), axis=2, plate_low=0.0, plate_high=4 * R,
                                   plate_stiffness=1e3, touch=1e-9 * R)
    assert list(np.nonzero(r.low)[0]) == [0, 1, 2] and list(np.nonzero(r.high)[0]) == [3]
    assert r.u[2, 2] > 0.0 and list(np.nonzero(r.pulled)[0]) == [2]


@pytest.mark.parametrize("axis, young", [("x", "1e8"), ("y", "[3e8, 1e8, 5e7]")])
def test_ordered_lattice_modulus_is_pi_over_4_E_r2(axis, young):
    """An ordered lattice loaded along a lattice axis: every column is a chain of bonds along the
    load, so E^D = pi/4 E r^2 (``constants.analytic_young``; E the bonds' modulus along the load).
    Tolerance 1e-12: a nu = 0 lattice does not move across the load, so the hold springs carry
    nothing and what remains is round-off (measured 2e-15)."""
    deck = load_deck(COMPRESS_SCHEMA, None, ["domain.box=[0.004, 0.002, 0.002]", f"loading.axis=\"{axis}\"",
                                             f"bonds.young={young}"])
    case = build_case(Communicator(), deck)
    assert case.constants.n_elements > 100
    assert static_modulus(case) == pytest.approx(case.constants.analytic_young, rel=1e-12)


@pytest.mark.parametrize("setting", ["plates.law=\"hertz\"", "plates.friction=0.3", "plates.lateral_walls=true"])
def test_plates_the_static_model_does_not_describe_are_refused(setting):
    deck = load_deck(COMPRESS_SCHEMA, None, ["domain.box=[0.004, 0.002, 0.002]", setting])
    with pytest.raises(ValueError, match="linear frictionless plates without lateral walls"):
        static_modulus(build_case(Communicator(), deck))
