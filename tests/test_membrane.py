"""The flexible membrane of the 2D biaxial test (``pardem.physics.membrane``), on hand-built
packings whose chain is known, and its loads against the pressure on the chord."""
import numpy as np
import pytest

from pardem.physics import membrane

D = 2e-4        # grain diameter [m]


def grid(nx=6, ny=10, drop=(), extra=()):
    """A square array of grains (spacing D), bottom row = bottom platen, top row = top platen;
    ``drop``: (col, row) removed; ``extra``: (x, y) in units of D added."""
    pts = [(c * D, r * D) for r in range(ny) for c in range(nx) if (c, r) not in drop]
    pts += [(px * D, py * D) for px, py in extra]
    x = np.array(pts)
    return x, np.isclose(x[:, 1], 0.0), np.isclose(x[:, 1], (ny - 1) * D)


def coords(x, links):
    return [tuple(np.round(x[k] / D, 6)) for k in links]


@pytest.mark.parametrize("side, col", [("right", 5), ("left", 0)])
def test_a_straight_side_is_its_outer_column(side, col):
    x, bottom, top = grid()
    links = membrane.chain(x, bottom, top, side, r_m=1.5 * D)
    assert coords(x, links) == [(col, r) for r in range(10)]


def test_the_chain_follows_a_bay_and_wraps_a_bump():
    # a missing grain at (5, 4): the chain steps in to (4, 4) and back out; a grain sticking out at
    # (6, 7): the chain goes out to it and skips (5, 7), which is inside the membrane
    x, bottom, top = grid(drop=[(5, 4)], extra=[(6, 7)])
    links = membrane.chain(x, bottom, top, "right", r_m=1.5 * D)
    assert coords(x, links) == [(5, 0), (5, 1), (5, 2), (5, 3), (4, 4), (5, 5), (5, 6), (6, 7), (5, 8), (5, 9)]


def test_a_gap_wider_than_the_search_distance_is_refused_in_one_line():
    x, bottom, top = grid(drop=[(c, 5) for c in range(6)])
    with pytest.raises(ValueError, match="without reaching the top platen"):
        membrane.chain(x, bottom, top, "right", r_m=1.5 * D)


def test_a_straight_vertical_chain_carries_the_pressure_times_its_height():
    x, bottom, top = grid()
    links = membrane.chain(x, bottom, top, "right", r_m=1.5 * D)
    p, t = 1e6, D
    f = membrane.forces(x, links, "right", p, t)
    height = 9 * D
    assert f.sum(axis=0) == pytest.approx([-p * t * height, 0.0], abs=1e-12 * p * t * height)
    # interior grains: one spacing each, pointing in (-x); the ends half of it
    assert np.allclose(f[1:-1], [-p * t * D, 0.0], rtol=0, atol=1e-9 * p * t * D)
    assert np.allclose(f[[0, -1]], [-0.5 * p * t * D, 0.0], rtol=0, atol=1e-9 * p * t * D)
    fl = membrane.forces(x, membrane.chain(x, bottom, top, "left", 1.5 * D), "left", p, t)
    assert fl.sum(axis=0) == pytest.approx([p * t * height, 0.0], abs=1e-12 * p * t * height)


def test_any_chain_carries_the_pressure_on_its_chord_normal_to_each_segment():
    """A random chain: the total is p t R(x_last - x_first) exactly, and each grain's force is the
    sum of its two half segments' L n (independent: computed segment by segment here)."""
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.uniform([-0.5, 0.2], [0.5, 1.0], size=(30, 2)), axis=0) * D
    links = np.arange(30)
    p, t = 3e5, 1.7 * D
    f = membrane.forces(x, links, "right", p, t)
    chord = x[-1] - x[0]
    assert f.sum(axis=0) == pytest.approx(p * t * np.array([-chord[1], chord[0]]), rel=1e-12)
    seg = np.diff(x, axis=0)
    L = np.linalg.norm(seg, axis=1)
    n_in = np.column_stack([-seg[:, 1], seg[:, 0]]) / L[:, None]      # inward (-x side) normals
    ref = np.zeros_like(x)
    ref[:-1] += 0.5 * p * t * L[:, None] * n_in
    ref[1:] += 0.5 * p * t * L[:, None] * n_in
    assert np.allclose(f, ref, rtol=1e-12, atol=1e-15 * p * t * D)
