"""Least-squares strain and moduli (pardem.engine.reducer), docs/physics.md section 5.

The fit U = H X0 + c is exact on affine displacement fields, equals NumPy's least squares on
non-affine ones, ignores elements flagged FLAG_NEAR_PLATE and ghost rows, gives the same result when
the sums are split over several "ranks", and reduces to the 1D formula of W on a lattice; the
Reducer reports it with the plate forces; young_and_poisson inverts a known uniaxial strain state.
"""
from types import SimpleNamespace

import numpy as np
import pytest

from pardem.parallel.communicator import Communicator
from pardem.engine.reducer import Reducer, gradient_from_sums, strain_sums, strain_tensor, young_and_poisson
from pardem.engine.state import FLAG_NEAR_PLATE, Bonds, Elements, Plates
from _util import FakeComm


def fit(x, x0, flags, n_owned, origin):
    s = np.empty(25)
    strain_sums(x, x0, flags, n_owned, origin, s)
    return gradient_from_sums(s), s


@pytest.fixture
def affine():
    rng = np.random.default_rng(17)
    n = 80
    x0 = rng.uniform(0.0, 0.01, size=(n, 3))
    H = rng.uniform(-1e-3, 1e-3, size=(3, 3))
    c = rng.uniform(-1e-5, 1e-5, size=3)
    x = x0 + x0 @ H.T + c
    return x0, x, H, rng


def test_affine_field_is_exact(affine):
    x0, x, H, _ = affine
    flags = np.zeros(len(x0), dtype=np.uint8)
    got, s = fit(x, x0, flags, len(x0), np.full(3, 0.005))
    assert s[0] == len(x0)
    np.testing.assert_allclose(got, H, rtol=0, atol=1e-12 * np.abs(H).max())
    np.testing.assert_allclose(strain_tensor(got), 0.5 * (H + H.T), rtol=0, atol=1e-12 * np.abs(H).max())


def test_flagged_and_ghost_rows_are_ignored(affine):
    x0, x, H, rng = affine
    n = len(x0)
    # 15 elements near the plates and 10 ghost rows, all with garbage displacements
    g0 = rng.uniform(0.0, 0.01, size=(25, 3))
    g = g0 + rng.normal(scale=1e-3, size=(25, 3))
    X0 = np.concatenate([x0[:40], g0[:15], x0[40:], g0[15:]])
    X = np.concatenate([x[:40], g[:15], x[40:], g[15:]])
    flags = np.zeros(len(X0), dtype=np.uint8)
    flags[40:55] |= FLAG_NEAR_PLATE
    flags[40:55] |= np.uint8(2)          # other flag bits must not matter
    flags[:3] |= np.uint8(2)
    got, s = fit(X, X0, flags, n + 15, np.zeros(3))
    assert s[0] == n
    np.testing.assert_allclose(got, H, rtol=0, atol=1e-12 * np.abs(H).max())


def test_matches_numpy_least_squares():
    rng = np.random.default_rng(23)
    x0 = rng.uniform(0.0, 0.01, size=(100, 3))
    x = x0 + rng.normal(scale=1e-5, size=x0.shape)     # not affine at all
    got, _ = fit(x, x0, np.zeros(100, dtype=np.uint8), 100, np.array([0.004, 0.006, 0.005]))
    A = np.hstack([x0, np.ones((100, 1))])
    sol = np.linalg.lstsq(A, x - x0, rcond=None)[0]    # U = [X0 1] sol, H = sol[:3].T
    np.testing.assert_allclose(got, sol[:3].T, rtol=0, atol=1e-9 * np.abs(sol[:3]).max())


def test_sums_split_over_ranks(affine):
    x0, x, H, rng = affine
    x = x + rng.normal(scale=1e-7, size=x.shape)
    flags = np.zeros(len(x0), dtype=np.uint8)
    origin = np.full(3, 0.005)
    whole, s_all = fit(x, x0, flags, len(x0), origin)
    total = np.zeros(25)
    for part in np.array_split(rng.permutation(len(x0)), 3):
        s = np.empty(25)
        strain_sums(x[part], x0[part], flags[part], len(part), origin, s)
        total += s
    np.testing.assert_allclose(total, s_all, rtol=1e-12, atol=1e-30)
    np.testing.assert_allclose(gradient_from_sums(total), whole, rtol=0, atol=1e-12 * np.abs(whole).max())


def test_lattice_uniaxial_formula():
    """On a grid, the x-x strain equals W's 1D formula sum(dX dUx) / sum(dX^2)."""
    rng = np.random.default_rng(31)
    g = np.arange(6) * 1e-3
    x0 = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    x = x0 + rng.normal(scale=1e-6, size=x0.shape)
    H, _ = fit(x, x0, np.zeros(len(x0), dtype=np.uint8), len(x0), np.zeros(3))
    dX = x0[:, 0] - x0[:, 0].mean()
    U = x[:, 0] - x0[:, 0]
    assert H[0, 0] == pytest.approx(np.sum(dX * (U - U.mean())) / np.sum(dX**2), rel=1e-10)


def test_too_few_elements():
    x0 = np.random.default_rng(0).uniform(size=(5, 3))
    flags = np.array([0, 0, 0, FLAG_NEAR_PLATE, FLAG_NEAR_PLATE], dtype=np.uint8)
    with pytest.raises(ValueError):
        fit(x0, x0, flags, 5, np.zeros(3))


@pytest.mark.parametrize("comm", [FakeComm(), Communicator()], ids=["fake", "mpi"])
def test_reducer_sample(affine, comm):
    x0, x, H, rng = affine
    e = Elements.from_spheres(x0, 1e-4, 1000.0)
    e.x[:] = x
    e.flags[:5] |= FLAG_NEAR_PLATE
    e.x[:5] += 1e-3                        # garbage on flagged elements
    plates = Plates.pair(0, -0.001, 0.011, 0.1, 1e5)
    plates.positions[1] -= 2e-4           # the moving plate has travelled 0.2 mm
    plates.force_local[:] = [3.5, 3.25]
    sim = SimpleNamespace(elements=e, plates=plates, time=0.002, step_count=7, bonds=Bonds.empty(),
                          bonds_broken_step=0)
    out = Reducer(comm, origin=x0.mean(axis=0)).sample(sim)
    np.testing.assert_allclose(out["H"], H, rtol=0, atol=1e-12 * np.abs(H).max())
    np.testing.assert_allclose(out["eps"], 0.5 * (H + H.T), rtol=0, atol=1e-12 * np.abs(H).max())
    assert out["force_fixed"] == 3.5 and out["force_moving"] == 3.25
    assert out["plate_displacement"] == pytest.approx(2e-4, rel=1e-12)
    assert out["time"] == 0.002 and out["step"] == 7
    assert out["bonds_broken"] == out["bonds_broken_step"] == out["bonds_yielded"] == 0


def test_young_and_poisson():
    E, nu_y, nu_z = 2.5e8, 0.31, 0.22
    S, F = 1e-4, 12.0
    ex = -F / (S * E)                       # compression along x
    eps = np.diag([ex, -nu_y * ex, -nu_z * ex])
    eps[0, 1] = eps[1, 0] = 1e-7            # shear does not enter
    young, nus = young_and_poisson(eps, F, 0, S)
    assert young == pytest.approx(E, rel=1e-12)
    assert nus == pytest.approx({"xy": nu_y, "xz": nu_z}, rel=1e-12)
    # the same state loaded along z
    eps_z = np.diag([-nu_y * ex, -nu_z * ex, ex])
    young, nus = young_and_poisson(eps_z, F, 2, S)
    assert young == pytest.approx(E, rel=1e-12)
    assert nus == pytest.approx({"zx": nu_y, "zy": nu_z}, rel=1e-12)
