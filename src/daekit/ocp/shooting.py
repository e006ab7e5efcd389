"""Direct multiple shooting on IDAS (CasADi's SUNDIALS interface) for an index-1 DAE.

The horizon ``[0, T]`` is cut into ``N`` intervals of length ``h = T/N``. The decision variables
are the states ``X_k`` and algebraic unknowns ``Z_k`` at the nodes ``t_k = k h``
(``k = 0..N``), one control value ``W_k`` per interval (piecewise constant), the free
parameters and (when free) ``T``. On each interval IDAS integrates the reduced system in the
scaled time ``s in [0, 1]``::

    dx/ds = h ode(t_k + h s, x, z, W_k, p),   0 = alg(t_k + h s, x, z, W_k, p),
    dq/ds = h L(t_k + h s, x, z, W_k, p)       (the Lagrange term, as an IDAS quadrature
                                                with error control, ``quad_err_con``)

from ``x(0) = X_k``; ``Z_k`` is only IDAS's starting guess for the algebraic unknowns (IDAS
computes the consistent ones itself, and their sensitivity to the guess is zero). One
integrator serves all intervals through ``Function.map``; the time ``t_k``, the step ``h``, the
control and the parameters are its parameters, so a free final time is plain time scaling.
The NLP's constraints are

- continuity ``X_{k+1} = x_k(1)`` (the integrator's end state),
- ``alg(t_k, X_k, Z_k, W) = 0`` at every node (so that ``Z_k`` is the true algebraic value
  there and bounds and path constraints on algebraic variables make sense), with ``W`` the
  control of the interval that ends at ``t_k`` (``W_0`` at ``t_0``: controls are read
  left-continuously, as in the collocation),
- the invariants at ``t = 0`` only, the boundary conditions (an independent subset on the
  invariant manifold), bounds and path constraints at the nodes.

The objective is ``sum_k q_k(1)`` plus the Mayer term at ``(T, X_N, Z_N, W_{N-1})``. IPOPT
uses a limited-memory Hessian by default (second-order IDAS sensitivities are costly);
``solver_options={"hessian_approximation": "exact"}`` asks for the exact one.

Multiple shooting integrates the dynamics to the integrator's tolerance, so for the same
piecewise constant controls it solves the same finite-dimensional problem as the collocation
up to the collocation's truncation error (order ``2d - 1`` at the interval ends), not the
(larger) error of the control discretization, which both share.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import OCPError
from .nlp import NLPBuilder, quiet
from .transcription import Transcription, finish, params_and_time

__all__ = ["transcribe", "interval_integrator", "DEFAULT_INTEGRATOR_OPTIONS"]

#: IDAS options used by the shooting transcription (``OCP(integrator_options=...)`` overrides).
#: ``quad_err_con``: the Lagrange term is an integrator quadrature, and without error control on
#: it IDAS/CVODES choose their steps from the states alone -- an integrand that varies where the
#: states do not (``(u - t)^2`` with ``s'' = u``) is then integrated with a few coarse steps
#: (measured: 0.0026429 instead of the exact 0.0016667 on the double integrator of the tests).
DEFAULT_INTEGRATOR_OPTIONS = {"abstol": 1e-10, "reltol": 1e-10, "max_num_steps": 50000,
                              "quad_err_con": True, "show_eval_warnings": False}


def interval_integrator(a, lagrange=None, tout=(1.0,), ncoef: int = 1, options=None,
                        name: str = "shoot"):
    """IDAS (CVODES when there are no algebraic unknowns) over one interval in scaled time.

    Parameters of the integrator: ``(W (nw * ncoef), p, t_k, h)``. With ``ncoef > 1`` the
    control is the polynomial through the Radau points of degree ``ncoef`` (the collocation's
    piecewise polynomial controls, for dense output); outputs at the scaled times ``tout``.
    """
    tk = ca.SX.sym("tk")
    h = ca.SX.sym("h")
    s = ca.SX.sym("s")
    nw = a.nw
    Wc = ca.SX.sym("Wc", nw * ncoef)
    if ncoef == 1:
        w_of_s = Wc
    else:
        from .collocation import radau_coefficients

        tau = radau_coefficients(ncoef)[0][1:]
        w_of_s = 0
        for r in range(ncoef):
            ell = 1
            for q in range(ncoef):
                if q != r:
                    ell = ell * (s - tau[q]) / (tau[r] - tau[q])
            w_of_s = w_of_s + ell * Wc[r * nw:(r + 1) * nw]
    src = ca.vertcat(a.t, a.w)
    dst = ca.vertcat(tk + h * s, w_of_s)
    exprs = [a.ode, a.alg] + ([lagrange] if lagrange is not None else [])
    ode, alg, *rest = ca.substitute(exprs, [src], [dst])
    dae = {"t": s, "x": a.x, "p": ca.vertcat(Wc, a.p, tk, h), "ode": h * ode}
    if a.nz:
        dae["z"] = a.z
        dae["alg"] = alg
    if rest:
        dae["quad"] = h * rest[0]
    opts = dict(DEFAULT_INTEGRATOR_OPTIONS)
    opts.update(options or {})
    plugin = "idas" if a.nz else "cvodes"
    try:
        return ca.integrator(name, plugin, dae, 0.0, [float(v) for v in tout], opts)
    except RuntimeError as exc:
        raise OCPError(
            f"could not build the {plugin.upper()} integrator for multiple shooting: "
            f"{str(exc).strip().splitlines()[-1]} (check OCP(integrator_options=...))"
        ) from None


def transcribe(prob, guess, T_guess: float | None = None, p_guess=None, kept=(),
               selectors=(), pins=()) -> Transcription:
    """Build the multiple shooting NLP of ``prob`` (a :class:`~daekit.ocp.compiled.Problem`);
    arguments as for :func:`daekit.ocp.collocation.transcribe`."""
    a = prob.aug
    N = prob.intervals
    nx, nz, nw = a.nx, a.nz, a.nw
    if nx == 0:
        raise OCPError(
            "multiple shooting needs at least one differential state; this system is purely "
            "algebraic: use method='collocation'"
        )
    B = NLPBuilder(ca.MX)
    Tg = prob.T_guess if T_guess is None else float(T_guess)
    P, T = params_and_time(prob, B, T_guess=Tg, p_guess=p_guess)
    h = T / N
    xlb, xub, zlb, zub, wlb, wub = prob.simple_bounds()
    an = [f"equation {n!r}" for n in prob.alg_names]
    F = interval_integrator(a, prob.lagrange if prob.has_lagrange else None,
                            options=prob.integrator_options)
    alg_fun = ca.Function("alg", [a.t, a.x, a.z, a.w, a.p], [a.alg])
    inv_fun = ca.Function("inv", [a.t, a.x, a.z, a.w, a.p], [a.inv])

    fr = [k / N for k in range(N + 1)]
    gx, gz, _ = guess(np.asarray(fr) * Tg)
    # controls: the guess's value at the interval's right end (the guesses are read
    # left-continuously: the simulated guess is exact there)
    gw = guess(np.asarray(fr[1:]) * Tg)[2]
    Xs, Zs, Ws = [], [], []
    for k in range(N + 1):
        Xs.append(B.var(f"x_{k}", nx, xlb, xub, gx[:, k])[0])
        Zs.append(B.var(f"z_{k}", nz, zlb, zub, gz[:, k])[0])
        if k < N:
            Ws.append(B.var(f"w_{k}", nw, wlb, wub, gw[:, k] if nw else 0.0)[0])
    W0 = Ws[0]
    Wnode = [W0] + Ws  # the control in force at each node (left-continuous)
    Pint = ca.horzcat(*[ca.vertcat(Ws[k], P, k * h, h) for k in range(N)])
    res = F.map(N)(x0=ca.horzcat(*Xs[:N]), z0=ca.horzcat(*Zs[:N]), p=Pint)
    xf = res["xf"]
    J = ca.MX(0)
    if prob.has_lagrange:
        # one decision variable per interval for its share of the integral, so that the
        # objective is linear and IPOPT's objective evaluations integrate nothing
        gq = _quad_guess(F.map(N), gx, gz, gw, prob, Tg, p_guess, N)
        Qs = ca.vertcat(*[B.var(f"q_{k}", 1, -np.inf, np.inf, gq[k])[0] for k in range(N)])
        J = ca.sum1(Qs)

    # t = 0: algebraic equations, invariants, path constraints
    B.con(alg_fun(0.0, Xs[0], Zs[0], W0, P), 0.0, 0.0, "algebraic equations", 0.0, "alg", an)
    if a.inv.numel():
        B.con(inv_fun(0.0, Xs[0], Zs[0], W0, P), 0.0, 0.0, "invariants", 0.0, "invariant",
              list(a.inv_names))
    prob.add_path(B, 0.0, Xs[0], Zs[0], W0, P, 0.0)
    for k in range(N):
        B.con(Xs[k + 1] - xf[:, k], 0.0, 0.0, f"continuity at the end of interval {k}",
              fr[k + 1], "dynamics")
        if prob.has_lagrange:
            B.con(Qs[k] - res["qf"][k], 0.0, 0.0, f"integral objective on interval {k}",
                  fr[k + 1], "dynamics")
        tk1 = (k + 1) * h
        B.con(alg_fun(tk1, Xs[k + 1], Zs[k + 1], Ws[k], P), 0.0, 0.0, "algebraic equations",
              fr[k + 1], "alg", an)
        prob.add_path(B, tk1, Xs[k + 1], Zs[k + 1], Ws[k], P, fr[k + 1])
    plugin = "IDAS" if nz else "CVODES"
    tol = {**DEFAULT_INTEGRATOR_OPTIONS, **(prob.integrator_options or {})}
    method = (f"multiple shooting on {plugin} (rtol {tol['reltol']:g}, atol {tol['abstol']:g}), "
              "one integrator mapped over the intervals")
    return finish(prob, B, J, P, T, fr, ca.horzcat(*Xs), ca.horzcat(*Zs), ca.horzcat(*Wnode),
                  ca.horzcat(*Ws), kept, selectors, pins, method,
                  list(range(N + 1)), 1, hessian_exact=False)


def _quad_guess(Fm, gx, gz, gw, prob, Tg, p_guess, N) -> np.ndarray:
    """Each interval's share of the integral objective along the guess (one integration)."""
    p = np.asarray(prob.p_guess() if p_guess is None else p_guess, float).reshape(-1, 1)
    h = Tg / N
    Pint = np.vstack([gw.reshape(-1, N), np.repeat(p, N, axis=1),
                      h * np.arange(N).reshape(1, -1), np.full((1, N), h)])
    try:
        with quiet():
            q = np.asarray(Fm(x0=gx[:, :N], z0=gz[:, :N], p=Pint)["qf"]).ravel()
    except RuntimeError:
        return np.zeros(N)
    return q if q.size == N and np.all(np.isfinite(q)) else np.zeros(N)
