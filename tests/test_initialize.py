"""Consistent initialization: invariants and alg hold, fixed values exactly, conflicts named."""

from __future__ import annotations

import importlib

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

import daekit as dk
from daekit.errors import InitializationError, ModelError
from daekit.examples.exact import planar_chain_hanging, planar_chain_rotating
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
    assert init.dof == 4 and len(init.dof_names) == 4 and init.fixed == ["p[0]"]
    assert len(init.free) == 3 and "p[0]" not in init.free  # the free values: not the fixed
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
    from daekit.reduction import reduce_index

    r = reduce_index(dk.examples.pendulum_planar())
    init = initialize(r, guess={"x": 1.0, "y": 0.0}, fixed={"der(x)": 0.0, "der(y)": 0.0})
    assert init["x"] == pytest.approx(1.0, abs=1e-12)
    assert abs(init["T"]) < 1e-10  # horizontal, at rest: no rod force
    assert init["der(y,2)"] == pytest.approx(-9.81, abs=1e-10)
    assert init.dof == 2


# --- sparse path (big systems) -----------------------------------------------------------------

INIT = importlib.import_module("daekit.initialize")  # the module (daekit.initialize is the function)


@pytest.fixture(params=["dense", "sparse"])
def path(request, monkeypatch):
    """Run a test on the dense SVD path and on the sparse SuperLU path."""
    monkeypatch.setattr(INIT, "_SPARSE_MIN_UNKNOWNS", 10**9 if request.param == "dense" else 0)
    return request.param


def _force(monkeypatch, which: str) -> None:
    monkeypatch.setattr(INIT, "_SPARSE_MIN_UNKNOWNS", 10**9 if which == "dense" else 0)


def _chain_state(N: int, seed: int = 0):
    """A consistent state of planar_chain(N) from random link angles and angular rates."""
    rng = np.random.default_rng(seed)
    th, om = rng.uniform(-1.0, 1.0, N), rng.uniform(-1.0, 1.0, N)
    d = np.column_stack([np.sin(th), -np.cos(th)])
    dd = om[:, None] * np.column_stack([np.cos(th), np.sin(th)])
    return np.cumsum(d, axis=0).ravel(), np.cumsum(dd, axis=0).ravel(), rng


@pytest.fixture(scope="module")
def chain60():
    from daekit.reduction import reduce_index

    return reduce_index(dk.examples.planar_chain(60))


def test_pendulum_cases_same_on_both_paths(monkeypatch):
    """Values, free states, redundant values and error messages agree on the two paths."""
    r = hand_pendulum3d()
    cases = [
        dict(guess={"p": [0.9, 0.1, -0.3], "v": [0, 1, 0]}, fixed={"p[0]": 0.6}),
        dict(fixed={"p": [0.6, 0.0, -0.8], "v": [0.8, 0.0, 0.6]}),
        dict(fixed={"p": [0.6, 0.0, -0.7]}),
        dict(fixed={"p": [0.6, 0.0, -0.8], "v": [0.8, 0.0, 0.7]}),
        dict(guess={"p": [0, 0, 0]}),
    ]
    out = {}
    for which in ("dense", "sparse"):
        _force(monkeypatch, which)
        res = []
        for c in cases:
            try:
                i = initialize(r, **c)
                res.append((np.r_[i.x0, i.z0], sorted(i.free), i.redundant))
            except InitializationError as exc:
                res.append(str(exc))
        out[which] = res
    for a, b in zip(out["dense"], out["sparse"], strict=True):
        if isinstance(a, str):
            assert a == b
        else:
            assert np.allclose(a[0], b[0], atol=1e-10, rtol=0) and a[1:] == b[1:]
    assert out["sparse"][1][2] == ["p[2]", "v[2]"]  # rod, d/dt rod imply two of the six values
    assert "p[0]" in out["sparse"][2] and "rod" in out["sparse"][2]


def test_chain_stretched_at_rest_both_paths_exact(chain60, monkeypatch):
    """Chain along the x-axis at rest: rods horizontal, so every mass falls freely:
    der(v) = (0, -g) for each mass, lam = 0; the x-coordinates of q and v are implied by the
    rods (q[2k] and v[2k] redundant). Same values and sets on both paths."""
    N = 60
    pos = np.zeros(2 * N)
    pos[0::2] = np.arange(1, N + 1)
    fixed = {"q": pos, "v": np.zeros(2 * N)}
    got = {}
    for which in ("dense", "sparse"):
        _force(monkeypatch, which)
        got[which] = initialize(chain60, fixed=fixed)
    d, s = got["dense"], got["sparse"]
    for init in (d, s):
        acc = init["der(v)"]
        assert np.abs(acc[0::2]).max() < 1e-12 and np.abs(acc[1::2] + 9.81).max() < 1e-12
        assert np.abs(init["lam"]).max() < 1e-12
        assert init.dof == 2 * N and init.residual < 1e-12
    assert np.abs(np.r_[d.x0, d.z0] - np.r_[s.x0, s.z0]).max() < 1e-10
    assert sorted(s.redundant) == sorted([f"q[{2 * k}]" for k in range(N)]
                                         + [f"v[{2 * k}]" for k in range(N)])
    assert s.redundant == d.redundant and len(s.dof_names) == len(d.dof_names) == 2 * N
    assert s.free == d.free == []  # everything was fixed


def test_chain_hanging_multipliers_exact(chain60, path):
    """Hanging at rest: rod k carries the weight of masses k..N (reference: exact.py)."""
    ex = planar_chain_hanging(60)
    init = initialize(chain60, fixed={"q": ex["q"], "v": ex["v"]})
    assert np.abs(init["lam"] - ex["lam"]).max() < 1e-9
    assert np.abs(init["der(v)"]).max() < 1e-10
    assert len(init.redundant) == 2 * 60  # the y-coordinates follow from the rods


def test_chain_rotating_accelerations_exact(path):
    """g = 0, turning rigidly: centripetal accelerations and tensions (reference: exact.py)."""
    from daekit.reduction import reduce_index

    N = 40
    r = reduce_index(dk.examples.planar_chain(N, g=0.0))
    ex = planar_chain_rotating(0.3, N, omega=1.5)
    # fix the tangential coordinates only; the radial ones are guesses
    init = initialize(r, guess={"q": ex["q"], "v": ex["v"]},
                      fixed={"q[1]": ex["q"][1], "v[1]": ex["v"][1]})
    assert np.abs(init["q"] - ex["q"]).max() < 1e-9
    assert np.abs(init["der(v)"] - ex["der(v)"]).max() < 1e-8
    assert np.abs(init["lam"] - ex["lam"]).max() < 1e-8


def test_chain_free_states_valid_and_paths_agree(chain60, monkeypatch):
    """From a guess near a known consistent state both paths find the same point; fixing
    exactly the reported ``free`` states at that state's values (guesses nearby) reproduces
    it, so ``free`` is a valid set of dynamic degrees of freedom."""
    N = 60
    q, v, rng = _chain_state(N)
    guess = {"q": q + 0.01 * rng.standard_normal(2 * N), "v": v + 0.01 * rng.standard_normal(2 * N)}
    exact = {f"q[{i}]": q[i] for i in range(2 * N)} | {f"v[{i}]": v[i] for i in range(2 * N)}
    got = {}
    for which in ("dense", "sparse"):
        _force(monkeypatch, which)
        a = initialize(chain60, guess=guess)
        assert a.dof == 2 * N and a.residual < 1e-12
        b = initialize(chain60, guess=guess, fixed={nm: exact[nm] for nm in a.free})
        assert np.abs(b["q"] - q).max() < 1e-10 and np.abs(b["v"] - v).max() < 1e-10
        assert b.redundant == []
        got[which] = (a, b)
    (ad, bd), (as_, bs) = got["dense"], got["sparse"]
    assert np.abs(np.r_[ad.x0, ad.z0] - np.r_[as_.x0, as_.z0]).max() < 1e-10
    assert np.abs(np.r_[bd.x0, bd.z0] - np.r_[bs.x0, bs.z0]).max() < 1e-10
    assert len(ad.free) == len(as_.free) == 2 * N


def test_chain_overspecified_conflict_named_on_both_paths(chain60, monkeypatch):
    """All of q, v fixed: half implied (accepted); one value off -> the same error naming it."""
    N = 60
    q, v, _ = _chain_state(N, seed=1)
    msgs, red = {}, {}
    for which in ("dense", "sparse"):
        _force(monkeypatch, which)
        init = initialize(chain60, fixed={"q": q, "v": v})
        red[which] = init.redundant
        assert len(init.redundant) == 2 * N
        bad = q.copy()
        bad[-1] += 1e-3
        with pytest.raises(InitializationError) as exc:
            initialize(chain60, fixed={"q": bad, "v": v})
        msgs[which] = str(exc.value)
    assert red["dense"] == red["sparse"]
    assert msgs["dense"] == msgs["sparse"]
    assert f"q[{2 * N - 1}]" in msgs["sparse"] and "rod[59]" in msgs["sparse"]


def test_greedy_dependence_skips_dependent_rows():
    """A row after a dependent one is judged against the accepted rows only (an unpivoted QR
    would call the second row dependent too)."""
    J = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    assert INIT._dependent_fixed(J, 0, ["a", "b", "c", "d"]) == ["a", "c"]
    rng = np.random.default_rng(3)
    # unit rows, combinations of earlier rows, and fresh rows, in a sparse matrix
    rows = [np.eye(8)[2], rng.standard_normal(8), np.eye(8)[5]]
    rows.append(2 * rows[1] - rows[0])  # dependent
    rows.append(np.eye(8)[2])  # dependent (repeat)
    rows += [np.eye(8)[j] for j in range(8)]  # 2 and 5 dependent, then 6 more accepted: 1 too many
    A = np.array(rows)
    dense = INIT._greedy_dependent_rows(A, 1e-9)
    sparse = INIT._greedy_dependent_sparse(sp.csr_matrix(A), 1e-9)
    assert dense == sparse
    assert len(A) - len(dense) == 8 and {3, 4} <= set(dense)


def test_no_guesses_at_all_still_finds_a_consistent_point():
    """Nothing given: the default start p = 0 is a singular point of the rod constraint; a
    second start from a generic point must find a consistent state."""
    import daekit as dk

    r = dk.reduce_index(dk.examples.pendulum3d())
    init = dk.initialize(r)
    p, v = init["p"], init["v"]
    assert abs(p @ p - 1.0) < 1e-12 and abs(p @ v) < 1e-12


def test_bad_fixed_and_guess_types():
    import daekit as dk

    r = dk.reduce_index(dk.examples.pendulum3d())
    with pytest.raises(dk.InitializationError, match="fixed must be a dict"):
        dk.initialize(r, fixed=[1, 2])
    with pytest.raises(dk.InitializationError, match="must be a number or a list of numbers"):
        dk.initialize(r, fixed={"p": "abc"})


def test_a_system_whose_input_is_not_a_symbol_is_named():
    """A hand-built system with an expression where a symbol belongs: a ModelError naming the
    element (not CasADi's "Xfunction input arguments must be purely symbolic")."""
    t, x, z, u = ca.SX.sym("t"), ca.SX.sym("x"), ca.SX.sym("z"), ca.SX.sym("u")
    r = ReducedDAE(t, x, z, ca.vertcat(u, ca.SX(0)), ca.SX(0, 1), z, z - x + u, ca.SX(0, 1), [],
                   ["x"], ["z"], ["u", "gain"], [], np.zeros(0), {"x": x, "z": z})
    with pytest.raises(ModelError, match=r"input 'gain' is the expression 0"):
        initialize(r, guess={"x": 1.0})


def test_a_system_with_one_symbol_in_two_roles_is_named():
    t, x, z = ca.SX.sym("t"), ca.SX.sym("x"), ca.SX.sym("z")
    r = ReducedDAE(t, x, z, ca.SX(0, 1), x, z, z - x, ca.SX(0, 1), [], ["x"], ["z"], [], ["k"],
                   np.ones(1), {"x": x, "z": z})
    with pytest.raises(ModelError, match=r"one symbol is used as two of them"):
        initialize(r, guess={"x": 1.0})
