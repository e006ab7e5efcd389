"""The constrained mechanical system RATTLE integrates: coordinates ``q``, a mass matrix
``M(q)``, a potential ``V(q)``, holonomic constraints ``c(q) = 0`` and velocity-free forces,
in CasADi SX; and the adapter that reads one off a :class:`LagrangianSystem`, a ReducedDAE
made by it, or a plain dict.

>>> import casadi as ca
>>> q = ca.SX.sym("q", 2)
>>> pend = ConstrainedMechanics(q=q, M=ca.DM.eye(2), V=9.81 * q[1], c=ca.sumsqr(q) - 1,
...                             q_names=["x", "y"], constraint_names=["rod"])
>>> pend.n, pend.m, pend.v_names, pend.multiplier_names
(2, 1, ['der(x)', 'der(y)'], ['lambda'])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ..errors import ModelError
from ..inputs import override_params
from ..model import element_name, parse_name
from ..wording import count

__all__ = ["ConstrainedMechanics", "as_constrained_mechanics", "acceleration_name"]


@dataclass
class ConstrainedMechanics:
    """A conservative mechanical system with holonomic constraints, in CasADi SX.

    Attributes
    ----------
    q : casadi.SX
        Generalized coordinates, an ``(n, 1)`` symbol.
    M : casadi.SX or DM or array
        Mass matrix ``(n, n)``: a constant, or an expression of ``q`` (and ``p``).
    V : casadi.SX
        Potential energy, a scalar expression of ``q`` (and ``p``).
    c : casadi.SX
        Holonomic constraints ``c(q) = 0``, an ``(m, 1)`` expression of ``q`` (and ``p``).
    force : casadi.SX or None
        Additional generalized force ``F(t, q, u)`` (no velocity dependence), ``(n, 1)``.
    t : casadi.SX or None
        The time symbol ``force`` may use.
    u : casadi.SX or None
        Input symbols ``force`` may use; their values are given as functions of time when
        simulating (``inputs={"u": ...}``).
    p, p_values : casadi.SX, array
        Parameters and their default values (constant during a run).
    u_names, p_names : list of str
        Element names of ``u`` and ``p`` (default ``u[i]``, and the symbols' own names).
    q_names, v_names : list of str
        Names of the coordinates and of their velocities (default ``q[i]`` and ``der(q)[i]``).
    constraint_names, multiplier_names : list of str
        Names of the constraints (default ``c[i]``) and of their multipliers (``lambda[i]``).
        The multiplier is defined by ``p' = ... - G^T lambda``.
    """

    q: ca.SX
    M: Any
    V: Any
    c: Any
    force: Any = None
    t: Any = None
    p: Any = None
    p_values: Any = None
    q_names: list[str] | None = None
    v_names: list[str] | None = None
    constraint_names: list[str] | None = None
    multiplier_names: list[str] | None = None
    u: Any = None
    u_names: list[str] | None = None
    p_names: list[str] | None = None

    def __post_init__(self) -> None:
        self.q = _column_symbol(self.q, "q")
        n = self.q.numel()
        if self.t is None:
            self.t = ca.SX.sym("t")
        if self.p is None:
            self.p = ca.SX(0, 1)
        self.p = _column_symbol(self.p, "p") if self.p.numel() else ca.SX(0, 1)
        pv = np.zeros(0) if self.p_values is None else np.asarray(self.p_values, float).ravel()
        if pv.size != self.p.numel():
            raise ModelError(
                f"ConstrainedMechanics: {count(self.p.numel(), 'parameter')} but "
                f"{count(pv.size, 'value')} in "
                "p_values: give one value per parameter element"
            )
        self.p_values = pv
        if self.p_names is None:
            self.p_names = [self.p[i].name() for i in range(self.p.numel())]
        self.p_names = list(self.p_names)
        if self.u is None:
            self.u = ca.SX(0, 1)
        self.u = _column_symbol(self.u, "u") if self.u.numel() else ca.SX(0, 1)
        self.u_names = list(self.u_names) if self.u_names else _indexed("u", self.u.numel())
        self.M = _as_sx(self.M, "M")
        if self.M.shape != (n, n):
            raise ModelError(
                f"ConstrainedMechanics: the mass matrix M is {self.M.shape[0]}x{self.M.shape[1]} "
                f"but there are {n} coordinates q: give an {n}x{n} matrix"
            )
        self.V = _as_sx(self.V, "V")
        if self.V.numel() != 1:
            raise ModelError("ConstrainedMechanics: the potential V must be a scalar expression")
        self.c = ca.vec(_as_sx(self.c, "c"))
        m = self.c.numel()
        if self.force is None:
            self.force = ca.SX.zeros(n, 1)
        self.force = ca.vec(_as_sx(self.force, "force"))
        if self.force.numel() != n:
            raise ModelError(
                f"ConstrainedMechanics: force has {self.force.numel()} elements, expected {n}"
            )
        self.q_names = list(self.q_names) if self.q_names else [f"q[{i}]" for i in range(n)]
        if self.v_names:
            self.v_names = list(self.v_names)
        else:
            self.v_names = [_velocity_name(s) for s in self.q_names]
        self.constraint_names = (
            list(self.constraint_names) if self.constraint_names else _indexed("c", m)
        )
        self.multiplier_names = (
            list(self.multiplier_names) if self.multiplier_names else _indexed("lambda", m)
        )
        for what, names, size in (
            ("q_names", self.q_names, n),
            ("v_names", self.v_names, n),
            ("constraint_names", self.constraint_names, m),
            ("multiplier_names", self.multiplier_names, m),
            ("u_names", self.u_names, self.u.numel()),
            ("p_names", self.p_names, self.p.numel()),
        ):
            if len(names) != size:
                raise ModelError(
                    f"ConstrainedMechanics: {what} has {len(names)} names for {size} elements"
                )
        allowed = ca.vertcat(self.q, self.p)
        for what, expr in (("M", self.M), ("V", self.V), ("c", self.c)):
            _check_free(expr, allowed, what)
        _check_free(self.force, ca.vertcat(self.q, self.p, self.t, self.u), "force")

    @property
    def n(self) -> int:
        """Number of coordinates."""
        return int(self.q.numel())

    @property
    def m(self) -> int:
        """Number of constraints."""
        return int(self.c.numel())

    @classmethod
    def from_functions(
        cls,
        n: int,
        M: Any,
        grad_V: ca.Function,
        c: ca.Function,
        G: ca.Function | None = None,
        V: ca.Function | None = None,
        **kw: Any,
    ) -> ConstrainedMechanics:
        """Build from CasADi Functions of ``q``: ``grad_V(q)``, ``c(q)``, optional ``G(q)`` and
        ``V(q)`` (for the energy), ``M`` a constant matrix or a Function of ``q``.

        Without ``V`` the potential is recovered only through its gradient: the energy reported
        in the stats then omits ``V`` (a warning-free but partial number), so pass ``V`` when
        the energy matters. ``G`` is ignored (it is ``jacobian(c, q)``); give it to check it.
        """
        q = ca.SX.sym("q", n)

        def call(f: Any) -> ca.SX:
            if isinstance(f, ca.Function):
                if f.is_a("MXFunction"):
                    f = f.expand()
                return f(q)
            return _as_sx(f, "M")

        Mq = call(M)
        if V is not None:
            Vq = call(V)
            force = None
        else:
            # no potential: put -grad V into the force (F may depend on q)
            Vq = ca.SX(0)
            force = -call(grad_V)
        cq = call(c)
        if G is not None:
            Gq = call(G)
            Gc = ca.jacobian(cq, q)
            err = ca.Function("gchk", [q], [Gq - Gc])
            qs = np.linspace(0.3, 1.1, n)
            if np.max(np.abs(np.array(err(qs)))) > 1e-8:
                raise ModelError(
                    "ConstrainedMechanics.from_functions: G(q) differs from the Jacobian of "
                    "c(q): give G = dc/dq (or leave it out)"
                )
        return cls(q=q, M=Mq, V=Vq, c=cq, force=force, **kw)


# ----------------------------------------------------------------------------------------------
# helpers


def _indexed(base: str, size: int) -> list[str]:
    return [element_name(base, size, i) for i in range(size)]


def acceleration_name(name: str) -> str | None:
    """The name of the second derivative of a coordinate's name (``"p[0]"`` ->
    ``"der(p,2)[0]"``, ``"x"`` -> ``"der(x,2)"``); None for a name that is not a plain
    coordinate (a derivative already, or not a daekit name)."""
    try:
        base, order, idx = parse_name(name)
    except ModelError:
        return None
    return None if order else _with_order(base, idx, 2)


def _velocity_name(name: str) -> str:
    """``"x"`` -> ``"der(x)"``, ``"p[1]"`` -> ``"der(p)[1]"``, ``"der(x)"`` -> ``"der(x,2)"``."""
    base, order, idx = parse_name(name)
    return _with_order(base, idx, order + 1)


def _with_order(base: str, idx: int | None, order: int) -> str:
    head = element_name(base, 1, 0, order)
    return head if idx is None else f"{head}[{idx}]"


def _column_symbol(x: Any, what: str) -> ca.SX:
    if isinstance(x, ca.SX) and x.is_valid_input():
        return ca.vec(x)
    if isinstance(x, (list, tuple)) and all(isinstance(e, ca.SX) for e in x):
        return ca.vertcat(*x)
    raise ModelError(
        f"ConstrainedMechanics: {what} must be a CasADi SX symbol (ca.SX.sym), got {type(x)}"
    )


def _as_sx(x: Any, what: str) -> ca.SX:
    if isinstance(x, ca.SX):
        return x
    if isinstance(x, ca.DM):
        return ca.SX(x)
    if isinstance(x, ca.MX):
        raise ModelError(
            f"ConstrainedMechanics: {what} is an MX expression; build the system with SX "
            "symbols (ca.SX.sym) so that the step can be unrolled"
        )
    try:
        return ca.SX(ca.DM(np.atleast_1d(np.asarray(x, float)) if np.ndim(x) < 2 else x))
    except Exception as exc:  # noqa: BLE001
        raise ModelError(f"ConstrainedMechanics: cannot read {what} as a matrix: {exc}") from exc


def _check_free(expr: ca.SX, allowed: ca.SX, what: str) -> None:
    ok = {s.element_hash() for s in ca.symvar(allowed)}
    bad = [s.name() for s in ca.symvar(expr) if s.element_hash() not in ok]
    if bad:
        raise ModelError(
            f"ConstrainedMechanics: {what} depends on {bad}, which is not a coordinate, "
            "parameter or (for force) time or input: RATTLE needs forces F(t, q, u) without "
            "velocities; simulate velocity-dependent forces (damping, friction) with an index-1 "
            "integrator instead (method='idas')"
        )


# ----------------------------------------------------------------------------------------------
# adapters


def as_constrained_mechanics(system: Any, params: dict | None = None) -> ConstrainedMechanics:
    """Read a RATTLE-ready mechanical system off ``system``.

    Accepted: a :class:`ConstrainedMechanics`; a :class:`daekit.mechanics.LagrangianSystem`
    (its kinetic energy must be ``q'^T M(q) q' / 2`` plus velocity-free terms, its forces free
    of velocities once the parameter values are in); a ``ReducedDAE`` made by it
    (``r.lagrangian``, as from ``LagrangianSystem.index1()``); a dict or any object with
    ``q``, ``M``, ``V`` and ``c`` (SX expressions; optional ``force``, ``t``, ``u``, ``p``,
    ``p_values`` and name lists). ``params`` overrides parameter values by name.
    """
    sysm = _as_mechanics(system, params)
    return _with_params(sysm, params) if params else sysm


def _as_mechanics(system: Any, params: dict | None) -> ConstrainedMechanics:
    if isinstance(system, ConstrainedMechanics):
        return system
    if _is_lagrangian(system):
        return _from_lagrangian(system, params)
    if isinstance(system, dict) and {"q", "M", "V", "c"} <= set(system):
        return ConstrainedMechanics(**system)
    if all(hasattr(system, a) for a in ("q", "M", "V", "c")):
        kw = {}
        for a in ("force", "t", "u", "p", "p_values", "q_names", "v_names", "constraint_names",
                  "multiplier_names", "u_names", "p_names"):
            val = getattr(system, a, None)
            if val is not None and not callable(val):
                kw[a] = val
        return ConstrainedMechanics(q=system.q, M=system.M, V=system.V, c=system.c, **kw)
    lagrangian = getattr(system, "lagrangian", None)
    if lagrangian is not None:
        return _as_mechanics(lagrangian, params)
    raise ModelError(
        f"method='rattle' needs a mechanical system (coordinates q, mass matrix M, potential V, "
        f"holonomic constraints c), got {type(system).__name__}"
        + (" without a LagrangianSystem (r.lagrangian)" if hasattr(system, "lagrangian") else "")
        + ": build it with daekit.mechanics.LagrangianSystem (and pass it or its index1()) or "
        "with daekit.simulate.rattle.ConstrainedMechanics"
    )


def _is_lagrangian(obj: Any) -> bool:
    return all(
        hasattr(obj, a)
        for a in ("mass_matrix", "potential_energy", "kinetic_energy", "momentum", "constraint",
                  "generalized_force", "coordinate_names", "velocity_names", "p_values")
    )


def _from_lagrangian(ls: Any, params: dict | None) -> ConstrainedMechanics:
    """Rebuild a LagrangianSystem through its public CasADi Functions in fresh SX symbols."""
    name = getattr(ls, "name", "mechanism")
    n = int(ls.n)
    m = int(getattr(ls, "m", 0))
    pv = np.asarray(ls.p_values, float).ravel()
    q = ca.SX.sym("q", n)
    dq = ca.SX.sym("dq", n)
    p = ca.SX.sym("p", pv.size)
    t = ca.SX.sym("t")
    groups_u = list(getattr(ls, "input_groups", []))
    nu = sum(k for _, k in groups_u)
    u = ca.SX.sym("u", nu)
    zero = ca.SX.zeros(n, 1)
    M = ls.mass_matrix(q, p)
    T0 = ls.kinetic_energy(q, zero, p)
    b = ls.momentum(q, zero, p)
    pg = getattr(ls, "parameter_groups", [])
    p_names = [element_name(g, k, i) for g, k, _ in pg for i in range(k)]
    if len(p_names) != pv.size:
        p_names = [f"p[{i}]" for i in range(pv.size)]
    pv = override_params(pv, p_names, params or {}, "RATTLE")
    pvals = ca.DM(pv)
    bfun = ca.Function("b", [q], [ca.substitute(b, p, pvals)])
    rng = np.random.default_rng(7)
    if any(np.max(np.abs(np.array(bfun(rng.uniform(-1, 1, n))))) > 1e-12 for _ in range(3)):
        raise ModelError(
            f"mechanical system {name!r}: the kinetic energy has terms linear in the velocities "
            "(dT/dq' is not zero at q' = 0), e.g. a moving frame; RATTLE here needs "
            "T = q'^T M(q) q' / 2 (+ velocity-free terms): use method='idas'"
        )
    V = ls.potential_energy(q, p) - T0  # velocity-free kinetic terms act as a potential
    c = ls.constraint(q, p) if m else ca.SX(0, 1)
    Q = ls.generalized_force(t, q, dq, u, p)
    Qv = ca.substitute(Q, p, pvals)
    if ca.depends_on(Qv, dq):
        bad = [ls.coordinate_names[i] for i in range(n) if ca.depends_on(Qv[i], dq)]
        raise ModelError(
            f"mechanical system {name!r}: the generalized force on {bad} depends on the "
            "velocities (damping or friction); RATTLE is for conservative systems with forces "
            "F(t, q, u): set the friction parameters to 0 or use method='idas'"
        )
    Q = ca.substitute(Q, dq, ca.DM.zeros(n, 1))  # velocity terms vanish at these parameters
    u_names = [element_name(g, k, i) for g, k in groups_u for i in range(k)]
    mname = getattr(ls, "multiplier_name", "z")
    return ConstrainedMechanics(
        q=q, M=M, V=V, c=c, force=Q, t=t, u=u, p=p, p_values=pv,
        q_names=ls.coordinate_names, v_names=ls.velocity_names,
        constraint_names=list(getattr(ls, "constraint_names", [])) or None,
        multiplier_names=[element_name(mname, m, j) for j in range(m)] or None,
        u_names=u_names or None, p_names=p_names or None,
    )


def _with_params(sysm: ConstrainedMechanics, params: dict) -> ConstrainedMechanics:
    pv = override_params(sysm.p_values, sysm.p_names, params, "RATTLE")
    return ConstrainedMechanics(
        q=sysm.q, M=sysm.M, V=sysm.V, c=sysm.c, force=sysm.force, t=sysm.t, p=sysm.p,
        p_values=pv, q_names=sysm.q_names, v_names=sysm.v_names,
        constraint_names=sysm.constraint_names, multiplier_names=sysm.multiplier_names,
        u=sysm.u, u_names=sysm.u_names, p_names=sysm.p_names,
    )
