"""What the two transcriptions (collocation, multiple shooting) share: the :class:`Transcription`
they return, the free parameters and final time as decision variables, and the common tail
(Mayer term, boundary conditions, the grid/ends/controls functions) in :func:`finish`."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..numerics import DenseFunction
from .nlp import NLPBuilder

__all__ = ["Transcription", "params_and_time", "finish"]


@dataclass
class Transcription:
    """An NLP built from a :class:`~daekit.ocp.compiled.Problem`.

    ``grid(V) -> (tfrac (1 x Nt), X, Z, W, T, P)``, ``ends(V) -> (v0, vT, P, T)``,
    ``controls(V) -> (nw, N * ncoef)`` (the control of each interval), ``node_index``: the grid
    column of each interval boundary.
    """

    builder: NLPBuilder
    J: ca.SX | ca.MX
    grid: ca.Function
    ends: ca.Function
    method: str
    nt: int
    hessian_exact: bool = True
    controls: ca.Function | None = None
    node_index: list[int] | None = None
    ncoef: int = 1
    derivatives: dict | None = None  # IPOPT's jac_g / hess_lag in closed form, when built


def params_and_time(prob, B: NLPBuilder, T_guess: float | None = None, p_guess=None):
    """Parameters (free ones as decision variables, started at ``p_guess`` when given) and the
    final time (a decision variable when free, started at ``T_guess`` clipped to its bounds)."""
    a = prob.aug
    S = B.sym
    entries = []
    for i, nm in enumerate(a.p_names):
        if nm in prob.free_params:
            lo, hi, g = prob.free_params[nm]
            if p_guess is not None and np.isfinite(p_guess[i]):
                g = float(np.clip(p_guess[i], lo, hi))
            v, _ = B.var(f"param_{nm}", 1, lo, hi, g)
            entries.append(v)
        else:
            entries.append(S(float(prob.p_values[i])))
    P = ca.vertcat(*entries) if entries else S(0, 1)
    if prob.T_free is not None:
        lo, hi, g = prob.T_free
        if T_guess is not None:
            g = float(np.clip(T_guess, lo, hi))
        T, _ = B.var("T", 1, lo, hi, g)
    else:
        T = S(prob.T_fixed)
    return P, T


def finish(prob, B: NLPBuilder, J, P, T, fr, X, Z, W, Wint, kept, selectors, pins,
           method: str, node_index: list[int], ncoef: int, hessian_exact: bool = True
           ) -> Transcription:
    """The common tail: the Mayer term at ``(T, X, Z, W)`` of the last grid column, the
    boundary conditions on ``v0 = (X, Z, W)`` of the first column and ``vT`` of the last, and
    the functions that read a decision vector. ``X, Z, W``: the values on the grid (one
    column per time of ``fr``); ``Wint``: the control of each interval (one column per
    coefficient)."""
    nt = len(fr)
    XT, ZT, WT = X[:, nt - 1], Z[:, nt - 1], W[:, nt - 1]
    if prob.has_mayer:
        J = J + prob.mayer_fun(T, XT, ZT, WT, P)
    v0 = ca.vertcat(X[:, 0], Z[:, 0], W[:, 0])
    vT = ca.vertcat(XT, ZT, WT)
    prob.add_boundary(B, v0, vT, P, T, kept, selectors, pins)
    V = B.V()
    # called on decision vectors (NumPy) after the solve: through their buffers, outputs as
    # dense arrays (SWIG's conversion of a 1600-vector to DM alone costs 0.14 ms)
    grid = DenseFunction(ca.Function(
        "grid", [V],
        [ca.DM(np.asarray(fr, float)).T, X, Z, W, T, P],
    ))
    ends = DenseFunction(ca.Function("ends", [V], [v0, vT, P, T]))
    controls = DenseFunction(ca.Function("controls", [V], [Wint]))
    return Transcription(B, J, grid, ends, method, len(fr), hessian_exact=hessian_exact,
                         controls=controls, node_index=node_index, ncoef=ncoef)
