"""A readable account of a reduced DAE (what ``daekit reduce`` prints)."""

from __future__ import annotations

import casadi as ca

from ..reduced import ReducedDAE
from ..wording import count

__all__ = ["format_reduced"]


def _expr(e: ca.SX, limit: int) -> str:
    s = str(e)
    return s if len(s) <= limit else s[: limit - 5] + " ..."


def format_reduced(r: ReducedDAE, max_rows: int = 60, width: int = 160) -> str:
    """The reduced equations, invariants and state selection of ``r`` as plain text.

    At most ``max_rows`` rows per section are listed (the rest is counted); expressions are
    cut at ``width`` characters.

    >>> import daekit as dk
    >>> from daekit.reduction import reduce_index
    >>> text = format_reduced(reduce_index(dk.examples.pendulum_planar()))
    >>> print(text.splitlines()[0])
    pendulum_planar reduced by differentiate: 4 states, 1 algebraic unknown, 2 invariants
    >>> "0 = d2/dt2 rod:" in text
    True
    """
    from .accept import as_reduced

    r = as_reduced(r, "format_reduced")
    name = getattr(r.model, "name", "model")
    out = [
        f"{name} reduced by {r.method}: {count(r.nx, 'state')}, "
        f"{count(r.nz, 'algebraic unknown')}, {count(len(r.invariant_names), 'invariant')}"
        + (f", stabilization {r.stabilization}" if r.stabilization else "")
    ]
    if r.index >= 2:
        out.append(f"  (index {r.index} form)")
    for note in r.amendments:
        out.append(f"  note: {note}")
    elim = r.eliminated
    if elim:
        shown = [f"{e['variable']} = {_expr(e['expression'], 40)} ({e['equation']})"
                 for e in elim[:max_rows]]
        more = f", ... ({len(elim) - max_rows} more)" if len(elim) > max_rows else ""
        out.append(f"  eliminated (given explicitly by an equation): {', '.join(shown)}{more}")

    def section(title, rows):
        out.append("")
        out.append(title)
        for k, row in enumerate(rows):
            if k == max_rows:
                out.append(f"  ... ({len(rows) - max_rows} more)")
                break
            out.append("  " + row)

    section("States x:", [", ".join(r.x_names)] if r.x_names else ["(none)"])
    section("Algebraic unknowns z:", [", ".join(r.z_names)] if r.z_names else ["(none)"])
    if r.u_names:
        section("Inputs u:", [", ".join(r.u_names)])
    if r.input_derivatives:
        out.append(f"  input derivatives needed: {', '.join(r.input_derivatives)}")
    section(
        "Differential equations x' = ode:",
        [f"d/dt {n} = {_expr(r.ode[i], width)}" for i, n in enumerate(r.x_names[:max_rows + 1])],
    )
    names = r.alg_labels
    section(
        "Algebraic equations 0 = alg:",
        [f"0 = {n}: {_expr(r.alg[i], width)}" for i, n in enumerate(names[:max_rows + 1])],
    )
    section(
        "Invariants (must hold at the initial time):",
        [f"0 = {n}: {_expr(r.invariants[i], width)}"
         for i, n in enumerate(r.invariant_names[:max_rows + 1])] or ["(none)"],
    )
    sel = r.state_selection
    if sel:
        rows = [f"states: {', '.join(sel['states']) or '(none)'}",
                f"dummies: {', '.join(sel['dummies']) or '(none)'}",
                f"condition at selection: {sel['condition']:.3g}"]
        for st in sel["stages"]:
            rows.append(
                f"stage {st['stage']}: equations {', '.join(st['equations'])} -> dummies "
                f"{', '.join(st['dummies'])} among {', '.join(st['candidates'])} "
                f"(condition {st['condition']:.3g})"
            )
        rows.append(f"rule: {sel.get('rule', '')}")
        section("State selection (dummy derivatives):", rows)
    return "\n".join(out)
