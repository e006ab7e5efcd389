"""Dummy derivatives with dynamic state selection, on the event-driven driver.

A dummy-derivative system (``reduce_index(model, method="dummy_derivatives")``) keeps the
original constraints among its algebraic equations, so nothing drifts; but its state selection
is valid only where the selected pivot block stays nonsingular (the planar pendulum with ``y``
as dummy fails where the rod passes ``y = 0``).

:class:`PivotMonitor` watches the pivot measure ``q = 1 / selection_condition``
(:func:`daekit.reduction.selection_condition`) at the rows of every driver segment (output
points and check points at most ``span / 500`` apart). It fires where ``q`` falls below
``1 / max(threshold, growth * condition at selection)``, or is predicted (linear extrapolation
from the previous row) to fall below it by the next row (:func:`first_degraded`: the same
decision as evaluating ``q`` exactly at every row, with eigenvalues at one row in eight and
rigorous bounds between them). Its action makes a new selection at
that point (:func:`daekit.reduction.reselect`), carries the values over by name
(:func:`daekit.reduction.map_values`), and the driver restarts IDAS there from the consistent
state of the new selection (``z`` re-solved, no IDACalcIC). When the new selection equals the
old one, the firing is ignored (no restart) and that selection's limit is relaxed tenfold.
Should IDAS fail in a segment, the monitor re-selects at the segment's start (``rescue``).
One integrator is built per selection and reused. IDAS's error test covers the selected
states only (``suppress_algebraic=True`` unless the user passes it): the dummies and multipliers
follow from the states through the kept constraints (measured at least as accurate as plain
IDAS, and 1.2-6x faster than with them in the test: see :func:`simulate_dummy`). At recorded
points the algebraic unknowns
are polished by Newton's method, so the original constraints (among ``alg``) hold to rounding.
"""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np

from .driver import Action, Driver, Firing, Monitor
from .system import System, signal_for, system_for
from .trajectory import Trajectory
from .vectorized import evaluate_rows

__all__ = ["PivotMonitor", "conditions", "first_degraded", "simulate_dummy"]


def _blocks(rr, T, X, Z, U, p) -> list[tuple[np.ndarray, np.ndarray]]:
    """The stage blocks of :func:`daekit.reduction.selection_condition` at many rows, by one
    vectorized evaluation: ``[(A (n, rows, candidates), selected columns)]``, rows of ``A``
    with a non-finite entry set to NaN."""
    T = np.asarray(T, dtype=float).ravel()
    n = T.size
    cache = rr.derived("simulate.selection_condition", lambda r: {})
    if "fun" not in cache:
        syms = [ca.SX.sym(k, v.numel()) for k, v in (("t", rr.t), ("x", rr.x), ("z", rr.z),
                                                    ("u", rr.u), ("p", rr.p))]
        J = rr.selection_jacobian(*syms)
        blocks = [(ca.densify(J[list(map(int, R)), list(map(int, C))]), np.asarray(cols, int))
                  for R, C, cols in rr.selection_blocks if len(R)]
        cache["fun"] = ca.Function("blocks", syms, [b for b, _ in blocks] or [ca.SX(0, 1)])
        cache["cols"] = [c for _, c in blocks]
        cache["shapes"] = [b.shape for b, _ in blocks]
        cache["maps"] = {}
    F, cols, shapes = cache["fun"], cache["cols"], cache["shapes"]
    if not cols or n == 0:
        return []
    P = np.repeat(np.asarray(p, float).reshape(1, -1), n, axis=0)
    res = evaluate_rows(F, [T, np.asarray(X, float).reshape(n, -1), np.asarray(Z, float).reshape(
        n, -1), np.asarray(U, float).reshape(n, -1), P], cache["maps"])
    out = []
    for i, c in enumerate(cols):
        A = np.transpose(res[i].reshape((n, shapes[i][1], shapes[i][0])), (0, 2, 1))
        if not np.isfinite(A).all():
            A = np.where(np.all(np.isfinite(A), axis=(1, 2))[:, None, None], A, np.nan)
        out.append((A, c))
    return out


def _sigmas(A: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sigma_max(A), sigma_min(A[:, :, c]))`` per row (NaN rows give NaN)."""
    S = A[:, :, c]
    with np.errstate(invalid="ignore"):
        if A.shape[1] == 1:  # one equation (a position constraint): closed form
            return np.sqrt(np.sum(A[:, 0, :] ** 2, axis=1)), np.abs(S[:, 0, 0])
        bad = ~np.isfinite(A[:, 0, 0])
        if bad.any():
            A, S = np.where(bad[:, None, None], 0.0, A), np.where(bad[:, None, None], 0.0, S)
        # singular values from the Gram matrices' eigenvalues (half the cost of SVDs; the
        # squaring is harmless at the conditions watched, up to ~1e7)
        G1 = A @ np.transpose(A, (0, 2, 1))
        G2 = np.transpose(S, (0, 2, 1)) @ S
        n = A.shape[0]
        if G1.shape == G2.shape:  # (square blocks: one batched call)
            ev = np.linalg.eigvalsh(np.concatenate([G1, G2]))
            smax2, smin2 = ev[:n, -1], ev[n:, 0]
        else:
            smax2, smin2 = np.linalg.eigvalsh(G1)[:, -1], np.linalg.eigvalsh(G2)[:, 0]
        smax, smin = np.sqrt(np.abs(smax2)), np.sqrt(np.maximum(smin2, 0.0))
    if bad.any():
        smax[bad] = smin[bad] = np.nan
    return smax, smin


def _fro(D: np.ndarray, sel) -> tuple[np.ndarray, np.ndarray]:
    """Frobenius norms (bounds on the spectral norms) of the flattened blocks ``D`` and of
    their selected columns (flat indices ``sel``)."""
    Ds = D[:, sel]
    return (np.sqrt(np.einsum("ij,ij->i", D, D)), np.sqrt(np.einsum("ij,ij->i", Ds, Ds)))


def _ratio(smax, smin) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(smin > 0, smax / smin, np.inf)
    return np.where(np.isnan(smax) | np.isnan(smin), np.inf, c)


def conditions(rr, T, X, Z, U, p) -> np.ndarray:
    """:func:`daekit.reduction.selection_condition` at many rows at once (the stage blocks by
    one vectorized evaluation, batched eigenvalues of their Gram matrices): ``inf`` where a
    block is singular.

    >>> import daekit as dk, numpy as np
    >>> rd = dk.reduce_index(dk.examples.pendulum_planar(), method="dummy_derivatives",
    ...                      point={"x": 0.0, "y": -1.0})
    >>> vals = {"x": 1.0, "der(x)": 0.0, "y": 1e-9, "der(y)": 0.0}
    >>> x = np.array([vals[k] for k in rd.x_names]); z = np.zeros(rd.nz)
    >>> z[rd.z_names.index("y")] = 1e-9
    >>> c = conditions(rd, [0.0], x[None, :], z[None, :], np.zeros((1, 0)), rd.p_values)
    >>> bool(np.isclose(c[0], dk.reduction.selection_condition(rd, x, z)))
    True
    """
    n = np.size(T)
    worst = np.ones(n)
    for A, c in _blocks(rr, T, X, Z, U, p):
        worst = np.maximum(worst, _ratio(*_sigmas(A, c)))
    return worst


#: exact pivot measures at every ``ANCHOR_STRIDE``-th check row; the rows between get bounds
ANCHOR_STRIDE = 8


def first_degraded(rr, T, X, Z, U, p, lim: float, q_prev: float | None = None,
                   stride: int = ANCHOR_STRIDE):
    """The first row where the pivot measure ``q = 1 / conditions(...)`` says re-select: ``q <
    lim``, or ``2 q - q_prev < lim`` (falling below ``lim`` by the next row at its present
    rate; ``q_prev`` the previous row's, for row 0 the argument). Returns ``(i, q_i)``, or
    ``(-1, q at the last row)`` when no row says so.

    The same decision as :func:`conditions` at every row, at a fraction of its cost:
    ``sigma_max`` and ``sigma_min`` are computed exactly (eigenvalues) only at every
    ``stride``-th row (anchors) and at the last. At a row ``i`` near an anchor ``a`` Weyl's
    inequality bounds them, ``|sigma_k(A_i) - sigma_k(A_a)| <= ||A_i - A_a||_2 <= ||A_i -
    A_a||_F``, which bounds ``q_i`` from below; the same between consecutive rows bounds
    ``q_{i-1} / q_i`` from above (for the rate test). The rows where the bounds cannot decide
    (near the limit, or falling fast) are computed exactly.
    The monitor thus looks at every check row, and pays eigenvalues at about one in
    ``stride`` of them while the pivot stays away from its limit.

    >>> import daekit as dk, numpy as np
    >>> rd = dk.reduce_index(dk.examples.pendulum_planar(), method="dummy_derivatives",
    ...                      point={"x": 0.0, "y": -1.0})
    >>> th = np.linspace(0.0, 1.5, 200)            # swinging out towards y = 0
    >>> vals = {"x": np.sin(th), "y": -np.cos(th), "der(x)": 0 * th, "der(y)": 0 * th}
    >>> X = np.column_stack([vals[k] for k in rd.x_names])
    >>> Z = np.zeros((th.size, rd.nz))
    >>> for j, k in enumerate(rd.z_names):
    ...     if k in vals:
    ...         Z[:, j] = vals[k]
    >>> U, p = np.zeros((th.size, 0)), rd.p_values
    >>> q = 1 / conditions(rd, th, X, Z, U, p)
    >>> i, qi = first_degraded(rd, th, X, Z, U, p, lim=0.2)
    >>> bool(i == np.nonzero((q < 0.2) | (2 * q - np.r_[np.nan, q[:-1]] < 0.2))[0][0])
    True
    """
    T = np.asarray(T, dtype=float).ravel()
    n = T.size
    if n == 0:
        return -1, q_prev
    qp = np.nan if q_prev is None else float(q_prev)
    blocks = _blocks(rr, T, X, Z, U, p)
    if not blocks:
        return -1, 1.0
    stride = max(int(stride), 1)
    if n <= 2 * stride:  # few rows: exact everywhere
        anchors = np.arange(n)
    else:
        anchors = np.arange(0, n, stride)
        if anchors[-1] != n - 1:
            anchors = np.append(anchors, n - 1)
    at_anchor = np.zeros(n, bool)
    at_anchor[anchors] = True
    hi = np.ones(n)  # an upper bound on the condition (the largest over the blocks)
    exact = np.ones(n)  # the condition where it is known exactly (every anchor)
    rho = np.ones(n)  # q_{i-1} <= rho_i q_i (row 0: unused)
    everywhere = True  # (every block exact at every row)
    slack = 1e-9  # (relative: rounding of the anchors' eigenvalues)
    for A, c in blocks:
        if A.shape[1] == 1 or anchors.size == n:  # closed form, or exact everywhere
            cnd = _ratio(*_sigmas(A, c))
            hi, exact = np.maximum(hi, cnd), np.maximum(exact, cnd)
            with np.errstate(invalid="ignore", divide="ignore"):
                r = np.maximum(cnd[1:], 1.0) / np.maximum(cnd[:-1], 1.0)
            rho[1:] = np.fmax(rho[1:], np.where(np.isnan(r), np.inf, r))
            continue
        everywhere = False
        amax, amin = _sigmas(A[anchors], c)
        exact[anchors] = np.maximum(exact[anchors], _ratio(amax, amin))
        Fa = np.ascontiguousarray(A).reshape(n, -1)  # rows flattened: (n, rows * candidates)
        sel = (np.arange(A.shape[1])[:, None] * A.shape[2] + np.asarray(c)[None, :]).ravel()
        # Weyl from the nearest anchor a: |sigma_k(A_i) - sigma_k(A_a)| <= ||A_i - A_a||_F
        rows = np.arange(n)
        j = np.clip(np.searchsorted(anchors, rows), 1, anchors.size - 1)
        k = np.where(rows - anchors[j - 1] <= anchors[j] - rows, j - 1, j)  # nearest (the
        # last anchor, n - 1, included: the rows of a last partial stride are nearer to it)
        dA, dS = _fro(Fa - Fa[anchors[k]], sel)
        m, sv = amax[k], amin[k]
        with np.errstate(invalid="ignore"):
            smax_lo = m * (1 - slack) - dA
            smin_lo = sv * (1 - slack) - dS - slack * m
            chi = _ratio(m * (1 + slack) + dA, np.maximum(smin_lo, 0.0))
        chi[~np.isfinite(Fa[:, 0])] = np.inf  # (non-finite entries: singular)
        hi = np.maximum(hi, chi)
        # from row i - 1 to row i the singular values move by at most the difference's norm:
        # sigma_min(S_{i-1}) <= sigma_min(S_i) + dS_i, sigma_max(A_{i-1}) >= sigma_max(A_i) - dA_i
        dA, dS = _fro(Fa[1:] - Fa[:-1], sel)
        with np.errstate(invalid="ignore", divide="ignore"):
            r = (1.0 + dS / smin_lo[1:]) / (1.0 - dA / smax_lo[1:])
        r = np.where((smax_lo[1:] > dA) & (smin_lo[1:] > 0) & ~np.isnan(r), r, np.inf)
        rho[1:] = np.fmax(rho[1:], r)
    q_lo = 1.0 / hi
    q = np.where(at_anchor | everywhere, 1.0 / exact, np.nan)
    if not everywhere:
        # no firing at row i if q_i >= lim and 2 q_i - q_{i-1} >= lim; with q_{i-1} <= rho_i q_i
        # the second holds when q_i (2 - rho_i) >= lim (row 0: the exact q_prev)
        with np.errstate(invalid="ignore"):
            ext = q_lo * (2.0 - rho)
            ext[0] = 2.0 * q_lo[0] - qp if np.isfinite(qp) else np.inf
            unsure = np.nonzero(~((q_lo >= lim) & (ext >= lim)))[0]
        need = np.unique(np.concatenate([unsure, unsure[unsure > 0] - 1]))
        need = need[~at_anchor[need]]
        if need.size:
            Xa, Za, Ua = (np.asarray(a, float).reshape(n, -1)[need] for a in (X, Z, U))
            q[need] = 1.0 / conditions(rr, T[need], Xa, Za, Ua, p)
    else:
        unsure = np.arange(n)
    prev = np.concatenate([[qp], q[:-1]])
    with np.errstate(invalid="ignore"):
        fire = (q[unsure] < lim) | (2.0 * q[unsure] - prev[unsure] < lim)
    hit = np.nonzero(fire)[0]
    if hit.size:
        i = int(unsure[hit[0]])
        return i, float(q[i])
    return -1, float(q[n - 1])


#: dummy-derivative systems with more algebraic unknowns than this are integrated as they are
#: (the elimination below substitutes one unknown at a time)
COMPACT_MAX_NZ = 200


def compact(rr):
    """``rr`` with the algebraic unknowns that an equation gives explicitly substituted.

    A dummy-derivative system keeps every derivative up to its offset as an unknown: the 3D
    pendulum's has 12 algebraic unknowns (``der(p)``, ``der(v)``, ``der(p,2)``, ``z``, the
    dummies ``p[2]``, ``v[2]``) where the index-1 form by hand has one. An equation affine in
    one unknown with a constant or parameter-only coefficient (``der(p)[0] - v[0] = 0``,
    ``m der(v)[0] - (u[0] - z p[0]) = 0``) gives it explicitly; substituting those leaves the
    same solution with fewer unknowns for IDAS (on the 3D pendulum at rtol 1e-8: 1838 steps
    instead of 3359: fewer algebraic unknowns carrying their Newton errors into IDAS's error
    test). Every name stays readable (``variables`` substituted). Returns ``rr`` itself when
    nothing is eliminated (or it has more than ``COMPACT_MAX_NZ`` algebraic unknowns); else a
    new ReducedDAE, built once per system; :func:`full_values` and :func:`compact_values`
    carry values between the two.

    >>> import daekit as dk
    >>> rd = dk.reduce_index(dk.examples.pendulum3d(), method="dummy_derivatives",
    ...                      point={"p": [0.56, 0.0, -0.83], "v": [0.0, 1.5, 0.0]})
    >>> rd.nz, compact(rd).nz
    (12, 3)
    """
    return rr.derived("simulate.compact", _build_compact)


def _build_compact(rr):
    nz = rr.nz
    if nz == 0 or nz > COMPACT_MAX_NZ:
        return rr
    pv = np.asarray(rr.p_values, dtype=float)
    zl = [rr.z[i] for i in range(nz)]
    names = list(rr.z_names)
    alg = [rr.alg[i] for i in range(rr.alg.numel())]
    alg_names = list(rr.alg_labels)
    others = ca.vertcat(rr.t, rr.x, rr.u)
    subs: list[tuple[ca.SX, ca.SX]] = []
    changed = True
    while changed:
        changed = False
        for i, a in enumerate(alg):
            for j, zj in enumerate(zl):
                if not ca.depends_on(a, zj):
                    continue
                c = ca.jacobian(a, zj)
                if ca.depends_on(c, ca.vertcat(others, *zl)):
                    continue  # not affine in zj, or a state-dependent coefficient
                cv = float(ca.DM(ca.Function("c", [rr.p], [c])(pv)))
                if not (math.isfinite(cv) and abs(cv) > 1e-12):
                    continue
                e = -ca.substitute(a, zj, ca.SX(0)) / c
                subs.append((zj, e))
                del alg[i], alg_names[i], zl[j], names[j]
                alg = [ca.substitute(b, zj, e) for b in alg]
                subs = [(s, ca.substitute(x, zj, e)) for s, x in subs]
                changed = True
                break
            if changed:
                break
    if not subs:
        return rr
    old = ca.vertcat(*[s for s, _ in subs])
    new = ca.vertcat(*[e for _, e in subs])

    def sub(x):
        x = ca.SX(x)
        return ca.substitute(x, old, new) if x.numel() else x

    zc = ca.vertcat(*zl) if zl else ca.SX(0, 1)
    zfull = ca.Function("zfull", [rr.t, rr.x, zc, rr.u, rr.p], [sub(rr.z)])
    sel = rr.selection_jacobian
    if sel is not None:  # the pivot measure of the full system, at zfull
        sel = ca.Function("J", [rr.t, rr.x, zc, rr.u, rr.p],
                          [sel(rr.t, rr.x, zfull(rr.t, rr.x, zc, rr.u, rr.p), rr.u, rr.p)])
    rc = dataclasses.replace(
        rr, z=zc, z_names=names, ode=sub(rr.ode), alg=ca.vertcat(*alg) if alg else ca.SX(0, 1),
        invariants=sub(rr.invariants), variables={k: sub(v) for k, v in rr.variables.items()},
        alg_names=alg_names, selection_jacobian=sel, info=dict(rr.info))
    idx = np.array([rr.z_names.index(n) for n in names], dtype=int)
    rc.derived("simulate.full_system", lambda _: (rr, zfull, idx))
    return rc


def _full_entry(rc):
    """``(full system, zfull, indices)`` of a compact system, or None."""
    store = rc.__dict__.get("_derived", {})
    hit = store.get("simulate.full_system")
    return None if hit is None else rc.derived("simulate.full_system", lambda _: None)


def full_values(rc, t, x, z, u, p):
    """``(rr, x, z_full)``: the values of a :func:`compact` system in its full system."""
    entry = _full_entry(rc)
    if entry is None:
        return rc, np.asarray(x, float), np.asarray(z, float)
    rr, zfull, _ = entry
    zf = np.asarray(zfull(float(t), x, z, u, p), dtype=float).ravel()
    return rr, np.asarray(x, float), zf


def full_system(rc):
    """The full dummy-derivative system of a :func:`compact` one (itself otherwise)."""
    entry = _full_entry(rc)
    return rc if entry is None else entry[0]


def compact_values(rc, z_full) -> np.ndarray:
    """The algebraic values of the compact system ``rc`` from those of its full system."""
    entry = _full_entry(rc)
    z_full = np.asarray(z_full, float).ravel()
    return z_full if entry is None else z_full[entry[2]]


class PivotMonitor(Monitor):
    """The dummy-derivative re-selection monitor (see the module docstring).

    Parameters
    ----------
    entry : callable
        ``entry(reduced) -> System`` (the System of a selection, built once).
    known : callable, optional
        ``known() -> {x_names tuple: System}``: the selections met so far (tried before a new
        reduction at a switch).
    pv : array
        Parameter values.
    threshold, growth : float
        Re-select when the condition exceeds ``max(threshold, growth * condition at
        selection)``.
    """

    name = "dummy_derivatives"
    #: the first segment is the whole span: a selection that stays good is one IDAS run (an
    #: early firing wastes the rest of it, but a degrading pivot makes IDAS fail soon after,
    #: and the driver then integrates only up to half-way to the failure)
    first_segment = 1.0

    def __init__(self, entry, pv, threshold: float = 3.0, growth: float = 2.5,
                 check_dt: float | None = None, known=None) -> None:
        self.entry = entry
        self.known = known or (lambda: {})
        self.pv = np.asarray(pv, dtype=float)
        self.threshold, self.growth = threshold, growth
        self.check_dt = check_dt
        self.switches: list[tuple[float, list[str]]] = []
        self.relax: dict[tuple, float] = {}
        self.declined = 0

    def _limit(self, rr) -> float:
        c0 = float((rr.state_selection or {}).get("condition", 1.0) or 1.0)
        return max(self.threshold, self.growth * c0) * self.relax.get(tuple(rr.x_names), 1.0)

    @staticmethod
    def _cond(rr, t, x, z, u, p) -> float:
        from ..reduction import selection_condition

        try:
            c = float(selection_condition(rr, x, z, u, p, t))
        except Exception:  # noqa: BLE001 - treated as singular
            return math.inf
        return c if math.isfinite(c) else math.inf

    def init(self, driver, t0, x0, z0):
        return {"q": None}

    def check(self, seg, state):
        rr = seg.system.r
        lim = 1.0 / self._limit(rr)
        qp = state.get("q")
        tp = state.get("tq", -math.inf)
        rows = np.nonzero(seg.check[1:])[0] + 1  # one batched evaluation
        i, qi = first_degraded(rr, seg.t[rows], seg.X[rows], seg.Z[rows], seg.U[rows], seg.p,
                               lim, qp)
        if i >= 0:
            j = int(rows[i])
            state["q_fire"] = qi
            return Firing(float(seg.t[j]), seg.X[j], seg.Z[j], index=j)
        state["q_seg"] = (qi, float(seg.t[rows[-1]])) if rows.size else (qp, tp)
        return None

    def accept(self, seg, upto, state):
        if "q_seg" in state:
            state["q"], state["tq"] = state.pop("q_seg")
        return state

    def _switch(self, t, x, z, system: System):
        from ..reduction import map_values, reselect

        u = system.sig.value(t)
        # the full dummy-derivative systems (with every derivative) carry values by name
        cur, x, z = full_values(system.r, t, x, z, u, self.pv)
        new = None
        # a selection met before that is well conditioned here: no new reduction needed
        for key, sy in self.known().items():
            if key == tuple(cur.x_names):
                continue
            full = full_system(sy.r)
            xa, za = map_values(cur, full, x, z)
            za = compact_values(sy.r, za)
            c = float(conditions(sy.r, [t], xa[None, :], za[None, :], np.asarray(u)[None, :],
                                 self.pv)[0])
            if c < 0.5 * self._limit(sy.r):
                new = full
                break
        if new is None:
            new = reselect(cur, (np.asarray(x, float), np.asarray(z, float)))
        if tuple(new.x_names) == tuple(cur.x_names):
            return None
        sy = self.entry(new)
        xn, zn = map_values(cur, new, x, z)
        self.switches.append((float(t), list(sy.r.x_names)))
        return Action(x=xn, z=compact_values(sy.r, zn), system=sy)

    def act(self, firing, driver, state):
        act = self._switch(firing.t, firing.x, firing.z, driver.current)
        if act is None:  # the same selection: keep going, relax its limit
            key = tuple(driver.current.r.x_names)
            self.relax[key] = self.relax.get(key, 1.0) * 10.0
            self.declined += 1
            state["q"] = state.get("q_fire")
            return Action(ignore=True), state
        state = {"q": None}
        return act, state

    def rescue(self, driver, t, x, z, system, error, state):
        u = system.sig.value(t)
        c = float(conditions(system.r, [t], np.asarray(x, float)[None, :],
                             np.asarray(z, float)[None, :], np.asarray(u)[None, :], self.pv)[0])
        if c < self._limit(system.r):
            # the selection is good where the segment starts (it was just made, typically):
            # a new reduction there would find it again (a fifth of a second on the planar
            # pendulum); the driver integrates up to half-way to the failure instead
            return None, state
        act = self._switch(t, x, z, system)
        return act, ({"q": None} if act is not None else state)


def simulate_dummy(r, tg, x0, z0, inputs, pv, rtol, atol, options, progress: bool = False,
                   threshold: float = 3.0, growth: float = 2.5, checks: int = 500) -> Trajectory:
    """Integrate the dummy-derivative system ``r`` over ``tg`` on the driver, re-selecting the
    states when the pivot degrades (see the module docstring)."""
    # the algebraic unknowns (the dummies, e.g. p[2] and v[2] of the 3D pendulum, and the
    # multipliers) are left out of IDAS's error test (suppress_algebraic=True, unless the user
    # says otherwise): they follow from the selected states through alg = 0, whose pivot the
    # monitor keeps well conditioned, so the states' error test controls them. Measured
    # against exact solutions (positions, largest error over the grid), with the dummies in
    # the test -> out of it:
    # - 3D pendulum, 10 s, rtol 1e-4 .. 1e-10: 0.69-0.93x the steps of the hand-written
    #   index-1 form and 2.3-16x more accurate than it (rtol 1e-8: 1838 -> 940 steps, error
    #   6.8e-7 -> 5.5e-7; at 1e-9 and 1e-10 5-6x less accurate than with the dummies);
    # - planar pendulum from horizontal, 100 s, 2001 points: rtol 1e-6 22 s -> 3.9 s, error
    #   1.9e-2 -> 1.1e-1 (plain IDAS 2.0e-1); rtol 1e-8 26 s -> 4.6 s, 2.4e-5 -> 2.2e-4 (plain
    #   1.1e-3): less accurate than before, still more accurate than plain IDAS;
    # - the (chaotic) double pendulum, 20 s, rtol 1e-6 .. 1e-10, 201 and 2001 points:
    #   0.36-1.04x plain IDAS's error, 2-4x less time than with the dummies.
    # (With the full, not compacted, dummy-derivative systems of earlier versions it had made
    # the planar pendulum 6-9x less accurate than plain IDAS.) tests/test_simulate_driver.py
    # checks the accuracy against plain IDAS.
    options = dict(options)
    options.setdefault("suppress_algebraic", True)
    # (IDAS's own Newton test, nonlin_conv_coeff 0.33: a tighter 0.1 took the 3D pendulum
    # from 1838 to 1321 steps at rtol 1e-8, and the rigid body of the tour from 14535 to
    # 1.37 million steps over 100 s at rtol 1e-6; not used)
    cache: dict[tuple, System] = {}

    def entry(rr) -> System:
        key = tuple(rr.x_names)
        if key not in cache:
            rc = compact(rr)  # explicitly given algebraic unknowns substituted
            cache[key] = system_for(rc, signal_for(rc, inputs), rtol, atol, options)
        return cache[key]

    system = entry(r)
    z0 = compact_values(system.r, z0)
    span = float(tg[-1] - tg[0])
    mon = PivotMonitor(entry, pv, threshold, growth, check_dt=span / max(int(checks), 1),
                       known=lambda: cache)
    d = Driver(system, tg, x0, z0, pv, [mon], progress=progress, label="dummy derivatives")
    res = d.run()
    for part in res.parts:  # the original constraints to rounding at the recorded points
        sy = part[0]
        T, X, Z = res.arrays(part)
        if T.size and sy.nz:
            res.set_rows(part, X, sy.polish_z(T, X, Z, sy.sig.values(T), pv))
    return res.trajectory({"selection_switches": mon.switches,
                           "selections_declined": mon.declined})

