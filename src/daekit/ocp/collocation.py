"""Direct collocation with Radau IIA (degree 1 to 5) on an index-1 DAE.

On each of ``N`` intervals of length ``h = T/N`` the state is a polynomial of degree ``d``
through the interval's start point and the ``d`` Radau points ``tau_1 < ... < tau_d = 1``; the
dynamics ``x' = ode`` and the algebraic equations ``0 = alg`` hold at the Radau points, where
the algebraic unknowns live. The last Radau point is the next interval's start (so states are
continuous without extra equations). The Lagrange term is integrated with the Radau weights
(exact for polynomials of degree ``2d - 2``). Radau IIA is stiffly accurate and of order
``2d - 1`` at the interval ends for index-1 DAEs.

Controls are piecewise constant (one value per interval) or piecewise polynomial (one value
per Radau point, degree ``d - 1`` on each interval). Extra decision variables at the initial
time: the algebraic unknowns ``z_0`` (with ``alg = 0``), where the invariants are imposed.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .nlp import NLPBuilder
from .transcription import Transcription, finish, params_and_time

__all__ = ["radau_coefficients", "transcribe", "Transcription"]


def radau_coefficients(d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points ``tau = [0, tau_1..tau_d]``, derivative matrix ``C`` (``C[r, j]``: derivative of the
    ``r``-th Lagrange basis polynomial through ``tau`` at ``tau_j``), quadrature weights ``b``
    (Radau IIA, for ``tau_1..tau_d``) and ``e0`` (the degree ``d - 1`` interpolant through the
    Radau points evaluated at 0).

    >>> tau, C, b, e0 = radau_coefficients(1)
    >>> tau.tolist(), b.tolist()
    ([0.0, 1.0], [1.0])
    """
    tau = np.array([0.0] + list(ca.collocation_points(d, "radau")))
    C = np.zeros((d + 1, d + 1))
    for r in range(d + 1):
        poly = np.poly1d([1.0])
        for s in range(d + 1):
            if s != r:
                poly *= np.poly1d([1.0, -tau[s]]) / (tau[r] - tau[s])
        dp = np.polyder(poly)
        for j in range(d + 1):
            C[r, j] = dp(tau[j])
    b = np.zeros(d)
    e0 = np.zeros(d)
    for r in range(d):
        poly = np.poly1d([1.0])
        for s in range(d):
            if s != r:
                poly *= np.poly1d([1.0, -tau[s + 1]]) / (tau[r + 1] - tau[s + 1])
        ip = np.polyint(poly)
        b[r] = ip(1.0) - ip(0.0)
        e0[r] = poly(0.0)
    return tau, C, b, e0


def transcribe(prob, guess, T_guess: float | None = None, p_guess=None, kept=(),
               selectors=(), pins=()) -> Transcription:
    """Build the collocation NLP of ``prob`` (a :class:`~daekit.ocp.compiled.Problem`) with the
    boundary conditions ``kept`` (indices) as equalities and the branch ``selectors``;
    ``guess(t)`` gives ``(X, Z, W)`` at times ``t`` of a horizon ``T_guess``."""
    a = prob.aug
    N, d = prob.intervals, prob.degree
    tau, C, b, e0 = radau_coefficients(d)
    nx, nz, nw = a.nx, a.nz, a.nw
    B = NLPBuilder(ca.SX)
    f = ca.Function("f", [a.t, a.x, a.z, a.w, a.p], [a.ode, a.alg, prob.lagrange])

    # parameters and final time
    Tg = prob.T_guess if T_guess is None else float(T_guess)
    P, T = params_and_time(prob, B, T_guess=Tg, p_guess=p_guess)
    h = T / N
    xlb, xub, zlb, zub, wlb, wub = prob.simple_bounds()
    an = [f"equation {n!r}" for n in prob.alg_names]

    def tv(frac):  # times of the guess
        return np.atleast_1d(np.asarray(frac, float)) * Tg

    g0x, g0z, g0w = guess(tv(0.0))
    X0, _ = B.var("x_0", nx, xlb, xub, g0x[:, 0])
    Z0, _ = B.var("z_0", nz, zlb, zub, g0z[:, 0])
    Xgrid, Zgrid, Wgrid, fr = [X0], [Z0], [], [0.0]
    Xk = X0
    J = 0
    W0 = None
    Wint = []
    for k in range(N):
        fr_k = [(k + tau[j]) / N for j in range(1, d + 1)]
        gx, gz, gw = guess(tv(fr_k))
        if prob.control_mode == "constant":
            Wk, _ = B.var(f"w_{k}", nw, wlb, wub, gw.mean(axis=1) if nw else 0.0)
            Wc = [Wk] * d
            Wint.append(Wk)
        else:
            Wc = [B.var(f"w_{k}_{j}", nw, wlb, wub, gw[:, j - 1])[0] for j in range(1, d + 1)]
            Wint.extend(Wc)
        if k == 0:
            W0 = Wc[0] if prob.control_mode == "constant" else sum(
                float(e0[j]) * Wc[j] for j in range(d)
            )
            Wgrid.append(W0)
            B.con(f(0.0, X0, Z0, W0, P)[1], 0.0, 0.0, "algebraic equations", 0.0, "alg", an)
            if a.inv.numel():
                inv0 = ca.substitute(
                    [a.inv], [ca.vertcat(a.t, a.x, a.z, a.w, a.p)],
                    [ca.vertcat(0.0, X0, Z0, W0, P)],
                )[0]
                B.con(inv0, 0.0, 0.0, "invariants", 0.0, "invariant", list(a.inv_names))
            prob.add_path(B, 0.0, X0, Z0, W0, P, 0.0)
        Xs = [Xk]
        Zs = []
        for j in range(1, d + 1):
            Xj, _ = B.var(f"x_{k}_{j}", nx, xlb, xub, gx[:, j - 1])
            Zj, _ = B.var(f"z_{k}_{j}", nz, zlb, zub, gz[:, j - 1])
            Xs.append(Xj)
            Zs.append(Zj)
        for j in range(1, d + 1):
            tkj = h * (k + tau[j])
            ode, alg, L = f(tkj, Xs[j], Zs[j - 1], Wc[j - 1], P)
            xp = sum(float(C[r, j]) * Xs[r] for r in range(d + 1))
            B.con(xp - h * ode, 0.0, 0.0, f"dynamics on interval {k}", fr_k[j - 1], "dynamics")
            B.con(alg, 0.0, 0.0, "algebraic equations", fr_k[j - 1], "alg", an)
            if prob.has_lagrange:
                J = J + h * float(b[j - 1]) * L
            prob.add_path(B, tkj, Xs[j], Zs[j - 1], Wc[j - 1], P, fr_k[j - 1])
            Xgrid.append(Xs[j])
            Zgrid.append(Zs[j - 1])
            Wgrid.append(Wc[j - 1])
            fr.append(fr_k[j - 1])
        Xk = Xs[d]
    ncoef = 1 if prob.control_mode == "constant" else d
    return finish(prob, B, ca.SX(J), P, T, fr, Xgrid, Zgrid, Wgrid, Wint, kept, selectors, pins,
                  f"Radau IIA collocation, degree {d}", [k * d for k in range(N + 1)], ncoef)
