"""Consistency after a reset: the reset values kept where the constraints allow.

A reset (``{"der(x)": -e * der(x)}``, an impact law) writes new values into some states of the
original model. On a constrained system these values are generally inconsistent: a velocity
jump violates the velocity-level invariant ``G(q) v = 0``. :func:`restore` makes the post-event
point consistent on the *reduced* system ``r``:

* Let ``k`` be the lowest derivative order among the reset names (``k = 1`` for a velocity
  reset). Every state of ``r`` of order below ``k`` (the positions, for a velocity reset) is
  kept exactly: position-level invariants are untouched by a velocity reset.
* The quantities of orders ``k`` up to one below the highest (the velocities) are the
  *targets*: the reset values where given, the pre-event values elsewhere. They are met in the
  least-squares sense subject to ``alg = 0`` and every invariant that the free quantities can
  influence (``G v = 0``): a minimal-change projection, solved by Gauss--Newton with the
  algebraic unknowns eliminated through ``alg`` (``d alg / dz`` is nonsingular).
* The metric is the mass matrix where it is known (a model from
  :class:`daekit.mechanics.LagrangianSystem`: ``(v - v*)^T M(q) (v - v*)``, so that an
  impact is a mass-weighted projection ``v+ = v* - M^-1 G^T (G M^-1 G^T)^-1 G v*``: the
  impulse acts along the constraint normals and a reset with ``e = 1`` conserves the kinetic
  energy of the admissible motion); the identity otherwise (unit masses).

The dense linear algebra here is of the size of the system and runs once per event.

Example
-------
>>> import numpy as np, daekit as dk
>>> r = dk.reduce_index(dk.examples.pendulum_planar())
>>> s = np.sqrt(0.5)
>>> x, z, info = restore(r, 0.0, np.array([s, 1.0, -s, 0.0]), np.zeros(r.nz), [], r.p_values,
...                      {"der(x)": 1.0})
>>> np.round(x, 12).tolist()    # positions kept; (1, 0) projected onto x dx + y dy = 0
[0.707106781187, 0.5, -0.707106781187, 0.5]
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import ModelError, SimulationError
from ..model import parse_name

__all__ = ["restore"]


def _orders(r) -> dict[str, int]:
    """Highest derivative order present in ``r.variables`` per model variable name."""
    top: dict[str, int] = {}
    for nm in r.variables:
        try:
            base, order, _ = parse_name(nm)
        except ModelError:
            continue
        top[base] = max(top.get(base, 0), order)
    return top


def _target_names(r, k: int) -> list[str]:
    model = r.model
    top = _orders(r)
    out = []
    for nm in r.variables:
        base, order, _ = parse_name(nm)
        var = model.variables.get(base) if model is not None else None
        if var is None or var.kind not in ("state", "variable"):
            continue
        if k <= order < top[base]:
            out.append(nm)
    return out


def _mass_metric(r, names: list[str], values: dict[str, float], p) -> np.ndarray | None:
    """Cholesky-like factor ``R`` with ``R^T R = M`` on the velocity names, or None."""
    ls = getattr(r, "lagrangian", None)
    if ls is None and r.model is not None:
        ls = getattr(r.model, "mechanics", None)
    if ls is None:
        return None
    vel = list(ls.velocity_names)
    if sorted(vel) != sorted(names):
        return None
    q = np.array([values[n] for n in ls.coordinate_names], dtype=float)
    try:
        M = np.asarray(ca.DM(ls.mass_matrix(q, np.asarray(p, float)[: ls.p_values.size])))
        np.linalg.cholesky(0.5 * (M + M.T))
    except Exception:  # noqa: BLE001 - no metric: identity
        return None
    perm = [vel.index(n) for n in names]
    Lp = np.linalg.cholesky(M[np.ix_(perm, perm)] * 0.5 + M[np.ix_(perm, perm)].T * 0.5)
    return Lp.T


_FUNS: dict = {}


def _functions(r, names: tuple[str, ...]):
    key = (id(r), id(r.alg), id(r.invariants), names)
    hit = _FUNS.get(key)
    if hit is not None and hit[0] is r:
        return hit[1]
    V = ca.vertcat(*[ca.SX(r.variables[n]) for n in names]) if names else ca.SX(0, 1)
    inv = r.invariants if r.invariants.numel() else ca.SX(0, 1)
    ins = [r.t, r.x, r.z, r.u, r.p]
    f = ca.Function("reset_lin", ins, [r.alg, inv, V, ca.jacobian(r.alg, r.x),
                                       ca.jacobian(r.alg, r.z), ca.jacobian(inv, r.x),
                                       ca.jacobian(inv, r.z), ca.jacobian(V, r.x),
                                       ca.jacobian(V, r.z)])
    if len(_FUNS) > 16:
        _FUNS.clear()
    _FUNS[key] = (r, f)
    return f


def _constrained_lsq(A, b, C, c, rcond: float = 1e-10):
    """``argmin ||A d - b||`` subject to ``C d = c`` (rows of ``C`` without rank dropped)."""
    n = A.shape[1] if A.size else C.shape[1]
    if C.shape[0]:
        U, S, Vt = np.linalg.svd(C, full_matrices=True)
        rank = int(np.sum(S > rcond * (S[0] if S.size else 1.0))) if S.size else 0
        d = Vt[:rank].T @ ((U[:, :rank].T @ c) / S[:rank]) if rank else np.zeros(n)
        N = Vt[rank:].T
    else:
        d, N = np.zeros(n), np.eye(n)
    if N.shape[1] and A.shape[0]:
        y = np.linalg.lstsq(A @ N, b - A @ d, rcond=1e-12)[0]
        d = d + N @ y
    return d


def restore(r, t: float, x, z, u, p, targets: dict[str, float], tol: float = 1e-14,
            max_iter: int = 30, repair: bool = True) -> tuple[np.ndarray, np.ndarray, dict]:
    """A consistent point of ``r`` after a reset to ``targets`` (see the module docstring).

    Parameters
    ----------
    r : ReducedDAE
    t, x, z, u, p
        The pre-event point.
    targets : dict of str to float
        Reset values by element name (keys of ``r.variables``).
    repair : bool
        First remove the integrator's drift of the invariants the held states carry (for a
        velocity reset: ``c(q) = 0``) by a minimal change of those states; the reset itself
        never moves them. ``info["repaired"]`` is the size of that change.

    Returns
    -------
    (x, z, info) with ``info["kept"]`` (max deviation of the reset names from their targets),
    ``info["metric"]`` (``"mass matrix"`` or ``"identity"``) and ``info["fixed"]`` (the states
    held).

    Raises
    ------
    SimulationError
        When no consistent point near the targets is found.
    """
    x = np.asarray(x, dtype=float).ravel().copy()
    z = np.asarray(z, dtype=float).ravel().copy()
    u = np.asarray(u, dtype=float).ravel()
    p = np.asarray(p, dtype=float).ravel()
    if not targets:
        return x, z, {"kept": 0.0, "metric": "identity", "fixed": []}
    k = min(parse_name(n)[1] for n in targets)
    names = _target_names(r, k)
    for n in targets:
        if n not in names:
            names.append(n)
    fun = _functions(r, tuple(names))
    ordx = [parse_name(n)[1] for n in r.x_names]
    free = np.array([o >= k for o in ordx], dtype=bool)
    fixed = [n for n, f in zip(r.x_names, free, strict=True) if not f]
    out0 = fun(t, x, z, u, p)
    V0 = np.asarray(out0[2], dtype=float).ravel()
    values = dict(zip(names, V0, strict=True))
    allv = {n: float(v) for n, v in zip(r.x_names, x, strict=True)}
    allv.update(values)
    goal = np.array([targets.get(n, values[n]) for n in names], dtype=float)
    for i, n in enumerate(r.x_names):  # a good start: the targets written in
        if n in targets:
            x[i] = targets[n]
    R = _mass_metric(r, [n for n in names], allv, p)
    metric = "mass matrix" if R is not None else "identity"
    if R is None:
        R = np.eye(len(names))
    fi = np.nonzero(free)[0]
    nf, nz = fi.size, z.size
    repaired = 0.0
    if repair:
        # drift of the lower-order invariants (the integrator's, not the reset's): removed first
        # by a minimal change of the held states, so that the restart is consistent
        repaired = _repair_fixed(fun, t, x, z, u, p, free, tol)
    for _ in range(max_iter):
        alg, inv, V, Ax, Az, Ix, Iz, Vx, Vz = (o.full()
                                                for o in fun(t, x, z, u, p))
        alg, inv, V = alg.ravel(), inv.ravel(), V.ravel()
        # joint unknowns (free states, all algebraic unknowns): C d = c, min ||A d - b||
        C = np.vstack([np.hstack([Ax[:, fi], Az]), np.hstack([Ix[:, fi], Iz])])
        c = -np.concatenate([alg, inv])
        # only the conditions the free quantities can move (G v = 0, not c(q) = 0)
        rows = np.nonzero(np.max(np.abs(C), axis=1, initial=0.0) > 1e-12)[0] if C.size else []
        C, c = C[rows], c[rows]
        A = R @ np.hstack([Vx[:, fi], Vz])
        b = R @ (goal - V)
        d = _constrained_lsq(A, b, C, c)
        x[fi] += d[:nf]
        z += d[nf:nf + nz]
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(z))):
            break
        step = float(np.max(np.abs(d), initial=0.0))
        scale = 1.0 + float(np.max(np.abs(x), initial=0.0)) + float(np.max(np.abs(z), initial=0.0))
        if step <= tol * scale:
            break
    alg, inv = (np.asarray(o, dtype=float).ravel() for o in fun(t, x, z, u, p)[:2])
    bad = float(np.max(np.abs(alg), initial=0.0))
    if not np.isfinite(bad) or bad > 1e-8 * (1.0 + float(np.max(np.abs(z), initial=0.0))):
        raise SimulationError(
            f"after the reset of {sorted(targets)} at t = {t:g} no consistent point was found "
            f"(residual {bad:.3g} of the equations); the reset values may be incompatible with "
            "the constraints",
            t=float(t),
        )
    Vn = np.asarray(fun(t, x, z, u, p)[2], dtype=float).ravel()
    kept = max((abs(Vn[names.index(n)] - v) for n, v in targets.items()), default=0.0)
    return x, z, {"kept": float(kept), "metric": metric, "fixed": fixed, "repaired": repaired}


def _repair_fixed(fun, t, x, z, u, p, free, tol) -> float:
    """Minimal-norm Gauss--Newton on the held states for the invariants only they move."""
    held = np.nonzero(~free)[0]
    if held.size == 0:
        return 0.0
    x0 = x[held].copy()
    for _ in range(10):
        _, inv, _, _, _, Ix, Iz, _, _ = (o.full()
                                         for o in fun(t, x, z, u, p))
        inv = inv.ravel()
        if not inv.size:
            break
        Ifree = np.hstack([Ix[:, np.nonzero(free)[0]], Iz])
        rows = np.nonzero(np.max(np.abs(Ifree), axis=1, initial=0.0) <= 1e-12)[0]
        if rows.size == 0 or np.max(np.abs(inv[rows])) <= tol * (1 + np.max(np.abs(x))):
            break
        J = Ix[np.ix_(rows, held)]
        x[held] += np.linalg.lstsq(J, -inv[rows], rcond=1e-12)[0]
    return float(np.max(np.abs(x[held] - x0), initial=0.0))
