"""The compiled optimal control problem: what :meth:`daekit.ocp.OCP.compile` returns.

:class:`Problem` is a frozen snapshot of an OCP statement turned into CasADi functions: the
objective terms, the simple bounds of the decision symbols, the path constraints, the boundary
conditions as a function of the end points ``(v0, vT, p, T)`` (``v = (x, z, w)``), the manifold
``[alg; invariants]`` with its Jacobian, and the order of preference of the conditions. The
transcriptions, the guess, the boundary analysis, the IPOPT run and the report read only this
object; changing the statement afterwards (``ocp.final(...)``) does not change it.

>>> import daekit as dk
>>> m = dk.Model("cart"); s = m.state("s"); u = m.control("u")
>>> _ = m.equation(m.der(s, 2) - u, name="newton")
>>> ocp = dk.OCP(m, t_final=1.0, intervals=4).minimize(integral=u**2)
>>> prob = ocp.initial({"s": 0}).final({"s": 1}).compile()
>>> prob.bc_labels, prob.intervals
(['initial s', 'final s'], 4)
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import OCPError
from ..numerics import DenseFunction
from .problem import Augmented

__all__ = ["Problem", "compile_problem", "Condition"]


@dataclass(frozen=True)
class Condition:
    """One boundary condition as stated: ``kind`` ("initial", "final", "periodic"), its label
    (``"final p[1]"``), the expression (in the augmented system's symbols) and the value."""

    kind: str
    label: str
    expr: ca.SX
    value: float


@dataclass(frozen=True)
class Problem:
    """A compiled OCP (see the module docstring); built by :func:`compile_problem`."""

    aug: Augmented
    name: str
    alg_names: list[str]
    method: str
    intervals: int
    degree: int
    control_mode: str
    verbose: bool
    solver_options: dict
    integrator_options: dict
    T_free: tuple[float, float, float] | None
    T_fixed: float | None
    T_guess: float
    free_params: dict
    p_values: np.ndarray
    default_guess: dict | None
    lagrange: ca.SX
    has_lagrange: bool
    has_mayer: bool
    mayer_fun: ca.Function | None
    lb: dict
    ub: dict
    path_fun: ca.Function | None
    path_lb: np.ndarray
    path_ub: np.ndarray
    path_labels: list[str]
    conditions: list[Condition]
    bc_fun: ca.Function
    bc_jac: ca.Function
    man_fun: ca.Function
    man_jac: ca.Function
    ends_fun: ca.Function
    bc_pref: list[int]
    bc_linear: list[bool]

    @property
    def bc_labels(self) -> list[str]:
        return [c.label for c in self.conditions]

    @property
    def bc_kinds(self) -> list[str]:
        return [c.kind for c in self.conditions]

    @property
    def man_names(self) -> list[str]:
        """Names of the manifold rows ``[alg; invariants]``: the model's equation names."""
        return [f"equation {n!r}" for n in self.alg_names] + [
            f"invariant {n!r}" for n in self.aug.inv_names]

    def model_fun(self) -> ca.Function:
        """``(t, x, z, w, p) -> (ode, alg, lagrange)``, built once per compiled problem (the
        transcriptions, the guess and the benchmarks share it)."""
        f = self.__dict__.get("_model_fun")
        if f is None:
            a = self.aug
            f = ca.Function("f", [a.t, a.x, a.z, a.w, a.p], [a.ode, a.alg, self.lagrange])
            self.__dict__["_model_fun"] = f
        return f

    def inv_fun(self) -> ca.Function:
        """``(t, x, z, w, p) -> invariants``, built once per compiled problem."""
        f = self.__dict__.get("_inv_fun")
        if f is None:
            a = self.aug
            f = ca.Function("inv", [a.t, a.x, a.z, a.w, a.p], [a.inv])
            self.__dict__["_inv_fun"] = f
        return f

    def dense(self, name: str) -> DenseFunction:
        """The function field ``name`` (``"ends_fun"``, ``"bc_fun"``, ``"bc_jac"``,
        ``"man_jac"``, ...) as a :class:`~daekit.numerics.DenseFunction` (NumPy in and out
        through its buffers), made once per compiled problem: the boundary analysis, its
        re-solve and the guess's projections share them.

        >>> import daekit as dk
        >>> m = dk.Model("cart"); s = m.state("s"); u = m.control("u")
        >>> _ = m.equation(m.der(s, 2) - u, name="newton")
        >>> prob = dk.OCP(m, t_final=1.0).minimize(integral=u**2).final({"s": 1}).compile()
        >>> prob.dense("bc_fun") is prob.dense("bc_fun")
        True
        """
        made = self.__dict__.setdefault("_dense", {})
        f = made.get(name)
        if f is None:
            f = made[name] = DenseFunction(getattr(self, name))
        return f

    def simple_bounds(self):
        return (self.lb["x"], self.ub["x"], self.lb["z"], self.ub["z"],
                self.lb["w"], self.ub["w"])

    def p_guess(self) -> np.ndarray:
        p = self.p_values.copy()
        for i, nm in enumerate(self.aug.p_names):
            if nm in self.free_params:
                p[i] = self.free_params[nm][2]
        return p

    def structure_key(self, kept) -> tuple:
        """What decides the NLP's variables and rows (a warm start reuses the decision vector
        when all but the boundary selection, the last entry, agree)."""
        return (self.method, self.intervals, self.degree, self.control_mode,
                self.T_free is not None, tuple(sorted(self.free_params)), tuple(kept))

    def add_path(self, B, t, X, Z, W, P, frac) -> None:
        if self.path_fun is not None:
            B.con(self.path_fun(t, X, Z, W, P), self.path_lb, self.path_ub,
                  "path constraints", frac, "path", self.path_labels)

    def add_boundary(self, B, v0, vT, P, T, kept, selectors=(), pins=()) -> None:
        """The kept conditions as equalities; ``selectors`` ``(index, lo, hi)`` as the
        inequalities ``lo <= c <= hi`` that keep a branch-selecting condition; ``pins``
        ``(end, i, value, label)``: ``v_end[i] = value`` at an isolated degenerate end point
        (see :mod:`daekit.ocp.boundary`)."""
        if pins:
            ends = {"initial": v0, "final": vT}
            B.con(ca.vertcat(*[ends[e][i] - val for e, i, val, _ in pins]), 0.0, 0.0,
                  "boundary conditions (end point)", None, "boundary",
                  [lab for *_, lab in pins])
        if not kept and not selectors:
            return
        rows = self.bc_fun(v0, vT, P, T)
        labels = self.bc_labels
        if kept:
            B.con(ca.vertcat(*[rows[i] for i in kept]), 0.0, 0.0, "boundary conditions", None,
                  "boundary", [labels[i] for i in kept])
        if selectors:
            B.con(ca.vertcat(*[rows[i] for i, _, _ in selectors]),
                  np.array([lo for _, lo, _ in selectors]),
                  np.array([hi for _, _, hi in selectors]), "branch of boundary conditions",
                  None, "boundary", [labels[i] + " (branch)" for i, _, _ in selectors])


def derivative_levels(a: Augmented) -> dict[tuple[str, int], int]:
    """Derivative level of every decision symbol: 0 for positions, 1 for velocities...

    A state ``x_i`` with ``x_j' = x_i`` (``p' = v``, or the state ``der(p)``) is one level
    above ``x_j``; an algebraic unknown or control named ``der(q, k)`` is ``k`` levels above
    ``q`` (``der(v)``: acceleration, level 2); other algebraic unknowns one level above the
    highest state; controls and parameters level 0.
    """
    from ..errors import ModelError
    from ..model import element_name, parse_name

    parent: dict[int, int] = {}
    for j in range(a.nx):
        w = a.which(a.ode[j])
        if w is not None and w[0] == "x" and w[1] != j:
            parent.setdefault(w[1], j)
    lev: dict[tuple[str, int], int] = {}
    for i in range(a.nx):
        k, n, seen = i, 0, {i}
        while k in parent and parent[k] not in seen:
            k = parent[k]
            seen.add(k)
            n += 1
        lev[("x", i)] = n
    top = max((lev[("x", i)] for i in range(a.nx)), default=0)

    def by_name(nm: str) -> int | None:
        try:
            base, order, idx = parse_name(nm)
        except ModelError:
            return None
        if order == 0:
            return None
        en = element_name(base, 1, 0, 0) + ("" if idx is None else f"[{idx}]")
        w = a.which(a.names[en]) if en in a.names else None
        return lev[w] + order if w is not None and w[0] == "x" else order

    for i, nm in enumerate(a.z_names):
        k = by_name(nm)
        lev[("z", i)] = top + 1 if k is None else k
    for i, nm in enumerate(a.w_names):
        k = by_name(nm)
        lev[("w", i)] = 0 if k is None else k
    for i in range(a.n_p):
        lev[("p", i)] = 0
    return lev


def kinematic_pairs(a: Augmented) -> list[tuple[int, int]]:
    """``(j, i)`` for every state with ``x_j' = x_i`` exactly (``p' = v``): used by the guess."""
    out = []
    for j in range(a.nx):
        w = a.which(a.ode[j])
        if w is not None and w[0] == "x" and w[1] != j:
            out.append((j, w[1]))
    return out


def _preference(a: Augmented, conditions: list[Condition]) -> list[int]:
    """Order of preference of the boundary conditions when an independent subset is chosen:
    position-level before velocity-level (the highest derivative level of the symbols a
    condition involves), then the order given."""
    lev = derivative_levels(a)
    keys = []
    for i, c in enumerate(conditions):
        ws = [a.which(s) for s in ca.symvar(c.expr)]
        keys.append((max((lev.get(w, 0) for w in ws if w is not None), default=0), i))
    order = sorted(range(len(keys)), key=lambda i: keys[i])
    pref = [0] * len(keys)
    for r, i in enumerate(order):
        pref[i] = r
    return pref


def compile_problem(ocp) -> Problem:
    """Freeze the statement of ``ocp`` (a :class:`daekit.ocp.OCP`) into a :class:`Problem`."""
    a: Augmented = ocp._aug
    if ocp._lagrange_user is None and ocp._mayer_user is None:
        raise OCPError("no objective: call ocp.minimize(integral=..., final=...) first")
    has_lagrange = ocp._lagrange_user is not None
    has_mayer = ocp._mayer_user is not None
    Tsym = ca.SX.sym("T")
    mayer_fun = None
    if has_mayer:
        may = ca.substitute([ocp._mayer_user], [a.t], [Tsym])[0]
        mayer_fun = ca.Function("mayer", [Tsym, a.x, a.z, a.w, a.p], [may])
    # bounds: simple (on one decision symbol) or general (path constraints)
    lb = {k: np.full(n, -np.inf) for k, n in (("x", a.nx), ("z", a.nz), ("w", a.nw))}
    ub = {k: np.full(n, np.inf) for k, n in (("x", a.nx), ("z", a.nz), ("w", a.nw))}
    path_exprs, path_lb, path_ub, path_labels = [], [], [], []
    for e, (lo, hi) in ocp._bounds.items():
        ex = a.names[e]
        w = a.which(ex)
        if w is not None and w[0] in lb:
            lb[w[0]][w[1]] = max(lb[w[0]][w[1]], lo)
            ub[w[0]][w[1]] = min(ub[w[0]][w[1]], hi)
        else:
            path_exprs.append(ex)
            path_lb.append([lo])
            path_ub.append([hi])
            path_labels.append(f"bound on {e}")
    for k in lb:
        bad = np.nonzero(lb[k] > ub[k])[0]
        if bad.size:
            nm = {"x": a.x_names, "z": a.z_names, "w": a.w_names}[k][bad[0]]
            raise OCPError(f"contradicting bounds on {nm!r}: lower {lb[k][bad[0]]:g} > upper "
                           f"{ub[k][bad[0]]:g}; correct one of the ocp.bound(...) calls")
    for ex, l_, u_, lab in ocp._path_user:
        path_exprs.append(ex)
        path_lb.append(l_)
        path_ub.append(u_)
        path_labels.extend([lab] * ex.numel()) if ex.numel() > 1 else path_labels.append(lab)
    path_fun = None
    if path_exprs:
        path_fun = ca.Function("path", [a.t, a.x, a.z, a.w, a.p], [ca.vertcat(*path_exprs)])
    cat = lambda xs: np.concatenate([np.ravel(x) for x in xs]) if xs else np.zeros(0)  # noqa: E731
    # boundary conditions as a function of (v0, vT, p, T), v = (x, z, w)
    n = a.nx + a.nz + a.nw
    v0 = ca.SX.sym("v0", n)
    vT = ca.SX.sym("vT", n)
    v = ca.vertcat(a.x, a.z, a.w)
    conds = [Condition(*c) for c in ocp._bc_user]
    rows = []
    # all conditions at both ends in one substitution each (not two per condition)
    sizes = [int(c.expr.numel()) for c in conds]
    offs = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    allc = ca.vertcat(*[ca.vec(c.expr) for c in conds]) if conds else ca.SX(0, 1)
    sub = ca.Function("ends", [ca.vertcat(a.t, v)], [allc])
    all0, allT = sub(ca.vertcat(0.0, v0)), sub(ca.vertcat(Tsym, vT))
    for k, c in enumerate(conds):
        e0, eT = all0[offs[k]:offs[k + 1]], allT[offs[k]:offs[k + 1]]
        if isinstance(c.value, tuple):  # up to sign: b . v(T), or a minor of [v(T) v(0)]
            rows.append(ca.dot(ca.DM(c.value[1]), eT) if c.value[0] == "normal" else
                        eT[0] * e0[1] - eT[1] * e0[0])
            continue
        rows.append(e0 - c.value if c.kind == "initial" else
                    eT - c.value if c.kind == "final" else eT - e0)
    bc = ca.vertcat(*rows) if rows else ca.SX(0, 1)
    Jbc = ca.jacobian(bc, ca.vertcat(v0, vT))
    linear = [not ca.depends_on(Jbc[i, :], ca.vertcat(v0, vT, a.p, Tsym))
              for i in range(bc.numel())]
    man = ca.vertcat(a.alg, a.inv)
    ends = ca.vertcat(ca.substitute([man], [ca.vertcat(a.t, v)], [ca.vertcat(0.0, v0)])[0],
                      ca.substitute([man], [ca.vertcat(a.t, v)], [ca.vertcat(Tsym, vT)])[0],
                      bc)
    r = a.reduced
    alg_names = list(r.alg_names)
    if len(alg_names) != a.nz:
        alg_names = [f"algebraic row {i}" for i in range(a.nz)]
    return Problem(
        aug=a,
        name=getattr(ocp.model, "name", None) or "ReducedDAE",
        alg_names=alg_names,
        method=ocp.method,
        intervals=ocp.intervals,
        degree=ocp.degree,
        control_mode=ocp.control_mode,
        verbose=ocp.verbose,
        solver_options=dict(ocp.solver_options),
        integrator_options=dict(ocp.integrator_options),
        T_free=ocp._T_free,
        T_fixed=ocp._T_fixed,
        T_guess=ocp._T_guess,
        free_params=dict(ocp._free_params),
        p_values=ocp._p_values.copy(),
        default_guess=None if ocp._default_guess is None else dict(ocp._default_guess),
        lagrange=ocp._lagrange_user if has_lagrange else ca.SX(0),
        has_lagrange=has_lagrange,
        has_mayer=has_mayer,
        mayer_fun=mayer_fun,
        lb=lb,
        ub=ub,
        path_fun=path_fun,
        path_lb=cat(path_lb),
        path_ub=cat(path_ub),
        path_labels=path_labels,
        conditions=conds,
        bc_fun=ca.Function("bc", [v0, vT, a.p, Tsym], [bc]),
        bc_jac=ca.Function("bc_jac", [v0, vT, a.p, Tsym], [Jbc]),
        man_fun=ca.Function("man", [a.t, v, a.p], [man]),
        man_jac=ca.Function("man_jac", [a.t, v, a.p], [ca.jacobian(man, v)]),
        ends_fun=ca.Function("ends", [v0, vT, a.p, Tsym],
                             [ends, ca.jacobian(ends, ca.vertcat(v0, vT))]),
        bc_pref=_preference(a, conds),
        bc_linear=linear,
    )
