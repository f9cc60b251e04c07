"""Compact domains (docs/physics.md section 4): jammed random packings, their bonds, their compression.

Packings are checked against independent O(N^2) NumPy computations (overlaps with minimum images,
bonded pairs, clusters), against the jamming physics (an at least isostatic contact network) and
statistics (radius distribution, isotropic fabric); a compressed column against the Voigt bound of
its bond network and against the static linear response of the same network (a sparse solve, 1.5 %),
one rank against two, and a restart against the uninterrupted run.
"""
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from pardem.protocols.compression import build_case, static_modulus
from pardem.io.deck_file import load_deck
from pardem.protocols.compression_deck import COMPRESS_SCHEMA
from pardem.domains.compact import (MIN_FRACTION, bonded_pairs, compact_domain, compact_packing,
                                    element_count, overlap_forces)
from pardem.drivers import compress
from pardem.io.series import read_series
from pardem.parallel.communicator import Communicator

R = 0.25e-3
DISPERSITY = 0.1
CUBE = [0.006] * 3                  # fully periodic, 24 R: ~2,100 elements
SMALL = [0.0035] * 3                # fully periodic, 14 R: ~415 elements
COLUMN = [0.012, 0.003, 0.003]      # flat faces normal to x (48 R), periodic across: ~1,050 elements
COLUMN_ARGS = ["--set", "domain.kind=compact", "--set", f"domain.box={COLUMN}",
               "--set", f"domain.radius={R}", "--set", "domain.seed=2", "--set", "loading.axis=x"]
MPIEXEC = shutil.which("mpiexec.mpich") or shutil.which("mpiexec")


@pytest.fixture(scope="module")
def cube():
    return compact_packing(CUBE, R, DISPERSITY, seed=1)


@pytest.fixture(scope="module")
def small():
    return compact_packing(SMALL, R, DISPERSITY, seed=3)


@pytest.fixture(scope="module")
def column():
    return compact_packing(COLUMN, R, DISPERSITY, seed=2, flat_axis=0)


def pair_overlaps(p):
    """Overlaps R_i + R_j - |d| [N, N] with minimum images along the periodic axes (brute force)."""
    x, r, L = p.positions, p.radii, np.array(p.box)
    periodic = np.arange(3) != p.flat_axis
    d = x[None, :, :] - x[:, None, :]
    d[..., periodic] -= L[periodic] * np.round(d[..., periodic] / L[periodic])
    ov = r[None, :] + r[:, None] - np.linalg.norm(d, axis=-1)
    np.fill_diagonal(ov, -np.inf)
    return ov


def brute_pairs(x, r, gap):
    """Set of (i, j), i < j, with surface gap below ``gap``, no periodicity."""
    dist = np.linalg.norm(x[None, :, :] - x[:, None, :], axis=-1)
    i, j = np.nonzero(np.triu(dist - r[None, :] - r[:, None] < gap, k=1))
    return set(zip(i.tolist(), j.tolist()))


def components(n, pairs):
    """Connected components (lists of nodes) by breadth-first search."""
    nbrs = [[] for _ in range(n)]
    for i, j in pairs:
        nbrs[i].append(j)
        nbrs[j].append(i)
    seen = np.zeros(n, bool)
    out = []
    for s in range(n):
        if seen[s]:
            continue
        seen[s] = True
        comp, todo = [s], [s]
        while todo:
            for b in nbrs[todo.pop()]:
                if not seen[b]:
                    seen[b] = True
                    comp.append(b)
                    todo.append(b)
        out.append(comp)
    return out


def test_overlap_forces_are_minus_the_energy_gradient():
    """The minimised energy and its forces agree (central differences), pair forces balance, and
    the energy is the brute-force sum over periodic pairs (images along y, z) and the x walls."""
    rng = np.random.default_rng(5)
    n, L = 40, np.array([6.0, 7.0, 8.0])
    x = rng.uniform(0.0, 1.0, (n, 3)) * L
    r = rng.uniform(0.8, 1.2, n)
    walls = np.array([True, False, False])
    i, j = np.triu_indices(n, 1)
    shift = np.zeros((len(i), 3))
    d = x[j] - x[i]
    shift[:, 1:] = -L[1:] * np.round(d[:, 1:] / L[1:])      # minimum images (L > 4 R_max)
    i, j = i.astype(np.int32), j.astype(np.int32)
    f = np.zeros_like(x)
    energy, _, _ = overlap_forces(x, r, i, j, shift, L, walls, f)
    delta = np.maximum(r[i] + r[j] - np.linalg.norm(d + shift, axis=1), 0.0)
    wall = np.maximum(r - x[:, 0], 0.0) ** 2 + np.maximum(x[:, 0] + r - L[0], 0.0) ** 2
    assert energy == pytest.approx(0.5 * np.sum(delta**2) + 0.5 * np.sum(wall), rel=1e-12)
    assert energy > 0 and wall.sum() > 0
    h = 1e-6
    for k, c in [(a, b) for a in range(0, n, 7) for b in range(3)]:
        xp, xm = x.copy(), x.copy()
        xp[k, c] += h
        xm[k, c] -= h
        g = (overlap_forces(xp, r, i, j, shift, L, walls, np.zeros_like(x))[0]
             - overlap_forces(xm, r, i, j, shift, L, walls, np.zeros_like(x))[0]) / (2 * h)
        assert f[k, c] == pytest.approx(-g, abs=1e-7)
    f_pairs = np.zeros_like(x)
    overlap_forces(x, r, i, j, shift, L, np.zeros(3, bool), f_pairs)
    assert np.abs(f_pairs.sum(axis=0)).max() < 1e-12


@pytest.mark.parametrize("name", ["cube", "column"])
def test_solid_fraction_and_tiny_overlaps(name, request):
    """Solid fraction >= 0.63 as reported; the largest overlap (brute force, periodic images
    included) is the reported one and below 1e-3 R: the bisection stops at a relative step of
    1e-4 in solid fraction, i.e. overlaps of order 1e-4 R."""
    p = request.getfixturevalue(name)
    fraction = 4.0 / 3.0 * np.pi * np.sum(p.radii**3) / np.prod(p.box)
    assert p.solid_fraction == pytest.approx(fraction, rel=1e-12)
    assert fraction >= MIN_FRACTION
    worst = pair_overlaps(p).max() / np.mean(p.radii)
    assert p.max_overlap == pytest.approx(worst, rel=1e-9)
    assert 0.0 < worst < 1e-3      # positive: the kept state is the jammed one, with contacts
    assert p.mean_radius == pytest.approx(R, rel=0.015)   # n set for 0.64, jammed within 0.63-0.65
    assert p.n == element_count(p.box, R, DISPERSITY)


def test_jammed_contact_network_is_isostatic(cube):
    """At the jamming point of frictionless spheres, once rattlers (fewer than 4 contacts) are
    removed, the contacts number 3 (N - 1) + O(1) (Maxwell count; O'Hern et al. 2003): mean contact
    number 6. A loose (unjammed) packing has far fewer, an over-compressed one more; the capped
    minimisations leave the state within a few contacts of isostatic (|Z - 6| < 0.05)."""
    contact = pair_overlaps(cube) > 0.0
    alive = np.ones(cube.n, bool)
    while True:
        z = (contact & alive[None, :]).sum(axis=1)
        drop = alive & (z < 4)
        if not drop.any():
            break
        alive &= ~drop
    n = alive.sum()
    contacts = contact[np.ix_(alive, alive)].sum() // 2
    assert n > 0.95 * cube.n                    # few rattlers (~2-3 % in 3D)
    assert 2 * contacts / n == pytest.approx(6.0, abs=0.05)


def test_flat_faces_touch_the_walls(column):
    """Along the flat axis every sphere lies within the box (to 1e-3 R), and a dense layer touches
    each face: at least half of face area / (pi R^2) elements within 1e-3 R of it (a face cut out
    of a periodic packing is rough on the scale of R: a handful would)."""
    x, r, L = column.positions[:, 0], column.radii, column.box[0]
    tol = 1e-3 * R
    assert np.all(x - r >= -tol) and np.all(x + r <= L + tol)
    assert column.max_wall_overlap * column.mean_radius < tol
    layer = 0.5 * column.box[1] * column.box[2] / (np.pi * column.mean_radius**2)
    assert np.sum(np.abs(x - r) < tol) > layer
    assert np.sum(np.abs(x + r - L) < tol) > layer


def test_radii_within_the_dispersity(cube):
    """Radii uniform in s R (1 +- d): the extreme ratio is at most (1 + d)/(1 - d) and, for n
    draws, within 20 d / n of it at each end (probability of a miss e^-10); the relative standard
    deviation is d / sqrt(3) within 5 standard errors of a sample variance."""
    r, d, n = cube.radii, DISPERSITY, cube.n
    assert r.max() / r.min() <= (1 + d) / (1 - d) * (1 + 1e-12)
    eps = 20 * d / n
    assert r.max() / r.min() >= (1 + d - eps) / (1 - d + eps)
    rel_std = np.std(r) / np.mean(r)
    # var of a uniform sample variance: (mu4 - sigma^4)/n with mu4 = 9/5 sigma^4
    assert rel_std == pytest.approx(d / np.sqrt(3), rel=5 * 0.5 * np.sqrt(0.8 / n))
    assert cube.mean_radius == pytest.approx(np.mean(r), rel=1e-12)


def test_same_seed_same_packing_other_seed_differs(small):
    again = compact_packing(SMALL, R, DISPERSITY, seed=3)
    assert again.positions.tobytes() == small.positions.tobytes()
    assert again.radii.tobytes() == small.radii.tobytes()
    other = compact_packing(SMALL, R, DISPERSITY, seed=4)
    assert other.n == small.n
    assert not np.allclose(np.sort(other.radii), np.sort(small.radii))
    assert np.abs(np.sort(other.positions[:, 0]) - np.sort(small.positions[:, 0])).max() > 0.1 * R


def test_bonds_are_exactly_the_pairs_within_the_gap(column):
    """Against an O(N^2) search without periodicity (so no bond crosses the periodic faces), and
    the elements kept are exactly the largest bonded cluster of the packing."""
    gap = 0.01 * column.mean_radius
    x, r, pairs = compact_domain(column, gap)
    assert set(map(tuple, pairs.tolist())) == brute_pairs(x, r, gap)
    assert np.all(pairs[:, 0] < pairs[:, 1])
    full = brute_pairs(column.positions, column.radii, gap)
    assert set(map(tuple, bonded_pairs(column.positions, column.radii, gap).tolist())) == full
    largest = max(components(column.n, full), key=len)
    assert len(largest) == len(r) > 0.99 * column.n
    kept = column.positions[np.sort(largest)]
    assert np.array_equal(kept[np.lexsort(kept.T)], x[np.lexsort(x.T)])
    z = 2 * len(pairs) / len(r)
    assert 5.0 < z < 6.5          # realistic coordination for a 1 % gap (contacts: ~6 minus the cut faces)


def test_fabric_is_isotropic(cube):
    """Bond directions of a cube: <n n> = I/3 within 5 standard errors of m independent isotropic
    directions (std of n_x^2: sqrt(4/45/m), the largest of the components)."""
    x, r, pairs = compact_domain(cube, 0.01 * cube.mean_radius)
    d = x[pairs[:, 1]] - x[pairs[:, 0]]
    n = d / np.linalg.norm(d, axis=1)[:, None]
    fabric = n.T @ n / len(n)
    assert np.abs(fabric - np.eye(3) / 3).max() < 5 * np.sqrt(4 / 45 / len(n))


def voigt_young(case, axis):
    """Young's modulus along ``axis`` of the affine (Voigt) stiffness of the bond network [Pa].

    Affine strain with no element rotation: each bond stretches by n.eps.l (axial stiffness ka)
    and shears by the rest of eps.l against both clamped ends (12 E I / L^3). Its energy bounds
    the relaxed one from above, so the modulus of the network cannot exceed this."""
    e, b = case.sim.elements, case.sim.bonds
    once = b.counted_once(e.n_owned)
    L0 = b.L0[once]
    n = (e.x[b.j[once]] - e.x[b.i[once]]) / L0[:, None]
    ks = 12.0 * b.kb[once] / L0**3           # kb = E I
    nnnn = np.einsum("a,ai,aj,ak,al->ijkl", L0**2 * (b.ka[once] - ks), n, n, n, n)
    ndn = np.einsum("a,ai,jk,al->ijkl", L0**2 * ks, n, np.eye(3), n)
    C = (nnnn + ndn) / np.prod(case.deck["domain"]["box"])
    C = 0.25 * (C + C.transpose(1, 0, 2, 3) + C.transpose(0, 1, 3, 2) + C.transpose(1, 0, 3, 2))
    voigt = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]
    M = np.array([[C[i, j, k, l] * (1 if k == l else 2) for k, l in voigt] for i, j in voigt])
    return 1.0 / np.linalg.inv(M)[axis, axis]


@pytest.fixture(scope="module")
def column_run(tmp_path_factory):
    """The column compressed along x on one rank, with a checkpoint half way."""
    out = tmp_path_factory.mktemp("column") / "one"
    assert compress.main(COLUMN_ARGS + ["--set", "checkpoint.every_steps=1000", "--set", "checkpoint.keep=10", "--out", str(out),
                                        "--quiet"]) == 0
    return json.loads((out / "summary.json").read_text()), out


def test_compression_modulus_within_the_voigt_bound(column_run, column):
    """A finite positive, quasi-static modulus (slope and secant agree), at most the Voigt bound
    of the same bonds (measured 0.81 of it); and the static linear response of the same bond network
    (``compression.static_modulus``, an independent computation) gives the same modulus within
    1.5 %: the dynamic slope's loading-rate error (about 2 % after 4 axial wave transits, 0.7 % after 8,
    pardem.protocols.anisotropy_study; this run lasts 5.8 of which 3.9 ramp) and the plates' contact
    set (the static modulus moves by 0.05 % between the elements touching at the start and every
    element the plate can reach by the end); measured 0.15 %. The static solve, the network's exact
    relaxed modulus, is the floor (a beam network has no closed-form lower bound to add)."""
    s, _ = column_run
    deck = load_deck(COMPRESS_SCHEMA, None, [a for a in COLUMN_ARGS if a != "--set"])
    case = build_case(Communicator(), deck, packing=column)   # the same packing (seed 2, flat x)
    assert case.constants.n_elements == s["n_elements"] and case.constants.n_bonds == s["n_bonds"]
    assert case.constants.domain_facts["solid_fraction"] >= MIN_FRACTION
    assert case.constants.n_elements + case.constants.domain_facts["removed_elements"] == column.n
    assert np.isnan(case.constants.analytic_young) and s["young_modulus_analytic"] is None   # strict JSON
    assert s["domain"]["solid_fraction"] >= MIN_FRACTION
    assert case.constants.cross_section == pytest.approx(COLUMN[1] * COLUMN[2], rel=1e-12)
    E, bound = s["young_modulus"], voigt_young(case, 0)
    assert np.isfinite(E) and E <= bound
    R_mean = case.constants.domain_facts["mean_radius"]
    travel = case.deck["loading"]["strain"] * case.constants.length
    statics = [static_modulus(case, touch=reach) for reach in (1e-3 * R_mean, travel)]
    for E_static in statics:
        assert E_static <= bound
        assert E == pytest.approx(E_static, rel=0.015)
    assert s["young_modulus_secant"] == pytest.approx(E, rel=0.05)
    for nu in s["poisson_ratios"].values():
        assert 0.0 < nu < 0.5


def test_the_frame_tilts_the_bond_moduli_not_the_packing(column):
    """Tilt 90 deg with TOR moduli [40, 10, 10] MPa: the packing is the same, and the bonds with
    E_L are those closest to y (where L turns to)."""
    args = [a for a in COLUMN_ARGS if a != "--set"] + ["bonds.young=[40e6, 10e6, 10e6]"]
    straight = build_case(Communicator(), load_deck(COMPRESS_SCHEMA, None, args), packing=column)
    tilted = build_case(Communicator(), load_deck(COMPRESS_SCHEMA, None, args + ["domain.tilt_deg=90"]),
                        packing=column)
    e, b = tilted.sim.elements, tilted.sim.bonds
    assert np.array_equal(straight.sim.elements.x, e.x)
    u = np.abs(e.x[b.j] - e.x[b.i])
    assert np.array_equal(b.young == 40e6, np.argmax(u, axis=1) == 1)
    u0 = np.abs(e.x[straight.sim.bonds.j] - e.x[straight.sim.bonds.i])
    assert np.array_equal(straight.sim.bonds.young == 40e6, np.argmax(u0, axis=1) == 0)


@pytest.mark.mpi
def test_two_ranks_agree_with_one(column_run, tmp_path):
    """Rank 0 builds the packing and broadcasts it: two ranks run the same column, to round-off."""
    s1, out1 = column_run
    out2 = tmp_path / "two"
    p = subprocess.run([MPIEXEC, "-n", "2", sys.executable, "-m", "pardem.drivers.compress", "--quiet",
                        "--out", str(out2), "--set", "checkpoint.every_steps=1000", *COLUMN_ARGS],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    s2 = json.loads((out2 / "summary.json").read_text())
    assert s2["n_ranks"] == 2 and all(r["owned_elements"] > 0 for r in s2["per_rank"])
    assert (s2["n_elements"], s2["n_bonds"]) == (s1["n_elements"], s1["n_bonds"])
    a, b = read_series(out1 / "series.csv"), read_series(out2 / "series.csv")
    assert a["step"] == b["step"]
    strains = [k for k in a if k.startswith("eps")]
    scale = max(np.abs(np.array(a[k])).max() for k in strains)
    for k in a:
        x, y = np.array(a[k]), np.array(b[k])
        tol = 1e-9 * (scale if k in strains else np.abs(x).max())
        assert np.abs(x - y).max() <= tol, k
    assert s2["young_modulus"] == pytest.approx(s1["young_modulus"], rel=1e-9)


def test_restart_continues_bit_for_bit(column_run, tmp_path):
    """The restart reads everything from the checkpoint (no packing is rebuilt)."""
    s, out = column_run
    first = out / "checkpoints" / "checkpoint-0000001000.h5"
    assert compress.main(["--restart", str(first), "--out", str(tmp_path / "r"), "--quiet"]) == 0
    r = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert r["steps"] == s["steps"] and r["young_modulus"] == s["young_modulus"]
    assert (tmp_path / "r" / "series.csv").read_text() == (out / "series.csv").read_text()


BAD = [
    (["--set", "domain.seed=-1"], "domain.seed", "an integer in [0, inf)"),
    (["--set", "domain.seed=1.5"], "domain.seed", "an integer in [0, inf)"),
    (["--set", "domain.seed=\"abc\""], "domain.seed", "an integer"),
    (["--set", "domain.dispersity=0.5"], "domain.dispersity", "[0.0, 0.5)"),
    (["--set", "domain.dispersity=-0.1"], "domain.dispersity", "[0.0, 0.5)"),
    (["--set", "domain.bond_gap=-0.01"], "domain.bond_gap", "[0.0, 0.5]"),
    (["--set", "domain.bond_gap=0.6"], "domain.bond_gap", "[0.0, 0.5]"),
    (["--set", "domain.kind=random"], "domain.kind", "'ordered', 'compact'"),
    (["--set", "domain.box=[0.001, 0.01, 0.01]"], "domain.box", "at least 6 radii"),
    (["--set", "domain.box=[0.003, 0.003, 0.003]", "--set", "domain.radius=0.25e-3"], "domain.box",
     "loading axis of at least 40 radii"),
]


@pytest.mark.parametrize("argv, field, allowed", BAD, ids=[b[1] + ":" + b[0][-1] for b in BAD])
def test_bad_compact_input_exits_2_with_one_line(argv, field, allowed, capsys, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        compress.main(["--set", "domain.kind=compact"] + argv + ["--out", str(out), "--quiet"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert field in err[0] and allowed in err[0], err[0]
    assert not out.exists()


def test_a_packing_of_another_domain_is_refused(small):
    deck = load_deck(COMPRESS_SCHEMA, None, [a for a in COLUMN_ARGS if a != "--set"])
    with pytest.raises(ValueError, match="not the deck's domain"):
        build_case(Communicator(), deck, packing=small)
