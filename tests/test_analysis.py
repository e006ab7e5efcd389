"""analyze(), the easy test, the derivative-array index, explain() (issue 2, items 4-5)."""

import numpy as np
import pytest

import daekit as dk
from daekit.analysis import differential_index, numeric_rank


def test_pendulum3d_analysis_fields():
    a = dk.analyze(dk.examples.pendulum3d())
    assert (a.structural_index, a.index, a.dof, a.structurally_ok) == (3, 3, 4, True)
    assert a.equation_offsets["rod"] == 2
    assert a.equation_offsets["newton[1]"] == 0
    assert a.equation_offsets["kinematics[2]"] == 1
    assert a.variable_offsets["p[0]"] == 2 and a.variable_offsets["z"] == 0
    assert a.numeric is None  # structural result trusted


def test_easy_test_lecture_l1_l3_l5():
    e1 = dk.is_index1(dk.examples.l1())  # [dF/dx' dF/dz] = [[-1, 0], [z, x']]: full rank
    assert e1 and e1.rank == 2 and np.isfinite(e1.condition)
    e3 = dk.is_index1(dk.examples.l3())
    assert not e3 and e3.rank == 6 and e3.size == 7
    assert e3.deficient_equations == ["rod"]
    e5 = dk.is_index1(dk.examples.l5())  # x1' appears in both, x2 only algebraically: full rank
    assert bool(e5)


def test_easy_test_condition_number_of_l1():
    # L1 at x' = 1, z = -1: the Jacobian [[-1, 0], [z, x']] = [[-1, 0], [-1, 1]]
    e = dk.is_index1(dk.examples.l1(), point={"der(x)": 1.0, "z": -1.0, "x": 0.0})
    assert e.condition == pytest.approx(np.linalg.cond(np.array([[-1.0, 0.0], [-1.0, 1.0]])), rel=0.05)
    # where x' = 0 the test fails (the lecture: "easy where x' != 0")
    e0 = dk.is_index1(dk.examples.l1(), point={"der(x)": 0.0, "z": -1.0, "x": -1.0})
    assert not e0


def test_structural_failure_numeric_index_f1_f2_f3():
    for factory, true_index in ((dk.examples.gear_petzold, 2), (dk.examples.f2, 3),
                                (dk.examples.f3, 2)):
        a = dk.analyze(factory())
        assert not a.structurally_ok
        assert a.structural_index == 1
        assert a.index == true_index and a.dof == 0
        text = a.explain()
        assert "NUMERICALLY" in text and "structural analysis FAILS" in text


def test_derivative_array_on_known_cases():
    # pendulum (first order): index 3, DOF 2 from the derivative array alone
    r = differential_index(dk.examples.pendulum_planar())
    assert (r.index, r.dof) == (3, 2)
    assert differential_index(dk.examples.l6()).index == 2
    assert differential_index(dk.examples.jay()).index == 2
    assert differential_index(dk.examples.chemakzo()).index == 1


def test_numeric_rank_tolerance_is_scaled():
    a = np.diag([1e8, 1.0, 1e-8])  # equilibration makes this well conditioned
    assert numeric_rank(a)[0] == 3
    b = np.array([[1.0, 2.0], [2.0, 4.0 + 1e-15]])
    assert numeric_rank(b)[0] == 1


def test_explain_pendulum_mentions_the_story():
    text = dk.analyze(dk.examples.pendulum3d()).explain()
    assert "Differential index 3" in text
    assert "rod must be differentiated twice" in text
    assert "rank 6 < 7" in text and "rod" in text
    assert "Degrees of freedom: 4" in text
    assert "Consistency conditions (must hold at the initial time): rod, d/dt rod." in text


def test_ode_has_index_zero_and_explains_it():
    m = dk.Model("decay")
    x = m.state("x", 2)
    m.equation(m.der(x) + x, name="decay")
    a = dk.analyze(m)
    assert (a.index, a.dof, a.structurally_ok) == (0, 2, True)
    assert "ODE (index 0)" in a.explain()


def test_point_is_used_for_the_system_jacobian():
    # L6: 0 = (x1^2 + x2^2 - 1)/2 differentiated gives x1 x2 + x2 z ... singular where x2 = 0
    m = dk.examples.l6()
    assert dk.analyze(m).structurally_ok
    assert not dk.analyze(m, point={"x2": 0.0}).structurally_ok


def test_analysis_to_dict_keys():
    d = dk.analyze(dk.examples.l2()).to_dict()
    for key in ("structural_index", "index", "dof", "structurally_ok", "equation_offsets",
                "variable_offsets"):
        assert key in d
    assert d["index"] == 3


def test_analyze_rejects_a_structurally_singular_model():
    m = dk.Model("bad")
    x = m.state("x")
    m.algebraic("y")
    m.equation(m.der(x) - x, name="a")
    m.equation(m.der(x) + 2 * x, name="b")
    with pytest.raises(dk.StructuralError, match="'y'"):
        dk.analyze(m)


def test_input_derivatives_are_reported_for_l2():
    a = dk.analyze(dk.examples.l2())
    assert a.input_derivatives == {"u": 2}  # x1 = u', z = u''
    assert "der(u,2)" in a.explain()
    assert dk.analyze(dk.examples.pendulum3d()).input_derivatives == {}  # u enters undifferentiated
    assert int(differential_index(dk.examples.l2())) == 3


def test_explicit_definitions_match_the_reduction():
    m = dk.examples.pendulum3d()
    a = dk.analyze(m)
    assert a.definitions == ["kinematics[0]", "kinematics[1]", "kinematics[2]"]
    assert dk.reduce_index(m).invariant_names == ["rod", "d/dt rod"]
