"""Tests of the Lagrangian front end (daekit.mechanics) and its example mechanisms.

References: lecture L3 (the index-1 form of the 3D pendulum), reference-problems.md section 2
(planar pendulum, case B, exact values), Pryce's Sigma-method (index 3 of Lagrangian systems).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit.errors import ModelError
from daekit.examples.mechanisms import (
    lagrangian_delta_robot,
    lagrangian_delta_robot_home,
    lagrangian_pendulum3d,
    lagrangian_planar_chain,
)
from daekit.mechanics import LagrangianSystem, lagrangian
from daekit.reduced import ReducedDAE
from daekit.structure import sigma_method

RNG = np.random.default_rng(12345)


def _fun(r: ReducedDAE, out) -> ca.Function:
    return ca.Function("f", [r.t, r.x, r.z, r.u, r.p], [out])


def _sigma_index(model) -> int:
    inc = model.incidence()
    assert inc.n_equations == inc.n_unknowns
    return sigma_method(inc.n_equations, inc.rows, inc.cols, inc.vals).index


# ----------------------------------------------------------------------------- 3D pendulum
def test_pendulum3d_matches_lecture_L3_residuals_and_solution():
    r = lagrangian_pendulum3d().index1()
    assert r.method == "lagrangian"
    assert r.p_names == ["m", "L", "g"]
    assert r.x_names == ["p[0]", "p[1]", "p[2]", "der(p)[0]", "der(p)[1]", "der(p)[2]"]
    assert r.z_names == ["der(p,2)[0]", "der(p,2)[1]", "der(p,2)[2]", "z"]
    alg = _fun(r, r.alg)
    ode = _fun(r, r.ode)
    jac = _fun(r, ca.jacobian(r.alg, r.z))
    e3 = np.array([0.0, 0.0, 1.0])
    for _ in range(20):
        p, v, u, a = (RNG.standard_normal(3) for _ in range(4))
        z = RNG.standard_normal()
        m, L, g = RNG.uniform(0.5, 2.0, 3)
        x = np.r_[p, v]
        zz = np.r_[a, z]
        pars = np.r_[m, L, g]
        # the lecture: [m I, p; p^T, 0] [v'; z] = [u - m g e3; -v.v]
        A = np.block([[m * np.eye(3), p[:, None]], [p[None, :], np.zeros((1, 1))]])
        b = np.r_[u - m * g * e3, -v @ v]
        res_lecture = A @ zz - b
        res = np.asarray(alg(0.0, x, zz, u, pars)).ravel()
        np.testing.assert_allclose(res, res_lecture, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(np.asarray(ode(0.0, x, zz, u, pars)).ravel(), np.r_[v, a])
        # solved (v', z): the linear system is solved the same way
        K = np.asarray(jac(0.0, x, zz, u, pars))
        np.testing.assert_allclose(K, A, rtol=1e-14, atol=1e-14)
        sol = np.linalg.solve(A, b)
        np.testing.assert_allclose(
            np.asarray(alg(0.0, x, sol, u, pars)).ravel(), 0.0, atol=1e-12
        )


def test_pendulum3d_invariants_are_c_and_dc_dt():
    r = lagrangian_pendulum3d().index1()
    assert r.invariant_names == ["rod", "d/dt rod"]
    inv = _fun(r, r.invariants)
    for _ in range(20):
        p, v, u, a = (RNG.standard_normal(3) for _ in range(4))
        m, L, g = RNG.uniform(0.5, 2.0, 3)
        val = np.asarray(inv(0.0, np.r_[p, v], np.r_[a, 0.3], u, [m, L, g])).ravel()
        np.testing.assert_allclose(val, [(p @ p - L**2) / 2, p @ v], rtol=1e-13, atol=1e-14)
    # the invariant chain: d/dt of "d/dt rod" along x' = ode is the constraint row of alg
    dinv = ca.jtimes(r.invariants[1], r.x, r.ode)
    f = _fun(r, dinv - r.alg[3])
    x = RNG.standard_normal(6)
    zu = RNG.standard_normal(4), RNG.standard_normal(3)
    assert abs(float(f(0.0, x, zu[0], zu[1], [1, 1, 9.81]))) < 1e-13


def test_pendulum3d_model_is_index3_and_names_work():
    sys3 = lagrangian_pendulum3d()
    m = sys3.model()
    assert m.unknown_names == ["p[0]", "p[1]", "p[2]", "z"]
    assert [e.name for e in m.equations] == ["motion", "rod"]
    assert _sigma_index(m) == 3
    a = dk.analyze(m)
    assert (a.index, a.dof) == (3, 4)  # 3 coordinates - 1 constraint, each with its velocity
    r = sys3.index1()
    for name in ("p[0]", "der(p)[2]", "der(p,2)[1]", "z"):
        assert name in r.variables
        assert m.resolve(name)  # the model knows every name of the index-1 form
    # the index-1 form and the model share symbols: variables are the model's own
    assert ca.is_equal(r.variables["der(p)[0]"], m.variables["p"].der(1)[0])
    assert r.model is m and r.lagrangian is sys3
    assert not sys3.is_conservative and sys3.has_constant_mass_matrix


def test_pendulum3d_index1_nonsingular_at_random_points():
    r = lagrangian_pendulum3d().index1()
    jac = _fun(r, ca.jacobian(r.alg, r.z))
    for _ in range(10):
        x = RNG.standard_normal(6)
        K = np.asarray(jac(0.0, x, np.zeros(4), np.zeros(3), [1.0, 1.0, 9.81]))
        assert np.linalg.cond(K) < 1e8


# ----------------------------------------------------------------------------- planar pendulum
def test_planar_pendulum_case_B_exact_solution():
    """reference-problems.md section 2, case B: theta0 = pi/2, g = 9.81, L = 1, at rest."""
    ch = lagrangian_planar_chain(1, mass=1.0, length=1.0, g=9.81)
    m = ch.model()
    assert _sigma_index(m) == 3
    r = ch.index1()
    assert r.x_names == ["q[0]", "q[1]", "der(q)[0]", "der(q)[1]"]
    F = ca.integrator(
        "F", "idas", r.dae_dict(), 0.0, [1.0], {"abstol": 1e-12, "reltol": 1e-12}
    )
    # released at rest from (1, 0): q'' = (0, -g), lam = 0
    out = F(x0=[1.0, 0.0, 0.0, 0.0], z0=[0.0, -9.81, 0.0], p=r.p_values)
    x1 = np.asarray(out["xf"]).ravel()
    exact = [-0.98629175113187531936, -0.16501085312554116875,
             -0.29690551591631582156, 1.7746436411126556265]
    np.testing.assert_allclose(x1, exact, atol=1e-8, rtol=0)
    # the rod force: T = -lam (unit mass and length) equals g (3 y - 2 y0) with y0 = 0
    lam = float(np.asarray(out["zf"]).ravel()[-1])
    assert abs(-lam - 9.81 * 3 * exact[1]) < 1e-7
    inv = np.asarray(_fun(r, r.invariants)(1.0, x1, out["zf"], [], r.p_values)).ravel()
    assert np.max(np.abs(inv)) < 1e-8


def test_planar_chain_structure_and_large_n():
    ch = lagrangian_planar_chain(3)
    assert _sigma_index(ch.model()) == 3
    assert ch.is_conservative and ch.is_separable and ch.has_constant_mass_matrix
    r = ch.index1()
    assert r.z_names[-3:] == ["lam[0]", "lam[1]", "lam[2]"]
    assert r.invariant_names == ["rod[0]", "rod[1]", "rod[2]",
                                 "d/dt rod[0]", "d/dt rod[1]", "d/dt rod[2]"]
    # a chain hanging at rest: rod k carries the weight of the masses below it, z_k = tension/L
    h = lagrangian_planar_chain(3, mass=2.0, length=0.5, g=9.81)
    q = np.array([0.0, -0.5, 0.0, -1.0, 0.0, -1.5])
    a, lam = h.acceleration(0.0, q, np.zeros(6), [], h.p_values)
    np.testing.assert_allclose(np.asarray(a).ravel(), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(lam).ravel(), np.array([3, 2, 1]) * 2.0 * 9.81 / 0.5,
                               rtol=1e-12)
    assert dk.analyze(ch.model()).dof == 6
    big = lagrangian_planar_chain(400)
    rb = big.index1()
    assert (rb.nx, rb.nz) == (1600, 1200)
    # the KKT Jacobian of the index-1 form stays sparse (no dense Hessians)
    assert ca.jacobian_sparsity(rb.alg, rb.z).nnz() < 20 * rb.nz


def test_chain_energy_and_acceleration_functions():
    """Two links: the Functions for structure-exploiting integrators agree with the DAE."""
    ch = lagrangian_planar_chain(2, mass=1.5, length=0.7)
    r = ch.index1()
    q = np.array([0.7, 0.0, 0.7, -0.7])  # consistent: rod 1 horizontal, rod 2 down
    dq = np.array([0.0, 0.5, 0.3, 0.5])  # consistent: rod1 . v1 = 0, rod2 . (v2 - v1) = 0
    inv = np.asarray(_fun(r, r.invariants)(0, np.r_[q, dq], np.zeros(6), [], r.p_values))
    assert np.max(np.abs(inv)) < 1e-14
    a, lam = ch.acceleration(0.0, q, dq, [], r.p_values)
    res = _fun(r, r.alg)(0.0, np.r_[q, dq], ca.vertcat(a, lam), [], r.p_values)
    assert float(ca.norm_inf(res)) < 1e-12
    E = float(ch.energy(q, dq, r.p_values))
    assert abs(E - (0.5 * 1.5 * dq @ dq + 1.5 * 9.81 * (q[1] + q[3]))) < 1e-13
    M = np.asarray(ch.mass_matrix(q, r.p_values))
    np.testing.assert_allclose(M, 1.5 * np.eye(4))
    G = np.asarray(ch.constraint_jacobian(q, r.p_values))
    np.testing.assert_allclose(G, [[0.7, 0, 0, 0], [0, 0.7, 0, -0.7]])


# ----------------------------------------------------------------------------- delta robot
def test_delta_robot_index3_home_consistent_and_nonsingular():
    robot = lagrangian_delta_robot()
    m = robot.model()
    assert _sigma_index(m) == 3
    assert (dk.analyze(m).index, dk.analyze(m).dof) == (3, 6)
    r = robot.index1()
    h = lagrangian_delta_robot_home()
    x = np.r_[h["alpha"], h["p"], h["der(alpha)"], h["der(p)"]]
    z = np.r_[h["der(alpha,2)"], h["der(p,2)"], h["z"]]
    # rods of length L = 0.6 from the elbows p_k = R_z(gamma_k) [r + a cos(al_k), 0, -a sin(al_k)]
    for k, gam in enumerate((0.0, 2 * np.pi / 3, 4 * np.pi / 3)):
        al = h["alpha"][k]
        ell = np.array([np.cos(gam) * (0.2 + 0.3 * np.cos(al)),
                        np.sin(gam) * (0.2 + 0.3 * np.cos(al)), -0.3 * np.sin(al)])
        assert abs(np.linalg.norm(h["p"] - ell) - 0.6) < 1e-12
    # static equilibrium: platform weight m_p g = 0.5 * 9.81 carried by the three rods
    # (vertical components of the rod forces 2 z_k (p_k - p))
    assert h["z"].min() > 0
    res = _fun(r, ca.vertcat(r.alg, r.invariants))(0.0, x, z, h["u"], r.p_values)
    assert float(ca.norm_inf(res)) < 1e-12
    K = np.asarray(_fun(r, ca.jacobian(r.alg, r.z))(0.0, x, z, h["u"], r.p_values))
    assert np.linalg.matrix_rank(K) == 9 and np.linalg.cond(K) < 1e6
    assert robot.check_configuration(np.r_[h["alpha"], h["p"]]) < 1e6


def test_delta_robot_matches_handwritten_cartesian_model():
    """The hand-written first-order model of the lecture (daekit.examples.lecture.delta_robot,
    written independently) has the same residuals at random points."""
    from daekit.examples import lecture

    hand = lecture.delta_robot()
    r = lagrangian_delta_robot().index1()
    V = hand.variables
    omega_d, v_d = V["omega"].der(1), V["v"].der(1)
    hand_syms = ca.vertcat(V["alpha"].sym, V["omega"].sym, V["p"].sym, V["v"].sym,
                           V["alpha"].der(1), V["p"].der(1), omega_d, v_d, V["z"].sym, V["u"].sym)
    hres = ca.Function("h", [hand_syms, hand.parameter_symbols], [hand.residual])
    mine = _fun(r, r.alg)
    pars = r.p_values
    assert list(r.p_names[:6]) == ["r", "a", "L", "m_arm", "m_p", "g"]
    for _ in range(10):
        al, om, p, v, dom, dv, z, u = (RNG.standard_normal(3) for _ in range(8))
        vals = np.r_[al, om, p, v, om, v, dom, dv, z, u]
        F = np.asarray(hres(vals, hand.parameter_values)).ravel()
        ours = np.asarray(mine(0.0, np.r_[al, p, om, v], np.r_[dom, dv, z], u, pars)).ravel()
        # hand: [arm_kinematics(3), platform_kinematics(3), arms(3), platform(3), rods(3)]
        np.testing.assert_allclose(ours[:6], F[6:12], rtol=1e-12, atol=1e-12)


def test_delta_robot_unforced_energy_conservation():
    robot = lagrangian_delta_robot()
    assert robot.has_constant_mass_matrix and not robot.is_conservative
    r = robot.index1()
    h = lagrangian_delta_robot_home()
    x0 = np.r_[h["alpha"], h["p"], np.zeros(6)]
    u0 = np.zeros(3)  # unforced: the motors let go, no friction (b = 0)
    a0, z0 = robot.acceleration(0.0, x0[:6], x0[6:], u0, r.p_values)
    grid = np.linspace(0.05, 0.3, 6)
    F = ca.integrator("F", "idas", r.dae_dict(), 0.0, grid, {"abstol": 1e-11, "reltol": 1e-11})
    out = F(x0=x0, z0=ca.vertcat(a0, z0), p=np.r_[r.p_values, u0])
    X = np.asarray(out["xf"])
    E = [float(robot.energy(X[:6, k], X[6:, k], r.p_values)) for k in range(X.shape[1])]
    E0 = float(robot.energy(x0[:6], x0[6:], r.p_values))
    # it really moves (falls by more than a centimetre and speeds up) ...
    assert abs(X[5, -1] - x0[5]) > 1e-2
    assert float(robot.kinetic_energy(X[:6, -1], X[6:, -1], r.p_values)) > 1e-2
    # ... and T + V stays constant to integrator tolerance
    assert max(abs(e - E0) for e in E) < 1e-8
    inv = _fun(r, r.invariants)
    assert max(float(ca.norm_inf(inv(0, X[:, k], 0, u0, r.p_values))) for k in range(6)) < 1e-8


# ----------------------------------------------------------------------------- flags, helpers
def test_flags_and_functions_of_a_spherical_pendulum():
    """Spherical coordinates: a configuration-dependent mass matrix diag(m L^2, m L^2 sin^2 th)."""
    th, ph = ca.SX.sym("th"), ca.SX.sym("ph")
    dth, dph = ca.SX.sym("dth"), ca.SX.sym("dph")
    T = 0.5 * (dth**2 + ca.sin(th) ** 2 * dph**2)
    sph = lagrangian({"th": th, "ph": ph}, {"th": dth, "ph": dph}, T, V=-9.81 * ca.cos(th))
    assert sph.is_conservative and not sph.has_constant_mass_matrix and not sph.is_separable
    np.testing.assert_allclose(np.asarray(sph.mass_matrix([0.5, 0.1], [])),
                               np.diag([1.0, np.sin(0.5) ** 2]), atol=1e-15)
    # Euler-Lagrange: th'' = sin th cos th ph'^2 - g sin th; ph'' = -2 cot th th' ph'
    a, _ = sph.acceleration(0.0, [0.5, 0.1], [0.3, 0.7], [], [])
    th0, dth0, dph0 = 0.5, 0.3, 0.7
    np.testing.assert_allclose(
        np.asarray(a).ravel(),
        [np.sin(th0) * np.cos(th0) * dph0**2 - 9.81 * np.sin(th0),
         -2 * np.cos(th0) / np.sin(th0) * dth0 * dph0],
        rtol=1e-13,
    )
    # at the pole the mass matrix is singular: named
    with pytest.raises(ModelError, match=r"'ph'"):
        sph.check_configuration([0.0, 0.3])
    r = sph.index1()
    assert r.nz == 2 and r.invariant_names == []


def test_time_dependent_force_without_constraints():
    """x'' + x = cos 2t, x(0) = x'(0) = 0: exact x = (cos t - cos 2t)/3."""
    x, dx, t = ca.SX.sym("x"), ca.SX.sym("dx"), ca.SX.sym("t")
    osc = lagrangian({"x": x}, dx, 0.5 * dx**2, 0.5 * x**2, forces=ca.cos(2 * t), t=t)
    assert not osc.is_conservative and osc.n_constraints == 0
    r = osc.index1()
    assert r.x_names == ["x", "der(x)"] and r.z_names == ["der(x,2)"]
    F = ca.integrator("F", "idas", r.dae_dict(), 0.0, [2.0], {"abstol": 1e-12, "reltol": 1e-12})
    xf = np.asarray(F(x0=[0.0, 0.0], z0=[1.0])["xf"]).ravel()
    np.testing.assert_allclose(xf, [(np.cos(2) - np.cos(4)) / 3, (-np.sin(2) + 2 * np.sin(4)) / 3],
                               atol=1e-9)
    assert _sigma_index(osc.model()) == 0


# ----------------------------------------------------------------------------- bad input
def _pend_syms():
    return ca.SX.sym("x", 2), ca.SX.sym("dx", 2)


def test_error_constraint_depends_on_velocity():
    x, dx = _pend_syms()
    with pytest.raises(ModelError, match=r"constraint 'rod'.*velocity 'der\(q\)\[0\]'"):
        LagrangianSystem(x, dx, 0.5 * ca.dot(dx, dx),
                         constraints={"rod": ca.dot(x, x) - 1 + dx[0]})


def test_error_kinetic_energy_not_quadratic():
    x, dx = _pend_syms()
    with pytest.raises(ModelError, match="not quadratic"):
        LagrangianSystem(x, dx, 0.5 * ca.dot(dx, dx) + dx[1] ** 4)


def test_error_mass_matrix_not_positive_definite():
    x, dx = _pend_syms()
    with pytest.raises(ModelError, match=r"positive definite.*'q\[1\]'"):
        LagrangianSystem(x, dx, 0.5 * dx[0] ** 2)  # no inertia for q[1]
    with pytest.raises(ModelError, match="positive definite"):
        LagrangianSystem(x, dx, 0.5 * (dx[0] ** 2 + dx[1] ** 2) + 2 * dx[0] * dx[1])
    ok = LagrangianSystem(x, dx, 0.5 * (dx[0] ** 2 + x[0] ** 2 * dx[1] ** 2))
    with pytest.raises(ModelError, match=r"'q\[1\]'"):
        ok.check_configuration([0.0, 1.0])


def test_error_mismatched_sizes():
    x, dx = _pend_syms()
    with pytest.raises(ModelError, match="3 velocities for 2 coordinates"):
        LagrangianSystem(x, ca.SX.sym("v", 3), 0.5 * ca.dot(dx, dx))
    with pytest.raises(ModelError, match="generalized forces have 3 elements"):
        LagrangianSystem(x, dx, 0.5 * ca.dot(dx, dx), forces=ca.SX.sym("u", 3),
                         inputs=ca.SX.sym("u2", 3))
    with pytest.raises(ModelError, match="kinetic energy T must be a scalar"):
        LagrangianSystem(x, dx, 0.5 * dx)
    with pytest.raises(ModelError, match="parameter 'm' has 1 symbol"):
        LagrangianSystem(x, dx, 0.5 * ca.dot(dx, dx), parameters={"m": (ca.SX.sym("m"), [1, 2])})
    with pytest.raises(ModelError, match="velocities 'b' have 1 elements"):
        a, b = ca.SX.sym("a"), ca.SX.sym("b", 2)
        LagrangianSystem({"a": a, "b": b}, {"a": ca.SX.sym("da"), "b": ca.SX.sym("db")},
                         0.5 * ca.dot(b, b))


def test_error_undeclared_symbol_and_redundant_constraints():
    x, dx = _pend_syms()
    k = ca.SX.sym("k")
    with pytest.raises(ModelError, match=r"potential energy V uses the symbol 'k'"):
        LagrangianSystem(x, dx, 0.5 * ca.dot(dx, dx), V=k * x[1])
    with pytest.raises(ModelError, match=r"constraint 'c\[1\]' is redundant"):
        LagrangianSystem(x, dx, 0.5 * ca.dot(dx, dx),
                         constraints=ca.vertcat(x[0] - x[1], 2 * x[0] - 2 * x[1]))
    with pytest.raises(ModelError, match="not a symbol"):
        LagrangianSystem(2 * x, dx, 0.5 * ca.dot(dx, dx))
    u = ca.SX.sym("u")
    with pytest.raises(ModelError, match=r"constraint 'c'.*input"):
        LagrangianSystem(x, dx, 0.5 * ca.dot(dx, dx), constraints=x[0] - u, inputs=u)


# ----------------------------------------------------------------------------- stabilization
def test_index1_carries_invariant_chains_like_reduce_index():
    r = lagrangian_pendulum3d().index1()
    assert r.chains == [{"equation": "rod", "row": 3, "invariants": [0, 1], "alg": 3}]
    assert r.alg_names == ["motion[0]", "motion[1]", "motion[2]", "d2/dt2 rod"]
    # Baumgarte with poles (-1, -1) adds c'' + 2 c' + c on the c'' row: 2 p.v + (p.p - L^2)/2
    rb = dk.baumgarte(r, poles=(-1.0, -1.0))
    diff = _fun(r, rb.alg - r.alg)
    for _ in range(3):
        p, v, a, u = (RNG.standard_normal(3) for _ in range(4))
        got = np.asarray(diff(0.0, np.r_[p, v], np.r_[a, 0.2], u, [1.0, 1.3, 9.81])).ravel()
        np.testing.assert_allclose(got, [0, 0, 0, 2 * p @ v + 0.5 * (p @ p - 1.3**2)],
                                   rtol=1e-13, atol=1e-13)
    rg = dk.ggl(r)
    assert rg.z_names[-1] == "mu(rod)" and rg.index == 2
    assert rg.info["ggl_positions"] == ["p[0]", "p[1]", "p[2]"]


def test_baumgarte_and_ggl_on_index1_match_reduce_index():
    """The spherical pendulum (L = 1, g = 9.81, u = 0) from p = (sin a, 0, -cos a), velocity
    1.5 e2, for 20 s: with Baumgarte (simulate(stabilization="baumgarte")) and with GGL, the
    LagrangianSystem index-1 form and reduce_index(pendulum3d()) give the same trajectory;
    |c| stays small, and the exact first integrals (energy |v|^2/2 + g p3 and the vertical
    angular momentum p1 v2 - p2 v1) are conserved."""
    a = 0.6
    p0 = [np.sin(a), 0.0, -np.cos(a)]
    v0 = [0.0, 1.5, 0.0]
    t = np.linspace(0.0, 20.0, 201)
    E0 = 0.5 * 1.5**2 + 9.81 * p0[2]
    Lz0 = p0[0] * v0[1]
    systems = {"lagrangian": (lagrangian_pendulum3d().index1(), "der(p)"),
               # like for like: the KKT form (v' algebraic), as the Lagrangian index-1 form;
               # the minimal form (v' substituted) has its own, equally small, errors
               "reduce_index": (dk.reduce_index(dk.examples.pendulum3d(), eliminate="states"),
                                "v"),
               "minimal": (dk.reduce_index(dk.examples.pendulum3d()), "v")}
    out = {}
    for label, (r, vname) in systems.items():
        fixed = {f"p[{i}]": p0[i] for i in range(3)}
        fixed.update({f"{vname}[{i}]": v0[i] for i in range(3)})
        for stab in ("baumgarte", "ggl"):
            if stab == "baumgarte":
                tr = dk.simulate(r, t, dk.initialize(r, fixed=fixed), stabilization="baumgarte",
                                 rtol=1e-9, atol=1e-9)
            else:
                rg = dk.ggl(r)
                tr = dk.simulate(rg, t, dk.initialize(rg, fixed=fixed), rtol=1e-9, atol=1e-9)
            P = np.stack([tr[f"p[{i}]"] for i in range(3)], axis=1)
            V = np.stack([tr[f"{vname}[{i}]"] for i in range(3)], axis=1)
            c = 0.5 * (np.sum(P**2, axis=1) - 1.0)
            assert np.max(np.abs(c)) < 1e-7, (label, stab)
            assert np.max(np.abs(np.sum(P * V, axis=1))) < 1e-7, (label, stab)
            E = 0.5 * np.sum(V**2, axis=1) + 9.81 * P[:, 2]
            assert np.max(np.abs(E - E0)) < 1e-5, (label, stab)
            assert np.max(np.abs(P[:, 0] * V[:, 1] - P[:, 1] * V[:, 0] - Lz0)) < 1e-5
            out[label, stab] = np.hstack([P, V])
    for stab in ("baumgarte", "ggl"):
        assert np.max(np.abs(out["lagrangian", stab] - out["reduce_index", stab])) < 1e-6
