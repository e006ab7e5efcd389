"""Total time derivatives of model expressions, by directional derivatives.

The total time derivative of an expression ``e(t, x, x', ..., u, u', ..., p)`` is the
directional derivative of ``e`` in the direction of the *shift* vector, which maps every
symbol ``x^(k)`` to ``x^(k+1)``, the time ``t`` to 1, every input derivative ``u^(k)`` to
``u^(k+1)`` and the parameters to 0:

    de/dt = (de/dV) S,    V = (t, x, x', ..., u, u', ...),   S = (1, x', x'', ..., u', u'', ...)

CasADi computes it in one forward sweep (``casadi.jtimes``), for a whole vector of equations at
once, without ever forming a Jacobian. Derivative symbols come from
:meth:`daekit.model.Variable.der` (created on demand).

Example
-------
>>> import casadi as ca, daekit as dk
>>> from daekit.reduction import time_derivative
>>> m = dk.Model("demo")
>>> x = m.state("x"); u = m.control("u")
>>> str(time_derivative(x * u + m.t, m))
'(((u*der(x))+(x*der(u)))+1)'
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..errors import ReductionError
from ..model import Model, Variable
from ..wording import derivative_name

__all__ = ["time_derivative", "Expansion", "expand", "derivative_name"]


def _registry(model: Model) -> dict[int, tuple[Variable, int, int]]:
    reg: dict[int, tuple[Variable, int, int]] = {}
    for var in model.variables.values():
        for order in [0, *sorted(var.ders)]:
            s = var.der(order)
            for i in range(var.size):
                reg[s[i].element_hash()] = (var, i, order)
    return reg


def time_derivative(expr, model: Model, k: int = 1) -> ca.SX:
    """The ``k``-th total time derivative of an expression in a model's symbols.

    Works for any SX expression built from the model's time, variables (and their derivative
    symbols), controls and parameters; new derivative symbols are created as needed. For the
    derivative of many equations at once, :func:`expand` is faster (one vectorized sweep).

    >>> import daekit as dk
    >>> m = dk.Model("d"); x = m.state("x")
    >>> str(time_derivative(x**2, m, 2))
    '((der(x)*(2.*der(x)))+((2.*x)*der(x,2)))'
    """
    e = ca.SX(expr)
    for _ in range(int(k)):
        reg = _registry(model)
        syms = ca.symvar(e)
        if not syms:
            return ca.SX.zeros(e.shape)
        shift = []
        t_hash = model.t.element_hash()
        for s in syms:
            h = s.element_hash()
            if h == t_hash:
                shift.append(ca.SX(1))
                continue
            hit = reg.get(h)
            if hit is None:
                raise ReductionError(
                    f"model {model.name!r}: cannot differentiate with respect to time: the symbol "
                    f"{s.name()!r} is not a variable of this model"
                )
            var, i, order = hit
            if var.kind == "parameter":
                shift.append(ca.SX(0))
            else:
                shift.append(var.der(order + 1)[i])
        e = ca.jtimes(e, ca.vertcat(*syms), ca.vertcat(*shift))
    return e


@dataclass
class Expansion:
    """Equations and their time derivatives, driven by Pryce's offsets.

    ``levels[k]`` holds ``F_i^(k)`` for the equation elements ``rows[k]`` (those with
    ``c_i >= k``); ``unknowns[j] = (variable, element)``; ``c``, ``d`` are the equation and
    variable offsets; ``control_orders[name]`` the highest derivative of each control the
    differentiated equations use.
    """

    model: Model
    unknowns: list[tuple[Variable, int]]
    c: np.ndarray
    d: np.ndarray
    levels: list[ca.SX]
    rows: list[np.ndarray]
    control_orders: dict[str, int]
    equation_names: list[str]
    unknown_names: list[str]
    pos: list[np.ndarray] = field(default_factory=list)  # pos[k][i] = row of i in levels[k]
    # transversal[i]: the unknown matched to equation i (Pryce's highest-value transversal; it
    # lies on the pattern of the system Jacobian, so it orders that matrix block triangularly)
    transversal: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def n(self) -> int:
        return len(self.unknowns)

    def equation(self, k: int, rows) -> ca.SX:
        """``F_i^(k)`` for the equation elements ``rows`` (each must have ``c_i >= k``)."""
        return self.levels[k][self.pos[k][np.asarray(rows, dtype=np.int64)].tolist()]

    def unknown(self, order_of, js) -> ca.SX:
        """Symbols ``x_j^(order_of[j])`` for unknowns ``js`` (``order_of``: array or function)."""
        js = [int(j) for j in js]
        orders = [order_of(j) if callable(order_of) else order_of[j] for j in js]
        return self.model.symbols_at(js, orders)


def sigma_offsets(model: Model, validate: bool = True):
    """Validate the model and return Pryce's (transversal, c, d) for its Sigma matrix."""
    model = Model.require(model, "reduce_index")
    if validate:
        model.validate()  # StructuralError naming the equations at fault
    try:
        s = model.sigma()
    except ValueError as exc:  # pragma: no cover - validate() catches structural singularity
        raise ReductionError(f"model {model.name!r}: structural analysis failed ({exc})") from None
    return (np.array(s.transversal), np.array(s.c, dtype=np.int64),
            np.array(s.d, dtype=np.int64))


def expand(model: Model, validate: bool = True) -> Expansion:
    """Differentiate every equation ``F_i`` of ``model`` ``c_i`` times (Pryce's offsets).

    One ``casadi.jtimes`` call per differentiation level, over all equations of that level.
    Made once per model until it changes (:meth:`daekit.Model.memo`: analysis and reduction
    share it; consumers do not modify it).
    """
    model = Model.require(model, "reduce_index")
    if validate:
        model.validate()  # StructuralError naming the equations at fault
    return model.memo("expansion", lambda: _expand(model))


def _expand(model: Model) -> Expansion:
    transversal, c, d = sigma_offsets(model, validate=False)
    unknowns = model.unknowns
    n = len(unknowns)
    F = model.residual
    maxc = int(c.max()) if n else 0

    # shift vectors: unknowns x_j^(k) -> x_j^(k+1) for k < d_j
    V, S = [model.t], [ca.SX(1)]
    start = 0
    for var in model.unknown_variables:
        dv = d[start : start + var.size]
        start += var.size
        for k in range(int(dv.max()) if dv.size else 0):
            idx = np.nonzero(dv > k)[0].tolist()
            V.append(var.der(k)[idx])
            S.append(var.der(k + 1)[idx])

    # controls: highest order used by F_i is o_i, by F_i^(c_i) it is o_i + c_i
    control_orders: dict[str, int] = {}
    for var in model.controls:
        top = -1
        for o in [0, *sorted(var.ders)]:
            r, _ = ca.jacobian_sparsity(F, var.der(o)).get_triplet()
            if r:
                top = max(top, o + int(c[np.asarray(r)].max()))
        if top < 0:
            top = max([0, *var.ders])
        control_orders[var.name] = top
        for k in range(top):
            V.append(var.der(k))
            S.append(var.der(k + 1))
    V = ca.vertcat(*V)
    S = ca.vertcat(*S)

    levels = [F]
    rows = [np.arange(n, dtype=np.int64)]
    pos = []
    for k in range(1, maxc + 1):
        rk = np.nonzero(c >= k)[0]
        prev_pos = np.full(n, -1, dtype=np.int64)
        prev_pos[rows[-1]] = np.arange(len(rows[-1]))
        sub = levels[-1][prev_pos[rk].tolist()] if len(rk) < len(rows[-1]) else levels[-1]
        levels.append(ca.jtimes(sub, V, S))
        rows.append(rk)
    for rk in rows:
        p = np.full(n, -1, dtype=np.int64)
        p[rk] = np.arange(len(rk))
        pos.append(p)
    return Expansion(
        model=model,
        unknowns=unknowns,
        c=c,
        d=d,
        levels=levels,
        rows=rows,
        control_orders=control_orders,
        equation_names=model.equation_names,
        unknown_names=model.unknown_names,
        pos=pos,
        transversal=np.asarray(transversal, dtype=np.int64),
    )
