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

from collections.abc import Mapping

import casadi as ca
import numpy as np
import scipy.linalg as sla

from ..errors import ReductionError
from ..model import Model
from ..reduced import ReducedDAE
from .differentiate import derivative_name
from .reduce import (
    _all_symbols,
    _assemble,
    _invariants,
    _pair_names,
    _states,
    _top_equations,
    amended_expansion,
    check_index1,
)

__all__ = ["dummy_derivatives", "reselect", "selection_condition", "map_values"]


def _point_vector(ex, point: Mapping | None, seed: int):
    """Values for all unknowns up to order d_j, controls up to the needed order, parameters."""
    model = ex.model
    rng = np.random.default_rng(seed)
    vals: dict[tuple[int, int, int], float] = {}
    t = 0.0
    if point:
        for name, value in point.items():
            if name == "t":
                t = float(value)
                continue
            els = model.resolve(name)
            arr = np.broadcast_to(np.asarray(value, dtype=float).ravel(), (len(els),))
            for (var, i, order), a in zip(els, arr, strict=True):
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


def _select(A: np.ndarray, m: int):
    """Columns of the best-conditioned m-by-m block of A (QR with column pivoting)."""
    _, _, piv = sla.qr(A, mode="economic", pivoting=True)
    cols = np.sort(piv[:m])
    return cols, _block_condition(A, cols)


def _block_condition(A: np.ndarray, cols) -> float:
    """``||A||_2 / sigma_min(A[:, cols])``: the condition of solving the stage equations for
    the selected columns, relative to the whole stage matrix (so a 1-by-1 block counts too)."""
    if A.shape[0] == 0:
        return 1.0
    if not np.all(np.isfinite(A)):
        return float("inf")
    smin = np.linalg.svd(A[:, cols], compute_uv=False)[-1]
    smax = np.linalg.norm(A, 2)
    return float(smax / smin) if smin > 0 else float("inf")


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
        (per stage: the equations, candidates, dummies chosen, condition number),
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
    top = _top_equations(ex)
    hi = ex.unknown(d, range(n))
    Jsym = ca.jacobian(top, hi)
    Xs, Us = _all_symbols(ex)
    Jf = ca.Function("J", [model.t, Xs, Us, model.parameter_symbols], [Jsym])
    t0, X0, U0, P0 = _point_vector(ex, point, seed)
    J = np.asarray(ca.DM(Jf(t0, X0, U0, P0)).full())
    if not np.all(np.isfinite(J)):
        raise ReductionError(
            f"model {model.name!r}: the system Jacobian is not finite at the selection point; "
            "give a point inside the model's domain: reduce_index(model, 'dummy_derivatives', "
            "point={...})"
        )
    eq_names = ex.equation_names
    selected = np.arange(n)
    dummy: set[tuple[int, int]] = set()
    stages, blocks = [], []
    for s in range(1, int(c.max(initial=0)) + 1):
        R = np.nonzero(c >= s)[0]
        C = selected[d[selected] >= s]
        A = J[np.ix_(R, C)]
        if len(R) > len(C) or np.linalg.matrix_rank(A) < len(R):
            bad = [derivative_name(eq_names[i], int(c[i]) - s) for i in R]
            raise ReductionError(
                f"model {model.name!r}: dummy-derivative selection failed at stage {s}: the "
                f"equations {bad[:12]} cannot be solved for any choice of derivatives at the "
                "selection point (the system Jacobian is singular there); give another point "
                "(point={...}) or use method='differentiate'"
            )
        cols, cond = _select(A, len(R))
        S = C[cols]
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
                "condition": cond,
            }
        )
        blocks.append((R, C, cols))
        selected = S

    states = _states(ex, skip=lambda j, k: (j, k) in dummy)
    dpairs = sorted(dummy, key=lambda jk: (jk[1], jk[0]))
    zpairs = [(j, int(d[j])) for j in range(n)] + dpairs
    alg = ca.vertcat(*ex.levels)
    alg_names = [derivative_name(eq_names[i], k) for k, rk in enumerate(ex.rows) for i in rk]
    inv, inv_names, chains = _invariants(ex)
    r = _assemble(ex, states, zpairs, alg, inv, inv_names, "dummy_derivatives")
    r.state_selection = {
        "states": list(r.x_names),
        "dummies": _pair_names(ex, dpairs),
        "stages": stages,
        "condition": max([st["condition"] for st in stages], default=1.0),
        "point": dict(point) if point else None,
        "rule": "QR with column pivoting of J[R_s, C_s] per stage (Mattsson-Soderlind on "
        "Pryce's stages)",
    }
    r.info["alg_names"] = alg_names
    r.info["chains"] = []  # invariants are part of alg: nothing to stabilize
    r.info["offsets"] = {"c": c.copy(), "d": d.copy()}
    r.info["amendments"] = amendments
    r.info["selection_jacobian"] = ca.Function("J", [r.t, r.x, r.z, r.u, r.p], [Jsym])
    r.info["selection_blocks"] = blocks
    if check:
        check_index1(r, seed=seed)
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
    u = np.zeros(r.nu) if u is None else np.asarray(u, dtype=float)
    p = r.p_values if p is None else np.asarray(p, dtype=float)
    J = np.asarray(ca.DM(r.info["selection_jacobian"](t, x, z, u, p)).full())
    worst = 1.0
    for R, C, cols in r.info["selection_blocks"]:
        worst = max(worst, _block_condition(J[np.ix_(R, C)], cols))
    return worst


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
