"""Gauss--Newton's convergence test (daekit.points.gauss_newton): multiple roots, rounding in
rows whose terms cancel, and stationary points of the residual that are not solutions."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from daekit.points import POINT_DIST, gauss_newton


def _power(m: int, root: float):
    """h(x) = (x - root)^m: a root of multiplicity m (the residual is 1/m of the row's terms
    at x = 0 for root 0, at every iterate)."""
    return lambda w: (np.array([(w[0] - root) ** m]),
                      sp.csr_matrix([[m * (w[0] - root) ** (m - 1)]]))


@pytest.mark.parametrize("m", [2, 3])
@pytest.mark.parametrize("root", [0.0, 1.0])
def test_multiple_roots_converge(m, root):
    # x**2 and x**3 from 0.5: Newton converges linearly with rate (m - 1) / m; the per-row
    # residual test alone never held (x**2: 60 iterations, consistent False)
    w, st = gauss_newton(_power(m, root), np.array([root + 0.5]))
    assert st.consistent and st.distance is not None and st.distance <= POINT_DIST
    assert abs(w[0] - root) <= 1e-7 * (1 + abs(root))
    assert st.iterations < 60


def test_simple_roots_by_the_residual_test():
    # a simple root converges quadratically, and the residual test (not the distance) accepts
    fun = lambda w: (np.array([w[0] ** 2 - 2.0]), sp.csr_matrix([[2 * w[0]]]))  # noqa: E731
    w, st = gauss_newton(fun, np.array([1.0]))
    assert st.consistent and st.distance is None
    assert abs(w[0] - np.sqrt(2.0)) < 1e-14


def test_a_stationary_point_is_not_a_solution():
    # h = (x, x - 1) has no zero; Gauss-Newton stops at x = 1/2 with tiny (zero) steps, but
    # the step does not remove the residual there: not consistent
    fun = lambda w: (np.array([w[0], w[0] - 1.0]),  # noqa: E731
                     sp.csr_matrix(np.array([[1.0], [1.0]])))
    w, st = gauss_newton(fun, np.array([3.0]))
    assert not st.consistent
    assert abs(w[0] - 0.5) < 1e-12


def test_no_real_root_is_not_accepted():
    # x**2 + 1: the steps do not shrink (the iterates wander), so no distance is predicted
    fun = lambda w: (np.array([w[0] ** 2 + 1.0]), sp.csr_matrix([[2 * w[0]]]))  # noqa: E731
    _, st = gauss_newton(fun, np.array([0.7]))
    assert not st.consistent


def test_distance_criterion_is_relative_per_unknown():
    # a double root far from zero in one unknown and a simple one in the other, in very
    # different units: both found to the relative distance
    s = 1e6

    def fun(w):
        h = np.array([(w[0] / s - 3.0) ** 2, w[1] * 1e-6 - 2e-6])
        J = sp.csr_matrix(np.array([[2 * (w[0] / s - 3.0) / s, 0.0], [0.0, 1e-6]]))
        return h, J

    w, st = gauss_newton(fun, np.array([3.5 * s, 5.0]))
    assert st.consistent
    assert abs(w[0] / s - 3.0) <= 1e-7 and abs(w[1] - 2.0) < 1e-10


@pytest.mark.parametrize("k", [1e-9, 1e-6, 1.0, 1e6, 1e9])
def test_multiple_root_in_any_unit(k):
    # (x - 1)^2 with x = k y: the same problem in another unit of the unknown; accepted only
    # where y is within the distance of its root 1 / k, relative to y (an absolute floor of 1
    # in the equilibrated units accepted y 1.2e-4 off its root for k = 1e9)
    fun = lambda w: (np.array([(k * w[0] - 1.0) ** 2]),  # noqa: E731
                     sp.csr_matrix([[2 * k * (k * w[0] - 1.0)]]))
    w, st = gauss_newton(fun, np.array([1.5 / k]))
    assert st.consistent
    assert abs(k * w[0] - 1.0) <= 10 * POINT_DIST


@pytest.mark.parametrize("k", [1e-6, 1e-3, 1.0, 1e3, 1e6])
def test_no_real_root_in_any_unit(k):
    # x^2 + 1e-14 has no real root: refused in every unit of x = k y (it was accepted for
    # k = 1e3 and 1e6, with 1000 times the least residual left)
    fun = lambda w: (np.array([(k * w[0]) ** 2 + 1e-14]),  # noqa: E731
                     sp.csr_matrix([[2 * k * k * w[0]]]))
    _, st = gauss_newton(fun, np.array([1.0 / k]))
    assert not st.consistent
