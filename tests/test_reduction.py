"""Index reduction: reduce_index (Pryce scheme), dummy derivatives, Baumgarte, GGL.

Numbers are checked against exact solutions (reference-problems.md sections 1, 2, 5) and
hand-derived formulas, never against the code's own earlier output.
"""

from __future__ import annotations

import warnings

import casadi as ca
import numpy as np
import pytest

import daekit as dk
import daekit.examples as ex
from daekit.errors import ReductionError, StructuralError
from daekit.model import Model
from daekit.reduction import (
    BaumgarteStiffnessWarning,
    baumgarte,
    check_index1,
    ggl,
    map_values,
    reduce_index,
    reselect,
    selection_condition,
    time_derivative,
)

EXAMPLES = {
    "pendulum3d": ex.pendulum3d,
    "pendulum_planar": ex.pendulum_planar,
    "l1": ex.l1,
    "l2": ex.l2,
    "l5": ex.l5,
    "l6": ex.l6,
    "chained_pendula_2": lambda: ex.chained_pendula(2),
    "chained_pendula_3": lambda: ex.chained_pendula(3),
    "planar_chain_5": lambda: ex.planar_chain(5),
    "delta_robot": ex.delta_robot,
    "arevalo": ex.arevalo,
    "jay": ex.jay,
    "brenan": ex.brenan,
    "chemakzo": ex.chemakzo,
    "transistor_amplifier": ex.transistor_amplifier,
}

# reference-problems.md section 2, case B (theta0 = pi/2, g = 9.81, L = 1)
CASE_B = {
    1.0: (-0.98629175113187531936, -0.16501085312554116875),
    10.0: (0.27508746257611686005, -0.96141920509912506427),
}


def _values(r, vals: dict[str, float]):
    """Arrays x, z of r from a dict of original names (missing names -> 0)."""
    x = np.array([vals.get(n, 0.0) for n in r.x_names], dtype=float)
    z = np.array([vals.get(n, 0.0) for n in r.z_names], dtype=float)
    return x, z


def _integrate(r, x0, z0, grid, u_expr=None, **opts):
    """Plain CasADi IDAS on r.dae_dict(); inputs substituted by expressions of t."""
    dae = r.dae_dict()
    if r.nu:
        assert u_expr is not None
        for key in ("ode", "alg"):
            dae[key] = ca.substitute(dae[key], r.u, u_expr)
        dae["p"] = r.p
    o = {"abstol": 1e-12, "reltol": 1e-12, "max_num_steps": 100000}
    o.update(opts)
    F = ca.integrator("F", "idas", dae, grid[0], list(grid[1:]), o)
    res = F(x0=x0, z0=z0, p=r.p_values)
    return np.asarray(res["xf"]), np.asarray(res["zf"])


# ------------------------------------------------------------------ structure of the result
@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_every_example_reduces_to_index1(name):
    m = EXAMPLES[name]()
    r = reduce_index(m)
    assert r.info["index1_check"] == "passed"
    assert r.nz == r.alg.numel() and r.nx == r.ode.numel()
    # the variable map covers every element of the original model
    for n in m.unknown_names:
        assert n in r.variables
    assert len(r.x_names) == r.nx and len(r.z_names) == r.nz and len(r.u_names) == r.nu
    # DOF: states minus invariants equals Pryce's DOF (sum d - sum c)
    c, d = r.offsets["c"], r.offsets["d"]
    assert r.nx - len(r.invariant_names) == int(d.sum() - c.sum())
    # dummy derivatives: square and index 1 as well, with x = DOF states
    rd = reduce_index(m, method="dummy_derivatives")
    assert rd.info["index1_check"] == "passed"
    assert rd.nx == int(d.sum() - c.sum())


def _pendulum3d_invariant_check(r, with_der_p: bool):
    """rod = (p.p - L^2)/2 and d/dt rod = p.v at random points (reference-problems L3)."""
    f = ca.Function("inv", [r.x, r.z, r.u, r.p], [r.invariants])
    rng = np.random.default_rng(1)
    L = float(r.p_values[r.p_names.index("L")])
    ir, idr = r.invariant_names.index("rod"), r.invariant_names.index("d/dt rod")
    for _ in range(5):
        p, v = rng.standard_normal(3), rng.standard_normal(3)
        vals = {f"p[{i}]": p[i] for i in range(3)}
        vals.update({f"v[{i}]": v[i] for i in range(3)})
        if with_der_p:
            vals.update({f"der(p)[{i}]": v[i] for i in range(3)})  # on the kinematics invariant
        x, z = _values(r, vals)
        inv = np.asarray(f(x, z, rng.standard_normal(r.nu), r.p_values)).ravel()
        assert inv[ir] == pytest.approx(0.5 * (p @ p - L**2), rel=1e-13, abs=1e-13)
        assert inv[idr] == pytest.approx(p @ v, rel=1e-13, abs=1e-13)
        others = [k for k in range(len(inv)) if k not in (ir, idr)]
        assert np.allclose(inv[others], 0.0)


def test_pendulum3d_plain_pryce_scheme():
    """eliminate=False: Pryce's scheme as it is, d_p = 2: p, der(p), v are states and the
    kinematics p' = v stays as three invariants."""
    r = reduce_index(ex.pendulum3d(), eliminate=False)
    assert (r.nx, r.nz) == (9, 7)
    assert r.invariant_names == [
        "kinematics[0]", "kinematics[1]", "kinematics[2]", "rod", "d/dt rod",
    ]
    assert sorted(r.z_names) == sorted(
        ["der(p,2)[0]", "der(p,2)[1]", "der(p,2)[2]", "der(v)[0]", "der(v)[1]", "der(v)[2]", "z"]
    )
    _pendulum3d_invariant_check(r, with_der_p=True)


def test_pendulum3d_states_eliminated_kkt_form():
    """eliminate="states": der(p) = v is eliminated; the KKT index-1 form (L3): states
    (p, v), algebraic (v', z), invariants rod and d/dt rod only."""
    r = reduce_index(ex.pendulum3d(), eliminate="states")
    assert r.info["index1_check"] == "passed"
    assert r.x_names == ["p[0]", "p[1]", "p[2]", "v[0]", "v[1]", "v[2]"]
    assert r.z_names == ["der(v)[0]", "der(v)[1]", "der(v)[2]", "z"]
    assert r.invariant_names == ["rod", "d/dt rod"]
    assert r.alg_names == ["newton[0]", "newton[1]", "newton[2]", "d2/dt2 rod"]
    v = r.model.variables["v"]
    for i in range(3):
        assert ca.is_equal(r.variables[f"der(p)[{i}]"], v.sym[i])
        assert ca.is_equal(r.variables[f"der(p,2)[{i}]"], v.der(1)[i])
    # p' = v
    assert all(ca.is_equal(r.ode[i], v.sym[i]) for i in range(3))
    assert [e["variable"] for e in r.eliminated] == [f"der(p)[{i}]" for i in range(3)]
    _pendulum3d_invariant_check(r, with_der_p=False)


def test_pendulum3d_alg_equals_lecture_kkt_form():
    """alg equals [m I, p; p^T, 0] [v'; z] - [u - m g e3; -v.v] (lecture L3) at random
    points (not only on solutions), for random parameters too."""
    r = reduce_index(ex.pendulum3d(), eliminate="states")
    f = ca.Function("g", [r.x, r.z, r.u, r.p], [r.alg])
    rng = np.random.default_rng(2)
    for _ in range(5):
        p, v, u = rng.standard_normal(3), rng.standard_normal(3), rng.standard_normal(3)
        a, zval = rng.standard_normal(3), rng.standard_normal()
        par = rng.uniform(0.5, 2.0, r.n_p)
        mass, g = par[r.p_names.index("m")], par[r.p_names.index("g")]
        K = np.block([[mass * np.eye(3), p[:, None]], [p[None, :], np.zeros((1, 1))]])
        rhs = np.concatenate([u - mass * g * np.array([0, 0, 1]), [-v @ v]])
        hand = K @ np.concatenate([a, [zval]]) - rhs
        x = np.concatenate([p, v])
        z = np.concatenate([a, [zval]])
        got = np.asarray(f(x, z, u, par)).ravel()
        assert np.max(np.abs(got - hand)) < 1e-12


def test_delta_robot_minimal_index1_form():
    """Delta robot (lecture L4): alpha' = omega and p' = v are eliminated; the invariants are
    the rods and their first derivatives only, and DOF = 12 - 6 = 6 (3 arms: 3 positions and
    3 velocities)."""
    m = ex.delta_robot()
    r0 = reduce_index(m, eliminate=False)
    r = reduce_index(m, eliminate="states")
    assert (r0.nx, r0.nz, len(r0.invariant_names)) == (18, 15, 12)
    assert (r.nx, r.nz) == (12, 9)
    assert r.x_names == (
        [f"alpha[{i}]" for i in range(3)] + [f"omega[{i}]" for i in range(3)]
        + [f"p[{i}]" for i in range(3)] + [f"v[{i}]" for i in range(3)]
    )
    assert sorted(r.invariant_names) == sorted(
        [f"rods[{i}]" for i in range(3)] + [f"d/dt rods[{i}]" for i in range(3)]
    )
    assert r.info["index1_check"] == "passed"
    # the invariants are the same functions as before, with der(alpha) = omega, der(p) = v
    vals = {}
    rng = np.random.default_rng(5)
    for nm in r.x_names + r.z_names:
        vals[nm] = rng.standard_normal()
    for i in range(3):
        vals[f"der(alpha)[{i}]"] = vals[f"omega[{i}]"]
        vals[f"der(p)[{i}]"] = vals[f"v[{i}]"]
    u = rng.standard_normal(r.nu)
    out = []
    for rr in (r0, r):
        x, z = _values(rr, vals)
        inv = np.asarray(ca.Function("i", [rr.x, rr.z, rr.u, rr.p], [rr.invariants])(
            x, z, u, rr.p_values)).ravel()
        out.append(dict(zip(rr.invariant_names, inv, strict=True)))
    for nm in r.invariant_names:
        assert out[1][nm] == pytest.approx(out[0][nm], rel=1e-12, abs=1e-12)


def _pendulum_velocity_split(scale: float = 2.0) -> Model:
    """Planar pendulum (x'' = -T x, y'' = -T y - g, x^2 + y^2 = 1) with velocities
    v1 = x', v2 = y' - x' written so that eliminating y' needs the eliminated x'."""
    m = Model("split")
    x, y = m.state("x"), m.state("y")
    v1, v2 = m.state("v1"), m.state("v2")
    T = m.algebraic("T")
    g = m.parameter("g", 9.81)
    m.equation(scale * m.der(x) - scale * v1, name="kx")  # coefficient 2, not 1
    m.equation(m.der(y) - m.der(x) - v2, name="ky")  # y' = x' + v2: depends on x'
    m.equation(m.der(v1) + T * x, name="nx")
    m.equation(m.der(v2) + m.der(v1) + T * y + g, name="ny")
    m.equation(x**2 + y**2 - 1.0, name="rod")
    return m


def test_elimination_in_dependency_order_matches_exact_solution():
    """Eliminations that depend on each other (y' = x' + v2 with x' = v1) resolve to
    y' = v1 + v2, and the result integrates to the exact pendulum (section 2, case B)."""
    r = reduce_index(_pendulum_velocity_split(), eliminate="states")
    assert r.x_names == ["x", "y", "v1", "v2"]
    assert r.invariant_names == ["rod", "d/dt rod"]
    assert sorted(r.z_names) == ["T", "der(v1)", "der(v2)"]
    v1, v2 = (r.model.variables[n].sym for n in ("v1", "v2"))
    f = ca.Function("f", [v1, v2], [r.variables["der(y)"] - (v1 + v2)])
    assert float(f(0.3, -1.7)) == 0.0
    x0, z0 = _values(r, {"x": 1.0, "y": 0.0, "der(v2)": -9.81})
    xf, _ = _integrate(r, x0, z0, [0.0, 1.0, 10.0])
    for col, t in enumerate((1.0, 10.0)):
        assert abs(xf[r.x_names.index("x"), col] - CASE_B[t][0]) < 1e-8
        assert abs(xf[r.x_names.index("y"), col] - CASE_B[t][1]) < 1e-8


def test_nonconstant_coefficient_is_not_eliminated():
    """x x' = ... is not explicit with a constant coefficient: der(x) stays a state."""
    m = Model("nc")
    x, v, T = m.state("x"), m.state("v"), m.algebraic("T")
    m.equation((1 + x**2) * m.der(x) - v, name="k")
    m.equation(m.der(v) - T, name="n")
    m.equation(x - ca.sin(m.t), name="track")
    r = reduce_index(m, eliminate="states")
    assert r.eliminated == []
    assert "der(x)" in r.x_names and r.invariant_names == ["k", "track", "d/dt track"]


def test_time_derivative_matches_hand_derivative():
    m = Model("td")
    x = m.state("x")
    u = m.control("u")
    k = m.parameter("k", 2.0)
    e = k * ca.sin(x) * u + m.t**2
    d2 = time_derivative(e, m, 2)
    # hand: d/dt = k cos(x) x' u + k sin(x) u' + 2t; d2/dt2 = ...
    X, X1, X2 = m.der(x, 0) if False else x, m.der(x), m.der(x, 2)
    U1, U2 = m.der(u), m.der(u, 2)
    hand = (
        k * (-ca.sin(X) * X1**2 * u + ca.cos(X) * X2 * u + ca.cos(X) * X1 * U1)
        + k * (ca.cos(X) * X1 * U1 + ca.sin(X) * U2)
        + 2
    )
    f = ca.Function("f", [m.t, x, X1, X2, u, U1, U2, k], [d2 - hand])
    rng = np.random.default_rng(3)
    for _ in range(3):
        assert abs(float(f(*rng.standard_normal(8)))) < 1e-12


# ------------------------------------------------------------------ integration vs exact
def test_planar_pendulum_matches_exact_solution_case_b():
    r = reduce_index(ex.pendulum_planar(g=9.81, L=1.0))
    # released at rest from theta0 = pi/2: x = 1, y = 0; T(0) = g (3y - 2y0) = 0
    x0, z0 = _values(r, {"x": 1.0, "y": 0.0, "der(y,2)": -9.81})
    xf, _ = _integrate(r, x0, z0, [0.0, 1.0, 10.0])
    ix, iy = r.x_names.index("x"), r.x_names.index("y")
    for col, t in enumerate((1.0, 10.0)):
        assert abs(xf[ix, col] - CASE_B[t][0]) < 1e-8
        assert abs(xf[iy, col] - CASE_B[t][1]) < 1e-8


def test_arevalo_e3_matches_exact_solution():
    r = reduce_index(ex.arevalo())
    t0 = 1.0

    def exact(t):
        s, c = np.sin(t * t), np.cos(t * t)
        return {
            "x": s, "y": c, "u": 2 * t * c, "v": -2 * t * s, "l": -4 * t * t,
            "der(x)": 2 * t * c, "der(y)": -2 * t * s,
        }

    x0, z0 = _values(r, exact(t0))
    grid = [1.0, 3.0, 5.0]
    xf, zf = _integrate(r, x0, z0, grid)
    for col, t in enumerate(grid[1:]):
        e = exact(t)
        for n in ("x", "y", "u", "v"):
            assert abs(xf[r.x_names.index(n), col] - e[n]) < 1e-6, (n, t)
        assert abs(zf[r.z_names.index("l"), col] - e["l"]) < 1e-4


def test_l2_needs_input_derivatives_and_integrates():
    r = reduce_index(ex.l2())
    assert r.input_derivatives == ["der(u)", "der(u,2)"]
    assert r.u_names == ["u", "der(u)", "der(u,2)"]
    t = r.t
    u_expr = ca.vertcat(ca.sin(t), ca.cos(t), -ca.sin(t))
    # DOF 0: x2 = u, x1 = u', z = u''
    x0, z0 = _values(r, {"x1": 1.0, "x2": 0.0, "der(x2)": 1.0})
    grid = [0.0, 1.0, 2.0, 5.0]
    xf, zf = _integrate(r, x0, z0, grid, u_expr=u_expr)
    for col, tt in enumerate(grid[1:]):
        assert abs(xf[r.x_names.index("x2"), col] - np.sin(tt)) < 1e-8
        assert abs(xf[r.x_names.index("x1"), col] - np.cos(tt)) < 1e-8
        assert abs(zf[r.z_names.index("z"), col] + np.sin(tt)) < 1e-8


def test_explicit_time_and_parameters():
    """E1 (Brenan et al.): y1 = e^-t + t sin t, y2 = sin t."""
    r = reduce_index(ex.brenan())
    x0, z0 = _values(r, {"y1": 1.0, "y2": 0.0})
    xf, zf = _integrate(r, x0, z0, [0.0, 2.0])
    vals = dict(zip(r.x_names, xf[:, 0], strict=True))
    vals.update(zip(r.z_names, zf[:, 0], strict=True))
    assert abs(vals["y1"] - (np.exp(-2.0) + 2.0 * np.sin(2.0))) < 1e-8
    assert abs(vals["y2"] - np.sin(2.0)) < 1e-8


# ------------------------------------------------------------------ dummy derivatives
def test_dummy_derivatives_pendulum_has_no_drift():
    m = ex.pendulum_planar(g=9.81, L=1.0)
    r = reduce_index(m, method="dummy_derivatives", point={"x": 0.3, "y": -0.95})
    # near the bottom the vertical position is the dummy, x stays a state
    assert r.state_selection["states"] == ["x", "der(x)"]
    assert r.state_selection["dummies"] == ["y", "der(y)"]
    theta0 = 0.5
    x0v, y0v = np.sin(theta0), -np.cos(theta0)
    T0 = 9.81 * (3 * y0v - 2 * y0v)
    x0, z0 = _values(
        r, {"x": x0v, "y": y0v, "T": T0, "der(x,2)": x0v * T0, "der(y,2)": y0v * T0 - 9.81}
    )
    grid = np.linspace(0.0, 10.0, 21)
    xf, zf = _integrate(r, x0, z0, grid, abstol=1e-8, reltol=1e-8)
    X = xf[r.x_names.index("x")]
    Y = zf[r.z_names.index("y")]
    assert np.max(np.abs(X**2 + Y**2 - 1.0)) < 1e-7
    # and it is the right motion: exact solution at t = 10
    from daekit.examples import exact

    e = exact.pendulum_planar(10.0, theta0, g=9.81, L=1.0)
    assert abs(X[-1] - float(e["x"])) < 1e-5


def test_selection_condition_and_reselect():
    m = ex.pendulum_planar()
    r = reduce_index(m, method="dummy_derivatives", point={"x": 0.0, "y": -1.0})
    assert r.state_selection["dummies"] == ["y", "der(y)"]
    assert r.state_selection["condition"] == pytest.approx(1.0)
    # at x = 1, y = 1e-8 the dummy y is badly determined by x
    vals = {"x": 1.0, "y": 1e-8}
    x, z = _values(r, vals)
    assert selection_condition(r, x, z) > 1e7
    r2 = reselect(r, (x, z))
    assert r2.state_selection["dummies"] == ["x", "der(x)"]
    x2, z2 = map_values(r, r2, x, z)
    assert x2[r2.x_names.index("y")] == pytest.approx(1e-8)
    assert z2[r2.z_names.index("x")] == pytest.approx(1.0)
    assert selection_condition(r2, x2, z2) < 2.0


# ------------------------------------------------------------------ stabilizations
def test_baumgarte_coefficients():
    r = reduce_index(ex.pendulum_planar())
    rb = baumgarte(r, poles=(-1.0, -1.0))
    assert rb.stabilization == "baumgarte"
    check_index1(rb)
    # alg_b - alg at random points equals c'' + 2 c' + c minus c'' on the rod row
    f = ca.Function("d", [r.x, r.z, r.p], [rb.alg - r.alg, r.invariants])
    rng = np.random.default_rng(4)
    for _ in range(3):
        diff, inv = (np.asarray(a).ravel() for a in f(rng.standard_normal(r.nx),
                                                      rng.standard_normal(r.nz), r.p_values))
        row = r.alg_names.index("d2/dt2 rod")
        assert diff[row] == pytest.approx(2.0 * inv[1] + 1.0 * inv[0], rel=1e-12, abs=1e-12)
        assert np.allclose(np.delete(diff, row), 0.0)
    # poles (-2, -3): s^2 + 5 s + 6
    assert baumgarte(r, poles=(-2.0, -3.0)).info["baumgarte"]["coefficients"]["rod"] == [6.0, 5.0]


def test_baumgarte_warns_on_fast_poles():
    r = reduce_index(ex.pendulum_planar())
    with pytest.warns(BaumgarteStiffnessWarning):
        baumgarte(r, poles=(-1e5, -1e5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        baumgarte(r, poles=(-1.0, -1.0))


def test_baumgarte_pendulum_inconsistent_start_decays():
    """Started off the manifold (c(0) = 0.01), Baumgarte pulls c back like (1 + t) e^-t."""
    r = baumgarte(reduce_index(ex.pendulum_planar()), poles=(-1.0, -1.0))
    x0, z0 = _values(r, {"x": np.sqrt(1.01), "y": 0.0})
    xf, _ = _integrate(r, x0, z0, [0.0, 10.0])
    X, Y = xf[r.x_names.index("x"), 0], xf[r.x_names.index("y"), 0]
    c10 = X**2 + Y**2 - 1.0
    assert c10 == pytest.approx(0.01 * 11 * np.exp(-10.0), rel=1e-4)


def test_ggl_pendulum_matches_exact():
    r = ggl(reduce_index(ex.pendulum_planar(g=9.81, L=1.0)))
    assert r.index == 2 and r.z_names[-1] == "mu(rod)"
    x0, z0 = _values(r, {"x": 1.0, "y": 0.0, "der(y,2)": -9.81})
    xf, _ = _integrate(r, x0, z0, [0.0, 1.0], suppress_algebraic=True,
                       abstol=1e-10, reltol=1e-10)
    assert abs(xf[r.x_names.index("x"), 0] - CASE_B[1.0][0]) < 1e-6
    assert abs(xf[r.x_names.index("y"), 0] - CASE_B[1.0][1]) < 1e-6


# ------------------------------------------------------------------ bad input
def test_structurally_singular_model_names_equations():
    m = Model("bad")
    x = m.state("x")
    y = m.algebraic("y")
    w = m.algebraic("w")
    m.equation(m.der(x) + y, name="e1")
    m.equation(x - 1.0, name="e2")
    m.equation(x + 2.0, name="e3")
    del w
    with pytest.raises(StructuralError) as err:
        reduce_index(m)
    msg = str(err.value)
    assert "e2" in msg or "e3" in msg


def _residual_at(r, vals, t):
    f = ca.Function("res", [r.t, r.x, r.z, r.p], [ca.vertcat(r.alg, r.invariants)])
    x, z = _values(r, vals)
    return np.asarray(f(t, x, z, r.p_values)).ravel()


@pytest.mark.parametrize(
    "maker, exact",
    [
        # reference-problems.md section 4: true DOF 0 and the exact solutions
        (ex.f1, lambda t: {"y": np.sin(t), "z": 0.0, "der(y)": np.cos(t), "der(z)": 0.0}),
        (ex.f2, lambda t: {"x": t + np.sin(t), "der(x)": 1 + np.cos(t),
                           "der(x,2)": -np.sin(t), "y": 0.0}),
        (ex.f3, lambda t: {"x1": np.cos(t) - t, "der(x1)": -np.sin(t) - 1,
                           "x2": np.sqrt(1 + 2 * np.sin(t)), "x3": t + 1 + np.sin(t)}),
    ],
)
def test_structural_analysis_failure_is_amended(maker, exact):
    """F1-F3: the Sigma-method fails (singular system Jacobian); the linear-combination
    amendment finds the true DOF 0, and the exact solution satisfies the reduced system."""
    r = reduce_index(maker())
    assert r.amendments and "linear-combination" in r.amendments[0]
    assert r.nx - len(r.invariant_names) == 0
    for t in (0.3, 1.1):
        assert np.max(np.abs(_residual_at(r, exact(t), t))) < 1e-12


def test_singular_system_jacobian_not_amendable_names_equations():
    m = Model("nonconstant")
    x1, x2 = m.state("x1"), m.state("x2")
    m.equation(m.der(x1) + x1 * m.der(x2) - 1.0, name="e1")
    m.equation(x1 * (m.der(x1) + x1 * m.der(x2)) + x2, name="e2")
    with pytest.raises(ReductionError) as err:
        reduce_index(m)
    msg = str(err.value)
    assert "singular" in msg and "'e1'" in msg and "'e2'" in msg


def test_unknown_method():
    with pytest.raises(ReductionError, match="unknown reduction method"):
        reduce_index(ex.l2(), method="magic")


def test_large_chain_is_fast():
    m = ex.planar_chain(200)
    r = reduce_index(m, eliminate="states")
    # q' = v eliminated: states (q, v), algebraic (v', lambda), invariants: the N rods and
    # their derivatives
    assert (r.nx, r.nz, len(r.invariant_names)) == (800, 600, 400)
    r0 = reduce_index(m, eliminate=False)
    assert (r0.nx, r0.nz, len(r0.invariant_names)) == (1200, 1000, 800)


def test_format_reduced_lists_equations_invariants_selection():
    from daekit.reduction import format_reduced

    text = format_reduced(reduce_index(ex.l2()))
    assert "input derivatives needed: der(u), der(u,2)" in text
    assert "0 = d/dt output:" in text
    text = format_reduced(
        reduce_index(ex.pendulum_planar(), method="dummy_derivatives", point={"x": 0.2, "y": -1})
    )
    assert "dummies: y, der(y)" in text


@pytest.mark.parametrize("angle, dummy_coord", [(0.3, 0), (1.2, 1)])
def test_dummy_derivatives_big_chain_per_block(angle, dummy_coord):
    """A 300-link chain (stage 1 has 900 equations: done per block) turning rigidly with g = 0
    (exact solution, daekit.examples.exact.planar_chain_rotating). Selected at the exact state
    at angle w t: every rod lies along (cos wt, sin wt), so the best pivot of rod k is the
    larger coordinate of mass k (x for wt = 0.3, y for wt = 1.2), and the velocities v are
    the dummies of the kinematics rows (their private columns). The exact solution satisfies
    every algebraic equation of the result (they include all invariants)."""

    from daekit.examples import exact

    N = 300
    m = ex.planar_chain(N, g=0.0)
    e = exact.planar_chain_rotating(angle, N)
    point = {"q": e["q"], "v": e["v"], "der(q)": e["der(q)"], "der(v)": e["der(v)"],
             "lam": e["lam"], "der(q,2)": e["der(v)"]}
    r = reduce_index(m, method="dummy_derivatives", point=point)
    st = r.state_selection["stages"]
    assert st[0]["blocks"] > 1 and np.isfinite(st[0]["condition_estimate"])
    assert r.info["index1_check"] == "passed"
    assert r.nx == 2 * N
    k = np.arange(N)
    assert set(st[1]["dummies"]) == {f"q[{2 * i + dummy_coord}]" for i in k}
    assert set(r.x_names) == (
        {f"q[{2 * i + 1 - dummy_coord}]" for i in k} | {f"der(q)[{2 * i + 1 - dummy_coord}]"
                                                         for i in k}
    )
    # the exact solution at another time satisfies alg = 0 (all equations and invariants)
    e2 = exact.planar_chain_rotating(angle + 0.05, N)
    vals = {}
    for name, arr in (("q", e2["q"]), ("v", e2["v"]), ("der(q)", e2["der(q)"]),
                      ("der(v)", e2["der(v)"]), ("der(q,2)", e2["der(v)"]), ("lam", e2["lam"])):
        vals.update({f"{name}[{i}]": float(a) for i, a in enumerate(arr)})
    x, z = _values(r, vals)
    assert len(vals) >= r.nx + r.nz
    res = np.asarray(ca.Function("g", [r.x, r.z, r.p], [r.alg])(x, z, r.p_values)).ravel()
    assert np.max(np.abs(res)) < 1e-9 * N
    # monitoring uses the same per-block measure as the selection
    xs, zs = _values(r, {**vals})
    assert selection_condition(r, xs, zs) < 10 * r.state_selection["condition"]


def test_baumgarte_rejects_unstable_poles():
    import daekit as dk

    r = dk.reduce_index(dk.examples.pendulum3d())
    with pytest.raises(dk.ReductionError, match=r"poles 1, 2 have real part >= 0"):
        dk.baumgarte(r, poles=(1.0, 2.0))


# ------------------------------------------------------------------ scaling and amendments
def _rc(C: float) -> Model:
    m = Model("rc")
    x = m.state("x")
    cap = m.parameter("C", C)
    m.equation(cap * m.der(x) + x, name="rc")
    return m


def test_badly_scaled_ode_keeps_its_derivative_and_exact_solution():
    """C x' + x = 0 is an ODE for any C > 0 (x = x0 exp(-t/C)); a small C must not read as a
    singular system Jacobian (which would amend the model into x = 0)."""
    r = reduce_index(_rc(1e-3), eliminate="states")
    assert r.amendments == [] and r.info["index1_check"] == "passed"
    assert (r.x_names, r.z_names) == (["x"], ["der(x)"])
    grid = [0.0, 1e-3, 5e-3]
    xf, zf = _integrate(r, np.array([2.0]), np.array([-2.0 / 1e-3]), grid)
    for col, t in enumerate(grid[1:]):
        assert xf[0, col] == pytest.approx(2.0 * np.exp(-t / 1e-3), rel=1e-8)
        assert zf[0, col] == pytest.approx(-2.0 / 1e-3 * np.exp(-t / 1e-3), rel=1e-6)
    for method, kw in (("differentiate", {"eliminate": "states"}), ("dummy_derivatives", {})):
        r12 = reduce_index(_rc(1e-12), method=method, **kw)
        assert r12.amendments == [] and r12.info["index1_check"] == "passed"
        assert r12.z_names == ["der(x)"] and r12.x_names == ["x"]
        # alg is still C x' + x: d alg / d x' = C
        f = ca.Function("j", [r12.x, r12.z, r12.p], [ca.jacobian(r12.alg, r12.z)])
        assert float(f(0.3, 0.7, r12.p_values)) == pytest.approx(1e-12, rel=1e-14)


def test_scaled_two_time_scale_model_is_not_amended():
    """M x' + x = 0, C y' + y = x with M = 1e3, C = 1e-8: index 1 as it is.
    Exact: x = x0 e^(-t/M), y = A e^(-t/M) + (y0 - A) e^(-t/C), A = x0 / (1 - C/M)."""
    m = Model("scaled")
    x, y = m.state("x"), m.state("y")
    M, C = m.parameter("M", 1e3), m.parameter("C", 1e-8)
    m.equation(M * m.der(x) + x, name="mech")
    m.equation(C * m.der(y) + y - x, name="elec")
    r = reduce_index(m, eliminate="states")
    assert r.amendments == [] and r.info["index1_check"] == "passed"
    assert r.x_names == ["x", "y"] and r.z_names == ["der(x)", "der(y)"]
    x0 = 1.0
    A = x0 / (1 - 1e-8 / 1e3)
    y0 = A + 1e-6  # a small fast transient on top of the slow manifold
    z0 = np.array([-x0 / 1e3, (x0 - y0) / 1e-8])
    grid = [0.0, 1e-8, 1.0, 50.0]
    # consistent start: no IDACalcIC (its Newton test struggles with the 1e8 derivative), and
    # the derivatives (algebraic here) out of the error test
    xf, _ = _integrate(r, np.array([x0, y0]), z0, grid, abstol=1e-12, reltol=1e-10,
                       calc_ic=False, init_xdot=list(z0), suppress_algebraic=True)
    for col, t in enumerate(grid[1:]):
        assert xf[0, col] == pytest.approx(x0 * np.exp(-t / 1e3), rel=1e-8)
        exact_y = A * np.exp(-t / 1e3) + (y0 - A) * np.exp(-t / 1e-8)
        assert xf[1, col] == pytest.approx(exact_y, rel=1e-8, abs=1e-9)


def test_amendment_with_coupling_to_an_earlier_block():
    """A Gear--Petzold pair whose dynamic equation also uses w' (w' = -w): the left null
    vector of the system Jacobian reaches the earlier block (the decay equation) through the
    back substitution. Exact: w = w0 e^-t, z = w, y = sin t + 2 t w; DOF 1."""
    m = Model("coupled")
    w, y, z = m.state("w"), m.state("y"), m.state("z")
    t = m.t
    m.equation(m.der(w) + w, name="decay")
    m.equation(m.der(y) - 2 * t * m.der(z) - z - ca.cos(t) + m.der(w), name="dynamic")
    m.equation(y - 2 * t * z - ca.sin(t), name="constraint")
    r = reduce_index(m)
    (note,) = r.amendments
    assert "'dynamic' was replaced" in note and "decay" in note and "d/dt constraint" in note
    assert r.nx - len(r.invariant_names) == 1

    def exact(tt):
        wv = 0.7 * np.exp(-tt)
        return {"w": wv, "der(w)": -wv, "z": wv, "der(z)": -wv, "y": np.sin(tt) + 2 * tt * wv,
                "der(y)": np.cos(tt) + 2 * wv - 2 * tt * wv}

    for tt in (0.2, 1.3):
        assert np.max(np.abs(_residual_at(r, exact(tt), tt))) < 1e-13
    x0, z0 = _values(r, exact(0.0))
    xf, _ = _integrate(r, x0, z0, [0.0, 2.0])
    assert xf[r.x_names.index("w"), 0] == pytest.approx(0.7 * np.exp(-2.0), rel=1e-9)


def test_amendment_in_a_large_model_uses_the_singular_block_only():
    """A 200-link chain (1000 equations) plus one Gear--Petzold pair: the singular 2-by-2
    block is found in the block triangular form and amended; the chain is untouched."""

    N = 200
    m = ex.planar_chain(N)
    y, z = m.state("y"), m.state("z")
    t = m.t
    m.equation(m.der(y) - 2 * t * m.der(z) - z - ca.cos(t), name="dynamic")
    m.equation(y - 2 * t * z - ca.sin(t), name="constraint")
    r = reduce_index(m)
    (note,) = r.amendments
    assert "+1*dynamic -1*d/dt constraint" in note
    assert r.info["index1_check"] == "passed"
    # chain as before (q' = v eliminated), the pair algebraic with its true DOF 0
    assert (r.nx, len(r.invariant_names)) == (4 * N, 2 * N)
    assert {"y", "z"} <= set(r.z_names)
    # the exact solution y = sin t, z = 0 satisfies the pair's equations
    rows = [r.alg_names.index(nm) for nm in ("dynamic", "constraint")]
    f = ca.Function("g", [r.t, r.x, r.z, r.p], [r.alg[rows]])
    for tt in (0.4, 2.0):
        x, zz = _values(r, {"y": np.sin(tt), "z": 0.0})
        assert np.max(np.abs(np.asarray(f(tt, x, zz, r.p_values)))) < 1e-14


# ------------------------------------------------------------------ messages and bad input
@pytest.mark.parametrize("N", [10, 150])
def test_dummy_derivative_failure_names_the_singular_block(N):
    """Two masses at the same place: rod k has a zero gradient, so stage 1 cannot be solved
    for d/dt rod[k]; the message names that equation only (N = 150: per-block stage)."""
    m = ex.planar_chain(N)
    q = np.zeros(2 * N)
    q[1::2] = -np.arange(1.0, N + 1)
    k = N // 2
    q[2 * k], q[2 * k + 1] = q[2 * k - 2], q[2 * k - 1]
    with pytest.raises(ReductionError) as err:
        reduce_index(m, method="dummy_derivatives", point={"q": q, "v": np.zeros(2 * N)})
    msg = str(err.value)
    assert f"'d/dt rod[{k}]' cannot be solved" in msg
    assert "kinematics" not in msg


def test_bad_point_poles_and_sizes_raise_reduction_errors():
    pend = ex.pendulum3d
    with pytest.raises(ReductionError, match=r"point\['p'\] has 2 values, but 'p' has 3"):
        reduce_index(pend(), method="dummy_derivatives", point={"p": [1, 2]})
    with pytest.raises(ReductionError, match=r"point\['p'\] = 'abc' is not numeric: it must be numbers"):
        reduce_index(pend(), method="dummy_derivatives", point={"p": "abc"})
    with pytest.raises(ReductionError, match=r"poles must be a number or a sequence"):
        baumgarte(reduce_index(pend()), poles="a")
    rd = reduce_index(pend(), method="dummy_derivatives")
    with pytest.raises(ReductionError, match=r"x must be 4 numbers .* got 2 values"):
        selection_condition(rd, [1, 2], [3])
    with pytest.raises(ReductionError, match=r"z must be \d+ numbers"):
        selection_condition(rd, np.zeros(rd.nx), [3])


# ------------------------------------------------------------------ minimal index-1 form
def test_pendulum3d_reduces_to_the_lecture_hand_form():
    """Default: der(p) = v and der(v) = (u - m g e3 - z p)/m are substituted: x = (p, v),
    z = (z) only, alg = d2/dt2 rod = p.a + v.v with that a (lecture L3's hand-written form),
    checked at random points and parameters (not only on solutions)."""
    r = reduce_index(ex.pendulum3d())
    assert r.info["index1_check"] == "passed"
    assert r.x_names == ["p[0]", "p[1]", "p[2]", "v[0]", "v[1]", "v[2]"]
    assert r.z_names == ["z"] and r.invariant_names == ["rod", "d/dt rod"]
    assert r.alg_names == ["d2/dt2 rod"]
    assert [e["variable"] for e in r.substituted] == [f"der(v)[{i}]" for i in range(3)]
    assert [e["equation"] for e in r.substituted] == [f"newton[{i}]" for i in range(3)]
    names = [f"der(v)[{i}]" for i in range(3)] + [f"der(p,2)[{i}]" for i in range(3)]
    f = ca.Function("g", [r.x, r.z, r.u, r.p],
                    [r.alg, r.ode, ca.vertcat(*[r.variables[n] for n in names])])
    rng = np.random.default_rng(7)
    for _ in range(5):
        p, v, u, zval = (rng.standard_normal(3), rng.standard_normal(3),
                         rng.standard_normal(3), rng.standard_normal())
        par = rng.uniform(0.5, 2.0, r.n_p)
        mass, g = par[r.p_names.index("m")], par[r.p_names.index("g")]
        a = (u - mass * g * np.array([0.0, 0.0, 1.0]) - zval * p) / mass
        alg, ode, acc = (np.asarray(o).ravel() for o in f(np.r_[p, v], zval, u, par))
        assert abs(alg[0] - (p @ a + v @ v)) < 1e-12
        assert np.max(np.abs(ode - np.r_[v, a])) < 1e-12
        assert np.max(np.abs(acc - np.r_[a, a])) < 1e-12  # der(v) and der(p,2) by name
    # the KKT form is still there on request
    rk = reduce_index(ex.pendulum3d(), eliminate="states")
    assert rk.z_names == ["der(v)[0]", "der(v)[1]", "der(v)[2]", "z"]
    with pytest.raises(ReductionError, match="eliminate='minimal' is not an option"):
        reduce_index(ex.pendulum3d(), eliminate="minimal")


def test_minimal_form_integrates_to_the_exact_pendulum():
    """Second-order planar pendulum and the split-velocity form: z = (T) only, and plain IDAS
    on the result reproduces the exact solution (reference-problems section 2, case B)."""
    r = reduce_index(ex.pendulum_planar())
    assert r.z_names == ["T"] and r.x_names == ["x", "der(x)", "y", "der(y)"]
    x0, z0 = _values(r, {"x": 1.0, "y": 0.0, "T": 0.0})
    xf, _ = _integrate(r, x0, z0, [0.0, 1.0, 10.0])
    for col, t in enumerate((1.0, 10.0)):
        assert abs(xf[0, col] - CASE_B[t][0]) < 1e-8 and abs(xf[2, col] - CASE_B[t][1]) < 1e-8
    rs = reduce_index(_pendulum_velocity_split())
    assert rs.z_names == ["T"] and rs.x_names == ["x", "y", "v1", "v2"]
    x0, z0 = _values(rs, {"x": 1.0, "y": 0.0})
    xf, _ = _integrate(rs, x0, z0, [0.0, 1.0, 10.0])
    for col, t in enumerate((1.0, 10.0)):
        assert abs(xf[0, col] - CASE_B[t][0]) < 1e-8 and abs(xf[1, col] - CASE_B[t][1]) < 1e-8


def test_minimal_form_chain_accelerations_exact():
    """A 30-link chain turning rigidly (g = 0): z = (lam) only; the substituted accelerations
    der(v), read by name, equal the exact centripetal ones at the exact state."""
    from daekit.examples.exact import planar_chain_rotating

    N = 30
    r = reduce_index(ex.planar_chain(N, g=0.0))
    assert (r.nx, r.nz) == (4 * N, N) and r.z_names == [f"lam[{k}]" for k in range(N)]
    e = planar_chain_rotating(0.7, N, omega=1.3)
    acc = ca.vertcat(*[r.variables[f"der(v)[{i}]"] for i in range(2 * N)])
    f = ca.Function("a", [r.x, r.z, r.p], [acc, r.alg])
    a, alg = (np.asarray(o).ravel() for o in f(np.r_[e["q"], e["v"]], e["lam"], r.p_values))
    assert np.max(np.abs(a - e["der(v)"])) < 1e-12 * np.max(np.abs(e["lam"]))
    assert np.max(np.abs(alg)) < 1e-11 * np.max(np.abs(e["lam"]))


def test_state_dependent_mass_keeps_the_kkt_form():
    """(2 + sin x) v' = -x: the coefficient depends on the state, so der(v) stays an algebraic
    unknown; a parameter coefficient k v' = -x is substituted."""
    m = Model("mass")
    x, v = m.state("x"), m.state("v")
    m.equation(m.der(x) - v, name="kin")
    m.equation((2 + ca.sin(x)) * m.der(v) + x, name="newton")
    r = reduce_index(m)
    assert r.z_names == ["der(v)"]
    assert [e["variable"] for e in r.substituted] == ["der(x)"]  # x' = v: explicit
    m2 = Model("param")
    x, v = m2.state("x"), m2.state("v")
    k = m2.parameter("k", 4.0)
    m2.equation(m2.der(x) - v, name="kin")
    m2.equation(k * m2.der(v) + x, name="newton")
    r2 = reduce_index(m2)
    assert r2.nz == 0 and r2.x_names == ["x", "v"] and r2.info["index1_check"] == "passed"
    # x'' = -x / k: x = cos(t / sqrt(k)) from x = 1, v = 0; also for another k
    F = ca.integrator("F", "cvodes", {"x": r2.x, "p": r2.p, "ode": r2.ode}, 0.0, [3.0],
                      {"abstol": 1e-12, "reltol": 1e-12})
    for kv in (4.0, 0.25):
        xf = np.asarray(F(x0=[1.0, 0.0], p=[kv])["xf"]).ravel()
        assert abs(xf[0] - np.cos(3.0 / np.sqrt(kv))) < 1e-9


def test_constant_coupled_mass_matrix_stays_algebraic_and_exact():
    """[[2, 1], [1, 2]] v' = -x: each acceleration's definition needs the other (a cycle), so
    both stay algebraic unknowns; the result is still exact. Modes: x1 + x2 with frequency
    1/sqrt(3), x1 - x2 with frequency 1."""
    m = Model("coupled_mass")
    x, v = m.state("x", 2), m.state("v", 2)
    m.equation(m.der(x) - v, name="kin")
    a = m.der(v)
    m.equation(ca.vertcat(2 * a[0] + a[1] + x[0], a[0] + 2 * a[1] + x[1]), name="newton")
    r = reduce_index(m)
    assert sorted(r.z_names) == ["der(v)[0]", "der(v)[1]"]
    assert [e["variable"] for e in r.substituted] == ["der(x)[0]", "der(x)[1]"]
    x0 = np.array([1.0, 0.0, 0.0, 0.0])  # x = (1, 0), v = 0
    xf, _ = _integrate(r, x0, np.zeros(2), [0.0, 2.0])
    s, d = 0.5 * np.cos(2.0 / np.sqrt(3.0)), 0.5 * np.cos(2.0)
    assert abs(xf[0, 0] - (s + d)) < 1e-8 and abs(xf[1, 0] - (s - d)) < 1e-8


def test_minimal_form_simulates_and_reads_der_v_by_name():
    """simulate + traj["der(v)"] on the minimal form of the second-order planar pendulum
    released at rest from horizontal, against the exact accelerations (elliptic functions)."""
    from daekit.examples.exact import pendulum_planar

    r = reduce_index(ex.pendulum_planar())
    init = dk.initialize(r, fixed={"x": 1.0, "der(x)": 0.0}, guess={"y": 0.0})
    ts = np.linspace(0.0, 2.0, 21)
    traj = dk.simulate(r, ts, init, rtol=1e-10, atol=1e-10)
    e = pendulum_planar(ts, np.pi / 2)
    assert np.max(np.abs(traj["der(x,2)"] - e["der(x,2)"])) < 1e-6
    assert np.max(np.abs(traj["der(y,2)"] - e["der(y,2)"])) < 1e-6
    assert np.max(np.abs(traj["T"] - e["T"])) < 1e-6
