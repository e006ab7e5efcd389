"""initialize on one system, many calls (issue 13): what is cached is right for every call.

The functions initialize builds are kept on the system and reused; the parameters are inputs
of them, so a later call with another rod length must give that length's consistent state.
Everything is checked against the 3D pendulum's exact consistency conditions: |p| = L,
p . v = 0, and the rod's second derivative, which gives the multiplier
z = m (|v|^2 - g p_3) / L^2 (from m a = -m g e_3 - z p and p . a + |v|^2 = 0).
"""

from __future__ import annotations

import copy
import dataclasses
import pickle

import numpy as np
import pytest

import daekit as dk


@pytest.fixture(scope="module")
def r():
    return dk.reduce_index(dk.examples.pendulum3d())


def exact_z(L, p, v, m=1.0, g=9.81):
    return m * (v @ v - g * p[2]) / L**2


@pytest.mark.parametrize("L,s", [(1.0, 1.0), (2.0, 0.5), (0.5, 3.0), (1.3, 0.0)])
def test_later_calls_use_their_own_parameters_and_values(r, L, s):
    """The same system (functions made on the first call) for several lengths and speeds:
    each result is the exact consistent state of its own length."""
    dk.initialize(r, fixed={"p": [0.6, 0.0, -0.8], "der(p)": [0.0, 1.0, 0.0]})  # warm
    p = np.array([0.6 * L, 0.0, -0.8 * L])
    v = np.array([0.0, s, 0.0])
    init = dk.initialize(r, fixed={"p": p, "der(p)": v}, params={"L": L})
    np.testing.assert_allclose(init["p"], p, rtol=0, atol=1e-15)
    np.testing.assert_allclose(init["v"], v, rtol=0, atol=1e-15)
    assert abs(init["p"] @ init["p"] - L**2) <= 1e-12 * L**2
    assert abs(init["p"] @ init["v"]) <= 1e-12
    assert init.z0[0] == pytest.approx(exact_z(L, p, v), rel=1e-12, abs=1e-12)
    # the rod and its derivative imply p[2] and der(p)[2] (given in that order)
    assert init.redundant == ["p[2]", "der(p)[2]"]
    assert init.dof == 4


def test_redundant_values_depend_on_the_values_not_only_the_names(r):
    """Same names, other values: at p = (L, 0, 0) the rod implies p[0] (and its derivative
    der(p)[0]) instead: d rod / dp = p has no p[2] component there. The analysis is made at
    each call's solution, never reused from the names."""
    a = dk.initialize(r, fixed={"p": [0.6, 0.0, -0.8], "der(p)": [0.0, 1.0, 0.0]})
    b = dk.initialize(r, fixed={"p": [1.0, 0.0, 0.0], "der(p)": [0.0, 1.0, 0.0]})
    assert a.redundant == ["p[2]", "der(p)[2]"]
    assert b.redundant == ["p[0]", "der(p)[0]"]
    assert b.z0[0] == pytest.approx(exact_z(1.0, np.array([1.0, 0, 0]), np.array([0, 1.0, 0])),
                                    rel=1e-12)


def test_guess_then_fixed_on_the_same_system(r):
    """Different sets of names on one system (each set's functions cached separately)."""
    g = dk.initialize(r, guess={"p": [0.5, 0.1, -0.9]})
    assert abs(g["p"] @ g["p"] - 1.0) <= 1e-12
    f = dk.initialize(r, fixed={"p[0]": 0.6, "p[1]": 0.0}, guess={"p[2]": -1.0})
    np.testing.assert_allclose(f["p"], [0.6, 0.0, -0.8], rtol=0, atol=1e-12)
    g2 = dk.initialize(r, guess={"p": [0.5, 0.1, -0.9]})
    np.testing.assert_array_equal(g2.x0, g.x0)  # the same call gives the same values


@pytest.mark.parametrize("g", [-2.0, -1.0, -0.9, -0.5, 0.5])
def test_positions_fixed_in_part_and_guessed_velocities_free(r, g):
    """p[0], p[1] fixed, p[2] only guessed, v not given (starts at 0): the consistent state
    nearest the guess is p = (0.6, 0, -0.8 sign(g)), v = 0 (the rod's derivative p . v = 0
    leaves v at its start). The curvature of p . v once made the step in v blow up (the
    reduced Hessian's rounding residue in directions no guess reaches was inverted)."""
    init = dk.initialize(r, fixed={"p[0]": 0.6, "p[1]": 0.0}, guess={"p[2]": g})
    np.testing.assert_allclose(init["p"], [0.6, 0.0, 0.8 * np.sign(g)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(init["v"], 0.0, rtol=0, atol=1e-12)
    assert init.z0[0] == pytest.approx(exact_z(1.0, init["p"], init["v"]), rel=1e-10)


def test_deferred_analysis_in_copies_and_pickles(r):
    """free / redundant / determined are made on first access, also through a copy, a
    pickle or dataclasses.replace, with the same result."""
    fixed = {"p": [0.6, 0.0, -0.8], "der(p)": [0.0, 1.0, 0.0]}
    ref = dk.initialize(r, fixed=fixed)
    want = (ref.redundant, ref.free, ref.dof, ref.dof_names, ref.determined, ref.notes)
    for make in (lambda i: pickle.loads(pickle.dumps(i)), copy.deepcopy, copy.copy,
                 lambda i: dataclasses.replace(i, t0=0.0)):
        other = make(dk.initialize(r, fixed=fixed))
        assert (other.redundant, other.free, other.dof, other.dof_names, other.determined,
                other.notes) == want
    assert want[0] == ["p[2]", "der(p)[2]"] and want[2] == 4
    # v = der(p) is fixed under its other name: determined, and no sign ambiguity noted
    assert want[4] == ["v[0]", "v[1]", "v[2]"] and want[5] == []
