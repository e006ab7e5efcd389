"""Consistent initialization: invariants and alg hold, fixed values exactly, conflicts named."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit.errors import InitializationError
from daekit.initialize import initialize
from daekit.reduced import ReducedDAE


def hand_pendulum3d(m=1.0, L=1.0, g=9.81):
    """Lecture L3 in index-1 form by hand: x = (p, v), z = (a, lambda)."""
    t = ca.SX.sym("t")
    p, v, a = ca.SX.sym("p", 3), ca.SX.sym("v", 3), ca.SX.sym("a", 3)
    lam = ca.SX.sym("z")
    u = ca.SX.sym("u", 3)
    e3 = ca.DM([0, 0, 1])
    alg = ca.vertcat(m * a - (u - m * g * e3 - lam * p), ca.dot(p, a) + ca.dot(v, v))
    inv = ca.vertcat((ca.dot(p, p) - L**2) / 2, ca.dot(p, v))
    names = {f"p[{i}]": p[i] for i in range(3)}
    names.update({f"v[{i}]": v[i] for i in range(3)})
    names.update({f"der(p)[{i}]": v[i] for i in range(3)})
    names.update({f"der(v)[{i}]": a[i] for i in range(3)})
    names["z"] = lam
    names.update({f"u[{i}]": u[i] for i in range(3)})
    return ReducedDAE(
        t, ca.vertcat(p, v), ca.vertcat(a, lam), u, ca.SX(0, 1), ca.vertcat(v, a), alg, inv,
        ["rod", "d/dt rod"], [f"p[{i}]" for i in range(3)] + [f"v[{i}]" for i in range(3)],
        [f"der(v)[{i}]" for i in range(3)] + ["z"], [f"u[{i}]" for i in range(3)], [],
        np.zeros(0), names, control_names=["u"],
    )


def test_pendulum_consistent_and_fixed_exact():
    r = hand_pendulum3d()
    init = initialize(r, guess={"p": [0.9, 0.1, -0.3], "v": [0, 1, 0]}, fixed={"p[0]": 0.6})
    p, v = init["p"], init["v"]
    assert init["p[0]"] == 0.6
    assert abs(p @ p - 1) < 1e-12 and abs(p @ v) < 1e-12
    # lambda from the index-1 equations: z = (v.v - g p3) (m = L = 1, u = 0)
    assert abs(init["z"] - (v @ v - 9.81 * p[2])) < 1e-10
    assert init.dof == 4 and len(init.free) == 4
    assert init.residual < 1e-12


def test_guess_is_a_least_squares_pull():
    r = hand_pendulum3d()
    # the guess (2, 0, 0) is off the sphere; the nearest point is (1, 0, 0)
    init = initialize(r, guess={"p": [2.0, 0.0, 0.0], "v": [0.0, 0.0, 0.0]})
    assert np.allclose(init["p"], [1, 0, 0], atol=1e-10)
    assert np.allclose(init["v"], 0, atol=1e-12)


def test_consistent_redundant_fixed_values_accepted():
    r = hand_pendulum3d()
    init = initialize(r, fixed={"p": [0.6, 0.0, -0.8], "v": [0.8, 0.0, 0.6]})
    assert np.allclose(init.x0, [0.6, 0, -0.8, 0.8, 0, 0.6])
    assert len(init.redundant) == 2  # rod and d/dt rod make two of the six values implied


def test_contradicting_fixed_values_are_named():
    r = hand_pendulum3d()
    with pytest.raises(InitializationError) as exc:
        initialize(r, fixed={"p": [0.6, 0.0, -0.7]})
    msg = str(exc.value)
    assert "p[0]" in msg and "p[2]" in msg and "rod" in msg
    with pytest.raises(InitializationError) as exc:
        initialize(r, guess={"p": [1, 0, 0]}, fixed={"v[0]": 1.0, "der(p)[0]": 2.0})
    assert "v[0]" in str(exc.value) and "der(p)[0]" in str(exc.value)


def test_unknown_name_and_bad_size():
    r = hand_pendulum3d()
    with pytest.raises(InitializationError, match="q"):
        initialize(r, fixed={"q": 1.0})
    with pytest.raises(InitializationError, match="3 element"):
        initialize(r, fixed={"p": [1.0, 0.0]})


def test_inputs_enter_algebraic_values():
    r = hand_pendulum3d()
    init = initialize(r, fixed={"p": [0.0, 0.0, -1.0], "v": [0, 0, 0]}, inputs={"u": [0, 0, 2]})
    # hanging at rest, m = 1: lambda p3 balances u3 - g: z = g - u3 ... with p3 = -1:
    # a = u - g e3 - z p = 0 -> z = -(u3 - g) / p3 = u3 - g ... sign: -z*(-1) = g - u3
    assert abs(init["z"] - (9.81 - 2.0)) < 1e-10


def test_initialize_reduced_index3_model():
    pytest.importorskip("daekit.reduction")
    from daekit.reduction import reduce_index

    r = reduce_index(dk.examples.pendulum_planar())
    init = initialize(r, guess={"x": 1.0, "y": 0.0}, fixed={"der(x)": 0.0, "der(y)": 0.0})
    assert init["x"] == pytest.approx(1.0, abs=1e-12)
    assert abs(init["T"]) < 1e-10  # horizontal, at rest: no rod force
    assert init["der(y,2)"] == pytest.approx(-9.81, abs=1e-10)
    assert init.dof == 2
