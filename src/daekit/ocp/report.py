"""The solution's report, and the diagnosis of a failed solve (which constraint is at fault)."""

from __future__ import annotations

import casadi as ca
import numpy as np

from .guess import seg

__all__ = ["diagnose", "endpoint_checks", "conflict_message"]


def _fmt_list(items: list[str], limit: int = 10) -> str:
    if len(items) <= limit:
        return ", ".join(items)
    return ", ".join(items[:limit]) + f", ... ({len(items)} in all)"


def _sign_notes(prob, r) -> list[str]:
    """Where final or periodic conditions fix every state of a declared invariant that is
    even in them (a unit quaternion), the sign imposed decides the branch: say so."""
    from ..reduction.invariants import even_declared

    if not (r.declared_invariants):
        return []
    a = prob.aug
    fixed: dict[str, set[str]] = {"final": set(), "periodic": set()}
    for c in prob.conditions:
        if c.kind in fixed and not isinstance(c.value, tuple) and c.expr.numel() == 1:
            w = a.which(c.expr)
            if w is not None and w[0] == "x":
                fixed[c.kind].add(a.x_names[w[1]])
    out = []
    for nm, states in even_declared(r).items():
        for kind, got in fixed.items():
            if set(states) <= got:
                out.append(
                    f"The {kind} conditions fix every component of {_fmt_list(states)}, and the "
                    f"invariant {nm!r} is the same for their negatives: the sign imposed decides "
                    "the branch (for a quaternion, q and -q are the same rotation, and the sign "
                    f"decides which way round it turns); ocp.{kind}(..., up_to_sign=...) "
                    "accepts either."
                )
    return out


def conflict_message(ba, prob) -> str:
    """The report's line for proven contradictory boundary conditions."""
    if ba.bound_conflicts:
        return ("CONTRADICTORY BOUNDARY CONDITIONS: " + "; ".join(ba.bound_conflicts)
                + ". IPOPT was not run: correct the condition or the bound.")
    names = [ba.labels[i] for i in ba.conflict]
    res = ba.conflict_residuals
    inv_names = prob.aug.inv_names
    what = ("the invariants (" + ", ".join(inv_names) + ") and the algebraic equations"
            if len(inv_names) else "the algebraic equations")
    if len(names) == 1:
        head = f"the boundary condition {names[0]} cannot hold together with {what}"
        drop = "without it the rest are consistent"
    elif ba.conflict_alone:
        head = f"the boundary conditions {', '.join(names)} contradict each other"
        drop = "dropping any one of them makes the rest consistent"
    else:
        head = (f"the boundary conditions {', '.join(names)} contradict each other "
                f"(together with {what})")
        drop = "dropping any one of them makes the rest consistent"
    resid = ", ".join(f"{ba.labels[i]} {res[i]:+.3g}" for i in ba.conflict) if res.size else ""
    return (
        f"CONTRADICTORY BOUNDARY CONDITIONS: {head} (they are affine, so this is certain); "
        f"{drop}. "
        + (f"At the closest point (least squares) their residuals are {resid}. " if resid
           else "")
        + "Nothing was dropped and IPOPT was not run: remove or correct one of them."
    )


def _suspected(ba, prob) -> str:
    names = [ba.labels[i] for i in ba.conflict]
    return (
        "WARNING: near the guess, the boundary conditions " + ", ".join(names)
        + " could not be met together with the model's equations ("
        + ", ".join(prob.man_names) + ") by a local least-squares projection (residual "
        f"{ba.residual:.2e}); this is not a proof (a nonconvex problem from one start), so "
        "IPOPT was run."
    )


def diagnose(prob, tr, ba, kept, V, g, lbg, ubg, lbx, ubx, success, status, stats, guess,
             pre=(), bres=None):
    """Return (report text, infeasibilities)."""
    a = prob.aug
    r = a.reduced
    lines = []
    lines.append(f"Optimal control of {prob.name!r}.")
    lines.append(
        f"Index-1 system ({r.method}): {a.nx} states ({_fmt_list(a.x_names)}), "
        f"{a.nz} algebraic unknowns, decision controls {_fmt_list(a.w_names) or 'none'}."
    )
    for base, K in a.chains:
        lines.append(
            f"The reduction needs derivatives of the input {base!r} up to order {K}: {base!r} and "
            f"its lower derivatives are states of a chain of {K} integrator(s); the decision "
            f"variable is its derivative of order {K}."
        )
    T = "free" if prob.T_free is not None else f"{prob.T_fixed:g}"
    lines.append(
        f"Transcription: {tr.method}, {prob.intervals} intervals, final time {T}, controls "
        f"piecewise {prob.control_mode}; NLP with {stats['n_variables']} variables and "
        f"{stats['n_constraints']} constraints. Initial guess: {guess.note}."
    )
    if a.inv_names:
        declared = set(r.declared_invariants)
        shown = [f"{nm} (declared)" if nm in declared else nm for nm in a.inv_names]
        lines.append(
            "Invariants imposed at t = 0 only (exact dynamics keep them afterwards): "
            f"{_fmt_list(shown)}."
        )
        lines.extend(_sign_notes(prob, r))
    if ba.labels:
        n = ba.n_conditions
        if ba.proven:
            lines.append(
                f"Boundary conditions: {n} given; they contradict each other (see below), so "
                "none was dropped as redundant."
            )
        elif kept == list(range(n)) and ba.dropped:
            lines.append(
                f"Boundary conditions: {n} given, but only {ba.rank} are independent on the "
                f"invariant manifold (dimension {ba.manifold_dims[0]} at t = 0 and "
                f"{ba.manifold_dims[1]} at t = T): all were imposed as asked (redundancy='keep'),"
                " which makes the NLP's constraint Jacobian rank deficient."
            )
        elif ba.dropped:
            sel = {i for i, _, _ in ba.selectors}
            pinned = {k for k, *_ in ba.pins}
            dropped = [ba.labels[i] for i in ba.dropped if prob.bc_kinds[i] not in pinned]
            replaced = [ba.labels[i] for i in ba.dropped if prob.bc_kinds[i] in pinned]
            v0, vT, P, TT = (np.asarray(x) for x in tr.ends(V))
            res = np.asarray(bres).ravel()
            worst = max(abs(res[i]) for i in ba.dropped)
            lines.append(
                f"Boundary conditions: {n} given, rank {ba.rank} on the invariant manifold "
                f"(dimension {ba.manifold_dims[0]} at t = 0 and {ba.manifold_dims[1]} at t = T; "
                "the final state lies on it because the invariants hold at t = 0 and the "
                "dynamics keep them). Imposed: "
                f"{_fmt_list([ba.labels[i] for i in kept] + [lab for *_, lab in ba.pins])}"
                + (f" (the last {len(ba.pins)} in place of {_fmt_list(replaced)}: the point "
                   "they determine, see below)" if ba.pins else "")
                + f". Dropped as implied by those and the invariants: {_fmt_list(dropped) or 'none'}"
                + (f" (branch-selecting ones kept as inequalities: "
                   f"{_fmt_list([ba.labels[i] for i in sorted(sel)])})" if sel else "")
                + ("." if ba.proven else
                   "; the largest residual of these" + (" and the replaced ones" if ba.pins
                                                        else "")
                   + f" at the solution is {worst:.2e}.")
            )
            if not ba.proven and worst > 1e-4 * max(1.0, float(np.max(np.abs(v0), initial=1.0))):
                lines.append(
                    "WARNING: a dropped condition does not hold at the solution: it was implied "
                    "only locally (another branch of the constraints was reached). After a "
                    "successful solve, solve() repeats it once imposing the violated condition; "
                    "otherwise give a guess closer to the intended solution or state the "
                    "conditions differently."
                )
        else:
            lines.append(f"Boundary conditions: {n}, independent on the invariant manifold.")
        if ba.notes:
            lines.append("Boundary analysis: " + "; ".join(ba.notes) + ".")
        if ba.conflict and not ba.proven:
            lines.append(_suspected(ba, prob))
    not_run = status == "Contradictory_Boundary_Conditions"
    lines.append(
        f"IPOPT not run ({status}; {stats['t_total']:.3g} s to build the NLP)." if not_run else
        f"IPOPT: {status} after {stats.get('iter_count', '?')} iterations "
        f"({stats['t_total']:.3g} s in all, {stats['t_build']:.3g} s to build the NLP)."
    )
    fr, _X, _Z, _W, T_opt, P_opt = (np.asarray(v) for v in tr.grid(V))
    P_opt = P_opt.ravel()
    extra = [f"Objective {float(stats.get('objective', np.nan)):.10g}"] if "objective" in stats \
        else []
    if prob.T_free is not None:
        extra.append(f"final time T = {float(T_opt.ravel()[0]):.8g}")
    free = [f"{n} = {P_opt[i]:.8g}" for i, n in enumerate(a.p_names) if n in prob.free_params]
    if free:
        extra.append(f"free parameters {', '.join(free)}")
    if "max_constraint_violation" in stats:
        extra.append(f"largest constraint violation {stats['max_constraint_violation']:.1e}")
    if "max_invariant" in stats:
        extra.append(
            f"invariants |.| <= {stats['max_invariant_t0']:.1e} at t = 0 and "
            f"<= {stats['max_invariant']:.1e} on the grid"
        )
    if extra:
        lines.append("; ".join(extra) + ".")
    so = {k.removeprefix("ipopt."): v for k, v in prob.solver_options.items()}
    if (prob.method == "shooting" and int(stats.get("iter_count", 0) or 0) > 100
            and so.get("hessian_approximation") != "exact"):
        lines.append(
            "Hint: many iterations with the limited-memory Hessian of the shooting transcription; "
            "solver_options={'hessian_approximation': 'exact'} (second-order IDAS "
            "sensitivities) often needs far fewer (periodic 3D pendulum: 214 -> 24), or warm "
            "start from a collocation solution: solve(guess=collocation_solution)."
        )
    infeas = []
    if not success:
        infeas = [] if ba.proven else _violations(tr, g, lbg, ubg, float(np.ravel(T_opt)[0]))
        pre = list(pre)
        lines.append("The solver did not succeed.")
        if ba.dropped and kept == list(range(ba.n_conditions)):
            lines.append(
                "The boundary conditions were all imposed (redundancy='keep') although only "
                f"{ba.rank} of {ba.n_conditions} are independent on the invariant manifold: the "
                "redundant ones ("
                f"{_fmt_list([ba.labels[i] for i in ba.dropped])}) make the constraint Jacobian "
                "rank deficient, which defeats IPOPT; solve with redundancy='drop'."
            )
        if pre:
            lines.extend(pre)
        if infeas:
            lines.append("Largest constraint violations at the point IPOPT returned:")
            for lab, v, t in infeas[:6]:
                when = f" at t = {t:.4g}" if t is not None else ""
                lines.append(f"  {lab}{when}: violated by {v:.3e}")
        active = [] if ba.proven else _active_bounds(prob, tr, V, lbx, ubx)
        if active:
            lines.append(f"Active variable bounds there: {_fmt_list(active)}.")
        if not ba.proven and not infeas:
            lines.append(
                "All constraints hold at the returned point: the failure is one of convergence "
                "(try more iterations, a better guess, or scaling)."
            )
        elif not ba.proven:
            lines.append(
                "Check the constraints named above: they cannot hold together with the "
                "dynamics and the invariants (or need a better initial guess)."
            )
    return "\n".join(lines), infeas


def _violations(tr, g, lbg, ubg, T: float = 1.0):
    viol = np.maximum(np.maximum(lbg - g, g - ubg), 0.0)
    viol[~np.isfinite(viol)] = np.inf
    best: dict[str, tuple[float, float | None]] = {}
    for grp in tr.builder.groups:
        for i in range(grp.start, grp.stop):
            v = float(viol[i])
            if v <= 1e-9:
                continue
            lab = grp.label
            if grp.names:
                k = i - grp.start
                sub = grp.names[k]
                if grp.kind == "invariant":
                    lab = f"invariant {sub!r}"
                elif grp.kind == "boundary":
                    lab = f"boundary condition {sub}"
                else:
                    lab = sub
            t = grp.time if isinstance(grp.time, (int, float)) else None
            if grp.times is not None:
                t = float(grp.times[i - grp.start])
            if lab not in best or v > best[lab][0]:
                best[lab] = (v, t)
    items = sorted(best.items(), key=lambda kv: -kv[1][0])
    tscale = T  # the rows' times are fractions of the horizon
    return [(lab, v, None if t is None else t * tscale) for lab, (v, t) in items]


def _active_bounds(prob, tr, V, lbx, ubx) -> list[str]:
    a = prob.aug
    out = []
    lb, ub = prob.lb, prob.ub
    for kind, names in (("x", a.x_names), ("z", a.z_names), ("w", a.w_names)):
        for i, nm in enumerate(names):
            if np.isfinite(lb[kind][i]):
                out.append((nm, ">=", lb[kind][i], kind, i))
            if np.isfinite(ub[kind][i]):
                out.append((nm, "<=", ub[kind][i], kind, i))
    if not out:
        return []
    fr, X, Z, W, T, P = (np.asarray(v) for v in tr.grid(V))
    M = {"x": X, "z": Z, "w": W}
    res = []
    for nm, op, val, kind, i in out:
        row = M[kind][i, :]
        tol = 1e-6 * max(1.0, abs(val))
        if (op == ">=" and np.any(row <= val + tol)) or (op == "<=" and np.any(row >= val - tol)):
            res.append(f"{nm} {op} {val:g}")
    return res


def endpoint_checks(prob, guess) -> list[str]:
    """Can the conditions at t = 0 (resp. T) hold together with alg, invariants and bounds?

    A local least-squares problem from the guess (IPOPT on the slacks): a residual is a strong
    hint, not a proof, and is reported as such after a failed run."""
    a = prob.aug
    out = []
    n = a.nx + a.nz + a.nw
    p = guess.p
    T = guess.T
    xlb, xub, zlb, zub, wlb, wub = prob.simple_bounds()
    lbv = np.concatenate([xlb, zlb, wlb])
    ubv = np.concatenate([xub, zub, wub])
    for kind, t in (("initial", 0.0), ("final", T)):
        v = ca.SX.sym("v", n)
        rows = prob.bc_fun(v, v, ca.DM(p), t)
        idx = [i for i, k in enumerate(prob.bc_kinds) if k == kind]
        labels = [prob.bc_labels[i] for i in idx] + prob.man_names
        eqs = ca.vertcat(*[rows[i] for i in idx], prob.man_fun(t, v, ca.DM(p)))
        if eqs.numel() == 0:
            continue
        path = None
        if prob.path_fun is not None:
            x, z, w = seg(v, 0, a.nx), seg(v, a.nx, a.nx + a.nz), seg(v, a.nx + a.nz, n)
            path = prob.path_fun(t, x, z, w, ca.DM(p))
        x0, _, _ = guess.fun(np.array([t]))
        start = np.concatenate([guess.fun(np.array([t]))[k][:, 0] for k in range(3)])
        del x0
        s = ca.SX.sym("s", eqs.numel())
        # minimize the equality residual (slacks) subject to bounds and path constraints
        nlp = {"x": ca.vertcat(v, s), "f": ca.sumsqr(s), "g": ca.vertcat(eqs - s, *(
            [path] if path is not None else []))}
        lbg = np.concatenate([np.zeros(eqs.numel())] + (
            [prob.path_lb] if path is not None else []))
        ubg = np.concatenate([np.zeros(eqs.numel())] + (
            [prob.path_ub] if path is not None else []))
        try:
            solver = ca.nlpsol("chk", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False,
                                                     "ipopt.sb": "yes", "ipopt.max_iter": 300,
                                                     "calc_lam_p": False, "no_nlp_grad": True})
            res = solver(x0=np.concatenate([np.clip(start, lbv, ubv), np.zeros(eqs.numel())]),
                         lbx=np.concatenate([lbv, -np.inf * np.ones(eqs.numel())]),
                         ubx=np.concatenate([ubv, np.inf * np.ones(eqs.numel())]),
                         lbg=lbg, ubg=ubg)
        except RuntimeError:
            continue
        sl = np.asarray(res["x"]).ravel()[n:]
        if np.max(np.abs(sl), initial=0.0) > 1e-5:
            bad = [f"{labels[i]} (residual {sl[i]:+.3g})" for i in np.argsort(-np.abs(sl))
                   if abs(sl[i]) > 1e-5]
            where = "t = 0" if kind == "initial" else "t = T"
            vals = np.asarray(res["x"]).ravel()[:n]
            names = a.x_names + a.z_names + a.w_names
            at_lo = np.abs(vals - lbv) < 1e-6
            at_hi = np.abs(vals - ubv) < 1e-6
            act = [f"{names[i]} >= {lbv[i]:g}" if at_lo[i] else f"{names[i]} <= {ubv[i]:g}"
                   for i in range(n) if at_lo[i] or at_hi[i]]
            msg = (f"LIKELY INFEASIBLE at {where}: the {kind} conditions, the model's equations "
                   f"and the bounds could not be met together by a least-squares search from "
                   f"the guess (a hint, not a proof); at the closest point found the violated "
                   f"ones are {_fmt_list(bad, 6)}")
            if act:
                msg += f", with the bounds {_fmt_list(act, 6)} active"
            out.append(msg + ".")
    return out
