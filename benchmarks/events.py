"""Benchmark: the wall pendulum with 20 impacts against the same pendulum without the wall.

The planar Cartesian pendulum (index 3, L = 1, g = 9.81) released at rest from horizontal, a
wall at x = 0 (restitution e = 1, so every swing is the same and the 20th impact comes at
``K(1/2)/w (1 + 2 * 19)``); the span covers 20 impacts. All in one run, best of ``REPEAT``:

1. ``daekit.simulate`` with the wall (``dk.examples.pendulum_wall``), each remedy that runs on
   the event-driven driver (none, Baumgarte) and on segments (projection, a GGL system);
2. ``daekit.simulate`` on the pendulum without the wall, same grid and tolerances (the cost of
   the pendulum itself), plain and with projection (the projection runs once each: they are
   slow, interval-wise);
3. hand-written expert code: SciPy ``solve_ivp`` (DOP853) on the minimal-coordinates ODE
   ``theta'' = -(g/L) sin theta`` with a terminal event ``theta = 0`` and a manual restart
   with ``theta' -> -e theta'`` (the strongest fair alternative: no constraints to keep).

Printed: wall time and CPU time (the steadier measure on a shared machine), each also as a
ratio to the plain run, integrator steps, number of impacts found, the largest error of the
impact times against the exact ones (``daekit.examples.exact.pendulum_wall_impacts``), and
the ratio to the plain daekit run without the wall.

Run: ``python benchmarks/events.py``
"""

from __future__ import annotations

import time

import numpy as np
from scipy.integrate import solve_ivp

import daekit as dk
from daekit.examples.exact import pendulum_wall_impacts

REPEAT = 3
TOL = 1e-8
N_IMPACTS = 20
E = 1.0
G = 9.81


CPU: dict = {}


def best_of(fn, repeat=REPEAT):
    """Best wall time of ``repeat`` runs (the best CPU time is kept in ``CPU[fn]``: on a shared
    machine the CPU time is the steadier measure)."""
    best, cpu, out = np.inf, np.inf, None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        best = min(best, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    CPU["last"] = cpu
    return best, out


def scipy_wall(t_end: float, tol: float):
    """The expert version: theta ODE, event theta = 0 falling, restart with reversed speed."""

    def rhs(_t, y):
        return [y[1], -G * np.sin(y[0])]

    def wall(_t, y):
        return y[0]

    wall.terminal = True
    wall.direction = -1
    t0, y0, hits, steps = 0.0, [np.pi / 2, 0.0], [], 0
    while t0 < t_end:
        sol = solve_ivp(rhs, (t0, t_end), y0, method="DOP853", rtol=tol, atol=tol,
                        events=wall)
        steps += sol.t.size - 1
        if sol.status != 1:
            break
        te, ye = sol.t_events[0][0], sol.y_events[0][0]
        hits.append(te)
        # restart just past the wall: theta = 0 exactly, speed reversed
        t0, y0 = te, [0.0, -E * ye[1]]
    return np.array(hits), steps


def main() -> None:
    ref = pendulum_wall_impacts(N_IMPACTS, E)
    t_end = float(ref[-1] + 0.5 * (ref[1] - ref[0]))  # half a swing past the 20th impact
    t = np.linspace(0.0, t_end, int(round(100 * t_end)) + 1)
    fixed = {"x": 1.0, "y": 0.0, "der(x)": 0.0}
    rows = []

    r0 = dk.reduce_index(dk.examples.pendulum_planar())
    init0 = dk.initialize(r0, fixed=fixed)
    t_plain, tr0 = best_of(lambda: dk.simulate(r0, t, init0, rtol=TOL, atol=TOL))
    rows.append(("daekit, no wall (plain)", t_plain, tr0.stats.get("steps"), "-", "-",
                 CPU["last"]))
    c_plain = CPU["last"]
    t_pp, trp = best_of(lambda: dk.simulate(r0, t, init0, stabilization="projection", rtol=TOL,
                                            atol=TOL), repeat=1)
    rows.append(("daekit, no wall, projection", t_pp, trp.stats.get("steps"), "-", "-",
                 CPU["last"]))

    rw = dk.reduce_index(dk.examples.pendulum_wall(E))
    initw = dk.initialize(rw, fixed=fixed)
    for remedy in (None, "baumgarte", "projection"):
        tw, trw = best_of(lambda remedy=remedy: dk.simulate(rw, t, initw, stabilization=remedy,
                                                            rtol=TOL, atol=TOL),
                          repeat=1 if remedy == "projection" else REPEAT)
        te = np.array([a for a, _ in trw.events])
        err = np.max(np.abs(te[:N_IMPACTS] - ref)) if te.size >= N_IMPACTS else float("nan")
        rows.append((f"daekit, wall, {remedy or 'none'}", tw, trw.stats.get("steps"),
                     str(te.size), f"{err:.1e}", CPU["last"]))

    rg = dk.ggl(rw)
    initg = dk.initialize(rg, fixed=fixed)
    tw, trw = best_of(lambda: dk.simulate(rg, t, initg, rtol=TOL, atol=TOL))
    te = np.array([a for a, _ in trw.events])
    err = np.max(np.abs(te[:N_IMPACTS] - ref)) if te.size >= N_IMPACTS else float("nan")
    rows.append(("daekit, wall, GGL", tw, trw.stats.get("steps"), str(te.size), f"{err:.1e}",
                 CPU["last"]))

    ts, (hits, steps) = best_of(lambda: scipy_wall(t_end, TOL))
    err = np.max(np.abs(hits[:N_IMPACTS] - ref)) if hits.size >= N_IMPACTS else float("nan")
    rows.append(("SciPy DOP853, theta ODE + events", ts, steps, str(hits.size), f"{err:.1e}",
                 CPU["last"]))

    print(f"Wall pendulum, e = {E}, {N_IMPACTS} impacts in {t_end:.2f} s, rtol = atol = {TOL:g}, "
          f"{t.size} output points (best of {REPEAT})")
    print(f"{'run':32s} {'wall [s]':>9s} {'/ plain':>8s} {'CPU [s]':>8s} {'/ plain':>8s} "
          f"{'steps':>7s} {'impacts':>8s} {'max |dt_impact|':>16s}")
    for name, w, st, n, err, c in rows:
        print(f"{name:32s} {w:9.4f} {w / t_plain:8.2f} {c:8.4f} {c / c_plain:8.2f} {st!s:>7s} "
              f"{n:>8s} {err:>16s}")


if __name__ == "__main__":
    main()
