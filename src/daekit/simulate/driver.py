"""The event-driven simulation driver: one continuous IDAS run, interrupted only by monitors.

:class:`Driver` integrates a :class:`~daekit.simulate.system.System` over the output grid in
*segments*: one CasADi IDAS grid integrator call covers many output points at once (IDAS steps
by its own error control and interpolates the output points; they never restart anything).
After each segment every :class:`Monitor` looks at it (the segment's rows: the start, the
output points inside it, and ``checks`` evenly spaced check points). When one fires, the
driver keeps the rows before the firing time, lets the monitor *act* (project, re-select the
states, reset a state, stop), and starts the next segment there. A restart of IDAS happens
only at such an event -- and at the end of a segment in which nothing fired, whose length
quadruples every time (the first is a quarter of the span unless the monitors say
otherwise), so there are only
logarithmically many of those. After an event the next
segment is 1.5 times the time since the previous restart (events that recur, like drift
crossing a tolerance, then cost little re-integration).

Writing a monitor
-----------------
Subclass :class:`Monitor` (Diffrax-like: ``init`` gives a state, ``check`` looks at a segment
and says whether and when it fired, ``act`` says what to do)::

    class Wall(Monitor):
        '''A user event: x[0] crosses zero falling; reset v[0] <- -0.8 v[0].'''
        name = "wall"
        def check(self, seg, state):
            g = seg.X[:, 0]                               # the event function on the rows
            hit = np.nonzero((g[:-1] > 0) & (g[1:] <= 0))[0]
            if hit.size == 0:
                return None
            i = int(hit[0])                               # sign change in [t_i, t_i+1]
            t, x, z = seg.driver.locate(seg, i, lambda t, x, z, u: x[0])   # Illinois
            return Firing(t, x, z, info=i)
        def act(self, firing, driver, state):
            x = firing.x.copy(); x[1] = -0.8 * x[1]
            return Action(x=x, record=True, label=self.name), state

- ``check(seg, state)`` gets a :class:`Segment` (``seg.t``, ``seg.X``, ``seg.Z``, ``seg.U``,
  ``seg.p``, ``seg.system``, ``seg.driver``; row 0 is the segment's start) and returns a
  :class:`Firing` or None. A firing at a row (``Firing(t=seg.t[i], ..., index=i)``) needs no
  re-integration; one between rows is located with the driver's services:
  :meth:`Driver.locate` (Illinois/secant on ``g(t, x, z, u)``, re-integrating from the last
  good row), :meth:`Driver.state_at` (the state at any time from a known one) and
  :meth:`Driver.refine` (the same interval re-integrated on a fine grid).
- ``act(firing, driver, state)`` returns ``(Action, state)``: the new ``x`` (``z`` is
  re-solved from ``alg = 0`` by the driver, so the restart is consistent), optionally a new
  ``system`` (dummy-derivative re-selection), ``record=True`` for a jump (the trajectory gets
  two rows at the event time: before and after), ``terminal=True`` to stop, ``ignore=True``
  when the firing turned out not to be an event (the monitor is asked again on the rest of the
  segment; nothing restarts), and a ``label`` for ``driver.events``.
- ``at_end(seg, driver, state)`` (optional): the segment ended without a firing; IDAS
  restarts there anyway, so an Action costs nothing extra (projection projects early when the
  drift is near the tolerance); ``horizon(state)`` (optional) suggests the next segment's
  length (the drift monitor predicts its next crossing).
- ``accept(seg, upto, state)`` (optional) is told which rows were kept (``seg.t[:upto + 1]``),
  e.g. to remember the last value of a pivot measure; ``rescue(driver, t, x, z, system, error,
  state)`` (optional) may return an Action when IDAS failed in a segment starting at ``t``
  (dummy derivatives re-select there); ``check_dt`` (attribute, optional) caps the spacing of
  check points.

Monitors in this package: :class:`daekit.simulate.projection.DriftMonitor` (projection by
drift tolerance) and :class:`daekit.simulate.dummy.PivotMonitor` (dummy-derivative
re-selection).

Example
-------
>>> import casadi as ca, numpy as np
>>> from daekit.reduced import ReducedDAE
>>> from daekit.inputs import InputSignal
>>> from daekit.simulate.system import system_for
>>> t = ca.SX.sym("t"); x = ca.SX.sym("x")
>>> r = ReducedDAE(t, x, ca.SX(0, 1), ca.SX(0, 1), ca.SX(0, 1), -x, ca.SX(0, 1), ca.SX(0, 1),
...     [], ["x"], [], [], [], np.zeros(0), {"x": x})
>>> s = system_for(r, InputSignal(r, None), 1e-10, 1e-10, {})
>>> class Halve(Monitor):            # halve x whenever it falls below 0.5 (a reset)
...     def check(self, seg, state):
...         i = np.nonzero(seg.X[:, 0] < 0.5)[0]
...         if i.size == 0:
...             return None
...         t, x, z = seg.driver.locate(seg, int(i[0]) - 1, lambda t, x, z, u: x[0] - 0.5)
...         return Firing(t, x, z)
...     def act(self, firing, driver, state):
...         return Action(x=2 * firing.x, record=True, label="halve"), state
>>> d = Driver(s, np.linspace(0, 2, 5), np.array([1.0]), np.zeros(0), np.zeros(0), [Halve()])
>>> res = d.run()
>>> [round(te, 6) for te, _ in res.events]      # x = e^{-t} reaches 0.5 at t = ln 2
[0.693147, 1.386294]
>>> tr = res.trajectory()
>>> bool(abs(tr["x"][-1] - 4 * np.exp(-2)) < 1e-8)
True
"""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import SimulationError
from .progress import Progress
from .system import IntegrationFailure, System, make_trajectory
from .trajectory import Trajectory

__all__ = ["Driver", "Monitor", "Segment", "Firing", "Action", "DriverResult"]


@dataclass
class Segment:
    """The rows of one IDAS run: ``t (K,)`` (row 0 the start), ``X (K, nx)``, ``Z (K, nz)``,
    ``U (K, nu)``, parameters ``p``, ``output`` (which rows are user output points), ``check``
    (which rows are the segment's check points, its start and end: they depend on the segment
    only, so a monitor that looks at them alone acts the same on every output grid)."""

    t: np.ndarray
    X: np.ndarray
    Z: np.ndarray
    U: np.ndarray
    p: np.ndarray
    output: np.ndarray
    system: System
    driver: Driver
    check: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.check is None:
            self.check = np.ones(self.t.size, bool)

    def tail(self, i: int) -> Segment:
        """The rows from ``i`` on (row ``i`` becomes the start)."""
        return Segment(self.t[i:], self.X[i:], self.Z[i:], self.U[i:], self.p, self.output[i:],
                       self.system, self.driver, self.check[i:])


@dataclass
class Firing:
    """A monitor fired at time ``t`` with the (pre-event) state ``x``, ``z``; ``index`` the
    segment row if ``t`` is one (-1: located between rows); ``info`` anything for ``act``."""

    t: float
    x: np.ndarray
    z: np.ndarray
    index: int = -1
    info: Any = None


@dataclass
class Action:
    """What a monitor does at its firing (see the module docstring)."""

    x: np.ndarray | None = None
    z: np.ndarray | None = None
    system: System | None = None
    record: bool = False
    terminal: bool = False
    ignore: bool = False
    label: str | None = None


class Monitor:
    """Base class of the driver's monitors (see the module docstring)."""

    name = "monitor"
    check_dt: float | None = None
    #: length of the driver's first segment as a fraction of the span (the smallest over the
    #: monitors is used)
    first_segment: float = 0.25

    def init(self, driver: Driver, t0: float, x0: np.ndarray, z0: np.ndarray) -> Any:
        """The monitor's state at the start (default None)."""
        return None

    def check(self, seg: Segment, state: Any) -> Firing | None:
        """Whether and when it fired in ``seg`` (the earliest time), or None."""
        return None

    def act(self, firing: Firing, driver: Driver, state: Any) -> tuple[Action, Any]:
        """What to do at ``firing``; returns ``(Action, new state)``."""
        return Action(), state

    def accept(self, seg: Segment, upto: int, state: Any) -> Any:
        """Rows ``seg.t[:upto + 1]`` were kept; returns the new state."""
        return state

    def at_end(self, seg: Segment, driver: Driver, state: Any) -> tuple[Action | None, Any]:
        """The segment ended without a firing and IDAS restarts at ``seg.t[-1]``: an Action to
        take there at no extra cost (e.g. project early), or None."""
        return None, state

    def horizon(self, state: Any) -> float | None:
        """The length of the next segment this monitor suggests (None: the driver's rule)."""
        return None

    def rescue(self, driver: Driver, t: float, x, z, system: System, error: IntegrationFailure,
               state: Any) -> tuple[Action | None, Any]:
        """IDAS failed in a segment starting at ``t``: an Action to try, or None."""
        return None, state


@dataclass
class DriverResult:
    """What :meth:`Driver.run` returns: the recorded rows per system, events, statistics.

    ``parts`` is a list of ``(system, t chunks, x chunks, z chunks)``, one per system integrated
    (dummy derivatives switch systems); the chunks are arrays (``(k,)``, ``(k, nx)``,
    ``(k, nz)``) read with :meth:`arrays` and replaced with :meth:`set_rows`."""

    parts: list = field(default_factory=list)  # [(system, [t (k,)], [X (k, nx)], [Z (k, nz)])]
    events: list = field(default_factory=list)  # [(t, label)]
    stats: dict = field(default_factory=dict)

    @staticmethod
    def arrays(part) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(T, X, Z)`` of one part, the chunks joined."""
        system, ts, xs, zs = part
        if not ts:
            return np.zeros(0), np.zeros((0, system.nx)), np.zeros((0, system.nz))
        if len(ts) == 1:
            return ts[0], xs[0], zs[0]
        return np.concatenate(ts), np.concatenate(xs), np.concatenate(zs)

    @staticmethod
    def set_rows(part, X, Z) -> None:
        """Replace the rows of ``part`` (same times), e.g. by projected ones."""
        T = DriverResult.arrays(part)[0]
        part[1][:] = [T]
        part[2][:] = [np.asarray(X, dtype=float).reshape(T.size, part[0].nx)]
        part[3][:] = [np.asarray(Z, dtype=float).reshape(T.size, part[0].nz)]

    def trajectory(self, extra_stats: dict | None = None) -> Trajectory:
        """The :class:`Trajectory` (by the original model's names) of the recorded rows."""
        stats = dict(self.stats)
        stats.update(extra_stats or {})
        trajs = []
        pv = self.stats.get("_p")
        for part in self.parts:
            system = part[0]
            tt, X, Z = self.arrays(part)
            if not tt.size:
                continue
            U = system.sig.values(tt)
            trajs.append(make_trajectory(system.r, tt, X, Z, U, pv, {}, system.evaluator))
        stats.pop("_p", None)
        if not trajs:
            return Trajectory([], {}, None, [], stats)
        if len(trajs) == 1:
            tr = trajs[0]
            tr.stats = stats
            tr.events = list(self.events)
            return tr
        names = list(trajs[0].values)
        t = np.concatenate([p.t for p in trajs])
        vals = {n: np.concatenate([p.values[n] for p in trajs]) for n in names}
        inv = np.vstack([p.invariants for p in trajs])
        tr = Trajectory(t, vals, inv, trajs[0].invariant_names, stats)
        tr.events = list(self.events)
        return tr


#: segment grids per System (weak: they go with the system), see :meth:`Driver._grid`
_GRIDS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _push(cur, t: float, x, z) -> None:
    """Append one row to the current part."""
    cur[1].append(np.array([float(t)]))
    cur[2].append(np.asarray(x, dtype=float).reshape(1, -1).copy())
    cur[3].append(np.asarray(z, dtype=float).reshape(1, -1).copy())


class Driver:
    """Integrate ``system`` over the output grid ``tg`` from the consistent ``(x0, z0)``.

    Parameters
    ----------
    system : System
    tg : array
        Output times (strictly increasing); ``tg[0]`` is the start.
    x0, z0 : arrays
        Consistent initial values (``alg = 0`` holds).
    pv : array
        Parameter values.
    monitors : list of Monitor
        Watch every segment (none: the whole grid is one IDAS run).
    progress : bool
        Progress bar (on a terminal only).
    checks : int
        Check points per segment (default 32 with monitors, 16 without).
    label : str
        For the progress bar and messages.
    """

    def __init__(self, system: System, tg, x0, z0, pv, monitors=(), progress: bool = False,
                 checks: int | None = None, label: str = "simulate") -> None:
        self.system = system
        self.tg = np.asarray(tg, dtype=float)
        self.x0 = np.asarray(x0, dtype=float).ravel()
        self.z0 = np.asarray(z0, dtype=float).ravel()
        self.pv = np.asarray(pv, dtype=float).ravel()
        self.monitors = list(monitors)
        self.progress = progress
        # check points per segment: with monitors where they look; without, they only bound
        # the steps a failing attempt may take (IDAS interpolates them: no effect on steps)
        # (each output of a CasADi grid integrator costs a few microseconds: a plain run
        # takes 16, whose intervals get a four times larger step budget, see _attempt)
        self.checks = int(checks) if checks is not None else (32 if self.monitors else 16)
        self.label = label
        self.span = float(self.tg[-1] - self.tg[0])
        self.stats: dict = {"steps": 0, "residual_evaluations": 0, "jacobian_evaluations": 0,
                            "error_test_failures": 0, "newton_failures": 0, "segments": 0,
                            "restarts": 0, "relocations": 0, "_p": self.pv}
        self.notes: list[str] = []
        #: the system being integrated now (monitors may switch it, e.g. dummy derivatives)
        self.current = system
        self._tg_key: bytes | None = None
        #: an estimate of x'' at the next restart where the solution goes on smoothly (the
        #: first step's rule, :meth:`System.step0`), None after a jump or a switch of systems
        self._xddot: np.ndarray | None = None
        #: False once a restart with that first step was followed by a firing in its first
        #: check interval (a drift tolerance far below the error weights: each step of
        #: tolerance size re-creates the drift; IDAS's tiny first step then does better)
        self._curved_starts = True
        self._hinted = False

    # ------------------------------------------------------------------ services
    def _count(self, st: dict) -> None:
        for k, v in st.items():
            self.stats[k] = self.stats.get(k, 0) + v

    def _attempt(self, system: System, grid, x, z, first: bool = False):
        """Run ``grid`` from ``(x, z)``: with a step budget per grid interval from the
        consistent values (at the very start: IDAS's own consistent initialization first),
        then excluding the algebraic unknowns from the error test; without monitors a last
        attempt gets the full budget. A failing attempt gives up early: grid intervals are
        short (check points), the budget is ``System.first_budget`` steps per interval."""
        user_budget = "max_num_steps" in system.options
        # the budget per grid interval (a plain run's 16 check points: four times the budget
        # of the 64 it used to have, the same total)
        per = System.first_budget * (4 if not self.monitors and self.checks <= 16 else 1)
        budget = {} if user_budget else {"max_num_steps": per}
        tries: list[tuple[dict, bool]] = []
        if first and system.r.index < 2:
            # IDACalcIC first (CasADi's default start, as in an expert's raw IDAS): from
            # consistent values it converges at once and the integrator is reused for every
            # initial state. The consistent start (``init_xdot``, ``step0``) is a CasADi
            # construction option: a new integrator per initial state, measured +1.6 ms (27 %)
            # per ensemble sample of the 3D pendulum for the same steps on average (1330
            # against 1337 over 200 samples); it stays the fallback (the slider crank)
            tries.append((budget, False))
        tries.append((budget, True))
        if system.options.get("suppress_algebraic", True):  # (not if the user said False)
            tries.append(({**budget, "suppress_algebraic": True,
                           "step0": 1e-12 * max(1.0, self.span)}, True))
        if not user_budget and not self.monitors:
            tries.append(({}, True))
        first_exc = None
        for k, (extra, consistent) in enumerate(tries):
            try:
                hint = self._xddot if k == 0 and self._curved_starts else None
                self._hinted = hint is not None
                X, Z, st = system.run(grid, x, z, self.pv, extra, consistent=consistent,
                                      span=self.span, xddot0=hint)
            except IntegrationFailure as exc:
                first_exc = first_exc or exc
                self.stats["failed_attempts"] = self.stats.get("failed_attempts", 0) + 1
                continue
            self._count(st)
            if k and not (first and k == 1):
                self.notes.append(f"a first IDAS attempt failed ({first_exc.why}); a retry "
                                  "with other settings succeeded")
            return X, Z
        raise first_exc

    def state_at(self, system: System, ta: float, xa, za, t: float):
        """The state ``(x, z)`` at ``t >= ta`` integrated from ``(xa, za)`` at ``ta``."""
        if t <= ta:
            return np.asarray(xa, float).copy(), np.asarray(za, float).copy()
        X, Z = self._attempt(system, np.array([ta, t]), xa, za)
        self.stats["relocations"] += 1
        return X[-1], Z[-1]

    def refine(self, seg: Segment, i: int, points: int = 16) -> Segment:
        """Rows ``i`` .. ``i + 1`` of ``seg`` re-integrated on ``points`` sub-intervals."""
        grid = np.linspace(seg.t[i], seg.t[i + 1], points + 1)
        X, Z = self._attempt(seg.system, grid, seg.X[i], seg.Z[i])
        self.stats["relocations"] += 1
        U = seg.system.sig.values(grid)
        return Segment(grid, X, Z, U, seg.p, np.zeros(grid.size, bool), seg.system, self)

    def locate(self, seg: Segment, i: int, g, tol: float | None = None, max_iter: int = 40):
        """Where ``g(t, x, z, u)`` changes sign in ``[seg.t[i], seg.t[i + 1]]``.

        Illinois (a safeguarded secant) on ``g`` along the solution, each value by
        re-integrating from row ``i`` (the last good point). Returns ``(t, x, z)`` at a time
        within ``tol`` (default ``1e-12 (1 + |t|)`` relative to the bracket) on the side where
        ``g`` has the sign of row ``i``, i.e. just before the crossing.
        """
        system = seg.system
        ta, tb = float(seg.t[i]), float(seg.t[i + 1])
        xa, za = seg.X[i], seg.Z[i]
        ga = float(g(ta, seg.X[i], seg.Z[i], seg.U[i]))
        gb = float(g(tb, seg.X[i + 1], seg.Z[i + 1], seg.U[i + 1]))
        lo, hi, glo, ghi = ta, tb, ga, gb
        xlo, zlo = xa, za
        tol = tol if tol is not None else 1e-12 * max(1.0, abs(tb))
        side = 0
        if ga == 0.0:
            return ta, np.asarray(xa, float).copy(), np.asarray(za, float).copy()
        for _ in range(max_iter):
            if hi - lo <= tol:
                break
            tm = hi - ghi * (hi - lo) / (ghi - glo) if ghi != glo else 0.5 * (lo + hi)
            if not (lo < tm < hi):
                tm = 0.5 * (lo + hi)
            xm, zm = self.state_at(system, ta, xa, za, tm)
            gm = float(g(tm, xm, zm, system.sig.value(tm)))
            if gm == 0.0 or (gm > 0) == (glo > 0):
                lo, glo, xlo, zlo = tm, gm, xm, zm
                if side == -1:
                    ghi *= 0.5
                side = -1
                if gm == 0.0:
                    break
            else:
                hi, ghi = tm, gm
                if side == 1:
                    glo *= 0.5
                side = 1
        return lo, np.asarray(xlo, float).copy(), np.asarray(zlo, float).copy()

    def curvature(self, seg: Segment, te: float) -> np.ndarray | None:
        """``x''`` at ``te`` estimated from the segment's check rows before it (they depend on
        the segment only, so the restart does not depend on the output grid): the difference
        of ``ode`` at the last two check rows at or before ``te``."""
        rows = np.nonzero(seg.check)[0]
        rows = rows[seg.t[rows] <= te]
        if rows.size < 2:
            return None
        i, j = int(rows[-2]), int(rows[-1])
        sy = seg.system
        f = [sy.xdot(float(seg.t[k]), seg.X[k], seg.Z[k], sy.sig.value(float(seg.t[k])),
                     self.pv) for k in (i, j)]
        return (f[1] - f[0]) / float(seg.t[j] - seg.t[i])

    def consistent(self, system: System, t: float, x, z) -> np.ndarray:
        """``z`` re-solved from ``alg(t, x, z) = 0`` (Newton)."""
        return system.solve_z(t, x, z, system.sig.value(t), self.pv)

    # ------------------------------------------------------------------ the loop
    def _grid(self, t: float, tb: float, k: int):
        """Segment grid from ``t`` to ``tb``: outputs ``tg[k:j]`` and check points (kept per
        system for the last few output grids: a repeated call, e.g. a parameter sweep on one
        grid, builds each segment grid once; the arrays are read-only)."""
        n = self.checks
        dts = [m.check_dt for m in self.monitors if getattr(m, "check_dt", None)]
        if dts:
            n = max(n, int(math.ceil((tb - t) / min(dts))))
        n = min(n, 20000)
        if self._tg_key is None:
            self._tg_key = self.tg.tobytes()  # (bytes cache their hash: hashed once)
        key = (self._tg_key, t, tb, k, n)
        cache = _GRIDS.get(self.system)
        if cache is None:
            cache = _GRIDS.setdefault(self.system, {})
        hit = cache.get(key)
        if hit is not None:
            return hit
        out = self._make_grid(t, tb, k, n)
        out = (*out, np.nonzero(out[1][1:])[0] + 1)  # the output rows after the start
        for a in (*out[:3], out[4]):
            a.flags.writeable = False
        if len(cache) >= 16:
            try:
                cache.pop(next(iter(cache)), None)
            except (RuntimeError, StopIteration):  # (another thread changed it meanwhile)
                pass
        cache[key] = out
        return out

    def _make_grid(self, t: float, tb: float, k: int, n: int):
        tg = self.tg
        j = int(np.searchsorted(tg, tb * (1 + 1e-14) + 1e-300, side="right"))
        outs = tg[k:j]
        pts = [np.array([t]), outs]
        if outs.size == 0 or outs[-1] < tb:
            pts.append(np.array([tb]))
        chk = np.linspace(t, tb, n + 1)
        chk[0], chk[-1] = t, tb
        pts.append(chk[1:-1])
        raw = np.concatenate(pts)
        # sorted, duplicates merged, with the flags of the merged points (one sort)
        o_raw = np.zeros(raw.size, bool)
        o_raw[1: 1 + outs.size] = True
        c_raw = ~o_raw
        c_raw[1: 1 + outs.size] = raw[1: 1 + outs.size] == tb  # an output at tb is chk[-1]
        order = np.argsort(raw, kind="stable")
        ps = raw[order]
        new = np.empty(ps.size, bool)
        new[0] = True
        np.not_equal(ps[1:], ps[:-1], out=new[1:])
        starts = np.nonzero(new)[0]
        grid = ps[starts]
        if starts.size == ps.size:
            is_out, is_chk = o_raw[order], c_raw[order]
        else:
            is_out = np.logical_or.reduceat(o_raw[order], starts)
            is_chk = np.logical_or.reduceat(c_raw[order], starts)
        # a check point closer than 1e-9 of the segment after an output point: dropped, the
        # output row stands for it (check rows depend only on the segment, not on the grid)
        if grid.size > 2:
            eps = 1e-9 * (tb - t)
            d_prev = np.diff(grid, prepend=-np.inf)
            drop = (d_prev < eps) & ~is_out
            drop[0] = False
            is_chk[np.nonzero(drop)[0] - 1] = True
            keep = ~drop
            grid, is_out, is_chk = grid[keep], is_out[keep], is_chk[keep]
        return grid, is_out, is_chk, j

    def run(self) -> DriverResult:
        """Integrate over the whole grid; returns a :class:`DriverResult`."""
        tg, n = self.tg, self.tg.size
        system = self.system
        t, x, z = float(tg[0]), self.x0.copy(), self.z0.copy()
        result = DriverResult(stats=self.stats)
        cur = (system, [], [], [])
        _push(cur, t, x, z)
        result.parts.append(cur)
        states = [m.init(self, t, x, z) for m in self.monitors]
        k = 1
        L = self.span * min([getattr(m, "first_segment", 0.25) for m in self.monitors] or [1.0])
        bar = Progress(self.progress, tg[0], tg[-1], self.label)
        w0 = time.perf_counter()
        last_fail_t = None
        fails = 0
        same_time_events = 0
        try:
            while k < n:
                tb = t + L
                if tb >= tg[-1] - 1e-12 * max(1.0, abs(tg[-1])) or (tg[-1] - tb) < 0.05 * L:
                    tb = float(tg[-1])
                grid, is_out, is_chk, j, out_rows = self._grid(t, tb, k)
                self.stats["segments"] += 1
                try:
                    X, Z = self._attempt(system, grid, x, z, first=(t == tg[0]))
                except IntegrationFailure as exc:
                    fails = fails + 1 if last_fail_t == t else 1
                    act = None
                    if fails == 1:
                        for mi, m in enumerate(self.monitors):
                            act, states[mi] = m.rescue(self, t, x, z, system, exc, states[mi])
                            if act is not None:
                                break
                    last_fail_t = t
                    if act is not None:
                        system, x, z, cur = self._apply(act, system, t, x, z, result, cur)
                        L = max(L / 4, 1e-6 * self.span)
                        continue
                    ahead = exc.t > t + 1e-9 * max(1.0, abs(t), self.span)
                    if self.monitors and fails <= 4 and ahead:
                        # integrate up to half-way to the failure: the monitors look at that
                        # part (a degrading pivot is seen before IDAS breaks down on it)
                        L = 0.5 * (exc.t - t)
                        continue
                    ok = grid[grid < exc.t - 1e-9 * max(1.0, abs(exc.t))]
                    if not self.monitors and fails == 1 and ok.size >= 2:
                        L = float(ok[-1] - t)  # keep the grid points before the failure
                        continue
                    partial = result.trajectory()
                    raise SimulationError(
                        f"simulate: IDAS failed at t = {exc.t:.6g}: {exc.why}. The trajectory "
                        f"up to t = {t:g} is attached as .trajectory.",
                        t=float(exc.t), trajectory=partial,
                    ) from None
                last_fail_t = None
                # inputs on the rows only for the monitors (a plain run does not need them)
                U = system.sig.values(grid) if self.monitors else np.zeros((grid.size, 0))
                seg = Segment(grid, X, Z, U, self.pv, is_out, system, self, is_chk)
                fired = self._earliest(seg, states)
                if fired is None:
                    self._record(cur, seg, len(grid) - 1, inclusive=True, rows=out_rows)
                    for mi, m in enumerate(self.monitors):
                        states[mi] = m.accept(seg, len(grid) - 1, states[mi])
                    t, x, z = float(grid[-1]), X[-1].copy(), Z[-1].copy()
                    if t < tg[-1]:
                        z = self.consistent(system, t, x, z)
                        self._xddot = self.curvature(seg, t)
                    k = j
                    bar.update(t)
                    if t < tg[-1]:
                        self.stats["restarts"] += 1
                        # IDAS restarts here anyway: monitors may act at no extra cost
                        for mi, m in enumerate(self.monitors):
                            act, states[mi] = m.at_end(seg, self, states[mi])
                            if act is not None:
                                if act.label is not None:
                                    result.events.append((t, act.label))
                                if act.record or (act.system is not None
                                                  and act.system is not system):
                                    self._xddot = None
                                system, x, z, cur = self._apply(act, system, t, x, z, result,
                                                                cur)
                    L = self._next_length(states, 4.0 * L)
                    continue
                mi, f, act = fired
                te = float(f.t)
                if self._hinted and te - t <= 1.01 * (float(grid[-1]) - t) / self.checks:
                    self._curved_starts = False
                upto = f.index if f.index >= 0 else int(np.searchsorted(grid, te, "right")) - 1
                self._record(cur, seg, upto, inclusive=False, before=te)
                for mj, m in enumerate(self.monitors):
                    if mj != mi:
                        states[mj] = m.accept(seg, upto, states[mj])
                k = int(np.searchsorted(tg, te, side="left"))
                at_output = k < n and abs(tg[k] - te) <= 1e-13 * max(1.0, abs(te))
                if act.record:
                    _push(cur, te, f.x, f.z)
                if act.label is not None:
                    result.events.append((te, act.label))
                same_time_events = same_time_events + 1 if te <= t else 0
                if same_time_events > 20:
                    raise SimulationError(
                        f"simulate: the monitor {self.monitors[mi].name!r} fires again and "
                        f"again at t = {te:g} without time advancing",
                        t=te, trajectory=result.trajectory())
                system0 = system
                system, x, z, cur = self._apply(act, system, te, f.x, f.z, result, cur)
                # the solution goes on smoothly unless the state jumps or the system switches
                smooth = system is system0 and not act.record
                self._xddot = self.curvature(seg, te) if smooth else None
                if act.record or at_output:
                    _push(cur, te, x, z)
                    if at_output:
                        k += 1
                if act.terminal:
                    break
                L = self._next_length(states, max(1.5 * (te - t), 1e-6 * self.span, L / 64))
                t = te
                self.stats["restarts"] += 1
                bar.update(t)
        finally:
            bar.close()
        self.stats["integrator_wall_time"] = time.perf_counter() - w0
        if self.notes:
            self.stats["note"] = "; ".join(dict.fromkeys(self.notes))
        return result

    def _next_length(self, states, default: float) -> float:
        hs = [h for m, st in zip(self.monitors, states, strict=True)
              if (h := m.horizon(st)) is not None and h > 0]
        L = min(hs) if hs else default
        return max(L, 1e-9 * max(self.span, 1e-300))

    def _earliest(self, seg: Segment, states):
        """The earliest firing over the monitors as ``(monitor index, Firing, Action)``. Only
        the earliest monitor acts; a firing it ignores is re-checked on the rest of the
        segment (and the earliest chosen again)."""
        subs = {mi: seg for mi in range(len(self.monitors))}
        cands = {mi: m.check(seg, states[mi]) for mi, m in enumerate(self.monitors)}
        while True:
            live = [(float(f.t), mi) for mi, f in cands.items() if f is not None]
            if not live:
                return None
            _, mi = min(live)
            f = cands[mi]
            m = self.monitors[mi]
            # IDAS's interpolated algebraic values satisfy alg = 0 only to the tolerance: made
            # consistent before anyone acts on them (a re-selection turns them into states)
            f.z = self.consistent(seg.system, float(f.t), f.x, f.z)
            act, states[mi] = m.act(f, self, states[mi])
            if not act.ignore:
                if f.index >= 0:
                    f.index = int(np.searchsorted(seg.t, f.t, "left"))
                return mi, f, act
            sub = subs[mi]
            i = f.index if f.index >= 0 else int(np.searchsorted(sub.t, f.t, "right")) - 1
            if i <= 0 or i >= sub.t.size - 1:
                cands[mi] = None
                continue
            subs[mi] = sub.tail(i)
            cands[mi] = m.check(subs[mi], states[mi])

    def _record(self, cur, seg: Segment, upto: int, inclusive: bool, before: float | None = None,
                rows: np.ndarray | None = None):
        """Keep the output rows of ``seg`` up to row ``upto`` (rows before ``before`` only;
        ``rows``: the output rows of the whole segment, known)."""
        sel = rows if rows is not None else np.nonzero(seg.output[1: upto + 1])[0] + 1
        if before is not None:
            sel = sel[seg.t[sel] < before]
        if sel.size:
            cur[1].append(seg.t[sel])
            cur[2].append(seg.X[sel])
            cur[3].append(seg.Z[sel])

    def _apply(self, act: Action, system: System, t: float, x, z, result: DriverResult, cur):
        x = np.asarray(act.x if act.x is not None else x, dtype=float).ravel().copy()
        z = np.asarray(act.z if act.z is not None else z, dtype=float).ravel().copy()
        if act.system is not None and act.system is not system:
            system = act.system
            self.current = system
            cur = (system, [], [], [])
            result.parts.append(cur)
        z = self.consistent(system, t, x, z)
        return system, x, z, cur
