"""One IPOPT run on a compiled OCP: transcribe with a boundary selection, solve, build the
:class:`~daekit.ocp.solution.OCPSolution` and its report.

IPOPT always runs unless the boundary analysis *proved* the conditions contradictory
(:attr:`BoundaryAnalysis.proven`). The end-point check (can the initial, resp. final,
conditions hold with the algebraic equations, the invariants, the bounds and the path
constraints? a small least-squares problem) only diagnoses a failed run.
"""

from __future__ import annotations

import time as _time

import casadi as ca
import numpy as np

from ..errors import OCPError
from .nlp import call_buffered, quiet
from .solution import STATUS_OK, OCPSolution, build_solution

__all__ = ["solve_once", "ipopt_options"]

#: Impose the branch-selecting conditions of the boundary analysis as inequalities (True), or
#: only check them at the solution and re-solve (False). Measured with the default guess
#: (IPOPT iterations, True / False): cart-pole swing-up 32 / 13 (full state) and 14 / 13 (the
#: user's form), Betts 10.103 13 / 13, 3D pendulum rest to rest 5 / 4, planar swing 5 / 4.
SELECTORS_AS_INEQUALITIES = True


def ipopt_options(prob, hessian_exact: bool = True) -> dict:
    """daekit's IPOPT options for ``prob`` (user's ``solver_options`` override them)."""
    opts = {"ipopt.print_level": 5 if prob.verbose else 0, "print_time": prob.verbose,
            "ipopt.sb": "yes"}
    if not hessian_exact:
        opts["ipopt.hessian_approximation"] = "limited-memory"
    for k, val in prob.solver_options.items():
        opts[k if "." in k or k in ("print_time", "expand") else f"ipopt.{k}"] = val
    opts.setdefault("ipopt.max_iter", 1000)
    # MUMPS' permuting scaling (an MC64-type matching) costs seconds per factorization on
    # these banded collocation KKT systems (measured: 10 s -> 0.34 s for 15 iterations on
    # 3400 variables); switch it off unless the user asks for it
    opts.setdefault("ipopt.mumps_permuting_scaling", 0)
    # CasADi builds the reverse-mode gradient of the whole Lagrangian ("nlp_grad") when the
    # solver is made, for the parameters' multipliers lam_p; these NLPs have no parameters and
    # never call it (IPOPT's stats: 0 calls). Not building it: nlpsol 2.1 -> 0.9 ms on the
    # planar swing, the same iterates
    opts.setdefault("no_nlp_grad", True)
    opts.setdefault("calc_lam_p", False)
    return opts


def solve_once(prob, g, ba, redundancy: str, check: bool, t_start: float,
               selectors: bool = True) -> OCPSolution:
    """One transcription and IPOPT run with the boundary selection of ``ba`` (its
    branch-selecting conditions as inequalities unless ``selectors`` is False)."""
    use_selectors = selectors
    from .report import conflict_message, diagnose, endpoint_checks

    n_bc = len(prob.conditions)
    if redundancy == "drop":
        # branch-selecting conditions as the inequalities |c| <= gap / 2 (daekit.ocp.boundary)
        kept, pins = list(ba.kept), list(ba.pins)
        selectors = list(ba.selectors) if SELECTORS_AS_INEQUALITIES and use_selectors else []
    else:
        kept, selectors, pins = list(range(n_bc)), [], []
    if prob.method == "collocation":
        from .collocation import transcribe
    else:
        from .shooting import transcribe
    tr = transcribe(prob, g.fun, g.T, g.p, kept=kept, selectors=selectors, pins=pins)
    B = tr.builder
    lbx, ubx, x0, lbg, ubg = B.arrays()
    key = prob.structure_key(kept)
    if (g.V is not None and g.V.size == x0.size and g.key is not None
            and g.key[:-1] == key[:-1]):
        # the same variables (the boundary selection, last in the key, only changes rows)
        x0 = g.V.copy()
    x0 = np.clip(x0, lbx, ubx)
    V, G = B.V(), B.G()
    opts = ipopt_options(prob, tr.hessian_exact)
    if tr.derivatives and tr.hessian_exact:
        opts.update(tr.derivatives)
    lam0 = {}
    if (g.lam is not None and g.V is not None and g.key == key
            and g.lam[0].size == x0.size and g.lam[1].size == lbg.size):
        # the same NLP: a primal-dual warm start (multipliers, a small barrier parameter)
        lam0 = {"lam_x0": g.lam[0], "lam_g0": g.lam[1]}
        for k_, v_ in (("warm_start_init_point", "yes"), ("mu_init", 1e-6),
                       ("warm_start_bound_push", 1e-9), ("warm_start_mult_bound_push", 1e-9)):
            opts.setdefault(f"ipopt.{k_}", v_)
    pre = []
    if ba.proven:
        pre.append(conflict_message(ba, prob))
    try:
        solver = ca.nlpsol("ocp", "ipopt", {"x": V, "f": tr.J, "g": G}, opts)
    except RuntimeError as exc:
        raise OCPError(f"could not build the NLP solver: {exc}") from None
    t_build = _time.perf_counter() - t_start
    if ba.proven:
        fx = ca.Function("fg", [V], [tr.J, G])(x0)
        res = {"x": x0, "f": fx[0], "g": fx[1]}
        stats = {"return_status": "Contradictory_Boundary_Conditions", "success": False,
                 "iter_count": 0}
    else:
        t_solve = _time.perf_counter()
        with quiet(not prob.verbose):
            res, stats = call_buffered(solver, x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg,
                                        **lam0)
        t_solve = _time.perf_counter() - t_solve
        stats["t_solve"] = t_solve
    stats["t_build"] = t_build
    stats["n_variables"] = int(V.numel())
    stats["n_constraints"] = int(G.numel())
    status = str(stats.get("return_status", "unknown"))
    success = bool(stats.get("success", False)) or status in STATUS_OK
    Vopt = np.asarray(res["x"]).ravel()
    gopt = np.asarray(res["g"]).ravel()
    if not success and not ba.proven and check:
        # diagnosis of a failed run: can the end conditions hold at all? (least squares)
        pre.extend(endpoint_checks(prob, g))
    viol_g = np.maximum(np.maximum(lbg - gopt, gopt - ubg), 0.0)
    viol_x = np.maximum(np.maximum(lbx - Vopt, Vopt - ubx), 0.0)
    stats.update({
        "objective": float(res["f"]),
        "method": prob.method,
        "transcription": tr.method,
        "intervals": prob.intervals,
        "guess": g.note,
        "max_constraint_violation": float(np.max(viol_g, initial=0.0)),
        "max_bound_violation": float(np.max(viol_x, initial=0.0)),
        "n_boundary_conditions": n_bc,
        "boundary_rank": ba.rank,
        "boundary_dropped": [ba.labels[i] for i in ba.dropped] if redundancy == "drop" else [],
        "boundary_selectors": [ba.labels[i] for i, _, _ in ba.selectors],
        "boundary_pins": [lab for *_, lab in pins],
        "boundary_selectors_imposed": bool(selectors),
    })
    stats["t_total"] = _time.perf_counter() - t_start
    v0e, vTe, Pe, Te = (np.asarray(x) for x in tr.ends(Vopt))
    bres = np.asarray(prob.bc_fun(v0e, vTe, Pe, Te), float).ravel()
    bc_residuals = (bres, max(1.0, float(np.max(np.abs(np.concatenate([v0e, vTe])),
                                                initial=1.0))))
    report, infeas = diagnose(prob, tr, ba, kept, Vopt, gopt, lbg, ubg, lbx, ubx, success,
                              status, stats, g, pre, bres)
    sol = build_solution(prob, tr, Vopt, float(res["f"]), success, status, stats, kept, ba,
                         report, infeas, bc_residuals)
    if "lam_x" in res:
        sol._lam = (np.asarray(res["lam_x"]).ravel(), np.asarray(res["lam_g"]).ravel())
    return sol
