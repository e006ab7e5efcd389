"""The re-solve: a dropped condition that does not hold at the solution is imposed, and the
problem is solved once more from that solution.

A dropped condition is implied by the kept ones and the invariants near the point of the
analysis; at the solution it holds to the accuracy the invariants hold at the ends (the
discretization's). A residual above ``1e-4 * max(1, |end state|)`` means that the solution
reached another branch of the constraints, where it is not implied. The re-solve imposes it
(as an equality, replacing a kept condition that depends on it there), and its report states
exactly what was imposed. If any condition still does not hold at the returned point,
``success`` is False: a report never contradicts the returned trajectory.
"""

from __future__ import annotations

import time as _time

from .boundary import analyze
from .run import solve_once

__all__ = ["dropped_violations", "resolve_violated", "unmet_conditions"]


def dropped_violations(sol, ba) -> list[tuple[int, float]]:
    """Dropped conditions that do not hold at ``sol``: ``[(index, residual)]``."""
    res, scale = sol._bc_residuals
    return [(i, float(res[i])) for i in ba.dropped if abs(res[i]) > 1e-4 * scale]


def unmet_conditions(sol) -> list[tuple[int, float]]:
    """Every boundary condition (kept or not) that does not hold at ``sol``."""
    res, scale = sol._bc_residuals
    return [(i, float(r)) for i, r in enumerate(res) if abs(r) > 1e-4 * scale]


def _names(ba, idx) -> str:
    return ", ".join(ba.labels[i] for i in idx) if idx else "nothing"


def resolve_violated(prob, first, ba, check: bool, make_guess):
    """Re-solve once, from ``first``, imposing the dropped conditions it violates."""
    viol = dropped_violations(first, ba)
    if not viol:
        return first
    t0 = _time.perf_counter()
    forced = [i for i, _ in viol]
    g = make_guess(prob, first)
    ba2 = analyze(prob, g, forced=forced)
    # the forced conditions are imposed even where one looks dependent (at the wrong branch),
    # so that the report's "imposing ..." is what was imposed
    ba2.kept = sorted(set(ba2.kept) | set(forced))
    ba2.dropped = [j for j in ba2.dropped if j not in ba2.kept]
    ba2.selectors = [s for s in ba2.selectors if s[0] not in forced]
    sol = solve_once(prob, g, ba2, "drop", check, t0)
    imposed = [ba2.labels[i] for i in ba2.kept]
    first_txt = (
        f"First solve: {first.status}, objective {first.objective:.10g}, but the dropped "
        + ", ".join(f"{ba.labels[i]} (residual {r:+.3g})" for i, r in viol)
        + " did not hold: the solution reached a branch of the constraints where "
        + ("it is" if len(viol) == 1 else "they are")
        + " not implied by the others. Re-solved from that solution imposing "
        + _names(ba, forced) + " as well (imposed in all: " + ", ".join(imposed) + ")."
    )
    sol.stats["resolved"] = {"first_objective": first.objective,
                             "first_status": first.status,
                             "forced": [ba.labels[i] for i in forced],
                             "first_iter_count": first.stats.get("iter_count")}
    lines = sol.report.split("\n")
    lines.insert(1, first_txt)
    bad = unmet_conditions(sol)
    if bad or not sol.success:
        sol.success = False
        lines.append(
            "FAILED: after the re-solve the boundary condition(s) "
            + (", ".join(f"{ba.labels[i]} (residual {r:+.3g})" for i, r in bad) if bad
               else _names(ba, forced))
            + " do not hold at the returned point; give a guess on the intended branch (e.g. "
            "a simulation near the intended motion) or state the conditions so that they "
            "select it."
        )
    sol.report = "\n".join(lines)
    return sol
