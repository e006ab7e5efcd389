"""Boundary conditions against the invariant manifold: redundancy detection and diagnosis.

A reduced (index-1) DAE is equivalent to the original model only on the manifold where its
invariants vanish; the transcription imposes them at the initial time, and exact dynamics
keep them at every later time, the final time included. Boundary conditions are therefore
only meaningful *along* the manifold: at each end point the admissible directions are the
null space ``N`` of the Jacobian of ``[alg; invariants]`` with respect to ``(x, z, w)``.

Full periodicity ``x(T) = x(0)`` of a pendulum imposes ``dim x`` conditions, but the states
at both ends live on manifolds of dimension ``dim x - (number of invariants)``, so only that
many of the periodicity conditions are independent: the rest are implied and, imposed
anyway, make the NLP's constraint Jacobian (nearly) rank deficient, which IPOPT punishes
with failed restorations.

:func:`analyze_boundary` computes ``A = J_bc * blockdiag(N_0, N_T)`` and keeps an independent
subset of the rows (:func:`independent_rows`: a greedy, column-pivoted-QR-like choice that
follows an order of preference).

*Where* ``A`` is evaluated matters: the rank of a set of conditions on the manifold can only
drop at special points, and the point that counts is the solution's, where the conditions
hold. Final ``v = 0`` of a pendulum (``p.v = 0`` on the manifold) is 2 conditions where
``v = 0`` but 3 where ``v != 0``; with a final ``p[0]`` also given, a guess whose final
velocity is not zero makes ``p[0]`` look implied by the three ``v``'s, and dropping it lets the
solver end anywhere. :meth:`daekit.ocp.OCP.boundary_analysis` therefore evaluates ``A`` at the
guess's end points projected (:func:`project_ends`, Gauss-Newton) onto the set where the
algebraic equations, the invariants and the given conditions hold, and at a random point of
that set nearby (which a special projected point, e.g. a planar guess of a 3D motion, cannot
fool); the rank is the larger of the two. Among the conditions it prefers position-level ones
to velocity-level ones, then the order given. After solving, a dropped condition that does not
hold (the solution reached a branch where it is not implied, e.g. ``p[2] = +0.8`` instead of
``-0.8`` when ``p[0], p[1]`` are imposed on a sphere) is imposed in a second solve.

Rank deficiency is redundancy only when the conditions are consistent. When the projection
leaves a residual (from the point above and from a perturbed one), the conditions may
*contradict* each other (``s(0) = 0``, ``s(T) = 1``, ``s(T) = s(0)`` also has rank 2 of 3):
:func:`conflicting_conditions` then looks for a minimal contradictory subset by a deletion
filter (several starts of the projection per test, so that a local least-squares point of a
consistent set is not taken for a contradiction), and nothing is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy


def as_array(M) -> np.ndarray:
    """A CasADi ``DM`` (or anything array-like) as a dense float array, built from its
    nonzeros and sparsity triplet: about 5x faster than ``DM.full()`` (SWIG's conversion) on
    the small sparse Jacobians the projections evaluate dozens of times per solve (measured
    0.016 against 0.07-0.09 ms for a 12 x 72 Jacobian with 180 nonzeros).

    >>> import casadi as ca
    >>> as_array(ca.DM(ca.Sparsity.diag(2), [1.0, 2.0])).tolist()
    [[1.0, 0.0], [0.0, 2.0]]
    """
    if isinstance(M, np.ndarray) or not hasattr(M, "nonzeros"):
        return np.asarray(M, dtype=float)
    if M.is_dense():
        return np.array(M.nonzeros(), dtype=float).reshape(M.shape, order="F")
    r, c = M.sparsity().get_triplet()
    out = np.zeros(M.shape)
    out[r, c] = M.nonzeros()
    return out

__all__ = ["as_array", "BoundaryAnalysis", "independent_rows",
           "analyze_boundary", "null_basis", "project_ends", "project_ends_many",
           "restricted_jacobian", "conflicting_conditions", "equilibrate"]


@dataclass
class BoundaryAnalysis:
    """Result of :func:`analyze_boundary`.

    Attributes
    ----------
    labels : list of str
        One label per boundary condition, e.g. ``"periodic p[0]"``.
    rank : int
        Rank of the boundary conditions' Jacobian restricted to the invariant manifold.
    kept, dropped : list of int
        Indices of the conditions imposed and of those implied by the others (redundant).
    singular_values : numpy.ndarray
        Of the restricted Jacobian (shows how close to rank deficient it is).
    restricted : numpy.ndarray
        The restricted Jacobian itself (rows = conditions).
    manifold_dims : tuple of int
        Dimension of the manifold at the initial and final point.
    notes : list of str
        What the analysis did (points used, forced conditions), for the report.
    ranks : list of int
        The rank at each point the analysis used (see :meth:`OCP.boundary_analysis`).
    preference : list of int
        The order of preference of each condition (lower is kept first).
    forced : list of int
        Conditions kept first because a previous solve violated them while dropped.
    conflict : list of int
        Non-empty when the conditions contradict each other: a minimal subset of them that
        cannot hold together (with the algebraic equations and the invariants unless
        :attr:`conflict_alone`); see :func:`conflicting_conditions`. Nothing is dropped then.
    conflict_alone : bool
        The :attr:`conflict` conditions contradict each other even without the algebraic
        equations and the invariants.
    conflict_residuals : numpy.ndarray
        Residual of every condition at the closest (least-squares) point.
    residual : float
        Largest residual of the projection onto the set where all conditions, the algebraic
        equations and the invariants hold (zero when they are consistent).
    proven : bool
        The contradiction is certain (affine conditions that contradict each other by
        themselves, or a value outside the variable's bounds); only then is IPOPT not run.
    bound_conflicts : list of str
        Conditions fixing a variable outside its bounds.
    selectors : list of (int, float, float)
        Dropped conditions that select a branch, imposed as ``lo <= c <= hi``.
    degenerate : bool
        The rank at the analysis point is lower than nearby (see :mod:`daekit.ocp.boundary`).
    pins : list of (str, int, float, str)
        At an end where the conditions are degenerate but select one isolated point of the
        manifold, that point's values of an independent subset of the states, imposed instead
        of the conditions of that end (which are checked at the solution).
    """

    labels: list[str]
    rank: int
    kept: list[int]
    dropped: list[int]
    singular_values: np.ndarray
    restricted: np.ndarray
    manifold_dims: tuple[int, int] = (0, 0)
    notes: list[str] = field(default_factory=list)
    ranks: list[int] = field(default_factory=list)
    preference: list[int] = field(default_factory=list)
    forced: list[int] = field(default_factory=list)
    conflict: list[int] = field(default_factory=list)
    conflict_alone: bool = False
    conflict_residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residual: float = 0.0
    proven: bool = False
    bound_conflicts: list[str] = field(default_factory=list)
    selectors: list[tuple[int, float, float]] = field(default_factory=list)
    degenerate: bool = False
    pins: list[tuple[str, int, float, str]] = field(default_factory=list)

    @property
    def n_conditions(self) -> int:
        return len(self.labels)

    @property
    def redundant(self) -> bool:
        return bool(self.dropped)


def null_basis(J: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis of the null space of ``J`` (columns)."""
    J = equilibrate(np.atleast_2d(np.asarray(J, dtype=float)))
    if J.shape[0] == 0:
        return np.eye(J.shape[1])
    return scipy.linalg.null_space(J, rcond=tol)


def equilibrate(J: np.ndarray) -> np.ndarray:
    """The rows of ``J`` scaled to unit length (zero rows stay zero): rank decisions and
    projections then do not depend on how an equation is scaled (``0 = z + 1e8 x - u``).

    >>> equilibrate(np.array([[3.0, 4.0], [0.0, 0.0]])).tolist()
    [[0.6, 0.8], [0.0, 0.0]]
    """
    J = np.atleast_2d(np.asarray(J, dtype=float))
    if J.size == 0:
        return J
    nrm = np.linalg.norm(J, axis=1)
    return J / np.where(nrm > 0, nrm, 1.0)[:, None]


def _rank(A: np.ndarray, tol: float) -> int:
    if A.size == 0:
        return 0
    sv = np.linalg.svd(A, compute_uv=False)
    return int(np.sum(sv > tol * max(1.0, float(sv[0]))))


def independent_rows(
    A: np.ndarray,
    tol: float = 1e-7,
    preference=None,
    others=(),
    forced=(),
    threshold: float = 0.1,
) -> tuple[int, list[int], list[int]]:
    """Rank of ``A`` and an independent subset of its rows, chosen by preference.

    Greedy orthogonalization with *threshold pivoting* (column-pivoted QR of ``A^T`` whose ties
    are broken by preference): at each step, among the remaining rows whose component
    orthogonal to the rows already chosen is at least ``threshold`` times the largest such
    component, the most preferred one is chosen. A row whose orthogonal component is below
    ``tol * max(1, largest row norm)`` is dependent: it is dropped.

    Parameters
    ----------
    preference : sequence of int, optional
        ``preference[i]`` is the rank of row ``i`` in the order of preference (lower first);
        default: the rows' own order.
    others : sequence of arrays
        The same rows evaluated elsewhere (other points): among the eligible rows, those that
        are also independent there (of the rows already chosen) come first.
    forced : sequence of int
        Rows chosen first (in this order) whenever they are independent of each other.

    Returns ``(rank, kept, dropped)`` with index lists in increasing order.

    >>> independent_rows(np.array([[1.0, 0.0], [2.0, 0.0], [0.0, 1.0]]))
    (2, [0, 2], [1])
    >>> independent_rows(np.array([[1.0, 0.0], [2.0, 0.0], [0.0, 1.0]]), preference=[2, 0, 1])
    (2, [1, 2], [0])
    """
    mats = [np.atleast_2d(np.asarray(A, dtype=float))]
    mats += [np.atleast_2d(np.asarray(B, dtype=float)) for B in others]
    m = mats[0].shape[0]
    if m == 0:
        return 0, [], []
    if mats[0].shape[1] == 0:
        return 0, [], list(range(m))
    pref = list(range(m)) if preference is None else [int(v) for v in preference]
    # residuals: the rows minus their projections on the span of the chosen rows (per point)
    res = [M.copy() for M in mats]
    lim = [tol * max(1.0, float(np.max(np.linalg.norm(M, axis=1), initial=0.0))) for M in mats]
    chosen: list[int] = []
    free = set(range(m))

    def take(i: int) -> None:
        for M, lk in zip(res, lim, strict=True):
            nrm = float(np.linalg.norm(M[i]))
            if nrm > lk:  # at a point where row i is dependent, nothing to project out
                q = M[i] / nrm
                M -= np.outer(M @ q, q)
        chosen.append(i)
        free.discard(i)

    for i in forced:
        if i in free and np.linalg.norm(res[0][i]) > lim[0]:
            take(int(i))
    while free:
        norms = {i: float(np.linalg.norm(res[0][i])) for i in free}
        cand = [i for i in free if norms[i] > lim[0]]
        if not cand:
            break
        top = max(norms[i] for i in cand)
        elig = [i for i in cand if norms[i] >= threshold * top]
        both = [i for i in elig
                if all(np.linalg.norm(R[i]) > lk for R, lk in zip(res[1:], lim[1:], strict=True))]
        take(min(both or elig, key=lambda i: (pref[i], i)))
    return len(chosen), sorted(chosen), sorted(free)


def restricted_jacobian(J_bc, J_man0, J_manT, n_conditions: int):
    """``J_bc * blockdiag(N_0, N_T)`` and the manifold dimensions ``(dim N_0, dim N_T)``."""
    N0 = null_basis(J_man0)
    NT = null_basis(J_manT)
    n = np.atleast_2d(J_man0).shape[1]
    J_bc = equilibrate(np.atleast_2d(np.asarray(J_bc, dtype=float)).reshape(n_conditions, 2 * n))
    return np.hstack([J_bc[:, :n] @ N0, J_bc[:, n:] @ NT]), (N0.shape[1], NT.shape[1])


def analyze_boundary(
    labels: list[str],
    J_bc: np.ndarray,
    J_man0: np.ndarray,
    J_manT: np.ndarray,
    tol: float = 1e-7,
    preference=None,
    others=(),
    forced=(),
) -> BoundaryAnalysis:
    """Rank of boundary conditions on the manifold and an independent subset.

    Parameters
    ----------
    labels : list of str
        One per condition.
    J_bc : array (n_bc, 2 n)
        Jacobian of the conditions with respect to ``(v_0, v_T)``, ``v = (x, z, w)``.
    J_man0, J_manT : array (n_man, n)
        Jacobians of ``[alg; invariants]`` with respect to ``v`` at the initial and final point.
    preference : sequence of int, optional
        Rank of each condition in the order of preference (see :func:`independent_rows`).
    others : sequence of (J_bc, J_man0, J_manT)
        The same Jacobians at other points. The rank is the largest over all points; the subset
        is chosen at a point of largest rank (the first such), preferring conditions that are
        independent at the other points too.
    forced : sequence of int
        Conditions to keep whenever they are independent of each other.

    >>> # one state, no manifold constraint: x(0) = 1 and 2 x(0) = 2 are one condition
    >>> a = analyze_boundary(["a", "b"], np.array([[1.0, 0], [2.0, 0]]), np.zeros((0, 1)),
    ...                      np.zeros((0, 1)))
    >>> a.rank, a.kept, a.dropped
    (1, [0], [1])
    """
    m = len(labels)
    pts = [(J_bc, J_man0, J_manT), *others]
    restricted = [restricted_jacobian(*pt, m) for pt in pts]
    ranks = [_rank(A, tol) for A, _ in restricted]
    k = int(np.argmax(ranks))
    A, dims = restricted[k]
    rest = [B for i, (B, _) in enumerate(restricted) if i != k]
    rank, kept, dropped = independent_rows(A, tol, preference, rest, forced)
    sv = np.linalg.svd(A, compute_uv=False) if A.size else np.zeros(0)
    ba = BoundaryAnalysis(
        labels=list(labels),
        rank=rank,
        kept=kept,
        dropped=dropped,
        singular_values=sv,
        restricted=A,
        manifold_dims=dims,
        ranks=ranks,
    )
    return ba


def project_ends(fun, v0, vT, p, T, tol: float = 1e-10, max_iter: int = 60):
    """Gauss-Newton projection of the end points ``(v0, vT)`` onto ``fun(v0, vT, p, T) = 0``.

    ``fun`` returns ``(residual, Jacobian with respect to (v0, vT))``; the steps are the
    least-norm solutions of the linearized equations (so redundant or, near a solution,
    dependent equations do no harm), halved while they do not decrease the residual. Each
    equation is scaled by the norm of its gradient at the start, so residuals are distances
    and an equation's scale (``0 = z + 1e8 x - u``) does not matter. Returns
    ``(v0, vT, largest scaled residual)``; where the equations cannot all hold, the point is a
    local least-squares one.
    """
    n = np.size(v0)
    y = np.concatenate([np.ravel(v0), np.ravel(vT)]).astype(float)

    r0, J0 = fun(y[:n], y[n:], p, T)
    r0 = as_array(r0).ravel()
    if r0.size == 0:
        return y[:n], y[n:], 0.0
    J0 = as_array(J0).reshape(r0.size, -1)
    nrm = np.linalg.norm(J0, axis=1)
    # rows scaled by their Jacobian's norm at the start: a residual is then a distance
    sc = 1.0 / np.where(nrm > 1e-300, nrm, 1.0)

    def ev(y):
        r, J = fun(y[:n], y[n:], p, T)
        r = as_array(r).ravel()
        return sc * r, sc[:, None] * as_array(J).reshape(r.size, 2 * n)

    r, J = ev(y)
    for _ in range(max_iter):
        nr = float(np.linalg.norm(r))
        if r.size == 0 or np.max(np.abs(r)) < tol:
            break
        d = np.linalg.lstsq(J, -r, rcond=1e-12)[0]
        step = 1.0
        while step > 1e-6:
            yn = y + step * d
            rn, Jn = ev(yn)
            if np.all(np.isfinite(rn)) and np.linalg.norm(rn) < nr:
                break
            step *= 0.5
        else:
            break
        y, r, J = yn, rn, Jn
    worst = float(np.max(np.abs(r), initial=0.0))
    return y[:n], y[n:], worst


def project_ends_many(fun, starts, p, T, tol: float = 1e-10, max_iter: int = 60) -> list:
    """:func:`project_ends` from several starts at once, one evaluation of ``fun`` per step
    for all of them.

    ``fun(V0, VT, p, T)`` takes the end points as columns (``n x k``) and returns the residuals
    ``(m, k)`` and the Jacobians ``(m, k, 2 n)``; a CasADi function of ``(v0, vT, p, T)``
    evaluates column-stacked arguments in one (mapped) call. Each start follows exactly the
    steps :func:`project_ends` takes from it (its own row scaling, least-norm Gauss-Newton
    steps, step halving); only the evaluations are batched. Returns ``[(v0, vT, largest
    scaled residual)]`` in the order of ``starts``.

    >>> import numpy as np
    >>> def circle(V0, VT, p, T):  # |v0| = 1 (VT is not involved)
    ...     r = (V0**2).sum(axis=0, keepdims=True) - 1.0
    ...     J = np.concatenate([2 * V0.T, 0 * VT.T], axis=1)[None]
    ...     return r, J
    >>> out = project_ends_many(circle, [(np.array([2.0, 0]), np.zeros(2)),
    ...                                  (np.array([0, 0.5]), np.zeros(2))], None, 0.0)
    >>> [np.round(v0, 12).tolist() for v0, _, _ in out]
    [[1.0, 0.0], [0.0, 1.0]]
    """
    k = len(starts)
    if k == 0:
        return []
    n = np.size(starts[0][0])
    Y = np.array([np.concatenate([np.ravel(a), np.ravel(b)]) for a, b in starts],
                 float).T.reshape(2 * n, k)

    def ev(Yc):
        R, J = fun(Yc[:n], Yc[n:], p, T)
        kc = Yc.shape[1]
        R = as_array(R).reshape(-1, kc)
        return R, as_array(J).reshape(R.shape[0], kc, 2 * n)

    R0, J0 = ev(Y)
    if R0.shape[0] == 0:
        return [(Y[:n, i].copy(), Y[n:, i].copy(), 0.0) for i in range(k)]
    nrm = np.linalg.norm(J0, axis=2)  # (m, k)
    sc = 1.0 / np.where(nrm > 1e-300, nrm, 1.0)
    R, J = sc * R0, sc[:, :, None] * J0
    active = list(range(k))
    for _ in range(max_iter):
        active = [i for i in active if not np.max(np.abs(R[:, i])) < tol]
        if not active:
            break
        nr = {i: float(np.linalg.norm(R[:, i])) for i in active}
        d = {i: np.linalg.lstsq(J[:, i], -R[:, i], rcond=1e-12)[0] for i in active}
        step = dict.fromkeys(active, 1.0)
        searching, stopped = list(active), []
        while searching:
            Yn = np.stack([Y[:, i] + step[i] * d[i] for i in searching], axis=1)
            Rn, Jn = ev(Yn)
            still = []
            for c, i in enumerate(searching):
                rn = sc[:, i] * Rn[:, c]
                if np.all(np.isfinite(rn)) and np.linalg.norm(rn) < nr[i]:
                    Y[:, i], R[:, i], J[:, i] = Yn[:, c], rn, sc[:, i, None] * Jn[:, c]
                    continue
                step[i] *= 0.5
                (still if step[i] > 1e-6 else stopped).append(i)
            searching = still
        active = [i for i in active if i not in stopped]
    return [(Y[:n, i].copy(), Y[n:, i].copy(), float(np.max(np.abs(R[:, i]), initial=0.0)))
            for i in range(k)]


def rows_of(fun, rows):
    """``fun`` restricted to the residual rows ``rows`` (for :func:`project_ends`)."""
    rows = np.asarray(rows, dtype=int)

    def sub(v0, vT, p, T):
        r, J = fun(v0, vT, p, T)
        r = as_array(r).ravel()
        J = as_array(J).reshape(r.size, -1)
        return r[rows], J[rows]

    return sub


def conflicting_conditions(
    fun,
    n_fixed: int,
    n_conditions: int,
    starts,
    p,
    T,
    order=None,
    tol: float = 1e-6,
) -> tuple[list[int], bool] | None:
    """A minimal subset of boundary conditions that cannot hold together (deletion filter).

    ``fun(v0, vT, p, T)`` returns the residual and Jacobian (with respect to ``(v0, vT)``) of
    ``n_fixed`` equations that always hold (the algebraic equations and the invariants at both
    ends) followed by the ``n_conditions`` boundary conditions. A set of conditions counts as
    *consistent* when :func:`project_ends` from any of the ``starts`` (pairs ``(v0, vT)``)
    reaches a largest residual below ``tol * max(1, |start|)``; the Gauss-Newton projection can
    stop at a local least-squares point of a consistent nonlinear set, so several starts (one
    perturbed) guard against calling it contradictory.

    Deletion filter: going through the conditions in ``order`` (default: as given; pass them
    by increasing residual at the least-squares point so that those carrying the residual are
    kept), a condition whose removal leaves the rest still contradictory is removed for good.
    What remains is *irreducible*: it is contradictory, and dropping any one of its conditions
    makes it consistent. Returns ``(subset, alone)``; ``alone`` says whether the subset is
    contradictory even without the ``n_fixed`` equations. An empty subset means the fixed
    equations cannot hold by themselves. Returns None when all the conditions are consistent
    after all (a start other than the first reaches them).

    >>> # x(0) = 0, x(T) = 1 and x(T) = x(0) contradict each other; y(0) = 2 plays no part
    >>> def fun(v0, vT, p, T):
    ...     r = np.array([v0[0], vT[0] - 1, vT[0] - v0[0], v0[1] - 2])
    ...     J = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [-1, 0, 1, 0], [0, 1, 0, 0]])
    ...     return r, J
    >>> conflicting_conditions(fun, 0, 4, [(np.zeros(2), np.zeros(2))], None, 1.0)
    ([0, 1, 2], True)
    """
    starts = [(np.asarray(a, float).ravel(), np.asarray(b, float).ravel()) for a, b in starts]

    def consistent(conds, fixed: bool = True) -> bool:
        rows = (list(range(n_fixed)) if fixed else []) + [n_fixed + i for i in conds]
        if not rows:
            return True
        sub = rows_of(fun, rows)
        for a, b in starts:
            lim = tol * max(1.0, float(np.max(np.abs(np.concatenate([a, b])), initial=0.0)))
            if project_ends(sub, a, b, p, T)[2] <= lim:
                return True
        return False

    keep = list(range(n_conditions))
    if consistent(keep):
        return None
    for i in (range(n_conditions) if order is None else order):
        rest = [j for j in keep if j != i]
        if not consistent(rest):
            keep = rest
    return sorted(keep), bool(keep) and not consistent(keep, fixed=False)
