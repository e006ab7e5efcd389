"""Pure structural algorithms on sparse data (no CasADi): Sigma-method, DM, BLT."""

import time

import numpy as np
import pytest

from daekit.structure import (
    block_triangular,
    canonical_offsets,
    dulmage_mendelsohn,
    highest_value_transversal,
    sigma_method,
    structural_index,
)
from daekit.structure.sigma import NoTransversal


def chained_pendula_sigma(p: int):
    """Sigma matrix of Pryce's chained pendula (reference-problems section 3), built by hand.

    Unknowns (x_i, y_i, l_i), equations: x_i'' + x_i l_i, y_i'' + y_i l_i - G,
    x_i^2 + y_i^2 - (L + c l_{i-1})^2.
    """
    rows, cols, vals = [], [], []
    for i in range(p):
        x, y, lam = 3 * i, 3 * i + 1, 3 * i + 2
        e = 3 * i
        rows += [e, e, e + 1, e + 1, e + 2, e + 2]
        cols += [x, lam, y, lam, x, y]
        vals += [2, 0, 2, 0, 0, 0]
        if i > 0:
            rows.append(e + 2)
            cols.append(3 * (i - 1) + 2)
            vals.append(0)
    return 3 * p, np.array(rows), np.array(cols), np.array(vals)


def test_chained_pendula_p2_offsets_as_published():
    n, r, c, v = chained_pendula_sigma(2)
    s = sigma_method(n, r, c, v)
    assert s.c.tolist() == [2, 2, 4, 0, 0, 2]  # Pryce, BIT 41 (2001)
    assert s.d.tolist() == [4, 4, 2, 2, 2, 0]
    assert s.index == 5 and s.dof == 4


@pytest.mark.parametrize("p", range(1, 11))
def test_chained_pendula_index_grows(p):
    s = sigma_method(*chained_pendula_sigma(p))
    assert (s.index, s.dof) == (2 * p + 1, 2 * p)


def test_transversal_is_highest_value():
    # Two perfect matchings: value 1 + 1 = 2 (diagonal) or 3 + 0 = 3 (anti-diagonal)
    t = highest_value_transversal(2, [0, 0, 1, 1], [0, 1, 0, 1], [1, 3, 0, 1])
    assert t.tolist() == [1, 0]


def test_no_transversal_raises():
    with pytest.raises(NoTransversal):
        highest_value_transversal(2, [0, 1], [0, 0], [1, 1])


def test_offsets_of_an_ode_and_index():
    c, d = canonical_offsets(2, [0, 0, 1, 1], [0, 1, 0, 1], [1, 0, 0, 1], [0, 1])
    assert c.tolist() == [0, 0] and d.tolist() == [1, 1]
    assert structural_index(c, d) == 0
    assert structural_index([1, 0], [1, 0]) == 2


def test_dulmage_mendelsohn_parts():
    # rows 0,1 both only on col 0 (over-determined); col 2 and 3 only in row 2 (under-determined)
    d = dulmage_mendelsohn(3, 4, [0, 1, 2, 2, 2], [0, 0, 1, 2, 3])
    assert d.over_rows == [0, 1] and d.over_cols == [0]
    assert d.under_rows == [2] and sorted(d.under_cols) == [1, 2, 3]
    assert d.matching_size == 2 and not d.is_square_nonsingular


def test_block_triangular_order():
    # x0 from row 0; {x1, x2} coupled in rows 1, 2 using x0; x3 from row 3 using x2
    rows = [0, 1, 1, 1, 2, 2, 3, 3]
    cols = [0, 0, 1, 2, 1, 2, 2, 3]
    blocks = block_triangular(4, rows, cols, [0, 1, 2, 3])
    assert [sorted(b[0]) for b in blocks] == [[0], [1, 2], [3]]


def planar_chain_sigma(N: int):
    """Sigma matrix of a planar chain of N links in first-order form (x, y, u, v, lam per link)."""
    rows, cols, vals = [], [], []

    def add(e, j, k):
        rows.append(e)
        cols.append(j)
        vals.append(k)

    for i in range(N):
        x, y, u, v, lam = (5 * i + k for k in range(5))
        e = 5 * i
        add(e, x, 1), add(e, u, 0)
        add(e + 1, y, 1), add(e + 1, v, 0)
        for eq, pos, vel in ((e + 2, x, u), (e + 3, y, v)):
            add(eq, vel, 1), add(eq, lam, 0), add(eq, pos, 0)
            if i > 0:
                add(eq, pos - 5, 0)
            if i < N - 1:
                add(eq, pos + 5, 0), add(eq, lam + 5, 0)
        add(e + 4, x, 0), add(e + 4, y, 0)
        if i > 0:
            add(e + 4, x - 5, 0), add(e + 4, y - 5, 0)
    return 5 * N, np.array(rows), np.array(cols), np.array(vals)


def test_planar_chain_structure():
    s = sigma_method(*planar_chain_sigma(50))
    assert (s.index, s.dof) == (3, 100)


def test_near_linear_scaling():
    """Ten times the equations take well under a hundred times as long (quadratic would)."""

    def run(N):
        n, r, c, v = planar_chain_sigma(N)
        t0 = time.perf_counter()
        s = sigma_method(n, r, c, v)
        dulmage_mendelsohn(n, n, r, c)
        block_triangular(n, r, c, s.transversal)
        return time.perf_counter() - t0

    small = min(run(400) for _ in range(3))  # 2,000 equations
    big = min(run(4000) for _ in range(2))  # 20,000 equations
    assert big < 35 * small, (small, big)


def _dense_best_value(n, rows, cols, vals):
    """The highest transversal value by SciPy's dense Hungarian solver (an independent method),
    or None when there is no transversal."""
    from scipy.optimize import linear_sum_assignment

    big = 10**6
    cost = np.full((n, n), float(big))
    cost[rows, cols] = -np.asarray(vals, dtype=float)
    r, c = linear_sum_assignment(cost)
    if np.any(cost[r, c] >= big):
        return None
    return int(-cost[r, c].sum())


def test_primal_dual_transversal_is_highest_value_on_random_patterns():
    """The primal-dual phases (and the LAPJVsp fallback) give a transversal of the largest
    value that the dense Hungarian method finds, on random sparse Sigma patterns with orders
    0..4; structurally singular ones raise NoTransversal; the offsets exist for the result."""
    from daekit.structure.sigma import _assignment_transversal, _primal_dual_transversal

    rng = np.random.default_rng(3)
    singular = solved = 0
    for trial in range(400):
        n = int(rng.integers(1, 25))
        mask = rng.random((n, n)) < rng.uniform(0.05, 0.5)
        if trial % 2:  # most of them with a transversal: a random permutation added
            mask[np.arange(n), rng.permutation(n)] = True
        rows, cols = np.nonzero(mask)
        vals = rng.integers(0, 5, rows.size)
        best = _dense_best_value(n, rows, cols, vals)
        if best is None:
            singular += 1
            with pytest.raises(NoTransversal):
                highest_value_transversal(n, rows, cols, vals)
            continue
        lookup = dict(zip((rows * n + cols).tolist(), vals.tolist()))
        for t in (highest_value_transversal(n, rows, cols, vals),
                  _primal_dual_transversal(n, rows, cols, vals, phases=10**6),
                  _assignment_transversal(n, rows, cols, vals)):
            assert sorted(t.tolist()) == list(range(n))
            assert sum(lookup[i * n + int(t[i])] for i in range(n)) == best
        c, d = canonical_offsets(n, rows, cols, vals, t)
        assert np.all(c >= 0) and np.all(d[cols] - c[rows] >= vals)
        solved += 1
    assert singular > 20 and solved > 200, (singular, solved)


def test_structurally_nonsingular_agrees_with_dulmage_mendelsohn():
    """The small-pattern matching (Python augmenting paths) and the big one (SciPy, through
    Dulmage--Mendelsohn) give the verdict of a perfect matching's existence, checked against
    brute force over all permutations on tiny patterns."""
    import itertools

    import numpy as np

    from daekit.structure import dulmage_mendelsohn, structurally_nonsingular

    rng = np.random.default_rng(7)
    for _ in range(300):
        n = int(rng.integers(1, 6))
        k = int(rng.integers(0, 2 * n + 1))
        rows, cols = rng.integers(0, n, k), rng.integers(0, n, k)
        pattern = set(zip(rows.tolist(), cols.tolist()))
        brute = any(all((i, p[i]) in pattern for i in range(n))
                    for p in itertools.permutations(range(n)))
        assert structurally_nonsingular(n, n, rows, cols) == brute
        assert dulmage_mendelsohn(n, n, rows, cols).is_square_nonsingular == brute
    assert not structurally_nonsingular(2, 3, [0, 1], [0, 1])
    # beyond SMALL_MATCHING rows: SciPy's route; a chain pattern and one with an empty column
    n = 100
    diag = np.arange(n)
    assert structurally_nonsingular(n, n, np.r_[diag, diag[1:]], np.r_[diag, diag[:-1]])
    assert not structurally_nonsingular(n, n, diag, np.minimum(diag, n - 2))
