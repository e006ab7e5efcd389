"""The plain-language account of an :class:`~daekit.analysis.Analysis`
(:meth:`Analysis.explain`): the index and why, the DOF, the easy test, what the reduction will
do, and where structural analysis fails, which part fails and why.

>>> import daekit as dk
>>> print(dk.analyze(dk.examples.pendulum_planar()).explain().splitlines()[0])  # doctest: +ELLIPSIS
Model 'pendulum_planar': ...
"""

from __future__ import annotations

from typing import Any

from ..wording import count, derivative_name, listing

__all__ = ["explain"]


def _count_dof(k: int) -> str:
    return count(k, "degree of freedom")


def _group(names_values: dict[str, int]) -> list[tuple[str, int]]:
    """Group element names 'e[0]', 'e[1]' with equal values into 'e' (or 'e[0..2]')."""
    groups: dict[str, list[tuple[str, int]]] = {}
    for name, v in names_values.items():
        base = name.split("[")[0] if name.endswith("]") else name
        groups.setdefault(base, []).append((name, v))
    out = []
    for base, items in groups.items():
        vals = {v for _, v in items}
        if len(vals) == 1:
            out.append((base, items[0][1]))
        else:
            out.extend(items)
    return out


def _times(k: int) -> str:
    return {0: "not differentiated", 1: "differentiated once", 2: "differentiated twice"}.get(
        k, f"differentiated {k} times"
    )


def _der(name: str, k: int) -> str:
    if k == 0:
        return name
    return f"der({name})" if k == 1 else f"der({name},{k})"


def explain(a: Any) -> str:
    """The account of the analysis ``a`` (an :class:`~daekit.analysis.Analysis`):
    :meth:`Analysis.explain <daekit.analysis.Analysis.explain>` calls it.

    >>> import daekit as dk
    >>> text = explain(dk.analyze(dk.examples.pendulum_planar()))
    >>> print(text.splitlines()[2])  # doctest: +NORMALIZE_WHITESPACE +ELLIPSIS
    Differential index 3, from structural analysis (Pryce's Sigma-method); the system Jacobian
    is nonsingular at the test point (reciprocal condition ...), so the structural DOF is
    the true one, and the derivative array at the test points confirms the index (Pryce's
    index is only an upper bound of the differential one).
    >>> "Degrees of freedom: 2 initial values can be chosen freely" in text
    True
    """
    n = len(a.equation_offsets)
    n_alg = sum(1 for v in a.highest_order.values() if v == 0)
    lines = [
        f"Model {a.model_name!r}: {count(n, 'equation')} in {count(n, 'unknown')} "
        f"({n - n_alg} appear differentiated, {n_alg} only algebraically)"
        + (f", {count(a.n_inputs, 'input')}." if a.n_inputs else "."),
        "",
    ]
    unconfirmed = getattr(a, "index_unconfirmed", [])
    if a.structurally_ok:
        head = (f"the system Jacobian is nonsingular at the test point (reciprocal condition "
                f"{a.jacobian_rcond:.1e}), so the structural DOF is the true one"
                + (" (if that holds on the solutions too: no consistent test point was found)"
                   if getattr(a, "points_consistent", True) is False else ""))
        if unconfirmed:
            lines.append(
                f"Differential index at most {a.index}, from structural analysis (Pryce's "
                f"Sigma-method): {head}, but Pryce's index is only an upper bound of the "
                "differential index and it was not checked here.")
        elif a.index_confirmed:
            lines.append(f"Differential index {a.index}: structural analysis (Pryce's "
                         f"Sigma-method) gives index {a.structural_index}; {head}.")
        else:
            lines.append(
                f"Differential index {a.index}, from structural analysis (Pryce's Sigma-method); "
                + (f"{head} and the index (an ODE)." if a.structural_index == 0 else
                   f"{head}, and the derivative array at the test points confirms the index "
                   "(Pryce's index is only an upper bound of the differential one)."))
    else:
        lines.extend(_explain_failure(a))
    for eqs, nu, why in unconfirmed:
        lines.append(f"The structural index {nu} of the equations {listing(eqs, 6)} is not "
                     f"confirmed: {why}; the differential index may be lower.")
    if a.index_confirmed:
        for eqs, nu, found in a.index_confirmed[1]:
            lines.append(
                f"The structural index {nu} of the equations {listing(eqs, 6)} is only an upper "
                f"bound: their derivative array (at consistent points) determines every "
                f"derivative after {found} differentiation(s), so the differential index is "
                f"{a.index}.")
    lines.append(f"(The numeric tests were evaluated {a.test_points}.)")
    lines.append("")
    e = a.easy
    if e.passed:
        lines.append(
            f"Easy test (the lecture's): [dF/dx' dF/dz] has full rank {e.rank} "
            f"(condition {e.condition:.1e}): Newton can solve for the derivatives and algebraic "
            "unknowns directly; any index-1 solver (IDAS, collocation) accepts this model as is."
        )
    else:
        lines.append(
            f"Easy test (the lecture's): [dF/dx' dF/dz] has rank {e.rank} < {e.size}: the model "
            "is NOT index 1 as written; an index-1 solver will reject it or fail."
            + (f" The rank deficiency involves: {', '.join(e.deficient_equations)}."
               if e.deficient_equations else "")
        )
    lines.append("")
    if a.structurally_ok:
        diff = [(nm, c) for nm, c in _group(a.equation_offsets) if c > 0]
        if diff:
            lines.append("Why: to reach a system that determines every unknown's highest derivative,")
            for nm, c in diff:
                lines.append(f"  - {nm} must be {_times(c)}")
            lines.append("  (all other equations are used as they are).")
        else:
            lines.append("Why: no equation needs differentiating.")
        alg = [nm for nm, v in a.highest_order.items() if v == 0]
        d = a.variable_offsets
        for nm, dv in _group({k: d[k] for k in alg}):
            block = next((b for b in a.blocks if any(v.split("[")[0] == nm.split("[")[0] or v == nm
                                                     for v in b[1])), None)
            eqs = ", ".join(dict.fromkeys(
                derivative_name(x.split("[")[0], a.equation_offsets[x]) for x in block[0])) if block else ""
            if dv == 0:
                tail = "its derivative needs one more differentiation."
            else:
                tail = (f"its derivatives up to {_der(nm, dv)} are needed, so in the reduced "
                        f"form {nm} becomes a state although the model never differentiates it.")
            lines.append(f"  - algebraic {nm}: determined as {_der(nm, dv)} together with {eqs}; "
                         + tail)
        if a.index == 0:
            lines.append("  It is an ODE (index 0).")
        elif any(v == 0 for v in d.values()):
            lines.append(
                f"  Index = (most differentiations of an equation, {max(a.equation_offsets.values())})"
                " + 1, because some unknowns are only determined algebraically at the top level."
            )
        else:
            lines.append(
                f"  Index = most differentiations of an equation = {max(a.equation_offsets.values())}."
            )
    lines.append("")
    lines.append(
        f"Degrees of freedom: {count(a.dof, 'initial value')} can be chosen freely; the rest follow from "
        "the equations and their hidden consistency conditions"
        + (" and the declared invariants." if a.declared_invariants else ".")
    )
    if a.declared_invariants:
        k = len(a.declared_invariants)
        lines.append(
            f"Declared invariants (m.invariant): {', '.join(a.declared_invariants)}. They hold "
            "along every solution that starts on them (reduce_index checks that their time "
            "derivative vanishes there), so, like consistency conditions, they must hold at the "
            f"initial time: {a.dof + k} degrees of freedom from the equations, {a.dof} with "
            f"the declared invariant{'s' if k > 1 else ''}. Remedies against their drift: "
            "stabilization='projection', 'baumgarte' (c' = -a c, one pole), or "
            "'dummy_derivatives' (one state per invariant becomes algebraic)."
        )
    if a.structurally_ok:
        defs = set(a.definitions)
        cons = [(nm, c) for nm, c in _group({k: v for k, v in a.equation_offsets.items()
                                             if k not in defs}) if c > 0]
        if cons:
            conds = []
            for nm, c in cons:
                conds.extend(derivative_name(nm, k) for k in range(c))
            lines.append(
                "Consistency conditions (must hold at the initial time): " + ", ".join(conds) + "."
            )
        if defs:
            names = ", ".join(nm for nm, _ in _group({k: 0 for k in a.definitions}))
            lines.append(
                f"(The equations {names} define derivatives explicitly; the reduced form substitutes them, "
                "so they hold by construction.)"
            )
    if a.input_derivatives:
        needs = ", ".join(_der(nm, k) for nm, k in _group(a.input_derivatives))
        lines.append(
            f"Inputs: the equations to differentiate contain inputs, so the reduction needs their "
            f"derivatives up to {needs}: give inputs as CasADi expressions of time when "
            "simulating (daekit differentiates them), and in optimal control they become a chain "
            "of integrators."
        )
    lines.append("")
    if a.index <= 1 and e.passed:
        lines.append("What to do: nothing special; simulate it directly.")
    elif a.structurally_ok:
        lines.append(
            "What to do: dk.reduce_index(model) gives an equivalent index-1 DAE with these "
            "consistency conditions; start from dk.initialize(...), and fight drift with "
            "stabilization='dummy_derivatives', 'projection' or 'baumgarte'."
        )
    else:
        lines.append(
            "What to do: dk.reduce_index(model) repairs cancellations with constant coefficients "
            "by itself (it replaces an equation by a combination in which the leading derivatives "
            "cancel, then reduces; see r.amendments). Where the cancellation depends on "
            "the variables, rewrite the model so that the structure shows the true dependencies."
        )
    return "\n".join(lines)


def _explain_failure(a: Any) -> list[str]:
    """The paragraph on a failed structural analysis: where it fails, what was computed
    instead, and which of the structural numbers are right."""
    n = len(a.equation_offsets)
    blocks = "; ".join(", ".join(b) for b in a.singular_blocks) or "?"
    plural = "s" if len(a.singular_blocks) > 1 else ""
    where = (f"the system Jacobian is singular at the test point in the diagonal block{plural} "
             f"of equations {blocks}, although the structure admits a matching")
    num = a.numeric
    if a.structural_part is None:
        text = (f"Differential index {a.index}, computed NUMERICALLY from the derivative array, "
                f"because structural analysis FAILS here: {where}.")
    else:
        k = len(num.equations) if num is not None else 0
        text = (f"Differential index {a.index}. Structural analysis FAILS in part of the model: "
                f"{where}. The {k} of {n} equations coupled to {'them' if plural else 'it'} "
                f"(sharing unknowns) were analyzed NUMERICALLY from the derivative array: index "
                f"{num.index}, {_count_dof(num.dof)}; the other {n - k} are structurally sound "
                f"(index {a.structural_part[0]}, {_count_dof(a.structural_part[1])}), and the "
                "model's index is the larger, its DOF the sum.")
    idx_ok = a.structural_index == a.index
    dof_ok = a.structural_dof - len(a.declared_invariants) == a.dof
    claims = (
        f"index {a.structural_index}"
        + (" (right)" if idx_ok else f" (wrong: the true index is {a.index})")
        + f" and {_count_dof(a.structural_dof)}"
        + (" (right)" if dof_ok else f" (wrong: the true number is {a.dof})")
    )
    text += f" Structural analysis of the whole model claims {claims}"
    text += ("; the equation offsets of the failing part are not to be trusted." if idx_ok and
             dof_ok else ".")
    text += (" (Typical causes: cancellations such as M*(x1' - x2') appearing in two "
             "equations, a singular mass matrix, or equations whose sum loses a derivative.)")
    lines = [text]
    if num is not None and num.ranks:
        lev = ", ".join(f"level {k}: rank {r} vs {rr} without targets" for k, r, rr in num.ranks)
        lines.append(f"  Derivative array ranks ({lev}).")
    return lines
