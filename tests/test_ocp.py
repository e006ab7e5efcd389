"""Optimal control (issue 5): daekit's OCP on index-3 models against independent solutions."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit.errors import OCPError
from daekit.examples.ocp_examples import (
    CARTPOLE,
    betts_pendulum_ocp,
    pendulum_with_tangential_force,
    swing_optimum_minimal_coordinates,
)
from daekit.examples.ocp_examples import cartpole_ocp as cartpole_ocp_example
from daekit.ocp import OCP, Free
from daekit.ocp.collocation import radau_coefficients
from daekit.ocp.consistency import independent_rows

G, L, T_SWING, TH1 = 9.81, 1.0, 2.0, np.pi / 6


def planar_pendulum_with_force():
    """Cartesian planar pendulum (index 3), unit mass, a tangential force ``u`` on the mass."""
    m = pendulum_with_tangential_force(L=L, g=G)
    v = m.variables
    return m, v["p"].sym, v["v"].sym, v["u"].sym


def swing_ocp(intervals=30, degree=3, controls="polynomial"):
    m, p, v, u = planar_pendulum_with_force()
    ocp = OCP(m, t_final=T_SWING, intervals=intervals, degree=degree, controls=controls)
    ocp.minimize(integral=u**2)
    ocp.initial({"p": [0.0, -L], "v": [0.0, 0.0]})
    ocp.final({"p": [L * np.sin(TH1), -L * np.cos(TH1)], "der(p)": [0.0, 0.0]})
    return ocp


def pontryagin_swing() -> float:
    """min int u^2 in the angle coordinate, by solve_bvp (independent of daekit's OCP)."""
    return swing_optimum_minimal_coordinates(TH1, T_SWING, L=L, g=G)


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


# ---------------------------------------------------------------------------- multiple shooting
def swing_both(intervals):
    out = {}
    for method in ("collocation", "shooting"):
        ocp = swing_ocp(intervals=intervals, controls="constant")
        ocp.method = method
        out[method] = ocp.solve()
        assert out[method].success, out[method].report
    return out["collocation"], out["shooting"]


@pytest.mark.slow
def test_shooting_agrees_with_collocation():
    """Both optimize over the same piecewise constant controls on the same N intervals, so the
    control discretization's error against the continuous optimum (measured 8e-3 relative at
    N = 20, 2e-3 at N = 40: O(h^2)) is common to both and cancels. What separates them is how
    the dynamics are integrated: IDAS to 1e-10 for shooting, Radau IIA degree 3 (order 5 at the
    interval ends) for collocation. The difference must therefore be far below 1e-4 and shrink
    like h^5 (measured 4.3e-6 and 1.3e-7: ratio 34)."""
    ref = pontryagin_swing()
    c20, s20 = swing_both(20)
    c40, s40 = swing_both(40)
    d20 = abs(c20.objective - s20.objective) / s20.objective
    d40 = abs(c40.objective - s40.objective) / s40.objective
    assert d20 < 1e-5 and d40 < 1e-6
    assert d20 / d40 > 16  # order >= 4 (measured ~32: order 5)
    # the control discretization's own error is much larger and common to both
    assert abs(s20.objective - ref) / ref > 100 * d20
    assert abs(s40.objective - ref) < abs(s20.objective - ref)
    # the shooting grid: the interval boundaries; the end state as asked; invariants hold
    assert s20.t == pytest.approx(np.linspace(0, T_SWING, 21))
    assert s20["p"][-1] == pytest.approx([np.sin(TH1), -np.cos(TH1)], abs=1e-8)
    assert np.max(np.abs(s20.invariants)) < 1e-8  # integrated to 1e-10, not to the stage order
    assert "multiple shooting on IDAS" in s20.report and "Dropped" in s20.report
    assert s20.stats["method"] == "shooting" and s20.stats["boundary_rank"] == 4
    # controls: one value per interval, the same as the collocation's to the truncation error
    assert s20.controls["u"][1:] == pytest.approx(c20.controls["u"][3::3], abs=1e-4)
    # finer output by simulating with the optimal controls: continuous at the nodes
    fine = s20.simulate(points_per_interval=4)
    assert fine.t.size == 81 and fine.stats["node_mismatch"] < 1e-8
    assert fine["p"][::4] == pytest.approx(s20["p"], abs=1e-8)
    # for collocation the same re-simulation estimates its discretization error
    assert 1e-9 < c20.simulate(2).stats["node_mismatch"] < 1e-5


@pytest.mark.slow
def test_shooting_crane_minimum_time_matches_collocation():
    from daekit.examples import ocp_examples as E

    col = E.crane_ocp(intervals=30).solve()
    sh = E.crane_ocp(intervals=30, method="shooting").solve()  # cold start: own simulation
    assert col.success and sh.success, sh.report
    # required: within 1 %; the shared control space makes it far closer (measured 7e-9)
    assert abs(sh.T - col.T) / col.T < 1e-4
    assert np.max(np.abs(sh["F"])) <= 5.0 + 1e-7  # IPOPT relaxes bounds by 1e-8 relative
    assert sh["x"][-1] == pytest.approx(2.0, abs=1e-7) and sh["y"][-1] == pytest.approx(-1, abs=1e-7)
    assert sh.boundary.rank == 8 and sh.boundary.n_conditions == 12


def test_shooting_rejects_polynomial_controls():
    m, p, v, u = planar_pendulum_with_force()
    with pytest.raises(OCPError, match="piecewise constant"):
        OCP(m, method="shooting", controls="polynomial")
    with pytest.raises(OCPError, match="'collocation' or 'shooting'"):
        OCP(m, method="pseudospectral")


# ---------------------------------------------------------------------------- initial guesses
def _swing_simulation(n=101):
    m, p, v, u = planar_pendulum_with_force()
    r = dk.reduce_index(m)
    init = dk.initialize(r, guess={"p": [0, -L], "v": [0, 0]}, fixed={"p[0]": 0.0, "v[0]": 0.0})
    # a feedforward of the user's choice (it does not reach the target: only a guess)
    return dk.simulate(r, np.linspace(0, T_SWING, n), init,
                       inputs={"u": lambda t: 1.5 * np.sin(np.pi * t / T_SWING) - 0.5})


@pytest.mark.parametrize(
    "method", ["collocation", pytest.param("shooting", marks=pytest.mark.slow)]
)
def test_guess_from_simulation(method):
    traj = _swing_simulation()
    ocp = swing_ocp(intervals=20, controls="constant")
    ocp.method = method
    # the NLP starts at the simulation interpolated onto its grid (IPOPT stopped at once)
    ocp.solver_options["max_iter"] = 0
    start = ocp.solve(guess=traj)
    for name in ("p", "v", "z"):
        expect = np.column_stack([np.interp(start.t, traj.t, c)
                                  for c in np.atleast_2d(traj[name].T)])
        assert start[name].reshape(expect.shape) == pytest.approx(expect, abs=1e-12)
    if method == "shooting":  # one control per interval: the simulated one at its end
        tk = np.linspace(0, T_SWING, 21)[1:]
        expect = np.interp(tk, traj.t, traj["u"])
        assert start.controls["u"][1:] == pytest.approx(expect, abs=1e-12)
    del ocp.solver_options["max_iter"]
    sol = ocp.solve(guess=traj)
    cold = ocp.solve()
    assert sol.success, sol.report
    assert sol.objective == pytest.approx(cold.objective, rel=1e-8)
    assert "interpolated from a simulation" in sol.report


@pytest.mark.slow
def test_guess_from_other_solution_and_free_final_time_from_trajectory():
    # a collocation solution starts a shooting solve (interpolated by names): fewer iterations
    ocp = swing_ocp(intervals=20, controls="constant")
    col = ocp.solve()
    sh_ocp = swing_ocp(intervals=20, controls="constant")
    sh_ocp.method = "shooting"
    cold = sh_ocp.solve()
    warm = sh_ocp.solve(guess=col)
    assert warm.success and warm.objective == pytest.approx(cold.objective, rel=1e-8)
    assert warm.stats["iter_count"] < cold.stats["iter_count"]
    assert "previous solution (collocation)" in warm.report
    # a free final time takes the trajectory's horizon as its guess
    m = dk.Model("double_integrator")
    s = m.state("s")
    u = m.control("u")
    m.equation(m.der(s, 2) - u, name="newton")
    traj = dk.Trajectory(np.linspace(0, 2.5, 6), {"s": np.linspace(0, 1, 6),
                                                  "der(s)": np.full(6, 0.4), "u": np.zeros(6)})
    ocp = OCP(m, t_final=Free(0.5, 5.0, 4.0), intervals=10, degree=2,
              solver_options={"max_iter": 0})
    ocp.minimize(final=m.t).bound("u", -1, 1)
    ocp.initial({"s": 0.0, "der(s)": 0.0}).final({"s": 1.0, "der(s)": 0.0})
    assert ocp.solve(guess=traj).T == pytest.approx(2.5)
    with pytest.raises(OCPError, match="Trajectory"):
        ocp.solve(guess=[1, 2, 3])


# ---------------------------------------------------------------------------- free parameters
@pytest.mark.parametrize("method", ["collocation", "shooting"])
def test_free_parameter_gives_the_exact_pendulum_period(method):
    """Which gravity g makes the pendulum (L = 1) released at rest from 60 degrees swing to -60
    degrees, at rest, in exactly 1 s, with no force? Half the period 4 K(k^2) sqrt(L/g),
    k = sin(30 deg): g = L (2 K(1/4) / 1 s)^2 = 11.3672... (the small-angle formula would say
    pi^2 = 9.87). The OCP: minimize int u^2 with g free; the optimum is u = 0 and that g."""
    from scipy.special import ellipk

    th0, tf = np.pi / 3, 1.0
    g_exact = L * (2 * ellipk(np.sin(th0 / 2) ** 2) / tf) ** 2
    m, p, v, u = planar_pendulum_with_force()
    ocp = OCP(m, t_final=tf, intervals=20, degree=3, method=method)
    ocp.minimize(integral=u**2)
    ocp.free_parameter("g", 5.0, 20.0, guess=9.81)
    ocp.initial({"p": [np.sin(th0), -np.cos(th0)], "v": [0.0, 0.0]})
    ocp.final({"p[0]": -np.sin(th0), "der(p)[0]": 0.0})
    sol = ocp.solve()
    assert sol.success, sol.report
    assert sol.parameters["g"] == pytest.approx(g_exact, rel=1e-6)
    assert sol.objective < 1e-10 and np.max(np.abs(sol["u"])) < 1e-5
    assert sol.parameters["L"] == L  # fixed ones stay


# ---------------------------------------------------------------------------- stats, report, output
@pytest.mark.parametrize(
    "method", ["collocation", pytest.param("shooting", marks=pytest.mark.slow)]
)
def test_solve_prints_nothing_and_reports(method, capfd):
    m, p, v, u = planar_pendulum_with_force()
    ocp = OCP(m, t_final=1.0, intervals=10, degree=2, method=method)
    ocp.minimize(integral=u**2).bound("u", -1, 1)
    ocp.initial({"p": [0.0, -1.0], "v": [0.0, 0.0]})
    ocp.final({"p[0]": 0.9})  # out of reach with |u| <= 1 in 1 s: IPOPT fails
    bad = ocp.solve()
    ocp._bc_user.pop()
    ocp.final({"p[0]": 0.1})
    good = ocp.solve()
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    assert not bad.success and "did not succeed" in bad.report
    assert good.success
    st = good.stats
    for key in ("iter_count", "return_status", "t_solve", "t_build", "t_total", "n_variables",
                "n_constraints", "method", "transcription", "intervals", "guess",
                "max_constraint_violation", "boundary_rank", "max_invariant_t0"):
        assert key in st, key
    assert st["max_constraint_violation"] < 1e-8 and st["max_invariant_t0"] < 1e-8
    assert st["method"] == method and st["intervals"] == 10
    name = {"collocation": "Radau IIA collocation", "shooting": "multiple shooting on IDAS"}
    assert "Solve_Succeeded" in good.report and name[method] in good.report
    assert bad.status not in ("Solve_Succeeded", "Infeasible_Boundary_Conditions")  # IPOPT ran


def test_shooting_path_constraint_against_analytic_optimum():
    """min int u^2, s'' = u, s: 0 -> 1 at rest in T = 1, with the speed limit s' <= V (a path
    constraint, imposed at the shooting nodes). For 1 < V < 1.5 the optimum accelerates with
    u linear to 0 on [0, t1], cruises at s' = V, and brakes symmetrically: t1 = 3 (V - 1)/(2 V),
    J = 16 V^3 / (9 (V - 1)) (15.36 for V = 1.2; 12 without the limit). Piecewise constant
    controls approximate the linear arcs to O(h^2) in the objective."""
    V = 1.2
    J_exact = 16 * V**3 / (9 * (V - 1))
    errs = []
    for N in (20, 40):
        m = dk.Model("double_integrator")
        s = m.state("s")
        u = m.control("u")
        m.equation(m.der(s, 2) - u, name="newton")
        ocp = OCP(m, t_final=1.0, intervals=N, method="shooting")
        ocp.minimize(integral=u**2).constrain(m.der(s), -np.inf, V, name="speed limit")
        ocp.initial({"s": 0, "der(s)": 0}).final({"s": 1, "der(s)": 0})
        sol = ocp.solve()
        assert sol.success, sol.report
        errs.append((sol.objective - J_exact) / J_exact)
        assert np.max(sol["der(s)"]) <= V + 1e-7
        # s' is piecewise linear between the nodes: the limit holds in between as well
        assert np.max(sol.simulate(5)["der(s)"]) <= V + 1e-7
    assert 0 < errs[1] < errs[0] < 1.5e-2 and errs[0] / errs[1] > 3.5  # second order


def test_shooting_on_an_ode_uses_cvodes_and_matches_riccati():
    """x' = -x + u, min int_0^1 x^2 + u^2 dt, x(0) = 1 (an index-0 ReducedDAE without algebraic
    unknowns: shooting integrates with CVODES). The continuous optimum is P(0) x0^2 with the
    Riccati equation P' = 2 P + P^2 - 1, P(1) = 0; piecewise constant controls on 40 intervals
    are within O(h^2) of it."""
    from scipy.integrate import solve_ivp

    from daekit.reduced import ReducedDAE

    t, x, u = ca.SX.sym("t"), ca.SX.sym("x"), ca.SX.sym("u")
    r = ReducedDAE(t, x, ca.SX(0, 1), u, ca.SX(0, 1), -x + u, ca.SX(0, 1), ca.SX(0, 1), [],
                   ["x"], [], ["u"], [], np.zeros(0), {"x": x, "u": u, "der(x)": -x + u})
    P0 = solve_ivp(lambda s, P: 2 * P + P**2 - 1, (1.0, 0.0), [0.0], rtol=1e-12,
                   atol=1e-12).y[0, -1]
    ocp = OCP(r, t_final=1.0, intervals=40, method="shooting")
    ocp.minimize(integral=x**2 + u**2).initial({"x": 1.0})
    sol = ocp.solve()
    assert sol.success, sol.report
    assert "CVODES" in sol.report
    assert sol.objective == pytest.approx(P0, rel=1e-3) and sol.objective > P0


# ---------------------------------------------------------------- 3D pendulum: rest to rest
TH0 = float(np.arcsin(0.6))  # p(0) = (0.6, 0, -0.8) = (sin th, 0, -cos th)


def pendulum3d_rest_to_rest():
    """The user guide's example: from rest at p = (0.6, 0, -0.8) to rest with p[0] = -0.6."""
    m = dk.examples.pendulum3d()
    u = m.variables["u"].sym
    ocp = OCP(m, t_final=2.0, intervals=30, degree=3)
    ocp.minimize(integral=ca.sumsqr(u))
    ocp.initial({"p": [0.6, 0.0, -0.8], "v": [0.0, 0.0, 0.0]})
    ocp.final({"p[0]": -0.6, "v": [0.0, 0.0, 0.0]})
    return ocp


def angle_reference(N=30, T=2.0, sub=6, d=3, thT=-TH0):
    """The same problem in the plane of the motion, in the angle ``th`` (p = (sin, 0, -cos)):
    ``th'' = u . (cos th, sin th) - g sin th`` with the same control (a constant vector
    (u0, u2) on each of the N intervals, cost ``sum h |u_k|^2``), the ODE collocated by hand
    (Radau, degree d) on ``sub`` subintervals per control interval. The motion stays in the
    plane (tested): u[1] = 0 and the out-of-plane states stay zero."""
    tau = np.append(0.0, ca.collocation_points(d, "radau"))
    C = np.zeros((d + 1, d + 1))
    for j in range(d + 1):
        ell = np.poly1d([1.0])
        for r in range(d + 1):
            if r != j:
                ell *= np.poly1d([1.0, -tau[r]]) / (tau[j] - tau[r])
        C[j] = np.polyder(ell)(tau)
    opti = ca.Opti()
    U = opti.variable(2, N)
    M = N * sub
    hf = T / M
    Y = opti.variable(2, M * d + 1)  # (th, th') at every collocation point
    opti.subject_to(Y[:, 0] == ca.DM([TH0, 0.0]))
    for k in range(M):
        u = U[:, k // sub]
        Ys = [Y[:, k * d + j] for j in range(d + 1)]
        for j in range(1, d + 1):
            th, om = Ys[j][0], Ys[j][1]
            f = ca.vertcat(om, u[0] * ca.cos(th) + u[1] * ca.sin(th) - G * ca.sin(th))
            opti.subject_to(sum(C[r, j] * Ys[r] for r in range(d + 1)) == hf * f)
    opti.subject_to(Y[:, -1] == ca.DM([thT, 0.0]))
    opti.minimize(T / N * ca.sumsqr(U))
    tt = np.linspace(0.0, T, M * d + 1)
    opti.set_initial(Y[0, :], TH0 * np.cos(np.pi * tt / T))
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})
    return float(opti.solve().value(opti.f))


def test_pendulum3d_rest_to_rest_imposes_every_user_condition():
    ocp = pendulum3d_rest_to_rest()
    sol = ocp.solve()
    assert sol.success, sol.report
    # the guess simulation (a free swing, u = 0) ran over the whole horizon
    # the free swing (u = 0) misses the final conditions: the guess blends along the manifold
    assert "a path along the invariant manifold" in sol.stats["guess"]
    ba = sol.boundary
    # on the 4-dim manifold: 4 independent initial conditions of 6, 3 final of 4 (v = 0 is 2
    # conditions where p.v = 0; p[0] the third)
    assert (ba.n_conditions, ba.rank, ba.manifold_dims) == (10, 7, (4, 4))
    kept = [ba.labels[i] for i in ba.kept]
    assert "final p[0]" in kept and sum(lab.startswith("final v") for lab in kept) == 2
    dropped = [ba.labels[i] for i in ba.dropped]
    assert dropped == ["initial p[2]", "initial v[2]", "final v[2]"]  # preference order
    p, v = sol["p"], sol["v"]
    assert np.max(np.abs(p[0] - [0.6, 0.0, -0.8])) < 1e-9
    assert np.max(np.abs(v[0])) < 1e-9
    assert abs(p[-1, 0] + 0.6) < 1e-9 and np.max(np.abs(v[-1, :2])) < 1e-9
    assert abs(v[-1, 2]) < 1e-6  # the truly redundant one: implied by p.v = 0 at T
    assert p[-1, 2] == pytest.approx(-0.8, abs=1e-6)  # the lower branch, the cheap one
    # planar motion: the minimal-coordinate (angle) problem is the same problem
    assert np.max(np.abs(p[:, 1])) < 1e-9 and np.max(np.abs(sol["u"][:, 1])) < 1e-9
    ref = angle_reference()
    assert sol.objective == pytest.approx(ref, rel=1e-5)  # measured: 7.7e-8 relative
    assert "WARNING" not in sol.report and "Re-solved" not in sol.report


def test_guess_simulation_runs_the_whole_free_swing():
    """The guess simulation (u = 0) against the exact pendulum motion (Jacobi elliptic):
    sin(th/2) = k sn(K - sqrt(g/L) t, k), k = sin(th0/2)."""
    from scipy.special import ellipj, ellipk

    from daekit.ocp.guess import make_guess

    ocp = pendulum3d_rest_to_rest()
    ocp._bc_user = [c for c in ocp._bc_user if c[0] == "initial"]  # no final: the simulation
    prob = ocp.compile()
    g = make_guess(prob, None)
    assert g.note == "simulation with the guessed controls"
    t = np.linspace(0.0, 2.0, 7)
    X = g.fun(t)[0]
    k = np.sin(TH0 / 2)
    sn = ellipj(ellipk(k**2) - np.sqrt(G) * t, k**2)[0]
    th = 2 * np.arcsin(k * sn)
    # the guess is interpolated linearly between collocation points: O(h^2) ~ 1e-3
    assert np.max(np.abs(X[0] - np.sin(th))) < 3e-3
    assert np.max(np.abs(X[2] + np.cos(th))) < 3e-3
    exact_T = make_guess(prob, None).fun(np.array([2.0]))[0][:, 0]
    assert exact_T[0] == pytest.approx(np.sin(th[-1]), abs=1e-4)  # a node: IDAS accuracy


def _wrong_branch_guess(ocp):
    r = dk.reduce_index(ocp.model)
    init = dk.initialize(r, guess={"p": [0.6, 0, 0.8], "v": [0, 0, 0]},
                         fixed={"p[0]": 0.6, "p[1]": 0.0, "v[0]": 0.0, "v[1]": 0.0})
    return dk.simulate(r, np.linspace(0, 2, 101), init, inputs={"u": lambda t: [0, 0, G]})


def test_branch_selecting_condition_is_kept_as_an_inequality():
    """initial p[0] = 0.6, p[1] = 0 on the sphere leave p[2] = -0.8 or +0.8: initial p[2] is
    implied only near its own branch. It is not dropped but kept as the inequality
    |p[2] + 0.8| <= 0.8 (half the distance to the other branch), inactive at the solution.
    From a guess on the other branch IPOPT is trapped by it (infeasible); solve() then runs
    once more without it, and the re-solve imposes initial p[2]: the result is on the
    intended branch and the report says all of it (from that guess IPOPT finds a costlier
    local optimum there, measured 136.1 against 15.46: a swing the long way round)."""
    ocp = pendulum3d_rest_to_rest()
    sol = ocp.solve()
    assert sol.success and sol.stats["boundary_selectors"] == ["initial p[2]"]
    assert sol.stats["boundary_selectors_imposed"] and "kept as inequalities" in sol.report
    wrong = ocp.solve(guess=_wrong_branch_guess(ocp))
    assert wrong.success, wrong.report
    assert "First run with the branch inequalities" in wrong.report
    assert wrong.stats["resolved"]["forced"] == ["initial p[2]"]
    assert wrong["p"][0] == pytest.approx([0.6, 0.0, -0.8], abs=1e-6)
    assert abs(wrong["p"][-1, 0] + 0.6) < 1e-6 and np.max(np.abs(wrong["v"][-1])) < 1e-5
    assert wrong.objective >= sol.objective - 1e-6  # the default guess finds the cheaper one


def test_violated_dropped_condition_is_imposed_on_a_second_solve(monkeypatch):
    """Without the branch inequalities (run.SELECTORS_AS_INEQUALITIES off), a guess on the
    other branch of the rod (p[2] = +0.8 at t = 0) ends on the wrong branch with initial p[2]
    dropped; solve() then imposes it and re-solves from that solution."""
    from daekit.ocp import run

    monkeypatch.setattr(run, "SELECTORS_AS_INEQUALITIES", False)
    ocp = pendulum3d_rest_to_rest()
    r = dk.reduce_index(ocp.model)
    init = dk.initialize(r, guess={"p": [0.6, 0, 0.8], "v": [0, 0, 0]},
                         fixed={"p[0]": 0.6, "p[1]": 0.0, "v[0]": 0.0, "v[1]": 0.0})
    wrong = dk.simulate(r, np.linspace(0, 2, 101), init, inputs={"u": lambda t: [0, 0, G]})
    assert wrong["p"][0, 2] == pytest.approx(0.8)
    sol = ocp.solve(guess=wrong)
    assert sol.success, sol.report
    assert "Re-solved from that solution imposing initial p[2]" in sol.report
    assert sol.stats["resolved"]["forced"] == ["initial p[2]"]
    p, v = sol["p"], sol["v"]
    assert np.max(np.abs(p[0] - [0.6, 0.0, -0.8])) < 1e-6 and np.max(np.abs(v[0])) < 1e-6
    assert abs(p[-1, 0] + 0.6) < 1e-6 and np.max(np.abs(v[-1])) < 1e-5


def test_independent_rows_prefers_and_forces():
    A = np.array([[1.0, 0.0], [2.0, 0.0], [0.0, 1.0]])
    assert independent_rows(A) == (2, [0, 2], [1])  # order given
    assert independent_rows(A, preference=[1, 0, 2]) == (2, [1, 2], [0])
    assert independent_rows(A, forced=[1]) == (2, [1, 2], [0])
    # a row at least 10 times smaller than the largest is not chosen for preference alone
    B = np.array([[1e-3, 1e-3], [1.0, 0.0], [0.0, 1.0]])
    assert independent_rows(B) == (2, [1, 2], [0])
    # a row dependent at another point is passed over when an alternative exists
    C1 = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    C2 = np.array([[1.0, 0.0], [2.0, 0.0], [1.0, 1.0]])
    assert independent_rows(C1, others=[C2]) == (2, [0, 2], [1])


def test_failed_guess_simulation_falls_back_to_a_consistent_final_point(monkeypatch):
    """Should the guess simulation fail, the rest of the guess runs straight to the nearest
    point that satisfies the invariants and the final conditions (not a state held constant)."""
    from daekit.ocp import guess as guess_mod

    real = guess_mod._GuessSimulator.interval

    def failing(self, x, z, w, tk, h):
        if tk > 0.25:
            raise RuntimeError("IDA_CONV_FAIL (simulated)")
        return real(self, x, z, w, tk, h)

    def whole_fails(self, *args):  # the one-call integration fails too: the interval loop runs
        raise RuntimeError("IDA_CONV_FAIL (simulated)")

    monkeypatch.setattr(guess_mod._GuessSimulator, "interval", failing)
    monkeypatch.setattr(guess_mod._GuessSimulator, "horizon", whole_fails)
    ocp = pendulum3d_rest_to_rest()
    g = guess_mod.make_guess(ocp.compile(), None)
    assert "failed at t = 0.2667" in g.note and "consistent final point" in g.note
    xT = g.fun(np.array([2.0]))[0][:, 0]
    assert np.max(np.abs(xT - [-0.6, 0.0, -0.8, 0.0, 0.0, 0.0])) < 1e-8
    sol = ocp.solve()
    assert sol.success and "straight line" in sol.report
    assert sol.objective == pytest.approx(15.4575249, rel=1e-6)  # angle_reference(), measured


# ---------------------------------------------------------------------------- integral objective
def _double_integrator():
    m = dk.Model("cart")
    s = m.state("s")
    u = m.control("u")
    m.equation(m.der(s, 2) - u, name="newton")
    return m, s, u


def _exact_tracking(T=2.0, N=40, rho=1e-3, npts=12):
    """Exact discrete optimum of min int (s - sin 3t)^2 + rho u^2 dt, s'' = u, s(0) = s'(0) = 0,
    over piecewise constant u on N intervals: s is linear in the controls (quadratic in t on
    each interval), so this is a linear least-squares problem; the integral by Gauss-Legendre
    with npts points per interval (exact for the polynomial part, 1e-16 for the sine)."""
    h = T / N
    xg, wg = np.polynomial.legendre.leggauss(npts)
    tau, w = 0.5 * h * (xg + 1), 0.5 * h * wg
    rows, rhs = [], []
    Sk, Vk = np.zeros(N), np.zeros(N)  # s and s' at the interval's start, linear in u
    for k in range(N):
        ek = np.eye(N)[k]
        for tj, wj in zip(tau, w, strict=True):
            rows.append(np.sqrt(wj) * (Sk + Vk * tj + ek * tj**2 / 2))
            rhs.append(np.sqrt(wj) * np.sin(3 * (k * h + tj)))
        rows.append(np.sqrt(rho * h) * ek)
        rhs.append(0.0)
        Sk, Vk = Sk + Vk * h + ek * h**2 / 2, Vk + ek * h
    A, b = np.array(rows), np.array(rhs)
    u = np.linalg.lstsq(A, b, rcond=None)[0]
    return float(np.sum((A @ u - b) ** 2))


@pytest.mark.parametrize("method", ["collocation", "shooting"])
def test_time_dependent_integrand_exact_discrete_optimum(method):
    """min int_0^2 (u - t)^2 dt over piecewise constant u, N = 20: the optimum is the interval
    mean of t, and the objective is T h^2 / 12 exactly (the variance of t on each interval).
    The integrand varies where the states do not; without error control on the quadrature
    (quad_err_con) IDAS integrated it with the states' coarse steps: 0.0026429 (+59 %)."""
    m, s, u = _double_integrator()
    T, N = 2.0, 20
    ocp = OCP(m, t_final=T, intervals=N, method=method)
    ocp.minimize(integral=(u - m.t) ** 2).initial({"s": 0, "der(s)": 0})
    sol = ocp.solve()
    h = T / N
    assert sol.success
    assert sol.objective == pytest.approx(T * h**2 / 12, rel=1e-5)  # 0.0016667
    k = np.ceil(sol.t[1:] / h - 1e-9) - 1  # the interval a grid time ends (left-continuous)
    assert sol.controls["u"][1:] == pytest.approx(h * (k + 0.5), abs=1e-5)


@pytest.mark.parametrize(
    "method", ["collocation", pytest.param("shooting", marks=pytest.mark.slow)]
)
def test_state_dependent_integrand_matches_exact_discrete_optimum(method):
    """Tracking min int (s - sin 3t)^2 + 1e-3 u^2 dt, N = 40, against the exact optimum over
    the same piecewise constant controls (linear least squares: 0.1306913696). Measured:
    collocation 0.1306914, shooting 0.1306914 (0.1307262 without quad_err_con)."""
    m, s, u = _double_integrator()
    ocp = OCP(m, t_final=2.0, intervals=40, method=method)
    ocp.minimize(integral=(s - ca.sin(3 * m.t)) ** 2 + 1e-3 * u**2)
    ocp.initial({"s": 0, "der(s)": 0})
    sol = ocp.solve()
    ref = _exact_tracking()
    assert ref == pytest.approx(0.1306914, abs=1e-7)
    assert sol.success
    assert sol.objective == pytest.approx(ref, rel=2e-6)


def test_shooting_integrator_controls_the_quadrature_error():
    from daekit.ocp.shooting import DEFAULT_INTEGRATOR_OPTIONS

    assert DEFAULT_INTEGRATOR_OPTIONS["quad_err_con"] is True


# ---------------------------------------------------------------------------- contradictions
def test_contradictory_boundary_conditions_are_named_not_dropped():
    """s(0) = 0, s(T) = 1 and s(T) = s(0) cannot hold together: the least-squares point leaves
    1/3 on each; the report names all three, nothing is dropped, IPOPT is not run."""
    m, s, u = _double_integrator()
    ocp = OCP(m, t_final=1.0, intervals=10)
    ocp.minimize(integral=u**2)
    ocp.initial({"s": 0}).final({"s": 1}).periodic(["s"])
    ba = ocp.boundary_analysis()
    assert [ba.labels[i] for i in ba.conflict] == ["initial s", "final s", "periodic s"]
    assert ba.conflict_alone and ba.dropped == []
    # least squares on the equations scaled to unit gradients (periodic s: (sT - s0)/sqrt 2)
    assert ba.residual == pytest.approx(1 / (2 * np.sqrt(2)), rel=1e-6)
    assert np.all(np.abs(ba.conflict_residuals) > 0.2) and ba.proven
    sol = ocp.solve()
    assert not sol.success and sol.status == "Contradictory_Boundary_Conditions"
    assert sol.stats["iter_count"] == 0
    assert ("the boundary conditions initial s, final s, periodic s contradict each other"
            in sol.report)
    assert "Dropped" not in sol.report and "branch" not in sol.report
    with pytest.raises(OCPError, match="initial s, final s, periodic s contradict"):
        ocp.solve(raise_on_failure=True)
    # the same conditions minus any one of them are consistent and solve
    ocp._bc_user.pop()
    assert ocp.boundary_analysis().conflict == []
    assert ocp.solve().success


def test_design_snippet_contradiction_is_blamed_on_p0_not_on_the_rod():
    """design.md's OCP snippet: initial p = (1, 0, 0) is on the rod, but final p[0] = 0
    contradicts periodic p[0] with initial p[0] = 1."""
    m = dk.examples.pendulum3d()
    p, u = m.variables["p"].sym, m.variables["u"].sym
    ocp = dk.OCP(m, t_final=3.0, intervals=60, degree=3)
    ocp.minimize(integral=ca.sumsqr(u), final=None)
    ocp.bound("z", -1.0, 15.0)
    ocp.constrain(ca.dot(p, p), 0.0, 4.0)
    ocp.initial({"p": [1, 0, 0], "der(p)": [0, 1, 0]})
    ocp.final({"p[0]": 0.0, "der(p)[0]": 0.0})
    ocp.periodic(["p", "der(p)"])
    sol = ocp.solve()
    assert not sol.success and sol.status == "Contradictory_Boundary_Conditions"
    assert [sol.boundary.labels[i] for i in sol.boundary.conflict] == [
        "initial p[0]", "final p[0]", "periodic p[0]"]
    assert ("the boundary conditions initial p[0], final p[0], periodic p[0] contradict each "
            "other" in sol.report)
    assert "rod" not in sol.report.split("CONTRADICTORY", 1)[1]
    assert "INFEASIBLE" not in sol.report and "Dropped" not in sol.report
    with pytest.raises(OCPError, match=r"final p\[0\], periodic p\[0\]"):
        ocp.solve(raise_on_failure=True)


def test_condition_contradicting_the_invariants_alone_is_not_vetoed_but_named():
    # final p[0] = 2 is beyond the unit rod's reach: nonlinear, so not a proof; IPOPT runs
    # (and fails), and the report names the condition and the model's equations by name
    m, p, v, u = planar_pendulum_with_force()
    ocp = OCP(m, t_final=1.0, intervals=10, degree=2, solver_options={"max_iter": 60})
    ocp.minimize(integral=u**2)
    ocp.initial({"p": [0.0, -1.0], "v": [0.0, 0.0]}).final({"p[0]": 2.0})
    sol = ocp.solve()
    assert not sol.success and sol.status != "Contradictory_Boundary_Conditions"
    assert sol.stats["iter_count"] > 0
    assert "WARNING: near the guess, the boundary conditions final p[0]" in sol.report
    assert "invariant 'rod'" in sol.report and "not a proof" in sol.report
    assert "algebraic equation" not in sol.report and "alg[" not in sol.report


# ---------------------------------------------------------------- issue 9: hard classics
betts_pendulum = betts_pendulum_ocp


def test_default_guess_starts_at_the_exact_consistent_point():
    """Betts 10.103 with only its two independent initial values (x = 1, der(y) = 0): the
    default guess starts at the one consistent point, x = 1, y = 0 (the unit circle),
    der(x) = 0 (the velocity invariant x der(x) + y der(y) = 0), der(y) = 0, to roundoff (a
    projection; the former least-squares start stopped at y = -5.7e-5)."""
    from daekit.ocp.guess import make_guess

    prob = betts_pendulum_ocp(initial_all=False).compile()
    X, _, _ = make_guess(prob, None).fun(np.array([0.0]))
    got = dict(zip(prob.aug.x_names, X[:, 0], strict=True))
    exact = {"x": 1.0, "y": 0.0, "der(x)": 0.0, "der(y)": 0.0}
    assert max(abs(got[k] - v) for k, v in exact.items()) <= 1e-12


@pytest.mark.parametrize("final_all", [True, False])
@pytest.mark.parametrize("asymmetry", [0.0, 1e-19, -1e-19])
def test_consistent_final_point_from_exactly_hanging(final_all, asymmetry):
    """The cart-pole's consistent final point from the exactly hanging state (where the zero
    control simulation ends) is the upright state at rest, s = 0, p = (0, L), lam = -m g / (2 L)
    (tip equation at rest), whatever the roundoff-level asymmetry of p[0]: a Gauss-Newton
    projection from the hanging state has no gradient towards either side there (before: no
    consistent point from the exact symmetric state, residual 1)."""
    from daekit.examples.ocp_examples import CARTPOLE, cartpole_ocp
    from daekit.ocp.guess import consistent_end

    prob = cartpole_ocp(final_all).compile()
    a = prob.aug
    L, m, g = CARTPOLE["L"], CARTPOLE["m"], CARTPOLE["g"]
    hanging = dict.fromkeys(a.x_names, 0.0) | {"p[1]": -L, "p[0]": asymmetry}
    xe, ze, ok = consistent_end(prob, np.array([hanging[n] for n in a.x_names]), np.zeros(a.nz),
                                np.zeros(a.nw), prob.p_guess(), CARTPOLE["T"])
    assert ok
    upright = dict.fromkeys(a.x_names, 0.0) | {"p[1]": L}
    assert np.max(np.abs(xe - [upright[n] for n in a.x_names])) <= 1e-12
    assert ze[0] == pytest.approx(-m * g / (2 * L), abs=1e-12)


@pytest.mark.parametrize("initial_all", [True, False])
def test_betts_pendulum_from_the_index3_model(initial_all):
    sol = betts_pendulum(initial_all).solve()
    assert sol.success, sol.report
    assert sol.objective == pytest.approx(12.8738889, abs=1e-4)  # independent angle form
    assert sol["y"][-1] == pytest.approx(-1.0, abs=1e-6)  # hanging at the end
    assert "IPOPT: Solve_Succeeded" in sol.report


def test_poor_least_squares_start_is_not_a_veto(monkeypatch):
    """A least-squares projection from a poor start is no proof of infeasibility.

    (1) A guess ending at x = y = 0: the Gauss-Newton projection onto final x = 0 and the rod
    stalls there (the rod's gradient vanishes at the pivot), leaving a residual of 1, yet the
    conditions are consistent: nothing is proven, IPOPT runs. (2) From the free swing (u = 0,
    the guess of the issue, which ends far from final x = 0) IPOPT runs and succeeds."""
    from daekit.ocp import guess as guess_mod

    ocp = betts_pendulum()
    t = np.linspace(0, 3, 31)
    zero = np.zeros(31)
    poor = dk.Trajectory(t, {"x": 1 - t / 3, "y": zero, "der(x)": zero, "der(y)": zero,
                             "lam": zero, "u": zero})
    ba = ocp.boundary_analysis(poor)
    assert ba.residual > 0.5 and not ba.proven and ba.conflict == []
    ocp.solver_options["max_iter"] = 3
    sol = ocp.solve(guess=poor)
    assert sol.stats["iter_count"] == 3 and sol.status == "Maximum_Iterations_Exceeded"
    assert "could not all be met together with the invariants near the guess" in sol.report
    assert "IPOPT is run all the same" in sol.report
    del ocp.solver_options["max_iter"]
    monkeypatch.setattr(guess_mod, "_final_miss", lambda *a: 0.0)  # keep the free swing
    sol = ocp.solve()
    assert sol.stats["guess"] == "simulation with the guessed controls"
    assert sol.success and sol.stats["iter_count"] > 0
    assert sol.objective == pytest.approx(12.8738889, abs=1e-4)


@pytest.mark.parametrize("k", [1e4, 1e8])
def test_badly_scaled_algebraic_equation_solves(k):
    m = dk.Model("scaled")
    x, z, u = m.state("x"), m.algebraic("z"), m.control("u")
    m.equation(m.der(x) - z, name="ode")
    m.equation(z + k * x - u, name="alg")
    ocp = OCP(m, t_final=1.0, intervals=20)
    ocp.minimize(integral=u**2 + x**2).initial({"x": 1})
    sol = ocp.solve()
    assert sol.success, sol.report
    assert sol["x"][0] == pytest.approx(1.0, abs=1e-9)
    # x' = -k x + u: the optimum is about 1/(2k) (Riccati); Radau's stiff decay misses the
    # initial layer between the collocation points, so the discrete one is smaller, not larger
    assert 0 <= sol.objective < 1 / k
    assert "CONTRADICTORY" not in sol.report and "INFEASIBLE" not in sol.report


def test_nan_boundary_value_raises_at_once():
    m, s, u = _double_integrator()
    ocp = OCP(m, t_final=1.0, intervals=5)
    with pytest.raises(OCPError, match="finite"):
        ocp.initial({"s": float("nan")})


CP = CARTPOLE


def cartpole_ocp(full: bool):
    return cartpole_ocp_example(final_all=full)


def cartpole_minimal_coordinates() -> float:
    """The same problem in (s, th) (th = 0 hanging), Radau IIA degree 3 on the same N
    intervals with piecewise constant F, written by hand in casadi.Opti."""
    M, mp, L, g, T, N, d = CP["M"], CP["m"], CP["L"], CP["g"], CP["T"], CP["N"], 3
    tau, C, b, _ = radau_coefficients(d)
    q = ca.SX.sym("q", 4)
    Fs = ca.SX.sym("F")
    th, ds, dth = q[1], q[2], q[3]
    Mm = ca.vertcat(ca.horzcat(M + mp, mp * L * ca.cos(th)),
                    ca.horzcat(mp * L * ca.cos(th), mp * L**2))
    rhs = ca.vertcat(Fs + mp * L * ca.sin(th) * dth**2, -mp * g * L * ca.sin(th))
    acc = ca.solve(Mm, rhs)
    f = ca.Function("f", [q, Fs], [ca.vertcat(ds, dth, acc)])
    opti = ca.Opti()
    X = opti.variable(4, N * d + 1)
    U = opti.variable(1, N)
    h = T / N
    J = 0
    for k in range(N):
        for j in range(1, d + 1):
            xp = sum(float(C[r_, j]) * X[:, k * d + r_] for r_ in range(d + 1))
            opti.subject_to(xp == h * f(X[:, k * d + j], U[k]))
            J = J + h * float(b[j - 1]) * U[k] ** 2
    opti.subject_to(X[:, 0] == ca.DM([0, 0, 0, 0]))
    opti.subject_to(X[:, -1] == ca.DM([0, np.pi, 0, 0]))
    tt = np.linspace(0, 1, N * d + 1)
    opti.set_initial(X[1, :], np.pi * tt)
    opti.minimize(J)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})
    return float(opti.solve().value(J))


@pytest.mark.slow
@pytest.mark.parametrize("full", [False, True])
def test_cartpole_swing_up_from_the_default_guess(full):
    sol = cartpole_ocp(full).solve()
    assert sol.success, sol.report
    L = CP["L"]
    assert sol["p"][-1] == pytest.approx([0.0, L], abs=1e-5)
    assert sol["s"][-1] == pytest.approx(0.0, abs=1e-8)
    ref = cartpole_minimal_coordinates()
    assert abs(sol.objective - ref) < 1e-4, (sol.objective, ref)
    assert "algebraic equation" not in sol.report


def _structured_problems():
    yield betts_pendulum_ocp()  # polynomial controls, bounds, redundant initial values
    m = pendulum_with_tangential_force(L=1.0, g=9.81)  # constant controls
    u = m.variables["u"].sym
    p = m.variables["p"].sym
    ocp = OCP(m, t_final=2.0, intervals=12, degree=2)
    ocp.minimize(integral=u**2 + p[0] ** 2, final=ca.sumsqr(m.der(p)))
    ocp.constrain(u * p[1], -3.0, 3.0, name="power")  # a path constraint
    ocp.initial({"p": [0.0, -1.0], "v": [0.0, 0.0]})
    ocp.final({"p": [np.sin(0.5), -np.cos(0.5)]})
    yield ocp
    m, s, u = _double_integrator()  # an ODE (no algebraic unknowns), integrand in t
    yield OCP(m, t_final=2.0, intervals=10).minimize(integral=(u - m.t) ** 2 * s).initial(
        {"s": 1, "der(s)": 0})


@pytest.mark.parametrize("case", [0, 1, 2])
def test_closed_form_collocation_derivatives_match_casadi_ad(case):
    """The collocation's constraint Jacobian, Lagrangian Hessian and objective gradient in
    closed form (per-point model derivatives scattered into place,
    daekit.ocp.collocation.STRUCTURED) equal CasADi's AD of the same NLP at random points and
    multipliers."""
    from daekit.ocp.boundary import analyze
    from daekit.ocp.collocation import transcribe
    from daekit.ocp.guess import make_guess

    ocp = list(_structured_problems())[case]
    prob = ocp.compile()
    g = make_guess(prob, None)
    ba = analyze(prob, g)
    tr = transcribe(prob, g.fun, g.T, g.p, kept=ba.kept, selectors=ba.selectors, pins=ba.pins)
    assert tr.derivatives is not None
    V, G, J = tr.builder.V(), tr.builder.G(), tr.J
    lf, lg = ca.MX.sym("lf"), ca.MX.sym("lg", G.numel())
    jac_ad = ca.Function("j", [V], [ca.jacobian(G, V)])
    hess_ad = ca.Function("h", [V, lf, lg], [ca.triu(ca.hessian(lf * J + ca.dot(lg, G), V)[0])])
    grad_ad = ca.Function("gf", [V], [J, ca.gradient(J, V)])
    assert tr.derivatives["grad_f"].sparsity_out(1).is_dense()  # IPOPT reads it as dense
    rng = np.random.default_rng(1)
    for _ in range(2):
        v = rng.standard_normal(V.numel())
        lam = rng.standard_normal(G.numel())
        g_cf, J_cf = tr.derivatives["jac_g"](v, [])
        H_cf = tr.derivatives["hess_lag"](v, [], 0.7, lam)
        f_cf, gf_cf = tr.derivatives["grad_f"](v, [])
        J_ref, H_ref = jac_ad(v), hess_ad(v, 0.7, lam)
        f_ad, gf_ref = grad_ad(v)
        g_ad = ca.Function("g", [V], [G])(v)
        assert np.allclose(np.asarray(g_cf).ravel(), np.asarray(g_ad).ravel())
        assert abs(float(f_cf) - float(f_ad)) <= 1e-12 * max(1.0, abs(float(f_ad)))
        for A, R in ((J_cf, J_ref), (H_cf, H_ref), (gf_cf, gf_ref)):
            A, R = np.asarray(ca.densify(A)), np.asarray(ca.densify(R))
            assert np.max(np.abs(A - R)) <= 1e-10 * max(1.0, np.max(np.abs(R)))


@pytest.mark.parametrize("as_residuals", [False, True])
def test_quadratic_composite_derivatives_match_casadi_ad(as_residuals):
    """The blend's closed-form derivatives (f quadratic in (V, Q), g linear in Q, Q a model
    mapped over points: daekit.ocp.derivatives.quadratic_composite) equal CasADi's AD of the
    composed NLP at random points and multipliers; also with f given as |r|^2 + c (the
    constant Hessian from the residuals' Jacobian)."""
    from daekit.ocp.derivatives import quadratic_composite

    rng = np.random.default_rng(2)
    K, ny = 4, 2
    y = ca.SX.sym("y", ny)
    t = ca.SX.sym("t")
    q = ca.vertcat(ca.sin(y[0]) * y[1] + t, y[0] ** 2 + y[1] ** 3, ca.exp(0.3 * y[1]))
    V = ca.MX.sym("V", K * ny)
    Q = ca.MX.sym("Q", 3, K)
    A, Bm = rng.standard_normal((5, K * ny)), rng.standard_normal((5, 3 * K))
    r = ca.mtimes(A, V) + ca.mtimes(Bm, ca.vec(Q)) - 1
    c = ca.sum2(Q[2, :]) + 0.5 * V[1]
    f = ca.sumsqr(r) + c
    g = ca.vec(Q[:2, 1:])
    pts = np.arange(K * ny).reshape(K, ny)
    ts = ca.DM(np.linspace(0, 1, K)).T
    f_r, g_r, opts = quadratic_composite(V, Q, f, g, q, y, [t, y], (ts, ca.reshape(V, ny, K)),
                                         pts, residuals=(r, c) if as_residuals else None)
    assert opts["grad_f"].sparsity_out(1).is_dense()  # IPOPT reads it as dense
    lf, lg = ca.MX.sym("lf"), ca.MX.sym("lg", g.numel())
    ref = ca.Function("ref", [V, lf, lg], [ca.gradient(f_r, V), ca.jacobian(g_r, V),
                                           ca.triu(ca.hessian(lf * f_r + ca.dot(lg, g_r), V)[0])])
    for _ in range(3):
        v, lam = rng.standard_normal(K * ny), rng.standard_normal(g.numel())
        gr, jg, H = ref(v, 0.8, lam)
        cf = (opts["grad_f"](v, [])[1], opts["jac_g"](v, [])[1],
              opts["hess_lag"](v, [], 0.8, lam))
        for A_, R_ in zip(cf, (gr, jg, H), strict=True):
            A_, R_ = np.asarray(ca.densify(A_)), np.asarray(ca.densify(R_))
            assert np.max(np.abs(A_ - R_)) <= 1e-10 * max(1.0, np.max(np.abs(R_)))
