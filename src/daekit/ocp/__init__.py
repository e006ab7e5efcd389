"""Optimal control on DAEs of any index: ``OCP``, ``Free``, ``OCPSolution``.

The model is reduced to index 1 (or given as a :class:`~daekit.reduced.ReducedDAE`); the
optimal control problem is transcribed (direct collocation with Radau IIA by default, or
multiple shooting on IDAS) and solved with IPOPT through CasADi. The consistency conditions
(invariants) are imposed at the initial time only, and boundary conditions that are redundant
with them (full periodicity of a constrained mechanism) are detected and dropped where the
rank decision is valid (a dropped condition the solution turns out to violate is imposed in a
second solve); IPOPT always runs unless the conditions are proven contradictory (then they are
named and nothing is solved); the solution's :attr:`OCPSolution.report` says what was done.

Layout: :class:`OCP` is the statement builder; :meth:`OCP.compile` freezes it into a
:class:`~daekit.ocp.compiled.Problem`, which :mod:`~daekit.ocp.guess`,
:mod:`~daekit.ocp.boundary` (which conditions to impose), :mod:`~daekit.ocp.collocation` and
:mod:`~daekit.ocp.shooting` (sharing :mod:`~daekit.ocp.transcription`), :mod:`~daekit.ocp.run`
(one IPOPT run), :mod:`~daekit.ocp.resolve` (the second solve) and :mod:`~daekit.ocp.report`
read; :mod:`~daekit.ocp.solution` builds the :class:`OCPSolution`.

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
from ..model import comparison_parts
from ..reduced import ReducedDAE
from ..wording import count
from .compiled import Problem, compile_problem
from .consistency import BoundaryAnalysis
from .problem import Augmented, augment
from .solution import OCPSolution

__all__ = ["OCP", "Free", "OCPSolution", "BoundaryAnalysis", "Problem"]


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
        raise OCPError(f"{what}: expected {count(n, 'value')}, got {arr.size}")
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
        elif (hasattr(model, "equations") and hasattr(model, "variables")) or hasattr(
                model, "index1"):  # a Model, or a LagrangianSystem (reduced as its .model())
            from ..reduction import reduce_index

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
            e = _no_comparison(self._aug.map_expr(integral, "the integral objective"),
                               "the integral objective")
            if e.numel() != 1:
                raise OCPError(f"the integral objective must be a scalar, got {e.numel()} elements")
            self._lagrange_user = e
        if final is not None:
            e = _no_comparison(self._aug.map_expr(final, "the final objective"),
                               "the final objective")
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
        """Path constraint ``lb <= expr <= ub`` at every collocation point (and at ``t = 0``).
        ``expr`` may instead be a condition, ``ocp.constrain(ca.dot(p, p) <= 4)`` (``>=``,
        ``==``, and ``<``, ``>`` taken as ``<=``, ``>=``), element by element, with ``lb`` and
        ``ub`` left out.

        >>> import casadi as ca, daekit as dk
        >>> m = dk.examples.pendulum_planar()
        >>> x = m.variables["x"].sym
        >>> ocp = dk.OCP(m, t_final=1.0).constrain(x >= -0.5, name="wall")
        """
        label = name or f"path constraint #{len(self._path_user) + 1}"
        e = self._aug.map_expr(expr, f"ocp.constrain ({label})")
        parts = comparison_parts(e)
        if parts is not None:
            if np.any(np.isfinite(np.asarray(lb, dtype=float))) or np.any(
                    np.isfinite(np.asarray(ub, dtype=float))):
                raise OCPError(
                    f"ocp.constrain ({label}): give either a condition (x <= 1) or an expression "
                    "with bounds (x, lb, ub), not both"
                )
            e, lb, ub = _condition_bounds(parts, f"ocp.constrain ({label})")
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
            if not np.all(np.isfinite(vals)):
                raise OCPError(
                    f"ocp.{kind}({{{name!r}: {val!r}}}): boundary values must be finite "
                    "numbers; give the value, or leave the condition out"
                )
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

    def parameter_values(self) -> dict[str, float]:
        """The fixed parameter values, one per parameter element: ``{"L": 1.0, ...}`` (what
        :meth:`set_parameters` takes back, e.g. to restore them after a sweep).

        >>> import daekit as dk
        >>> m = dk.Model("cart"); s = m.state("s"); u = m.control("u")
        >>> M = m.parameter("M", 1.0)
        >>> _ = m.equation(M * m.der(s, 2) - u, name="newton")
        >>> OCP(m).set_parameters({"M": 2.0}).parameter_values()
        {'M': 2.0}
        """
        return dict(zip(self._aug.p_names, self._p_values.tolist(), strict=True))

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

    # ------------------------------------------------------------------ compilation
    def compile(self) -> Problem:
        """The statement as a frozen :class:`~daekit.ocp.compiled.Problem` (CasADi functions of
        the objective, bounds, path constraints, boundary conditions and manifold), which the
        transcriptions, the guess, the boundary analysis and the report read.

        >>> import daekit as dk
        >>> m = dk.Model("cart"); s = m.state("s"); u = m.control("u")
        >>> _ = m.equation(m.der(s, 2) - u, name="newton")
        >>> prob = OCP(m).minimize(integral=u**2).initial({"s": 0}).compile()
        >>> prob.bc_labels, prob.aug.x_names
        (['initial s'], ['s', 'der(s)'])
        """
        return compile_problem(self)

    # ------------------------------------------------------------------ analysis
    def boundary_analysis(self, guess=None) -> BoundaryAnalysis:
        """Rank of the boundary conditions restricted to the invariant manifold, near the guess.

        ``a.rank < a.n_conditions`` means that imposing all of them together with the
        invariants is redundant (the naive NLP is rank deficient); ``a.kept`` is the subset
        :meth:`solve` imposes, ``a.selectors`` the dropped ones that select a branch (imposed
        as inequalities). See :mod:`daekit.ocp.boundary` for where the rank is evaluated and
        when a condition counts as implied. The subset follows an order of preference
        (``a.preference``): conditions on positions before those on velocities (derivative
        level of the variables involved, ``p' = v`` makes ``v`` a velocity), then the order
        given.

        >>> import casadi as ca, daekit as dk
        >>> m = dk.examples.pendulum3d()
        >>> ocp = dk.OCP(m, t_final=2.0, intervals=10)
        >>> _ = ocp.minimize(integral=ca.sumsqr(m.variables["u"].sym))
        >>> _ = ocp.initial({"p": [0.6, 0.0, -0.8], "v": [0.0, 0.0, 0.0]})
        >>> _ = ocp.final({"p[0]": -0.6, "v": [0.0, 0.0, 0.0]})
        >>> a = ocp.boundary_analysis()
        >>> a.rank, [a.labels[i] for i in a.dropped]   # on the sphere, with p.v = 0
        (7, ['initial p[2]', 'initial v[2]', 'final v[2]'])
        >>> "initial p[2]" in [a.labels[i] for i, lo, hi in a.selectors]   # p[2] = -0.8 or +0.8
        True
        """
        from .boundary import analyze
        from .guess import make_guess

        prob = self.compile()
        g = make_guess(prob, prob.default_guess if guess is None else guess)
        return analyze(prob, g)

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
            zero (clipped to their bounds); where that simulation does not end where the final
            conditions ask, the states blend from it to a consistent final point (see
            :mod:`daekit.ocp.guess`). A :class:`daekit.Trajectory` from
            :func:`daekit.simulate` (your simulation with controls of your choice): its values
            by the original names are interpolated onto the NLP's grid (with a free final
            time, its last time is the guess of ``T``). A previous :class:`OCPSolution`: warm
            start from it (its decision vector as is when the NLP is the same, else
            interpolated by names: a collocation solution can start a shooting solve). A
            dict: constant or callable guesses for controls (``{"u": lambda t: ...}``, used
            in the simulation) and constant guesses for states at ``t = 0``.
        redundancy : {"drop", "keep"}
            "drop" imposes an independent subset of the boundary conditions on the invariant
            manifold (see :mod:`daekit.ocp.boundary`); branch-selecting ones are kept as
            inequalities; if a dropped condition then does not hold at the solution (residual
            above ``1e-4 * max(1, |end states|)``: another branch), the problem is solved once
            more from that solution with the violated conditions imposed (the report says so
            and ``stats["resolved"]`` holds the first objective and the conditions forced); if
            any condition still does not hold, ``success`` is False and the report names it.
            "keep" imposes all (naive).
        check : bool
            After a failed run, check whether the initial (final) conditions, the model's
            equations, the bounds and the path constraints can hold together at ``t = 0``
            (``t = T``), by a small least-squares problem, and name the conditions at fault.
            IPOPT is always run, except when the conditions are *proven* contradictory
            (affine conditions that contradict each other, e.g. ``initial s = 0``,
            ``final s = 1`` and ``periodic s``, or a value outside a variable's bounds): then
            ``sol.status`` is ``"Contradictory_Boundary_Conditions"`` and the report names a
            minimal contradictory subset (``sol.boundary.conflict``).
        raise_on_failure : bool
            Raise :class:`~daekit.errors.OCPError` with the report when IPOPT does not succeed
            (otherwise ``sol.success`` is False and ``sol.report`` says why).
        """
        from .boundary import analyze
        from .guess import make_guess
        from .resolve import resolve_violated
        from .run import solve_once

        if redundancy not in ("drop", "keep"):
            raise OCPError(f"solve(redundancy=...): 'drop' or 'keep', got {redundancy!r}")
        t_start = _time.perf_counter()
        prob = self.compile()
        g = make_guess(prob, prob.default_guess if guess is None else guess)
        ba = analyze(prob, g)
        self._last_boundary = ba
        sol = solve_once(prob, g, ba, redundancy, check, t_start)
        if (not sol.success and redundancy == "drop" and ba.selectors and not ba.proven
                and sol.stats.get("boundary_selectors_imposed")):
            # the branch inequalities can trap IPOPT when the guess lies on another branch:
            # once more without them (the dropped conditions are then checked, and imposed by
            # the re-solve if violated)
            first = sol
            sol = solve_once(prob, g, ba, redundancy, check, _time.perf_counter(),
                             selectors=False)
            retry = {"status": first.status, "iter_count": first.stats.get("iter_count")}
        else:
            retry = None
        if redundancy == "drop" and sol.success and ba.dropped:
            sol = resolve_violated(prob, sol, ba, check, make_guess)
        if retry is not None:
            sol.stats["first_with_branch_inequalities"] = retry
            lines = sol.report.split("\n")
            lines.insert(1, f"First run with the branch inequalities: {retry['status']} after "
                            f"{retry['iter_count']} iterations (the guess lies on another "
                            "branch); run again without them.")
            sol.report = "\n".join(lines)
        if not sol.success and raise_on_failure:
            raise OCPError(sol.report)
        return sol




def _no_comparison(e: ca.SX, what: str) -> ca.SX:
    """``e``, or an :class:`OCPError` where it is a comparison (a 0/1 value, no objective)."""
    parts = comparison_parts(e)
    if parts is not None and any(op is not None for op in parts[0]):
        raise OCPError(
            f"{what} is a comparison, whose value is 0 or 1: minimize a numeric "
            "expression, and state conditions with ocp.constrain or ocp.bound"
        )
    return e


def _condition_bounds(parts, what: str) -> tuple[ca.SX, np.ndarray, np.ndarray]:
    """``(expr, lb, ub)`` of the conditions ``parts`` (:func:`daekit.model.comparison_parts`):
    ``a <= c`` with a constant ``c`` is ``a`` bounded above by ``c`` (a constant on the left
    bounds below), otherwise ``a - b <= 0``; ``==`` gives ``lb = ub``."""
    ops, lhs, rhs = parts
    exprs, lb, ub = [], [], []
    for k, op in enumerate(ops):
        if op not in ("<=", "<", "=="):
            shown = "no comparison" if op is None else repr(op)
            raise OCPError(
                f"{what}: element {k} is {shown}; a condition takes <=, >=, <, > or == on "
                "every element"
            )
        a, b = lhs[k], rhs[k]
        if b.is_constant():
            e, lo, hi = a, -np.inf, float(b)
        elif a.is_constant():
            e, lo, hi = b, float(a), np.inf
        else:
            e, lo, hi = a - b, -np.inf, 0.0
        if op == "==":
            lo = hi = hi if np.isfinite(hi) else lo
        exprs.append(e)
        lb.append(lo)
        ub.append(hi)
    return ca.vertcat(*exprs), np.array(lb), np.array(ub)
