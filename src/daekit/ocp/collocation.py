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

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .nlp import NLPBuilder

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


@dataclass
class Transcription:
    builder: NLPBuilder
    J: ca.SX
    grid: ca.Function  # V -> (tfrac (1 x Nt), X, Z, W, T, P)
    ends: ca.Function  # V -> (v0, vT, P, T)
    method: str
    nt: int
    hessian_exact: bool = True
    controls: ca.Function | None = None  # V -> (nw, N * ncoef): the control of each interval
    node_index: list[int] | None = None  # grid column of each interval boundary t_k
    ncoef: int = 1  # control values per interval (1: constant, d: polynomial)


def transcribe(ocp, guess, T_guess: float | None = None,
                p_guess=None) -> Transcription:
    """Build the collocation NLP of ``ocp`` (an :class:`daekit.ocp.OCP` after preparation);
    ``guess(t)`` gives ``(X, Z, W)`` at times ``t`` of a horizon ``T_guess``."""
    a = ocp._aug
    N, d = ocp.intervals, ocp.degree
    tau, C, b, e0 = radau_coefficients(d)
    nx, nz, nw = a.nx, a.nz, a.nw
    B = NLPBuilder(ca.SX)
    f = ca.Function("f", [a.t, a.x, a.z, a.w, a.p], [a.ode, a.alg, ocp._lagrange])

    # parameters and final time
    Tg = ocp._T_guess if T_guess is None else float(T_guess)
    P, T = _params_and_time(ocp, B, T_guess=Tg, p_guess=p_guess)
    h = T / N
    xlb, xub, zlb, zub, wlb, wub = ocp._simple_bounds()

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
        if ocp.control_mode == "constant":
            Wk, _ = B.var(f"w_{k}", nw, wlb, wub, gw.mean(axis=1) if nw else 0.0)
            Wc = [Wk] * d
            Wint.append(Wk)
        else:
            Wc = [B.var(f"w_{k}_{j}", nw, wlb, wub, gw[:, j - 1])[0] for j in range(1, d + 1)]
            Wint.extend(Wc)
        if k == 0:
            W0 = Wc[0] if ocp.control_mode == "constant" else sum(
                e0[j] * Wc[j] for j in range(d)
            )
            Wgrid.append(W0)
            B.con(f(0.0, X0, Z0, W0, P)[1], 0.0, 0.0, "algebraic equations", 0.0, "alg")
            if a.inv.numel():
                inv0 = ca.substitute(
                    [a.inv], [ca.vertcat(a.t, a.x, a.z, a.w, a.p)],
                    [ca.vertcat(0.0, X0, Z0, W0, P)],
                )[0]
                B.con(inv0, 0.0, 0.0, "invariants", 0.0, "invariant", list(a.inv_names))
            ocp._add_path(B, 0.0, X0, Z0, W0, P, 0.0)
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
            xp = sum(C[r, j] * Xs[r] for r in range(d + 1))
            B.con(xp - h * ode, 0.0, 0.0, f"dynamics on interval {k}", fr_k[j - 1], "dynamics")
            B.con(alg, 0.0, 0.0, "algebraic equations", fr_k[j - 1], "alg")
            if ocp._has_lagrange:
                J = J + h * b[j - 1] * L
            ocp._add_path(B, tkj, Xs[j], Zs[j - 1], Wc[j - 1], P, fr_k[j - 1])
            Xgrid.append(Xs[j])
            Zgrid.append(Zs[j - 1])
            Wgrid.append(Wc[j - 1])
            fr.append(fr_k[j - 1])
        Xk = Xs[d]
    XT, ZT, WT = Xgrid[-1], Zgrid[-1], Wgrid[-1]
    if ocp._has_mayer:
        J = J + ocp._mayer_fun(T, XT, ZT, WT, P)
    v0 = ca.vertcat(X0, Z0, W0)
    vT = ca.vertcat(XT, ZT, WT)
    ocp._add_boundary(B, v0, vT, P, T)
    V = B.V()
    grid = ca.Function(
        "grid", [V],
        [ca.DM(fr).T, ca.horzcat(*Xgrid), ca.horzcat(*Zgrid), ca.horzcat(*Wgrid), T, P],
    )
    ends = ca.Function("ends", [V], [v0, vT, P, T])
    controls = ca.Function("controls", [V], [ca.horzcat(*Wint)])
    ncoef = 1 if ocp.control_mode == "constant" else d
    return Transcription(B, ca.SX(J), grid, ends, f"Radau IIA collocation, degree {d}", len(fr),
                         controls=controls, node_index=[k * d for k in range(N + 1)],
                         ncoef=ncoef)


def _params_and_time(ocp, B: NLPBuilder, T_guess: float | None = None, p_guess=None):
    """Parameters (free ones as decision variables, started at ``p_guess`` when given) and the
    final time (a decision variable when free, started at ``T_guess`` clipped to its bounds)."""
    a = ocp._aug
    S = B.sym
    entries = []
    for i, nm in enumerate(a.p_names):
        if nm in ocp._free_params:
            lo, hi, g = ocp._free_params[nm]
            if p_guess is not None and np.isfinite(p_guess[i]):
                g = float(np.clip(p_guess[i], lo, hi))
            v, _ = B.var(f"param_{nm}", 1, lo, hi, g)
            entries.append(v)
        else:
            entries.append(S(float(ocp._p_values[i])))
    P = ca.vertcat(*entries) if entries else S(0, 1)
    if ocp._T_free is not None:
        lo, hi, g = ocp._T_free
        if T_guess is not None:
            g = float(np.clip(T_guess, lo, hi))
        T, _ = B.var("T", 1, lo, hi, g)
    else:
        T = S(ocp._T_fixed)
    return P, T
