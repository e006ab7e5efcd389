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


# ----------------------------------------------------------------------------------------------
# the plan of a call's names (made once per system and set of fixed and guessed names)
CASES = [
    ({"p": [0.6, 0.0, -0.8], "der(p)": [0.0, 1.0, 0.0]}, None),  # every state: no step
    ({"der(p)": [0.0, 1.0, 0.0], "p": [0.6, 0.0, -0.8]}, None),  # the same, other order
    ({"p[0]": 0.6, "p[1]": 0.0}, {"p[2]": -1.0, "der(p)": [0.0, 1.0, 0.1]}),  # Newton steps
    ({"p": [0.6, 0.0, -0.8], "v[1]": 1.0, "der(p)[1]": 1.0}, None),  # one quantity, two names
    (None, {"p": [0.5, 0.1, -0.9]}),
]


@pytest.mark.parametrize("fixed,guess", CASES)
def test_a_kept_plan_gives_what_a_new_one_gives(r, fixed, guess):
    """A later call with the same names takes the plan the first made (with other values: a
    rod of length 2, the positions doubled); a copy of the system (no caches) makes
    everything anew: the same values to the last bit, and both meet the exact conditions."""

    def doubled(d):
        return None if d is None else {k: 2 * np.asarray(v) if k.startswith("p") else v
                                       for k, v in d.items()}

    first = dk.initialize(r, fixed=doubled(fixed), guess=doubled(guess), params={"L": 2.0})
    assert abs(first["p"] @ first["p"] - 4.0) <= 1e-12  # (makes the plan)
    warm = dk.initialize(r, fixed=fixed, guess=guess)
    cold = dk.initialize(copy.copy(r), fixed=fixed, guess=guess)
    np.testing.assert_array_equal(warm.x0, cold.x0)
    np.testing.assert_array_equal(warm.z0, cold.z0)
    assert warm.values == cold.values
    assert (warm.fixed, warm.redundant, warm.free, warm.dof, warm.iterations) == \
        (cold.fixed, cold.redundant, cold.free, cold.dof, cold.iterations)
    p, v = warm["p"], warm["v"]
    assert abs(p @ p - 1.0) <= 1e-12 and abs(p @ v) <= 1e-12
    assert warm.z0[0] == pytest.approx(exact_z(1.0, p, v), rel=1e-10)
    for k, val in (fixed or {}).items():  # fixed values held exactly
        np.testing.assert_array_equal(warm[k], val)


def test_other_names_other_plan(r):
    """Alternating sets of names on one system: each call is right for its own names (the
    fixed order is the call's, also for the same names in another order: with v fixed first,
    p . v = 0 implies p[1])."""
    a = {"p": [0.6, 0.0, -0.8], "der(p)": [0.0, 1.0, 0.0]}
    b = {"der(p)": [0.0, 1.0, 0.0], "p": [0.6, 0.0, -0.8]}
    for _ in range(2):
        ia = dk.initialize(r, fixed=a)
        ib = dk.initialize(r, fixed=b)
        ic = dk.initialize(r, fixed={"p[0]": 0.8, "p[1]": 0.0}, guess={"p[2]": 0.5})
        assert ia.fixed[:3] == ["p[0]", "p[1]", "p[2]"]
        assert ib.fixed[:3] == ["der(p)[0]", "der(p)[1]", "der(p)[2]"]
        assert ia.redundant == ["p[2]", "der(p)[2]"] and ib.redundant == ["p[1]", "p[2]"]
        np.testing.assert_array_equal(ia.x0, ib.x0)
        np.testing.assert_allclose(ic["p"], [0.8, 0.0, 0.6], rtol=0, atol=1e-12)


def test_a_kept_plan_still_finds_contradictions(r):
    """Names seen before, values that contradict the rod or each other: the same errors,
    naming the culprits, as on a first call."""
    fixed = {"p": [0.6, 0.0, -0.8], "der(p)": [0.0, 1.0, 0.0]}
    dk.initialize(r, fixed=fixed)
    with pytest.raises(dk.InitializationError, match=r"p\[0\] = 1.*\['rod'\]"):
        dk.initialize(r, fixed={"p": [1.0, 0.0, -0.8], "der(p)": [0.0, 1.0, 0.0]})
    two = {"p": [0.6, 0.0, -0.8], "v[1]": 1.0, "der(p)[1]": 1.0}
    dk.initialize(r, fixed=two)
    with pytest.raises(dk.InitializationError,
                       match=r"v\[1\] = 1 and der\(p\)\[1\] = 2 contradict each other"):
        dk.initialize(r, fixed={**two, "der(p)[1]": 2.0})
    with pytest.raises(dk.InitializationError, match=r"'p' has 3 elements .* 2 values"):
        dk.initialize(r, fixed={"p": [0.6, 0.0], "der(p)": [0.0, 1.0, 0.0]})
    with pytest.raises(dk.InitializationError, match=r"value of 'der\(p\)' is not finite"):
        dk.initialize(r, fixed={"p": [0.6, 0.0, -0.8], "der(p)": [0.0, np.nan, 0.0]})
    # and the plan is still right afterwards
    ok = dk.initialize(r, fixed=fixed)
    np.testing.assert_array_equal(ok["p"], fixed["p"])
