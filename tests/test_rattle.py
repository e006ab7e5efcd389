"""RATTLE against exact pendulum solutions (reference-problems.md section 2; conical pendulum).

Checks: second order (error ratio ~4 when h halves), constraints |c| and |c'| at rounding level
after *every* step, energy error bounded without drift over 10,000 periods, exact conservation
of angular momentum about the vertical (a quadratic first integral RATTLE preserves).
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from daekit.errors import DaekitError, InitializationError, ModelError, SimulationError
from daekit.simulate.rattle import ConstrainedMechanics, simulate_rattle

# reference-problems.md, section 2, case A: theta0 = pi/6, g = 9.8, L = 1
TH0 = math.pi / 6
G_A = 9.8
X5, Y5 = -0.47657872558204044491, -0.87913179803860933284
VX5, VY5 = -0.44557789585068082516, 0.24154847569592584488
T5 = -8.8723769481601169089  # rod force per unit length (x'' = x T)
PERIOD_A = 2.042030945383572727548968


def planar_pendulum() -> ConstrainedMechanics:
    q = ca.SX.sym("q", 2)
    return ConstrainedMechanics(
        q=q, M=ca.DM.eye(2), V=G_A * q[1], c=0.5 * (ca.dot(q, q) - 1.0),
        q_names=["x", "y"], constraint_names=["rod"], multiplier_names=["lam"],
    )


def pendulum3d(g: float = 9.81, L: float = 1.0) -> ConstrainedMechanics:
    p = ca.SX.sym("p", 3)
    return ConstrainedMechanics(
        q=p, M=ca.DM.eye(3), V=g * p[2], c=0.5 * (ca.dot(p, p) - L**2),
        q_names=[f"p[{i}]" for i in range(3)], v_names=[f"der(p)[{i}]" for i in range(3)],
        constraint_names=["rod"], multiplier_names=["z"],
    )


INIT_A = {"x": math.sin(TH0), "y": -math.cos(TH0), "der(x)": 0.0, "der(y)": 0.0}


def error_at_5(h: float) -> float:
    tr = simulate_rattle(planar_pendulum(), np.linspace(0.0, 5.0, 11), INIT_A, dt=h)
    assert tr.t[-1] == 5.0
    return math.hypot(tr["x"][-1] - X5, tr["y"][-1] - Y5)


def test_planar_second_order_against_exact():
    e1, e2 = error_at_5(0.01), error_at_5(0.005)
    order = math.log2(e1 / e2)
    assert 3.5 <= e1 / e2 <= 4.5, (e1, e2)
    assert 1.8 < order < 2.2
    assert e2 < 1e-4


def test_planar_values_constraints_and_multiplier():
    tr = simulate_rattle(planar_pendulum(), np.linspace(0.0, 5.0, 501), INIT_A, dt=1e-3)
    assert abs(tr["x"][-1] - X5) < 2e-6 and abs(tr["y"][-1] - Y5) < 2e-6
    assert abs(tr["der(x)"][-1] - VX5) < 2e-5 and abs(tr["der(y)"][-1] - VY5) < 2e-5
    # p' = -grad V - G^T lam with G = q^T: x'' = -x lam, so lam = -T
    assert abs(-tr["lam"][-1] - T5) < 1e-3
    # every step: |c| and |c'| at rounding level; also at the output points
    assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10
    assert np.max(np.abs(tr.invariants)) < 1e-10
    assert tr.invariant_names == ["rod", "d/dt rod"]
    assert tr.stats["steps"] == 5000


def test_planar_energy_bounded_over_10000_periods():
    # 10,000 periods at h = 0.05 (408,000 steps) must run in well under 20 s
    n_periods, per = 10_000, 4
    t = np.linspace(0.0, n_periods * PERIOD_A, n_periods * per + 1)
    tr = simulate_rattle(planar_pendulum(), t, INIT_A, dt=0.05)
    assert tr.stats["wall_time"] < 20.0
    E = tr.stats["energy"]
    dE = np.abs(E - E[0])
    first = dE[: 1000 * per].max()
    last = dE[-1000 * per :].max()
    assert 1e-5 < first < 1e-2  # an O(h^2) oscillation, not zero
    assert last <= 2.0 * first, (first, last)
    assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10
    assert tr.stats["energy_error_max"] <= 2.0 * first


def conical(beta: float, g: float = 9.81, L: float = 1.0):
    """Exact conical pendulum: uniform circle at height -L cos(beta), w^2 = g / (L cos beta)."""
    w = math.sqrt(g / (L * math.cos(beta)))
    rho = L * math.sin(beta)

    def p(t):
        return np.array([rho * math.cos(w * t), rho * math.sin(w * t), -L * math.cos(beta)])

    def v(t):
        return np.array([-rho * w * math.sin(w * t), rho * w * math.cos(w * t), 0.0])

    return p, v, w


def test_3d_conical_pendulum_order_constraints_momentum():
    beta = 0.7
    p, v, _ = conical(beta)
    init = {"p": p(0.0), "der(p)": v(0.0)}
    errs = []
    for h in (0.01, 0.005):
        tr = simulate_rattle(pendulum3d(), np.linspace(0.0, 3.0, 31), init, dt=h)
        errs.append(np.max(np.abs(tr["p"][-1] - p(3.0))))
        assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10
        # angular momentum about the vertical: conserved exactly (to rounding) by RATTLE
        P, V = tr["p"], tr["der(p)"]
        Lz = P[:, 0] * V[:, 1] - P[:, 1] * V[:, 0]
        assert np.max(np.abs(Lz - Lz[0])) < 1e-11
        # consistent multiplier z = m (g cos(beta) + |v|^2)/L ... for a circle at rest height:
        # z L^2 = v.v - g p_z  (from c'' = 0)
        vv = np.sum(v(3.0) ** 2)
        assert abs(tr["z"][-1] - (vv + 9.81 * math.cos(beta))) < 1e-3
    assert 3.5 <= errs[0] / errs[1] <= 4.5, errs


def test_3d_pendulum_energy_bounded():
    init = {"p": [1.0, 0.0, 0.0], "der(p)": [0.0, 1.0, 0.0]}
    t = np.linspace(0.0, 400.0, 8001)
    tr = simulate_rattle(pendulum3d(), t, init, dt=0.02)
    dE = np.abs(tr.stats["energy"] - tr.stats["energy"][0])
    k = 1000
    assert dE[-k:].max() <= 2.0 * dE[:k].max()
    assert 1e-4 < dE.max() < 3e-2  # O(h^2) oscillation around E0 = 0.5
    assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10


def test_position_dependent_mass_matrix_polar_pendulum():
    # the same pendulum in polar coordinates (r, th): M = diag(1, r^2), implicit RATTLE
    q = ca.SX.sym("q", 2)
    r, th = q[0], q[1]
    sysm = ConstrainedMechanics(
        q=q, M=ca.diag(ca.vertcat(1, r**2)), V=-G_A * r * ca.cos(th), c=r - 1.0,
        q_names=["r", "th"],
    )
    errs = []
    for h in (0.01, 0.005):
        tr = simulate_rattle(sysm, np.linspace(0.0, 5.0, 6), {"r": 1.0, "th": TH0}, dt=h)
        x, y = math.sin(tr["th"][-1]), -math.cos(tr["th"][-1])
        errs.append(math.hypot(x - X5, y - Y5))
        assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10
    assert 3.5 <= errs[0] / errs[1] <= 4.5, errs


def test_time_dependent_force_and_parameters():
    # a free particle on a circle (no gravity) pushed by a constant tangential... here:
    # F = (0, -g) as an explicit force with g a parameter reproduces case A exactly
    q = ca.SX.sym("q", 2)
    g = ca.SX.sym("g")
    t = ca.SX.sym("t")
    sysm = ConstrainedMechanics(
        q=q, M=ca.DM.eye(2), V=0, c=0.5 * (ca.dot(q, q) - 1.0), force=ca.vertcat(0, -g + 0 * t),
        t=t, p=g, p_values=[1.0], q_names=["x", "y"],
    )
    tr = simulate_rattle(sysm, np.linspace(0.0, 5.0, 6), INIT_A, dt=1e-3, params={"g": G_A})
    assert abs(tr["x"][-1] - X5) < 2e-6 and abs(tr["y"][-1] - Y5) < 2e-6


def test_nonuniform_output_grid():
    t = np.array([0.0, 0.013, 0.5, 0.5003, 2.0, 5.0])
    tr = simulate_rattle(planar_pendulum(), t, INIT_A, dt=1e-3)
    np.testing.assert_array_equal(tr.t, t)
    assert abs(tr["x"][-1] - X5) < 5e-6
    assert tr.stats["max_c"] < 1e-10


def test_bad_input():
    sysm = planar_pendulum()
    with pytest.raises(InitializationError, match="rod"):
        simulate_rattle(sysm, [0.0, 1.0], {"x": 1.0, "y": 0.5})
    with pytest.raises(InitializationError, match="y"):
        simulate_rattle(sysm, [0.0, 1.0], {"x": 1.0})
    with pytest.raises(SimulationError, match="increasing"):
        simulate_rattle(sysm, [1.0, 0.0], INIT_A)
    with pytest.raises(DaekitError, match="inputs"):
        simulate_rattle(sysm, [0.0, 1.0], INIT_A, inputs={"u": lambda t: 0})
    with pytest.raises(ModelError, match="mechanical system"):
        simulate_rattle(object(), [0.0, 1.0], INIT_A)
    q = ca.SX.sym("q", 2)
    v = ca.SX.sym("v", 2)
    with pytest.raises(ModelError, match="velocity"):
        ConstrainedMechanics(q=q, M=ca.DM.eye(2), V=0, c=q[0], force=-v)
    with pytest.raises(ModelError, match="2x2"):
        ConstrainedMechanics(q=q, M=ca.DM.eye(3), V=0, c=q[0])


def test_rank_loss_raises_with_partial_trajectory():
    # a free particle sliding along the cusp curve y^2 = x^3 toward the cusp at the origin,
    # where the constraint Jacobian G = [-3 x^2, 2 y] vanishes (reached at arc length ~1.44)
    q = ca.SX.sym("q", 2)
    sysm = ConstrainedMechanics(q=q, M=ca.DM.eye(2), V=0, c=q[1] ** 2 - q[0] ** 3,
                                q_names=["x", "y"], constraint_names=["cusp"])
    v = -np.array([1.0, 1.5]) / math.hypot(1.0, 1.5)
    init = {"x": 1.0, "y": 1.0, "der(x)": v[0], "der(y)": v[1]}
    with pytest.raises(SimulationError, match="full rank") as info:
        simulate_rattle(sysm, np.linspace(0.0, 3.0, 31), init, dt=0.01)
    err = info.value
    assert 1.0 < err.t < 1.6
    part = err.trajectory
    assert part.t[-1] == pytest.approx(err.t) and part["x"][-1] < 0.3
    assert np.max(np.abs(part.invariants)) < 1e-10


def test_constraint_without_full_rank_at_start():
    q = ca.SX.sym("q", 2)
    sysm = ConstrainedMechanics(q=q, M=ca.DM.eye(2), V=0,
                                c=(ca.dot(q, q) - 1.0) ** 2, constraint_names=["sq"])
    with pytest.raises(InitializationError, match="sq"):
        simulate_rattle(sysm, [0.0, 1.0], [1.0, 0.0, 0.0, 1.0])


# ------------------------------------------------------------------ the Lagrangian front end


def test_lagrangian_chain_and_its_index1_form_against_exact():
    from daekit.examples.mechanisms import lagrangian_planar_chain

    ch = lagrangian_planar_chain(1, g=G_A)  # the planar pendulum of case A
    init = {"q": [math.sin(TH0), -math.cos(TH0)], "der(q)": [0.0, 0.0]}
    for system in (ch, ch.index1()):
        tr = simulate_rattle(system, np.linspace(0.0, 5.0, 11), init, dt=1e-3)
        assert abs(tr["q[0]"][-1] - X5) < 2e-6 and abs(tr["q[1]"][-1] - Y5) < 2e-6
        assert abs(tr["der(q)"][-1, 0] - VX5) < 2e-5
        assert abs(-tr["lam"][-1] - T5) < 1e-3  # lam = -T for m = L = 1
        # the acceleration read off the index-1 formula: x'' = x T
        assert abs(tr["der(q,2)[0]"][-1] - X5 * T5) < 2e-3
        assert tr.invariant_names == ["rod", "d/dt rod"]
        assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10


def test_lagrangian_pendulum3d_with_inputs():
    from daekit.examples.mechanisms import lagrangian_pendulum3d

    beta = 0.5
    p, v, _ = conical(beta, g=9.81)
    sys3 = lagrangian_pendulum3d()
    init = {"p": p(0.0), "der(p)": v(0.0)}
    tr = simulate_rattle(sys3, np.linspace(0.0, 2.0, 21), init, dt=1e-3,
                         inputs={"u": lambda t: [0, 0, 0]})
    assert np.max(np.abs(tr["p"][-1] - p(2.0))) < 1e-4
    # a constant upward force m g cancels gravity: uniform motion on a great circle,
    # |v| constant, z = |v|^2 / L^2
    tr = simulate_rattle(sys3, np.linspace(0.0, 2.0, 21), {"p": [1, 0, 0], "der(p)": [0, 1, 0]},
                         dt=1e-3, inputs={"u": [0.0, 0.0, 9.81]})
    assert np.allclose(tr["p"][-1], [math.cos(2.0), math.sin(2.0), 0.0], atol=1e-5)
    assert np.allclose(tr["z"], 1.0, atol=1e-9)
    tr0 = simulate_rattle(sys3, np.linspace(0.0, 2.0, 21), init, dt=1e-3)  # u not given: 0
    assert np.max(np.abs(tr0["p"][-1] - p(2.0))) < 1e-4
    with pytest.raises(SimulationError, match="not an input"):
        simulate_rattle(sys3, [0.0, 1.0], init, inputs={"w": 0.0})
    with pytest.raises(SimulationError, match="CasADi"):
        simulate_rattle(sys3, [0.0, 1.0], init, inputs={"u": lambda t: [0, 0, float(t)]})


def test_lagrangian_delta_robot_rest_and_fall():
    from daekit.examples.mechanisms import lagrangian_delta_robot, lagrangian_delta_robot_home

    robot = lagrangian_delta_robot()
    home = lagrangian_delta_robot_home()
    # held by the static torques: stays at rest, the rod forces are the static ones
    tr = simulate_rattle(robot, np.linspace(0.0, 1.0, 11), home, inputs={"u": home["u"]},
                         dt=1e-3)
    assert np.max(np.abs(tr["alpha"] - home["alpha"])) < 1e-10
    assert np.max(np.abs(tr["p"] - home["p"])) < 1e-10
    assert np.allclose(tr["z"], home["z"], rtol=1e-8)
    # motors off: the robot falls; constraints hold at every step, energy stays put
    tr = simulate_rattle(robot, np.linspace(0.0, 2.0, 201), home, inputs={"u": 0.0}, dt=1e-3)
    assert tr["p"][-1, 2] < home["p"][2] - 0.1
    assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10
    E = tr.stats["energy"]
    assert np.max(np.abs(E - E[0])) < 1e-2 * (np.max(E) - np.min(E) + abs(E[0]))
    # viscous friction is not conservative: a clear error
    with pytest.raises(ModelError, match="velocities"):
        simulate_rattle(robot, [0.0, 1.0], home, inputs={"u": 0.0}, params={"b": 0.1})


def test_through_simulate_and_initialize():
    from daekit.examples.mechanisms import lagrangian_pendulum3d
    from daekit.initialize import initialize
    from daekit.simulate import simulate

    beta = 0.6
    p, v, _ = conical(beta)
    r = lagrangian_pendulum3d().index1()
    fixed = {f"p[{i}]": p(0.0)[i] for i in range(2)}
    fixed.update({f"der(p)[{i}]": v(0.0)[i] for i in range(2)})
    init = initialize(r, guess={"p": p(0.0), "der(p)": v(0.0)}, fixed=fixed)
    tr = simulate(r, np.linspace(0.0, 2.0, 21), init, method="rattle", dt=1e-3)
    assert np.max(np.abs(tr["p"][-1] - p(2.0))) < 1e-4
    assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10
    for name in ("z", "der(p,2)[0]", "u[0]", "der(p)[2]"):
        assert name in tr


def test_newton_iterations_raised_when_needed():
    # from rest at the horizontal with h = 0.1, one Newton iteration is not enough: the chunk
    # is redone with more, and the constraints still hold to rounding level
    tr = simulate_rattle(planar_pendulum(), np.linspace(0.0, 20.0, 201),
                         {"x": 1.0, "y": 0.0}, dt=0.1, newton_iter=1)
    assert tr.stats["max_c"] < 1e-10 and tr.stats["max_cdot"] < 1e-10
    assert tr.stats["newton_iterations"] > tr.stats["steps"]


def test_rattle_refuses_options_it_would_ignore():
    import daekit as dk

    r = dk.examples.lagrangian_pendulum3d().index1()
    init = dk.initialize(r, fixed={"p": [0.6, 0, -0.8], "der(p)": [0, 1, 0]})
    with pytest.raises(dk.DaekitError, match="takes no stabilization"):
        dk.simulate(r, [0, 1], init, method="rattle", stabilization="projection")
    with pytest.raises(dk.DaekitError, match="unknown option"):
        dk.simulate(r, [0, 1], init, method="rattle", max_num_steps=10)
