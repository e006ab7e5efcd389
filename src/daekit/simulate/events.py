"""Event-driven simulation: declared events, resets, and the model's own switches.

:func:`daekit.simulate` comes here when the model has events (:meth:`daekit.Model.event`) or
its equations contain switches (``if_else`` conditions, ``fabs``/``sign``/``fmin``/``fmax``
kinks; :mod:`daekit.events`). Two paths share the rules below:

* without stabilization, with Baumgarte and with projection (sim's drift-tolerance
  ``DriftMonitor``), the events are one more monitor, :class:`EventMonitor`, of the
  event-driven driver :mod:`daekit.simulate.driver`, passed through ``simulate(...,
  monitors=[...])``: one continuous IDAS run, interrupted only at an event; location by the
  driver's Illinois re-integration from the last row before the crossing, to
  ``rtol * max(1, |t|)``; the event point is the last one before the crossing. The switch
  branches ride along as constant states (:func:`with_branch_states`), so flipping one is a
  reset;
* with dummy derivatives or a GGL (index-2) system the time span is integrated in *segments*,
  each an ordinary run of that remedy through :func:`daekit.simulate`, on a grid of the output
  points plus check points, and located by re-integration as below (the event point is the
  first one past the crossing). ``use_driver=False`` sends the other remedies this way too.

Monitoring
    Every event function and switching function is evaluated at every point of a segment's
    grid: the output points and extra check points so that no check interval is longer than
    ``event_spacing`` (default: the smaller of the output spacing and 1/200 of the span; with
    dummy derivatives, whose segments restart at every grid point, the output spacing). A
    crossing is a change of sign between two consecutive check points (in the event's
    ``direction``). **Rule for double crossings:** a function that crosses zero twice inside
    one check interval is not seen; make ``event_spacing`` shorter than the shortest time the
    function can spend on one side of zero.
Location
    By re-integration from the last check point before the crossing (same remedy's system,
    same tolerances) with the Illinois variant of regula falsi on the crossing function,
    until the bracket is shorter than ``rtol * max(1, |t|)``. The event time is an end of the
    bracket (on the driver the one before the crossing, on segments the one past it); its
    accuracy is that of the integrated solution, about ``atol / |g'|``. Functions that crossed
    within that bracket fire together (*simultaneous*), declared events in declaration order,
    then switches.
After an event
    The trajectory gets a row at the event time with the values just before it. Resets are
    evaluated on these values, applied in order, and consistency is restored on the reduced
    system by :func:`daekit.simulate.reset.restore` (reset values kept where the constraints
    allow; velocity-level invariants re-imposed by a minimal-change projection,
    mass-weighted when the mass matrix is known; positions untouched by a velocity reset).
    A switch flips its branch (the integrated equations keep every switch frozen in its branch,
    so a segment is smooth). With dummy derivatives the state selection is re-checked at the
    post-event point and remade when its pivot is poor. The next segment (a restart of the
    integrator) starts there; its first row, at the same time, holds the post-event values. A
    function that just fired is re-armed once it has left a band around zero ten times the
    size of its value at the event (no chattering at the restart). A terminal event
    ends the trajectory at the event row.
Zeno behaviour
    ``zeno_count`` (default 10) events within a window shorter than ``zeno_window`` (default
    ``1e-4`` of the span), or ``zeno_count`` gaps between events each shorter than the one
    before (ratio at most 0.99) with the geometric sum of the rest, the time left to the
    accumulation point, below 1/100 of the span, or more than ``max_events`` (default 10,000)
    in all, end the run with a :class:`~daekit.errors.SimulationError` carrying the trajectory
    so far and, for a geometric sequence of event times, the estimated accumulation time.
Cost
    A segment runs to the end of the span or to ``t + H`` (``H`` starts at a quarter of the span,
    is set to 2.7 times the last gap between events after each event and doubled after a
    segment without one), so little is integrated past an event and thrown away. After an
    event the check spacing is also at most a tenth of the time between the last two events,
    so that a sequence of shrinking gaps (a bouncing ball) is followed.

``traj.events`` lists ``(t, name)`` (a switch is named ``switch:<condition>``),
``traj.stats["events"]`` counts them.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping

import casadi as ca
import numpy as np

from ..errors import SimulationError
from ..events import branch_values, event_symbols, freeze_switches, reduced_events
from .driver import Action, Firing, Monitor
from .reset import restore
from .trajectory import Trajectory

__all__ = ["simulate_events", "simulate_rattle_events", "has_events", "EventMonitor",
           "with_branch_states"]

_SUM_STATS = ("steps", "residual_evaluations", "jacobian_evaluations", "error_test_failures",
              "newton_failures", "integrator_wall_time", "intervals")


def has_events(r) -> bool:
    """True if ``r``'s model declares events or ``r``'s equations contain switches.

    >>> import daekit as dk
    >>> has_events(dk.reduce_index(dk.examples.pendulum_planar()))
    False
    """
    from ..events import SCAN_LIMIT, switches

    if getattr(getattr(r, "model", None), "events", None):
        return True
    def scan(r) -> bool:
        found = switches(r, limit=SCAN_LIMIT)
        if found is None:
            r.info["switch_scan"] = f"not scanned (more than {SCAN_LIMIT} instructions)"
        return bool(found)

    return r.derived("simulate.has_switches", scan)


def first_crossing(G: np.ndarray, ref: list, band, dirs, *, rows: int | None = None,
                   first_row_arms: bool = True) -> tuple[int | None, list[int], list]:
    """The first row of ``G`` (rows: times; columns: monitors) at which a monitor changes sign
    in its direction: the one sign-change scan of the driver, the segment path and RATTLE.

    ``ref[i]`` is monitor ``i``'s sign before the first row, or None while it is disarmed (it
    arms once ``|g| > band[i]``: a monitor that has just fired is not re-fired by its own
    zero); ``dirs[i]`` is ``+1`` (rising only), ``-1`` (falling only) or ``0`` (both); a change
    against the direction only updates the sign. With ``first_row_arms`` the first row only
    sets signs (it is the last row already accepted). Returns ``(j, crossed, ref)``: the row,
    the monitors that crossed between rows ``j - 1`` and ``j`` and the signs before row ``j``;
    ``(None, [], ref)`` with the signs after all rows when nothing crossed.

    >>> G = np.array([[1.0, -1.0], [0.5, 1.0], [-0.5, 2.0]])
    >>> first_crossing(G, [None, None], [0.0, 0.0], [0, -1])
    (2, [0], [1.0, 1.0])
    """
    ref = list(ref)
    for j in range(G.shape[0] if rows is None else rows):
        crossed = []
        new = list(ref)
        for i in range(len(ref)):
            g = G[j, i]
            if ref[i] is None:
                if abs(g) > band[i]:
                    new[i] = 1.0 if g > 0 else -1.0
                continue
            s = 1.0 if g > 0 else (-1.0 if g < 0 else 0.0)
            if s != ref[i] and (j > 0 or not first_row_arms):
                rising = ref[i] < 0
                if dirs[i] == 0 or (dirs[i] > 0) == rising:
                    crossed.append(i)
            if s != 0:
                new[i] = s
        if crossed:
            return j, crossed, ref
        ref = new
    return None, [], ref


class _Monitors:
    """Event functions (by original names) and switching functions (by r's symbols)."""

    def __init__(self, r, rf, found, pv_len: int) -> None:
        self.events = reduced_events(r) if getattr(r, "model", None) is not None else []
        model = r.model
        self.names = [e.name for e in self.events] + [f"switch:{s.text}" for s in found]
        self.dirs = [e.direction for e in self.events] + [0] * len(found)
        self.n_ev = len(self.events)
        self.found = found
        decl = model.events if model is not None else []
        syms, used = [], []
        for ev in decl:
            for s, nm in zip(ca.symvar(ev.expr), event_symbols(model, ev.expr), strict=True):
                if nm not in used:
                    used.append(nm)
                    syms.append(s)
            for val in ev.reset.values():
                for s, nm in zip(ca.symvar(val), event_symbols(model, val), strict=True):
                    if nm not in used:
                        used.append(nm)
                        syms.append(s)
        self.used = used
        vec = ca.vertcat(*syms) if syms else ca.SX(0, 1)
        self.decl = decl
        self.fev = ca.Function("events", [vec], [ca.vertcat(*[e.expr for e in decl])
                                                 if decl else ca.SX(0, 1)])
        self.freset = [ca.Function(f"reset_{e.name}", [vec],
                                   [ca.vertcat(*e.reset.values()) if e.reset else ca.SX(0, 1)])
                       for e in decl]
        self.rf = rf
        self.fsw = (ca.Function("switches", [rf.t, rf.x, rf.z, rf.u, rf.p],
                                [ca.vertcat(*[s.expr for s in found])]) if found else None)

    def _vec(self, values: Mapping, t) -> np.ndarray:
        n = np.size(t)
        cols = []
        for nm in self.used:
            if nm == "t":
                cols.append(np.broadcast_to(np.asarray(t, float), (n,)))
            else:
                cols.append(np.asarray(values[nm], dtype=float).reshape(-1)[:n])
        return np.column_stack(cols) if cols else np.zeros((n, 0))

    def values(self, traj: Trajectory, pv) -> np.ndarray:
        """(rows, monitors) values on a trajectory."""
        n = traj.t.size
        out = np.zeros((n, len(self.names)))
        if self.n_ev:
            V = self._vec(traj.values, traj.t)
            F = self.fev.map(n)
            out[:, : self.n_ev] = np.asarray(F(V.T), dtype=float).reshape(self.n_ev, n).T
        if self.fsw is not None:
            rf = self.rf
            X = np.column_stack([traj.values[nm] for nm in rf.x_names]) if rf.nx else \
                np.zeros((n, 0))
            Z = np.column_stack([traj.values.get(nm, np.zeros(n)) for nm in rf.z_names]) \
                if rf.nz else np.zeros((n, 0))
            U = np.column_stack([traj.values.get(nm, np.zeros(n)) for nm in rf.u_names]) \
                if rf.nu else np.zeros((n, 0))
            F = self.fsw.map(n)
            P = np.repeat(np.asarray(pv, float).reshape(-1, 1), n, axis=1)
            res = F(traj.t.reshape(1, -1), X.T, Z.T, U.T, P)
            out[:, self.n_ev:] = np.asarray(res, dtype=float).reshape(len(self.found), n).T
        return out

    def event_values(self, row: Mapping, t: float) -> np.ndarray:
        """The declared events' functions at one point given by name."""
        if not self.n_ev:
            return np.zeros(0)
        v = self._vec({n: np.atleast_1d(row[n]) for n in self.used if n != "t"}, t)
        return np.asarray(self.fev(v.T), dtype=float).ravel()

    def reset_targets(self, k: int, row: Mapping, t: float) -> dict[str, float]:
        ev = self.decl[k]
        if not ev.reset:
            return {}
        v = self._vec({n: np.atleast_1d(row[n]) for n in self.used if n != "t"}, t)
        vals = np.asarray(self.freset[k](v.T), dtype=float).ravel()
        return dict(zip(ev.reset, vals, strict=True))


def with_branch_states(rf, n_branch: int):
    """``rf`` (from :func:`daekit.events.freeze_switches`) with its branch parameters moved
    into the state as constants (``b' = 0``): a monitor can then flip a branch by resetting a
    state, the way the driver restarts. Returns ``rf`` itself without branches.

    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> from daekit.events import freeze_switches
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x")
    >>> r = ReducedDAE(t, x, ca.SX(0, 1), ca.SX(0, 1), ca.SX(0, 1), -ca.fabs(x - 1),
    ...     ca.SX(0, 1), ca.SX(0, 1), [], ["x"], [], [], [], np.zeros(0), {"x": x})
    >>> rb = with_branch_states(freeze_switches(r)[0], 1)
    >>> rb.x_names, rb.p_names
    (['x', '__switch0'], [])
    """
    import dataclasses

    if n_branch == 0:
        return rf
    npo = rf.n_p - n_branch
    b = rf.p[npo:]
    return dataclasses.replace(
        rf, x=ca.vertcat(rf.x, b), ode=ca.vertcat(rf.ode, ca.SX.zeros(n_branch)),
        p=rf.p[:npo], p_names=list(rf.p_names[:npo]),
        p_values=np.asarray(rf.p_values, float)[:npo],
        x_names=list(rf.x_names) + list(rf.p_names[npo:]),
        info=dict(rf.info),
    )


def _flip(kind: str, b: float) -> float:
    return -b if kind in ("fabs", "sign") else 1.0 - b


class EventMonitor(Monitor):
    """The model's events and switches as a monitor of the event-driven driver
    (:class:`daekit.simulate.driver.Monitor`).

    Built by :func:`simulate_events` for a system ``rb`` (:func:`with_branch_states` of the
    frozen system); the same rules as the module docstring: sign changes at the segment's rows
    (``check_dt`` caps their spacing), location by the driver's Illinois re-integration,
    re-arming bands, simultaneous firings in declaration order, resets through
    :func:`daekit.simulate.reset.restore`, Zeno rules. ``log`` holds ``(t, name)`` of every
    event; ``zeno`` the message when the run was stopped for Zeno behaviour.
    """

    name = "events"

    def __init__(self, r_work, rb, found, monitors: _Monitors, n_x: int, pv, dt_check: float,
                 span: float, zeno_count: int, zeno_window: float, max_events: int) -> None:
        self.r_work, self.rb, self.found, self.mon = r_work, rb, found, monitors
        self.n_x = n_x
        self.pv = np.asarray(pv, float)
        self.check_dt = dt_check
        self.dt_check = dt_check
        self.span = span
        self.zeno_count, self.zeno_window, self.max_events = zeno_count, zeno_window, max_events
        exprs = [e.expr for e in monitors.events] + [sw.expr for sw in found]
        self.n = len(exprs)
        self.g = ca.Function("monitors", [rb.t, rb.x, rb.z, rb.u, rb.p],
                             [ca.vertcat(*exprs) if exprs else ca.SX(0, 1)])
        self.resets = [ca.Function(f"reset_{e.name}", [rb.t, rb.x, rb.z, rb.u, rb.p],
                                   [ca.vertcat(*e.reset.values()) if e.reset else ca.SX(0, 1)])
                       for e in monitors.events]
        self._maps: dict[int, ca.Function] = {}
        self.log: list[tuple[float, str]] = []
        self.zeno: str | None = None
        self.last_gap = 0.0
        self.stats: dict = {}

    def _G(self, t, X, Z, U) -> np.ndarray:
        n = np.size(t)
        if n == 1:
            out = self.g(float(np.ravel(t)[0]), np.ravel(X), np.ravel(Z), np.ravel(U), self.pv)
            return np.asarray(out, dtype=float).reshape(1, self.n)
        F = self._maps.get(n)
        if F is None:
            if len(self._maps) > 8:
                self._maps.clear()
            F = self._maps[n] = self.g.map(n)
        P = np.repeat(self.pv.reshape(-1, 1), n, axis=1)
        out = F(np.asarray(t, float).reshape(1, -1), np.asarray(X).T, np.asarray(Z).T,
                np.asarray(U).T, P)
        return np.asarray(out, dtype=float).reshape(self.n, n).T

    def init(self, driver, t0, x0, z0):
        return {"ref": [None] * self.n, "band": [0.0] * self.n, "primed": False}

    def _scan(self, G, state, upto=None):
        """(row j, crossed list, refs after rows < j) of the first crossing, or (None, [], refs)."""
        return first_crossing(G, state["ref"], state["band"], self.mon.dirs,
                              rows=None if upto is None else upto + 1)

    def check(self, seg, state):
        if self.n == 0:
            return None
        G = self._G(seg.t, seg.X, seg.Z, seg.U)
        j, crossed, _ = self._scan(G, state)
        if j is None:
            return None
        ga, gb = G[j - 1], G[j]
        ta, tb = float(seg.t[j - 1]), float(seg.t[j])
        lin = {i: ta + (tb - ta) * ga[i] / (ga[i] - gb[i]) if ga[i] != gb[i] else tb
               for i in crossed}
        lead = min(crossed, key=lambda i: (lin[i], i))

        def g_lead(t, x, z, u):
            return float(self._G(np.array([t]), x.reshape(1, -1), z.reshape(1, -1),
                                 np.asarray(u, float).reshape(1, -1))[0, lead])

        tol = self.rb_tol * max(1.0, abs(tb))
        te, xe, ze = seg.driver.locate(seg, j - 1, g_lead, tol=tol)
        return Firing(te, xe, ze, info=(j - 1, crossed, lead, ga))

    rb_tol = 1e-12

    def accept(self, seg, upto, state):
        if self.n == 0:
            return state
        G = self._G(seg.t[: upto + 1], seg.X[: upto + 1], seg.Z[: upto + 1], seg.U[: upto + 1])
        _, _, ref = self._scan(G, state)
        state = dict(state)
        state["ref"] = ref
        return state

    def act(self, firing, driver, state):
        i0, crossed, lead, ga = firing.info
        te = float(firing.t)
        sig = driver.system.sig
        ue = sig.value(te)
        ge = self._G(np.array([te]), firing.x.reshape(1, -1), firing.z.reshape(1, -1),
                     np.asarray(ue, float).reshape(1, -1))[0]
        fired = [lead]
        for i in crossed:
            if i != lead and (np.sign(ge[i]) != np.sign(ga[i]) or
                              abs(ge[i]) <= 1e3 * abs(ge[lead]) + 1e-300):
                fired.append(i)
        fired.sort()
        state = dict(state)
        ref, band = list(state["ref"]), list(state["band"])
        # refs of the others: their values at the event
        for i in range(self.n):
            if ge[i] != 0 and ref[i] is not None:
                ref[i] = 1.0 if ge[i] > 0 else -1.0
        x = np.asarray(firing.x, float).copy()
        z = np.asarray(firing.z, float).copy()
        names = self.mon.names
        terminal = False
        for i in fired:
            self.log.append((te, names[i]))
            ref[i] = None
            band[i] = 10.0 * abs(float(ge[i])) + 1e-300
            if i < self.mon.n_ev:
                ev = self.mon.events[i]
                terminal = terminal or ev.terminal
                if ev.reset and not ev.terminal:
                    vals = np.asarray(self.resets[i](te, x, z, ue, self.pv), float).ravel()
                    targets = dict(zip(ev.reset, vals, strict=True))
                    xr, zr, info = _restore(self.r_work, te, x[: self.n_x], z, ue, self.pv,
                                            targets)
                    x[: self.n_x], z = xr, zr
                    self.stats["max_reset_deviation"] = max(
                        self.stats.get("max_reset_deviation", 0.0), info["kept"])
                    self.stats["reset_metric"] = info["metric"]
            else:
                k = i - self.mon.n_ev
                x[self.n_x + k] = _flip(self.found[k].kind, x[self.n_x + k])
        # a function that the jump itself carried across zero (e.g. an energy threshold
        # passed at an impact) fires at the event too, in declaration order
        if any(i < self.mon.n_ev and self.mon.events[i].reset for i in fired) and not terminal:
            gp = self._G(np.array([te]), x.reshape(1, -1), z.reshape(1, -1),
                         np.asarray(ue, float).reshape(1, -1))[0]
            dirs = self.mon.dirs
            for i in range(self.mon.n_ev):
                if i in fired or ge[i] == 0 or np.sign(gp[i]) == np.sign(ge[i]):
                    continue
                rising = ge[i] < 0
                if dirs[i] == 0 or (dirs[i] > 0) == rising:
                    self.log.append((te, names[i]))
                    fired.append(i)
                    ref[i], band[i] = None, 10.0 * abs(float(gp[i])) + 1e-300
                    terminal = terminal or self.mon.events[i].terminal
                else:
                    ref[i] = 1.0 if gp[i] > 0 else -1.0
        state["ref"], state["band"] = ref, band
        times = [e[0] for e in self.log]
        prev = times[: -len(fired)]
        if prev and te > prev[-1]:
            self.last_gap = te - prev[-1]
            self.check_dt = min(self.dt_check, self.last_gap / 10.0)
        label = "+".join(names[i] for i in fired)
        msg = _zeno_message(self.log, self.zeno_count, self.zeno_window, self.max_events,
                            self.span)
        if msg is not None:
            self.zeno = msg
            return Action(record=True, terminal=True, label=label), state
        if terminal:
            return Action(x=x, z=z, record=True, terminal=True, label=label), state
        return Action(x=x, z=z, record=True, label=label), state


def _zeno_message(events, zeno_count, zeno_window, max_events, span) -> str | None:
    """The Zeno rules of the module docstring on the event log; a message, or None."""
    geometric = False
    if len(events) > zeno_count:
        gz = np.diff([e_[0] for e_ in events[-zeno_count - 1:]])
        if np.all(gz > 0) and np.all(gz[1:] <= 0.99 * gz[:-1]):
            rho_ = gz[-1] / gz[-2]
            geometric = gz[-1] * rho_ / (1 - rho_) < 1e-2 * span
    if not (len(events) > max_events or geometric or (
            len(events) >= zeno_count and events[-1][0] - events[-zeno_count][0] < zeno_window)):
        return None
    times = np.array([e[0] for e in events[-zeno_count:]])
    gaps = np.diff(times)
    est = ""
    if gaps.size >= 3 and gaps[-2] > 0:
        rho = gaps[-1] / gaps[-2]
        if 0 < rho < 1:
            est = (f"; the event times accumulate geometrically (ratio {rho:.3g}) at "
                   f"t = {times[-1] + gaps[-1] * rho / (1 - rho):.10g}")
    return (
        f"simulate: Zeno behaviour: {len(events)} events, the last {len(times)} of them "
        f"({', '.join(sorted({e[1] for e in events[-zeno_count:]}))}) within "
        f"{times[-1] - times[0]:.3g} (zeno_window = {zeno_window:.3g}){est}. Stop the "
        "simulation there with a terminal event (e.g. when the speed is small), or "
        "change the model. The trajectory up to the last event is attached as .trajectory."
    )


def _simulate_driver(r_work, rf, found, mon, tg, row0, sig, pv_user, rtol, atol, options,
                     dt_check, zeno_count, zeno_window, max_events, progress, wall0,
                     stabilization, seg_stab, inputs, params, drift_tol=None,
                     project_output=None, run=None) -> Trajectory:
    """The remedies on the event-driven driver (none, Baumgarte, projection): ``simulate`` with
    the :class:`EventMonitor` among its monitors (``run`` is that ``simulate``)."""
    simulate = run

    t0 = float(tg[0])
    span = float(tg[-1] - tg[0])
    rb = with_branch_states(rf, len(found))
    x0 = np.array([row0.get(n, 0.0) for n in r_work.x_names])
    z0 = np.array([row0.get(n, 0.0) for n in r_work.z_names])
    u0 = sig.value(t0)
    b0 = branch_values(found, r_work, t0, x0, z0, u0, pv_user)
    em = EventMonitor(r_work, rb, found, mon, r_work.nx, pv_user, dt_check, span, zeno_count,
                      zeno_window, max_events)
    em.rb_tol = rtol
    row = dict(row0)
    row.update({f"__switch{k}": float(b) for k, b in enumerate(b0)})
    init = _init_of(rb, t0, row, pv_user, u0)
    extra = ({"drift_tol": drift_tol, "project_output": project_output}
             if seg_stab == "projection" else {})
    traj = simulate(rb, tg, init, inputs=inputs, params=params, stabilization=seg_stab,
                    rtol=rtol, atol=atol, progress=progress, monitors=[em], events=False,
                    **extra, **options)
    traj.stats.update({"events": len(em.log), **em.stats,
                       "wall_time": time.perf_counter() - wall0,
                       "stabilization": stabilization})
    traj.events = list(em.log)
    last = em.log[-1] if em.log else None
    at_last = [n_ for te_, n_ in em.log if last is not None and te_ == last[0]]
    terminal = [e.name for e in mon.events if e.terminal and e.name in at_last]
    if last is not None and traj.t.size >= 2 and traj.t[-1] == traj.t[-2] == last[0] and (
            em.zeno or terminal):
        if all(v[-1] == v[-2] for v in traj.values.values()):
            traj = traj.slice(traj.t.size - 1)  # no jump: the event row ends it
            traj.events = list(em.log)
    if terminal and not em.zeno:
        traj.stats["terminated_by"] = terminal[0]
    if em.zeno:
        raise SimulationError(em.zeno, t=float(em.log[-1][0]), trajectory=traj)
    return traj


_VALUES: dict = {}


def _values_at(r, t, x, z, u, p) -> dict[str, float]:
    """Every name of ``r.variables`` at one point (one CasADi Function per system)."""
    key = id(r)
    hit = _VALUES.get(key)
    if hit is None or hit[0] is not r:
        names = list(r.variables)
        f = ca.Function("values_at", [r.t, r.x, r.z, r.u, r.p],
                        [ca.vertcat(*[ca.SX(r.variables[n]) for n in names])])
        if len(_VALUES) > 16:
            _VALUES.clear()
        hit = _VALUES[key] = (r, names, f)
    _, names, f = hit
    vals = np.asarray(f(t, x, z, u, p), dtype=float).ravel()
    return dict(zip(names, vals, strict=True))


def _row(traj: Trajectory, j: int) -> dict[str, float]:
    return {n: float(a[j]) for n, a in traj.values.items()}


def _init_of(r, t, row: Mapping, pv, u):
    from ..initialize import InitialValues

    x0 = np.array([row.get(n, 0.0) for n in r.x_names], dtype=float)
    z0 = np.array([row.get(n, 0.0) for n in r.z_names], dtype=float)
    return InitialValues(float(t), x0, z0, np.asarray(u, float), np.asarray(pv, float),
                         dict(row), x_names=list(r.x_names), z_names=list(r.z_names))


def simulate_events(r, t, init, inputs=None, params=None, stabilization=None, rtol=1e-8,
                    atol=1e-8, poles=(-1.0, -1.0), event_spacing: float | None = None,
                    zeno_count: int = 10, zeno_window: float | None = None,
                    max_events: int = 10000, progress: bool = False, use_driver: bool = True,
                    drift_tol: float | None = None, project_output: bool | None = None,
                    run: Callable[..., Trajectory] | None = None, **options) -> Trajectory:
    """Simulate ``r`` with its model's events and its switches (see the module docstring).

    ``run`` is the simulation of one segment without events (:func:`daekit.simulate`, which
    passes itself: this module sits below the dispatcher and never imports it).

    Called by :func:`daekit.simulate` (same arguments); the extra keywords ``event_spacing``,
    ``zeno_count``, ``zeno_window`` and ``max_events`` may be passed to it.

    >>> import numpy as np, daekit as dk
    >>> m = dk.Model("fall"); h = m.state("h")
    >>> _ = m.equation(m.der(h, 2) + 9.81, name="gravity")
    >>> _ = m.event(h, name="floor", direction=-1, reset={"der(h)": -m.der(h)})
    >>> r = dk.reduce_index(m)
    >>> init = dk.initialize(r, fixed={"h": 1.0, "der(h)": 0.0})
    >>> traj = dk.simulate(r, np.linspace(0, 1, 11), init, rtol=1e-10, atol=1e-10)
    >>> [(round(te, 8), n) for te, n in traj.events]     # sqrt(2 / 9.81) = 0.45152364
    [(0.45152364, 'floor')]
    >>> bool(abs(traj["h"][-1] - (1 - 9.81 * (1 - 2 * 0.45152364) ** 2 / 2)) < 1e-7)
    True
    """
    from ..inputs import InputSignal, resolve_params
    from ..reduction import baumgarte, reselect, selection_condition

    if run is None:
        raise TypeError("simulate_events needs run=, the simulation of one segment "
                        "(daekit.simulate passes itself)")
    simulate = run

    wall0 = time.perf_counter()
    tg = np.asarray(t, dtype=float).ravel()
    t0, tf = float(tg[0]), float(tg[-1])
    span = tf - t0
    if stabilization == "baumgarte":
        r_work, seg_stab = baumgarte(r, poles=poles), None
    elif stabilization in ("projection", "dummy_derivatives"):
        r_work, seg_stab = r, stabilization
    else:
        r_work, seg_stab = r, None
    dummy = stabilization == "dummy_derivatives"
    index2 = r_work.index >= 2
    rf, found = (r_work, []) if dummy else freeze_switches(r_work)
    mon = _Monitors(r_work, rf, found, r_work.n_p)
    n_mon = len(mon.names)
    pv_user = resolve_params(r_work, params)
    sig = InputSignal(r_work, inputs)

    # the first point: consistent initial values of r (through simulate's own path)
    with warnings.catch_warnings():  # the run itself says what it says
        warnings.simplefilter("ignore")
        first = simulate(r_work, tg[:2], init, inputs=inputs, params=params,
                         stabilization=seg_stab, rtol=rtol, atol=atol, events=False, **options)
    row0 = _row(first, 0)
    x0 = np.array([row0.get(n, 0.0) for n in r_work.x_names])
    z0 = np.array([row0.get(n, 0.0) for n in r_work.z_names])
    u0 = sig.value(t0)
    branches = branch_values(found, r_work, t0, x0, z0, u0, pv_user)

    def pv_of(b) -> np.ndarray:
        return np.concatenate([pv_user, b]) if found else pv_user

    def params_of(b) -> dict:
        out = dict(params or {})
        for k, v in enumerate(b):
            out[f"__switch{k}"] = float(v)
        return out

    spacing = float(np.min(np.diff(tg))) if tg.size > 1 else span
    if event_spacing:
        dt_check = float(event_spacing)
    elif seg_stab == "dummy_derivatives":  # segments restart at every grid point
        dt_check = spacing
    else:
        dt_check = min(spacing, span / 200.0)
    if zeno_window is None:
        zeno_window = 1e-4 * max(span, 1e-300)

    # the continuous-run remedies on the driver; an index-2 (GGL) system on segments of
    # simulate's own GGL path (its restart needs a moderate first step from a consistent point)
    if seg_stab != "dummy_derivatives" and use_driver and not index2:
        return _simulate_driver(r_work, rf, found, mon, tg, row0, sig, pv_user, rtol, atol,
                                options, dt_check, zeno_count, zeno_window, max_events,
                                progress, wall0, stabilization, seg_stab, inputs, params,
                                drift_tol, project_output, run=simulate)
    r_cur = rf
    if dummy:
        r_cur = r_work
    init_cur = _init_of(r_cur, t0, row0, pv_of(branches), u0)
    t_cur = t0
    H = span / 4.0
    ref = [None] * n_mon  # sign each monitor had last (None: disarmed)
    band = [0.0] * n_mon
    kept_t, kept_rows, kept_inv = [], [], []
    inv_names: list[str] = list(first.invariant_names)
    events: list[tuple[float, str]] = []
    stats: dict = {"segments": 0, "event_locations": 0}
    is_user_time = set(tg.tolist())
    first_row_is_post = False  # True: the next segment's row 0 is a post-event row
    last_gap = 0.0

    def keep(traj: Trajectory, j: int) -> None:
        kept_t.append(float(traj.t[j]))
        kept_rows.append(_row(traj, j))
        kept_inv.append(traj.invariants[j].copy() if traj.invariants.size else np.zeros(0))

    def add_stats(traj: Trajectory) -> None:
        for k in _SUM_STATS:
            v = traj.stats.get(k)
            if isinstance(v, (int, float)):
                stats[k] = stats.get(k, 0) + v

    def partial_traj() -> Trajectory:
        return _assemble(kept_t, kept_rows, kept_inv, inv_names, stats, events)

    def run(rr, grid, ini, b, stab):
        return simulate(rr, grid, ini, inputs=inputs, params=params_of(b), stabilization=stab,
                        rtol=rtol, atol=atol, events=False, **options)

    while t_cur < tf - 1e-14 * max(1.0, abs(tf)):
        t_end = min(tf, t_cur + H)
        if tf - t_end < 1e-9 * span:
            t_end = tf
        users = tg[(tg > t_cur) & (tg < t_end)]
        pts = [t_cur, t_end]
        # after events, checks at least 10 per gap between the last two (bouncing: gaps shrink)
        dt_seg = min(dt_check, last_gap / 10.0) if last_gap else dt_check
        ncheck = max(1, int(math.ceil((t_end - t_cur) / dt_seg)))
        if seg_stab is not None and not event_spacing and dt_seg >= spacing:
            # segments that restart at every grid point: the output points only
            pts = np.union1d(pts, users)
        else:
            pts = np.union1d(np.union1d(pts, users), np.linspace(t_cur, t_end, ncheck + 1))
        # a check point within rounding of an output point gives way to it
        eps = 1e-12 * max(1.0, abs(t_end))
        if users.size:
            k_ = np.clip(np.searchsorted(users, pts), 1, users.size) - 1
            d_ = np.minimum(np.abs(pts - users[k_]),
                            np.abs(pts - users[np.minimum(k_ + 1, users.size - 1)]))
            pts = pts[(d_ > eps) | np.isin(pts, users) | (pts == t_cur) | (pts == t_end)]
        pts = pts[np.concatenate([[True], np.diff(pts) > eps])]
        # no point just after the start (a restart over a tiny first interval is fragile)
        # (an index-2 GGL run starts with a step of 1e-4 of the smallest grid interval)
        near = (1e-1 if index2 else 1e-3) * dt_seg
        close = (pts > t_cur) & (pts < t_cur + near) & (pts < t_end)
        if index2:  # no check point just before an output point either
            is_user = np.isin(pts, tg)
            dprev = np.diff(pts, prepend=-np.inf)
            dnext = np.diff(pts, append=np.inf)
            close |= ~is_user & ((dprev < near) | (dnext < near)) & (pts > t_cur) & (pts < t_end)
        pts = pts[~close]
        if pts.size < 2:
            break
        stats["segments"] += 1
        failure = None
        try:
            seg = run(r_cur, pts, init_cur, branches, seg_stab)
        except SimulationError as exc:
            if exc.trajectory is None or len(exc.trajectory) < 1:
                exc.trajectory = partial_traj()
                raise
            seg, failure = exc.trajectory, exc
        add_stats(seg)
        G = mon.values(seg, pv_of(branches))
        j_hit, crossed_hit, ref = first_crossing(G, ref, band, mon.dirs)
        hit = None if j_hit is None else (j_hit, crossed_hit)  # rows j-1 -> j
        if hit is None:
            last = seg.t.size - 1
            for j in range(seg.t.size):
                if j == 0 and not first_row_is_post and kept_t:
                    continue
                if seg.t[j] in is_user_time or (j == 0 and first_row_is_post) or not kept_t:
                    keep(seg, j)
            first_row_is_post = False
            if failure is not None:
                failure.trajectory = partial_traj()
                raise failure
            t_cur = float(seg.t[last])
            init_cur = _init_of(r_cur, t_cur, _row(seg, last), pv_of(branches),
                                sig.value(t_cur))
            H *= 2.0
            continue
        j, crossed = hit
        for jj in range(j):
            if jj == 0 and not first_row_is_post and kept_t:
                continue
            if seg.t[jj] in is_user_time or (jj == 0 and first_row_is_post) or not kept_t:
                keep(seg, jj)
        first_row_is_post = False
        # --- location: Illinois on the earliest crossing, re-integrating from row j-1
        # re-integrate from one check point further back (never over a tiny interval)
        # (a row right at the crossing may be degenerate: with dummy derivatives the point
        # where a selection is singular; one check point further back is a clean start)
        ja = j - 2 if j >= 2 else j - 1
        # only from a row of this segment's own grid: a remedy may add rows of its own (a
        # re-selection point), whose values are not a clean restart point
        own = set(np.asarray(pts, float).tolist())
        while ja > 0 and float(seg.t[ja]) not in own:
            ja -= 1
        ta = float(seg.t[ja])
        row_a = _row(seg, ja)
        r_loc = r_cur
        if dummy:
            xa = np.array([row_a.get(n, 0.0) for n in r_loc.x_names])
            za = np.array([row_a.get(n, 0.0) for n in r_loc.z_names])
            try:
                cond = float(selection_condition(r_loc, xa, za, sig.value(ta), pv_user, ta))
            except Exception:  # noqa: BLE001 - treat as poor
                cond = math.inf
            if not (cond < 2.0):
                r_loc = reselect(r_loc, row_a)
        init_a = _init_of(r_loc, ta, row_a, pv_of(branches), sig.value(ta))
        ga, gb = G[j - 1], G[j]
        tb = float(seg.t[j])
        t_left = float(seg.t[j - 1])
        # the earliest crossing by linear interpolation picks the function to locate on
        lin = {i: t_left + (tb - t_left) * ga[i] / (ga[i] - gb[i]) if ga[i] != gb[i] else tb
               for i in crossed}
        lead = min(crossed, key=lambda i: (lin[i], i))

        def value_at(tt: float, branches=branches, r_loc=r_loc, init_a=init_a, ta=ta, tb=tb,
                     lead=lead):
            stats["event_locations"] += 1
            try:
                # with dummy derivatives through the remedy itself: a selection made at ta
                # may degrade before tt, and a degrading selection loses accuracy silently
                tr = run(r_loc, np.array([ta, tt]), init_a, branches,
                         "dummy_derivatives" if dummy else None)
            except SimulationError as exc:
                raise SimulationError(
                    f"simulate: locating the event {mon.names[lead]!r} in [{ta:.10g}, {tb:.10g}] "
                    f"failed: {exc}", t=float(tt), trajectory=partial_traj()) from None
            return mon.values(tr, pv_of(branches))[-1], tr

        tl, tr_ = t_left, tb
        gl, gr = float(ga[lead]), float(gb[lead])
        trow, tvals = None, None
        side = 0
        tol_t = rtol * max(1.0, abs(tb))
        for _ in range(200):
            if tr_ - tl <= tol_t:
                break
            tm = tl + (tr_ - tl) * gl / (gl - gr) if gl != gr else 0.5 * (tl + tr_)
            tm = min(max(tm, tl + 0.05 * tol_t), tr_ - 0.05 * tol_t)
            vals, tr_traj = value_at(tm)
            gm = float(vals[lead])
            if (gm > 0) == (gl > 0) and gm != 0:
                tl, gl = tm, gm
                if side == -1:
                    gr *= 0.5
                side = -1
            else:
                tr_, gr = tm, gm
                trow, tvals = tr_traj, vals
                if side == 1:
                    gl *= 0.5
                side = 1
        if trow is None or trow.t[-1] != tr_:
            tvals, trow = value_at(tr_)
        te = float(tr_)
        pre = _row(trow, trow.t.size - 1)
        # simultaneous: every monitor whose sign changed between row j-1 and te
        fired = []
        for i in range(n_mon):
            if i in crossed or (ref[i] is not None and np.sign(tvals[i]) != np.sign(ga[i])
                                and np.sign(tvals[i]) != 0):
                rising = ga[i] < 0
                if i == lead or mon.dirs[i] == 0 or (mon.dirs[i] > 0) == rising:
                    if i == lead or np.sign(tvals[i]) != np.sign(ga[i]):
                        fired.append(i)
        fired.sort()
        kept_t.append(te)
        kept_rows.append(pre)
        kept_inv.append(trow.invariants[-1].copy() if trow.invariants.size else np.zeros(0))
        for i in fired:
            events.append((te, mon.names[i]))
            ref[i] = None
            band[i] = 10.0 * abs(float(tvals[i]))
        for i in range(n_mon):
            if i not in fired and ref[i] is not None and tvals[i] != 0:
                ref[i] = 1.0 if tvals[i] > 0 else -1.0
        stats["events"] = len(events)
        if any(i < mon.n_ev and mon.decl[i].terminal for i in fired):
            stats["terminated_by"] = next(mon.names[i] for i in fired
                                          if i < mon.n_ev and mon.decl[i].terminal)
            break
        # Zeno
        msg = _zeno_message(events, zeno_count, zeno_window, max_events, span)
        if msg is not None:
            raise SimulationError(msg, t=te, trajectory=partial_traj())
        # --- resets, consistency, switch branches
        ue = sig.value(te)
        xe = np.array([pre.get(n, 0.0) for n in r_loc.x_names])
        ze = np.array([pre.get(n, 0.0) for n in r_loc.z_names])
        post = dict(pre)
        for i in fired:
            if i < mon.n_ev:
                targets = mon.reset_targets(i, post, te)
                if targets:
                    xe, ze, info = _restore(r_loc, te, xe, ze, ue, pv_of(branches), targets)
                    stats["max_reset_deviation"] = max(stats.get("max_reset_deviation", 0.0),
                                                       info["kept"])
                    stats["reset_metric"] = info["metric"]
                    post.update(zip(r_loc.x_names, xe, strict=True))
                    post.update(zip(r_loc.z_names, ze, strict=True))
        # a function that the jump itself carried across zero fires at the event too
        jump_terminal = False
        if any(i < mon.n_ev and mon.decl[i].reset for i in fired):
            vals_post = _values_at(r_loc, te, xe, ze, ue, pv_of(branches))
            gp = mon.event_values(vals_post, te)
            for i in range(mon.n_ev):
                if i in fired or tvals[i] == 0 or np.sign(gp[i]) == np.sign(tvals[i]):
                    continue
                rising = tvals[i] < 0
                if mon.dirs[i] == 0 or (mon.dirs[i] > 0) == rising:
                    events.append((te, mon.names[i]))
                    ref[i], band[i] = None, 10.0 * abs(float(gp[i])) + 1e-300
                    jump_terminal = jump_terminal or mon.decl[i].terminal
                    if jump_terminal and "terminated_by" not in stats:
                        stats["terminated_by"] = mon.names[i]
                else:
                    ref[i] = 1.0 if gp[i] > 0 else -1.0
            stats["events"] = len(events)
        if jump_terminal:
            break
        if any(i >= mon.n_ev for i in fired):
            branches = branch_values(found, r_work, te, xe, ze, ue, pv_user)
        r_cur = r_loc
        if dummy:
            try:
                cond = float(selection_condition(r_cur, xe, ze, ue, pv_user, te))
            except Exception:  # noqa: BLE001
                cond = math.inf
            if not (cond < 3.0):
                r_new = reselect(r_cur, (xe, ze))
                from ..reduction import map_values

                xe, ze = map_values(r_cur, r_new, xe, ze)
                r_cur = r_new
        init_cur = _init_of(r_cur, te, dict(zip(r_cur.x_names, xe, strict=True))
                            | dict(zip(r_cur.z_names, ze, strict=True)), pv_of(branches), ue)
        gap = te - events[-len(fired) - 1][0] if len(events) > len(fired) else te - t0
        last_gap = gap if gap > 0 else last_gap
        # 2.7, not an integer: a periodic motion (e = 1) would otherwise end every segment on
        # the same phase, e.g. a turning point where a state selection is singular
        H = max(2.7 * gap, 1e-6 * span)
        t_cur = te
        first_row_is_post = True
        if te >= tf - 1e-14 * max(1.0, abs(tf)):
            break
    stats["events"] = len(events)
    stats["wall_time"] = time.perf_counter() - wall0
    stats["stabilization"] = stabilization
    return _assemble(kept_t, kept_rows, kept_inv, inv_names, stats, events)


def _restore(r, t, x, z, u, p, targets):
    """:func:`restore` on ``r``; an index-2 (GGL) system through the index-1 system it came from
    (its algebraic unknowns are not determined by ``alg`` at fixed states), the GGL multipliers
    then zero."""
    r1 = r.origin if r.index >= 2 else None
    if r1 is None or list(r1.x_names) != list(r.x_names):
        return restore(r, t, x, z, u, p, targets)
    zmap = dict(zip(r.z_names, z, strict=True))
    z1 = np.array([zmap.get(n, 0.0) for n in r1.z_names])
    x, z1, info = restore(r1, t, x, z1, u, p, targets)
    z1map = dict(zip(r1.z_names, z1, strict=True))
    return x, np.array([z1map.get(n, 0.0) for n in r.z_names]), info


def _assemble(ts, rows, invs, inv_names, stats, events) -> Trajectory:
    names = list(rows[0]) if rows else []
    vals = {n: np.array([rw.get(n, np.nan) for rw in rows], dtype=float) for n in names}
    ninv = len(inv_names)
    inv = np.array([iv if iv.size == ninv else np.full(ninv, np.nan) for iv in invs]) \
        if invs else np.zeros((0, ninv))
    traj = Trajectory(np.array(ts, dtype=float), vals, inv.reshape(len(ts), ninv),
                      inv_names, dict(stats), events=list(events))
    return traj


def simulate_rattle_events(r, t, init, params=None, inputs=None, dt: float | None = None,
                           newton_iter: int = 8, zeno_count: int = 10,
                           zeno_window: float | None = None, max_events: int = 10000,
                           progress: bool = False, **unknown) -> Trajectory:
    """RATTLE (:mod:`daekit.simulate.rattle`) with the model's events.

    RATTLE takes fixed steps (``dt``, as :func:`~daekit.simulate.rattle.simulate_rattle`); the
    event functions are evaluated after every step. In the step where one changes sign the
    event is located on that step by Illinois on the fraction ``theta`` of the step, each value
    from a partial RATTLE step ``theta h`` from the step's start (a second-order interpolant
    of the step that keeps the constraints exactly), to ``1e-12`` of the step. Resets go
    through :func:`daekit.simulate.reset.restore` on ``r`` (mass-weighted for a Lagrangian
    system), the momenta follow from the new velocities, and the rest of the step
    (``(1 - theta) h``) is taken from the post-event point, so the later steps stay on the
    grid. At most one event per step: a second crossing inside the rest of the same step is
    not seen. ``r`` is a Lagrangian index-1 system (``LagrangianSystem.index1()``) whose
    model declares the events; they may use coordinates, velocities, parameters and ``t``.

    >>> import casadi as ca, numpy as np, daekit as dk
    >>> q = ca.SX.sym("q", 2); v = ca.SX.sym("v", 2)
    >>> ls = dk.lagrangian(q, v, 0.5 * ca.dot(v, v), V=9.81 * q[1],
    ...                    constraints={"rod": ca.dot(q, q) - 1})
    >>> mq = ls.model(); qs = mq.variables["q"].sym
    >>> _ = mq.event(qs[0], name="wall", direction=-1, reset={"der(q)": -mq.der(qs)})
    >>> r = ls.index1()
    >>> tr = dk.simulate(r, np.linspace(0, 1, 101), {"q": [1, 0], "der(q)": [0, 0]},
    ...                  method="rattle", dt=1e-3)
    >>> round(tr.events[0][0], 5)       # exact: 0.5919604869
    0.59196
    """
    from ..inputs import resolve_params
    from .rattle import rattle_stepper, simulate_rattle

    if unknown:
        from ..errors import ModelError

        raise ModelError(f"simulate(method='rattle') with events: unknown option(s) "
                         f"{sorted(unknown)}")
    wall0 = time.perf_counter()
    tg = np.asarray(t, dtype=float).ravel()
    t0, tf = float(tg[0]), float(tg[-1])
    span = tf - t0
    if zeno_window is None:
        zeno_window = 1e-4 * span
    first = simulate_rattle(r, tg[:2], init, params=params, inputs=inputs, dt=dt)
    sysm, step, helpers = rattle_stepper(r, (t0, tf), params, inputs, newton_iter)
    n, m_ = sysm.n, sysm.m
    q0 = np.array([first.values[nm][0] for nm in sysm.q_names])
    v0 = np.array([first.values[nm][0] for nm in sysm.v_names])
    p0 = np.asarray(helpers["p_of_v"](q0, v0), float).ravel()
    lam0 = np.asarray(helpers["out"](t0, q0, p0)[4], float).ravel()
    X = np.concatenate([[t0], q0, p0, lam0, [0.0, 0.0]])
    mon = _Monitors(r, r, [], r.n_p)
    pv = resolve_params(r, params)
    pvals = dict(zip(r.p_names, pv, strict=True))
    allowed = set(sysm.q_names) | set(sysm.v_names) | set(pvals) | {"t"}
    bad = [nm for nm in mon.used if nm not in allowed]
    if bad:
        from ..errors import ModelError

        raise ModelError(
            f"simulate(method='rattle'): the events use {bad}; with RATTLE an event may use "
            "the coordinates, velocities, parameters and t only (use method='idas')"
        )

    def state(Xk):
        q = Xk[1:1 + n]
        v = np.asarray(helpers["out"](Xk[0], q, Xk[1 + n:1 + 2 * n])[0], float).ravel()
        return q, v

    def gvals(Xk) -> np.ndarray:
        if not mon.n_ev:
            return np.zeros(0)
        q, v = state(Xk)
        vals = {**{nm: np.atleast_1d(val) for nm, val in zip(sysm.q_names, q, strict=True)},
                **{nm: np.atleast_1d(val) for nm, val in zip(sysm.v_names, v, strict=True)},
                **{nm: np.atleast_1d(val) for nm, val in pvals.items()}}
        vec = mon._vec(vals, np.atleast_1d(Xk[0]))
        return np.asarray(mon.fev(vec.T), float).ravel()

    spacing = np.diff(tg)
    if dt is None:
        from .rattle import DEFAULT_DT

        dt = min(float(np.min(spacing)), DEFAULT_DT)
    nsteps = np.maximum(1, np.ceil(spacing / dt - 1e-8)).astype(int)
    rows: list[np.ndarray] = [X.copy()]
    events: list[tuple[float, str]] = []
    nev = mon.n_ev
    ref = [None] * nev
    band = [0.0] * nev
    g_cur = gvals(X)
    for i in range(nev):
        if g_cur[i] != 0:
            ref[i] = 1.0 if g_cur[i] > 0 else -1.0
    total_steps = 0
    stop = False
    zeno_msg = None

    def do_step(Xa, h):
        return np.asarray(step(Xa, h), float).ravel()

    chunks: dict[int, ca.Function] = {}

    def run_chunk(Xa, h, K):
        """K steps of size h from Xa: the K states after each step, (K, len(X))."""
        if K not in chunks:
            chunks[K] = step.mapaccum(K)
        return np.asarray(chunks[K](Xa, ca.DM.ones(1, K) * h), float).T

    gmap: dict[int, ca.Function] = {}
    outv = helpers["out"]

    def gvals_rows(Xr) -> np.ndarray:
        """Event functions on the rows of Xr, (rows, events)."""
        N = Xr.shape[0]
        if not nev:
            return np.zeros((N, 0))
        if N not in gmap:
            gmap[N] = outv.map(N)
        Vr = np.asarray(gmap[N](Xr[:, 0].reshape(1, -1), Xr[:, 1:1 + n].T,
                                Xr[:, 1 + n:1 + 2 * n].T)[0], float).reshape(n, N)
        cols = []
        for nm in mon.used:
            if nm == "t":
                cols.append(Xr[:, 0])
            elif nm in sysm.q_names:
                cols.append(Xr[:, 1 + sysm.q_names.index(nm)])
            elif nm in sysm.v_names:
                cols.append(Vr[sysm.v_names.index(nm)])
            else:
                cols.append(np.full(N, pvals[nm]))
        vec = np.column_stack(cols) if cols else np.zeros((N, 0))
        return np.asarray(mon.fev.map(N)(vec.T), float).reshape(nev, N).T

    for k in range(tg.size - 1):
        h = spacing[k] / nsteps[k]
        left = int(nsteps[k])
        while left > 0 and not stop:
            K = min(left, 64)
            K = 1 << (K.bit_length() - 1)  # powers of two: few distinct chunk Functions
            Xc = run_chunk(X, h, K)
            total_steps += K
            Gc = gvals_rows(Xc)
            j_hit, crossed_hit, ref = first_crossing(Gc, ref, band, mon.dirs, rows=K,
                                                     first_row_arms=False)
            hit = None if j_hit is None else (j_hit, crossed_hit)
            if hit is None:
                X = Xc[-1].copy()
                left -= K
                continue
            jrow, crossed = hit
            Xa = X if jrow == 0 else Xc[jrow - 1].copy()
            X1 = Xc[jrow]
            total_steps -= K - jrow - 1  # the steps after the crossing are taken again
            left -= jrow + 1
            g0 = gvals(Xa)
            g1 = gvals(X1)
            lin = {i: g0[i] / (g0[i] - g1[i]) if g0[i] != g1[i] else 1.0 for i in crossed}
            lead = min(crossed, key=lambda i: (lin[i], i))
            lo, hi, glo, ghi = 0.0, 1.0, float(g0[lead]), float(g1[lead])
            Xe, side = X1, 0
            for _it in range(60):
                if hi - lo <= 1e-12:
                    break
                th = hi - ghi * (hi - lo) / (ghi - glo) if ghi != glo else 0.5 * (lo + hi)
                if not (lo < th < hi):
                    th = 0.5 * (lo + hi)
                Xm = do_step(Xa, th * h)
                gm = float(gvals(Xm)[lead])
                if gm != 0 and (gm > 0) == (glo > 0):
                    lo, glo = th, gm
                    if side == -1:
                        ghi *= 0.5
                    side = -1
                else:
                    hi, ghi, Xe = th, gm, Xm
                    if side == 1:
                        glo *= 0.5
                    side = 1
            if Xe is X1 and hi < 1.0:
                Xe = do_step(Xa, hi * h)
            theta = hi
            te = float(Xe[0])
            ge = gvals(Xe)
            fired = sorted({lead} | {i for i in crossed if np.sign(ge[i]) != np.sign(g0[i])})
            rows.append(Xe.copy())
            q, v = state(Xe)
            Xp = Xe.copy()
            terminal = False
            for i in fired:
                events.append((te, mon.names[i]))
                ref[i] = None
                band[i] = 10.0 * abs(float(ge[i])) + 1e-300
                ev = mon.events[i]
                terminal = terminal or ev.terminal
                if ev.reset and not ev.terminal:
                    ue = np.asarray(helpers["u"](te), float).ravel() if r.nu else np.zeros(0)
                    out = helpers["out"](te, Xp[1:1 + n], Xp[1 + n:1 + 2 * n])
                    acc = np.asarray(out[5], float).ravel()
                    lam = np.asarray(out[4], float).ravel()
                    x_r = np.concatenate([q, v])
                    z_r = np.concatenate([acc, lam])
                    row = dict(zip(r.x_names, x_r, strict=True)) | dict(
                        zip(r.z_names, z_r, strict=True)) | pvals
                    targets = mon.reset_targets(i, row, te)
                    xr, _, _ = restore(r, te, x_r, z_r, ue, pv, targets)
                    q, v = xr[:n], xr[n:2 * n]
                    Xp[1:1 + n] = q
                    Xp[1 + n:1 + 2 * n] = np.asarray(helpers["p_of_v"](q, v), float).ravel()
            for i in range(nev):
                if i not in fired and ge[i] != 0 and ref[i] is not None:
                    ref[i] = 1.0 if ge[i] > 0 else -1.0
            zeno_msg = _zeno_message(events, zeno_count, zeno_window, max_events, span)
            if terminal or zeno_msg is not None:
                stop = True
                break
            rows.append(Xp.copy())
            X1 = do_step(Xp, (1.0 - theta) * h) if theta < 1.0 else Xp
            X1[0] = Xa[0] + h  # exactly on the step grid
            g1 = gvals(X1)
            for i in range(nev):
                if ref[i] is None and abs(g1[i]) > band[i]:
                    ref[i] = 1.0 if g1[i] > 0 else -1.0
            X = X1
        if stop:
            break
        X[0] = tg[k + 1]
        rows.append(X.copy())
    R = np.array(rows)
    tt = R[:, 0]
    N = tt.size
    outm = helpers["out"].map(N)
    V, E, c, cd, lam, acc = (np.asarray(a) for a in outm(tt.reshape(1, -1), R[:, 1:1 + n].T,
                                                          R[:, 1 + n:1 + 2 * n].T))
    values: dict[str, np.ndarray] = {}
    for i, nm in enumerate(sysm.q_names):
        values[nm] = R[:, 1 + i].copy()
    for i, nm in enumerate(sysm.v_names):
        values[nm] = V[i].copy()
    for i, nm in enumerate(sysm.multiplier_names):
        values[nm] = lam[i].copy()
    for nm, expr_name in zip(sysm.q_names, r.z_names[:n], strict=False):
        values.setdefault(expr_name, acc[sysm.q_names.index(nm)].copy())
    inv = np.vstack([c, cd]).T if m_ else np.zeros((N, 0))
    inv_names = list(sysm.constraint_names) + [f"d/dt {s_}" for s_ in sysm.constraint_names]
    stats = {"method": "rattle", "steps": total_steps, "dt": float(dt), "events": len(events),
             "wall_time": time.perf_counter() - wall0, "energy": np.asarray(E).ravel()}
    if events and any(e.terminal and e.name == events[-1][1] for e in mon.events):
        stats["terminated_by"] = events[-1][1]
    traj = Trajectory(tt, values, inv, inv_names, stats, events=events)
    if zeno_msg is not None:
        raise SimulationError(zeno_msg, t=float(events[-1][0]), trajectory=traj)
    return traj
