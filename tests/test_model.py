"""Model validation: every error case names the equation or variable at fault (issue 2, item 2)."""

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit.errors import ModelError
from daekit.model import parse_name


def pendulum(extra=None):
    m = dk.Model("pend")
    p = m.state("p", 2)
    v = m.state("v", 2)
    z = m.algebraic("z")
    m.equation(m.der(p) - v, name="kinematics")
    m.equation(m.der(v) - (ca.DM([0, -9.81]) - z * p), name="newton")
    m.equation(0.5 * (ca.dot(p, p) - 1), name="rod")
    return m, p, v, z


def test_undeclared_symbol_names_equation_and_symbol():
    m, p, v, z = pendulum()
    q = ca.SX.sym("q")
    with pytest.raises(dk.ModelError, match=r"equation 'bad' uses the symbol 'q'"):
        m.equation(p[0] - q, name="bad")


def test_der_of_non_variable():
    m, p, v, z = pendulum()
    with pytest.raises(dk.ModelError, match=r"derivative of an expression"):
        m.der(p[0] * p[1])
    with pytest.raises(dk.ModelError, match=r"'w' is not a variable of this model"):
        m.der(ca.SX.sym("w"))
    with pytest.raises(dk.ModelError, match=r"der\(\) takes a model variable"):
        m.der(3.0)
    par = m.parameter("L", 1.0)
    with pytest.raises(dk.ModelError, match=r"der\(L\) is the derivative of a parameter"):
        m.der(par)


def test_duplicate_names():
    m, p, v, z = pendulum()
    with pytest.raises(dk.ModelError, match=r"the name 'p' is declared twice"):
        m.state("p")
    with pytest.raises(dk.ModelError, match=r"equation name 'rod' is used twice"):
        m.equation(p[0], name="rod")


def test_derivative_of_algebraic_variable():
    m, p, v, z = pendulum()
    with pytest.raises(dk.ModelError, match=r"algebraic variable 'z' is used"):
        m.der(z)


def test_state_whose_derivative_never_appears():
    m = dk.Model("lazy")
    x = m.state("x")
    y = m.state("y")
    m.equation(m.der(x) + x, name="decay")
    m.equation(y - x, name="copy")
    with pytest.raises(dk.ModelError, match=r"state 'y' .* derivative never appears"):
        m.validate()


def test_no_equations():
    m = dk.Model("empty")
    m.state("x")
    with pytest.raises(dk.ModelError, match="has no equations"):
        dk.analyze(m)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_nonfinite_constants(bad):
    m = dk.Model("nan")
    x = m.state("x")
    with pytest.raises(dk.ModelError, match=r"equation 'decay' contains the constant"):
        m.equation(m.der(x) + bad * x, name="decay")
    with pytest.raises(dk.ModelError, match=r"parameter 'k' has a non-finite value"):
        m.parameter("k", bad)


def test_not_square_names_overdetermined_equations():
    m, p, v, z = pendulum()
    q = m.state("q")
    m.equation(m.der(q) + q, name="decay")
    m.equation(q - 1, name="pin")  # a second equation for q alone: 7 equations, 6 unknowns
    with pytest.raises(dk.StructuralError) as err:
        m.validate()
    e = err.value
    assert "Over-determined" in str(e) and "'pin'" in str(e)
    assert set(e.overdetermined_equations) == {"decay", "pin"}  # the pendulum is fine
    assert e.overdetermined_variables == ["q"]
    assert e.underdetermined_variables == []


def test_underdetermined_names_variables():
    m2 = dk.Model("under2")
    x = m2.state("x")
    y = m2.algebraic("y")
    w = m2.algebraic("w")
    m2.equation(m2.der(x) + x, name="decay")
    m2.equation(y + w - x, name="sum")
    with pytest.raises(dk.StructuralError) as err:
        m2.validate()
    assert set(err.value.underdetermined_variables) == {"y", "w"}
    assert err.value.underdetermined_equations == ["sum"]
    assert "Under-determined" in str(err.value) and "'y'" in str(err.value)


def test_structurally_singular_square_system():
    # square (3 x 3) but x appears in no equation that can be matched to it
    m = dk.Model("singular")
    x = m.state("x")
    y = m.algebraic("y")
    w = m.algebraic("w")
    m.equation(m.der(x) - y, name="a")
    m.equation(y - 1, name="b")
    m.equation(y**2 - 2, name="c")
    with pytest.raises(dk.StructuralError) as err:
        m.validate()
    assert set(err.value.overdetermined_equations) == {"b", "c"}
    assert "w" in err.value.underdetermined_variables
    del w


def test_vector_names_and_higher_derivatives():
    m = dk.Model("names")
    p = m.state("p", 2)
    d2 = m.der(p, 2)
    assert [d2[i].name() for i in range(2)] == ["der(p,2)[0]", "der(p,2)[1]"]
    assert ca.is_equal(m.der(m.der(p)), d2)
    assert m.der(p[1], 3).name() == "der(p,3)[1]"
    assert parse_name("der(p,2)[1]") == ("p", 2, 1)
    assert parse_name(" z ") == ("z", 0, None)
    with pytest.raises(dk.ModelError):
        parse_name("der(p")
    with pytest.raises(dk.ModelError, match="no variable 'q'"):
        m.resolve("q")
    with pytest.raises(dk.ModelError, match="out of range"):
        m.resolve("p[2]")


def test_sigma_matrix_from_sparsity():
    m, p, v, z = pendulum()
    inc = m.incidence()
    sigma = np.full((5, 5), -1)
    sigma[inc.rows, inc.cols] = inc.vals
    # unknowns p0 p1 v0 v1 z; equations kin0 kin1 newton0 newton1 rod
    expected = np.array([
        [1, -1, 0, -1, -1],
        [-1, 1, -1, 0, -1],
        [0, -1, 1, -1, 0],
        [-1, 0, -1, 1, 0],
        [0, 0, -1, -1, -1],
    ])
    assert np.array_equal(sigma, expected)


def test_non_models_and_lists():
    with pytest.raises(dk.ModelError, match="analyze needs a daekit.Model, got int"):
        dk.analyze(42)
    with pytest.raises(dk.ModelError, match="reduce_index needs a daekit.Model, got str"):
        dk.reduce_index("x")
    m = dk.Model("list")
    x = m.state("x", 2)
    m.equation([m.der(x[0]) + x[0], m.der(x[1]) - x[0]], name="pair")
    assert m.n_equations == 2
    with pytest.raises(dk.ModelError, match="a list must hold CasADi SX expressions or numbers"):
        m.equation([object()], name="bad")


def test_parameter_values_must_be_numbers():
    m = dk.Model("p")
    with pytest.raises(dk.ModelError, match=r"parameter 'k' needs a number .* got 'abc'"):
        m.parameter("k", "abc")
    with pytest.raises(dk.ModelError, match=r"parameter 'k' needs a number .* got None"):
        m.parameter("k", None)
    assert m.parameter("k", [1, 2]).numel() == 2


def test_structural_zeros_in_an_equation_are_rejected():
    m = dk.Model("sparse")
    x = m.state("x", 2)
    with pytest.raises(dk.ModelError, match=r"equation 'e': e\[1\], e\[2\] are identically zero"):
        m.equation(ca.diag(m.der(x) + x), name="e")  # 2x2 diagonal: entries 1, 2 are "0 = 0"
    with pytest.raises(dk.ModelError, match=r"equation 'f': f\[1\] is identically zero"):
        m.equation(ca.vertcat(m.der(x[0]), 0), name="f")
    m.equation(m.der(x) + x, name="e")
    assert m.n_equations == 2


def test_equation_without_unknowns_is_named():
    m = dk.Model("ctrl")
    x = m.state("x")
    u = m.control("u")
    m.equation(m.der(x) - x, name="a")
    m.equation(u - 1, name="b")
    with pytest.raises(dk.StructuralError) as err:
        m.validate()
    assert "the equations 'b' involve no unknowns" in str(err.value)
    assert "only the unknowns ," not in str(err.value)
    assert err.value.overdetermined_equations == ["b"]


def test_equations_written_with_double_equals_are_residuals():
    """``m.equation(lhs == rhs)`` means ``lhs - rhs == 0`` (CasADi's ``==`` alone is a 0/1
    comparison: evaluated as a residual it is 0 wherever lhs != rhs, and the planar pendulum
    written so was analysed as having solutions everywhere)."""
    m = dk.Model("pendulum")
    p = m.state("p", 2)
    v = m.state("v", 2)
    lam = m.algebraic("lam")
    m.equation(m.der(p) == v, name="kinematics")
    m.equation(m.der(v) == -lam * p - ca.vertcat(0, 9.81), name="newton")
    m.equation(ca.dot(p, p) == 1, name="rod")
    assert ca.is_equal(ca.simplify(m.residual[4] - (ca.dot(p, p) - 1)), ca.SX(0))
    a = dk.analyze(m)
    assert (a.index, a.dof) == (3, 2)
    x = m.state("x")
    with pytest.raises(ModelError, match=r"equation 'cap' is a comparison \(<= or >=\)"):
        m.equation(x <= 1, name="cap")
    with pytest.raises(ModelError, match=r"'both\[1\]' is a comparison \(< or >\)"):
        m.equation(ca.vertcat(x == 1, x < 2), name="both")


def test_a_long_vector_equation_with_double_equals():
    """Vectors beyond the 1024-element scan are probed; ``v == w`` compares every element."""
    m = dk.Model("long")
    x = m.state("x", 3000)
    m.equation(m.der(x) == -x, name="decay")
    assert ca.is_equal(m.residual[2999], m.der(x)[2999] + x[2999], 1)


def test_one_comparison_among_many_residuals_is_found():
    """A single comparison in a long vector (beyond any probe) is still read as one."""
    m = dk.Model("long")
    x = m.state("x", 2000)
    res = [m.der(x)[i] + x[i] for i in range(2000)]
    res[1357] = m.der(x)[1357] == -x[1357]
    m.equation(ca.vertcat(*res), name="decay")
    assert ca.is_equal(m.residual[1357], m.der(x)[1357] - (-x[1357]), 2)
    res[1357] = m.der(x)[1357] <= -x[1357]
    with pytest.raises(ModelError, match=r"'mixed\[1357\]' is a comparison"):
        m.equation(ca.vertcat(*res), name="mixed")


def test_der_of_a_whole_vector_is_its_elements_derivatives():
    """m.der of a whole vector (the fast path) is the vector of its elements' derivatives, of
    any order, and still refuses algebraic variables and parameters."""
    m = dk.Model("vec")
    x = m.state("x", 5)
    z = m.algebraic("z", 3)
    k = m.parameter("k", [1.0, 2.0])
    for order in (1, 2):
        whole = m.der(x, order)
        assert ca.is_equal(whole, ca.vertcat(*[m.der(x[i], order) for i in range(5)]))
    assert ca.is_equal(m.der(m.der(x)), m.der(x, 2))
    assert ca.is_equal(m.der(x[1:3]), m.der(x)[1:3])
    with pytest.raises(ModelError, match="algebraic variable 'z'"):
        m.der(z)
    with pytest.raises(ModelError, match="parameter"):
        m.der(k)
