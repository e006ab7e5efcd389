"""The fast paths of the per-call work (issue 14): each gives what the plain form gives.

- equilibrate's exponent formulations (dense and sparse) against the plain one (products of
  the scaled matrix in every sweep, at the end of this file): the same powers of two, exactly;
- the union-find of small models' connected parts against SciPy's connected_components;
- CasADi functions called through their raw buffers (FastFunction) against Function calls,
  also from two threads at once;
- the derivative array tested at its top level first: the same answer as level by level;
- initialize from a start that is consistent already (every state fixed, as in a sweep over
  initial states): no Gauss-Newton step, and the exact multiplier.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

import daekit as dk
from daekit import numerics
from daekit.analysis.core import _components, _derivative_array
from daekit.model import Incidence
from daekit.points import TestPoint, consistent_point
from daekit.reduction.differentiate import expand


def _random_matrix(rng, kind, m, n):
    A = rng.standard_normal((m, n)) * (rng.random((m, n)) < rng.uniform(0.1, 1.0))
    if kind == 1:  # wild units: rows and columns scaled by powers of two
        A = A * 2.0 ** rng.integers(-30, 30, (m, 1)) * 2.0 ** rng.integers(-30, 30, (1, n))
    elif kind == 2:  # entries that are powers of two (ties in the rounding of the exponents)
        A = np.round(A * 4) / 4 * 2.0 ** rng.integers(-3, 3, (m, n))
    elif kind == 3:  # decades apart, with rounding residue of exact zeros
        A = A * 10.0 ** rng.uniform(-12, 12, (m, 1))
        A[rng.random((m, n)) < 0.1] = 1e-17
    elif kind == 4:  # non-finite entries and a zero row
        A[rng.random((m, n)) < 0.05] = np.nan
        A[0] = 0.0
    return A


def test_equilibrate_dense_is_the_plain_iteration():
    rng = np.random.default_rng(7)
    for trial in range(400):
        A = _random_matrix(rng, trial % 5, int(rng.integers(1, 30)), int(rng.integers(1, 30)))
        dr, dc = numerics.equilibrate(A)
        rr, rc = equilibrate_reference(A)
        np.testing.assert_array_equal(dr, rr)
        np.testing.assert_array_equal(dc, rc)


def test_equilibrate_sparse_is_the_plain_iteration():
    rng = np.random.default_rng(8)
    for trial in range(12):
        m, n = int(rng.integers(250, 600)), int(rng.integers(250, 600))  # > DENSE_EQUILIBRATE
        A = sp.random(m, n, density=float(rng.uniform(0.003, 0.02)), random_state=trial,
                      format="csr")
        A = (sp.diags(2.0 ** rng.integers(-20, 20, m)) @ A
             @ sp.diags(10.0 ** rng.uniform(-8, 8, n))).tocsr()
        if trial % 3 == 0:
            A.data[rng.random(A.nnz) < 0.05] = 1e-25
        dr, dc = numerics.equilibrate(A)
        rr, rc = equilibrate_reference(A)
        np.testing.assert_array_equal(dr, rr)
        np.testing.assert_array_equal(dc, rc)
        B = abs(sp.diags(dr) @ A @ sp.diags(dc)).tocsr()
        rmax = B.max(axis=1).toarray().ravel()
        assert np.all((rmax == 0) | ((rmax >= 0.5) & (rmax <= 2.0)))


def test_small_components_match_scipy():
    rng = np.random.default_rng(9)
    for _ in range(300):
        ne, nu, nnz = int(rng.integers(1, 60)), int(rng.integers(1, 60)), int(rng.integers(0, 90))
        rows, cols = rng.integers(0, ne, nnz), rng.integers(0, nu, nnz)
        eq_lab, unk_lab = _components(Incidence(ne, nu, rows, cols, np.zeros(nnz, int)))
        g = sp.csr_matrix((np.ones(nnz, np.int8), (rows, ne + cols)), shape=(ne + nu, ne + nu))
        _, lab = sp.csgraph.connected_components(g, directed=False)
        np.testing.assert_array_equal(eq_lab, lab[:ne])
        np.testing.assert_array_equal(unk_lab, lab[ne:])


def test_fast_function_matches_function_from_two_threads():
    x = ca.SX.sym("x", 3)
    t = ca.SX.sym("t")
    f = ca.Function("f", [t, x], [ca.sin(x) * t, ca.sum1(x**2), ca.SX(0, 1)])
    fast = numerics.FastFunction(f)
    rng = np.random.default_rng(1)
    args = [(float(rng.uniform()), rng.standard_normal(3)) for _ in range(400)]

    def run(chunk):
        return [fast(tv, xv) for tv, xv in chunk]

    with ThreadPoolExecutor(2) as ex:
        parts = list(ex.map(run, [args[::2], args[1::2]]))
    got = {id(a): o for chunk, res in zip([args[::2], args[1::2]], parts, strict=True)
           for a, o in zip(chunk, res, strict=True)}
    for a in args:
        want = f(*a)
        out = got[id(a)]
        np.testing.assert_array_equal(out[0], np.asarray(want[0]).ravel())
        np.testing.assert_array_equal(out[1], np.asarray(want[1]).ravel())
        assert out[2].size == 0
        np.testing.assert_allclose(out[0], np.sin(a[1]) * a[0], rtol=1e-15)


@pytest.mark.parametrize("top", [2, 4])
def test_derivative_array_top_level_first_is_level_by_level(top):
    """The planar pendulum (differential index 3): up to level 2 no level determines the
    derivatives (None both ways); up to level 4 both find index 3 with 2 degrees of freedom."""
    m = dk.examples.pendulum_planar()
    inc = m.incidence()
    m_all = np.zeros(inc.n_unknowns, dtype=np.int64)
    np.maximum.at(m_all, inc.cols, inc.vals)
    rows = cols = np.arange(inc.n_unknowns)
    out = []
    for top_first in (False, True):
        pt = TestPoint(m, None, seed=3)
        assert consistent_point(pt, ca.vertcat(*expand(m).levels)).consistent
        out.append(_derivative_array(m, rows, cols, m_all, pt, top, "analyze", soft=True,
                                     top_first=top_first))
    if top == 2:
        assert out == [None, None]
    else:
        assert [(o.index, o.dof) for o in out] == [(3, 2), (3, 2)]


# --------------------------------------------------------------------------- the plain form
# equilibrate as first written (products of the scaled matrix in every Ruiz sweep, SciPy's
# sparse products, Curtis--Reid's normal equations by SuperLU): the reference for the
# exponent formulations in daekit.numerics.


def _pow2_inv_sqrt(mx):
    mx = np.asarray(mx, dtype=float).ravel()
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(mx > 0, -np.round(0.5 * np.log2(np.where(mx > 0, mx, 1.0))), 0.0)
    return np.exp2(e)


def _curtis_reid(B):
    C = sp.coo_matrix(B)
    keep = C.data > 0
    rows, cols, vals = C.row[keep], C.col[keep], np.log2(C.data[keep])
    m, n = C.shape
    if rows.size == 0:
        return np.zeros(m), np.zeros(n)
    P = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(m, n))
    rc = np.bincount(rows, minlength=m).astype(float)
    cc = np.bincount(cols, minlength=n).astype(float)
    K = sp.bmat([[sp.diags(rc + 1e-10), P], [P.T, sp.diags(cc + 1e-10)]], format="csc")
    b = -np.r_[np.bincount(rows, vals, minlength=m), np.bincount(cols, vals, minlength=n)]
    sol = sp.linalg.spsolve(K, b)
    return sol[:m], sol[m:]


def _ruiz(B, dr, dc, issparse):
    for _ in range(numerics.RUIZ_ITERATIONS):
        if issparse:
            S = sp.diags(dr) @ B @ sp.diags(dc)
            rmax = S.max(axis=1).toarray().ravel()
            cmax = S.max(axis=0).toarray().ravel()
        else:
            S = B * dr[:, None] * dc[None, :]
            rmax, cmax = S.max(axis=1), S.max(axis=0)
        ok_r = (rmax == 0) | ((rmax >= 0.5) & (rmax <= 2.0))
        ok_c = (cmax == 0) | ((cmax >= 0.5) & (cmax <= 2.0))
        if ok_r.all() and ok_c.all():
            break
        dr = dr * _pow2_inv_sqrt(rmax)
        dc = dc * _pow2_inv_sqrt(cmax)
    return dr, dc


def equilibrate_reference(A):
    issparse = sp.issparse(A)
    if issparse:
        B = abs(sp.csr_matrix(A, dtype=float))
        B.data[~np.isfinite(B.data)] = 0.0
        B.eliminate_zeros()
    else:
        B = np.abs(np.atleast_2d(np.asarray(A, dtype=float)))
        B = np.where(np.isfinite(B), B, 0.0)
    m, n = B.shape
    if m == 0 or n == 0:
        return np.ones(m), np.ones(n)
    if issparse:
        rmax0 = B.max(axis=1).toarray().ravel()
        B = B.tocoo()
        sig = B.data > numerics.ROW_NOISE * rmax0[B.row]
        B = sp.csr_matrix((B.data[sig], (B.row[sig], B.col[sig])), shape=(m, n))
    else:
        B = np.where(B > numerics.ROW_NOISE * B.max(axis=1, keepdims=True), B, 0.0)
    dr, dc = _ruiz(B, np.ones(m), np.ones(n), issparse)
    S = (sp.diags(dr) @ B @ sp.diags(dc)).tocsr() if issparse else B * dr[:, None] * dc[None, :]
    if issparse:
        S.data[S.data <= numerics.NOISE] = 0.0
        S.eliminate_zeros()
        keep = sp.diags(1.0 / dr) @ S @ sp.diags(1.0 / dc)
    else:
        keep = np.where(S > numerics.NOISE, B, 0.0)
    lr, lc = _curtis_reid(keep)
    return _ruiz(B, np.exp2(np.round(lr)), np.exp2(np.round(lc)), issparse)


@pytest.mark.parametrize("L, speed", [(1.0, 1.2), (0.8, 0.5), (1.2, 2.0)])
def test_initialize_all_states_fixed_takes_no_step(L, speed):
    # 3D pendulum (m = 1, g = 9.81), every state fixed and consistent (p, v on the rod and
    # tangent to it): nothing to iterate; the rod force per unit length follows from d/dt p.v = 0,
    # z = (v.v - g p3) / L^2 exactly
    r = dk.reduce_index(dk.examples.pendulum3d())
    p, v = [0.6 * L, 0.0, -0.8 * L], [0.0, speed, 0.0]
    init = dk.initialize(r, fixed={"p": p, "der(p)": v}, params={"L": L})
    assert init.iterations == 0
    assert init.x0.tolist() == p + v  # held to the last bit
    assert init.z0[0] == pytest.approx((speed**2 + 9.81 * 0.8 * L) / L**2, rel=1e-14)
    assert sorted(init.redundant) == ["der(p)[2]", "p[2]"] and init.dof == 4
    # the same values pushed off the rod by 1e-6: a contradiction, still found
    with pytest.raises(dk.errors.InitializationError, match="rod"):
        dk.initialize(r, fixed={"p": [p[0] + 1e-6, 0.0, p[2]], "der(p)": v}, params={"L": L})


def _stacked_truth(C: np.ndarray, cols: list[int]) -> list[int]:
    """Fixed states implied by the rows of ``C`` and the fixed states before them: dense
    Gram-Schmidt on the rows ``[C; e_j ...]`` in that order (rows normalized)."""
    from daekit.initialize import _greedy_dependent_rows

    E = np.zeros((len(cols), C.shape[1]))
    E[np.arange(len(cols)), cols] = 1.0
    rows = np.vstack([C, E])
    norms = np.linalg.norm(rows, axis=1)
    rows = rows / np.where(norms > 0, norms, 1.0)[:, None]
    dep = _greedy_dependent_rows(rows, 1e-9)
    return [k - C.shape[0] for k in dep if k >= C.shape[0]]


@pytest.mark.parametrize("seed", range(40))
def test_redundant_fixed_states_match_dense_gram_schmidt(seed):
    # the linear elimination of the sparse path (_redundant_fixed_states) against the dense
    # greedy row basis, on chain-like banded consistency rows (some rows combinations of
    # others, some states in no row) with random subsets of fixed states in random order,
    # some fixed twice
    from daekit.initialize import _redundant_fixed_states

    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 40))
    m = int(rng.integers(1, n))
    C = np.zeros((m, n))
    for i in range(m):
        j = int(rng.integers(0, n - 2))
        C[i, j:j + 3] = rng.normal(size=3) * (rng.random(3) < 0.8)
    if m > 2 and seed % 3 == 0:
        C[-1] = C[0] * 2.0 - C[1] * 0.5  # a dependent consistency row
    C[:, rng.random(n) < 0.1] = 0.0
    C = C * 10.0 ** rng.uniform(-3, 3, (1, n))  # units of the states
    cols = rng.permutation(n)[: int(rng.integers(1, n + 1))].tolist()
    if seed % 4 == 0:
        cols.append(cols[0])  # fixed twice
    got = _redundant_fixed_states(sp.csr_matrix(C), np.array(cols))
    assert got == _stacked_truth(C, cols)


def test_all_fixed_chain_redundant_values_exactly():
    # the planar chain of 70 links (350 unknowns: the sparse path) stretched along the x-axis at
    # rest, every position and velocity fixed: the rods and their derivatives fix every x
    # component (rod k: 2 (x_k - x_{k-1}) d x), so exactly the x components are implied, in
    # either order of the fixed values
    N = 70
    r = dk.reduce_index(dk.examples.planar_chain(N))
    pos = np.zeros(2 * N)
    pos[0::2] = np.arange(1, N + 1)
    xs = {f"q[{2 * k}]" for k in range(N)} | {f"v[{2 * k}]" for k in range(N)}
    for fixed in ({"q": pos, "v": np.zeros(2 * N)}, {"v": np.zeros(2 * N), "q": pos}):
        init = dk.initialize(r, fixed=fixed)
        assert set(init.redundant) == xs and len(init.redundant) == 2 * N
        assert init.iterations == 0 and init.dof == 2 * N
