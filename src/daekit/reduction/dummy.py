"""Dummy derivatives (Mattsson & Soderlind 1993), driven by Pryce's offsets.

Every equation ``F_i`` is kept together with *all* its derivatives ``F_i^(k)``, ``k = 0..c_i``.
That gives ``sum c_i`` more equations than the differentiation scheme has; to stay square, as many
derivatives ``x_j^(k)`` (``k < d_j``) stop being states and become algebraic "dummy
derivatives". The invariants are then part of the algebraic equations: nothing is left to drift.

State selection (McKenzie & Pryce 2017, the Mattsson--Soderlind rule on Pryce's stages)
-------------------------------------------------------------------------------------
Let ``J`` be Pryce's system Jacobian, ``J_ij = dF_i^(c_i)/dx_j^(d_j)``, evaluated at a point.
Because ``dF_i^(c_i-s)/dx_j^(d_j-s) = J_ij`` (Griewank's lemma), stage ``s = 1, 2, ...`` works on
the rows ``R_s = {i : c_i >= s}`` and the columns ``C_s`` chosen at stage ``s - 1`` (all columns at
stage 0):

1. ``A = J[R_s, C_s]`` (it has full row rank where ``J`` is nonsingular);
2. QR with column pivoting of ``A`` (``scipy.linalg.qr(A, pivoting=True)``) picks the ``|R_s|``
   best-conditioned columns ``S_s``; the derivatives ``x_j^(d_j - s)``, ``j in S_s``, become
   dummies; ``C_{s+1} = S_s``;
3. ``||A||_2 / sigma_min(A[:, S_s])`` is recorded as the stage's condition number: it measures
   how well the remaining states determine the dummies (1 is ideal).

Big stages (more than 400 equations) are not factored densely (that grows like ``n^3``: 2 s
for a 500-link chain). They are split into blocks (:func:`_stage_blocks`): first every row
that alone uses some columns ("private" columns, e.g. ``v'`` in ``(p' - v)' = p'' - v'``) takes
the largest of them, provided it is at least 0.1 times the row's largest entry (threshold
pivoting), which can make further columns private (a chain is peeled link by link); the rest
is split by a maximum matching and its block triangular form
(:func:`~daekit.structure.dulmage_mendelsohn`, :func:`~daekit.structure.block_triangular`).
Each block gets the dense QR rule above on its own rows and candidate columns; the chosen
matrix is block triangular, so it is nonsingular when every chosen block is. The stage's
``"condition"`` is then the largest block condition number (what :func:`selection_condition`
monitors), and ``"condition_estimate"`` an estimate of ``||A||_1 ||A[:, S_s]^-1||_1`` for the
whole stage (sparse LU, Hager's estimator). A 1000-link chain (5000 equations) is selected in
well under a second.

The states are the derivatives ``x_j^(k)``, ``k < d_j``, that are not dummies, with
``(x_j^(k))' = x_j^(k+1)``; the algebraic unknowns are all highest derivatives and the dummies.
The selection is valid only where the chosen blocks stay nonsingular (a pendulum's ``x`` as
dummy fails where the rod passes ``x = 0``). :func:`selection_condition` measures it at given
values; when it grows (say above 1e3 times its value at selection), call :func:`reselect` at
the current point and continue with the new system (:func:`map_values` carries the values over).

Example
-------
>>> import daekit as dk
>>> from daekit.reduction import reduce_index, selection_condition
>>> m = dk.examples.pendulum_planar()
>>> r = reduce_index(m, method="dummy_derivatives", point={"x": 1.0, "y": 0.0})
>>> r.state_selection["states"], r.state_selection["dummies"]
(['y', 'der(y)'], ['x', 'der(x)'])
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping

import casadi as ca
import numpy as np
import scipy
import scipy.sparse as sp

from .. import numerics
from ..errors import ReductionError
from ..model import Model
from ..numerics import RANK_RTOL
from ..points import check_point
from ..reduced import ReducedDAE
from ..structure import block_triangular, dulmage_mendelsohn
from ..threads import limit_blas_threads
from .assemble import (
    all_symbols,
    assemble,
    invariant_rows,
    pair_names,
    state_pairs,
    top_equations,
)
from .differentiate import derivative_name
from .invariants import attach_declared, declared_dummy
from .reduce import OTHER_METHODS, amended_expansion, check_amendments, check_index1

__all__ = ["dummy_derivatives", "reselect", "selection_condition", "map_values"]


def _point_vector(ex, point: Mapping | None, seed: int):
    """Values for all unknowns up to order d_j, controls up to the needed order, parameters."""
    model = ex.model
    rng = np.random.default_rng(seed)
    vals: dict[tuple[int, int, int], float] = {}
    t = 0.0
    for name, arr in check_point(model, point, ReductionError).items():  # the one check of a user's point
        if name == "t":
            t = float(arr[0])
            continue
        for (var, i, order), a in zip(model.resolve(name), arr, strict=True):
            vals[id(var), i, order] = float(a)

    def get(var, i, order, default):
        return vals.get((id(var), i, order), default)

    X = []
    for j, (var, i) in enumerate(ex.unknowns):
        for k in range(int(ex.d[j]) + 1):
            X.append(get(var, i, k, rng.uniform(0.2, 1.2)))
    U = []
    for var in model.controls:
        for k in range(ex.control_orders.get(var.name, 0) + 1):
            for i in range(var.size):
                U.append(get(var, i, k, rng.uniform(0.2, 1.2)))
    P = []
    for var in model.parameters:
        for i in range(var.size):
            P.append(get(var, i, 0, float(var.default[i])))
    return t, np.asarray(X), np.asarray(U), np.asarray(P)


_DENSE_STAGE = 400  # stages with more equations are split into blocks


def _select(A: np.ndarray, m: int):
    """Columns of the best-conditioned m-by-m block of A (QR with column pivoting)."""
    if A.shape[0] == 1:  # one equation: the largest entry (what the QR would pick)
        cols = np.array([int(np.argmax(np.abs(A[0])))])
    else:
        _, _, piv = scipy.linalg.qr(A, mode="economic", pivoting=True)
        cols = np.sort(piv[:m])
    return cols, _block_condition(A, cols)


def _block_condition(A: np.ndarray, cols) -> float:
    """``||A||_2 / sigma_min(A[:, cols])``: the condition of solving the stage equations for
    the selected columns, relative to the whole stage matrix (so a 1-by-1 block counts too)."""
    if A.shape[0] == 0:
        return 1.0
    if not np.all(np.isfinite(A)):
        return float("inf")
    if A.shape[0] == 1:
        smin, smax = abs(float(A[0, cols[0]])), float(np.linalg.norm(A))
    else:
        smin = np.linalg.svd(A[:, cols], compute_uv=False)[-1]
        smax = np.linalg.norm(A, 2)
    return float(smax / smin) if smin > 0 else float("inf")


def _dense(J: sp.csr_matrix, R, C) -> np.ndarray:
    """``J[R, C]`` as a dense array, read row by row from CSR (fast for small blocks)."""
    where = {int(c): k for k, c in enumerate(C)}
    out = np.zeros((len(R), len(C)))
    for a, i in enumerate(R):
        lo, hi = J.indptr[i], J.indptr[i + 1]
        for c, v in zip(J.indices[lo:hi], J.data[lo:hi], strict=True):
            k = where.get(int(c))
            if k is not None:
                out[a, k] = v
    return out


def _peel(A: sp.csr_matrix, threshold: float = 0.1):
    """Rows that can take a column no other remaining row uses ("private" columns).

    Repeatedly: a column used by one remaining row only is private to it; the row takes its
    private column of largest magnitude when that entry is at least ``threshold`` times the
    row's largest entry (threshold pivoting), and leaves, which may make further columns
    private. Returns ``[(row, private columns)]`` in peeling order and the boolean mask of the
    rows left (the core).
    """
    Ac = A.tocsc()
    m, nc = A.shape
    count = np.diff(Ac.indptr).astype(np.int64)
    alive = np.ones(m, dtype=bool)
    taken = np.zeros(nc, dtype=bool)
    peeled = []
    queue = deque(np.nonzero(count == 1)[0].tolist())
    while queue:
        col = queue.popleft()
        if count[col] != 1 or taken[col]:
            continue
        rows_c = Ac.indices[Ac.indptr[col] : Ac.indptr[col + 1]]
        r = int(next(rr for rr in rows_c if alive[rr]))
        lo, hi = A.indptr[r], A.indptr[r + 1]
        cols_r, vals_r = A.indices[lo:hi], np.abs(A.data[lo:hi])
        priv = [k for k, cc in enumerate(cols_r) if count[cc] == 1 and not taken[cc]]
        best = max(priv, key=lambda k: vals_r[k])
        if not vals_r[best] > 0 or vals_r[best] < threshold * vals_r.max():
            continue  # not a good pivot (yet): the row stays in the core for now
        alive[r] = False
        taken[cols_r[best]] = True
        peeled.append((r, cols_r[priv]))
        for cc in cols_r:
            count[cc] -= 1
            if count[cc] == 1 and not taken[cc]:
                queue.append(int(cc))
    return peeled, alive, taken


def _stage_blocks(J: sp.csr_matrix, R: np.ndarray, C: np.ndarray):
    """Blocks ``(rows, candidates)`` (global indices) of the stage matrix ``A = J[R, C]``.

    1. :func:`_peel`: rows with a private column become one-row blocks whose candidates are
       their private columns.
    2. The remaining core: a maximum matching of its rows to the columns left
       (:func:`dulmage_mendelsohn`) gives a square matrix whose block lower triangular form
       (:func:`block_triangular`) orders the core rows in blocks; every unmatched column joins
       the earliest block whose rows use it.

    Choosing, in every block, as many of its candidates as it has rows keeps the chosen matrix
    block lower triangular (core blocks first, then the peeled rows in reverse order): it is
    nonsingular when every chosen block is. None when a core row cannot be matched.
    """
    A = J[R][:, C].tocsr()
    peeled, alive, taken = _peel(A)
    out = []
    core = np.nonzero(alive)[0]
    if len(core):
        ccols = np.nonzero(~taken)[0]
        Ak = A[core][:, ccols].tocoo()
        m, nc = Ak.shape
        dm = dulmage_mendelsohn(m, nc, Ak.row, Ak.col)
        rm = np.asarray(dm.row_match)
        if np.any(rm < 0):
            return None
        pos = np.full(nc, -1, dtype=np.int64)
        pos[rm] = np.arange(m)
        sq = pos[Ak.col] >= 0
        blocks = block_triangular(m, Ak.row[sq], pos[Ak.col[sq]], np.arange(m))
        blk_of_row = np.empty(m, dtype=np.int64)
        for b, (rows_b, _) in enumerate(blocks):
            blk_of_row[rows_b] = b
        first = np.full(nc, len(blocks), dtype=np.int64)
        np.minimum.at(first, Ak.col[~sq], blk_of_row[Ak.row[~sq]])
        extra = [[] for _ in blocks]
        for col in np.nonzero(first < len(blocks))[0]:
            extra[first[col]].append(int(col))
        for b, (rows_b, _) in enumerate(blocks):
            cand = np.sort(np.concatenate([rm[rows_b], extra[b]]).astype(np.int64))
            out.append((R[core[rows_b]], C[ccols[cand]]))
    for r, priv in reversed(peeled):
        out.append((R[[r]], C[np.sort(priv)]))
    return out


def _condition_estimate(J: sp.csr_matrix, R, C, S) -> float:
    """``||A||_1 ||A_S^-1||_1`` for ``A = J[R, C]``, ``A_S = J[R, S]`` (sparse LU and Hager's
    1-norm estimator, ``scipy.sparse.linalg.onenormest``): the conditioning of the whole stage
    with the chosen columns, which the per-block numbers do not show."""
    A = J[R][:, C]
    AS = sp.csc_matrix(J[R][:, S])
    try:
        lu = sp.linalg.splu(AS)
    except RuntimeError:
        return float("inf")
    n = AS.shape[0]
    inv = sp.linalg.LinearOperator((n, n), matvec=lu.solve, rmatvec=lambda y: lu.solve(y, "T"),
                              dtype=float)
    return float(abs(A).sum(axis=0).max() * sp.linalg.onenormest(inv))


def _deficient_rows(A: np.ndarray, which: bool = True):
    """Positions of the rows of the wide matrix ``A`` in a rank deficiency (its left null
    space; all rows when ``which`` is False), or None when ``A`` has full row rank. Judged
    after row and column equilibration by powers of two, with the tolerance of
    :func:`daekit.analysis.numeric_rank` (``RANK_RTOL * max(shape) * sigma_max``), so badly
    scaled rows are not taken for dependent ones."""
    m = A.shape[0]
    if m == 0:
        return None
    if not np.all(np.isfinite(A)):
        return np.arange(m)
    dr, dc = numerics.equilibrate(A)
    Ae = A * dr[:, None] * dc[None, :]
    s = np.linalg.svd(Ae, compute_uv=False)
    tol = RANK_RTOL * max(A.shape) * s[0] if s.size and s[0] > 0 else np.inf
    rank = int(np.sum(s > tol))
    if rank == m:
        return None
    if not which:
        return np.arange(m)
    U = np.linalg.svd(Ae, full_matrices=False)[0]  # m x m: A is wide
    w = np.linalg.norm(U[:, rank:], axis=1)
    return np.nonzero(w > 1e-8 * w.max())[0]


def _select_stage(J: sp.csr_matrix, R: np.ndarray, C: np.ndarray):
    """Selection for one stage: ``([(rows, candidates, chosen positions, condition)], None)``,
    or ``(None, rows)`` when the equations cannot be solved for any choice (numerically
    singular), with ``rows`` the equations (global indices) at fault: the singular block's
    rows, or the rows in the left null space of the stage matrix.

    Up to ``_DENSE_STAGE`` equations: one dense QR with column pivoting of ``J[R, C]``. Bigger
    stages: per block of :func:`_stage_blocks`, dense QR of each block; if a block turns out
    singular at the point, the whole stage is done densely after all, and when that fails
    too, the block is the one reported.
    """
    if len(R) > len(C):
        return None, R
    failed = None
    if len(R) > _DENSE_STAGE:
        blocks = _stage_blocks(J, R, C)
        out = []
        for Rb, Cb in blocks or []:
            Ab = _dense(J, Rb, Cb)
            cols, cond = _select(Ab, len(Rb)) if len(Cb) > len(Rb) else (
                np.arange(len(Cb)), _block_condition(Ab, np.arange(len(Cb))))
            if not np.isfinite(cond) or cond > 1e12:
                failed = Rb
                break
            out.append((Rb, Cb, cols, cond))
        else:
            if blocks is not None:
                return out, None
    A = _dense(J, R, C)
    bad = _deficient_rows(A, which=failed is None)
    if bad is not None:
        return None, (failed if failed is not None else R[bad])
    cols, cond = _select(A, len(R))
    return [(R, C, cols, cond)], None



#: Most rows of the expansion for which the selection is checked at a consistent point.
CONSISTENT_SELECTION_LIMIT = 100


def _at_consistent_point(ex, Jf, Xs, Us, J, blocks, seed: int):
    """The system Jacobian at a consistent point (the expansion holds, :mod:`daekit.points`),
    entries that vanish on the solutions removed (:func:`daekit.numerics.vanishing_removed`
    against ``J``, the random point's), when a block chosen at the random point is singular
    there; else None (also when no consistent point is found or the model is big). A
    constraint times ``1.5 + sin(y)`` has ``d/dy`` = the constraint times ``cos(y)``: large
    at a random point, so that ``y`` was chosen a dummy, and zero on the solutions, where the
    selection then failed silently (a DOF lost)."""
    from ..points import TestPoint, consistent_point

    levels = ca.vertcat(*ex.levels)
    if levels.numel() > CONSISTENT_SELECTION_LIMIT or not blocks:
        return None
    model = ex.model
    pt = TestPoint(model, None, seed)
    if not consistent_point(pt, levels).consistent:
        return None
    P0 = np.asarray(model.parameter_values, dtype=float)
    X0 = pt.evaluate(ca.vertsplit(Xs))
    U0 = pt.evaluate(ca.vertsplit(Us)) if Us.numel() else np.zeros(0)
    Jc = numerics.to_scipy(ca.DM(Jf(pt.t, X0, U0, P0))).tocsr()
    if not np.all(np.isfinite(Jc.data)) or Jc.shape != J.shape:
        return None
    Jc = numerics.vanishing_removed(Jc, J)
    for Rb, Cb, cols in blocks:
        A = _dense(Jc, Rb, Cb)[:, cols]
        if numerics.rank_info(A).rank < len(Rb):
            return Jc
    return None


@limit_blas_threads
def dummy_derivatives(
    model: Model, point: Mapping | None = None, check: bool = True, seed: int = 0
) -> ReducedDAE:
    """Index-1 system by dummy derivatives; same as ``reduce_index(model, "dummy_derivatives")``.

    Parameters
    ----------
    model : daekit.Model
    point : dict, optional
        Values by original name (``{"x": 1.0, "y": 0.0, "der(x)": 0.0}``) at which the state
        selection is made (use the initial point); missing values are random (seeded).
    check : bool
        Check that the result is index 1 at random points.
    seed : int
        Seed of the random values.

    Returns
    -------
    ReducedDAE
        ``r.state_selection`` holds ``"states"``, ``"dummies"`` (original names), ``"stages"``
        (per stage: the equations, candidates, dummies chosen, condition number, number of
        blocks, and for stages done per block ``"condition_estimate"``),
        ``"condition"`` (largest stage condition number) and ``"point"``.

    Example
    -------
    >>> import daekit as dk
    >>> r = dummy_derivatives(dk.examples.pendulum_planar(), point={"x": 0.0, "y": -1.0})
    >>> r.x_names, r.state_selection["condition"]
    (['x', 'der(x)'], 1.0)
    """
    ex, amendments = amended_expansion(model, seed=seed)
    n, c, d = ex.n, ex.c, ex.d
    top = top_equations(ex)
    hi = ex.unknown(d, range(n))
    Jsym = ca.jacobian(top, hi)
    Xs, Us = all_symbols(ex)
    Jf = ca.Function("J", [model.t, Xs, Us, model.parameter_symbols], [Jsym])
    t0, X0, U0, P0 = _point_vector(ex, point, seed)
    J = numerics.to_scipy(ca.DM(Jf(t0, X0, U0, P0))).tocsr()
    if not np.all(np.isfinite(J.data)):
        raise ReductionError(
            f"model {model.name!r}: the system Jacobian is not finite at the selection point; "
            "give a point inside the model's domain: reduce_index(model, 'dummy_derivatives', "
            "point={...})"
        )
    eq_names = ex.equation_names

    def select(J):
        """The stages' selection from the system Jacobian ``J`` (CSR)."""
        selected = np.arange(n)
        dummy: set[tuple[int, int]] = set()
        stages, blocks = [], []
        for s in range(1, int(c.max(initial=0)) + 1):
            R = np.nonzero(c >= s)[0]
            C = selected[d[selected] >= s]
            chosen, bad_rows = _select_stage(J, R, C)
            if chosen is None:
                bad = [derivative_name(eq_names[i], int(c[i]) - s) for i in bad_rows]
                shown = ", ".join(repr(b) for b in bad[:12]) + (
                    f" ... ({len(bad)} equations)" if len(bad) > 12 else "")
                raise ReductionError(
                    f"model {model.name!r}: dummy-derivative selection failed at stage {s}: the "
                    f"equations {shown} cannot be solved for any choice of derivatives at the "
                    "selection point (the system Jacobian is singular there); give another point "
                    "(point={...}) or use method='differentiate'"
                )
            S = np.sort(np.concatenate([Cb[cols] for _, Cb, cols, _ in chosen]))
            for j in S:
                dummy.add((int(j), int(d[j]) - s))
            stages.append(
                {
                    "stage": s,
                    "equations": [derivative_name(eq_names[i], int(c[i]) - s) for i in R],
                    "candidates": [ex.unknowns[j][0].element(ex.unknowns[j][1], int(d[j]) - s)
                                   for j in C],
                    "dummies": [ex.unknowns[j][0].element(ex.unknowns[j][1], int(d[j]) - s)
                                for j in S],
                    "condition": max(cond for *_, cond in chosen),
                    "blocks": len(chosen),
                }
            )
            if len(chosen) > 1:
                stages[-1]["condition_estimate"] = _condition_estimate(J, R, C, S)
            blocks += [(Rb, Cb, cols) for Rb, Cb, cols, _ in chosen]
            selected = S

        return stages, blocks, dummy

    stages, blocks, dummy = select(J)
    if point is None:
        Jc = _at_consistent_point(ex, Jf, Xs, Us, J, blocks, seed)
        if Jc is not None:  # a chosen block singular on the solutions: select there
            stages, blocks, dummy = select(Jc)
            for st in stages:
                st["at"] = "a consistent point"

    states = state_pairs(ex, skip=lambda j, k: (j, k) in dummy)
    dpairs = sorted(dummy, key=lambda jk: (jk[1], jk[0]))
    zpairs = [(j, int(d[j])) for j in range(n)] + dpairs
    alg = ca.vertcat(*ex.levels)
    alg_names = [derivative_name(eq_names[i], k) for k, rk in enumerate(ex.rows) for i in rk]
    inv, inv_names, chains = invariant_rows(ex)
    r = assemble(ex, states, zpairs, alg, inv, inv_names, "dummy_derivatives")
    r.state_selection = {
        "states": list(r.x_names),
        "dummies": pair_names(ex, dpairs),
        "stages": stages,
        "condition": max([st["condition"] for st in stages], default=1.0),
        "point": dict(point) if point else None,
        "rule": "QR with column pivoting of J[R_s, C_s] per stage (Mattsson-Soderlind on "
        "Pryce's stages); stages above 400 equations per block (private columns by threshold "
        "pivoting, then block triangular form)",
    }
    r.alg_names = alg_names
    r.chains = []  # invariants are part of alg: nothing to stabilize
    r.offsets = {"c": c.copy(), "d": d.copy()}
    r.amendments = amendments
    n_found = len(r.invariant_names)  # declared invariants (m.invariant): one dummy state each
    declared_dummy(attach_declared(r, model, check=check, seed=seed), n_found, point, seed)
    dec = r.declared_selection
    if dec:  # their gradient G joins J as one more diagonal block, watched like the stages
        Gsym = dec["expression"]
        k, nc = Gsym.shape
        Jsym = ca.diagcat(Jsym, Gsym)
        blocks = blocks + [(np.arange(n, n + k), np.arange(n, n + nc), dec["cols"])]
    r.selection_jacobian = ca.Function("J", [r.t, r.x, r.z, r.u, r.p], [Jsym])
    r.selection_blocks = blocks
    if check:
        check_index1(r, seed=seed)
        if amendments:  # the DOF and the model's equations at its solutions, as for
            check_amendments(model, r, seed=seed)  # method="differentiate"
    return r


def selection_condition(r: ReducedDAE, x, z, u=None, p=None, t: float = 0.0) -> float:
    """How well the current dummy-derivative selection of ``r`` is conditioned at given values.

    Returns the largest, over the stages, of ``||J[R_s, C_s]|| / sigma_min(J[R_s, S_s])``
    (the selected block ``S_s`` among the candidates ``C_s``) of Pryce's system Jacobian at
    ``(t, x, z, u, p)``: arrays in the order of ``r.x``, ``r.z``, ``r.u``, ``r.p``; ``u``
    defaults to zeros and ``p`` to ``r.p_values``. ``inf`` where a block is singular.
    Compare with ``r.state_selection["condition"]`` (its value at selection) and call
    :func:`reselect` when it has grown by orders of magnitude.

    >>> import daekit as dk, numpy as np
    >>> r = dummy_derivatives(dk.examples.pendulum_planar(), point={"x": 0.0, "y": -1.0})
    >>> vals = {"x": 1.0, "der(x)": 0.0, "y": 0.0, "der(y)": 0.0}
    >>> x = np.array([vals[n] for n in r.x_names]); z = np.zeros(r.nz)
    >>> z[r.z_names.index("y")] = 1e-9      # near x = 1, y = 0: y is a bad dummy
    >>> selection_condition(r, x, z) > 1e6
    True
    """
    if r.method != "dummy_derivatives":
        raise ReductionError(
            "selection_condition needs a ReducedDAE made with method='dummy_derivatives'"
        )
    x = _sized(x, r.nx, "x", r.x_names)
    z = _sized(z, r.nz, "z", r.z_names)
    u = np.zeros(r.nu) if u is None else _sized(u, r.nu, "u", r.u_names)
    p = r.p_values if p is None else _sized(p, r.n_p, "p", r.p_names)
    try:
        t = float(t)
    except (TypeError, ValueError):
        raise ReductionError(f"selection_condition: t must be one number, got {t!r}") from None
    J = numerics.to_scipy(ca.DM(r.selection_jacobian(t, x, z, u, p))).tocsr()
    worst = 1.0
    for R, C, cols in r.selection_blocks:
        worst = max(worst, _block_condition(_dense(J, R, C), cols))
    return worst


def _sized(value, size: int, what: str, names) -> np.ndarray:
    """``value`` as ``size`` floats; a ReductionError naming the argument otherwise."""
    try:
        arr = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.size != size:
        got = "not numbers" if arr is None else f"{arr.size} values"
        shown = ", ".join(names[:6]) + (", ..." if len(names) > 6 else "")
        raise ReductionError(
            f"selection_condition: {what} must be {size} numbers in the order of r.{what}_names "
            f"({shown}); got {got}"
        )
    return arr


def _named_values(r: ReducedDAE, x, z) -> dict[str, float]:
    x = np.asarray(x, dtype=float).ravel()
    z = np.asarray(z, dtype=float).ravel()
    out = dict(zip(r.x_names, x.tolist(), strict=True))
    out.update(zip(r.z_names, z.tolist(), strict=True))
    return out


def map_values(r_from: ReducedDAE, r_to: ReducedDAE, x, z) -> tuple[np.ndarray, np.ndarray]:
    """Carry values ``(x, z)`` of one dummy-derivative system over to another selection.

    Both systems have the same unknowns (every derivative up to its offset), only split
    differently into states and algebraic variables, so this is a renaming.
    """
    vals = _named_values(r_from, x, z)
    try:
        return (
            np.array([vals[n] for n in r_to.x_names]),
            np.array([vals[n] for n in r_to.z_names]),
        )
    except KeyError as exc:
        raise ReductionError(
            f"map_values: {exc.args[0]!r} is not an unknown of the source system; both systems "
            "must come from the same model by dummy derivatives"
        ) from None


def reselect(r: ReducedDAE, point, seed: int = 0) -> ReducedDAE:
    """Make a new dummy-derivative selection of ``r.model`` at ``point``.

    ``point``: a dict of values by original name, or a tuple ``(x, z)`` of values of ``r``'s own
    ``r.x``, ``r.z`` (e.g. the current state of a simulation). Carry the state over with
    :func:`map_values`.

    >>> import daekit as dk, numpy as np
    >>> r = dummy_derivatives(dk.examples.pendulum_planar(), point={"x": 0.0, "y": -1.0})
    >>> r2 = reselect(r, {"x": 1.0, "y": 0.0})
    >>> r2.x_names
    ['y', 'der(y)']
    """
    if r.model is None:
        raise ReductionError("reselect needs the original model (r.model is None)")
    if isinstance(point, tuple) and len(point) == 2:
        point = _named_values(r, point[0], point[1])
    return dummy_derivatives(r.model, point=point, seed=seed)


OTHER_METHODS["dummy_derivatives"] = dummy_derivatives  # reduce_index(m, method=...)
