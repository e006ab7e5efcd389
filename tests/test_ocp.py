"""Optimal control (issue 5): daekit's OCP on index-3 models against independent solutions."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_bvp

import daekit as dk
from daekit.errors import OCPError
from daekit.ocp import OCP, Free
from daekit.ocp.collocation import radau_coefficients
from daekit.ocp.consistency import independent_rows

G, L, T_SWING, TH1 = 9.81, 1.0, 2.0, np.pi / 6


def planar_pendulum_with_force():
    """Cartesian planar pendulum (index 3), unit mass, a tangential force ``u`` on the mass."""
    m = dk.Model("pendulum_force")
    p = m.state("p", 2)
    v = m.state("v", 2)
    z = m.algebraic("z")
    u = m.control("u")
    Lp = m.parameter("L", L)
    g = m.parameter("g", G)
    tangent = ca.vertcat(-p[1], p[0]) / Lp  # unit tangent (cos th, sin th), p = L (sin, -cos)
    m.equation(m.der(p) - v, name="kinematics")
    m.equation(m.der(v) - (u * tangent - ca.vertcat(0, g) - z * p), name="newton")
    m.equation(0.5 * (ca.dot(p, p) - Lp**2), name="rod")
    return m, p, v, u


def swing_ocp(intervals=30, degree=3, controls="polynomial"):
    m, p, v, u = planar_pendulum_with_force()
    ocp = OCP(m, t_final=T_SWING, intervals=intervals, degree=degree, controls=controls)
    ocp.minimize(integral=u**2)
    ocp.initial({"p": [0.0, -L], "v": [0.0, 0.0]})
    ocp.final({"p": [L * np.sin(TH1), -L * np.cos(TH1)], "der(p)": [0.0, 0.0]})
    return ocp


def pontryagin_swing() -> float:
    """min int u^2 for th'' = -(g/L) sin th + u/L (m = 1), th: 0 -> TH1 at rest, by solve_bvp on
    the optimality conditions: u = -lam2/(2L), lam1' = lam2 (g/L) cos th, lam2' = -lam1."""

    def f(t, y):
        th, om, l1, l2, _ = y
        u = -l2 / (2 * L)
        return np.vstack([om, -G / L * np.sin(th) + u / L, l2 * G / L * np.cos(th), -l1, u**2])

    def bc(ya, yb):
        return np.array([ya[0], ya[1], yb[0] - TH1, yb[1], ya[4]])

    t = np.linspace(0, T_SWING, 200)
    y0 = np.vstack([TH1 * t / T_SWING, np.zeros((4, t.size))])
    s = solve_bvp(f, bc, t, y0, tol=1e-10, max_nodes=100000)
    assert s.status == 0
    return float(s.y[4, -1])


def test_index3_pendulum_matches_minimal_coordinates_bvp():
    ref = pontryagin_swing()
    sol = swing_ocp().solve()
    assert sol.success, sol.report
    assert abs(sol.objective - ref) / ref < 1e-5
    # the state stays on the rod's manifold (imposed at t = 0 only) and ends where asked
    # (interior collocation points are accurate to the stage order only)
    assert np.max(np.abs(sol.invariants)) < 1e-4
    assert np.max(np.abs(sol.invariants[-1])) < 1e-7
    assert sol["p"][-1] == pytest.approx([np.sin(TH1), -np.cos(TH1)], abs=1e-6)
    assert sol["v"].shape == (sol.t.size, 2)
    # the full initial/final states (8 conditions) have rank 4 on the 2-dim manifold
    assert sol.boundary.n_conditions == 8 and sol.boundary.rank == 4
    assert "Dropped" in sol.report


def test_warm_start_from_previous_solution():
    ocp = swing_ocp(intervals=20)
    sol = ocp.solve()
    again = ocp.solve(guess=sol)
    assert again.success
    assert again.stats["iter_count"] <= 3
    assert again.objective == pytest.approx(sol.objective, rel=1e-9)


def pendulum3d_periodic(intervals=30):
    m = dk.examples.pendulum3d()
    u = m.variables["u"].sym
    ocp = OCP(m, t_final=2.0, intervals=intervals, degree=3)
    ocp.minimize(integral=ca.sumsqr(u))
    a = np.pi / 6
    ocp.initial({"p": [np.sin(a), 0.0, -np.cos(a)]})
    ocp.periodic(["p", "v"])
    return ocp


def test_periodic_3d_pendulum_redundancy_detected_and_handled():
    ocp = pendulum3d_periodic()
    guess = {"v": [0.0, 1.5, 0.0]}
    ba = ocp.boundary_analysis(guess)
    # naive: 3 initial + 6 periodic conditions, but on the 4-dim manifold only 2 + 4 count
    assert ba.n_conditions == 9 and ba.manifold_dims == (4, 4)
    assert ba.rank == 6
    sv = ba.singular_values
    assert np.sum(sv > 1e-8 * sv[0]) == 6 and sv[6] < 1e-12  # rank deficient: exactly
    sol = ocp.solve(guess=guess)
    assert sol.success, sol.report
    p, v = sol["p"], sol["v"]
    assert np.max(np.abs(p[-1] - p[0])) < 1e-5 and np.max(np.abs(v[-1] - v[0])) < 1e-5
    assert np.max(np.abs(np.sum(p * p, axis=1) - 1.0)) < 1e-5
    assert "Dropped as implied" in sol.report and "periodic" in sol.report


def test_unknown_names_are_reported():
    m, p, v, u = planar_pendulum_with_force()
    ocp = OCP(m, t_final=1.0, intervals=5)
    with pytest.raises(OCPError, match="'q'"):
        ocp.bound("q", 0, 1)
    with pytest.raises(OCPError, match=r"p\[5\]"):
        ocp.initial({"p[5]": 1.0})
    with pytest.raises(OCPError, match="'w'"):
        ocp.constrain(ca.SX.sym("w") ** 2, 0, 1)
    with pytest.raises(OCPError, match="no objective"):
        ocp.solve()
    with pytest.raises(OCPError, match="degree"):
        OCP(m, degree=7)


def test_bound_contradicting_invariant_is_named():
    m, p, v, u = planar_pendulum_with_force()
    ocp = OCP(m, t_final=1.0, intervals=10, degree=2)
    ocp.minimize(integral=u**2)
    ocp.initial({"v": [0.0, 0.0]})
    ocp.bound("p[0]", 0.8, 2.0).bound("p[1]", 0.8, 2.0)  # then p.p >= 1.28 > L^2
    sol = ocp.solve()
    assert not sol.success
    assert "INFEASIBLE" in sol.report and "invariant 'rod'" in sol.report
    assert "p[0] >= 0.8" in sol.report and "p[1] >= 0.8" in sol.report
    with pytest.raises(OCPError, match="rod"):
        ocp.solve(raise_on_failure=True)


def test_infeasible_final_constraint_is_named():
    m, p, v, u = planar_pendulum_with_force()
    ocp = OCP(m, t_final=1.0, intervals=10, degree=2)
    ocp.minimize(integral=u**2)
    ocp.initial({"p": [0.0, -1.0], "v": [0.0, 0.0]})
    ocp.final({"p[0]": 2.0})  # beyond the rod's reach
    sol = ocp.solve()
    assert not sol.success
    assert "final p[0]" in sol.report and "INFEASIBLE at t = T" in sol.report


def test_input_derivatives_become_integrator_chain():
    # L2: x2 = u, x1 = u', z = u''. min int z^2 moving x2 from 0 to 1 at rest in T = 1:
    # the minimum of int u''^2 with u(0)=0, u'(0)=0, u(1)=1, u'(1)=0 is the cubic 3t^2 - 2t^3,
    # int (6 - 12 t)^2 dt = 12.
    m = dk.examples.l2()
    z = m.variables["z"].sym
    ocp = OCP(m, t_final=1.0, intervals=10, degree=3, controls="polynomial")
    ocp.minimize(integral=z**2)
    ocp.initial({"x2": 0.0, "x1": 0.0})
    ocp.final({"x2": 1.0, "x1": 0.0})
    sol = ocp.solve()
    assert sol.success, sol.report
    assert sol.objective == pytest.approx(12.0, rel=1e-8)
    assert "chain" in sol.report
    t = sol.t
    assert sol["u"] == pytest.approx(3 * t**2 - 2 * t**3, abs=1e-8)


def test_free_final_time_double_integrator():
    # min T, |u| <= 1, s: 0 -> 1 at rest: bang-bang, T = 2 exactly (switch at t = 1, a node).
    m = dk.Model("double_integrator")
    s = m.state("s")
    u = m.control("u")
    m.equation(m.der(s, 2) - u, name="newton")
    ocp = OCP(m, t_final=Free(0.5, 5.0, 3.0), intervals=20, degree=2)
    ocp.minimize(final=m.t)
    ocp.bound("u", -1.0, 1.0)
    ocp.initial({"s": 0.0, "der(s)": 0.0})
    ocp.final({"s": 1.0, "der(s)": 0.0})
    sol = ocp.solve()
    assert sol.success, sol.report
    assert sol.T == pytest.approx(2.0, abs=1e-6)
    assert sol.objective == pytest.approx(2.0, abs=1e-6)


def test_radau_coefficients_exact():
    for d in range(1, 6):
        tau, C, b, _ = radau_coefficients(d)
        assert tau[-1] == pytest.approx(1.0)
        # quadrature exact for degree 2d - 2; differentiation exact for degree d
        for k in range(2 * d - 1):
            assert b @ tau[1:] ** k == pytest.approx(1.0 / (k + 1), abs=1e-12)
        for k in range(1, d + 1):
            assert C.T @ tau**k == pytest.approx(k * tau ** (k - 1), abs=1e-10)


def test_independent_rows():
    A = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 2.0]])
    rank, kept, dropped = independent_rows(A)
    assert rank == 3 and len(dropped) == 1
    assert np.linalg.matrix_rank(A[kept]) == 3


def test_examples_solve_and_plot(tmp_path):
    from daekit.examples import ocp_examples as E

    sol = E.crane_ocp(intervals=30).solve()
    assert sol.success, sol.report
    # no faster than the rigid load moved bang-bang: T >= 2 sqrt(D (M + m) / F_max)
    assert sol.T > 2 * np.sqrt(2.0 * 1.5 / 5.0)
    assert np.max(np.abs(sol["F"])) <= 5.0 + 1e-8
    assert sol["x"][-1] == pytest.approx(2.0, abs=1e-6) and sol["y"][-1] == pytest.approx(-1, abs=1e-6)
    E.crane_figure(sol, str(tmp_path / "crane.png"))
    sol = E.delta_robot_ocp(intervals=15).solve()
    assert sol.success, sol.report
    home = dk.examples.delta_robot_home((0.7, 0.1, 0.45))
    assert sol["p"][-1] == pytest.approx(home["p"], abs=1e-6)  # a dropped condition holds
    E.delta_robot_figure(sol, str(tmp_path / "delta.png"))
    assert (tmp_path / "crane.png").stat().st_size > 0 and (tmp_path / "delta.png").exists()
