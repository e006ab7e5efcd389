"""Plain IDAS runs on the event-driven driver, and systems without differential states.

Without monitors the :class:`~daekit.simulate.driver.Driver` integrates the whole output grid
in one IDAS run (the output points are interpolated by IDAS and restart nothing). It starts
without IDACalcIC from ``xdot0 = ode(x0, z0)`` (the values are consistent: ``z0`` was solved
from ``alg = 0``) with a first step set by the tolerances and the whole time span, and with a
step budget; should that attempt fail, a second one excludes the algebraic unknowns from the
error test and starts with a tiny step (fully implicit index-1 models with fast inputs, such
as the transistor amplifier, need it), a third has the full step budget; if all fail, the
grid is integrated up to the failure, and the error carries the partial trajectory.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import SimulationError
from .driver import Driver
from .system import System, make_trajectory
from .trajectory import Trajectory

__all__ = ["run_idas", "run_algebraic"]


def run_idas(system: System, tg, x0, z0, pv, monitors=(), progress: bool = False,
             label: str = "simulate", checks: int | None = None) -> Trajectory:
    """Integrate ``system`` over ``tg`` with the driver and the given monitors.

    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> from daekit.inputs import InputSignal
    >>> from daekit.simulate.system import system_for
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x")
    >>> r = ReducedDAE(t, x, ca.SX(0, 1), ca.SX(0, 1), ca.SX(0, 1), -x, ca.SX(0, 1),
    ...     ca.SX(0, 1), [], ["x"], [], [], [], np.zeros(0), {"x": x})
    >>> s = system_for(r, InputSignal(r, None), 1e-10, 1e-10, {})
    >>> tr = run_idas(s, np.linspace(0, 1, 11), [1.0], [], [])
    >>> bool(abs(tr["x"][-1] - np.exp(-1)) < 1e-8), tr.stats["segments"]
    (True, 1)
    """
    d = Driver(system, tg, x0, z0, pv, monitors, progress=progress, checks=checks, label=label)
    return d.run().trajectory()


def run_algebraic(system: System, tg, z0, U, pv) -> Trajectory:
    """A system without differential states: Newton on ``alg = 0`` at every output time."""
    r = system.r
    w0 = time.perf_counter()
    n = tg.size
    X = np.zeros((n, 0))
    Z = np.empty((n, r.nz))
    Z[0] = z0
    x = np.zeros(0)
    for k in range(1, n):
        Z[k] = system.solve_z(tg[k], x, Z[k - 1], U[k], pv)
        g = np.asarray(system.alg_fun(tg[k], x, Z[k], U[k], pv)[0], dtype=float).ravel()
        if not np.all(np.isfinite(g)) or np.max(np.abs(g), initial=0.0) > 1e-8 * (
            1 + np.max(np.abs(Z[k]), initial=0.0)
        ):
            partial = make_trajectory(r, tg[:k], X[:k], Z[:k], U[:k], pv, {})
            raise SimulationError(
                f"simulate: no state to integrate, and Newton on the algebraic equations failed "
                f"at t = {tg[k]:g} (residual {np.max(np.abs(g)):.3g}); the trajectory up to "
                f"t = {tg[k - 1]:g} is attached as .trajectory.",
                t=float(tg[k]),
                trajectory=partial,
            )
    stats = {"steps": 0, "newton_solves": n - 1, "integrator_wall_time": time.perf_counter() - w0,
             "note": "no differential states: algebraic equations solved at each output time"}
    return make_trajectory(r, tg, X, Z, U, pv, stats, system.evaluator)
