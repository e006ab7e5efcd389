"""Issue 8, the benchmark's speed work: the compact dummy-derivative form, the vectorized row
evaluation, lazily evaluated trajectory values, and the batched projection and pivot measure,
each checked against an exact reference (conservation laws, the reduction's own definitions,
NumPy's linear algebra, CasADi's own evaluation)."""

from __future__ import annotations

import pickle

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit.reduction import selection_condition
from daekit.simulate.dummy import compact, compact_values, conditions, full_values
from daekit.simulate.vectorized import RowEvaluator, evaluate_rows, spd_inverse

P0 = [float(np.sin(0.6)), 0.0, float(-np.cos(0.6))]
V0 = [0.0, 1.5, 0.0]
G = 9.81


def _conserved(tr):
    """Energy and vertical angular momentum of the 3D pendulum (m = L = 1): exact invariants
    of the motion."""
    p, v = tr["p"], tr["v"]
    energy = 0.5 * np.sum(v**2, axis=1) + G * p[:, 2]
    lz = p[:, 0] * v[:, 1] - p[:, 1] * v[:, 0]
    return energy, lz


@pytest.fixture(scope="module")
def pendulum3d():
    m = dk.examples.pendulum3d()
    r = dk.reduce_index(m)
    rd = dk.reduce_index(m, method="dummy_derivatives", point={"p": P0, "v": V0})
    fixed = {"p": P0, "v": V0}
    return r, rd, dk.initialize(r, fixed=fixed), dk.initialize(rd, fixed=fixed)


def test_compact_dummy_form_is_the_lecture_size_and_as_exact(pendulum3d, monkeypatch):
    """The 3D pendulum's dummy-derivative system has 12 algebraic unknowns; its compact form
    has 3 (z and the two dummies), integrates in fewer steps than the full form at rtol 1e-8
    (940 against 1180; with the algebraic unknowns in IDAS's error test 1838 against 3354),
    conserves energy at least as well as the plain index-1 form and
    the angular momentum about the vertical to the tolerance's order (exact invariants)."""
    import importlib

    r, rd, init, initd = pendulum3d
    rc = compact(rd)
    assert rd.nz == 12 and rc.nz == 3 and rc.nx == rd.nx == 4
    assert set(rc.z_names) <= set(rd.z_names) and "z" in rc.z_names
    t = np.linspace(0.0, 10.0, 201)
    plain = dk.simulate(r, t, init, rtol=1e-8, atol=1e-8)
    dd = dk.simulate(rd, t, initd, rtol=1e-8, atol=1e-8, stabilization="dummy_derivatives")
    monkeypatch.setattr(importlib.import_module("daekit.simulate.dummy"), "COMPACT_MAX_NZ", 0)
    rfull = dk.reduce_index(dk.examples.pendulum3d(), method="dummy_derivatives",
                            point={"p": P0, "v": V0})
    full = dk.simulate(rfull, t, dk.initialize(rfull, fixed={"p": P0, "v": V0}), rtol=1e-8,
                       atol=1e-8, stabilization="dummy_derivatives")
    assert dd.stats["steps"] <= full.stats["steps"]  # (940 against 1180)
    # with the algebraic unknowns in IDAS's error test the compaction matters more
    dd_all = dk.simulate(rd, t, initd, rtol=1e-8, atol=1e-8, stabilization="dummy_derivatives",
                         suppress_algebraic=False)
    full_all = dk.simulate(rfull, t, dk.initialize(rfull, fixed={"p": P0, "v": V0}),
                           rtol=1e-8, atol=1e-8, stabilization="dummy_derivatives",
                           suppress_algebraic=False)
    assert dd_all.stats["steps"] <= 0.7 * full_all.stats["steps"]  # (1838 against 3354)
    (e_dd, lz_dd), (e_plain, _) = _conserved(dd), _conserved(plain)
    assert np.max(np.abs(e_dd - e_dd[0])) <= np.max(np.abs(e_plain - e_plain[0]))
    assert np.max(np.abs(lz_dd - lz_dd[0])) < 2e-6  # an exact invariant, at rtol 1e-8
    # every name of the model is readable, and the rod holds to rounding
    assert np.max(np.abs(np.sum(dd["p"] ** 2, axis=1) - 1.0)) < 1e-12
    assert np.allclose(dd["der(p)"], dd["v"], atol=1e-12)
    acc = -dd["z"][:, None] * dd["p"] - np.array([0.0, 0.0, G])
    assert np.allclose(dd["der(v)"], acc, atol=1e-9)


def test_compact_values_round_trip_and_the_pivot_measure(pendulum3d):
    """Values carried between the full and the compact system agree, and the batched pivot
    measure on the compact system equals daekit.reduction.selection_condition of the full
    one (its definition) at consistent points."""
    _, rd, _, initd = pendulum3d
    rc = compact(rd)
    t = np.linspace(0.0, 3.0, 40)
    tr = dk.simulate(rd, t, initd, rtol=1e-10, atol=1e-10, stabilization="dummy_derivatives")
    X = np.column_stack([tr[n] for n in rc.x_names])
    Zc = np.column_stack([tr[n] for n in rc.z_names])
    U = np.zeros((t.size, rc.nu))
    got = conditions(rc, t, X, Zc, U, rc.p_values)
    for k in range(0, t.size, 7):
        full, x, zf = full_values(rc, t[k], X[k], Zc[k], U[k], rc.p_values)
        assert full is rd
        assert np.allclose(compact_values(rc, zf), Zc[k], rtol=0, atol=1e-15)
        want = selection_condition(rd, x, zf, U[k], rd.p_values, t[k])
        assert got[k] == pytest.approx(want, rel=1e-9)


def test_row_evaluator_matches_casadi():
    """The NumPy translation of an SX Function gives CasADi's own values, for the operations
    it translates (and refuses MX functions)."""
    x = ca.SX.sym("x", 3)
    p = ca.SX.sym("p")
    e = ca.vertcat(ca.sin(x[0]) * ca.exp(x[1]) / (1 + x[2] ** 2), ca.atan2(x[0], x[1]),
                   ca.fmin(x[0], p) + ca.fabs(x[2]) ** 1.5, ca.if_else(x[0] > 0.2, x[1], -p),
                   ca.sqrt(1 + x[1] ** 2) - ca.tanh(x[2]) + ca.log(2 + ca.cos(x[0])), 4.0)
    F = ca.Function("f", [x, p], [e, ca.jacobian(e, x)])
    rng = np.random.default_rng(3)
    X = rng.normal(size=(300, 3))
    P = rng.normal(size=(300, 1))
    R = RowEvaluator(F)
    assert R.ok
    got = R([X, P])
    for k in (0, 17, 299):
        want = [np.asarray(F(X[k], P[k])[i].nonzeros(), dtype=float) for i in range(2)]
        for i in range(2):
            assert np.allclose(got[i][k], want[i], rtol=1e-14, atol=1e-14)
    # the mapped CasADi path (below the row threshold) agrees
    small = evaluate_rows(F, [X[:5], P[:5]], {})
    assert np.allclose(small[1], got[1][:5], rtol=1e-14, atol=1e-14)
    xm = ca.MX.sym("x")
    assert not RowEvaluator(ca.Function("g", [xm], [2 * xm])).ok


def test_spd_inverse_matches_numpy():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 4, 6))
    M = A @ np.transpose(A, (0, 2, 1))
    assert np.allclose(spd_inverse(M), np.linalg.inv(M), rtol=1e-10, atol=1e-12)


def test_lazy_trajectory_values_equal_the_model_and_pickle(pendulum3d):
    """Variables other than the states are evaluated when first read: they equal the model's
    expressions (der(v) = -z p - g e3), and a pickled trajectory carries them all."""
    r, _, init, _ = pendulum3d
    tr = dk.simulate(r, np.linspace(0.0, 2.0, 300), init, rtol=1e-8, atol=1e-8)
    assert "der(v)[2]" in tr.values and len(tr.values) == len(list(tr.values))
    acc = -tr["z"][:, None] * tr["p"] - np.array([0.0, 0.0, G])
    assert np.allclose(tr["der(v)"], acc, rtol=0, atol=1e-12)
    c = 0.5 * (np.sum(tr["p"] ** 2, axis=1) - 1.0)
    assert np.allclose(tr.invariant("rod"), c, rtol=0, atol=1e-15)
    back = pickle.loads(pickle.dumps(tr))
    assert isinstance(back.values, dict)
    assert np.array_equal(back["der(v)"], tr["der(v)"])
    assert np.array_equal(back.invariants, tr.invariants)


def test_output_projection_is_exact_on_many_rows(pendulum3d):
    """Projected output rows (simplified Gauss--Newton, vectorized) satisfy the invariants
    to rounding on 2001 points, and stay within the integration's accuracy of plain IDAS."""
    r, _, init, _ = pendulum3d
    t = np.linspace(0.0, 10.0, 2001)
    plain = dk.simulate(r, t, init, rtol=1e-8, atol=1e-8)
    proj = dk.simulate(r, t, init, rtol=1e-8, atol=1e-8, stabilization="projection",
                       project_output=True)
    assert proj.stats["output_projected"] and proj.stats["rows_projected"] == t.size
    assert np.max(np.abs(proj.invariants)) < 1e-13
    assert np.max(np.abs(proj["p"] - plain["p"])) < 1e-5


@pytest.mark.parametrize("n", [5, 500])  # few rows (short function) and many: both routes
@pytest.mark.parametrize("symbolic", [True, False])
def test_row_projection_is_the_exact_nearest_point(n, symbolic, circle_system):
    """Rows off the unit circle by up to 1e-6 (x = (1 + e) (cos a, sin a), z = x[0] from
    alg = z - x[0]) projected with unit weights: the nearest point of the circle is x / |x|
    exactly, and z follows; for the generated Gauss--Newton step and the batched NumPy one
    alike. (z is weighted 1e8 times less than x, not free: that leaves 1e-8 of the correction,
    1e-14 here.)"""
    from daekit.simulate.projection import Projector

    P = Projector(circle_system)
    if not symbolic:
        P.SYMBOLIC_STEP_MAX_NH = 0
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 2 * np.pi, n)
    e = rng.uniform(-1e-6, 1e-6, n)
    X = (1 + e)[:, None] * np.column_stack([np.cos(a), np.sin(a)])
    Z = X[:, :1] + rng.uniform(-1e-6, 1e-6, (n, 1))
    Xp, Zp = P.project_rows(np.zeros(n), X, Z, np.zeros((n, 0)), np.zeros(0))
    exact = X / np.linalg.norm(X, axis=1, keepdims=True)
    assert np.max(np.abs(Xp - exact)) < 1e-13
    assert np.max(np.abs(Zp[:, 0] - exact[:, 0])) < 1e-13
    assert np.max(np.abs(Xp - X)) > 1e-7  # (it did move them)
    assert P._symbolic is symbolic


@pytest.mark.parametrize("u", ["constant", "varying"])
def test_compact_pickling_carries_the_inputs(pendulum3d, u):
    """Inside compact_pickling (an ensemble's workers) a trajectory travels as its state arrays;
    constant inputs as one row. Unpickled, every column equals the sender's bit for bit, and
    der(v) is the model's -z p - g e3 + u (unit mass) with the inputs sent."""
    from daekit.simulate.trajectory import compact_pickling

    r, _, init, _ = pendulum3d
    force = ca.DM([0.3, 0.0, 0.0]) if u == "constant" else \
        ca.vertcat(0.3 * ca.sin(r.t), 0.0, 0.1 * r.t)
    tr = dk.simulate(r, np.linspace(0.0, 1.0, 50), init, inputs={"u": force}, rtol=1e-8,
                     atol=1e-8)
    with compact_pickling():
        back = pickle.loads(pickle.dumps(tr))
    for name in ("p", "v", "z", "u", "der(v)"):
        assert np.array_equal(back[name], tr[name]), name
    acc = -tr["z"][:, None] * tr["p"] - np.array([0.0, 0.0, G]) + back["u"]
    assert np.allclose(back["der(v)"], acc, rtol=0, atol=1e-12)
