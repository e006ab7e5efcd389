"""The system an OCP transcription works on: a ReducedDAE plus chains of integrators for inputs.

:func:`augment` turns a :class:`~daekit.reduced.ReducedDAE` into an :class:`Augmented` system
``x' = ode(t, x, z, w, p)``, ``0 = alg(t, x, z, w, p)`` whose inputs ``w`` are the decision
controls. Where the reduction needs derivatives of an input (``r.input_derivatives``, e.g.
``u'``, ``u''``), the input and its lower derivatives become states of a chain of integrators
``u' = u1``, ``u1' = u2`` and the highest derivative ``u''`` becomes the decision variable.

It also maps the user's expressions, written in the original model's symbols (``m.der(p)``,
controls, parameters, ``m.t``), to expressions in ``t, x, z, w, p`` through ``r.variables``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..errors import ModelError, OCPError
from ..model import NameNotFoundError, element_name, parse_name, select_name
from ..reduced import Numel, ReducedDAE

__all__ = ["Augmented", "augment"]


@dataclass
class Augmented:
    """An index-1 system whose inputs are the decision controls (see the module docstring)."""

    t: ca.SX
    x: ca.SX
    z: ca.SX
    w: ca.SX
    p: ca.SX
    ode: ca.SX
    alg: ca.SX
    inv: ca.SX
    inv_names: list[str]
    x_names: list[str]
    z_names: list[str]
    w_names: list[str]
    p_names: list[str]
    p_values: np.ndarray
    names: dict[str, ca.SX]
    reduced: ReducedDAE
    chains: list[tuple[str, int]] = field(default_factory=list)
    _index: dict[int, tuple[str, int]] = field(default_factory=dict)

    nx = Numel("x", "Number of differential states (chains included).")
    nz = Numel("z", "Number of algebraic unknowns.")
    nw = Numel("w", "Number of controls (the highest input derivatives).")
    n_p = Numel("p", "Number of parameters.")

    def which(self, expr: ca.SX) -> tuple[str, int] | None:
        """``("x", i)``, ``("z", i)``, ``("w", i)`` or ``("p", i)`` when ``expr`` is exactly one
        decision symbol, else None."""
        if expr.numel() != 1 or not expr.is_symbolic():
            return None
        return self._index.get(expr.element_hash())

    # ------------------------------------------------------------------ names
    def elements(self, name: str, what: str = "name") -> list[str]:
        """Element names meant by ``name`` (``"p"`` -> ``["p[0]", "p[1]"]``); OCPError if none."""
        return self.select(name, what)[0]

    def select(self, name: str, what: str = "name") -> tuple[list[str], bool]:
        """:func:`daekit.model.select_name` on the model's names; OCPError if none."""
        if not isinstance(name, str):
            raise OCPError(f"{what}: expected a variable name (a string), got {name!r}")
        try:
            return select_name(name.replace(" ", ""), self.names, "the model")
        except NameNotFoundError as exc:
            raise OCPError(
                f"{what}: {exc} (elements as 'p[0]', derivatives as 'der(p)', 'der(p)[0]', "
                "'der(p,2)')"
            ) from None

    def expr_of(self, name: str, what: str = "name") -> ca.SX:
        """The column of expressions (in t, x, z, w, p) of the elements of ``name``."""
        return ca.vertcat(*[self.names[e] for e in self.elements(name, what)])

    def map_expr(self, expr, what: str) -> ca.SX:
        """Rewrite a user expression (model symbols or the reduced system's) in t, x, z, w, p."""
        if isinstance(expr, ca.MX):
            raise OCPError(
                f"{what}: MX expressions are not supported; build it from the SX symbols of the "
                "model (m.state, m.der, m.control, m.parameter, m.t)"
            )
        try:
            ex = expr if isinstance(expr, ca.SX) else ca.SX(ca.DM(np.asarray(expr, dtype=float)))
        except Exception as exc:  # noqa: BLE001 - turned into a daekit error
            raise OCPError(f"{what}: cannot read {expr!r} as an expression ({exc})") from None
        ex = ca.vec(ca.densify(ex))
        r = self.reduced
        model = r.model
        own = self._own_hashes()
        src, dst = [], []
        for s in ca.symvar(ex):
            h = s.element_hash()
            if h in own:
                continue
            if model is not None and hasattr(model, "t") and h == model.t.element_hash():
                src.append(s)
                dst.append(self.t)
                continue
            hit = model.lookup(s) if model is not None and hasattr(model, "lookup") else None
            if hit is None:
                raise OCPError(
                    f"{what} uses the symbol {s.name()!r}, which is not a variable of the model; "
                    "write it with the symbols the model returned (m.state, m.der, m.control, "
                    "m.parameter, m.t)"
                )
            var, idx, order = hit
            ename = element_name(var.name, var.size, idx, order)
            if ename not in self.names:
                raise OCPError(
                    f"{what} uses {ename!r}, which the reduced system does not define (the "
                    "reduction keeps derivatives only up to the order the model needs); write "
                    "the expression with lower derivatives"
                )
            src.append(s)
            dst.append(self.names[ename])
        if src:
            ex = ca.substitute([ex], [ca.vertcat(*src)], [ca.vertcat(*dst)])[0]
        return ex

    def _own_hashes(self) -> set[int]:
        out = {self.t.element_hash()}
        for v in (self.x, self.z, self.w, self.p):
            out.update(v[i].element_hash() for i in range(v.numel()))
        return out


def augment(r: ReducedDAE) -> Augmented:
    """Chains of integrators for the input derivatives the reduction needs; see module docstring."""
    # group input elements by (base element, order)
    groups: dict[tuple[str, int | None], dict[int, int]] = {}
    order_of: list[tuple[tuple[str, int | None], int]] = []
    for i, n in enumerate(r.u_names):
        try:
            base, order, idx = parse_name(n)
        except ModelError:
            base, order, idx = n, 0, None
        key = (base, idx)
        groups.setdefault(key, {})[order] = i
        order_of.append((key, order))
    u_sub = [None] * r.nu
    xs, odes, x_names = [], [], []
    ws, w_names = [], []
    chains: list[tuple[str, int]] = []
    for key, orders in groups.items():
        base, idx = key
        K = max(orders)
        def ename(k: int, base=base, idx=idx) -> str:
            nm = element_name(base, 1, 0, k)
            return nm if idx is None else f"{nm}[{idx}]"
        if K == 0:
            i = orders[0]
            ws.append(r.u[i])
            w_names.append(r.u_names[i])
            u_sub[i] = r.u[i]
            continue
        chain = [ca.SX.sym(ename(k)) for k in range(K)]
        top = ca.SX.sym(ename(K))
        for k in range(K):
            xs.append(chain[k])
            x_names.append(ename(k))
            odes.append(chain[k + 1] if k + 1 < K else top)
        ws.append(top)
        w_names.append(ename(K))
        chains.append((ename(0), K))
        for k, i in orders.items():
            u_sub[i] = chain[k] if k < K else top
    w = ca.vertcat(*ws) if ws else ca.SX(0, 1)
    u_new = ca.vertcat(*u_sub) if r.nu else ca.SX(0, 1)

    def sub(e: ca.SX) -> ca.SX:
        if r.nu == 0 or e.numel() == 0 or not chains:  # no chain: u is its own substitute
            return e
        return ca.substitute([e], [r.u], [u_new])[0]

    x = ca.vertcat(r.x, *xs)
    ode = ca.vertcat(sub(r.ode), *odes)
    names: dict[str, ca.SX] = {}
    for n, e in r.variables.items():
        names[n] = sub(ca.SX(e))
    for nm, v in zip(r.x_names, ca.vertsplit(r.x), strict=True):
        names.setdefault(nm, v)
    for nm, v in zip(r.z_names, ca.vertsplit(r.z), strict=True):
        names.setdefault(nm, v)
    for i, nm in enumerate(r.u_names):
        names[nm] = u_new[i]
    for nm, v in zip(x_names, xs, strict=True):
        names[nm] = v
    for nm, v in zip(r.p_names, ca.vertsplit(r.p), strict=True):
        names.setdefault(nm, v)
    aug = Augmented(
        t=r.t,
        x=x,
        z=r.z,
        w=w,
        p=r.p,
        ode=ode,
        alg=sub(r.alg),
        inv=sub(ca.vec(r.invariants)) if r.invariants.numel() else ca.SX(0, 1),
        inv_names=list(r.invariant_names),
        x_names=list(r.x_names) + x_names,
        z_names=list(r.z_names),
        w_names=w_names,
        p_names=list(r.p_names),
        p_values=np.asarray(r.p_values, dtype=float).ravel(),
        names=names,
        reduced=r,
        chains=chains,
    )
    for kind, v in (("x", aug.x), ("z", aug.z), ("w", aug.w), ("p", aug.p)):
        for i in range(v.numel()):
            aug._index[v[i].element_hash()] = (kind, i)
    return aug
