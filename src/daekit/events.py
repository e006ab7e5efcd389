"""Events of a model carried to its reduced system, and the model's own switches.

Two kinds of zero-crossing functions reach the simulator:

* **declared events** (:meth:`daekit.Model.event`): written in the model's names; on a
  :class:`~daekit.reduced.ReducedDAE` ``r`` they become expressions of ``r``'s symbols
  ``(t, x, z, u, p)`` through ``r.variables`` (:func:`reduced_events`). This works for every
  reduction (``differentiate`` with or without elimination, ``dummy_derivatives``, the
  Lagrangian index-1 form, Baumgarte and GGL forms, which keep ``r.variables``).
* **switches** inside the equations (:func:`switches`): the conditions of ``if_else``
  (a relation ``a < b``, ``a <= b``, ``a == b``, ``a != b``) and the kinks of ``fabs``,
  ``sign``, ``fmin`` and ``fmax``. They are found by walking CasADi's SX instruction list of
  ``ode``, ``alg`` and the invariants. As Modelica tools do, the simulator integrates with
  every switch *frozen* in the branch it had at the start of a segment (the equations are
  then smooth), watches the switching functions (``b - a`` for ``a < b``; ``a`` for
  ``fabs(a)`` and ``sign(a)``; ``a - b`` for ``fmin(a, b)``, ``fmax(a, b)``), and at a
  crossing stops, flips the branch and restarts: no step is wasted on crawling through the
  discontinuity. :func:`freeze_switches` builds that frozen system: one extra parameter
  per switch holding its branch.

Example
-------
>>> import casadi as ca, daekit as dk
>>> m = dk.Model("switch")
>>> x = m.state("x"); z = m.algebraic("z")
>>> _ = m.equation(m.der(x) - z, name="flow")
>>> _ = m.equation(z - ca.if_else(x > 0.5, 2, 1), name="law")
>>> r = dk.reduce_index(m)
>>> [s.kind for s in switches(r)]
['relation']
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .errors import ModelError
from .model import element_name, parse_name

__all__ = ["ReducedEvent", "Switch", "reduced_events", "switches", "freeze_switches",
           "event_symbols", "branch_values", "SCAN_LIMIT"]


@dataclass
class ReducedEvent:
    """A declared event on a reduced system.

    Attributes
    ----------
    name : str
    expr : casadi.SX
        The event function in ``r``'s symbols ``(t, x, z, u, p)``.
    direction : int
    terminal : bool
    reset : dict of str to casadi.SX
        New values by element name, as expressions of ``r``'s symbols (the pre-event values).
    order : int
        Declaration order (simultaneous events fire in this order).
    """

    name: str
    expr: ca.SX
    direction: int
    terminal: bool
    reset: dict
    order: int


@dataclass
class Switch:
    """One discontinuity inside the equations (see :func:`switches`).

    ``kind`` is ``"relation"`` (an ``if_else`` condition), ``"fabs"``, ``"sign"``, ``"fmin"``
    or ``"fmax"``; ``expr`` the switching function in ``r``'s symbols; ``text`` a short
    printed form for messages.
    """

    kind: str
    expr: ca.SX
    text: str
    branch: ca.SX | None = None  # the branch value (unfrozen) in r's symbols


def _name_map(r) -> tuple[list[ca.SX], list[ca.SX]]:
    """Model symbols -> their expressions in ``r``'s symbols (through ``r.variables``)."""
    model = r.model
    olds, news = [], []
    for var in model.variables.values():
        for order in [0, *sorted(var.ders)]:
            sym = var.der(order)
            for i in range(var.size):
                nm = element_name(var.name, var.size, i, order)
                if nm in r.variables:
                    olds.append(sym[i])
                    news.append(ca.SX(r.variables[nm]))
    return olds, news


def event_symbols(model, expr: ca.SX) -> list[str]:
    """Element names (and ``"t"``) an expression of the model's symbols uses.

    >>> import daekit as dk
    >>> m = dk.examples.pendulum_planar()
    >>> event_symbols(m, m.variables["x"].sym + m.der(m.variables["y"].sym))
    ['x', 'der(y)']
    """
    out = []
    th = model.t.element_hash()
    for s in ca.symvar(expr):
        if s.element_hash() == th:
            out.append("t")
            continue
        hit = model.lookup(s)
        if hit is None:
            raise ModelError(f"model {model.name!r}: the symbol {s.name()!r} is not the model's")
        var, i, order = hit
        out.append(element_name(var.name, var.size, i, order))
    return out


def reduced_events(r) -> list[ReducedEvent]:
    """The model's declared events as expressions of ``r``'s symbols.

    Raises :class:`ModelError` naming the event when it uses a quantity the reduced system does
    not compute (e.g. a third derivative of a position).

    >>> import daekit as dk
    >>> m = dk.examples.pendulum_planar()
    >>> x = m.variables["x"].sym
    >>> _ = m.event(x, name="wall", direction=-1, reset={"der(x)": -m.der(x)})
    >>> for method in ("differentiate", "dummy_derivatives"):
    ...     ev = reduced_events(dk.reduce_index(m, method=method))[0]
    ...     print(ev.name, ev.direction, sorted(ev.reset))
    wall -1 ['der(x)']
    wall -1 ['der(x)']
    """
    model = getattr(r, "model", None)
    if model is None or not getattr(model, "events", None):
        return []
    cache = r.derived("events", lambda r: {})
    if len(model.events) in cache:
        return cache[len(model.events)]
    olds, news = _name_map(r)
    top: dict[str, int] = {}
    for nm in r.variables:
        b, o, _ = parse_name(nm)
        top[b] = max(top.get(b, 0), o)
    known = {s.element_hash() for s in olds} | {model.t.element_hash()}
    out = []
    for k, ev in enumerate(model.events):
        exprs = [ev.expr] + list(ev.reset.values())
        for e, what in zip(exprs, ["the event function"] + [f"reset {n!r}" for n in ev.reset],
                           strict=True):
            for s in ca.symvar(e):
                if s.element_hash() not in known:
                    raise ModelError(
                        f"model {model.name!r}, event {ev.name!r}: {what} uses {s.name()!r}, "
                        f"which the reduced system ({r.method}) does not compute; write it with "
                        "lower derivatives"
                    )
        for key in ev.reset:
            base, order, _ = parse_name(key)
            if key in r.variables and order >= top.get(base, 0) and order > 0:
                raise ModelError(
                    f"model {model.name!r}, event {ev.name!r}: reset {key!r} is the highest "
                    f"derivative of {base!r}, which the equations determine (an acceleration); "
                    "reset positions and velocities only"
                )
            if key not in r.variables:
                raise ModelError(
                    f"model {model.name!r}, event {ev.name!r}: reset {key!r} is not a quantity "
                    f"of the reduced system ({r.method}); reset states or derivatives below the "
                    "highest order (e.g. positions and velocities, not accelerations)"
                )
        subst = ca.substitute(exprs, olds, news) if olds else exprs
        subst = [ca.substitute(e, model.t, r.t) for e in subst]
        out.append(ReducedEvent(ev.name, subst[0], ev.direction, ev.terminal,
                                dict(zip(ev.reset, subst[1:], strict=True)), k))
    cache[len(model.events)] = out
    return out


_RELATIONS = (ca.OP_LT, ca.OP_LE, ca.OP_EQ, ca.OP_NE)
_KINKS = {ca.OP_FABS: "fabs", ca.OP_SIGN: "sign", ca.OP_FMIN: "fmin", ca.OP_FMAX: "fmax"}


def _depends(e: ca.SX, wrt: ca.SX) -> bool:
    return bool(wrt.numel()) and bool(ca.depends_on(e, wrt))


def _replay(r, exprs: list[ca.SX], frozen: bool, limit: int | None = None):
    """Walk the instruction list of ``exprs``; return (switches, outputs, branch symbols).

    With ``frozen`` every switch is replaced by its branch symbol in the rebuilt outputs.
    Beyond ``limit`` instructions nothing is walked and the switches are ``None``."""
    ins = [r.t, r.x, r.z, r.u, r.p]
    out_all = ca.vertcat(*[ca.vec(ca.SX(e)) for e in exprs]) if exprs else ca.SX(0, 1)
    f = ca.Function("switch_walk", ins, [out_all])
    n = f.n_instructions()
    if limit is not None and n > limit:
        return None, exprs, ca.SX(0, 1)
    ops = [f.instruction_id(k) for k in range(n)]
    interesting = set(_RELATIONS) | set(_KINKS)
    if not any(o in interesting for o in ops):
        return [], exprs, ca.SX(0, 1)
    nodes = f.instructions_sx()  # the SX of each instruction's output
    states = ca.vertcat(r.x, r.z)
    found: list[Switch] = []
    seen: dict[int, int] = {}
    work: dict[int, ca.SX] = {}
    branch_syms: list[ca.SX] = []
    symbolic_in = [ca.vec(v) for v in ins]
    result = [None] * int(out_all.numel())
    for k in range(n):
        op = ops[k]
        iin = f.instruction_input(k)
        iout = f.instruction_output(k)
        if op == ca.OP_INPUT:
            work[iout[0]] = symbolic_in[iin[0]][iin[1]]
            continue
        if op == ca.OP_OUTPUT:
            result[iout[1]] = work[iin[0]]
            continue
        if op == ca.OP_CONST:
            work[iout[0]] = ca.SX(f.instruction_constant(k))
            continue
        args = [work[i] for i in iin if i >= 0]
        node = nodes[k]
        sw = None
        if op in _RELATIONS or op in _KINKS:
            a = args[0]
            b = args[1] if len(args) > 1 else None
            if op in _RELATIONS:
                g, kind = b - a, "relation"
            elif op in (ca.OP_FABS, ca.OP_SIGN):
                g, kind = a, _KINKS[op]
            else:
                g, kind = a - b, _KINKS[op]
            if _depends(g, ca.vertcat(r.t, states, r.u)):
                h = node.element_hash()
                if h not in seen:
                    seen[h] = len(found)
                    found.append(Switch(kind, g, str(node)[:80]))
                    branch_syms.append(ca.SX.sym(f"switch{len(found) - 1}"))
                sw = seen[h]
        if sw is not None and found[sw].branch is None:
            a = args[0]
            if op in _RELATIONS:
                found[sw].branch = ca.SX.binary(op, args[0], args[1])
            elif op in (ca.OP_FABS, ca.OP_SIGN):
                found[sw].branch = ca.if_else(a >= 0, 1, -1)
            elif op == ca.OP_FMIN:
                found[sw].branch = a <= args[1]
            else:
                found[sw].branch = a >= args[1]
        if frozen and sw is not None:
            s = branch_syms[sw]
            if op in _RELATIONS:
                # a crisp boolean even if the branch value drifts by rounding (carried as a
                # constant state, IDAS may leave it 1e-27 off 0, which `?:` takes as true)
                val = s > 0.5
            elif op == ca.OP_FABS:
                val = s * args[0]
            elif op == ca.OP_SIGN:
                val = s
            else:  # fmin, fmax: s = 1 picks the first argument
                val = s * args[0] + (1 - s) * args[1]
        elif len(args) == 1:
            val = ca.SX.unary(op, args[0])
        else:
            val = ca.SX.binary(op, args[0], args[1])
        work[iout[0]] = val
    outs = []
    pos = 0
    for e in exprs:
        sz = int(ca.SX(e).numel())
        piece = ca.vertcat(*[result[pos + i] for i in range(sz)]) if sz else ca.SX(0, 1)
        outs.append(piece)
        pos += sz
    return found, outs, (ca.vertcat(*branch_syms) if branch_syms else ca.SX(0, 1))


#: instruction count above which :func:`switches` does not walk the equations unless asked
#: (the walk is Python-level, about 2 microseconds per instruction)
SCAN_LIMIT = 200_000


def switches(r, limit: int | None = None) -> list[Switch] | None:
    """The discontinuities of ``r``'s equations that depend on time, states or inputs.

    Conditions of ``if_else`` and the kinks of ``fabs``, ``sign``, ``fmin``, ``fmax`` in
    ``ode``, ``alg`` and the invariants (the same node used twice counts once); conditions on
    parameters only are not switches. See the module docstring. With ``limit``, equations of
    more than ``limit`` CasADi instructions are not walked and ``None`` is returned (the
    simulator uses :data:`SCAN_LIMIT`: a larger model's switches are not found automatically;
    call ``switches(r)`` yourself, or write the switch as a declared event).

    >>> import casadi as ca
    >>> from daekit.reduced import ReducedDAE
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x")
    >>> r = ReducedDAE(t, x, ca.SX(0, 1), ca.SX(0, 1), ca.SX(0, 1), -ca.fabs(x - 1),
    ...     ca.SX(0, 1), ca.SX(0, 1), [], ["x"], [], [], [], np.zeros(0))
    >>> [(s.kind, str(s.expr)) for s in switches(r)]
    [('fabs', '(x-1)')]
    """
    found, _, _ = _replay(r, [r.ode, r.alg, r.invariants], frozen=False, limit=limit)
    return found


def freeze_switches(r):
    """``(r_frozen, switches)``: ``r`` with every switch replaced by a branch parameter.

    The branch parameters are appended to ``r.p`` (names ``__switch0``, ...): 1 or 0 for a
    relation (true or false), +1 or -1 for ``fabs`` and ``sign``, 1 or 0 for ``fmin``/``fmax``
    (1: the first argument is taken). ``r.variables`` are frozen the same way. Returns ``r``
    itself and ``[]`` when there are no switches.

    >>> import casadi as ca
    >>> from daekit.reduced import ReducedDAE
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x")
    >>> r = ReducedDAE(t, x, ca.SX(0, 1), ca.SX(0, 1), ca.SX(0, 1), -ca.fabs(x - 1),
    ...     ca.SX(0, 1), ca.SX(0, 1), [], ["x"], [], [], [], np.zeros(0))
    >>> rf, sw = freeze_switches(r)
    >>> rf.p_names, str(rf.ode)
    (['__switch0'], '(-(__switch0*(x-1)))')
    """
    import dataclasses

    names = list(r.variables)
    exprs = [r.ode, r.alg, r.invariants] + [ca.SX(r.variables[n]) for n in names]
    plain, _, _ = _replay(r, exprs, frozen=False)
    if not plain:
        return r, []
    found, outs, syms = _replay(r, exprs, frozen=True)
    for s, q in zip(found, plain, strict=True):
        s.branch = q.branch
    # __switchK symbols were created as switch{K}; rename for the parameter list
    pnames = list(r.p_names) + [f"__switch{k}" for k in range(len(found))]
    psyms = [ca.SX.sym(n) for n in pnames[len(r.p_names):]]
    outs = ca.substitute(outs, [syms], [ca.vertcat(*psyms)])
    sw_exprs = ca.substitute([s.expr for s in found], [syms], [ca.vertcat(*psyms)])
    for s, e in zip(found, sw_exprs, strict=True):
        s.expr = e
    variables = dict(zip(names, outs[3:], strict=True))
    info = {**r.info, "switches": found}
    rf = dataclasses.replace(
        r, ode=outs[0], alg=outs[1], invariants=outs[2], variables=variables,
        p=ca.vertcat(r.p, *psyms), p_names=pnames,
        p_values=np.concatenate([np.asarray(r.p_values, float), np.zeros(len(found))]),
        info=info,
    )
    return rf, found


def branch_values(found: list[Switch], r, t, x, z, u, p) -> np.ndarray:
    """Branch parameter values of the switches at a point (``p`` without the branches).

    >>> import casadi as ca
    >>> from daekit.reduced import ReducedDAE
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x")
    >>> r = ReducedDAE(t, x, ca.SX(0, 1), ca.SX(0, 1), ca.SX(0, 1), -ca.fabs(x - 1),
    ...     ca.SX(0, 1), ca.SX(0, 1), [], ["x"], [], [], [], np.zeros(0))
    >>> branch_values(switches(r), r, 0.0, [3.0], [], [], []).tolist()
    [1.0]
    >>> branch_values(switches(r), r, 0.0, [0.5], [], [], []).tolist()
    [-1.0]
    """
    if not found:
        return np.zeros(0)
    f = ca.Function("switch_eval", [r.t, r.x, r.z, r.u, r.p],
                    [ca.vertcat(*[s.branch for s in found])])
    return np.asarray(f(t, x, z, u, p), dtype=float).ravel()
