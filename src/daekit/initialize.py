"""Consistent initial values for a reduced (index-1) DAE.

A :class:`~daekit.reduced.ReducedDAE` is equivalent to the original model only on the manifold
where its algebraic equations ``alg = 0`` *and* its invariants (the consistency conditions, e.g.
the pendulum's ``c = (p.p - L^2)/2`` and ``c' = p.v``) hold. :func:`initialize` finds a point on
that manifold: values you *fix* are held exactly, values you *guess* are pulled to in a weighted
least-squares sense, and everything else is found.

Method (Gauss--Newton with CasADi Jacobians): unknowns ``w = (x, z)``; constraints
``h(w) = [alg; invariants; fixed(w) - fixed values] = 0``; objective
``||G(w) - guess||^2``. Each iteration solves the linearized problem
``min ||G + J_G d - guess||  s.t.  h + J_h d = 0`` through an SVD of ``J_h`` (minimum-norm
particular step plus a least-squares step in the null space), so redundant but consistent
constraints do no harm. Values that cannot be made consistent leave a residual; the rows
carrying it (at a Gauss--Newton stationary point the residual lies in the left null space of
``J_h``) name the conflicting fixed values and consistency conditions.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.linalg

from .errors import DaekitError, InitializationError

__all__ = ["InitialValues", "initialize"]


@dataclass
class InitialValues:
    """Consistent initial values of a ReducedDAE.

    Attributes
    ----------
    t0 : float
    x0, z0 : numpy.ndarray
        States and algebraic unknowns of the reduced system (orders ``r.x_names``, ``r.z_names``).
    u0, p : numpy.ndarray
        Inputs at ``t0`` and the parameter values used.
    values : dict of str to float
        Every element of the original model (``"p[0]"``, ``"der(p)[0]"``, ``"z"``, inputs).
    free : set of str
        A set of state element names that could have been fixed freely (one choice of dynamic
        degrees of freedom; found by a column-pivoted QR of the consistency Jacobian).
    dof : int
        Number of dynamic degrees of freedom (``len(free)``).
    redundant : list of str
        Fixed values that were implied by the others (consistent, hence accepted).
    residual : float
        Max |alg|, |invariant| at the solution.
    iterations : int

    ``init["p"]`` returns the values of ``p`` as an array, ``init["p[0]"]`` a float.
    """

    t0: float
    x0: np.ndarray
    z0: np.ndarray
    u0: np.ndarray
    p: np.ndarray
    values: dict[str, float]
    free: set[str] = field(default_factory=set)
    dof: int = 0
    redundant: list[str] = field(default_factory=list)
    residual: float = 0.0
    iterations: int = 0
    x_names: list[str] = field(default_factory=list)
    z_names: list[str] = field(default_factory=list)

    def __getitem__(self, name: str):
        from .simulate.trajectory import expand_name

        elems = expand_name(name, self.values, "these initial values")
        if len(elems) == 1 and ("[" in name or not elems[0].endswith("]")):
            return float(self.values[elems[0]])
        return np.array([self.values[e] for e in elems])

    def __repr__(self) -> str:
        shown = ", ".join(f"{n}={v:.6g}" for n, v in zip(self.x_names, self.x0, strict=False))
        return (
            f"InitialValues(t0={self.t0:g}: {shown}; dof={self.dof}, "
            f"residual={self.residual:.1e})"
        )


def _name_values(r, key: str, val, what: str) -> list[tuple[str, ca.SX, float]]:
    """(element name, expression of (t,x,z,u,p), value) for each element meant by ``key``."""
    from .simulate.trajectory import NameNotFoundError, expand_name

    try:
        elems = expand_name(key, r.variables, "the model")
    except NameNotFoundError as exc:
        raise InitializationError(f"{what}: {exc}") from None
    arr = np.atleast_1d(np.asarray(val, dtype=float)).ravel()
    if arr.size == 1 and len(elems) > 1:
        arr = np.repeat(arr, len(elems))
    if arr.size != len(elems):
        raise InitializationError(
            f"{what}: {key!r} has {len(elems)} element(s) ({', '.join(elems)}) but "
            f"{arr.size} value(s) were given"
        )
    if not np.all(np.isfinite(arr)):
        raise InitializationError(f"{what}: the value of {key!r} is not finite: {val!r}")
    return [(e, ca.SX(r.variables[e]), float(v)) for e, v in zip(elems, arr, strict=False)]


def _fmt(names_vals: list[tuple[str, float]]) -> str:
    return ", ".join(f"{n} = {v:g}" for n, v in names_vals)


def initialize(
    r,
    t0: float = 0.0,
    guess: Mapping | None = None,
    fixed: Mapping | None = None,
    inputs: Mapping | None = None,
    params: Mapping | None = None,
    tol: float = 1e-12,
    max_iter: int = 100,
) -> InitialValues:
    """Consistent initial values: ``alg = 0`` and every invariant hold, ``fixed`` values exactly.

    Parameters
    ----------
    r : ReducedDAE
    t0 : float
        Initial time (invariants and inputs may depend on time).
    guess : dict, optional
        ``{name: value}`` pulled to in the least-squares sense (names of the original model:
        ``"p"``, ``"p[0]"``, ``"der(p)"``, ``"z"``). Unguessed states start at 0.
    fixed : dict, optional
        ``{name: value}`` held exactly. Fix at most the dynamic degrees of freedom
        (``InitialValues.free`` shows one valid choice); values implied by the others are
        accepted when consistent, and a contradiction raises :class:`InitializationError`
        naming the fixed values and consistency conditions in conflict.
    inputs, params : dict, optional
        As for :func:`daekit.simulate` (input values and derivatives at ``t0`` enter the
        invariants).
    tol : float
        Required max |residual| (scaled by ``1 + |values|``).

    Method: Gauss--Newton with CasADi Jacobians and SVD-based minimum-norm steps (see the
    module docstring); no IPOPT needed.

    Example
    -------
    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> from daekit.initialize import initialize
    >>> t = ca.SX.sym("t"); p = ca.SX.sym("p", 2); v = ca.SX.sym("v", 2); T = ca.SX.sym("T")
    >>> acc = T * p - ca.vertcat(0, 9.81)          # planar pendulum, index-1 form
    >>> alg = ca.dot(p, acc) + ca.dot(v, v)          # second derivative of the rod constraint
    >>> names = {"p[0]": p[0], "p[1]": p[1], "v[0]": v[0], "v[1]": v[1], "T": T}
    >>> r = ReducedDAE(t, ca.vertcat(p, v), T, ca.SX(0, 1), ca.SX(0, 1), ca.vertcat(v, acc),
    ...     alg, ca.vertcat((ca.dot(p, p) - 1) / 2, ca.dot(p, v)), ["rod", "d/dt rod"],
    ...     ["p[0]", "p[1]", "v[0]", "v[1]"], ["T"], [], [], np.zeros(0), names)
    >>> init = initialize(r, guess={"p": [0.9, 0.1]}, fixed={"v[0]": 0.0})
    >>> bool(abs(np.linalg.norm(init["p"]) - 1) < 1e-12), init.dof
    (True, 2)
    """
    from .simulate.inputs import InputSignal, resolve_params

    t0 = float(t0)
    nx, nz = r.nx, r.nz
    n = nx + nz
    pv = resolve_params(r, params)
    sig = InputSignal(r, inputs)
    u0 = sig.value(t0)

    w = ca.SX.sym("w", n)
    xs = w[:nx] if nx else ca.SX(0, 1)
    zs = w[nx:] if nz else ca.SX(0, 1)

    def on_w(expr: ca.SX) -> ca.SX:
        e = ca.vec(ca.densify(ca.SX(expr)))
        return ca.substitute(
            [e],
            [r.t, r.x, r.z, r.u, r.p],
            [ca.SX(t0), xs, zs, ca.DM(u0), ca.DM(pv)],
        )[0]

    fixed_items: list[tuple[str, ca.SX, float]] = []
    for k, v in (fixed or {}).items():
        fixed_items += _name_values(r, k, v, "fixed")
    guess_items: list[tuple[str, ca.SX, float]] = []
    for k, v in (guess or {}).items():
        guess_items += _name_values(r, k, v, "guess")
    fixed_names = [f[0] for f in fixed_items]
    dup = {nm for nm in fixed_names if fixed_names.count(nm) > 1}
    if dup:
        raise InitializationError(f"fixed: {sorted(dup)} given more than once")
    # two names for the same quantity (e.g. "der(p)" and "v" after elimination): symbols are
    # compared by hash, other expressions pairwise
    seen: dict[int, tuple[str, float]] = {}
    others: list[tuple[str, ca.SX, float]] = []
    for ni, ei, vi in fixed_items:
        e = ca.SX(ei)
        if e.is_symbolic():
            nj, vj = seen.setdefault(e.element_hash(), (ni, vi))
            pairs = [(nj, vj)] if nj != ni else []
        else:
            pairs = [(nj, vj) for nj, ej, vj in others if ca.is_equal(e, ej, 2)]
            others.append((ni, e, vi))
        for nj, vj in pairs:
            if abs(vi - vj) > 1e-12 * (1 + abs(vi)):
                raise InitializationError(
                    f"initialize: the fixed values {nj} = {vj:g} and {ni} = {vi:g} contradict "
                    f"each other: in this system both are the same quantity; fix only one"
                )

    alg = on_w(r.alg)
    inv = on_w(r.invariants) if r.invariants.numel() else ca.SX(0, 1)
    fix_expr = ca.vertcat(*[on_w(e) for _, e, _ in fixed_items]) if fixed_items else ca.SX(0, 1)
    fix_val = np.array([v for _, _, v in fixed_items])
    h = ca.vertcat(alg, inv, fix_expr)
    G = ca.vertcat(*[on_w(e) for _, e, _ in guess_items]) if guess_items else ca.SX(0, 1)
    gval = np.array([v for _, _, v in guess_items])
    row_names = (
        [f"alg[{i}]" for i in range(alg.numel())]
        + list(r.invariant_names)
        + fixed_names
    )
    n_alg, n_inv = int(alg.numel()), int(inv.numel())
    hfun = ca.Function("h", [w], [h, ca.jacobian(h, w)])
    gfun = ca.Function("g", [w], [G, ca.jacobian(G, w)])

    # starting point: x, z from guesses/fixed values that name them directly, else 0
    w0 = np.zeros(n)
    direct = {}
    for i, nm in enumerate(list(r.x_names) + list(r.z_names)):
        direct[nm] = i
    for nm, _, v in guess_items + fixed_items:
        if nm in direct:
            w0[direct[nm]] = v
    # z from alg with x frozen when alg is index 1 (a few Newton steps, failures ignored)
    w0 = _newton_z(hfun, w0, nx, n_alg)

    def hval(wv):
        hv, J = hfun(wv)
        hv = np.asarray(hv, dtype=float).ravel()
        hv[n_alg + n_inv:] -= fix_val
        return hv, np.asarray(J.full() if hasattr(J, "full") else J, dtype=float)

    wv = w0.copy()
    it = 0
    hv, J = hval(wv)
    scale = 1.0 + np.abs(np.concatenate([fix_val, gval, [0.0]])).max()
    converged = False
    history: list[float] = []
    for it in range(1, max_iter + 1):  # noqa: B007
        if not np.all(np.isfinite(hv)) or not np.all(np.isfinite(J)):
            bad = [row_names[i] for i in np.where(~np.isfinite(hv))[0]][:5]
            raise InitializationError(
                f"initialize: the equations {bad or '(Jacobian)'} are not finite at the current "
                "point; give guesses closer to a consistent state"
            )
        d = _gn_step(hv, J, gfun, wv, gval)
        normh = np.linalg.norm(hv)
        alpha = 1.0
        for _ in range(30):
            wn = wv + alpha * d
            hn, Jn = hval(wn)
            if np.all(np.isfinite(hn)) and (
                np.linalg.norm(hn) <= max(normh * (1 - 1e-4 * alpha), tol * scale) or alpha < 1e-3
            ):
                break
            alpha *= 0.5
        step = np.max(np.abs(wn - wv)) if n else 0.0
        if not np.all(np.isfinite(hn)) or np.linalg.norm(hn) > 1e3 * max(normh, 1.0):
            break  # diverging: analyse the best point reached
        wv, hv, J = wn, hn, Jn
        if np.max(np.abs(hv), initial=0.0) <= tol * scale and step <= 1e-9 * (
            1 + np.max(np.abs(wv), initial=0.0)
        ):
            converged = True
            break
        history.append(float(np.linalg.norm(hv)))
        if len(history) > 10 and history[-1] > 0.999 * history[-10] and history[-1] > 1e-6:
            break  # stagnating far from zero: inconsistent
    res = float(np.max(np.abs(hv), initial=0.0))
    if not converged and res > 1e-8 * scale:
        _raise_conflict(hv, J, row_names, n_alg, n_inv, fixed_items, res, it)

    # redundant fixed values: rows of J dependent on the rows before them
    redundant = _dependent_fixed(J, n_alg + n_inv, fixed_names)
    free = _free_states(r, J[: n_alg + n_inv], nx, set(fixed_names))

    x0, z0 = wv[:nx].copy(), wv[nx:].copy()
    values = _evaluate_variables(r, t0, x0, z0, u0, pv)
    cons = float(np.max(np.abs(hv[: n_alg + n_inv]), initial=0.0))
    return InitialValues(
        t0, x0, z0, u0, pv, values, free, len(free), redundant, cons, it,
        list(r.x_names), list(r.z_names),
    )


def _gn_step(hv, J, gfun, wv, gval) -> np.ndarray:
    n = wv.size
    if J.shape[0]:
        U, S, Vt = np.linalg.svd(J, full_matrices=True)
        k = int(np.sum(S > 1e-11 * max(S[0], 1e-300))) if S.size else 0
        dp = -(Vt[:k].T @ ((U[:, :k].T @ hv) / S[:k]))
        N = Vt[k:].T
    else:
        dp = np.zeros(n)
        N = np.eye(n)
    if gval.size and N.shape[1]:
        Gv, JG = gfun(wv)
        Gv = np.asarray(Gv, dtype=float).ravel()
        JG = np.asarray(JG.full(), dtype=float)
        A = JG @ N
        b = -(Gv + JG @ dp - gval)
        y = np.linalg.lstsq(A, b, rcond=1e-12)[0]
        return dp + N @ y
    return dp


def _newton_z(hfun, w0, nx, n_alg, iters: int = 20) -> np.ndarray:
    """Solve alg for z at fixed x (best effort; the joint iteration corrects anything left)."""
    n = w0.size
    if n_alg == 0 or n == nx:
        return w0
    w = w0.copy()
    for _ in range(iters):
        hv, J = hfun(w)
        g = np.asarray(hv, dtype=float).ravel()[:n_alg]
        Jz = np.asarray(J.full(), dtype=float)[:n_alg, nx:]
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(Jz))):
            return w0
        if np.max(np.abs(g), initial=0.0) < 1e-14:
            break
        dz = np.linalg.lstsq(Jz, -g, rcond=1e-12)[0]
        w[nx:] += dz
    return w if np.all(np.isfinite(w)) else w0


def _raise_conflict(hv, J, row_names, n_alg, n_inv, fixed_items, res, it) -> None:
    # at a Gauss-Newton stationary point J^T h ~ 0: h lies in the left null space; the rows
    # carrying it are the ones in conflict
    mag = np.abs(hv)
    involved = np.where(mag > 1e-6 * mag.max())[0] if mag.size else np.zeros(0, int)
    fixed_rows = [i for i in involved if i >= n_alg + n_inv]
    cond_rows = [row_names[i] for i in involved if n_alg <= i < n_alg + n_inv]
    alg_rows = [row_names[i] for i in involved if i < n_alg and mag[i] > 1e-3 * mag.max()]
    lhs = (J.T @ hv) if J.size else np.zeros(0)
    stationary = np.linalg.norm(lhs) <= 1e-6 * max(np.linalg.norm(hv), 1e-300) * max(
        1.0, np.linalg.norm(J)
    )
    if fixed_rows:
        fx = [(fixed_items[i - n_alg - n_inv][0], fixed_items[i - n_alg - n_inv][2])
              for i in fixed_rows]
        conds = cond_rows + alg_rows
        raise InitializationError(
            f"initialize: the fixed values {_fmt(fx)} contradict "
            + (f"the consistency conditions {conds}" if conds else "each other")
            + f" (max residual {res:.3g} after {it} iterations). Fix fewer values - fix only "
            "dynamic degrees of freedom - or make them consistent, and give the rest as guesses."
        )
    what = cond_rows + alg_rows
    hint = (
        "the equations cannot all hold" if stationary
        else "Gauss-Newton did not converge; give guesses closer to a consistent state"
    )
    raise InitializationError(
        f"initialize: no consistent values found: {what} keep a residual of {res:.3g} after "
        f"{it} iterations ({hint})."
    )


def _dependent_fixed(J, n_cons, fixed_names) -> list[str]:
    """Fixed values whose rows of ``J`` lie in the span of the consistency rows and of the
    fixed rows before them: one QR of the stacked rows (no pivoting, so the order is kept);
    ``|R_kk|`` is the distance of row ``k`` from the span of the rows before it."""
    if not fixed_names:
        return []
    n = J.shape[1]
    base = J[:n_cons]
    if base.size:
        # an orthonormal basis of the consistency rows' span, then remove it from the fixed rows
        u, sv, vt = np.linalg.svd(base, full_matrices=False)
        rank = int(np.sum(sv > 1e-9 * max(sv.max(initial=0.0), 1e-300)))
        basis = vt[:rank]
        rows = J[n_cons:] - (J[n_cons:] @ basis.T) @ basis
    else:
        rows = J[n_cons:].copy()
    if rows.shape[0] == 0 or n == 0:
        return list(fixed_names)
    scale = max(1.0, np.abs(J).max())
    r = scipy.linalg.qr(rows.T, mode="r")[0]
    diag = np.abs(np.diag(r)) if r.shape[0] >= rows.shape[0] else np.r_[
        np.abs(np.diag(r)), np.zeros(rows.shape[0] - r.shape[0])]
    return [nm for k, nm in enumerate(fixed_names) if diag[k] <= 1e-9 * scale]


def _free_states(r, Jc, nx, fixed: set[str]) -> set[str]:
    """A set of state names that can be fixed freely.

    The algebraic unknowns are eliminated first (``alg`` is solvable for ``z``):
    ``J = J_inv,x - J_inv,z J_alg,z^+ J_alg,x``; then a column-pivoted QR of ``J`` picks
    ``rank J`` dependent states (the pivots); the remaining states are free. The user's fixed
    states are weighted down so that they are reported free whenever they can be.
    """
    nz = Jc.shape[1] - nx
    n_alg = r.nz if r.alg.numel() == r.nz else int(r.alg.numel())
    Ja, Ji = Jc[:n_alg], Jc[n_alg:]
    if Ji.shape[0] == 0 or nx == 0:
        return set(r.x_names)
    if nz and n_alg:
        Jred = Ji[:, :nx] - Ji[:, nx:] @ np.linalg.lstsq(Ja[:, nx:], Ja[:, :nx], rcond=1e-12)[0]
    else:
        Jred = Ji[:, :nx]
    sv = np.linalg.svd(Jred, compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * max(sv.max(initial=0.0), 1e-300)))
    colw = np.array([1e-2 if nm in fixed else 1.0 for nm in r.x_names])
    _, _, piv = scipy.linalg.qr(Jred * colw, mode="economic", pivoting=True)
    dependent = set(piv[:rank].tolist())
    return {r.x_names[i] for i in range(nx) if i not in dependent}


def _evaluate_variables(r, t0, x0, z0, u0, pv) -> dict[str, float]:
    names = list(r.variables)
    for nm, _i in zip(r.u_names, range(len(r.u_names)), strict=False):
        if nm not in r.variables:
            names.append(nm)
    exprs = []
    for nm in names:
        if nm in r.variables:
            exprs.append(ca.SX(r.variables[nm]))
        else:
            exprs.append(r.u[r.u_names.index(nm)])
    if not names:
        return {}
    f = ca.Function("vars", [r.t, r.x, r.z, r.u, r.p], [ca.vertcat(*exprs)])
    try:
        vals = np.asarray(f(t0, x0, z0, u0, pv), dtype=float).ravel()
    except RuntimeError as exc:  # pragma: no cover - defensive
        raise DaekitError(f"cannot evaluate the model's variables: {exc}") from None
    return dict(zip(names, vals.tolist(), strict=False))
