"""What analysis and reduction share to be cheap (issue 14), and that sharing changes nothing.

- Pryce's system Jacobian made once (:meth:`daekit.Model.system_jacobian`): the same values
  from its two constructions (one Jacobian per offset value, or the residual's Jacobians by
  order) as the entries ``dF_i / dx_j^(sigma_ij)`` differentiated one by one;
- ``system_jacobian_singular`` gives the same verdict whether ``analyze`` decided it first or
  not (the published failures of structural analysis, and a regular model);
- ``reduce_index`` after ``analyze`` starts its check at the consistent point analyze kept:
  that point satisfies the reduced system (``alg = 0`` and the invariants, checked exactly
  here, and the pendulum's rod force against the closed form ``T = (g y - |v|^2) / L^2``),
  and a changed parameter value is never served a point made with the old one;
- equilibration of tiny dense matrices in Python floats: the same powers of two as the
  array formulation, bit for bit.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit import numerics
from daekit.analysis import system_jacobian_singular
from daekit.points import PointFunction, TestPoint, reduced_consistent_point

MODELS = [
    dk.examples.pendulum_planar,
    dk.examples.l3,
    lambda: dk.examples.chained_pendula(2),
    lambda: dk.examples.planar_chain(4),
    dk.examples.gear_petzold,
]


def _entry_by_entry(m, c, d, pt):
    """``dF_i / dx_j^(d_j - c_i)`` for every incidence entry with ``sigma_ij = d_j - c_i``,
    each differentiated on its own (the definition)."""
    inc = m.incidence()
    out = np.zeros((m.n_equations, m.n_unknowns))
    F = m.residual
    for i, j, k in zip(inc.rows.tolist(), inc.cols.tolist(), inc.vals.tolist(), strict=True):
        if k != d[j] - c[i]:
            continue
        out[i, j] = PointFunction(m, ca.jacobian(F[i], m.symbol(j, k))).dense(pt)[0, 0]
    return out


@pytest.mark.parametrize("make", MODELS)
@pytest.mark.parametrize("warm", [False, True])
def test_system_jacobian_is_the_entries_derivatives(make, warm):
    m = make()
    s = m.sigma()
    if warm:  # the analysis's residual Jacobians by order exist: assembled from them
        for order in range(int(m.incidence().vals.max()) + 1):
            m.residual_jacobian(order)
    J = m.system_jacobian(s.c, s.d)
    assert J is m.system_jacobian(s.c, s.d)  # made once
    pt = TestPoint(m, None, seed=3)
    got = PointFunction(m, J).dense(pt)
    np.testing.assert_allclose(got, _entry_by_entry(m, s.c, s.d, pt), rtol=1e-14, atol=0)


@pytest.mark.parametrize("make", [dk.examples.gear_petzold, dk.examples.oki_linear,
                                  dk.examples.iwata_nonlinear, dk.examples.pendulum_planar])
def test_masked_check_verdict_is_the_same_with_and_without_analyze(make):
    alone = make()
    s = alone.sigma()
    fresh = system_jacobian_singular(alone, s.c, s.d)
    shared = make()
    dk.analyze(shared)  # decides it at the same random point and keeps the verdict
    s2 = shared.sigma()
    assert system_jacobian_singular(shared, s2.c, s2.d) == fresh
    if make is dk.examples.pendulum_planar:
        assert fresh is None
    else:  # the published failures: the system Jacobian is singular
        assert fresh and set(fresh) <= set(alone.equation_names)


def test_reduce_after_analyze_starts_at_the_kept_consistent_point():
    m = dk.examples.pendulum_planar()
    dk.analyze(m)
    r = dk.reduce_index(m)
    assert r.info["index1_check_at"] == "a consistent point"
    t, x, z, u, p = reduced_consistent_point(r, remembered=True)
    kept_t = m.memo("results", dict)["consistent_point"][0]
    assert t == kept_t  # the analysis's point, not a new random one
    f = ca.Function("c", [r.t, r.x, r.z, r.u, r.p], [r.alg, r.invariants])
    alg, inv = (np.asarray(v, dtype=float).ravel() for v in f(t, x, z, u, p))
    assert np.abs(alg).max() < 1e-12 and np.abs(inv).max() < 1e-12
    xs = dict(zip(r.x_names, x, strict=True))
    g, L = (float(v.default[0]) for v in (m.variables["g"], m.variables["L"]))
    T_exact = (g * xs["y"] - (xs["der(x)"] ** 2 + xs["der(y)"] ** 2)) / L**2
    assert z[r.z_names.index("T")] == pytest.approx(T_exact, rel=1e-10, abs=1e-12)
    # another parameter value: the kept point (made with the old one) is not used
    m.variables["L"].default = np.array([2.0])
    r2 = dk.reduce_index(m)
    t2, x2, z2, u2, p2 = reduced_consistent_point(r2, remembered=True)
    assert t2 != kept_t
    xs2 = dict(zip(r2.x_names, x2, strict=True))
    assert xs2["x"] ** 2 + xs2["y"] ** 2 == pytest.approx(4.0, rel=1e-10)


def test_tiny_equilibration_is_the_array_formulation_bit_for_bit():
    rng = np.random.default_rng(11)
    limit = numerics.TINY_EQUILIBRATE
    try:
        for trial in range(1200):
            m, n = int(rng.integers(1, 9)), int(rng.integers(1, 9))
            A = rng.standard_normal((m, n)) * (rng.random((m, n)) < rng.uniform(0.2, 1.0))
            if trial % 3 == 0:  # powers of two: ties of the rounding
                A = np.sign(A) * 2.0 ** rng.integers(-40, 40, A.shape) * (A != 0)
            if trial % 7 == 0:
                A[rng.random(A.shape) < 0.1] = np.inf
            if trial % 11 == 0:
                A[0] = 0.0
            numerics.TINY_EQUILIBRATE = limit
            tiny = numerics.equilibrate(A)
            numerics.TINY_EQUILIBRATE = -1
            array = numerics.equilibrate(A)
            np.testing.assert_array_equal(tiny[0], array[0])
            np.testing.assert_array_equal(tiny[1], array[1])
    finally:
        numerics.TINY_EQUILIBRATE = limit


@pytest.mark.parametrize("kind", ["band", "wide", "dense column"])
def test_sparse_minimum_norm_step_is_the_pseudoinverse_solution(kind):
    """The sparse Gauss--Newton step (normal equations by banded Cholesky where ``J J^T`` has
    a narrow band after reordering, SuperLU where it is wide, the KKT system where a dense
    column fills ``J J^T``) is ``-pinv(J) h``, the least-norm solution of ``J d = -h``, to
    1e-10 relative: checked against NumPy's SVD-based ``lstsq`` on 300 x 500 patterns."""
    import scipy.sparse as sp

    from daekit import points

    rng = np.random.default_rng(3)
    m, n = 300, 500
    rows = np.repeat(np.arange(m), 3)
    if kind == "band":  # each row couples neighbouring unknowns (a chain)
        cols = (np.repeat(np.arange(m), 3) * n // m + np.tile([0, 1, 2], m)) % n
    else:  # scattered: J J^T of a wide band after reordering
        cols = rng.integers(0, n, rows.size)
    J = sp.csc_matrix((rng.normal(size=rows.size), (rows, cols)), shape=(m, n))
    if kind == "dense column":
        J = sp.csc_matrix(sp.hstack([J[:, :-1], sp.csc_matrix(rng.normal(size=(m, 1)))]))
    h = rng.normal(size=m)
    want = -np.linalg.lstsq(J.toarray(), h, rcond=None)[0]
    got = points._min_norm_step(J, h)
    assert np.linalg.norm(got - want) <= 1e-10 * np.linalg.norm(want)
    if kind == "band":
        assert points._band_solver((J @ J.T).tocsc(), 1e-12) is not None


def test_min_norm_step_with_a_dense_column_skips_the_normal_equations():
    # one unknown in every row (a shared parameter-like column) fills J J^T completely: the step
    # comes from the augmented system without forming it, still the pseudoinverse solution
    import scipy.sparse as sp

    from daekit import points

    rng = np.random.default_rng(3)
    m = 400
    rows = np.repeat(np.arange(m), 2)
    cols = np.repeat(np.arange(m), 2) + np.tile([0, 1], m)
    vals = np.tile([3.0, 0.5], m) * rng.uniform(0.8, 1.2, rows.size)  # well conditioned
    J = sp.hstack([sp.csc_matrix((vals, (rows, cols)), shape=(m, m + 1)),
                   sp.csc_matrix(rng.normal(size=(m, 1)))]).tocsc()
    h = rng.normal(size=m)
    d = points._min_norm_step(J, h)
    ref = -np.linalg.pinv(J.toarray()) @ h
    assert np.linalg.norm(d - ref) <= 1e-10 * np.linalg.norm(ref)
