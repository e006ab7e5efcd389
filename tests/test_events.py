"""Events, resets with consistency restored, switches (issue 12).

Exact references: the wall pendulum's impact times (daekit.examples.exact.pendulum_wall_impacts,
from the complete elliptic integral K and energy loss e^2 per impact), free fall, exponential
decay, the piecewise-linear switch model, and an independent mass-weighted projection.
"""

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit.errors import ModelError, SimulationError
from daekit.examples.exact import pendulum_wall_impacts
from daekit.simulate.reset import restore


def wall_pendulum(e: float) -> dk.Model:
    m = dk.examples.pendulum_planar()
    x = m.variables["x"].sym
    y = m.variables["y"].sym
    m.event(x, name="wall", direction=-1,
            reset={"der(x)": -e * m.der(x), "der(y)": -e * m.der(y)})
    return m


def run_wall(e: float, remedy: str | None):
    m = wall_pendulum(e)
    if remedy == "dummy_derivatives":
        r = dk.reduce_index(m, method="dummy_derivatives", point={"x": 1.0, "y": 0.0})
    else:
        r = dk.reduce_index(m)
    stab = remedy
    if remedy == "ggl":
        r, stab = dk.ggl(r), None
    init = dk.initialize(r, fixed={"x": 1.0, "y": 0.0, "der(x)": 0.0})
    ref = pendulum_wall_impacts(5, e)
    tg = np.linspace(0.0, ref[-1] + 0.1, 41)
    tr = dk.simulate(r, tg, init, stabilization=stab, rtol=1e-10, atol=1e-10)
    # every output point, and two rows (before, after) per impact
    assert set(tg.tolist()) <= set(tr.t.tolist()) and tr.t.size == tg.size + 2 * len(tr.events)
    assert np.all(np.diff(tr.t) >= 0)
    return tr, ref


def check_wall(tr, ref):
    te = np.array([t for t, n in tr.events if n == "wall"])
    assert te.size >= 5
    assert np.max(np.abs(te[:5] - ref)) < 1e-8
    assert tr.stats["events"] == len(tr.events)
    for t in te[:5]:
        rows = np.nonzero(tr.t == t)[0]
        assert rows.size == 2  # pre- and post-event rows
        pre, post = rows
        x, y = tr["x"][post], tr["y"][post]
        vx, vy = tr["der(x)"][post], tr["der(y)"][post]
        assert abs(x * x + y * y - 1.0) < 1e-10  # rod
        assert abs(x * vx + y * vy) < 1e-10  # velocity constraint
        assert tr["der(x)"][pre] < 0 < tr["der(x)"][post]  # the jump is recorded


@pytest.mark.parametrize("e", [1.0, 0.8])
@pytest.mark.parametrize("remedy", [None, "baumgarte", "projection", "ggl"])
def test_wall_pendulum_impact_times(e, remedy):
    tr, ref = run_wall(e, remedy)
    check_wall(tr, ref)


@pytest.mark.slow
@pytest.mark.parametrize("e", [
    pytest.param(1.0, marks=pytest.mark.xfail(
        strict=True, reason="1.8e-8 (measured): with e = 1 every swing comes to rest exactly "
        "at horizontal, where a selection is singular; the dummy-derivative segments "
        "(re-selected there) lose ~4e-9 per impact")),
    0.8,
])
def test_wall_pendulum_dummy_derivatives(e):
    tr, ref = run_wall(e, "dummy_derivatives")
    check_wall(tr, ref)


def test_exact_impact_reference():
    t = pendulum_wall_impacts(5, 1.0)
    assert abs(t[0] - 0.5919604868940593) < 1e-15
    assert np.allclose(np.diff(t), 2 * t[0], rtol=0, atol=1e-14)  # half periods


def independent_projection(q, v_star, M):
    """v+ = v* - M^-1 G^T (G M^-1 G^T)^-1 G v* for the rod x^2 + y^2 = 1 (G = 2 q^T)."""
    G = 2.0 * q.reshape(1, -1)
    Mi = np.linalg.inv(M)
    mu = np.linalg.solve(G @ Mi @ G.T, G @ v_star)
    return v_star - (Mi @ G.T @ mu).ravel()


def test_velocity_reset_is_mass_weighted_projection_in_simulation():
    m = dk.examples.pendulum_planar()
    y = m.variables["y"].sym
    # away from the bottom (y = -0.5, 60 degrees): a reset of der(x) alone violates G v = 0
    m.event(y + 0.5, name="kick", direction=-1, reset={"der(x)": 0.3})
    r = dk.reduce_index(m)
    init = dk.initialize(r, fixed={"x": 1.0, "y": 0.0, "der(x)": 0.0})
    tr = dk.simulate(r, np.linspace(0, 0.5, 11), init, rtol=1e-10, atol=1e-10)
    (te, name), = tr.events
    pre, post = np.nonzero(tr.t == te)[0]
    q = np.array([tr["x"][pre], tr["y"][pre]])
    v_star = np.array([0.3, tr["der(y)"][pre]])
    want = independent_projection(q, v_star, np.eye(2))
    got = np.array([tr["der(x)"][post], tr["der(y)"][post]])
    assert np.max(np.abs(got - want)) < 1e-12
    # positions: only the integrator's drift of the rod removed (the reset does not move them)
    assert np.max(np.abs(np.array([tr["x"][post], tr["y"][post]]) - q)) < 1e-9
    assert abs(tr["x"][post] ** 2 + tr["y"][post] ** 2 - 1.0) < 1e-13
    assert abs(q @ got) < 1e-12


def test_reset_mass_matrix_weighted_for_lagrangian_system():
    q = ca.SX.sym("q", 2)
    dq = ca.SX.sym("dq", 2)
    M = np.diag([1.0, 4.0])
    T = 0.5 * ca.dot(dq, M @ dq)
    ls = dk.lagrangian(q, dq, T, V=9.81 * q[1], constraints={"rod": ca.dot(q, q) - 1})
    r = ls.index1()
    s = np.sqrt(0.5)
    x = np.array([s, -s, 0.2, 0.7])  # (q, dq): dq violates G dq = 0
    z = np.zeros(r.nz)
    xp, zp, info = restore(r, 0.0, x, z, [], r.p_values, {"der(q)[0]": 0.2, "der(q)[1]": 0.7})
    assert info["metric"] == "mass matrix"
    want = independent_projection(x[:2], np.array([0.2, 0.7]), M)
    assert np.max(np.abs(xp[2:] - want)) < 1e-12
    assert np.all(xp[:2] == x[:2])


# "segments": the segment path (dummy derivatives and GGL use it) on a plain system
PATHS = [{}, {"use_driver": False}]


@pytest.mark.parametrize("path", PATHS)
def test_zeno_bouncing_ball_ends_with_error(path):
    m = dk.Model("ball")
    h = m.state("h")
    m.equation(m.der(h, 2) + 9.81, name="gravity")
    m.event(h, name="floor", direction=-1, reset={"der(h)": -0.5 * m.der(h)})
    r = dk.reduce_index(m)
    init = dk.initialize(r, fixed={"h": 1.0, "der(h)": 0.0})
    with pytest.raises(SimulationError, match="Zeno") as info:
        dk.simulate(r, np.linspace(0, 3, 31), init, rtol=1e-10, atol=1e-10, **path)
    t1 = np.sqrt(2 / 9.81)
    t_inf = t1 * (1 + 2 * 0.5 / (1 - 0.5))  # the accumulation point of the bounces
    part = info.value.trajectory
    assert part is not None and len(part.events) >= 10
    assert abs(part.events[0][0] - t1) < 1e-8
    assert part.events[-1][0] < t_inf + 1e-6
    assert t_inf - 1e-2 * 3 < info.value.t < t_inf  # stopped within 1/100 of the span of it
    import re

    est = float(re.search(r"accumulate geometrically .* at t = ([0-9]+\.[0-9]+)", str(info.value))[1])
    assert abs(est - t_inf) < 1e-7  # the estimated accumulation point


def test_terminal_event_ends_trajectory():
    m = dk.Model("decay")
    x = m.state("x")
    m.equation(m.der(x) + x, name="decay")
    m.event(x - 0.5, name="half", terminal=True)
    r = dk.reduce_index(m)
    tr = dk.simulate(r, np.linspace(0, 3, 31), dk.initialize(r, fixed={"x": 1.0}),
                     rtol=1e-10, atol=1e-10)
    assert [n for _, n in tr.events] == ["half"]
    assert abs(tr.t[-1] - np.log(2)) < 1e-9
    assert abs(tr["x"][-1] - 0.5) < 1e-9
    assert tr.stats["terminated_by"] == "half"


def test_if_else_switch_is_located_and_cheap():
    m = dk.Model("switch")
    x = m.state("x")
    z = m.algebraic("z")
    m.equation(m.der(x) - z, name="flow")
    m.equation(z - ca.if_else(x > 0.5, 2, 1), name="law")
    r = dk.reduce_index(m)
    tr = dk.simulate(r, np.linspace(0, 1, 11), dk.initialize(r, fixed={"x": 0.0}),
                     rtol=1e-10, atol=1e-10)
    assert len(tr.events) == 1 and abs(tr.events[0][0] - 0.5) < 1e-9
    assert tr.events[0][1].startswith("switch:")
    exact = np.where(tr.t <= 0.5, tr.t, 0.5 + 2 * (tr.t - 0.5))
    assert np.max(np.abs(tr["x"] - exact)) < 1e-8
    assert tr.stats["steps"] < 500  # not 100,000 steps crawling through the switch


def test_fabs_kink_is_a_switch():
    m = dk.Model("kink")
    x = m.state("x")
    m.equation(m.der(x) + ca.fabs(x - 0.5) + 0.5, name="flow")
    r = dk.reduce_index(m)
    assert [s.kind for s in dk.events.switches(r)] == ["fabs"]


def test_event_validation_names_the_culprit():
    m = dk.examples.pendulum_planar()
    x = m.variables["x"].sym
    with pytest.raises(ModelError, match="'T'"):
        m.event(x, name="bad", reset={"T": 0.0})
    with pytest.raises(ModelError, match="direction"):
        m.event(x, name="bad", direction=2)
    with pytest.raises(ModelError, match="'w'"):
        m.event(x, name="bad", reset={"w": 0.0})
    with pytest.raises(ModelError, match="scalar"):
        m.event(ca.vertcat(x, x), name="bad")
    other = ca.SX.sym("q")
    with pytest.raises(ModelError, match="'q'"):
        m.event(other, name="bad")
    m.event(x, name="ok")
    with pytest.raises(ModelError, match="twice"):
        m.event(x, name="ok")
    m2 = dk.examples.pendulum_planar()
    m2.event(m2.variables["x"].sym, name="acc", reset={"der(x,2)": 0.0})
    with pytest.raises(ModelError, match="acc"):
        dk.events.reduced_events(dk.reduce_index(m2))


def rattle_wall(e: float):
    q = ca.SX.sym("q", 2)
    v = ca.SX.sym("v", 2)
    ls = dk.lagrangian(q, v, 0.5 * ca.dot(v, v), V=9.81 * q[1],
                       constraints={"rod": ca.dot(q, q) - 1})
    mq = ls.model()
    qs = mq.variables["q"].sym
    mq.event(qs[0], name="wall", direction=-1, reset={"der(q)": -e * mq.der(qs)})
    return ls.index1()


@pytest.mark.parametrize("e", [1.0, 0.8])
def test_rattle_impact_times_second_order(e):
    ref = pendulum_wall_impacts(5, e)
    errs = []
    for dt in (1e-3, 2.5e-4):
        tr = dk.simulate(rattle_wall(e), np.linspace(0, ref[-1] + 0.1, 41),
                         {"q": [1, 0], "der(q)": [0, 0]}, method="rattle", dt=dt)
        te = np.array([t for t, n in tr.events])
        assert te.size == 5
        errs.append(np.max(np.abs(te - ref)))
        assert np.max(np.abs(tr.invariants)) < 1e-10  # rod and velocity constraint, resets too
        for t in te:
            pre, post = np.nonzero(tr.t == t)[0]
            assert tr["der(q)[0]"][pre] < 0 < tr["der(q)[0]"][post]
    assert errs[1] < 1e-6
    assert 10 < errs[0] / errs[1] < 24  # dt / 4: the error of a second-order method / 16


def test_cli_simulate_reports_events(capsys, tmp_path):
    import json

    from daekit.cli import main

    out = tmp_path / "wall.json"
    fixed = json.dumps({"x": 1.0, "y": 0.0, "der(x)": 0.0})
    assert main(["simulate", "pendulum_wall", "--t-end", "1.0", "--points", "11", "--fixed",
                 fixed, "--rtol", "1e-10", "--atol", "1e-10", "--quiet", "--json",
                 str(out)]) == 0
    text = capsys.readouterr().out
    assert "events: wall at t = 0.59196048" in text
    data = json.loads(out.read_text())
    (te, name), = data["events"]
    assert name == "wall" and abs(te - pendulum_wall_impacts(1, 0.8)[0]) < 1e-8


@pytest.mark.parametrize("path", PATHS)
def test_simultaneous_events_fire_in_declaration_order(path):
    m = dk.Model("decay")
    x = m.state("x")
    m.equation(m.der(x) + x, name="decay")
    m.event(2 * x - 1, name="second")  # the same crossing as 'first', declared first
    m.event(x - 0.5, name="first", reset={"x": 1.0})
    r = dk.reduce_index(m)
    tr = dk.simulate(r, np.linspace(0, 1, 11), dk.initialize(r, fixed={"x": 1.0}),
                     rtol=1e-10, atol=1e-10, **path)
    assert [n for _, n in tr.events] == ["second", "first"]
    assert abs(tr.events[0][0] - np.log(2)) < 1e-8 and tr.events[0][0] == tr.events[1][0]
    # after the reset x = 1 again: x = exp(-(t - ln 2))
    k = tr.t > tr.events[0][0]
    assert np.max(np.abs(tr["x"][k] - np.exp(-(tr.t[k] - np.log(2))))) < 1e-8


def test_event_on_an_input_and_time():
    m = dk.Model("driven")
    x = m.state("x")
    u = m.control("u")
    m.equation(m.der(x) - u, name="integrator")
    m.event(m.t - 0.25, name="clock", reset={"x": 0.0})
    r = dk.reduce_index(m)
    tr = dk.simulate(r, np.linspace(0, 0.5, 6), dk.initialize(r, fixed={"x": 0.0}),
                     inputs={"u": 2.0 + 0 * r.t}, rtol=1e-10, atol=1e-10)
    (te, name), = tr.events
    assert abs(te - 0.25) < 1e-9
    assert abs(tr["x"][-1] - 2.0 * (0.5 - te)) < 1e-8


@pytest.mark.parametrize("remedy", [None, "projection", "segments"])
def test_terminal_threshold_crossed_by_the_jump_fires_at_the_impact(remedy):
    m = dk.examples.pendulum_wall(0.5)
    x, y = m.variables["x"].sym, m.variables["y"].sym
    energy = 0.5 * (m.der(x) ** 2 + m.der(y) ** 2) + 9.81 * (y + 1)
    # 9.81 at the start, x e^2 = 1/4 per impact: 2.45 after the first, 0.61 after the second
    m.event(energy - 1.0, name="low_energy", direction=-1, terminal=True)
    r = dk.reduce_index(m)
    init = dk.initialize(r, fixed={"x": 1.0, "y": 0.0, "der(x)": 0.0})
    kw = {"use_driver": False} if remedy == "segments" else {"stabilization": remedy}
    tr = dk.simulate(r, np.linspace(0, 5, 51), init, rtol=1e-10, atol=1e-10, **kw)
    t2 = pendulum_wall_impacts(2, 0.5)[1]
    assert [n for _, n in tr.events] == ["wall", "wall", "low_energy"]
    assert abs(tr.events[-1][0] - t2) < 1e-8 and tr.t[-1] == tr.events[-1][0]
    assert tr.stats["terminated_by"] == "low_energy"


@pytest.mark.parametrize("path", PATHS)
def test_switching_force_on_index3_pendulum_matches_minimal_coordinates(path):
    """x'' = x T + f, f = -1 for x > 0 else +1 (an if_else in the index-3 model) against the
    angle form theta'' = -g sin(theta) + f cos(theta) integrated independently (SciPy, with
    its own event on sin(theta)): the switch times agree; a branch carried as a state must
    stay crisp (a drift of 1e-27 once switched both branches on)."""
    from scipy.integrate import solve_ivp

    m = dk.Model("pend_switch")
    x, y = m.state("x"), m.state("y")
    T = m.algebraic("T")
    m.equation(m.der(x, 2) - x * T - ca.if_else(x > 0, -1.0, 1.0), name="newton_x")
    m.equation(m.der(y, 2) - (y * T - 9.81), name="newton_y")
    m.equation(x**2 + y**2 - 1, name="rod")
    r = dk.reduce_index(m)
    init = dk.initialize(r, fixed={"x": 0.5, "der(x)": 0.0, "y": -np.sqrt(0.75)})
    tr = dk.simulate(r, np.linspace(0, 3, 31), init, rtol=1e-10, atol=1e-10, **path)

    def rhs(_t, s):
        f = -1.0 if np.sin(s[0]) > 0 else 1.0
        return [s[1], -9.81 * np.sin(s[0]) + f * np.cos(s[0])]

    def cross(_t, s):
        return np.sin(s[0])

    ref = solve_ivp(rhs, (0, 3), [np.arcsin(0.5), 0.0], rtol=1e-12, atol=1e-12, max_step=1e-3,
                    events=cross).t_events[0]
    te = np.array([t for t, _ in tr.events])
    assert te.size == ref.size >= 3
    assert np.max(np.abs(te - ref)) < 1e-6
