"""Simulation with dummy derivatives and dynamic state selection.

A dummy-derivative system (``reduce_index(model, method="dummy_derivatives")``) keeps the
original constraints among its algebraic equations, so nothing drifts; but its state selection
is valid only where the selected pivot block stays nonsingular (the planar pendulum with ``y``
as dummy fails where the rod passes ``y = 0``).

The rule used here: the time span is watched at ``checks`` evenly spaced points (plus the output
points); one IDAS call covers an output interval with those check points as its output grid
(no restart unless the selection changes). At each check point the pivot measure
``q = 1 / selection_condition`` (:func:`daekit.reduction.selection_condition`) is computed; when
``q`` is below ``1 / max(threshold, growth * condition at selection)``, or is predicted (linear
extrapolation from the previous check point) to fall below it by the next one, a new selection
is made at that point (:func:`daekit.reduction.reselect`), the values are carried over by name
(:func:`daekit.reduction.map_values`), the algebraic values re-solved, and integration restarts
there. One integrator is built per selection and reused. If IDAS still fails inside an interval,
the interval is retried after a fresh selection at its start, in two halves (recursively, up
to ``max_split`` times). At recorded points the algebraic unknowns are polished by Newton's
method, so the original constraints (among ``alg``) hold to rounding.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import SimulationError
from .inputs import InputSignal
from .trajectory import Trajectory

__all__ = ["simulate_dummy"]


def simulate_dummy(r, tg, x0, z0, inputs, params, sig, pv, system, progress, rtol, atol,
                   options, threshold: float = 3.0, growth: float = 2.5,
                   max_split: int = 6, checks: int = 500) -> Trajectory:
    """Integrate the dummy-derivative system ``r`` over the grid ``tg``, re-selecting states."""
    from ..reduction import map_values, reselect, selection_condition
    from .idas import _Progress, _reason, _reraise_input_error, _System

    options = dict(options)
    options.setdefault("max_num_steps", 5000)  # a failing interval is retried: fail cheaply
    system = _System(r, sig, rtol, atol, options)
    cache: dict[tuple, tuple] = {tuple(r.x_names): (r, sig, system)}

    def entry(rr):
        key = tuple(rr.x_names)
        if key not in cache:
            sg = InputSignal(rr, inputs)
            cache[key] = (rr, sg, _System(rr, sg, rtol, atol, options))
        return cache[key]

    def cond_of(rr, t, x, z, u) -> float:
        try:
            c = float(selection_condition(rr, x, z, u, pv, t))
        except Exception:  # noqa: BLE001 - treated as singular
            return math.inf
        return c if math.isfinite(c) else math.inf

    def limit_of(rr) -> float:
        c0 = float((rr.state_selection or {}).get("condition", 1.0) or 1.0)
        return max(threshold, growth * c0)

    st = {"cur": r, "x": np.asarray(x0, float), "z": np.asarray(z0, float), "q": None,
          "t": float(tg[0])}
    segments: list[tuple] = []
    seg: tuple[list, list, list] = ([], [], [])
    switches: list[tuple[float, list[str]]] = []
    stats: dict = {"steps": 0, "residual_evaluations": 0, "retries": 0}

    def record(t):
        rr, sg, sy = entry(st["cur"])
        st["z"] = sy.solve_z(t, st["x"], st["z"], sg.value(t), pv)
        seg[0].append(float(t))
        seg[1].append(st["x"].copy())
        seg[2].append(st["z"].copy())

    def switch(t) -> bool:
        nonlocal seg
        cur = st["cur"]
        new = reselect(cur, (st["x"], st["z"]))
        if tuple(new.x_names) == tuple(cur.x_names):
            return False
        xn, zn = map_values(cur, new, st["x"], st["z"])
        rr, sg, sy = entry(new)
        if rr is not new:
            xn, zn = map_values(new, rr, xn, zn)
        zn = sy.solve_z(t, xn, zn, sg.value(t), pv)
        segments.append((cur, seg))
        seg = ([], [], [])
        st.update(cur=rr, x=xn, z=zn, q=None)
        switches.append((float(t), list(rr.x_names)))
        return True

    def check(t) -> bool:
        rr, sg, _ = entry(st["cur"])
        q = 1.0 / cond_of(rr, t, st["x"], st["z"], sg.value(t))
        qp = st["q"]
        st["q"] = q
        lim = 1.0 / limit_of(rr)
        if q < lim or (qp is not None and 2.0 * q - qp < lim):
            return switch(t)
        return False

    def advance(ta, tb, depth=0):
        """Integrate [ta, tb] from the current state, checking the selection on the way."""
        rr, sg, sy = entry(st["cur"])
        n = max(1, math.ceil((tb - ta) / dt_check - 1e-9))
        F = sy.scaled_integrator(n)
        try:
            res = F(x0=st["x"], z0=st["z"], p=np.concatenate([pv, [ta, tb - ta]]))
        except RuntimeError as exc:
            _reraise_input_error(sy)
            stats["retries"] += 1
            if n > 1:  # march check interval by check interval, checking in between
                pts = np.linspace(ta, tb, n + 1)
                for j in range(n):
                    if st["t"] < pts[j + 1] - 1e-12 * max(1.0, abs(tb)):
                        advance(max(st["t"], pts[j]), pts[j + 1], depth + 1)
                return
            if depth >= max_split:
                raise SimulationError(
                    f"simulate: IDAS failed at t = {ta:.6g} with dummy derivatives (states "
                    f"{list(rr.x_names)}): {_reason(exc)}",
                    t=float(ta),
                ) from None
            switch(ta)
            tm = 0.5 * (ta + tb)
            advance(ta, tm, depth + 1)
            advance(tm, tb, depth + 1)
            return
        s = F.stats()
        stats["steps"] += int(s.get("nsteps", 0))
        stats["residual_evaluations"] += int(s.get("nfevals", 0))
        X = np.asarray(res["xf"], float).reshape(rr.nx, n)
        Z = np.asarray(res["zf"], float).reshape(rr.nz, n)
        for j in range(n):
            tj = tb if j == n - 1 else ta + (j + 1) * (tb - ta) / n
            st["x"], st["z"], st["t"] = X[:, j].copy(), Z[:, j].copy(), tj
            if check(tj) and j < n - 1:
                advance(tj, tb, depth)
                return

    bar = _Progress(progress, tg[0], tg[-1], "dummy derivatives")
    w0 = time.perf_counter()
    dt_check = (tg[-1] - tg[0]) / max(int(checks), 1)
    record(tg[0])
    check(tg[0])
    try:
        for k in range(tg.size - 1):
            try:
                advance(tg[k], tg[k + 1])
            except SimulationError as exc:
                segments.append((st["cur"], seg))
                exc.trajectory = _assemble(segments, pv, stats, inputs)
                raise
            record(tg[k + 1])
            bar.update(tg[k + 1])
    finally:
        bar.close()
    segments.append((st["cur"], seg))
    stats["integrator_wall_time"] = time.perf_counter() - w0
    stats["intervals"] = tg.size - 1
    stats["selection_switches"] = switches
    return _assemble(segments, pv, stats, inputs)


def _assemble(segments, pv, stats, inputs) -> Trajectory:
    from .idas import _make_trajectory

    parts = []
    for rr, (ts, xs, zs) in segments:
        if not ts:
            continue
        ts = np.asarray(ts, float)
        X = np.vstack(xs).reshape(ts.size, rr.nx)
        Z = np.vstack(zs).reshape(ts.size, rr.nz)
        U = InputSignal(rr, inputs).values(ts)
        parts.append(_make_trajectory(rr, ts, X, Z, U, pv, {}))
    if not parts:
        return Trajectory([], {}, None, [], stats)
    names = list(parts[0].values)
    t = np.concatenate([p.t for p in parts])
    vals = {n: np.concatenate([p.values[n] for p in parts]) for n in names}
    inv = np.vstack([p.invariants for p in parts])
    return Trajectory(t, vals, inv, parts[0].invariant_names, stats)
