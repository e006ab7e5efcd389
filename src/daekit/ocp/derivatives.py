"""Closed-form derivatives for NLPs built from a model evaluated at many points.

Both the collocation NLP and the default guess's blend are ``f(V, Q)``, ``g(V, Q)`` with
``Q = q(y_k)`` a small model function mapped over points ``k`` whose local unknowns ``y_k``
are entries of the decision vector ``V`` (``pts[k]``). CasADi's AD of the whole NLP then costs
more to build than the solve itself; the chain rule through the per-point Jacobians and
Hessians of ``q`` (small SX functions, mapped) gives the same derivatives, cheap to build and
to evaluate. The helpers here place per-point values into the NLP's sparse matrices.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["dm_triplet", "pattern", "summed_pattern", "point_jacobian", "point_hessian",
           "quadratic_composite"]


def _ccs(nrow, ncol, keys):
    """The sparsity of the sorted distinct column-major keys ``col * nrow + row``."""
    cols = keys // nrow
    colind = np.searchsorted(cols, np.arange(ncol + 1), side="left")
    return _compressed(nrow, ncol, colind, keys % nrow)


def _compressed(nrow, ncol, colind, rows):
    """A Sparsity from compressed columns, passed to CasADi as one list (measured 0.31 against
    0.45 ms for ``Sparsity(nrow, ncol, colind, rows)`` with 9000 nonzeros)."""
    return ca.Sparsity.compressed(
        np.concatenate([[nrow, ncol], colind, rows]).astype(np.int64).tolist())


def dm_triplet(nrow, ncol, rows, cols, vals) -> ca.DM:
    """A sparse DM from entries (duplicates summed).

    >>> dm_triplet(2, 2, [0, 1, 0], [0, 1, 0], [1.0, 2.0, 3.0]).full().tolist()
    [[4.0, 0.0], [0.0, 2.0]]
    """
    key = np.asarray(cols, np.int64) * nrow + np.asarray(rows, np.int64)
    uniq, inv = np.unique(key, return_inverse=True)
    data = np.bincount(inv.ravel(), weights=np.asarray(vals, float).ravel(),
                       minlength=uniq.size)
    return ca.DM(_ccs(nrow, ncol, uniq), data.tolist())


def pattern(nrow, ncol, rows, cols):
    """The sparsity of distinct entries ``(rows, cols)`` and the permutation that puts
    values given in entry order into its (column-major) nonzero order."""
    key = np.asarray(cols, np.int64) * nrow + np.asarray(rows, np.int64)
    order = np.argsort(key, kind="stable")
    return _ccs(nrow, ncol, key[order]), order


def summed_pattern(n, rows, cols):
    """The sparsity of the entries ``(rows, cols)`` (duplicates summed) and the 0/1 matrix
    that sums values given in entry order into its nonzeros."""
    key = np.asarray(cols, np.int64) * n + np.asarray(rows, np.int64)
    uniq, inv = np.unique(key, return_inverse=True)
    # one 1 per column (entry e sums into nonzero inv[e]), given in compressed columns
    A = _compressed(int(uniq.size), int(key.size), np.arange(key.size + 1), inv.ravel())
    return _ccs(n, n, uniq), ca.DM(A, 1.0)


def point_jacobian(q, y, syms, args, pts, nV) -> ca.MX:
    """``dQ/dV`` (rows ``k nq + i``): the Jacobian of the point function ``q(syms)`` with
    respect to its local unknowns ``y``, mapped over the points (``args``: the mapped
    arguments, ``pts[k]``: the decision-vector index of each entry of ``y`` at point ``k``)."""
    M = pts.shape[0]
    nq = int(q.numel())
    jf = ca.Function("jq", syms, [ca.jacobian(q, y)])
    jr, jc = (np.asarray(v, int) for v in jf.sparsity_out(0).get_triplet())
    if jr.size == 0:
        return ca.MX(nq * M, nV)
    sp, perm = pattern(nq * M, nV, (np.arange(M).reshape(-1, 1) * nq + jr).ravel(),
                       pts[:, jc].ravel())
    return ca.MX(sp, ca.vec(jf.map(M)(*args).nz[:])[perm.tolist()])


def point_hessian(q, y, syms, args, lq, pts, nV):
    """The upper triangle of ``sum_k d^2 (lq_k . q(y_k)) / dV^2`` (``lq``: ``nq x M``), or None
    when ``q`` is linear in ``y``."""
    M = pts.shape[0]
    lq_s = ca.SX.sym("lq", q.numel())
    hf = ca.Function("hq", [*syms, lq_s], [ca.triu(ca.hessian(ca.dot(lq_s, q), y)[0])])
    hr, hc = (np.asarray(v, int) for v in hf.sparsity_out(0).get_triplet())
    if hr.size == 0:
        return None
    gr, gc = pts[:, hr].ravel(), pts[:, hc].ravel()
    sp, S = summed_pattern(nV, np.minimum(gr, gc), np.maximum(gr, gc))
    return ca.MX(sp, ca.mtimes(S, ca.vec(hf.map(M)(*args, lq).nz[:])))


def quadratic_composite(V, Q, f, g, q, y, syms, args, pts, residuals=None) -> tuple:
    """For ``f`` quadratic in ``(V, Q)`` and ``g`` linear in ``Q`` alone (MX in the symbols ``V``
    and ``Q``), with ``Q = q`` mapped over the points: ``(f, g, options)``, the NLP with ``Q``
    replaced and IPOPT's ``jac_g``/``hess_lag``/``grad_f`` in closed form.

    ``residuals = (r, c)`` with ``f = |r|^2 + c``, ``r`` and ``c`` linear in ``(V, Q)``: the
    constant Hessian of ``f`` is then ``2 R^T R`` (``R``: the constant Jacobian of ``r``), one
    first-order derivative instead of a second-order one.

    >>> V = ca.MX.sym("V", 2); Q = ca.MX.sym("Q", 1, 2)
    >>> x = ca.SX.sym("x"); q = x**2
    >>> pts = np.array([[0], [1]])
    >>> f, g, opts = quadratic_composite(V, Q, ca.sumsqr(Q - 1), Q[0, 0], q, x, [x],
    ...                                  [ca.reshape(V, 1, 2)], pts)
    >>> float(opts["hess_lag"](ca.DM([2, 3]), [], 1.0, 0.5)[1, 1])  # 12 x^2 - 4 at x = 3
    104.0
    """
    nV, M = int(V.numel()), pts.shape[0]
    nq = int(q.numel())
    Qv = ca.vec(Q)
    Qval = ca.Function("q", syms, [q]).map(M)(*args)
    fg = ca.Function("fg", [V, Q], [f, g])
    f_real, g_real = fg(V, Qval)
    D = point_jacobian(q, y, syms, args, pts, nV)
    zV, zQ = ca.DM.zeros(nV), ca.DM.zeros(nq, M)
    W = ca.vertcat(V, Qv)
    if residuals is None:
        Hf = ca.Function("Hf", [V, Q], [ca.hessian(f, W)[0]])(zV, zQ)  # constant
        GQ = ca.Function("GQ", [V, Q], [ca.jacobian(g, Qv)])(zV, zQ)
        grad = ca.Function("gr", [V, Q], [ca.gradient(f, V), ca.gradient(f, Qv)])
        fV, fQ = grad(V, Qval)
    else:
        r, c = residuals
        c = ca.MX(c) if not isinstance(c, ca.MX) else c
        R, gc, GQ = ca.Function("lin", [V, Q], [ca.jacobian(r, W), ca.gradient(c, W),
                                                 ca.jacobian(g, Qv)])(zV, zQ)
        R, gc = ca.DM(ca.sparsify(R)), ca.DM(ca.sparsify(gc))
        Hf = 2 * ca.mtimes(R.T, R)
        fW = 2 * ca.mtimes(R.T, ca.Function("r", [V, Q], [r])(V, Qval)) + gc
        fV, fQ = fW[:nV], fW[nV:]
    Hf = ca.DM(ca.sparsify(Hf))
    fVV, fVQ, fQQ = Hf[:nV, :nV], Hf[:nV, nV:], Hf[nV:, nV:]
    GQ = ca.DM(ca.sparsify(GQ))
    p_in = ca.MX.sym("p", 0)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.numel())
    BD = ca.mtimes(fVQ, D)
    H = lam_f * (fVV + BD + BD.T + ca.mtimes(D.T, ca.mtimes(fQQ, D)))
    lq = lam_f * fQ + ca.mtimes(GQ.T, lam_g)
    Hp = point_hessian(q, y, syms, args, ca.reshape(lq, nq, M), pts, nV)
    if Hp is not None:
        H = ca.triu(H) + Hp
    opts = {
        "grad_f": ca.Function("nlp_grad_f", [V, p_in],  # IPOPT takes a dense gradient
                              [f_real, ca.densify(fV + ca.mtimes(D.T, fQ))]),
        "jac_g": ca.Function("nlp_jac_g", [V, p_in], [g_real, ca.mtimes(GQ, D)]),
        "hess_lag": ca.Function("nlp_hess_l", [V, p_in, lam_f, lam_g], [ca.triu(H)]),
    }
    return f_real, g_real, opts
