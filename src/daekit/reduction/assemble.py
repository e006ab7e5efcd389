"""The reassembly step of index reduction: a :class:`~daekit.reduced.ReducedDAE` from an
expansion (Pryce's differentiated equations) and a choice of states, algebraic unknowns,
equations and invariants.

Both Pryce's scheme (:mod:`daekit.reduction.reduce`) and dummy derivatives
(:mod:`daekit.reduction.dummy`) decide *which* derivatives are states; this module turns the
decision into symbols, names and the variable map (ModelingToolkit's StateSelection.jl keeps
the same split: algorithms on the integer structure, then one step that reassembles
equations).

>>> import daekit as dk
>>> from daekit.reduction.differentiate import expand
>>> ex = expand(dk.examples.pendulum_planar())
>>> pair_names(ex, state_pairs(ex, None))
['x', 'der(x)', 'y', 'der(y)']
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model import element_name
from ..reduced import ReducedDAE
from .differentiate import Expansion, derivative_name

__all__ = ["state_pairs", "pair_symbols", "top_equations", "invariant_rows", "element_names",
           "pair_names", "assemble", "all_symbols"]


def state_pairs(ex: Expansion, skip):
    """States x_j^(k), k < d_j, grouped by variable then order.

    ``skip``: None or a boolean function (j, k) -> the derivative is not a state (a dummy
    derivative, or an eliminated one). Returns the list of (j, k).
    """
    d = np.asarray(ex.d, dtype=np.int64)
    js_all, ks_all = [], []
    j0 = 0
    for var in ex.model.unknown_variables:
        js = np.arange(j0, j0 + var.size, dtype=np.int64)
        j0 += var.size
        dv = d[js]
        for k in range(int(dv.max()) if dv.size else 0):
            sel = js[dv > k]
            js_all.append(sel)
            ks_all.append(np.full(sel.size, k, dtype=np.int64))
    if not js_all:
        return []
    out = list(zip(np.concatenate(js_all).tolist(), np.concatenate(ks_all).tolist()))
    if skip is not None:
        out = [jk for jk in out if not skip(*jk)]
    return out


def pair_symbols(ex: Expansion, pairs, shift: int = 0) -> ca.SX:
    """Symbols ``x_j^(k + shift)`` for the pairs ``(j, k)``, in order."""
    return ex.model.symbols_at([j for j, _ in pairs], [k + shift for _, k in pairs])


def top_equations(ex: Expansion) -> ca.SX:
    """F_i^(c_i) for all i, in equation order."""
    n = ex.n
    parts = []
    idx_of = np.empty(n, dtype=np.int64)
    offset = 0
    # concatenate all levels once, then pick one row per equation
    for k, rk in enumerate(ex.rows):
        top = rk[ex.c[rk] == k]
        idx_of[top] = offset + ex.pos[k][top]
        offset += len(rk)
    parts = ca.vertcat(*ex.levels)
    return parts[idx_of.tolist()]


def invariant_rows(ex: Expansion, skip=()):
    """F_i^(k), k < c_i, ordered by equation then k; their names; and the chains.

    Equations in ``skip`` (eliminated) are left out; a chain's ``"alg"`` is the row of its
    top equation ``F_i^(c_i)`` among the algebraic equations that are kept.
    """
    n = ex.n
    offs = np.cumsum([0] + [len(r) for r in ex.rows])
    idx, names, chains = [], [], []
    alg_row = 0
    for i in range(n):
        if i in skip:
            continue
        alg_row += 1
        ci = int(ex.c[i])
        if ci == 0:
            continue
        chain = []
        for k in range(ci):
            chain.append(len(idx))
            idx.append(int(offs[k] + ex.pos[k][i]))
            names.append(derivative_name(ex.equation_names[i], k))
        chains.append(
            {"equation": ex.equation_names[i], "row": i, "invariants": chain, "alg": alg_row - 1}
        )
    allrows = ca.vertcat(*ex.levels)
    inv = allrows[idx] if idx else ca.SX(0, 1)
    return inv, names, chains


def element_names(var, k: int) -> list[str]:
    """``["der(p)[0]", "der(p)[1]", ...]``: the names of ``var``'s order-``k`` elements."""
    base = element_name(var.name, 1, 0, k)
    return [base] if var.size == 1 else [f"{base}[{i}]" for i in range(var.size)]


def pair_names(ex: Expansion, pairs) -> list[str]:
    """Original names ``"der(p)[0]"`` of the pairs ``(j, k)``."""
    pairs = list(pairs)
    if not pairs:
        return []
    jk = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    var_of, elem_of = ex.model.unknown_arrays()  # ex.unknowns are the model's, in order
    variables = ex.model.unknown_variables
    # every name of each (variable, order) met, once; then one gather
    key = var_of[jk[:, 0]] * (int(jk[:, 1].max()) + 1) + jk[:, 1]
    uniq, inv = np.unique(key, return_inverse=True)
    names: list[str] = []
    base = np.empty(uniq.size, dtype=np.int64)
    width = int(jk[:, 1].max()) + 1
    for g, kk in enumerate(uniq.tolist()):
        base[g] = len(names)
        names += element_names(variables[kk // width], kk % width)
    flat = np.array(names, dtype=object)
    return flat[base[inv] + elem_of[jk[:, 0]]].tolist()


def assemble(ex, states, zpairs, alg, invariants, invariant_names, method):
    """ReducedDAE from the pieces: states ``x_j^(k)`` (pairs) with ``(x_j^(k))' = x_j^(k+1)``,
    algebraic unknowns (pairs), equations; fills u (with input derivatives), p and the
    variable map."""
    model = ex.model
    x = pair_symbols(ex, states)
    ode = pair_symbols(ex, states, shift=1)
    x_names = pair_names(ex, states)
    z = pair_symbols(ex, zpairs)
    z_names = pair_names(ex, zpairs)
    # inputs: the controls, then their derivatives up to the order needed
    u_parts, u_names, input_derivatives = [], [], []
    for var in model.controls:
        u_parts.append(var.sym)
        u_names += [var.element(i) for i in range(var.size)]
    for var in model.controls:
        for k in range(1, ex.control_orders.get(var.name, 0) + 1):
            u_parts.append(var.der(k))
            u_names += [var.element(i, k) for i in range(var.size)]
            input_derivatives.append(element_name(var.name, 1, 0, k))
    u = ca.vertcat(*u_parts) if u_parts else ca.SX(0, 1)
    p = model.parameter_symbols
    p_names = [v.element(i) for v in model.parameters for i in range(v.size)]
    variables: dict[str, ca.SX] = {}
    # whole vectors: one vertsplit per variable and order, names made in one comprehension
    j0 = 0
    for var in model.unknown_variables:
        dj = ex.d[j0:j0 + var.size]
        j0 += var.size
        for k in range(int(dj.max()) + 1 if dj.size else 0):
            elems = ca.vertsplit(var.der(k))
            names = element_names(var, k)
            if bool(np.all(dj >= k)):
                variables.update(zip(names, elems, strict=True))
            else:
                variables.update((names[i], elems[i]) for i in np.nonzero(dj >= k)[0])
    for var in model.controls:
        for k in range(ex.control_orders.get(var.name, 0) + 1):
            variables.update(zip(element_names(var, k), ca.vertsplit(var.der(k)), strict=True))
    for var in model.parameters:
        variables.update(zip(element_names(var, 0), ca.vertsplit(var.sym), strict=True))
    return ReducedDAE(
        t=model.t,
        x=x,
        z=z,
        u=u,
        p=p,
        ode=ode,
        alg=alg,
        invariants=invariants,
        invariant_names=invariant_names,
        x_names=x_names,
        z_names=z_names,
        u_names=u_names,
        p_names=p_names,
        p_values=model.parameter_values.copy(),
        variables=variables,
        input_derivatives=input_derivatives,
        control_names=[v.name for v in model.controls],
        method=method,
        model=model,
    )


def all_symbols(ex: Expansion):
    """All unknown symbols up to order d_j and control symbols up to the needed order."""
    pairs = [(j, k) for j in range(ex.n) for k in range(int(ex.d[j]) + 1)]
    X = pair_symbols(ex, pairs)
    U = [var.der(k) for var in ex.model.controls
         for k in range(ex.control_orders.get(var.name, 0) + 1)]
    return X, (ca.vertcat(*U) if U else ca.SX(0, 1))
