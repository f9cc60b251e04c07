"""The rebuild kernels of a contact list (pardem.physics.pair_lists) against NumPy oracles, and the
property they and every reordering rely on: a reproducible run's state by gid does not depend on
the order in which its rows are stored.

* ``order_by_key``: the pairs in the order of a stable NumPy sort of their keys (``gid_i * 2^31 +
  gid_j``), with random gids, random pair order, ghost rows and runs of many pairs per first end;
* ``carry_history``: the rows of the table for the keys, as ``contacts.lookup`` (sort + binary
  search) finds them, for key-ordered and unordered tables, duplicates, absent keys and rows of
  signed zeros (``Contacts.table`` leaves them out, so they come back as +0.0);
* ``shift_metres_into``: NumPy's ``shifts * period``, bit for bit;
* a GRAN-SHEAR-like sheared periodic packing (polydisperse, Hertz-Mindlin with friction, rebuilds
  during the run) built from the same particles stored in two row orders gives, after the run, the
  same bits by gid for x, v, w, f, t and the same contact history by key.
"""
import numpy as np
import pytest

from pardem.engine import contacts as contacts_mod
from pardem.engine.contacts import lookup, pair_keys
from pardem.engine.system import Cell, ContactModel, Decomposition, Integration, Particles, System, build
from pardem.parallel.communicator import Communicator
from pardem.physics.pair_lists import carry_history, order_by_key, scattered, shift_metres_into, spatial_order


def random_pairs(rng, n_rows, n_pairs, gid):
    """Unique row pairs oriented by gid, in random order, with random int8 shifts."""
    a = rng.integers(0, n_rows, 4 * n_pairs)
    b = rng.integers(0, n_rows, 4 * n_pairs)
    keep = a != b
    a, b = a[keep], b[keep]
    swap = gid[a] > gid[b]
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    _, first = np.unique(pair_keys(gid[a], gid[b]), return_index=True)
    first = rng.permutation(first)[:n_pairs]
    pairs = np.stack([a[first], b[first]], axis=1).astype(np.int32)
    shifts = rng.integers(-1, 2, (len(pairs), 3)).astype(np.int8)
    return pairs, shifts


@pytest.mark.parametrize("n_rows, n_pairs", [(1, 0), (2, 1), (50, 300), (2000, 9000), (30, 400)])
def test_order_by_key_is_the_sort_of_the_keys(n_rows, n_pairs):
    rng = np.random.default_rng(n_rows + n_pairs)
    gid = rng.permutation(10 * n_rows)[:n_rows].astype(np.int64)      # sparse, shuffled gids
    pairs, shifts = random_pairs(rng, n_rows, n_pairs, gid)
    keys = pair_keys(gid[pairs[:, 0]], gid[pairs[:, 1]])
    order = np.argsort(keys, kind="stable")
    i, j, s, k = order_by_key(pairs, shifts, gid, n_rows)
    np.testing.assert_array_equal(i, pairs[order, 0])
    np.testing.assert_array_equal(j, pairs[order, 1])
    np.testing.assert_array_equal(s, shifts[order])
    np.testing.assert_array_equal(k, keys[order])


def test_carry_history_equals_lookup():
    rng = np.random.default_rng(7)
    keys = np.unique(rng.integers(0, 5000, 800)).astype(np.int64)
    table_keys = np.concatenate([rng.choice(keys, 300, replace=False), rng.integers(0, 5000, 200)])
    values = rng.normal(size=(len(table_keys), 3))
    values[5] = 0.0
    values[6] = -0.0                       # signed zeros: not in Contacts.table, so +0.0 back
    values[7, 1] = -0.0                    # a live row keeps its signed zero
    values[8:12] = 0.0
    table_keys = np.concatenate([table_keys, table_keys[:40]])            # duplicates (two ranks' parts)
    values = np.concatenate([values, values[:40]])
    values[-35] = 0.0                      # ... one of them not live: the live one is taken
    for tk, tv in ((table_keys, values), (np.sort(table_keys), values[np.argsort(table_keys, kind="stable")])):
        live = np.any(tv != 0.0, axis=1)
        want = lookup(keys, tk[live], tv[live], 3)
        got = carry_history(keys, tk, tv, 3)
        assert got.tobytes() == want.tobytes()
    assert carry_history(keys, np.zeros(0, np.int64), np.zeros((0, 3)), 3).tobytes() == np.zeros((len(keys), 3)).tobytes()


def test_shift_metres_into_is_numpy_product():
    rng = np.random.default_rng(3)
    shifts = rng.integers(-3, 4, (1000, 3)).astype(np.int8)
    period = np.array([1.2345678901e-3, 0.0, 7.1e-3])
    out = np.empty((1000, 3))
    shift_metres_into(shifts, period, out)
    assert out.tobytes() == (shifts * period).tobytes()


from pardem.physics.pair_lists import crossing_rows, shift_metres_rows  # noqa: E402


def test_shift_metres_rows_of_the_crossing_rows_is_the_full_product():
    """Rewriting only the rows with a non-zero image gives the array of the full product for
    every new period (a zero image is +0.0 whatever the period)."""
    rng = np.random.default_rng(4)
    shifts = (rng.integers(-1, 2, (1000, 3)) * (rng.random((1000, 1)) < 0.2)).astype(np.int8)
    rows = crossing_rows(shifts)
    assert 0 < len(rows) < 400
    out = np.empty((1000, 3))
    shift_metres_into(shifts, np.array([1e-3, 2e-3, 0.0]), out)
    period = np.array([1.2345678901e-3, 2.5e-3, 0.0])
    shift_metres_rows(shifts, period, rows, out)
    assert out.tobytes() == (shifts * period).tobytes()


@pytest.mark.parametrize("sort", [False, True])
def test_deforming_cell_shifts_are_those_of_the_current_period(monkeypatch, sort):
    """In a deforming cell the list's shifts in metres (list order, and the computing order of
    sorted rows) are rewritten each step on the pairs across a boundary only: after a run with
    rebuilds they equal the full product with the current period, bit for bit."""
    if sort:
        monkeypatch.setattr(contacts_mod, "SORT_MIN_ROWS", 0)
        # sorted whatever the rows' order (where a rank judges whether its rows are scattered)
        monkeypatch.setattr(contacts_mod, "scattered", lambda *args: True, raising=False)
    sim = build(Communicator(), sheared_packing())
    sim.run(120)
    c = sim.contacts
    assert c.builds > 2 and len(crossing_rows(c.shifts)) > 0
    want = np.empty_like(c.shift)
    shift_metres_into(c.shifts, c.shift_period(), want)
    assert c.shift.tobytes() == want.tobytes()
    if sort:
        assert c._order is not None      # the pairs were computed in the sorted rows' order
        shifts_c, shift_c = c._order[7], c._order[3]
        shift_metres_into(shifts_c, c.shift_period(), want)
        assert shift_c.tobytes() == want.tobytes()

def sheared_packing():
    """A dense polydisperse packing (jittered lattice, radii +-20 %, overlapping) in a periodic
    cell in pure shear at 1e4 1/s, with random velocities and spins."""
    rng = np.random.default_rng(11)
    n, R = 6, 0.1e-3
    g = (np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) * 2 * R
    x = g + rng.uniform(-0.05, 0.05, g.shape) * R
    r = R * rng.uniform(0.8, 1.2, len(x)) * 1.02
    side = n * 2 * R
    return System(Particles(x, r, 2500.0, velocities=rng.normal(0.0, 1.0, x.shape),
                            angular_velocities=rng.normal(0.0, 500.0, x.shape), allow_overlaps=True),
                  contacts=ContactModel("hertz_mindlin", {"young": 72e9, "poisson": 0.2, "friction": 0.5}),
                  cell=Cell((0, 0, 0), (side, side, side), rate=(1e4, -1e4, 0.0)),
                  integration=Integration(dt=2e-8, orientation=False),
                  decomposition=Decomposition(slab_axis=0, skin=0.1 * R))


def permute_rows(sim, perm):
    """Store the rows of a single-process simulation in the order ``perm`` (every per-element
    array, in place), then rebuild its contact list."""
    e = sim.elements
    n = e.n_total
    for name, a in list(vars(e).items()) + list(e.properties.items()):
        if isinstance(a, np.ndarray) and a.ndim and a.shape[0] == n:
            a[:] = a[perm]
    sim.contacts.rebuild(e, sim.bonds)


def by_gid(sim):
    e = sim.elements
    o = np.argsort(e.gid[:e.n_owned])
    state = {k: getattr(e, k)[:e.n_owned][o].tobytes() for k in ("x", "v", "w", "f", "t")}
    c = sim.contacts
    ko = np.argsort(c.keys)
    state["keys"] = c.keys[ko].tobytes()
    state["history"] = c.history[ko].tobytes()
    return state


def test_state_by_gid_does_not_depend_on_row_order():
    """A reproducible run adds every element's loads in an order fixed by gids (pairs in key
    order), and every global decision (rebuild, wrap) is a max or a per-row rule: the same
    particles (same gids) stored in another row order end in the same bits."""
    comm = Communicator()
    runs = []
    for perm in (None, np.random.default_rng(5).permutation(216)):
        sim = build(comm, sheared_packing())
        if perm is not None:
            permute_rows(sim, perm)
            assert np.any(sim.elements.gid != np.arange(216))
        b0 = sim.contacts.builds
        sim.run(300)
        runs.append((by_gid(sim), sim.contacts.builds - b0))
    (a, builds_a), (b, builds_b) = runs
    assert 3 < builds_a < 150    # the lists were rebuilt during the run (the path under test)
    assert builds_a == builds_b
    for k in a:
        assert a[k] == b[k], k


def test_spatial_sort_keeps_the_bits(monkeypatch):
    """Rows stored in spatial order at every rebuild, pairs computed by first row and their loads
    added in key order (``Contacts.sort_rows``): the same bits by gid as the list order, also for
    a packing whose rows start in a random order; the rows were indeed reordered."""
    monkeypatch.setattr(contacts_mod, "SORT_MIN_ROWS", 0)    # sort these 216 rows too
    monkeypatch.setattr(contacts_mod, "scattered", lambda *args: True)   # whatever their order
    comm = Communicator()
    runs = []
    for sort in (False, True):
        sim = build(comm, sheared_packing())
        permute_rows(sim, np.random.default_rng(8).permutation(216))
        sim.contacts.sort_rows = sort
        sim.run(150)
        sim.run(150)                      # a second run: the energy steps at the runs' ends
        runs.append((by_gid(sim), sim.elements.gid.copy()))
    (a, rows_a), (b, rows_b) = runs
    assert not np.array_equal(rows_a, rows_b)
    for k in a:
        assert a[k] == b[k], k


def lattice(n, spacing=1.0):
    g = np.arange(n) * spacing
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)


@pytest.mark.parametrize("n", [10, 24])
def test_rows_built_in_order_are_not_scattered_and_shuffled_rows_are(n):
    """``pair_lists.scattered``: a lattice stored axis by axis is as local as the Morton order (the
    mean storage gap of neighbours, 1, n and n^2 rows, is about n^2 / 3, below twice the Morton
    order's); the same lattice shuffled has a gap about N / 3, many times the Morton order's.
    The pairs are the 6 nearest neighbours, found by brute force over the lattice's index grid."""
    x = lattice(n)
    idx = np.arange(n ** 3).reshape(n, n, n)
    pairs = np.concatenate([np.stack([np.roll(idx, -1, a)[tuple(slice(0, n - 1) if b == a else slice(None)
                                                               for b in range(3))].ravel(),
                                      idx[tuple(slice(0, n - 1) if b == a else slice(None) for b in range(3))].ravel()],
                                     axis=1) for a in range(3)])
    lo, hi = x.min(axis=0) - 0.5, x.max(axis=0) + 0.5
    assert not scattered(pairs[:, 0], pairs[:, 1], x, n ** 3, lo, hi, 1.0)
    perm = np.random.default_rng(3).permutation(n ** 3)      # row perm[k] goes to position k
    where = np.empty_like(perm)
    where[perm] = np.arange(n ** 3)
    assert scattered(where[pairs[:, 0]], where[pairs[:, 1]], x[perm], n ** 3, lo, hi, 1.0)


def test_a_lattice_in_order_is_not_sorted_and_a_shuffled_packing_is(monkeypatch):
    """The rows are sorted only where it pays: the time loop leaves a packing stored in a local
    order as it is, and sorts one stored at random (the same bits either way: tests above)."""
    monkeypatch.setattr(contacts_mod, "SORT_MIN_ROWS", 0)
    comm = Communicator()
    orders = []
    for perm in (None, np.random.default_rng(8).permutation(216)):
        sim = build(comm, sheared_packing())
        if perm is None:
            e, c = sim.elements, sim.contacts      # a local order: Morton's
            permute_rows(sim, spatial_order(e.x, e.n_total, *c.grid_box(e.x), c.cut))
        else:
            permute_rows(sim, perm)
        before = sim.elements.gid.copy()
        sim.run(150)
        orders.append((sim.contacts.scattered, np.array_equal(before, sim.elements.gid)))
    assert orders[0] == (False, True)
    assert orders[1] == (True, False)
