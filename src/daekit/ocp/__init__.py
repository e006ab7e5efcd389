"""Optimal control on DAEs of any index: ``OCP``, ``Free``, ``OCPSolution``.

The model is reduced to index 1 (or given as a :class:`~daekit.reduced.ReducedDAE`); the
optimal control problem is transcribed (direct collocation with Radau IIA by default, or
multiple shooting on IDAS) and solved with IPOPT through CasADi. The consistency conditions
(invariants) are imposed at the initial time only, and boundary conditions that are redundant
with them (full periodicity of a constrained mechanism) are detected and dropped (a dropped
condition the solution turns out to violate is imposed in a second solve; conditions that
contradict each other are named instead and nothing is solved); the solution's
:attr:`OCPSolution.report` says what was done.

Example: swing a planar pendulum (index 3 in Cartesian coordinates: unit mass and rod, a
tangential force ``u``) from rest at the bottom to rest at 30 degrees in 2 s with the least
control effort ``int u^2 dt``.

>>> import casadi as ca, numpy as np, daekit as dk
>>> m = dk.Model("swing")
>>> p = m.state("p", 2); z = m.algebraic("z"); u = m.control("u")
>>> tangent = ca.vertcat(-p[1], p[0])
>>> _ = m.equation(m.der(p, 2) - (u * tangent - ca.vertcat(0, 9.81) - z * p), name="newton")
>>> _ = m.equation(0.5 * (ca.dot(p, p) - 1), name="rod")
>>> ocp = dk.OCP(m, t_final=2.0, intervals=20, degree=3)
>>> _ = ocp.minimize(integral=u**2)
>>> _ = ocp.initial({"p": [0, -1], "der(p)": [0, 0]})
>>> _ = ocp.final({"p": [0.5, -np.sqrt(3) / 2], "der(p)": [0, 0]})
>>> sol = ocp.solve()
>>> sol.success, round(sol.objective, 4)   # the continuous optimum is 2.6108 (see the tests)
(True, 2.6315)

The 8 boundary conditions are only 4 independent ones on the rod's 2-dimensional manifold at
each end; the report says which were imposed. The invariants (``rod`` and its derivative) are
imposed at ``t = 0`` and hold along the solution (to the collocation's accuracy, which is lower
at the interior collocation points than at the interval ends):

>>> sol.boundary.n_conditions, sol.boundary.rank
(8, 4)
>>> bool(np.max(np.abs(sol.invariants)) < 1e-4), sol["p"].shape
(True, (61, 2))

Multiple shooting on IDAS (the same piecewise constant controls, dynamics integrated to
1e-10) finds the same optimum up to the collocation's O(h^5) truncation error:

>>> ocp.method = "shooting"
>>> sh = ocp.solve(guess=sol)              # warm start from the collocation solution
>>> sh.success, round(sh.objective, 4), sh.t.size
(True, 2.6315, 21)
>>> bool(abs(sh.objective - sol.objective) < 1e-5 * sol.objective)
True
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import OCPError
from ..reduced import ReducedDAE
from .consistency import BoundaryAnalysis, analyze_boundary
from .nlp import quiet
from .problem import Augmented, augment

__all__ = ["OCP", "Free", "OCPSolution", "BoundaryAnalysis"]

_STATUS_OK = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}


@dataclass
class Free:
    """A free decision quantity (the final time) with bounds and a guess.

    >>> Free(1.0, 5.0).guess
    3.0
    """

    lo: float
    hi: float
    guess: float | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.lo) and np.isfinite(self.hi)) or self.lo > self.hi:
            raise OCPError(f"Free({self.lo}, {self.hi}): needs finite bounds with lo <= hi")
        if self.lo <= 0:
            raise OCPError(f"Free({self.lo}, {self.hi}): a free final time needs lo > 0")
        if self.guess is None:
            self.guess = 0.5 * (self.lo + self.hi)
        if not self.lo <= self.guess <= self.hi:
            raise OCPError(f"Free({self.lo}, {self.hi}, guess={self.guess}): guess out of bounds")


def _sign_names(up_to_sign, names: list[str], what: str) -> set[str]:
    """The names (among ``names``) meant by ``up_to_sign``: None/False, True, a name or a list."""
    if up_to_sign is None or up_to_sign is False:
        return set()
    if up_to_sign is True:
        return set(names)
    chosen = [up_to_sign] if isinstance(up_to_sign, str) else list(up_to_sign)
    bad = [n for n in chosen if n not in names]
    if bad:
        raise OCPError(
            f"{what}: up_to_sign names {bad}, which are not among the conditions given "
            f"({', '.join(names)}); name a vector of the conditions, e.g. up_to_sign='q'"
        )
    return set(chosen)


def _up_to_sign_rows(kind: str, name: str, els: list[str], vals, names: dict) -> list:
    """Boundary rows imposing ``v = ±value`` (final) or ``v(T) = ±v(0)`` (periodic) on the
    vector ``name``: entries ``(kind, label, expr, val)`` whose ``val`` is a tuple
    ``("normal", b)`` (the row ``b . v(T)``) or ``("minor",)`` (``v_i(T) v_j(0) - v_j(T)
    v_i(0)`` for the pair ``expr = (v_i, v_j)``)."""
    n = len(els)
    if n < 2:
        raise OCPError(
            f"ocp.{kind}: up_to_sign={name!r} needs a vector (a quaternion, say); {name!r} has "
            "one element: impose its value, or its square, instead"
        )
    ex = ca.vertcat(*[names[e] for e in els])
    if kind == "periodic":
        return [(kind, f"periodic {name} = ±{name}(0) ({els[i]}, {els[j]})",
                 ca.vertcat(ex[i], ex[j]), ("minor",))
                for i in range(n) for j in range(i + 1, n)]
    a = np.asarray(vals, dtype=float)
    if not np.linalg.norm(a) > 0:
        raise OCPError(f"ocp.{kind}: up_to_sign={name!r} needs a nonzero value")
    # an orthonormal basis of the complement of a: the last n - 1 columns of Q in a = Q R
    B = np.linalg.qr(a.reshape(-1, 1), mode="complete")[0][:, 1:]
    shown = ", ".join(f"{x:.6g}" for x in a)
    return [(kind, f"{kind} {name} = ±({shown}) [{k + 1} of {n - 1}]", ex, ("normal", B[:, k]))
            for k in range(n - 1)]


def _vec(val, n: int, what: str) -> np.ndarray:
    try:
        arr = np.asarray(ca.DM(val) if isinstance(val, ca.DM) else val, dtype=float).ravel()
    except (TypeError, ValueError):
        raise OCPError(f"{what}: expected numbers, got {val!r}") from None
    if arr.size == 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n:
        raise OCPError(f"{what}: expected {n} value(s), got {arr.size}")
    return arr


class OCP:
    """An optimal control problem on a DAE model of any index.

    Parameters
    ----------
    model : daekit.Model or daekit.reduced.ReducedDAE
        An original model (any index; reduced with :func:`daekit.reduction.reduce_index`) or an
        index-1 ReducedDAE. Expressions and names refer to the original model's variables.
    t_final : float or Free
        Horizon length (the problem starts at ``t = 0``), or ``Free(lo, hi, guess)``.
    intervals : int
        Number of control intervals ``N``.
    degree : int
        Radau IIA collocation degree, 1 to 5 (collocation only).
    method : {"collocation", "shooting"}
        Direct collocation with Radau IIA (:mod:`daekit.ocp.collocation`), or direct multiple
        shooting with one IDAS integrator per interval (:mod:`daekit.ocp.shooting`; CVODES
        when there are no algebraic unknowns). Shooting integrates to the integrator's
        tolerance on the intervals and imposes bounds and path constraints at the interval
        boundaries only; it uses a limited-memory Hessian (cheap iterations) unless
        ``solver_options={"hessian_approximation": "exact"}`` (second-order sensitivities:
        costlier iterations, often far fewer of them on hard problems such as periodic orbits).
    controls : {"constant", "polynomial"}
        Piecewise constant controls, or piecewise polynomial of degree ``degree - 1``
        (values at the Radau points; collocation only).
    integrator_options : dict
        Options of the shooting integrator (CasADi's IDAS options), overriding daekit's
        ``{"abstol": 1e-10, "reltol": 1e-10, "max_num_steps": 50000, "quad_err_con": True}``
        (error control on the integral objective too); also used by
        :meth:`OCPSolution.simulate`.
    verbose : bool
        Let IPOPT print its iterations.
    solver_options : dict
        Extra IPOPT options, e.g. ``{"max_iter": 500, "tol": 1e-10}``. daekit's defaults:
        ``max_iter = 1000``, ``mumps_permuting_scaling = 0`` (much faster factorizations of
        collocation KKT systems), printing off unless ``verbose``.

    Example
    -------
    >>> import casadi as ca, daekit as dk
    >>> m = dk.Model("cart"); s = m.state("s"); u = m.control("u")
    >>> _ = m.equation(m.der(s, 2) - u, name="newton")
    >>> ocp = OCP(m, t_final=1.0, intervals=10, controls="polynomial")
    >>> _ = ocp.minimize(integral=u**2)
    >>> _ = ocp.initial({"s": 0, "der(s)": 0}).final({"s": 1, "der(s)": 0})
    >>> round(ocp.solve().objective, 6)   # the cubic 3t^2 - 2t^3: int (6 - 12t)^2 dt = 12
    12.0
    """

    def __init__(
        self,
        model,
        t_final: float | Free = 1.0,
        intervals: int = 50,
        degree: int = 3,
        method: str = "collocation",
        controls: str = "constant",
        verbose: bool = False,
        solver_options: dict | None = None,
        integrator_options: dict | None = None,
    ) -> None:
        if isinstance(model, ReducedDAE):
            r = model
        elif hasattr(model, "equations") and hasattr(model, "variables"):
            try:
                from ..reduction import reduce_index
            except ImportError as exc:  # pragma: no cover - depends on the reduction module
                raise OCPError(
                    "OCP needs daekit.reduction.reduce_index to reduce the model; pass a "
                    f"ReducedDAE instead ({exc})"
                ) from None
            r = reduce_index(model)
        else:
            raise OCPError(
                f"OCP(model): expected a daekit.Model or a ReducedDAE, got {type(model).__name__}"
            )
        if int(intervals) != intervals or intervals < 1:
            raise OCPError(f"OCP: intervals must be a positive integer, got {intervals!r}")
        if int(degree) != degree or not 1 <= degree <= 5:
            raise OCPError(f"OCP: degree must be 1, 2, 3, 4 or 5 (Radau IIA), got {degree!r}")
        if controls not in ("constant", "polynomial"):
            raise OCPError(f"OCP: controls must be 'constant' or 'polynomial', got {controls!r}")
        if integrator_options is not None and not isinstance(integrator_options, dict):
            raise OCPError(
                f"OCP: integrator_options must be a dict, got {type(integrator_options).__name__}"
            )
        self.model = model
        self.reduced = r
        self.intervals = int(intervals)
        self.degree = int(degree)
        self.control_mode = controls
        self.method = method  # validated by the property
        self.verbose = bool(verbose)
        self.solver_options = dict(solver_options or {})
        self.integrator_options = dict(integrator_options or {})
        self._aug: Augmented = augment(r)
        if isinstance(t_final, Free):
            self._T_free = (float(t_final.lo), float(t_final.hi), float(t_final.guess))
            self._T_fixed = None
            self._T_guess = float(t_final.guess)
        else:
            try:
                T = float(t_final)
            except (TypeError, ValueError):
                raise OCPError(
                    f"OCP: t_final must be a number or Free(...), got {t_final!r}"
                ) from None
            if not np.isfinite(T) or T <= 0:
                raise OCPError(f"OCP: t_final must be positive and finite, got {t_final!r}")
            self._T_free, self._T_fixed, self._T_guess = None, T, T
        self._lagrange_user: ca.SX | None = None
        self._mayer_user: ca.SX | None = None
        self._bounds: dict[str, list[float]] = {}
        self._path_user: list[tuple[ca.SX, np.ndarray, np.ndarray, str]] = []
        self._bc_user: list[tuple[str, str, ca.SX, float]] = []  # (kind, label, expr, value)
        self._free_params: dict[str, tuple[float, float, float]] = {}
        self._p_values = self._aug.p_values.copy()
        self._last_boundary: BoundaryAnalysis | None = None
        self._default_guess: dict | None = None

    @property
    def method(self) -> str:
        """The transcription, ``"collocation"`` or ``"shooting"``; may be changed between solves
        (``ocp.method = "shooting"; ocp.solve(guess=collocation_solution)``)."""
        return self._method

    @method.setter
    def method(self, value: str) -> None:
        if value not in ("collocation", "shooting"):
            raise OCPError(f"OCP: method must be 'collocation' or 'shooting', got {value!r}")
        if value == "shooting" and self.control_mode != "constant":
            raise OCPError(
                "OCP: multiple shooting supports piecewise constant controls only "
                "(controls='constant'); use method='collocation' for polynomial controls"
            )
        self._method = value

    # ------------------------------------------------------------------ problem statement
    def minimize(self, integral=None, final=None) -> OCP:
        """Objective ``integral_0^T integral dt + final`` (expressions in the model's symbols;
        ``final`` is evaluated at ``t = T``, so ``final=m.t`` minimizes the final time)."""
        if integral is None and final is None:
            raise OCPError("ocp.minimize(): give an integral (Lagrange) and/or final (Mayer) term")
        if integral is not None:
            e = self._aug.map_expr(integral, "the integral objective")
            if e.numel() != 1:
                raise OCPError(f"the integral objective must be a scalar, got {e.numel()} elements")
            self._lagrange_user = e
        if final is not None:
            e = self._aug.map_expr(final, "the final objective")
            if e.numel() != 1:
                raise OCPError(f"the final objective must be a scalar, got {e.numel()} elements")
            self._mayer_user = e
        return self

    def bound(self, name: str, lo=-np.inf, hi=np.inf) -> OCP:
        """Bounds ``lo <= name <= hi`` along the whole horizon, for any variable or element by
        name (``"z"``, ``"p[0]"``, ``"der(p)"``, controls, free parameters)."""
        els = self._aug.elements(name, f"ocp.bound({name!r})")
        lo_ = _vec(lo, len(els), f"ocp.bound({name!r}) lower bound")
        hi_ = _vec(hi, len(els), f"ocp.bound({name!r}) upper bound")
        for e, a, b in zip(els, lo_, hi_, strict=True):
            if a > b:
                raise OCPError(f"ocp.bound({name!r}): lower bound {a} > upper bound {b} for {e!r}")
            w = self._aug.which(self._aug.names[e])
            if w is not None and w[0] == "p":
                if e not in self._free_params:
                    raise OCPError(
                        f"ocp.bound({name!r}): {e!r} is a fixed parameter; make it a decision "
                        "variable with ocp.free_parameter(name, lo, hi, guess)"
                    )
                g = float(np.clip(self._free_params[e][2], a, b))
                self._free_params[e] = (float(a), float(b), g)
                continue
            self._bounds[e] = [float(a), float(b)]
        return self

    def constrain(self, expr, lb=-np.inf, ub=np.inf, name: str | None = None) -> OCP:
        """Path constraint ``lb <= expr <= ub`` at every collocation point (and at ``t = 0``)."""
        label = name or f"path constraint #{len(self._path_user) + 1}"
        e = self._aug.map_expr(expr, f"ocp.constrain ({label})")
        lb_ = _vec(lb, e.numel(), f"ocp.constrain ({label}) lb")
        ub_ = _vec(ub, e.numel(), f"ocp.constrain ({label}) ub")
        if np.any(lb_ > ub_):
            raise OCPError(f"ocp.constrain ({label}): lb > ub")
        self._path_user.append((e, lb_, ub_, label))
        return self

    def _conditions(self, kind: str, values: dict, up_to_sign=None) -> None:
        if not isinstance(values, dict):
            raise OCPError(
                f"ocp.{kind}(...) takes a dict {{name: value}}, got {type(values).__name__}"
            )
        signed = _sign_names(up_to_sign, list(values), f"ocp.{kind}")
        for name, val in values.items():
            els = self._aug.elements(name, f"ocp.{kind}({{{name!r}: ...}})")
            vals = _vec(val, len(els), f"ocp.{kind}({{{name!r}: ...}})")
            if name in signed:
                self._bc_user.extend(_up_to_sign_rows(kind, name, els, vals, self._aug.names))
                continue
            for e, v in zip(els, vals, strict=True):
                self._bc_user.append((kind, f"{kind} {e}", self._aug.names[e], float(v)))

    def initial(self, values: dict) -> OCP:
        """Conditions at ``t = 0``: ``{name: value}``. Redundancy with the invariants is handled."""
        self._conditions("initial", values)
        return self

    def final(self, values: dict, up_to_sign=None) -> OCP:
        """Conditions at ``t = T``: ``{name: value}``.

        ``up_to_sign``: a name of ``values`` (or a list of them, or True for all) whose value
        is imposed up to its sign, ``v(T) = ±value``: a unit quaternion and its negative are
        the same rotation. Imposed as ``v(T)`` parallel to ``value`` (``B^T v(T) = 0`` with
        ``B`` an orthonormal basis of the complement of ``value``: ``n - 1`` conditions); with
        the invariant ``|q| = 1`` that leaves exactly ``q(T) = ±value``. Without it, the sign
        given decides which way round the attitude turns.
        """
        self._conditions("final", values, up_to_sign)
        return self

    def periodic(self, names, up_to_sign=None) -> OCP:
        """``v(T) = v(0)`` for each named variable (``["p", "der(p)"]``).

        ``up_to_sign``: names among ``names`` (or True for all) for which ``v(T) = ±v(0)``
        suffices (``v(T)`` parallel to ``v(0)``: the 2-by-2 minors
        ``v_i(T) v_j(0) - v_j(T) v_i(0)``, of which the boundary analysis keeps the ``n - 1``
        independent ones). Periodicity on a unit quaternion is redundant with its norm (held
        at ``t = 0``, kept by the dynamics) either way; the analysis drops the implied row.
        """
        if isinstance(names, str):
            names = [names]
        signed = _sign_names(up_to_sign, list(names), "ocp.periodic")
        for name in names:
            els = self._aug.elements(name, f"ocp.periodic([{name!r}])")
            if name in signed:
                self._bc_user.extend(_up_to_sign_rows("periodic", name, els, None,
                                                      self._aug.names))
                continue
            for e in els:
                self._bc_user.append(("periodic", f"periodic {e}", self._aug.names[e], 0.0))
        return self

    def free_parameter(self, name: str, lo: float, hi: float, guess: float | None = None) -> OCP:
        """Make a model parameter a decision variable with bounds ``lo <= name <= hi``."""
        for e in self._aug.elements(name, f"ocp.free_parameter({name!r})"):
            w = self._aug.which(self._aug.names[e])
            if w is None or w[0] != "p":
                raise OCPError(f"ocp.free_parameter({name!r}): {e!r} is not a model parameter")
            g = self._p_values[w[1]] if guess is None else guess
            if not lo <= g <= hi:
                g = 0.5 * (lo + hi)
            self._free_params[e] = (float(lo), float(hi), float(g))
        return self

    def set_guess(self, values: dict) -> OCP:
        """Default guesses used when :meth:`solve` gets none: constant or callable values for
        controls (``{"u": [0, 0, 9.81]}``) and constant values for states at ``t = 0``."""
        for name in values:
            self._aug.elements(name, f"ocp.set_guess({{{name!r}: ...}})")
        self._default_guess = dict(values)
        return self

    def set_parameters(self, values: dict) -> OCP:
        """Change fixed parameter values: ``{"L": 2.0}``."""
        for name, val in values.items():
            els = self._aug.elements(name, f"ocp.set_parameters({{{name!r}: ...}})")
            for e, v in zip(els, _vec(val, len(els), f"parameter {name!r}"), strict=True):
                w = self._aug.which(self._aug.names[e])
                if w is None or w[0] != "p":
                    raise OCPError(f"ocp.set_parameters: {e!r} is not a model parameter")
                self._p_values[w[1]] = v
        return self

    # ------------------------------------------------------------------ preparation
    def _prepare(self) -> None:
        a = self._aug
        self._has_lagrange = self._lagrange_user is not None
        self._has_mayer = self._mayer_user is not None
        if not (self._has_lagrange or self._has_mayer):
            raise OCPError("no objective: call ocp.minimize(integral=..., final=...) first")
        self._lagrange = self._lagrange_user if self._has_lagrange else ca.SX(0)
        Tsym = ca.SX.sym("T")
        if self._has_mayer:
            may = ca.substitute([self._mayer_user], [a.t], [Tsym])[0]
            self._mayer_fun = ca.Function("mayer", [Tsym, a.x, a.z, a.w, a.p], [may])
        # bounds: simple (on one decision symbol) or general (path constraints)
        lb = {k: np.full(n, -np.inf) for k, n in (("x", a.nx), ("z", a.nz), ("w", a.nw))}
        ub = {k: np.full(n, np.inf) for k, n in (("x", a.nx), ("z", a.nz), ("w", a.nw))}
        path_exprs, path_lb, path_ub, path_labels = [], [], [], []
        for e, (lo, hi) in self._bounds.items():
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
                raise OCPError(f"contradicting bounds on the same variable ({k}[{bad[0]}])")
        self._lb, self._ub = lb, ub
        for ex, l_, u_, lab in self._path_user:
            path_exprs.append(ex)
            path_lb.append(l_)
            path_ub.append(u_)
            path_labels.extend([lab] * ex.numel()) if ex.numel() > 1 else path_labels.append(lab)
        if path_exprs:
            pe = ca.vertcat(*path_exprs)
            self._path_fun = ca.Function("path", [a.t, a.x, a.z, a.w, a.p], [pe])
            self._path_lb = np.concatenate([np.ravel(x) for x in path_lb])
            self._path_ub = np.concatenate([np.ravel(x) for x in path_ub])
            self._path_labels = path_labels
        else:
            self._path_fun = None
        # boundary conditions as a function of (v0, vT, p, T), v = (x, z, w)
        n = a.nx + a.nz + a.nw
        v0 = ca.SX.sym("v0", n)
        vT = ca.SX.sym("vT", n)
        v = ca.vertcat(a.x, a.z, a.w)
        rows, labels, kinds = [], [], []
        for kind, label, ex, val in self._bc_user:
            e0 = ca.substitute([ex], [ca.vertcat(a.t, v)], [ca.vertcat(0.0, v0)])[0]
            eT = ca.substitute([ex], [ca.vertcat(a.t, v)], [ca.vertcat(Tsym, vT)])[0]
            if isinstance(val, tuple):  # up to sign: b . v(T) = 0, or a minor of [v(T) v(0)]
                rows.append(ca.dot(ca.DM(val[1]), eT) if val[0] == "normal" else
                            eT[0] * e0[1] - eT[1] * e0[0])
            elif kind == "initial":
                rows.append(e0 - val)
            elif kind == "final":
                rows.append(eT - val)
            else:
                rows.append(eT - e0)
            labels.append(label)
            kinds.append(kind)
        bc = ca.vertcat(*rows) if rows else ca.SX(0, 1)
        self._bc_fun = ca.Function("bc", [v0, vT, a.p, Tsym], [bc])
        self._bc_jac = ca.Function(
            "bc_jac", [v0, vT, a.p, Tsym], [ca.jacobian(bc, ca.vertcat(v0, vT))]
        )
        self._bc_labels = labels
        self._bc_kinds = kinds
        man = ca.vertcat(a.alg, a.inv)
        self._man_jac = ca.Function("man_jac", [a.t, v, a.p], [ca.jacobian(man, v)])
        self._man_fun = ca.Function("man", [a.t, v, a.p], [man])
        # the end points' equations (manifold at both ends, all conditions) for the projection
        # of the boundary analysis: residual and Jacobian with respect to (v0, vT)
        ends = ca.vertcat(ca.substitute([man], [ca.vertcat(a.t, v)], [ca.vertcat(0.0, v0)])[0],
                          ca.substitute([man], [ca.vertcat(a.t, v)], [ca.vertcat(Tsym, vT)])[0],
                          bc)
        self._ends_fun = ca.Function("ends", [v0, vT, a.p, Tsym],
                                     [ends, ca.jacobian(ends, ca.vertcat(v0, vT))])
        self._bc_pref = self._preference()
        self._kept = list(range(len(labels)))

    def _levels(self) -> dict[tuple[str, int], int]:
        """Derivative level of every decision symbol: 0 for positions, 1 for velocities...

        A state ``x_i`` with ``x_j' = x_i`` (``p' = v``, or the state ``der(p)``) is one level
        above ``x_j``; an algebraic unknown or control named ``der(q, k)`` is ``k`` levels above
        ``q`` (``der(v)``: acceleration, level 2); other algebraic unknowns one level above the
        highest state; controls and parameters level 0.
        """
        from ..errors import ModelError
        from ..model import element_name, parse_name

        a = self._aug
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
        for i in range(a.np_):
            lev[("p", i)] = 0
        return lev

    def _preference(self) -> list[int]:
        """Order of preference of the boundary conditions when an independent subset is chosen:
        position-level before velocity-level (the highest derivative level of the symbols a
        condition involves), then the order given."""
        a = self._aug
        lev = self._levels()
        keys = []
        for i, (_kind, _label, ex, _val) in enumerate(self._bc_user):
            ws = [a.which(s) for s in ca.symvar(ex)]
            keys.append((max((lev.get(w, 0) for w in ws if w is not None), default=0), i))
        order = sorted(range(len(keys)), key=lambda i: keys[i])
        pref = [0] * len(keys)
        for r, i in enumerate(order):
            pref[i] = r
        return pref

    def _simple_bounds(self):
        return (self._lb["x"], self._ub["x"], self._lb["z"], self._ub["z"],
                self._lb["w"], self._ub["w"])

    def _add_path(self, B, t, X, Z, W, P, frac) -> None:
        if self._path_fun is not None:
            B.con(self._path_fun(t, X, Z, W, P), self._path_lb, self._path_ub,
                  "path constraints", frac, "path", self._path_labels)

    def _add_boundary(self, B, v0, vT, P, T) -> None:
        if not self._kept:
            return
        rows = self._bc_fun(v0, vT, P, T)
        idx = self._kept
        sel = ca.vertcat(*[rows[i] for i in idx])
        B.con(sel, 0.0, 0.0, "boundary conditions", None, "boundary",
              [self._bc_labels[i] for i in idx])

    def _p_guess(self) -> np.ndarray:
        p = self._p_values.copy()
        for i, nm in enumerate(self._aug.p_names):
            if nm in self._free_params:
                p[i] = self._free_params[nm][2]
        return p

    # ------------------------------------------------------------------ analysis
    def boundary_analysis(self, guess=None) -> BoundaryAnalysis:
        """Rank of the boundary conditions restricted to the invariant manifold, near the guess.

        ``a.rank < a.n_conditions`` means that imposing all of them together with the
        invariants is redundant (the naive NLP is rank deficient); ``a.kept`` is the subset
        :meth:`solve` imposes. The rank is evaluated where the conditions hold: at the guess's
        end points projected onto the set where the algebraic equations, the invariants and
        all the conditions hold, and at a random point of that set nearby (``a.ranks``; the
        larger counts). The subset follows an order of preference (``a.preference``):
        conditions on positions before those on velocities (derivative level of the
        variables involved, ``p' = v`` makes ``v`` a velocity), then the order given.

        >>> import casadi as ca, daekit as dk
        >>> m = dk.examples.pendulum3d()
        >>> ocp = dk.OCP(m, t_final=2.0, intervals=10)
        >>> _ = ocp.minimize(integral=ca.sumsqr(m.variables["u"].sym))
        >>> _ = ocp.initial({"p": [0.6, 0.0, -0.8], "v": [0.0, 0.0, 0.0]})
        >>> _ = ocp.final({"p[0]": -0.6, "v": [0.0, 0.0, 0.0]})
        >>> a = ocp.boundary_analysis()
        >>> a.rank, [a.labels[i] for i in a.dropped]   # on the sphere, with p.v = 0
        (7, ['initial p[2]', 'initial v[2]', 'final v[2]'])
        """
        from .guess import make_guess

        self._prepare()
        g = make_guess(self, self._default_guess if guess is None else guess)
        return self._analyze(g)

    def _analyze(self, g, forced=()) -> BoundaryAnalysis:
        """Boundary analysis at the end points of the guess ``g`` (see :meth:`boundary_analysis`).

        The rank of a set of conditions on the manifold matters where they hold: the guess's end
        points are first projected (Gauss-Newton, least-norm steps) onto the set where the
        algebraic equations, the invariants and all the conditions hold (point a); a random
        point of that set nearby (point b) guards against a special point a (e.g. a planar
        guess of a 3D motion). The rank is the larger of the two; the subset imposed is
        independent at that point and, as far as possible, at the other one, and follows the
        order of preference (position level before velocity level, then the order given);
        ``forced`` conditions are taken first.
        """
        from .consistency import project_ends

        a = self._aug
        T = g.T
        x0, z0, w0 = g.fun(np.array([0.0]))
        xT, zT, wT = g.fun(np.array([T]))
        v0 = np.concatenate([x0[:, 0], z0[:, 0], w0[:, 0]])
        vT = np.concatenate([xT[:, 0], zT[:, 0], wT[:, 0]])
        p = g.p
        if not self._bc_labels:
            J0 = np.asarray(self._man_jac(0.0, v0, p))
            JT = np.asarray(self._man_jac(T, vT, p))
            return BoundaryAnalysis([], 0, [], [], np.zeros(0), np.zeros((0, 0)),
                                    (J0.shape[1] - a.nz, JT.shape[1] - a.nz))
        if "periodic" in self._bc_kinds:
            # a non-periodic guess would put point a far from the periodic solutions' set
            vT = v0.copy()
        a0, aT, res_a = project_ends(self._ends_fun, v0, vT, p, T)
        rng = np.random.default_rng(7)
        y = np.concatenate([a0, aT])
        y = y + 0.03 * np.maximum(1.0, np.abs(y)) * rng.standard_normal(y.size)
        n = v0.size
        b0, bT, res_b = project_ends(self._ends_fun, y[:n], y[n:], p, T)
        pts = []
        for e0, eT in ((a0, aT), (b0, bT)):
            pts.append((np.asarray(self._bc_jac(e0, eT, p, T)),
                        np.asarray(self._man_jac(0.0, e0, p)),
                        np.asarray(self._man_jac(T, eT, p))))
        ba = analyze_boundary(self._bc_labels, *pts[0], preference=self._bc_pref,
                              others=pts[1:], forced=list(forced))
        ba.preference = list(self._bc_pref)
        ba.forced = [int(i) for i in forced]
        # the manifold counts w as free directions; report the state-space dimension
        ba.manifold_dims = (ba.manifold_dims[0] - a.nw, ba.manifold_dims[1] - a.nw)
        ba.notes.append(
            "rank evaluated at the guess's end points projected onto the manifold and the given "
            f"conditions (residual {res_a:.1e}) and at a random point of that set nearby "
            f"(residual {res_b:.1e}): ranks {ba.ranks[0]} and {ba.ranks[1]}"
        )
        ba.residual = float(res_a)
        lim = [1e-6 * max(1.0, float(np.max(np.abs(np.concatenate(e)), initial=0.0)))
               for e in ((a0, aT), (b0, bT))]
        if res_a > lim[0] and res_b > lim[1]:
            # starts of the consistency tests: the least-squares point, perturbed copies of it
            # (a projection can stop at a symmetric stationary point, e.g. p = (0.5, 0, 0)
            # for a unit rod, which a perturbation breaks), and the guess
            ya = np.concatenate([a0, aT])
            sc = np.maximum(1.0, np.abs(ya))
            starts = [(a0, aT)]
            for amp in (0.03, 0.3):
                yp = ya + amp * sc * rng.standard_normal(ya.size)
                starts.append((yp[:n], yp[n:]))
            self._find_conflict(ba, [*starts, (v0, vT)], p, T)
        if res_a > lim[0] and not ba.conflict:
            ba.notes.append(
                "the conditions could not all be met together with the invariants near the "
                f"guess (least-squares residual {res_a:.2e})"
            )
        return ba

    def _find_conflict(self, ba: BoundaryAnalysis, starts, p, T) -> None:
        """Fill ``ba.conflict`` when the boundary conditions contradict each other.

        Called when the projection of the analysis leaves a residual (from two starts): a
        minimal contradictory subset is found by a deletion filter
        (:func:`~daekit.ocp.consistency.conflicting_conditions`) that tries to remove the
        conditions with the smallest residual at the least-squares point first, so that the
        ones carrying the residual are those named.
        """
        from .consistency import conflicting_conditions

        n_fixed = 2 * int(self._man_fun.size1_out(0))
        a0, aT = starts[0]
        r = np.asarray(self._ends_fun(a0, aT, p, T)[0], float).ravel()[n_fixed:]
        order = sorted(range(r.size), key=lambda i: (abs(r[i]), -i))
        found = conflicting_conditions(self._ends_fun, n_fixed, r.size, starts, p, T, order)
        if found is None:
            return
        ba.conflict, ba.conflict_alone = found
        ba.conflict_residuals = r
        ba.kept, ba.dropped = list(range(r.size)), []

    # ------------------------------------------------------------------ solve
    def solve(
        self,
        guess=None,
        redundancy: str = "drop",
        raise_on_failure: bool = False,
        check: bool = True,
    ) -> OCPSolution:
        """Transcribe and solve with IPOPT; returns an :class:`OCPSolution`.

        Parameters
        ----------
        guess : None, Trajectory, OCPSolution, or dict
            None: simulate the model from a consistent initial point with the controls at
            zero (clipped to their bounds). A :class:`daekit.Trajectory` from
            :func:`daekit.simulate` (your simulation with controls of your choice): its values
            by the original names are interpolated onto the NLP's grid (with a free final
            time, its last time is the guess of ``T``). A previous :class:`OCPSolution`: warm
            start from it (its decision vector as is when the NLP is the same, else
            interpolated by names: a collocation solution can start a shooting solve). A
            dict: constant or callable guesses for controls (``{"u": lambda t: ...}``, used
            in the simulation) and constant guesses for states at ``t = 0``.
            Contradictory boundary conditions (no point satisfies them all together with the
            algebraic equations and the invariants, e.g. ``initial s = 0``, ``final s = 1`` and
            ``periodic s``) are found by the boundary analysis before anything is dropped:
            IPOPT is not run, ``sol.status`` is ``"Contradictory_Boundary_Conditions"`` and
            the report names a minimal contradictory subset (``sol.boundary.conflict``).
        redundancy : {"drop", "keep"}
            "drop" imposes an independent subset of the boundary conditions on the invariant
            manifold (see :mod:`daekit.ocp.consistency` and :meth:`boundary_analysis`); if a
            dropped condition then does not hold at the solution (residual above
            ``1e-4 * max(1, |x(0)|)``: another branch of the constraints), the problem is solved
            once more from that solution with the violated conditions imposed (the report
            says so and ``stats["resolved"]`` holds the first objective and the conditions
            forced); if they still do not hold, ``success`` is False and the report names
            them. "keep" imposes all (naive).
        check : bool
            First check that the initial (final) conditions, the algebraic equations, the
            invariants, the bounds and the path constraints can hold together at ``t = 0``
            (``t = T``), by a small least-squares problem; if they cannot, IPOPT is not run and
            the report names the conditions at fault (status
            ``"Infeasible_Boundary_Conditions"``).
        raise_on_failure : bool
            Raise :class:`~daekit.errors.OCPError` with the report when IPOPT does not succeed
            (otherwise ``sol.success`` is False and ``sol.report`` says why).
        """
        from .guess import make_guess

        if redundancy not in ("drop", "keep"):
            raise OCPError(f"solve(redundancy=...): 'drop' or 'keep', got {redundancy!r}")
        t_start = _time.perf_counter()
        self._prepare()
        g = make_guess(self, self._default_guess if guess is None else guess)
        ba = self._analyze(g)
        sol = self._solve_once(g, ba, redundancy, check, t_start)
        if redundancy == "drop" and sol.success and ba.dropped:
            sol = self._resolve_violated(sol, ba, check)
        if not sol.success and raise_on_failure:
            raise OCPError(sol.report)
        return sol

    def _dropped_violations(self, sol, ba) -> list[tuple[int, float]]:
        """Dropped conditions that do not hold at ``sol``: ``[(index, residual)]``.

        A dropped condition is implied by the kept ones and the invariants near the point of
        the analysis; at the solution it holds to the accuracy the invariants hold at the ends
        (the discretization's). A residual above ``1e-4 * max(1, |end state|)`` means that the
        solution reached another branch of the constraints where it is not implied.
        """
        res, scale = sol._bc_residuals
        return [(i, float(res[i])) for i in ba.dropped if abs(res[i]) > 1e-4 * scale]

    def _resolve_violated(self, first, ba, check: bool):
        """Re-solve once, from ``first``, imposing the dropped conditions it violates."""
        from .guess import make_guess

        viol = self._dropped_violations(first, ba)
        if not viol:
            return first
        t0 = _time.perf_counter()
        forced = [i for i, _ in viol]
        g = make_guess(self, first)
        ba2 = self._analyze(g, forced=forced)
        labels = [ba.labels[i] for i in forced]
        swapped = [ba.labels[i] for i in ba.kept if i not in ba2.kept]
        sol = self._solve_once(g, ba2, "drop", check, t0)
        first_txt = (
            f"First solve: {first.status}, objective {first.objective:.10g}, but the dropped "
            + ", ".join(f"{ba.labels[i]} (residual {r:+.3g})" for i, r in viol)
            + " did not hold: the solution reached a branch of the constraints where "
            + ("it is" if len(viol) == 1 else "they are")
            + " not implied by the others. Re-solved from that solution imposing "
            + _list_or_none(labels)
            + " instead of " + _list_or_none(swapped) + "."
        )
        sol.stats["resolved"] = {"first_objective": first.objective,
                                 "first_status": first.status, "forced": labels,
                                 "first_iter_count": first.stats.get("iter_count")}
        lines = sol.report.split("\n")
        lines.insert(1, first_txt)
        problems = [ba.labels[i] for i in forced if i not in ba2.kept]
        viol2 = self._dropped_violations(sol, ba2) if sol.success else []
        if viol2 or problems or not sol.success:
            bad = problems + [ba2.labels[i] for i, _ in viol2]
            sol.success = False
            lines.append(
                "FAILED: after the re-solve the boundary condition(s) "
                + _list_or_none(bad or labels)
                + " still do not hold together with the others at the solution; give a guess "
                "on the intended branch (e.g. a simulation near the intended motion) or state "
                "the conditions so that they select it."
            )
        sol.report = "\n".join(lines)
        return sol

    def _solve_once(self, g, ba, redundancy: str, check: bool, t_start: float):
        """One transcription and IPOPT run with the boundary selection of ``ba``."""
        from .report import diagnose, endpoint_checks

        self._last_boundary = ba
        self._kept = ba.kept if redundancy == "drop" else list(range(len(self._bc_labels)))
        if self.method == "collocation":
            from .collocation import transcribe
        else:
            from .shooting import transcribe
        tr = transcribe(self, g.fun, g.T, g.p)
        B = tr.builder
        lbx, ubx, x0, lbg, ubg = B.arrays()
        if (g.V is not None and g.V.size == x0.size and g.key is not None
                and g.key[:-1] == self._structure_key()[:-1]):
            # the same variables (the boundary selection, last in the key, only changes rows)
            x0 = g.V.copy()
        x0 = np.clip(x0, lbx, ubx)
        V, G = B.V(), B.G()
        opts = {"ipopt.print_level": 5 if self.verbose else 0, "print_time": self.verbose,
                "ipopt.sb": "yes"}
        if not tr.hessian_exact:
            opts["ipopt.hessian_approximation"] = "limited-memory"
        for k, val in self.solver_options.items():
            opts[k if "." in k or k in ("print_time", "expand") else f"ipopt.{k}"] = val
        opts.setdefault("ipopt.max_iter", 1000)
        # MUMPS' permuting scaling (an MC64-type matching) costs seconds per factorization on
        # these banded collocation KKT systems (measured: 10 s -> 0.34 s for 15 iterations on
        # 3400 variables); switch it off unless the user asks for it
        opts.setdefault("ipopt.mumps_permuting_scaling", 0)
        pre = endpoint_checks(self, g) if check else []
        if ba.conflict:
            # contradictory conditions: no NLP point satisfies them, do not run IPOPT
            pre = [_conflict_message(ba, self._aug.inv_names)] + pre
        try:
            solver = ca.nlpsol("ocp", "ipopt", {"x": V, "f": tr.J, "g": G}, opts)
        except RuntimeError as exc:
            raise OCPError(f"could not build the NLP solver: {exc}") from None
        t_build = _time.perf_counter() - t_start
        if pre:
            # the end-point conditions cannot hold: do not run IPOPT into a wall
            fx = ca.Function("fg", [V], [tr.J, G])(x0)
            res = {"x": x0, "f": fx[0], "g": fx[1]}
            status = ("Contradictory_Boundary_Conditions" if ba.conflict
                      else "Infeasible_Boundary_Conditions")
            stats = {"return_status": status, "success": False,
                     "iter_count": 0}
        else:
            t_solve = _time.perf_counter()
            with quiet(not self.verbose):
                res = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
            t_solve = _time.perf_counter() - t_solve
            stats = dict(solver.stats())
            stats["t_solve"] = t_solve
        stats["t_build"] = t_build
        stats["t_total"] = _time.perf_counter() - t_start
        stats["n_variables"] = int(V.numel())
        stats["n_constraints"] = int(G.numel())
        status = str(stats.get("return_status", "unknown"))
        success = bool(stats.get("success", False)) or status in _STATUS_OK
        Vopt = np.asarray(res["x"]).ravel()
        gopt = np.asarray(res["g"]).ravel()
        viol_g = np.maximum(np.maximum(lbg - gopt, gopt - ubg), 0.0)
        viol_x = np.maximum(np.maximum(lbx - Vopt, Vopt - ubx), 0.0)
        stats.update({
            "objective": float(res["f"]),
            "method": self.method,
            "transcription": tr.method,
            "intervals": self.intervals,
            "guess": g.note,
            "max_constraint_violation": float(np.max(viol_g, initial=0.0)),
            "max_bound_violation": float(np.max(viol_x, initial=0.0)),
            "n_boundary_conditions": len(self._bc_labels),
            "boundary_rank": ba.rank,
            "boundary_dropped": [ba.labels[i] for i in ba.dropped] if redundancy == "drop" else [],
        })
        sol = OCPSolution._from_grid(self, tr, Vopt, float(res["f"]), success, status, stats)
        sol.boundary = ba
        sol.report, sol.infeasibilities = diagnose(
            self, tr, ba, Vopt, gopt, lbg, ubg, lbx, ubx, success, status, stats, g, pre
        )
        v0e, vTe, Pe, Te = (np.asarray(x) for x in tr.ends(Vopt))
        res = np.asarray(self._bc_fun(v0e, vTe, Pe, Te), float).ravel()
        sol._bc_residuals = (res, max(1.0, float(np.max(np.abs(v0e), initial=1.0))))
        return sol

    def _structure_key(self):
        return (self.method, self.intervals, self.degree, self.control_mode,
                self._T_free is not None, tuple(sorted(self._free_params)), tuple(self._kept))


def _list_or_none(items: list[str]) -> str:
    return ", ".join(items) if items else "nothing"


def _conflict_message(ba: BoundaryAnalysis, inv_names) -> str:
    """The report's line for contradictory boundary conditions (``ba.conflict``)."""
    names = [ba.labels[i] for i in ba.conflict]
    res = ba.conflict_residuals
    what = ("the invariants (" + ", ".join(inv_names) + ") and the algebraic equations"
            if len(inv_names) else "the algebraic equations")
    if len(names) == 1:
        head = f"the boundary condition {names[0]} cannot hold together with {what}"
        drop = "without it the rest are consistent"
    elif ba.conflict_alone:
        head = f"the boundary conditions {', '.join(names)} contradict each other"
    else:
        head = (f"the boundary conditions {', '.join(names)} contradict each other "
                f"(together with {what})")
    if len(names) > 1:
        drop = "dropping any one of them makes the rest consistent"
    resid = ", ".join(f"{ba.labels[i]} {res[i]:+.3g}" for i in ba.conflict) if res.size else ""
    return (
        f"CONTRADICTORY BOUNDARY CONDITIONS: {head}; {drop}. "
        + (f"At the closest point (least squares) their residuals are {resid} "
           f"(largest residual {ba.residual:.3g}). " if resid else "")
        + "Nothing was dropped and IPOPT was not run: remove or correct one of them."
    )


class OCPSolution:
    """The solution of an :class:`OCP`: the same interface as a simulation Trajectory.

    Attributes
    ----------
    success : bool
        IPOPT converged (``Solve_Succeeded`` or ``Solved_To_Acceptable_Level``).
    status : str
        IPOPT's return status, or daekit's when IPOPT was not run:
        ``"Contradictory_Boundary_Conditions"`` (see :attr:`BoundaryAnalysis.conflict`),
        ``"Infeasible_Boundary_Conditions"`` (the end-point check of ``solve(check=True)``).
    objective : float
    t : numpy.ndarray
        Time grid: ``0`` and every collocation point (shooting: the interval boundaries).
    T : float
        Final time.
    invariants : numpy.ndarray (len(t), number of invariants)
        The invariants along the solution (small: they are imposed at ``t = 0`` only).
    invariant_names : list of str
    parameters : dict
        Parameter values used (free ones at their optimum).
    stats : dict
        IPOPT's statistics (``iter_count``, ``return_status``, ``iterations``: the history of
        objective and infeasibilities, ``t_wall_nlp_*``: time per function) and daekit's:
        ``objective``, ``method``, ``transcription``, ``intervals``, ``guess`` (where the
        initial guess came from), ``t_build``, ``t_solve``, ``t_total``, ``n_variables``,
        ``n_constraints``, ``max_constraint_violation``, ``max_bound_violation``,
        ``max_invariant_t0``, ``max_invariant`` (on the grid), ``n_boundary_conditions``,
        ``boundary_rank``, ``boundary_dropped``, and ``resolved`` (only after a second solve
        that imposed violated dropped conditions: ``first_objective``, ``first_status``,
        ``first_iter_count``, ``forced``).
    method : str
        ``"collocation"`` or ``"shooting"``.
    report : str
        What was done: reduction, transcription, boundary conditions kept and dropped (and why),
        solver outcome, and on failure the constraints at fault.
    infeasibilities : list of (label, violation, time)
        Largest constraint violations at the returned point (empty on success).

    ``sol["p"]`` gives any original variable or element by name, ``(len(t),)`` for one element,
    ``(len(t), k)`` for a vector. Controls are read left-continuously: the value at a grid time
    is that of the interval ending there (at ``t = 0``, the first interval's).
    :meth:`simulate` gives a finer :class:`daekit.Trajectory` by integrating with the optimal
    controls; :attr:`controls` the decision controls on the grid.
    """

    def __init__(self) -> None:
        self.success = False
        self.status = ""
        self.objective = float("nan")
        self.t = np.zeros(0)
        self.T = float("nan")
        self.invariants = np.zeros((0, 0))
        self.invariant_names: list[str] = []
        self.parameters: dict[str, float] = {}
        self.stats: dict = {}
        self.report = ""
        self.infeasibilities: list = []
        self.boundary: BoundaryAnalysis | None = None
        self.method = ""
        self._bc_residuals: tuple[np.ndarray, float] = (np.zeros(0), 1.0)

    @classmethod
    def _from_grid(cls, ocp: OCP, tr, V, f, success, status, stats) -> OCPSolution:
        s = cls()
        a = ocp._aug
        fr, X, Z, W, T, P = (np.asarray(v) for v in tr.grid(V))
        s.T = float(np.asarray(T).ravel()[0])
        s.t = np.asarray(fr).ravel() * s.T
        s._X, s._Z, s._W, s._P = X, Z, W, np.asarray(P).ravel()
        s._aug = a
        s._V = V
        s._key = ocp._structure_key()
        s.success, s.status, s.objective, s.stats = success, status, f, stats
        s.parameters = dict(zip(a.p_names, s._P.tolist(), strict=True))
        s.invariant_names = list(a.inv_names)
        if a.inv.numel():
            s.invariants = s._eval(a.inv)
        else:
            s.invariants = np.zeros((s.t.size, 0))
        s.method = ocp.method
        s._N = ocp.intervals
        s._ncoef = tr.ncoef
        s._node_index = list(tr.node_index) if tr.node_index is not None else None
        s._Wint = None
        if tr.controls is not None:
            s._Wint = np.asarray(tr.controls(V)).reshape(a.nw, ocp.intervals * tr.ncoef)
        s._integrator_options = dict(ocp.integrator_options)
        if s.invariants.size:
            stats["max_invariant_t0"] = float(np.max(np.abs(s.invariants[0])))
            stats["max_invariant"] = float(np.max(np.abs(s.invariants)))
        return s

    def _eval(self, expr: ca.SX) -> np.ndarray:
        a = self._aug
        fn = ca.Function("ev", [a.t, a.x, a.z, a.w, a.p], [expr])
        n = self.t.size
        out = fn.map(n)(self.t.reshape(1, -1), self._X, self._Z, self._W,
                        np.repeat(self._P.reshape(-1, 1), n, axis=1))
        return np.asarray(out).T

    def __getitem__(self, name: str) -> np.ndarray:
        els = self._aug.elements(name, f"solution[{name!r}]")
        val = self._eval(ca.vertcat(*[self._aug.names[e] for e in els]))
        return val[:, 0] if len(els) == 1 else val

    def simulate(self, points_per_interval: int = 10, rtol: float | None = None,
                 atol: float | None = None):
        """Finer output: integrate each interval with IDAS from the solution's state at its
        start, with the optimal controls, and return a :class:`daekit.Trajectory`.

        The time grid has ``points_per_interval`` equally spaced points on each interval (and
        ``t = 0``); values by the original model's names, the invariants, and in ``stats``
        ``"node_mismatch"``: the largest difference between an interval's integrated end state
        and the solution's state there (zero up to the integrator's tolerance for shooting;
        for collocation, an a posteriori estimate of its discretization error).

        >>> import daekit as dk
        >>> m = dk.Model("cart"); s = m.state("s"); u = m.control("u")
        >>> _ = m.equation(m.der(s, 2) - u, name="newton")
        >>> ocp = dk.OCP(m, t_final=1.0, intervals=4, method="shooting")
        >>> _ = ocp.minimize(integral=u**2).initial({"s": 0, "der(s)": 0}).final({"s": 1})
        >>> fine = ocp.solve().simulate(points_per_interval=5)
        >>> fine.t.size, round(float(fine["s"][-1]), 8), fine.stats["node_mismatch"] < 1e-8
        (21, 1.0, True)
        """
        from ..simulate import Trajectory
        from .collocation import radau_coefficients
        from .shooting import DEFAULT_INTEGRATOR_OPTIONS, interval_integrator

        if self._Wint is None or self._node_index is None:
            raise OCPError("this solution has no interval data to simulate from")
        n = int(points_per_interval)
        if n < 1:
            raise OCPError(f"simulate(points_per_interval={points_per_interval!r}): need >= 1")
        a, N, nc = self._aug, self._N, self._ncoef
        opts = {**DEFAULT_INTEGRATOR_OPTIONS, **self._integrator_options}
        if rtol is not None:
            opts["reltol"] = float(rtol)
        if atol is not None:
            opts["abstol"] = float(atol)
        svals = np.linspace(0.0, 1.0, n + 1)[1:]
        F = interval_integrator(a, None, tout=svals, ncoef=nc, options=opts, name="dense")
        h = self.T / N
        idx = self._node_index
        X0, Z0 = self._X[:, idx[:N]], self._Z[:, idx[:N]]
        Wc = self._Wint.reshape(a.nw, N, nc).transpose(2, 0, 1).reshape(a.nw * nc, N)
        P = np.vstack([Wc, np.repeat(self._P.reshape(-1, 1), N, axis=1),
                       h * np.arange(N).reshape(1, -1), np.full((1, N), h)])
        try:
            with quiet():
                res = F.map(N)(x0=X0, z0=Z0, p=P)
        except RuntimeError as exc:
            raise OCPError(
                "simulating the solution failed: "
                f"{str(exc).strip().splitlines()[-1]} (try rtol/atol)"
            ) from None
        xf = np.asarray(res["xf"]).reshape(a.nx, N * n)
        zf = np.asarray(res["zf"]).reshape(a.nz, N * n)
        if nc == 1:
            basis = np.ones((n, 1))
        else:
            tau = radau_coefficients(nc)[0][1:]
            basis = np.array([[np.prod([(sv - tau[q]) / (tau[r] - tau[q])
                                        for q in range(nc) if q != r]) for r in range(nc)]
                              for sv in svals])
        Wd = np.einsum("jr,wkr->wkj", basis, self._Wint.reshape(a.nw, N, nc)).reshape(a.nw, N * n)
        t = np.concatenate([[0.0], (np.arange(N).reshape(-1, 1) + svals).ravel() * h])
        X = np.hstack([self._X[:, :1], xf])
        Z = np.hstack([self._Z[:, :1], zf])
        W = np.hstack([self._W[:, :1], Wd])
        ends = xf[:, n - 1::n]
        mismatch = float(np.max(np.abs(ends - self._X[:, idx[1:]]), initial=0.0))
        names = list(a.names)
        fn = ca.Function("ev", [a.t, a.x, a.z, a.w, a.p],
                         [ca.vertcat(*[ca.SX(a.names[k]) for k in names]), a.inv])
        m = t.size
        vals, inv = fn.map(m)(t.reshape(1, -1), X, Z, W, np.repeat(self._P.reshape(-1, 1), m, 1))
        vals, inv = np.asarray(vals), np.asarray(inv)
        return Trajectory(
            t, {k: vals[i] for i, k in enumerate(names)}, inv.T if inv.size else None,
            self.invariant_names,
            {"method": f"IDAS re-simulation of the {self.method} solution, interval by interval",
             "node_mismatch": mismatch, "points_per_interval": n},
        )

    @property
    def controls(self) -> dict[str, np.ndarray]:
        """The decision controls on the grid by name."""
        return {n: self._W[i, :].copy() for i, n in enumerate(self._aug.w_names)}

    def __repr__(self) -> str:
        return (f"OCPSolution(success={self.success}, status={self.status!r}, "
                f"objective={self.objective:.10g}, T={self.T:.6g}, {self.t.size} time points)")
