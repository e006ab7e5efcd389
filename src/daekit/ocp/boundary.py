"""Boundary analysis of a compiled OCP at a guess: which conditions to impose, which are implied,
which select a branch, and which (provably) contradict each other.

The primitives (rank on the manifold, projections, the deletion filter) are in
:mod:`daekit.ocp.consistency`; this module decides with them, at the guess of a solve:

1. The guess's end points are projected (Gauss-Newton, least-norm steps, equations scaled) onto
   the set ``S`` where the algebraic equations, the invariants and all the conditions hold:
   point ``a``. Random points of the *manifold* nearby (perturbations of ``a`` projected onto
   the algebraic equations and invariants only, so the conditions do not hold there) give the
   generic rank of the conditions in a neighbourhood.
2. If the rank at ``a`` equals the generic rank nearby, the rank is constant near ``a`` and a
   condition dependent on the kept ones there is implied by them on a neighbourhood: it is
   dropped (its residual is checked again at the solution). If the rank at ``a`` is lower (a
   degenerate point: the tangent of ``p[1] = L`` vanishes at the upright position) the subset
   is chosen at the generic points, and the report says that the conditions are degenerate.
3. A dropped condition is never dropped blindly: the set where the kept conditions hold is
   searched from far starts; where it has points on which the dropped condition does not hold
   (``s = 0, p[0] = 0`` on a circle: the pole up or down), the condition *selects a branch*. It
   is then imposed as the inequality ``|c| <= gap / 2`` (``gap``: its value on the nearest other
   branch found), which holds strictly at the solution (so the constraint Jacobian stays
   regular) and excludes the other branches.
4. When the projection leaves a residual, a minimal contradictory subset is looked for (a
   deletion filter). It is a *proof* of contradiction only when the subset's conditions are
   affine (least squares is then global) and contradict each other by themselves, or when a
   condition fixes a variable outside its bounds; only then is IPOPT not run. Otherwise the
   report warns and IPOPT runs.
"""

from __future__ import annotations

import numpy as np

from .consistency import (
    BoundaryAnalysis,
    analyze_boundary,
    as_array,
    conflicting_conditions,
    project_ends,
    project_ends_many,
    rows_of,
)

__all__ = ["analyze", "end_points", "columns"]


def end_points(g):
    """``(v0, vT)`` of a guess (``v = (x, z, w)``)."""
    x0, z0, w0 = g.fun(np.array([0.0]))
    xT, zT, wT = g.fun(np.array([g.T]))
    return (np.concatenate([x0[:, 0], z0[:, 0], w0[:, 0]]),
            np.concatenate([xT[:, 0], zT[:, 0], wT[:, 0]]))


def _scale(*vs) -> float:
    return max(1.0, float(np.max(np.abs(np.concatenate([np.ravel(v) for v in vs])), initial=0.0)))


def analyze(prob, g, forced=()) -> BoundaryAnalysis:
    """Boundary analysis of ``prob`` at the end points of the guess ``g`` (module docstring)."""
    a = prob.aug
    T, p = g.T, g.p
    v0, vT = end_points(g)
    labels = prob.bc_labels
    nman = int(prob.man_fun.size1_out(0))
    # the end-point functions evaluated through their buffers (dozens of small calls here),
    # made once per compiled problem
    ends, bc_jac, man_jac = (prob.dense(k) for k in ("ends_fun", "bc_jac", "man_jac"))
    if not labels:
        J0 = man_jac(0.0, v0, p)
        JT = man_jac(T, vT, p)
        return BoundaryAnalysis([], 0, [], [], np.zeros(0), np.zeros((0, 0)),
                                (J0.shape[1] - a.nz - a.nw, JT.shape[1] - a.nz - a.nw))
    if "periodic" in prob.bc_kinds:
        # a non-periodic guess would put point a far from the periodic solutions' set
        vT = v0.copy()
    n = v0.size
    a0, aT, res_a = project_ends(ends, v0, vT, p, T)
    rng = np.random.default_rng(7)
    # the neighbourhood: points of the manifold near a (where the conditions need not hold);
    # periodic conditions are redundant only where x(T) = x(0), so for them the points
    # are taken on the set where all the conditions hold (their rank is constant there)
    man = ends
    y = np.concatenate([a0, aT])
    sc = np.maximum(1.0, np.abs(y))
    yps = [y + 0.05 * sc * rng.standard_normal(y.size) for _ in range(2)]
    generic = [(b0, bT) for b0, bT, _r in
               project_ends_many(columns(man), [(yp[:n], yp[n:]) for yp in yps], p, T)]

    def jacs(e0, eT):
        return bc_jac(e0, eT, p, T), man_jac(0.0, e0, p), man_jac(T, eT, p)

    at_a = jacs(a0, aT)
    at_b = [jacs(*e) for e in generic]
    probe = analyze_boundary(labels, *at_a, preference=prob.bc_pref, others=at_b,
                             forced=list(forced))
    r_a, r_gen = probe.ranks[0], max(probe.ranks[1:], default=probe.ranks[0])
    degenerate = False
    if degenerate:
        # choose where the rank is the generic one, preferring rows regular at a too
        ba = analyze_boundary(labels, *at_b[int(np.argmax(probe.ranks[1:]))],
                              preference=prob.bc_pref, others=[at_a], forced=list(forced))
        ba.ranks = probe.ranks
    else:
        ba = probe  # the same call (it returns a new record; computed once)
    ba.preference = list(prob.bc_pref)
    ba.forced = [int(i) for i in forced]
    # the manifold counts w as free directions; report the state-space dimension
    ba.manifold_dims = (ba.manifold_dims[0] - a.nw, ba.manifold_dims[1] - a.nw)
    ba.notes.append(
        "rank evaluated at the guess's end points projected onto the manifold and the given "
        f"conditions (residual {res_a:.1e}): {r_a}, and at random points of that set "
        f"nearby: {r_gen}"
    )
    if degenerate:
        ba.degenerate = True
        ba.notes.append(
            f"the conditions are degenerate at that point (rank {r_a} there, {r_gen} nearby: a "
            "condition touches the manifold, e.g. a position at its extreme); the subset imposed "
            "is independent nearby, and IPOPT may converge more slowly"
        )
    ba.residual = float(res_a)
    scale = _scale(a0, aT)
    if res_a > 1e-6:
        starts = [(a0, aT)]
        yp0 = np.concatenate([a0, aT])
        for amp in (0.03, 0.3):
            yp = yp0 + amp * np.maximum(1.0, np.abs(yp0)) * rng.standard_normal(yp0.size)
            starts.append((yp[:n], yp[n:]))
        _find_conflict(prob, ba, [*starts, (v0, vT)], p, T, nman)
        if not ba.conflict:
            ba.notes.append(
                "the conditions could not all be met together with the invariants near the "
                f"guess (least-squares residual {res_a:.2e}); IPOPT is run all the same"
            )
    _bound_conflicts(prob, ba)
    if not ba.proven and "periodic" not in prob.bc_kinds:
        _pin_isolated_ends(prob, ba, (a0, aT), at_a, at_b, p, T, nman, rng)
        if ba.pins:
            ba.degenerate = True
    if ba.dropped and not ba.proven:
        _branch_selectors(prob, ba, (a0, aT), (v0, vT), p, T, nman, scale, rng)
    return ba


def _find_conflict(prob, ba: BoundaryAnalysis, starts, p, T, nman: int) -> None:
    """A minimal subset of conditions that cannot hold together (deletion filter, trying to
    remove the conditions with the smallest residual at the least-squares point first); proven
    when its conditions are affine and contradict each other without the manifold."""
    a0, aT = starts[0]
    n_fixed = 2 * nman
    ends = prob.dense("ends_fun")
    r = ends(a0, aT, p, T)[0].ravel()[n_fixed:]
    order = sorted(range(r.size), key=lambda i: (abs(r[i]), -i))
    found = conflicting_conditions(ends, n_fixed, r.size, starts, p, T, order)
    if found is None:
        return
    subset, alone = found
    ba.conflict, ba.conflict_alone = subset, alone
    ba.conflict_residuals = r
    ba.proven = bool(subset) and alone and all(prob.bc_linear[i] for i in subset)
    if ba.proven:
        ba.kept, ba.dropped = list(range(r.size)), []


def _pin_isolated_ends(prob, ba, a_pt, at_a, at_b, p, T, nman, rng) -> None:
    """At an end whose conditions are degenerate at ``a`` but determine one isolated point of
    the manifold (the pole upright at rest: ``p[1] = L`` touches the circle there), impose that
    point instead: the values of an independent subset of the states at it (regular, the same
    point set); the end's own conditions are checked at the solution."""
    from .compiled import derivative_levels
    from .consistency import equilibrate, independent_rows, null_basis

    a = prob.aug
    n = a_pt[0].size
    lev = derivative_levels(a)
    names = a.x_names
    for e, kind in enumerate(("initial", "final")):
        idx = [i for i, k in enumerate(prob.bc_kinds) if k == kind]
        if not idx:
            continue
        cols = slice(e * n, (e + 1) * n)

        A = equilibrate(np.asarray(at_a[0], float)[idx][:, cols]) @ null_basis(at_a[1 + e])
        sv = np.linalg.svd(A, compute_uv=False) if A.size else np.zeros(0)
        dim = null_basis(at_a[1 + e]).shape[1] - a.nw
        if dim <= 0 or sv.size < dim or sv[dim - 1] > 1e-4:
            continue  # the end's conditions do not fix the point, or fix it regularly
        rows = list(range(e * nman, (e + 1) * nman)) + [2 * nman + i for i in idx]
        sub = rows_of(prob.dense("ends_fun"), rows)
        y = np.concatenate(a_pt)
        isolated = True
        for _ in range(3):
            d = np.zeros_like(y)
            d[cols] = 0.05 * np.maximum(1.0, np.abs(y[cols])) * rng.standard_normal(n)
            e0, eT, res = project_ends(sub, (y + d)[:n], (y + d)[n:], p, T, max_iter=200)
            back = np.concatenate([e0, eT])[cols][: a.nx]
            if res > 1e-8 or np.max(np.abs(back - y[cols][: a.nx])) > 1e-3 * np.max(np.abs(d)):
                isolated = False
                break
        if not isolated:
            continue
        # the point itself, to roundoff: Gauss-Newton converges only linearly at a degenerate
        # root (residual ~ distance^2), so iterate it to the end from a
        y0, yT, _ = project_ends(sub, y[:n], y[n:], p, T, tol=0.0, max_iter=300)
        y = np.concatenate([y0, yT])
        # an independent subset of the states there (positions first)
        A = np.eye(n)[: a.nx] @ null_basis(at_a[1 + e])
        pref = sorted(range(a.nx), key=lambda i: (lev[("x", i)], i))
        order = [0] * a.nx
        for r_, i in enumerate(pref):
            order[i] = r_
        _, chosen, _ = independent_rows(A, 1e-7, order)
        pt = y[cols]
        ba.pins.extend((kind, int(i), float(pt[i]), f"{kind} {names[i]} = {pt[i]:.6g} (the point)")
                       for i in chosen)
        ba.kept = [i for i in ba.kept if i not in idx]
        ba.dropped = sorted(set(ba.dropped) | set(idx))
        ba.notes.append(
            f"the {kind} conditions ({', '.join(ba.labels[i] for i in idx)}) are degenerate at "
            "their point but determine it (an isolated point of the manifold): imposed as the "
            "values of " + ", ".join(names[i] for i in chosen) + " there, which is regular; the "
            "conditions themselves are checked at the solution"
        )


def _bound_conflicts(prob, ba: BoundaryAnalysis) -> None:
    """Conditions that fix one variable to a value outside its bounds: a proof."""
    a = prob.aug
    for c in prob.conditions:
        if c.kind == "periodic" or isinstance(c.value, tuple):  # (tuple: up to sign)
            continue
        w = a.which(c.expr)
        if w is None or w[0] not in prob.lb:
            continue
        lo, hi = prob.lb[w[0]][w[1]], prob.ub[w[0]][w[1]]
        if not lo <= c.value <= hi:
            ba.bound_conflicts.append(
                f"{c.label} = {c.value:g} is outside the bounds [{lo:g}, {hi:g}] of "
                f"{c.label.split(' ', 1)[1]}")
    if ba.bound_conflicts:
        ba.proven = True


def columns(fun, rows=None):
    """The CasADi end-point function ``fun(v0, vT, p, T) -> (r, J)`` evaluated on end points
    given as columns, in one mapped call, in the form :func:`project_ends_many` takes:
    residuals ``(m, k)`` and Jacobians ``(m, k, 2 n)`` (only the rows ``rows`` when given).

    >>> import casadi as ca, numpy as np
    >>> v0, vT = ca.SX.sym("v0", 2), ca.SX.sym("vT", 2)
    >>> r = ca.vertcat(ca.sumsqr(v0) - 1, vT[0] - v0[0])
    >>> f = ca.Function("f", [v0, vT, ca.SX.sym("p", 0), ca.SX.sym("T")],
    ...                 [r, ca.jacobian(r, ca.vertcat(v0, vT))])
    >>> R, J = columns(f)(np.array([[1.0, 2.0], [0, 0]]), np.zeros((2, 2)), [], 0.0)
    >>> R.tolist(), J.shape
    ([[0.0, 3.0], [-1.0, -2.0]], (2, 2, 4))
    """
    def sub(V0, VT, p, T):
        k = V0.shape[1]
        R, J = fun(V0, VT, p, T)
        R = as_array(R).reshape(-1, k)
        J = as_array(J).reshape(R.shape[0], k, 2 * V0.shape[0])
        return (R, J) if rows is None else (R[rows], J[rows])

    return sub


def _branch_selectors(prob, ba, a_pt, guess_pt, p, T, nman, scale, rng) -> None:
    """Dropped conditions that select a branch of the set where the kept ones hold become
    inequalities ``|c| <= gap / 2`` (see the module docstring)."""
    n = a_pt[0].size
    rows = list(range(2 * nman)) + [2 * nman + i for i in ba.kept]
    pinned = {k for k, *_ in ba.pins}
    pin_rows = [(0 if k == "initial" else n) + i for k, i, _, _ in ba.pins]
    pin_vals = np.array([v for _, _, v, _ in ba.pins]).reshape(-1, 1)

    sub0 = columns(prob.dense("ends_fun"), rows)

    def sub(V0, VT, p_, T_):  # all starts at once (columns): one mapped evaluation
        k = V0.shape[1]
        R, J = sub0(V0, VT, p_, T_)
        if not pin_rows:
            return R, J
        Y_ = np.vstack([V0, VT])
        E = np.broadcast_to(np.eye(2 * n)[pin_rows][:, None, :], (len(pin_rows), k, 2 * n))
        return np.vstack([R, Y_[pin_rows] - pin_vals]), np.concatenate([J, E], axis=0)
    y = np.concatenate(a_pt)
    sc = np.maximum(1.0, np.abs(y))
    starts = [guess_pt, (2 * a_pt[0] - guess_pt[0], 2 * a_pt[1] - guess_pt[1]),
              (-a_pt[0], -a_pt[1])]
    for amp in (0.5, 0.5, 1.5):
        yp = y + amp * sc * rng.standard_normal(y.size)
        starts.append((yp[:n], yp[n:]))
    others = []
    for e0, eT, res in project_ends_many(sub, starts, p, T, max_iter=30):
        if res < 1e-9:
            others.append(prob.dense("bc_fun")(e0, eT, p, T).ravel())
    if not others:
        return
    R = np.abs(np.array(others))
    for i in ba.dropped:
        if prob.bc_kinds[i] in pinned:
            continue
        gaps = R[:, i][R[:, i] > 1e-4 * scale]
        if gaps.size:
            gap = float(np.min(gaps))
            ba.selectors.append((i, -0.5 * gap, 0.5 * gap))
    if ba.selectors:
        ba.notes.append(
            "where the imposed conditions hold there are other branches on which "
            + ", ".join(ba.labels[i] for i, _, _ in ba.selectors)
            + " do" + ("es" if len(ba.selectors) == 1 else "")
            + " not hold: kept as the inequalities |c| <= "
            + ", ".join(f"{hi:.3g}" for _, _, hi in ba.selectors)
            + " (half the distance to the nearest other branch), which exclude those branches,"
            " are inactive at the solution and keep the constraint Jacobian regular"
        )
