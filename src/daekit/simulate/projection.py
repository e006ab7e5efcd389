"""Projection onto the consistency manifold ``{alg = 0, invariants = 0}``, by drift tolerance.

After integration the states of an index-1 reduction drift off the manifold on which the
invariants hold (the pendulum's ``c`` and ``c'``). :class:`Projector` moves them back by the
smallest change of ``x`` in a weighted norm (the algebraic unknowns ``z`` follow freely, as
``alg = 0`` defines them): each Gauss--Newton iteration solves the sparse KKT system

    [ D    J^T ] [dw]   [ 0 ]
    [ J    0   ] [ l] = [-h ],     h = [alg; invariants],  w = (x, z),  D = diag(W, 0)

with ``J = dh/dw`` in CasADi's sparse form, factored by SciPy's sparse LU (no dense matrix:
a 500-link chain projects in milliseconds). ``W`` is the metric on ``x``; by default each
state is weighted by ``1 / (atol + rtol |x_i|)^2``, the norm IDAS measures its errors in, so the
projection changes what the integrator considers accurate as little as possible. (A mass-matrix
metric for mechanical systems is not used yet.) See Hairer, Lubich, Wanner, *Geometric
Numerical Integration*, ch. IV.4.

:class:`DriftMonitor` is the driver's monitor for ``stabilization="projection"``: IDAS runs on
undisturbed until ``max |invariant|`` exceeds ``drift_tol`` at a check point; the state is then
projected at the last check point where the drift was still within the tolerance (located by
re-integration if that is the segment's start), and integration restarts from there. The
default ``drift_tol`` is :func:`default_drift_tol` ``= 100 atol``.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import scipy.sparse as sp

from ..errors import SimulationError
from ..numerics import FastFunction
from .driver import Action, Firing, Monitor, Segment
from .vectorized import evaluate_columns, evaluate_rows, fast_call, rows_equal, spd_inverse

__all__ = ["Projector", "DriftMonitor", "default_drift_tol"]


def default_drift_tol(rtol: float, atol: float) -> float:
    """The default drift tolerance of ``stabilization="projection"``: ``100 atol``.

    Right after any (re)start IDAS's own local errors put the invariants at the level of the
    error weights (``atol + rtol |x|``) within a few steps, so a tolerance near ``atol`` would
    fire again at once and turn projection into restarts at every few steps; a hundred times
    that leaves room for long undisturbed runs (measured on the pendulums: a handful of
    projections per 100 s) while keeping the drift far below that of the plain index-1 form.

    >>> default_drift_tol(1e-6, 1e-8)
    1e-06
    """
    return 100.0 * float(atol)


class Projector:
    """Projects ``(x, z)`` onto ``{alg = 0, invariants = 0}`` at a given time, inputs, params.

    Parameters
    ----------
    r : ReducedDAE
    weights : array, optional
        The metric ``W`` on ``x`` (a vector: diagonal); default all ones. Use
        :meth:`set_tolerances` for IDAS's error weights.

    Example
    -------
    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> from daekit.simulate.projection import Projector
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x", 2); z = ca.SX.sym("z")
    >>> r = ReducedDAE(t, x, z, ca.SX(0, 1), ca.SX(0, 1), ca.vertcat(-x[1], x[0]), z - x[0],
    ...     ca.dot(x, x) - 1, ["circle"], ["x[0]", "x[1]"], ["z"], [], [], np.zeros(0))
    >>> xp, zp, dist = Projector(r)(0.0, np.array([1.1, 0.0]), np.array([1.1]), [], [])
    >>> np.round(xp, 12).tolist(), round(float(zp[0]), 12)
    ([1.0, 0.0], 1.0)
    """

    def __init__(self, r, weights=None) -> None:
        self.nx, self.nz = r.nx, r.nz
        alg = ca.vec(r.alg) if r.alg.numel() else ca.SX(0, 1)
        h = ca.vertcat(alg, ca.vec(r.invariants)) if r.invariants.numel() else alg
        w = ca.vertcat(r.x, r.z)
        self.nh = int(h.numel())
        J = ca.jacobian(h, w)
        d = ca.SX.sym("d", self.nx)  # the metric's diagonal on x
        reg = ca.SX.sym("reg")
        n = self.nx + self.nz
        D = ca.diag(ca.vertcat(d, ca.SX(self.nz, 1)))
        D = ca.SX(ca.Sparsity.diag(n), ca.vertcat(d, ca.SX.zeros(self.nz))) if n else D
        K = ca.blockcat([[D, J.T], [J, -reg * ca.SX.eye(self.nh)]])
        self.fun = ca.Function("proj", [r.t, w, r.u, r.p], [h])
        self.kkt = ca.Function("proj_kkt", [r.t, w, r.u, r.p, d, reg], [h, K])
        self.weights = np.ones(self.nx) if weights is None else np.asarray(weights, float)
        self.rtol = self.atol = None
        self.stats = {"projections": 0, "projection_iterations": 0}
        self._ksp = None
        self._lu = None
        self._dense = None
        self._symbolic = False
        self._step_fast: FastFunction | None = None
        self._maps: dict[int, ca.Function] = {}

    def set_tolerances(self, rtol: float, atol: float) -> None:
        """Weight ``x_i`` by ``1 / (atol + rtol |x_i|)^2`` at the point projected."""
        self.rtol, self.atol = float(rtol), float(atol)

    def _metric(self, x: np.ndarray) -> np.ndarray:
        if self.rtol is None:
            return self.weights
        wx = 1.0 / (self.atol + self.rtol * np.abs(x)) ** 2
        return wx / np.max(wx, initial=1.0)

    def _h(self, t, w, u, p) -> np.ndarray:
        return np.asarray(self.fun(t, w, u, p), dtype=float).ravel()

    def _factor(self, t, w, u, p, dmet):
        """Sparse LU of the KKT matrix at ``w`` (nonzeros straight into NumPy)."""
        F = self.kkt
        if self._ksp is None:
            sp_ = F.sparsity_out(1)
            colind, row = sp_.get_ccs()
            self._ksp = (np.asarray(row), np.asarray(colind), sp_.shape)
        row, colind, shape = self._ksp
        for reg in (0.0, 1e-12, 1e-8):
            out = fast_call(F, dict(zip(F.name_in(), [np.atleast_1d(float(t)), w, u, p, dmet,
                                                      np.atleast_1d(reg)], strict=True)),
                            {F.name_out(1): (F.nnz_out(1),)})
            K = sp.csc_matrix((out[F.name_out(1)], row, colind), shape=shape)
            try:
                with np.errstate(all="ignore"):
                    return sp.linalg.splu(K)
            except RuntimeError:
                continue
        return None

    def __call__(self, t, x, z, u, p, tol: float = 1e-13, max_iter: int = 20,
                 reuse: bool = False):
        """Return ``(x, z, max |dx|)``; raises :class:`SimulationError` if it cannot converge."""
        w = np.concatenate([np.asarray(x, float).ravel(), np.asarray(z, float).ravel()])
        w0 = w.copy()
        u = np.asarray(u, dtype=float).ravel()
        p = np.asarray(p, dtype=float).ravel()
        if self._dense is None and self.nx + self.nz + self.nh <= 96:
            self._build(u.size, p.size)
        if self._symbolic:
            w, res = self._point_by_steps(t, w, u, p, tol, max_iter)
        else:
            w, res = self._point_by_kkt(t, w, u, p, tol, max_iter, reuse)
        if not np.isfinite(res) or res > 1e-8 * (1.0 + float(np.max(np.abs(w), initial=0.0))):
            raise SimulationError(
                f"projection onto the invariants failed at t = {t:g} (residual {res:.3g}); the "
                "constraint Jacobian may have lost rank there, or the state left the manifold too "
                "far: use tighter tolerances or a smaller drift_tol",
                t=float(t),
            )
        self.stats["projections"] += 1
        dx = float(np.max(np.abs(w[: self.nx] - w0[: self.nx]), initial=0.0))
        return w[: self.nx], w[self.nx:], dx

    def _point_by_steps(self, t, w, u, p, tol, max_iter):
        """Gauss--Newton at one point by the generated step function (small systems: one
        buffered call per iteration, microseconds)."""
        if self._step_fast is None:
            self._step_fast = FastFunction(self._dense)
        nx = self.nx
        d = np.empty(w.size)
        if self.rtol is not None:
            sx = self.atol + self.rtol * np.abs(w[:nx])
            d[:nx] = sx * sx  # D^+ on x (its scale does not matter); z: free (large)
        else:
            d[:nx] = 1.0 / self.weights
        d[nx:] = 1e8 * np.max(d[:nx], initial=1.0)
        tt = np.array([float(t)])
        res = np.inf
        for _ in range(max_iter + 1):
            hv, dw = self._step_fast(tt, w, u, p, d)[:2]
            res = float(np.max(np.abs(hv), initial=0.0))
            if not np.isfinite(res) or res <= tol * (1.0 + float(np.max(np.abs(w), initial=0.0))):
                break
            if not np.all(np.isfinite(dw)):
                break
            w = w + dw
            self.stats["projection_iterations"] += 1
        return w, res

    def _point_by_kkt(self, t, w, u, p, tol, max_iter, reuse):
        """Gauss--Newton at one point with the sparse KKT matrix (sparse LU)."""
        dmet = self._metric(w[: self.nx])
        res = np.inf
        n = w.size
        lu = self._lu if reuse else None  # simplified Newton: an LU from a nearby point
        last = np.inf
        for _ in range(max_iter):
            hv = self._h(t, w, u, p)
            res = float(np.max(np.abs(hv), initial=0.0))
            if not np.isfinite(res) or res <= tol * (1.0 + float(np.max(np.abs(w), initial=0.0))):
                break
            if lu is None or res > 0.5 * last:  # (re)factor when convergence is slow
                lu = self._factor(t, w, u, p, dmet)
                if lu is None:
                    break
            last = res
            sol = lu.solve(np.concatenate([np.zeros(n), -hv]))
            if not np.all(np.isfinite(sol)):
                break
            w = w + sol[:n]
            self.stats["projection_iterations"] += 1
        else:
            res = float(np.max(np.abs(self._h(t, w, u, p)), initial=0.0))
        self._lu = lu
        return w, res


    def project_rows(self, T, X, Z, U, p, iters: int = 6, chunk: int = 4096):
        """Project many rows at once (the recorded output points): batched Gauss--Newton with
        the minimum-norm step ``dw = -D^+ J^T (J D^+ J^T)^{-1} h`` (small ``nh x nh`` solves,
        ``z`` free) where ``nx + nz + nh <= 96``, in chunks of ``chunk`` rows; else row by row
        with the sparse KKT. ``h`` and its Jacobian are evaluated for all rows at once
        (:func:`daekit.simulate.vectorized.evaluate_rows`); the first step's matrix is kept
        for the next steps (simplified Newton: rows within drift_tol converge in one or two),
        only rows not yet converged are iterated, and those still far off get a new Jacobian.
        Returns ``(X, Z)``; rows that do not converge stay as they were."""
        T = np.asarray(T, float).ravel()
        X = np.array(X, dtype=float, copy=True)
        Z = np.array(Z, dtype=float, copy=True)
        N, nx, nz, nh = T.size, self.nx, self.nz, self.nh
        n = nx + nz
        if N == 0 or nh == 0:
            return X, Z
        if n + nh > 96:
            for i in range(N):
                try:
                    X[i], Z[i], _ = self(T[i], X[i], Z[i], U[i], p, reuse=i > 0)
                except SimulationError:
                    pass
                self.stats["projections"] -= 1  # output projections are not counted
            return X, Z
        U = np.asarray(U, float).reshape(N, -1)
        for a in range(0, N, chunk):
            b = min(N, a + chunk)
            X[a:b], Z[a:b] = self._project_chunk(T[a:b], X[a:b], Z[a:b], U[a:b], p, iters)
        return X, Z

    #: up to this many equations in ``h`` a projected row's Gauss--Newton step is one
    #: generated function (Cholesky of ``J D^+ J^T`` written out), evaluated for all rows at
    #: once by :func:`~daekit.simulate.vectorized.evaluate_rows`; beyond, batched NumPy
    SYMBOLIC_STEP_MAX_NH = 12

    def _step_function(self, nu: int, npar: int) -> tuple[ca.Function, ca.Function]:
        """``(t, w, u, p, d) -> (h, dw, L, JD)``: the minimum-norm Gauss--Newton step
        ``dw = -D J^T (J D J^T)^{-1} h`` with ``D = diag(d)`` as one SX function (``J`` sparse,
        the Cholesky factor ``L`` of the ``nh x nh`` matrix written out: a singular
        ``J D J^T`` gives NaN), with ``L`` (lower triangle, by rows) and the nonzeros of
        ``J D`` for simplified steps; and ``(L, JD, h) -> dw``, such a step with them."""
        n, nh = self.nx + self.nz, self.nh
        w, t = ca.SX.sym("w", n), ca.SX.sym("t")
        u, pp, d = ca.SX.sym("u", nu), ca.SX.sym("p", npar), ca.SX.sym("d", n)
        h = self.fun(t, w, u, pp)
        J = ca.jacobian(h, w)
        JD = ca.mtimes(J, ca.diag(d))
        M = ca.mtimes(JD, J.T)
        L = [[ca.SX(0)] * nh for _ in range(nh)]
        for j in range(nh):
            L[j][j] = ca.sqrt(M[j, j] - sum((L[j][k] ** 2 for k in range(j)), ca.SX(0)))
            for i in range(j + 1, nh):
                L[i][j] = (M[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), ca.SX(0))) \
                    / L[j][j]
        low = [(i, j) for i in range(nh) for j in range(i + 1)]
        step = ca.Function("proj_step", [t, w, u, pp, d],
                           [h, ca.densify(_min_norm_step(L, JD, h)),
                            ca.vertcat(*[L[i][j] for i, j in low]),
                            ca.vertcat(*JD.nonzeros()) if JD.nnz() else ca.SX(0, 1)])
        Ls = ca.SX.sym("L", len(low))
        Lm = [[ca.SX(0)] * nh for _ in range(nh)]
        for k, (i, j) in enumerate(low):
            Lm[i][j] = Ls[k]
        jd = ca.SX.sym("jd", JD.nnz())
        hs = ca.SX.sym("h", nh)
        JDs = ca.SX(JD.sparsity(), jd)
        simple = ca.Function("proj_simplified", [Ls, jd, hs],
                             [ca.densify(_min_norm_step(Lm, JDs, hs))])
        return step, simple

    def _build(self, nu: int, npar: int) -> None:
        n = self.nx + self.nz
        w = ca.SX.sym("w", n)
        t, u = ca.SX.sym("t"), ca.SX.sym("u", nu)
        pp = ca.SX.sym("p", npar)
        h = self.fun(t, w, u, pp)
        self._honly = ca.Function("proj_h", [t, w, u, pp], [h])
        self._symbolic = self.nh <= self.SYMBOLIC_STEP_MAX_NH
        if self._symbolic:
            self._dense, self._simplified = self._step_function(nu, npar)
        else:
            self._dense = ca.Function("proj_dense", [t, w, u, pp],
                                      [h, ca.densify(ca.jacobian(h, w))])

    def _project_chunk(self, T, X, Z, U, p, iters):
        nx, nz, nh = self.nx, self.nz, self.nh
        n = nx + nz
        N = T.size
        if self._dense is None:
            self._build(U.shape[1], np.size(p))
        if self._symbolic:
            return self._symbolic_chunk(T, X, Z, U, p, iters)
        m = N  # (no padding: evaluated row-wise, vectorized.evaluate_rows)
        W = np.hstack([X, Z])
        W0 = W.copy()
        P = np.repeat(np.asarray(p, float).reshape(1, -1), m, axis=0)
        cj = self._maps.setdefault("hj", {})
        ch = self._maps.setdefault("h", {})
        if self.rtol is not None:
            wx = 1.0 / (self.atol + self.rtol * np.abs(W[:, :nx])) ** 2
            Dinv = np.max(wx, axis=1, keepdims=True) / wx  # D^+ on x; z: free (large)
        else:
            Dinv = np.repeat((1.0 / self.weights)[None, :], m, axis=0)
        Dinv = np.hstack([Dinv, np.full((m, nz), 1e8 * np.max(Dinv, initial=1.0))])
        tiny = 1e-14 * (1 + np.max(np.abs(W), axis=1))
        # Gauss--Newton with the matrix of the first step kept (simplified Newton): the rows
        # are within drift_tol of the manifold, so the first step leaves O(drift^2) and the
        # next ones need only h (a third of the cost of h with its Jacobian)
        H, Jnz = evaluate_rows(self._dense, [T, W, U, P], cj)
        if not np.all(np.isfinite(H)) or np.all(np.max(np.abs(H), axis=1) < tiny):
            return X, Z
        Jt = Jnz.reshape(m, n, nh)  # J^T per row (CasADi's column-major blocks)
        JD = np.transpose(Jt * Dinv[:, :, None], (0, 2, 1))  # J D^+, (m, nh, n)
        Minv = spd_inverse(JD @ Jt)  # (J D^+ J^T)^-1
        W -= np.einsum("kij,ki->kj", JD, np.einsum("kij,kj->ki", Minv, H))
        rows = None  # all rows (no fancy indexing while every row is iterated)
        for _ in range(1, iters):
            sub = [T, W, U, P] if rows is None else [T[rows], W[rows], U[rows], P[rows]]
            Hr = evaluate_rows(self._honly, sub, ch)[0]
            res = np.max(np.abs(Hr), axis=1)
            still = res >= (tiny if rows is None else tiny[rows])
            rows = np.nonzero(still)[0] if rows is None else rows[still]
            if rows.size == 0:
                break
            Hr, res = Hr[still], res[still]
            # rows still far from the manifold (slow simplified steps): a new Jacobian
            far = rows[res > 1e-8 * (1 + np.max(np.abs(W[rows]), axis=1))]
            if far.size:
                Jf = evaluate_rows(self._dense, [T[far], W[far], U[far], P[far]], cj)[1]
                Jf = Jf.reshape(far.size, n, nh)
                JD[far] = JDf = np.transpose(Jf * Dinv[far][:, :, None], (0, 2, 1))
                Minv[far] = spd_inverse(JDf @ Jf)
            dW = np.einsum("kij,ki->kj", JD[rows], np.einsum("kij,kj->ki", Minv[rows], Hr))
            if not np.all(np.isfinite(dW)):
                break
            W[rows] -= dW
        return self._finish(W, W0, nx)

    @staticmethod
    def _finish(W, W0, nx):
        ok = np.all(np.isfinite(W), axis=1)
        W[~ok] = W0[~ok]
        return W[:, :nx], W[:, nx:]

    def _symbolic_chunk(self, T, X, Z, U, p, iters):
        """Gauss--Newton by the generated step functions, on all rows at once in column layout
        (``(size, rows)``; inputs the same on every row passed once): a full step for every
        row, then simplified steps (the first step's factor: a third of the cost) on the rows
        whose ``h`` is not yet at rounding, full steps again for rows still off after three.
        Rows that end non-finite stay as they were."""
        nx, nz = self.nx, self.nz
        N = T.size
        cj = self._maps.setdefault("hj", {})
        ch = self._maps.setdefault("h", {})
        Wc = np.vstack([np.asarray(X, float).T, np.asarray(Z, float).T])  # (n, N)
        W0 = Wc.copy()
        Tc = T.reshape(1, N)
        U = np.asarray(U, float).reshape(N, -1)
        Uc = U[:1].T.copy() if not U.size or rows_equal(U) else np.ascontiguousarray(U.T)
        Pc = np.asarray(p, float).reshape(-1, 1)
        if self.rtol is not None:
            sx = self.atol + self.rtol * np.abs(Wc[:nx])
            Dx = sx * sx  # D^+ on x (its scale does not matter); z: free (large)
        else:
            Dx = (1.0 / self.weights)[:, None]
        Dc = np.vstack([Dx, np.repeat(1e8 * _colmax(Dx)[None, :], nz, axis=0)])
        tiny = 1e-14 * (1 + _colmax(np.abs(Wc)))

        def cols(a, rows):
            return a if rows is None or a.shape[1] == 1 else a[:, rows]

        H, dW, Lf, JDf = evaluate_columns(self._dense, [Tc, Wc, Uc, Pc, Dc], N, cj)
        if not np.isfinite(H).all() or (_colmax(np.abs(H)) < tiny).all():
            return np.array(X, dtype=float), np.array(Z, dtype=float)
        Wc += dW
        # simplified steps with the first step's factor (from within drift_tol of the manifold
        # each leaves about |dw1| times the last correction), on the rows whose h says they
        # need one; a row still off after three gets a full step (a new factor) instead
        simple = self._maps.setdefault("simple", {})
        rows = None  # all rows (no fancy indexing while every row is iterated)
        for it in range(iters):
            n_rows = N if rows is None else rows.size
            Hr = evaluate_columns(self._honly, [cols(a, rows) for a in (Tc, Wc, Uc, Pc)],
                                  n_rows, ch)[0]
            keep = _colmax(np.abs(Hr)) >= (tiny if rows is None else tiny[rows])
            rows = np.nonzero(keep)[0] if rows is None else rows[keep]
            Hr = Hr[:, keep]
            if rows.size == 0:
                break
            if it < 3:
                dW = evaluate_columns(self._simplified, [Lf[:, rows], JDf[:, rows], Hr],
                                      rows.size, simple)[0]
            else:
                dW, L2, JD2 = evaluate_columns(
                    self._dense, [cols(a, rows) for a in (Tc, Wc, Uc, Pc, Dc)], rows.size,
                    cj)[1:]
                Lf[:, rows], JDf[:, rows] = L2, JD2
            if not np.isfinite(dW).all():
                break
            Wc[:, rows] += dW
        ok = np.isfinite(_colmax(np.abs(Wc)))  # (NaN propagates through the maximum)
        Wc[:, ~ok] = W0[:, ~ok]
        return Wc[:nx].T, Wc[nx:].T


def _min_norm_step(L, JD, h) -> ca.SX:
    """``-JD^T (L L^T)^{-1} h`` (``L`` a lower-triangular list of lists of SX)."""
    nh = len(L)
    y = [ca.SX(0)] * nh
    for i in range(nh):  # L y = h
        y[i] = (h[i] - sum((L[i][k] * y[k] for k in range(i)), ca.SX(0))) / L[i][i]
    lam = [ca.SX(0)] * nh
    for i in reversed(range(nh)):  # L^T lam = y
        lam[i] = (y[i] - sum((L[k][i] * lam[k] for k in range(i + 1, nh)), ca.SX(0))) / L[i][i]
    return -ca.mtimes(JD.T, ca.vertcat(*lam))


def _colmax(A: np.ndarray) -> np.ndarray:
    """The maximum over axis 0 of a short, wide ``(k, N)`` array, one row at a time (NumPy's
    axis-0 reduction walks such an array column by column: 5-10 times slower here)."""
    if A.shape[1] < 256:  # (few columns: one call is cheaper than the loop)
        return A.max(axis=0)
    out = np.array(A[0], dtype=float, copy=True)
    for row in A[1:]:
        np.maximum(out, row, out=out)
    return out


def _pow2(n: int) -> int:
    return n if n <= 64 else 1 << (n - 1).bit_length()


def _rows(seg, rows):
    """The segment restricted to some rows."""
    return Segment(seg.t[rows], seg.X[rows], seg.Z[rows], seg.U[rows], seg.p, seg.output[rows],
                   seg.system, seg.driver, seg.check[rows])


class DriftMonitor(Monitor):
    """Fires when ``max |invariant|`` exceeds ``tol``; acts by projecting (see the module doc).

    Parameters
    ----------
    projector : Projector
    tol : float
        The drift tolerance on the largest absolute invariant value.
    """

    name = "projection"
    #: the first segment is the whole span: a run whose drift never reaches drift_tol is then
    #: one IDAS run, exactly the plain one
    first_segment = 1.0

    def __init__(self, projector: Projector, tol: float) -> None:
        self.projector = projector
        self.tol = float(tol)
        self.max_correction = 0.0
        self.max_drift = 0.0
        self.t_proj = None  # time of the last projection (or the start)
        self.next_h = None  # suggested length of the next segment
        self._end = None  # (segment start, end, drift at the end) of the last checked segment
        self._cross = None  # time by which the drift had crossed the tolerance

    def init(self, driver, t0, x0, z0):
        self.t_proj = float(t0)
        return None

    def _drift(self, seg) -> np.ndarray:
        inv = seg.system.evaluator.invariants(seg.t, seg.X, seg.Z, seg.U, seg.p)
        return np.max(np.abs(inv), axis=1, initial=0.0)

    def check(self, seg, state):
        rows = np.nonzero(seg.check)[0]  # check rows only: the same on every output grid
        d = self._drift(seg.tail(0) if rows.size == seg.t.size else _rows(seg, rows))
        bad = np.nonzero(d[1:] > self.tol)[0]
        if bad.size == 0:
            self.max_drift = max(self.max_drift, float(np.max(d, initial=0.0)))
            self._end = (float(seg.t[0]), float(seg.t[-1]), float(d[-1]))
            return None
        b = int(bad[0])  # check rows 0..b within the tolerance, row b + 1 beyond it
        i, i1 = int(rows[b]), int(rows[b + 1])
        self.max_drift = max(self.max_drift, float(np.max(d[: b + 1], initial=0.0)))
        self._cross = float(seg.t[i1])
        if b > 0:
            return Firing(float(seg.t[i]), seg.X[i], seg.Z[i], index=i)
        ev = seg.system.evaluator
        half = 0.5 * self.tol

        def g(t, x, z, u):
            v = ev.invariants(np.array([t]), x[None, :], z[None, :], np.asarray(u)[None, :],
                              seg.p)
            return float(np.max(np.abs(v), initial=0.0)) - half

        if g(seg.t[0], seg.X[0], seg.Z[0], seg.U[0]) >= 0:  # not even the start: project it
            return Firing(float(seg.t[0]), seg.X[0], seg.Z[0], index=0)
        sub = _rows(seg, np.array([0, i1]))
        t, x, z = seg.driver.locate(sub, 0, g, tol=1e-6 * (seg.t[i1] - seg.t[0]))
        return Firing(t, x, z)

    def _project(self, driver, t, x, z):
        u = driver.current.sig.value(t)
        x, z, dx = self.projector(t, x, z, u, driver.pv)
        self.max_correction = max(self.max_correction, dx)
        return x, z

    def act(self, firing, driver, state):
        x, z = self._project(driver, firing.t, firing.x, firing.z)
        cycle = max((self._cross or firing.t) - self.t_proj, 0.0)
        self.t_proj = float(firing.t)
        # the drift crossed the tolerance after `cycle`: aim at ending the next segment, and
        # projecting there for free, well before that
        self.next_h = 0.6 * cycle if cycle > 0 else None
        return Action(x=x, z=z), state

    def at_end(self, seg, driver, state):
        if self._end is None:
            return None, state
        t0s, te, de = self._end
        self._end = None
        age = te - self.t_proj  # time since the last projection
        seg_len = te - t0s
        if de > 0.25 * self.tol:
            # near the tolerance, and IDAS restarts here anyway: project now; drift grows
            # roughly quadratically in time (measured), so it reaches tol/2 again after about
            # age * sqrt(tol / 2 / de)
            x, z = self._project(driver, te, seg.X[-1], seg.Z[-1])
            self.t_proj = te
            self.next_h = age * min(max(math.sqrt(0.5 * self.tol / max(de, 1e-300)), 0.5), 2.0)
            return Action(x=x, z=z), state
        total = age * math.sqrt(0.5 * self.tol / max(de, 1e-300 * self.tol))
        self.next_h = min(max(total - age, 0.5 * seg_len), 2.0 * max(seg_len, age))
        return None, state

    def horizon(self, state):
        return self.next_h
