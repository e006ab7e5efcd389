"""Conditions written with CasADi's comparison operators, where a user writes them naturally:
``m.equation(lhs == rhs)``, ``m.event(x <= 0.25)``, ``ocp.constrain(u <= 0.8)``. CasADi's
``==``, ``<=`` build 0/1 expressions; daekit reads them as residuals, event functions and
bounds, and refuses them where they mean nothing (an objective, an inequality "equation").
Exact references: exponential decay and linear motion (event times in closed form), and an
OCP whose path constraint is active everywhere (J in closed form)."""

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit.errors import ModelError, OCPError


def decay_model() -> tuple[dk.Model, ca.SX]:
    m = dk.Model("decay")
    x = m.state("x")
    m.equation(m.der(x) == -x, name="decay")  # the residual der(x) + x
    return m, x


@pytest.mark.parametrize("condition, t_exact", [
    (lambda x: x <= 0.25, np.log(4.0)),  # falling through 0.25: t = ln 4
    (lambda x: 0.5 >= x, np.log(2.0)),   # the same written the other way round
    (lambda x: x == 0.125, np.log(8.0)),  # crossing either way
])
def test_event_conditions_fire_when_they_become_true(condition, t_exact):
    m, x = decay_model()
    m.event(condition(x), name="reached", terminal=True)
    r = dk.reduce_index(m)
    tr = dk.simulate(r, np.linspace(0, 3, 31), dk.initialize(r, fixed={"x": 1.0}),
                     rtol=1e-10, atol=1e-10)
    assert [n for _, n in tr.events] == ["reached"]
    assert abs(tr.t[-1] - t_exact) < 1e-8


def test_a_condition_that_is_true_from_the_start_fires_only_when_it_becomes_true_again():
    """``x >= 0.5`` on a rising x from 0: fires at t = 0.5; the falling condition ``x <= 2``,
    true from the start, never fires (it becomes true only by a falling crossing)."""
    m = dk.Model("ramp")
    x = m.state("x")
    m.equation(m.der(x) == 1, name="ramp")
    m.event(x <= 2.0, name="below_two")
    m.event(x >= 0.5, name="half", terminal=True)
    r = dk.reduce_index(m)
    tr = dk.simulate(r, np.linspace(0, 1, 11), dk.initialize(r, fixed={"x": 0.0}),
                     rtol=1e-10, atol=1e-10)
    assert [n for _, n in tr.events] == ["half"]
    assert abs(tr.t[-1] - 0.5) < 1e-9


def test_event_conditions_that_mean_nothing_are_named():
    m, x = decay_model()
    with pytest.raises(ModelError, match=r"event 'up'.*direction=1 contradicts it"):
        m.event(x <= 0.25, name="up", direction=1)
    with pytest.raises(ModelError, match=r"event 'both'.*direction=0 contradicts it"):
        m.event(x <= 0.25, name="both", direction=0)
    with pytest.raises(ModelError, match=r"event 'ne': the condition '!=' is not an event"):
        m.event(x != 0.25, name="ne")


def path_ocp(constrain):
    """min int_0^1 (u - 1)^2 dt, x' = u, x(0) = 0, with u <= 0.8 as a path constraint: the
    bound is active everywhere, u = 0.8, J = 0.04 and x(1) = 0.8 exactly."""
    m = dk.Model("push")
    x = m.state("x")
    u = m.control("u")
    m.equation(m.der(x) == u, name="move")
    ocp = dk.OCP(m, t_final=1.0, intervals=10, degree=2)
    ocp.minimize(integral=(u - 1) ** 2)
    ocp.initial({"x": 0.0})
    constrain(ocp, u)
    return ocp


@pytest.mark.parametrize("constrain", [
    lambda ocp, u: ocp.constrain(u <= 0.8),
    lambda ocp, u: ocp.constrain(0.8 >= u),
    lambda ocp, u: ocp.constrain(u - 0.8 <= 0),
    lambda ocp, u: ocp.constrain(u, ub=0.8),  # the bounds form, for comparison
])
def test_path_conditions_are_bounds(constrain):
    sol = path_ocp(constrain).solve()
    assert sol.success
    assert abs(sol.objective - 0.04) < 1e-7
    assert abs(sol["x"][-1] - 0.8) < 1e-7


def test_conditions_where_they_mean_nothing_are_refused():
    m = dk.Model("push")
    x = m.state("x")
    u = m.control("u")
    m.equation(m.der(x) == u, name="move")
    with pytest.raises(ModelError, match=r"equation 'cap' is a comparison \(<= or >=\)"):
        m.equation(x <= 1, name="cap")
    ocp = dk.OCP(m, t_final=1.0, intervals=5)
    with pytest.raises(OCPError, match=r"integral objective is a comparison, whose value is 0 or 1"):
        ocp.minimize(integral=u <= 1)
    with pytest.raises(OCPError, match=r"either a condition .* or an expression with bounds"):
        ocp.constrain(u <= 1, -1.0, 1.0)
    with pytest.raises(OCPError, match=r"element 1 is no comparison"):
        ocp.constrain(ca.vertcat(u <= 1, x))
