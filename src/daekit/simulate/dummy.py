"""Dummy derivatives with dynamic state selection, on the event-driven driver.

A dummy-derivative system (``reduce_index(model, method="dummy_derivatives")``) keeps the
original constraints among its algebraic equations, so nothing drifts; but its state selection
is valid only where the selected pivot block stays nonsingular (the planar pendulum with ``y``
as dummy fails where the rod passes ``y = 0``).

:class:`PivotMonitor` watches the pivot measure ``q = 1 / selection_condition``
(:func:`daekit.reduction.selection_condition`) at the rows of every driver segment (output
points and check points at most ``span / 500`` apart). It fires where ``q`` falls below
``1 / max(threshold, growth * condition at selection)``, or is predicted (linear extrapolation
from the previous row) to fall below it by the next row. Its action makes a new selection at
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

__all__ = ["PivotMonitor", "simulate_dummy"]


def conditions(rr, T, X, Z, U, p) -> np.ndarray:
    """:func:`daekit.reduction.selection_condition` at many rows at once (the stage blocks by
    one vectorized evaluation, batched eigenvalues of their Gram matrices): ``inf`` where a
    block is singular."""
    T = np.asarray(T, dtype=float).ravel()
    n = T.size
    if n == 0:
        return np.zeros(0)
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
    if not cols:
        return np.ones(n)
    P = np.repeat(np.asarray(p, float).reshape(1, -1), n, axis=0)
    res = evaluate_rows(F, [T, np.asarray(X, float).reshape(n, -1), np.asarray(Z, float).reshape(
        n, -1), np.asarray(U, float).reshape(n, -1), P], cache["maps"])
    worst = np.ones(n)
    for i, c in enumerate(cols):
        A = np.transpose(res[i].reshape((n, shapes[i][1], shapes[i][0])), (0, 2, 1))
        ok = None
        if not np.isfinite(res[i]).all():
            ok = np.all(np.isfinite(A), axis=(1, 2))
            A = np.where(ok[:, None, None], A, 0.0)
        # singular values from the Gram matrices' eigenvalues (half the cost of SVDs; the
        # squaring is harmless at the conditions watched, up to ~1e7)
        S = A[:, :, c]
        with np.errstate(divide="ignore", invalid="ignore"):
            if A.shape[1] == 1:  # one equation (a position constraint): closed form
                smax2 = np.sum(A[:, 0, :] ** 2, axis=1)
                smin2 = S[:, 0, 0] ** 2
            else:
                G1 = A @ np.transpose(A, (0, 2, 1))
                G2 = np.transpose(S, (0, 2, 1)) @ S
                if G1.shape == G2.shape:  # (square blocks: one batched call)
                    ev = np.linalg.eigvalsh(np.concatenate([G1, G2]))
                    smax2, smin2 = ev[:n, -1], ev[n:, 0]
                else:
                    smax2 = np.linalg.eigvalsh(G1)[:, -1]
                    smin2 = np.linalg.eigvalsh(G2)[:, 0]
            cond = np.where(smin2 > 0, np.sqrt(np.abs(smax2) / smin2), np.inf)
        if ok is not None:
            cond[~ok] = np.inf
        worst = np.maximum(worst, cond)
    return worst


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
        q = 1.0 / conditions(rr, seg.t[rows], seg.X[rows], seg.Z[rows], seg.U[rows], seg.p)
        prev = np.concatenate([[qp if qp is not None else np.nan], q[:-1]])
        with np.errstate(invalid="ignore"):
            bad = (q < lim) | (2.0 * q - prev < lim)
        hit = np.nonzero(bad)[0]
        if hit.size:
            j = int(rows[hit[0]])
            state["q_fire"] = float(q[hit[0]])
            return Firing(float(seg.t[j]), seg.X[j], seg.Z[j], index=j)
        state["q_seg"] = (float(q[-1]), float(seg.t[rows[-1]])) if rows.size else (qp, tp)
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

