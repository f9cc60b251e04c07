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


@njit(cache=True, error_model="numpy")
def add_in_order(loads, inc_start, inc, f, t):
    """Add the loads of pairs computed out of the list's order (``pair_loop``'s ``ordered``) to the
    rows, row by row: ``loads`` [n, 12] of pair q are (F_i, T_i) for its first end and (-F_i,
    T_j) for its second, all -0.0 for a pair that acts nothing (``x + (-0.0) == x`` and ``x - F
    == x + (-F)`` bitwise, so no branch is needed); row r's entries ``inc[inc_start[r]:
    inc_start[r + 1]]`` are ``2 q`` (first end) or ``2 q + 1`` (second end) in the list's order,
    so each row receives the same additions in the same order as from the one-pass loop
    (``pair_lists.compute_order``)."""
    for r in range(inc_start.shape[0] - 1):
        a = inc_start[r]
        b = inc_start[r + 1]
        if a == b:
            continue
        f0, f1, f2 = f[r, 0], f[r, 1], f[r, 2]
        t0, t1, t2 = t[r, 0], t[r, 1], t[r, 2]
        for e in range(a, b):
            code = inc[e]
            q = code >> 1
            o = (code & 1) * 6
            f0 += loads[q, o]
            f1 += loads[q, o + 1]
            f2 += loads[q, o + 2]
            t0 += loads[q, o + 3]
            t1 += loads[q, o + 4]
            t2 += loads[q, o + 5]
        store_row(f, t, r, f0, f1, f2, t0, t1, t2)
