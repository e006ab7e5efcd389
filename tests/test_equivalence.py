"""Equivalent models give equal answers (issue 10).

Property-based, with seeded generators of our own: manufactured-solution models (the exact
solution is chosen first, the equations are built to vanish on it) of index 1 to 5 and 2 to
60 unknowns, made of

* ODE blocks ``y' - y*'(t) + a (y - y*(t)) + b (sin y - sin y*(t)) = 0`` (index 0, one DOF
  each), and
* integrator chains of length ``k - 1`` closed by a constraint, ``x_1' = x_2``, ...,
  ``x_{k-1}' = z``, ``phi(x_1) = phi(g(t))`` with ``phi(x) = x + x^3/10`` (index ``k``, no DOF;
  ``k = 1`` is ``phi(z) = phi(g(t))``), with ``x_i = g^(i-1)``, ``z = g^(k-1)``,

coupled by terms ``c (y - y*(t))`` that vanish on the solution. The model's index is the
longest chain's ``k``, its DOF the number of ODE blocks. Then equivalence transformations are
applied at random: an equation times ``1.5 + sin(u)`` (a nonzero function of an unknown); a
constant or variable multiple of one equation added to another; a constant invertible mixing
of a block of equations; units of variables and equations scaled by ``1e-6 .. 1e6``; random
equation order. None changes the solutions, so ``analyze`` must give the same index and DOF,
and ``reduce_index`` either a system whose DOF (``initialize``) and simulated solution (to
1e-6 of the exact one) are right, or a named :class:`daekit.ReductionError`.

The default suite runs ``FAST_CASES`` cases; ``@pytest.mark.slow`` runs 500.
``python tests/test_equivalence.py 500`` prints the counts.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import pytest

import daekit as dk

FAST_CASES = 8
#: Share of the generated cases enlarged to 36..60 unknowns (see :func:`generate`).
BIG_SHARE = 0.2
#: Measured on seeds 0..499 (``python tests/test_equivalence.py 500``, every case simulated,
#: session 5): analyze right on all 500 (session 4: 498, wrong on seed 15, whose derivative
#: array had no consistent point by Gauss-Newton's residual test, and seed 146, whose Pryce
#: index 7 was not lowered to the true 5), no analyze error; the reduction right (DOF,
#: initial values, simulated solution to 1e-6) on 451, a named ReductionError on 49, silently
#: wrong on 0. (Session 2, the 35-unknown generator: 487 / 13, and 434 / 66 / 0.)
MAX_WRONG = 0
#: Least share of analyses right; the rest may be named errors, none wrong.
MIN_ANALYSIS_OK = 0.99
MAX_ANALYSIS_WRONG = 0.0
#: Least share of cases reduced, initialized and simulated right (the rest: named errors).
MIN_OK = 0.88
SLOW_CASES = 500
#: IDAS tolerances of the simulated check. At rtol >= 1e-10 the reduced systems of index-4/5
#: chains show a pathology of the integrator (nearly every step fails the error test once:
#: 114302 steps, 114276 failures on seed 3, and ends 3e-5 off), at rtol <= 1e-11 they take
#: about 100 steps and end 1e-10 off; reported to the simulate owner.
RTOL, ATOL = 1e-11, 1e-13
T0, T1 = 0.3, 0.8


@dataclass
class Case:
    seed: int
    model: dk.Model
    index: int
    dof: int
    exact: dict  # scaled element name -> function of t
    ode_states: list  # scaled element names of the ODE-block states (the DOF)
    transforms: list = field(default_factory=list)


def _trig(a, b, w, ph):
    """value and derivatives of a + b sin(w t + ph): n -> callable t -> float / SX"""
    def f(t, n=0, sym=False):
        s = ca.sin if sym else np.sin
        base = a if n == 0 else 0.0
        return base + b * w**n * s(w * t + ph + n * np.pi / 2)
    return f


def generate(seed: int, transform: bool = True, big: bool | None = None) -> Case:
    """A random manufactured-solution model and its truth (index, DOF, exact solution).
    ``big``: enlarged to 36..60 unknowns (None: for a share ``BIG_SHARE`` of the seeds; False:
    never, the model of the 35-unknown generator)."""
    rng = np.random.default_rng(seed)
    K = int(rng.integers(1, 6))  # the model's index
    budget = int(rng.integers(max(2, K), 61))
    chains = [K]
    used = K
    while used < budget and rng.random() < 0.5:
        k = int(rng.integers(1, K + 1))
        if used + k > budget:
            break
        chains.append(k)
        used += k
    n_ode = budget - used
    if n_ode > 12:  # keep the models small enough for fast tests: fewer ODE blocks
        n_ode = int(rng.integers(0, 13))
    if sum(chains) + n_ode < 2:
        n_ode = 1
    # a share BIG_SHARE of the cases are enlarged to 36..60 unknowns by more chains and ODE
    # blocks, drawn from a second stream (the other cases are the models of the 35-unknown
    # generator, unchanged)
    rng2 = np.random.default_rng([seed, 60])
    extra_chains, extra_ode = [], 0
    if (rng2.random() < BIG_SHARE) if big is None else big:
        target = int(rng2.integers(36, 61))
        total = sum(chains) + n_ode
        while len(extra_chains) < 4 and total + K <= target and rng2.random() < 0.6:
            k = int(rng2.integers(1, K + 1))
            extra_chains.append(k)
            total += k
        extra_ode = target - total
    m = dk.Model(f"manufactured_{seed}")
    t = m.t
    scale_vars = transform and rng.random() < 0.5
    exact: dict = {}
    eqs: list = []  # (name, expr)
    phys: list = []  # physical values (SX) of the unknowns, for coupling and multiples
    ode_states = []

    def unit(r_=rng):
        return float(10 ** r_.uniform(-6, 6)) if scale_vars else 1.0

    # ODE blocks
    ys = []
    for b in range(n_ode + extra_ode):
        r_ = rng if b < n_ode else rng2
        s = unit(r_)
        yv = m.state(f"y{b}")
        y, dy = s * yv, s * m.der(yv)
        ystar = _trig(2.0 + r_.uniform(0, 1), r_.uniform(0.2, 0.8), r_.uniform(0.5, 2),
                      r_.uniform(0, 6))
        a_, b_ = r_.uniform(0.5, 2.0), r_.uniform(-0.5, 0.5)
        e = (dy - ystar(t, 1, True) + a_ * (y - ystar(t, 0, True))
             + b_ * (ca.sin(y) - ca.sin(ystar(t, 0, True))))
        eqs.append((f"ode{b}", e))
        exact[f"y{b}"] = (lambda tt, f=ystar, s=s: f(tt) / s)
        ys.append((y, ystar))
        phys.append(y)
        ode_states.append(f"y{b}")
    # chains
    chain_x1 = []
    for c, k in enumerate(chains + extra_chains):
        r_ = rng if c < len(chains) else rng2
        g = _trig(1.0 + r_.uniform(0, 1), r_.uniform(0.2, 0.8), r_.uniform(0.5, 1.5),
                  r_.uniform(0, 6))
        xs, dxs = [], []
        for i in range(k - 1):
            s = unit(r_)
            xv = m.state(f"x{c}_{i}")
            xs.append(s * xv)
            dxs.append(s * m.der(xv))
            exact[f"x{c}_{i}"] = (lambda tt, i=i, g=g, s=s: g(tt, i) / s)
        s = unit(r_)
        zv = m.algebraic(f"z{c}")
        zz = s * zv
        exact[f"z{c}"] = (lambda tt, g=g, k=k, s=s: g(tt, k - 1) / s)

        def coupling(r_=r_):
            if not ys or r_.random() < 0.5:
                return 0
            y, ystar = ys[int(r_.integers(len(ys)))]
            return r_.uniform(-1, 1) * (y - ystar(t, 0, True))

        chain = xs + [zz]
        for i in range(k - 1):
            eqs.append((f"chain{c}_{i}", dxs[i] - chain[i + 1] + coupling()))
        first = chain[0]
        phi = lambda v: v + v**3 / 10  # noqa: E731
        eqs.append((f"con{c}", phi(first) - phi(g(t, 0, True)) + coupling()))
        phys += chain
        chain_x1.append((first, g))
    # chain values feeding the ODEs (vanish on the solution)
    for b in range(len(ys)):
        if chain_x1 and rng.random() < 0.4:
            x1, g = chain_x1[int(rng.integers(len(chain_x1)))]
            name, e = eqs[b]
            eqs[b] = (name, e + rng.uniform(-1, 1) * (x1 - g(t, 0, True)))
    transforms = []
    if scale_vars:
        transforms.append("units of variables")
    if transform:
        eqs, transforms = _transform(rng, eqs, phys, transforms)
    for name, e in eqs:
        m.equation(e, name=name)
    return Case(seed, m, K, n_ode + extra_ode, exact, ode_states, transforms)


def _transform(rng, eqs, phys, transforms):
    n = len(eqs)
    names = [nm for nm, _ in eqs]
    E = [e for _, e in eqs]
    if rng.random() < 0.4:  # equation times a nonzero function of an unknown
        i, u = int(rng.integers(n)), phys[int(rng.integers(len(phys)))]
        E[i] = (1.5 + ca.sin(u)) * E[i]
        transforms.append(f"{names[i]} times 1.5 + sin(unknown)")
    if n >= 2 and rng.random() < 0.4:  # a multiple of one equation added to another
        i, j = (int(v) for v in rng.choice(n, 2, replace=False))
        if rng.random() < 0.5:
            c = rng.uniform(-2, 2)
            transforms.append(f"{names[i]} + {c:.2f} {names[j]}")
        else:
            c = phys[int(rng.integers(len(phys)))]
            transforms.append(f"{names[i]} + unknown * {names[j]}")
        E[i] = E[i] + c * E[j]
    if n >= 2 and rng.random() < 0.4:  # constant invertible mixing of a block
        size = int(rng.integers(2, min(n, 3) + 1))
        S = [int(v) for v in rng.choice(n, size, replace=False)]
        while True:
            M = rng.uniform(-1, 1, (size, size)) + 2 * np.eye(size)
            if np.linalg.cond(M) < 20:
                break
        old = [E[i] for i in S]
        for r_, i in enumerate(S):
            E[i] = sum(float(M[r_, q]) * old[q] for q in range(size))
        transforms.append("mixing of " + ", ".join(names[i] for i in S))
    if rng.random() < 0.5:  # units of equations
        for i in range(n):
            if rng.random() < 0.5:
                E[i] = float(10 ** rng.uniform(-6, 6)) * E[i]
        transforms.append("units of equations")
    order = rng.permutation(n) if rng.random() < 0.5 else np.arange(n)
    if rng.random() < 0.5:
        transforms.append("equation order")
    return [(names[i], E[i]) for i in order], transforms


@dataclass
class Outcome:
    analysis_ok: bool
    reduction: str  # "ok", "ReductionError", "wrong"
    detail: str = ""
    analysis: str = "ok"  # "ok", "error" (a named daekit error), "wrong"


def check(case: Case, simulate: bool = True) -> Outcome:
    """Analyze, reduce, initialize and simulate one case against its truth."""
    kind = "ok"
    try:
        a = dk.analyze(case.model)
        ok_a = (a.index, a.dof) == (case.index, case.dof)
        detail = "" if ok_a else f"analyze gave index {a.index}, DOF {a.dof}"
        kind = "ok" if ok_a else "wrong"
    except dk.DaekitError as exc:
        ok_a, kind = False, "error"
        detail = f"analyze: {type(exc).__name__}: {str(exc)[:120]}"
    out = _check_reduction(case, simulate, detail)
    out.analysis_ok, out.analysis = ok_a, kind
    return out


def _check_reduction(case: Case, simulate: bool, detail: str) -> Outcome:
    ok_a = False
    try:
        r = dk.reduce_index(case.model)
    except dk.ReductionError as exc:
        named = any(nm in str(exc) for nm in case.model.equation_names)
        return Outcome(ok_a, "ReductionError" if named else "wrong",
                       detail + ("" if named else f"; unnamed ReductionError: {exc}"))
    fixed = {nm: case.exact[nm](T0) for nm in case.ode_states}
    guess = {nm: f(T0) * (1 + 1e-3) for nm, f in case.exact.items() if nm not in fixed}
    try:
        init = dk.initialize(r, t0=T0, guess=guess, fixed=fixed)
    except dk.InitializationError as exc:
        return Outcome(ok_a, "wrong", detail + f"; initialize: {exc}")
    if init.dof != case.dof:
        return Outcome(ok_a, "wrong", detail + f"; reduced DOF {init.dof} != {case.dof}")
    errs = [abs(init[nm] - f(T0)) / (1e-3 + abs(f(T0))) for nm, f in case.exact.items()]
    if max(errs) > 1e-6:
        return Outcome(ok_a, "wrong", detail + f"; initial values off by {max(errs):.1e}")
    if simulate:
        try:
            traj = dk.simulate(r, np.linspace(T0, T1, 3), init, rtol=RTOL, atol=ATOL)
        except dk.DaekitError as exc:
            return Outcome(ok_a, "wrong", detail + f"; simulate: {str(exc)[:200]}")
        errs = [abs(traj[nm][-1] - f(T1)) / (1e-3 + abs(f(T1))) for nm, f in case.exact.items()]
        if max(errs) > 1e-6:
            return Outcome(ok_a, "wrong", detail + f"; solution off by {max(errs):.1e}")
    return Outcome(ok_a, "ok", detail)


def run(count: int, start: int = 0, simulate_every: int = 1, verbose: bool = False):
    """Counts over ``count`` cases (seeds ``start`` ..): analysis right, reduction right /
    named ReductionError / wrong; the failing seeds with their details."""
    counts = {"analysis_ok": 0, "analysis_error": 0, "analysis_wrong": 0, "ok": 0,
              "ReductionError": 0, "wrong": 0}
    failures = []
    sizes, indices = [], []
    for k in range(start, start + count):
        case = generate(k)
        sizes.append(case.model.n_unknowns)
        indices.append(case.index)
        out = check(case, simulate=(k % simulate_every == 0))
        counts["analysis_ok"] += out.analysis_ok
        counts["analysis_error"] += out.analysis == "error"
        counts["analysis_wrong"] += out.analysis == "wrong"
        counts[out.reduction] += 1
        if not out.analysis_ok or out.reduction == "wrong":
            failures.append((k, case.transforms, out.detail))
            if verbose:
                print(k, case.transforms, out.detail, flush=True)
        if verbose and (k - start + 1) % 10 == 0:
            print(f"after {k - start + 1} cases: {counts}", flush=True)
    return counts, failures, sizes, indices


def test_generator_truth_without_transformations():
    """The untransformed models: analyze and the whole pipeline agree with the truth (this
    checks the generator itself)."""
    for k in range(6):
        case = generate(1000 + k, transform=False)
        out = check(case, simulate=(k % 2 == 0))
        assert out.analysis_ok and out.reduction == "ok", (k, out.detail)


def _assert_rates(counts, n, failures, min_ok=MIN_OK, min_analysis=MIN_ANALYSIS_OK,
                  max_analysis_wrong=MAX_ANALYSIS_WRONG):
    assert counts["wrong"] <= MAX_WRONG * n, (counts, failures)
    assert counts["analysis_ok"] >= min_analysis * n, (counts, failures)
    assert counts["analysis_wrong"] <= max_analysis_wrong * n, (counts, failures)
    assert counts["ok"] + counts["ReductionError"] + counts["wrong"] == n
    assert counts["ok"] >= min_ok * n, counts  # named errors are allowed, not as the rule


def test_equivalent_models_fast():
    counts, failures, sizes, indices = run(FAST_CASES, simulate_every=8)
    assert set(indices) >= {3, 4, 5}
    assert min(sizes) >= 2 and max(sizes) <= 60
    # 8 cases (two of them enlarged to 48 and 49 unknowns): all analysed right (seed 7 was
    # not before session 3), some reductions declined by a named error
    _assert_rates(counts, FAST_CASES, failures, min_ok=0.5, min_analysis=1.0,
                  max_analysis_wrong=0.0)


@pytest.mark.slow
def test_equivalent_models_500():
    """The acceptance run: 500 cases (seeds 0..499), every third simulated (about 100 s;
    ``python tests/test_equivalence.py 500`` simulates all and prints the counts)."""
    counts, failures, sizes, indices = run(SLOW_CASES, simulate_every=3)
    assert set(indices) == {1, 2, 3, 4, 5}
    assert min(sizes) >= 2 and 55 <= max(sizes) <= 60
    _assert_rates(counts, SLOW_CASES, failures)


# ----------------------------------------------------------------------------- the snippets
def gp_scaled(combination: bool = False) -> dk.Model:
    m = dk.Model("gp_scaled")
    y, z, t = m.state("y"), m.state("z"), m.t
    e1 = m.der(y) - 2 * t * m.der(z) - z - ca.cos(t)
    e2 = (2 + ca.sin(y)) * (y - 2 * t * z - ca.sin(t))
    m.equation(e1, name="dynamic")
    m.equation(e2 + z * e1 if combination else e2, name="constraint")
    return m


@pytest.mark.parametrize("combination", [False, True])
def test_gear_petzold_scaled_constraint(combination):
    # Gear-Petzold (eta = -2): index 2, DOF 0, exact solution y = sin t, z = 0
    a = dk.analyze(gp_scaled(combination))
    assert (a.index, a.dof, a.structurally_ok) == (2, 0, False)
    assert "consistent points" in a.test_points
    with pytest.raises(dk.ReductionError, match="dynamic"):
        dk.reduce_index(gp_scaled(combination))


def index4_chain_mixed() -> dk.Model:
    """x1' = x2, x2' = x3, x3' = z, (1.2 + 0.5 sin x3) (x1 - sin t) = 0, mixed by a constant
    invertible matrix: index 4, DOF 0, x1 = sin t, z = -cos t."""
    m = dk.Model("index4_mixed")
    x = [m.state(f"a{i}") for i in range(1, 4)]
    z = m.algebraic("z")
    t = m.t
    E = [m.der(x[0]) - x[1], m.der(x[1]) - x[2], m.der(x[2]) - z,
         (1.2 + 0.5 * ca.sin(x[2])) * (x[0] - ca.sin(t))]
    M = np.array([[1.0, 0.5, 0.0, 0.2], [0.0, 1.0, 0.3, 0.0], [0.4, 0.0, 1.0, 0.5],
                  [0.0, 0.2, 0.0, 1.0]])
    for i in range(4):
        m.equation(sum(float(M[i, j]) * E[j] for j in range(4)), name=f"mix{i}")
    return m


def test_index4_chain_mixing():
    a = dk.analyze(index4_chain_mixed())
    assert (a.index, a.dof) == (4, 0)
    try:
        r = dk.reduce_index(index4_chain_mixed())
    except dk.ReductionError as exc:
        assert "mix" in str(exc)
        return
    t0 = 0.4
    init = dk.initialize(r, t0=t0, guess={"a1": np.sin(t0), "a2": np.cos(t0),
                                           "a3": -np.sin(t0), "z": -np.cos(t0)})
    assert init.dof == 0
    traj = dk.simulate(r, np.linspace(t0, t0 + 1, 3), init, rtol=1e-10, atol=1e-10)
    assert abs(traj["a1"][-1] - np.sin(t0 + 1)) < 1e-6
    assert abs(traj["z"][-1] + np.cos(t0 + 1)) < 1e-6


def stiff_constraint(k: float) -> dk.Model:
    """The minimal slider-crank-like model of the issue: q' = v, v' = w,
    w = (-k q0 + lam, -k q1), q0 = 0: index 3, DOF 2 for every k."""
    m = dk.Model("stiff")
    q, v = m.state("q", 2), m.state("v", 2)
    w, lam = m.algebraic("w", 2), m.algebraic("lam")
    kk = m.parameter("k", k)
    m.equation(m.der(q) - v, name="kin")
    m.equation(m.der(v) - w, name="acc")
    m.equation(w - ca.vertcat(-kk * q[0] + lam, -kk * q[1]), name="force")
    m.equation(q[0], name="c")
    return m


@pytest.mark.parametrize("k", [1.0, 1e6, 2e8, 2e11])
def test_stiff_coefficient_does_not_change_the_index(k):
    d = dk.differential_index(stiff_constraint(k))
    assert (d.index, d.dof) == (3, 2)
    a = dk.analyze(stiff_constraint(k))
    assert (a.index, a.dof) == (3, 2)


def test_redundancy_is_scale_invariant():
    # x' + z = 0, z - 1e6 x = 0, x fixed: x is free, not redundant
    m = dk.Model("scaled")
    x, z = m.state("x"), m.algebraic("z")
    m.equation(m.der(x) + z, name="e1")
    m.equation(z - 1e6 * x, name="e2")
    init = dk.initialize(dk.reduce_index(m), fixed={"x": 0.5})
    assert init.dof_names == ["x"] and init.redundant == [] and init.dof == 1
    assert abs(init["z"] - 5e5) < 1e-6


def test_dummy_derivative_dof_and_free():
    m = dk.examples.l3()
    r = dk.reduce_index(m, method="dummy_derivatives")
    init = dk.initialize(r, guess={"p": [0.6, 0.0, -0.8]})
    assert init.dof == 4 and len(init.dof_names) == 4


#: Seeds whose analysis was wrong at the start of session 3 (the 35-unknown generator) and is
#: right now: the consistent points were not found (Gauss-Newton from draws in the model's
#: units, 1e5 away physically in units of 1e-6, stalled or drifted to values of 1e19), or the
#: structural index of a 16-unknown part was not confirmed (seed 393).
FORMERLY_WRONG = [7, 32, 96, 104, 135, 224, 263, 276, 393, 488]
#: Seed 229 (session 4): ``(1.5 + sin(0.45 z0)) (0.066 x0_0' - 2286 x0_1)`` puts z0 into the
#: equation and opens a transversal whose entry vanishes on the solutions; Gauss-Newton
#: stalled from the first draw, and the verdict stood on the random point (index 2 / DOF 1
#: against the true 3 / 0): two more draws are tried now.
FORMERLY_WRONG += [229]
#: Session 5: seed 15 (no consistent point of its derivative array: Gauss-Newton's per-row test
#: could not be met in rows whose terms cancel, residual 5e-12; DOF 4 at an inconsistent point
#: against the true 3). Seed 146 (Pryce's index 7 of a 16-unknown part, truly 5: the
#: confirming derivative array jumped to its level 6 in one Gauss-Newton solve, which drifted
#: to values of 1e16, and its ranks at the inconsistent point said "not determined") is
#: test_confirmed_index_is_said_so.
FORMERLY_WRONG += [15]


@pytest.mark.parametrize("seed", FORMERLY_WRONG)
def test_formerly_wrong_analyses(seed):
    case = generate(seed, big=False)
    a = dk.analyze(case.model)
    assert (a.index, a.dof) == (case.index, case.dof), case.transforms


def test_confirmed_index_is_said_so():
    """Seed 146: the structural index 7 is lowered to the differential index 5 and explain()
    says so; with the check's size limit below the part's, the index is only an upper bound,
    and both the field and explain() say that."""
    from daekit.analysis import core

    model = generate(146).model
    a = dk.analyze(model)
    assert (a.structural_index, a.index, a.dof) == (7, 5, 3) and a.index_unconfirmed == []
    assert a.index_confirmed[0] == 5
    assert "gives index 7" in a.explain() and "the differential index is 5" in a.explain()
    limit = core.CONFIRM_ARRAY_LIMIT
    try:
        core.CONFIRM_ARRAY_LIMIT = 100
        b = dk.analyze(generate(146).model)
    finally:
        core.CONFIRM_ARRAY_LIMIT = limit
    assert b.index == 7 and len(b.index_unconfirmed) == 1
    eqs, nu, why = b.index_unconfirmed[0]
    assert nu == 7 and len(eqs) == 16 and "exceed the 100" in why
    text = b.explain()
    assert "Differential index at most 7" in text and "is not confirmed" in text
    assert "structural result is the true one" not in text
    assert b.to_dict()["index_is_upper_bound"] and not a.to_dict()["index_is_upper_bound"]


def test_confirmed_index_on_textbook_models():
    # the pendulum: index 3 confirmed by the derivative array; an ODE needs no check
    a = dk.analyze(dk.examples.pendulum_planar())
    assert a.index == 3 and a.index_unconfirmed == [] and a.index_confirmed is None
    assert "confirms the index" in a.explain()
    b = dk.analyze(dk.examples.rigid_body())
    assert b.index == 0 and "(an ODE)" in b.explain()


def test_points_consistent_says_where_the_numbers_hold():
    # x' = z, x^2 + 1 = 0 has no real solution, so no consistent point: the result says so,
    # in the field and in explain() (its numbers are those of a random point)
    m = dk.Model("no_real_solution")
    x, z = m.state("x"), m.algebraic("z")
    m.equation(m.der(x) - z, name="kin")
    m.equation(x**2 + 1, name="never")
    a = dk.analyze(m)
    assert a.points_consistent is False and a.to_dict()["points_consistent"] is False
    assert "at a RANDOM point" in a.explain()
    assert dk.analyze(dk.examples.l3()).points_consistent is True
    assert dk.analyze(dk.examples.l3(), consistent=False).points_consistent is None


def test_slider_crank_analysis_at_consistent_points():
    # Gauss-Newton's rows of cancelling terms left a residual of 4e-13 the per-row test could
    # not accept: the analysis fell back to a random point (test set slider crank, reference
    # problem: index 2, DOF 11 in the index-2 form)
    a = dk.analyze(dk.examples.slider_crank())
    assert (a.index, a.dof) == (2, 11)
    assert a.test_points.startswith("at consistent points"), a.test_points
    assert a.points_consistent


def test_generator_reaches_60_unknowns():
    sizes = [generate(k).model.n_unknowns for k in range(60)]
    assert min(sizes) >= 2 and 55 <= max(sizes) <= 60
    # the enlarged cases leave the others as they were
    assert generate(7).model.n_unknowns == generate(7, big=False).model.n_unknowns == 12


def _dummy_check(case: Case):
    """reduce_index(method="dummy_derivatives") + initialize from the exact DOF values:
    "ok" (the DOF and the values right), "ReductionError" (named) or a description."""
    try:
        r = dk.reduce_index(case.model, method="dummy_derivatives")
    except dk.ReductionError as exc:
        named = any(nm in str(exc) for nm in case.model.equation_names)
        return "ReductionError" if named else f"unnamed: {exc}"
    fixed = {nm: case.exact[nm](T0) for nm in case.ode_states}
    guess = {nm: f(T0) * (1 + 1e-3) for nm, f in case.exact.items() if nm not in fixed}
    try:
        init = dk.initialize(r, t0=T0, guess=guess, fixed=fixed)
    except dk.InitializationError as exc:
        return f"initialize: {exc}"
    if init.dof != case.dof or len(init.dof_names) != case.dof:
        return f"dof {init.dof} {init.dof_names}, truth {case.dof}"
    err = max(abs(init[nm] - f(T0)) / (1e-3 + abs(f(T0))) for nm, f in case.exact.items())
    return "ok" if err <= 1e-6 else f"values off by {err:.1e}"


@pytest.mark.parametrize("seed, outcome", [(90, "ok"), (434, "ReductionError"),
                                           (244, "ReductionError")])
def test_dummy_derivatives_on_generated_models(seed, outcome):
    # 90: con0 times 1.5 + sin(y1) made y1 a dummy at the random selection point (d con0/dy1
    # is con0 cos(y1), zero on the solutions): the system lost a DOF (dof 1, truth 2). Now
    # the selection is checked and made again at a consistent point. 434, 244: amendments
    # that the method "differentiate" rejects (DOF 4 / values off by 0.8 before)
    assert _dummy_check(generate(seed, big=False)) == outcome


def test_dummy_derivative_pendulum_from_rough_guesses():
    """Item 5 of issue 10: the planar pendulum (reference problem 2) in dummy-derivative form
    at t = 0.7, released from pi/6, the two exact DOF values y, y' fixed, the others guessed
    10 % off: consistent values to 1e-8 of the exact solution, dof 2, for every guess."""
    from daekit.examples import exact

    t0 = 0.7
    ex = {k: float(v) for k, v in exact.pendulum_planar(t0, np.pi / 6, g=9.81).items()}
    r = dk.reduce_index(dk.examples.pendulum_planar(), method="dummy_derivatives")
    rng = np.random.default_rng(0)
    for _ in range(40):
        guess = {nm: ex[nm] * (1 + 0.1 * rng.uniform(-1, 1))
                 for nm in ["x", "der(x)", "der(x,2)", "der(y,2)", "T"]}
        init = dk.initialize(r, t0=t0, guess=guess, fixed={"y": ex["y"], "der(y)": ex["der(y)"]})
        assert init.dof == 2 and sorted(init.dof_names) == ["der(y)", "y"]
        assert init.redundant == []
        for nm in ["x", "der(x)", "T"]:
            assert abs(init[nm] - ex[nm]) < 1e-8 * (1 + abs(ex[nm])), nm


def test_dummy_derivative_inconsistent_values_are_named():
    # the message blames the fixed values only when they are inconsistent: here they are
    # (|p| = 2 on the unit circle's pendulum)
    r = dk.reduce_index(dk.examples.pendulum_planar(), method="dummy_derivatives")
    with pytest.raises(dk.InitializationError) as err:
        dk.initialize(r, fixed={"y": -2.0, "der(y)": 0.0}, guess={"x": 0.1})
    msg = str(err.value)
    assert "contradict" in msg and "y = -2" in msg and msg.count("'rod'") == 1


def run_dummy(count: int, start: int = 0, verbose: bool = False):
    """Counts of :func:`_dummy_check` over ``count`` cases: the dummy-derivative form's DOF
    and initial values (``python tests/test_equivalence.py 500 --dummy``)."""
    counts: dict[str, int] = {"ok": 0, "ReductionError": 0, "wrong": 0}
    for k in range(start, start + count):
        out = _dummy_check(generate(k))
        counts[out if out in counts else "wrong"] += 1
        if verbose and out not in ("ok", "ReductionError"):
            print(k, out, flush=True)
    return counts


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else SLOW_CASES
    if "--dummy" in sys.argv:
        print(f"{n} cases, method='dummy_derivatives': {run_dummy(n, verbose=True)}")
        sys.exit()
    counts, failures, sizes, indices = run(n, verbose=True)
    print(f"{n} cases (unknowns {min(sizes)}..{max(sizes)}, index "
          f"{dict(sorted({k: indices.count(k) for k in set(indices)}.items()))}): {counts}")
