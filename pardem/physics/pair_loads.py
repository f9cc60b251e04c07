"""Adding the loads of one interacting pair (bond or contact) to the element rows."""
from numba import njit


@njit(cache=True, inline="always", error_model="numpy")
def scatter_pair(i, j, f, t, out):
    """Add ``out`` = (F_i, T_i, T_j) [N, N m, N m] to rows i and j (j gets ``-F_i``); rows may be
    ghosts (the parallel layer ignores their loads)."""
    f[i, 0] += out[0]
    f[i, 1] += out[1]
    f[i, 2] += out[2]
    f[j, 0] -= out[0]
    f[j, 1] -= out[1]
    f[j, 2] -= out[2]
    t[i, 0] += out[3]
    t[i, 1] += out[4]
    t[i, 2] += out[5]
    t[j, 0] += out[6]
    t[j, 1] += out[7]
    t[j, 2] += out[8]


@njit(cache=True, inline="always", error_model="numpy")
def store_row(f, t, row, f0, f1, f2, t0, t1, t2):
    """Write the loads of one row kept in registers, ``f[row] = (f0, f1, f2)``, ``t[row] = (t0, t1,
    t2)`` (the loops that sum a run of pairs with the same first end outside memory)."""
    f[row, 0] = f0
    f[row, 1] = f1
    f[row, 2] = f2
    t[row, 0] = t0
    t[row, 1] = t1
    t[row, 2] = t2


@njit(cache=True, inline="always", error_model="numpy")
def next_run(f, t, cur, row, f0, f1, f2, t0, t1, t2):
    """A new run of pairs with first end ``row``: the loads of the last run's row ``cur`` (kept in
    registers, none when ``cur < 0``) stored, those of ``row`` loaded. Returns ``(row, f[row],
    t[row])`` as 7 scalars."""
    if cur >= 0:
        store_row(f, t, cur, f0, f1, f2, t0, t1, t2)
    return row, f[row, 0], f[row, 1], f[row, 2], t[row, 0], t[row, 1], t[row, 2]
