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


# ----------------------------------------------------------------------------- review fixes
def chain_with_f1(n_links, coupling=0.0):
    """planar_chain(N) (index 3, DOF 2N) plus Gear and Petzold's F1 pair with eta = -2
    (index 2, DOF 0; reference-problems.md): independent DAEs, so index 3 and DOF 2N. With
    ``coupling`` != 0 the chain's q[0] enters F1's forcing: then both are one connected part,
    still index 3 and DOF 2N (F1 only needs q, never its derivative)."""
    import casadi as ca

    m = dk.examples.planar_chain(n_links)
    y, z, t = m.state("y"), m.state("z"), m.t
    q = m.variables["q"].sym
    m.equation(m.der(y) - 2 * t * m.der(z) - z - ca.cos(t) + coupling * q[0], name="dynamic")
    m.equation(y - 2 * t * z - ca.sin(t), name="constraint")
    return m


def test_partial_structural_failure_is_analyzed_numerically_only_where_needed():
    a = dk.analyze(chain_with_f1(2))
    assert not a.structurally_ok
    assert (a.structural_index, a.structural_dof) == (3, 5)
    assert (a.index, a.dof) == (3, 4)
    assert a.singular_blocks == [["dynamic", "constraint"]]
    assert a.numeric.equations == ["dynamic", "constraint"]
    assert (a.numeric.index, a.numeric.dof) == (2, 0)  # F1 alone
    assert a.structural_part == (3, 4)  # the chain alone
    text = a.explain()
    assert "structural analysis FAILS" in text.replace("Structural", "structural")
    assert "equations dynamic, constraint" in text
    assert "index 3 (right)" in text and "5 degrees of freedom (wrong: the true number is 4)" in text
    assert "both are wrong" not in text


def test_partial_failure_scales_to_big_models():
    a = dk.analyze(chain_with_f1(400))  # 2002 equations; the whole derivative array took 383 s
    assert (a.index, a.dof, a.structurally_ok) == (3, 800, False)


def test_numeric_part_can_raise_the_index():
    # F2 (index 3, DOF 0) next to an ODE x' = -x (index 0, DOF 1): index 3, DOF 1
    import casadi as ca

    m = dk.Model("f2_and_decay")
    x, y, w = m.state("x"), m.algebraic("y"), m.state("w")
    m.equation(-m.der(x, 2) - y - ca.sin(m.t), name="forced")
    m.equation(m.der(x, 2) + x + y - m.t, name="spring")
    m.equation(m.der(w) + w, name="decay")
    a = dk.analyze(m)
    assert (a.index, a.dof) == (3, 1)
    assert a.structural_part == (0, 1)
    assert (a.structural_index, a.structural_dof) == (1, 3)
    assert "index 1 (wrong: the true index is 3)" in a.explain()


def test_coupled_failure_small_is_exact_and_big_raises_quickly():
    a = dk.analyze(chain_with_f1(3, coupling=0.1))  # one connected part: all numeric
    assert a.structural_part is None and len(a.numeric.equations) == 17
    assert (a.index, a.dof) == (3, 6)
    with pytest.raises(dk.ModelError, match=r"fails in the equations 'dynamic', 'constraint'.*"
                                            r"1002 equations.*point="):
        dk.analyze(chain_with_f1(200, coupling=0.1))


def domain_model(root="x - 1"):
    import casadi as ca

    m = dk.Model("dom")
    x, z = m.state("x"), m.algebraic("z")
    m.equation(m.der(x) + z, name="a")
    m.equation(z * ca.sqrt(eval(root, {"x": x})) - 1, name="b")
    return m


def test_points_outside_the_domain_are_retried_then_named():
    m = domain_model()  # undefined at the first draws (x in [0.1, 0.3]): index 1, DOF 1
    a = dk.analyze(m)
    assert (a.index, a.dof, a.structurally_ok) == (1, 1, True)
    assert dk.is_index1(m) and differential_index(m).index == 1
    for call in (dk.analyze, dk.is_index1, differential_index):
        with pytest.raises(dk.ModelError, match=r"equation\(s\) 'b' is not finite.*point="):
            call(domain_model("-x**2 - 1"))  # nowhere defined
        with pytest.raises(dk.ModelError, match=r"'b' is not finite"):
            call(m, point={"x": 0.5})  # the user's value is kept


def test_bad_points_are_named():
    m = dk.examples.pendulum3d()
    with pytest.raises(dk.ModelError, match=r"point\['p'\] has 2 values, but 'p' has 3"):
        dk.analyze(m, point={"p": [1, 2]})
    with pytest.raises(dk.ModelError, match=r"point\['p'\] = 'abc' is not numeric.*3 numbers"):
        dk.analyze(m, point={"p": "abc"})
    with pytest.raises(dk.ModelError, match=r"point\['p'\] has 2 values"):
        dk.is_index1(m, point={"p": [1, 0]})
    with pytest.raises(dk.ModelError, match=r"point must be a dict"):
        dk.analyze(m, point=[1, 2])


def test_definitions_are_the_reductions_eliminations():
    m = dk.Model("cyclic")
    p, q, v, w = (m.state(s) for s in "pqvw")
    lam = m.algebraic("l")
    m.equation(m.der(p) - m.der(q) - v, name="A")
    m.equation(m.der(p) + m.der(q) - w, name="B")
    m.equation(m.der(v) + lam * (p - q), name="C")
    m.equation(m.der(w) + lam * (p + q) + 9.81, name="D")
    m.equation(p**2 + q**2 - 1, name="rod")
    a = dk.analyze(m)
    r = dk.reduce_index(m)
    assert r.invariant_names == ["A", "B", "rod", "d/dt rod"]  # the cyclic definitions stay
    assert a.definitions == [e["equation"] for e in r.eliminated] == []
    text = a.explain()
    assert "Consistency conditions (must hold at the initial time): A, B, rod, d/dt rod." in text
    assert "by construction" not in text
    m3 = dk.examples.pendulum3d()
    assert dk.analyze(m3).definitions == [e["equation"] for e in dk.reduce_index(m3).eliminated]


def test_easy_test_blockwise_rank_above_the_dense_limit():
    # K copies of F2: leading Jacobian w.r.t. (x'', y) is blockdiag([[-1, -1], [1, 1]]): rank K,
    # every equation in the left null space (1, 1) of its block
    import casadi as ca

    for k, dense in ((10, True), (70, False)):
        m = dk.Model("oki_many")
        x, y = m.state("x", k), m.algebraic("y", k)
        m.equation(-m.der(x, 2) - y - ca.sin(m.t), name="forced")
        m.equation(m.der(x, 2) + x + y - m.t, name="spring")
        assert (m.n_equations <= 120) == dense
        e = dk.is_index1(m)
        assert (e.rank, e.size, bool(e)) == (k, 2 * k, False)
        assert sorted(e.deficient_equations) == sorted(m.equation_names)


def coupled_zero(k, with_c=False):
    m = dk.Model("coupled_zero")
    x, w = m.state("x", k), m.state("w")
    a, b = m.algebraic("a"), m.algebraic("b")
    c = m.algebraic("c") if with_c else 0
    m.equation(m.der(x) + x, name="ode")
    m.equation(m.der(w) + w, name="wdyn")
    m.equation(w * a + c - 1, name="e1")
    m.equation(a + w * b, name="e2")
    if with_c:
        m.equation(c - x[0], name="e3")
    return m


def test_easy_test_rank_is_exact_when_singular_blocks_couple():
    # Leading Jacobian w.r.t. (a, b) at w = 0: [[w, 0], [1, w]] = [[0, 0], [1, 0]]: two
    # singular 1x1 blocks of the BLT form, but rank 1 (not 0); left null vector (1, 0): e1.
    for k in (10, 130):  # dense path and blockwise path (more than 120 equations)
        e = dk.is_index1(coupled_zero(k), point={"w": 0.0})
        assert (e.rank, e.size) == (k + 2, k + 3)
        assert e.deficient_equations == ["e1"]
        # e1 also uses c, which the nonsingular block e3 determines: null vector e1 - e3
        e = dk.is_index1(coupled_zero(k, with_c=True), point={"w": 0.0})
        assert (e.rank, e.size) == (k + 3, k + 4)
        assert sorted(e.deficient_equations) == ["e1", "e3"]
