"""The model: variables, derivatives, equations, parameters, and their validation.

A :class:`Model` holds a DAE as a person writes it, ``F(t, x, x', x'', ..., z, u, p) = 0``,
in residual form. Variables are CasADi SX column vectors; their elements are named ``p[0]``,
derivatives ``der(p)[0]``, ``der(p,2)[0]`` (scalars: ``z``, ``der(z)``).

Example
-------
>>> import casadi as ca, daekit as dk
>>> m = dk.Model("pendulum")
>>> p = m.state("p", 2); v = m.state("v", 2); z = m.algebraic("z")
>>> _ = m.equation(m.der(p) - v, name="kinematics")
>>> _ = m.equation(m.der(v) - (ca.DM([0, -9.81]) - z * p), name="newton")
>>> _ = m.equation(0.5 * (ca.dot(p, p) - 1), name="rod")
>>> m.n_equations, m.n_unknowns
(5, 5)
"""

from __future__ import annotations

import copy
import math
import re
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .errors import ModelError, StructuralError
from .wording import count, listing

__all__ = ["Model", "Variable", "Equation", "Event", "parse_name", "element_name", "expand_name",
           "select_name", "fit_elements", "NameNotFoundError", "comparison_parts"]

UNKNOWN_KINDS = ("state", "algebraic", "variable")
#: :meth:`Model.symbols_at` of at most this many symbols picks the scalar symbols themselves
#: (one ``vertcat``) instead of indexing stacked columns (NumPy set-up costs more there).
SMALL_SYMBOLS = 32
KINDS = UNKNOWN_KINDS + ("control", "parameter")
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.]*$")
_REF_RE = re.compile(
    r"^\s*(?:der\(\s*(?P<dname>[A-Za-z_][A-Za-z0-9_.]*)\s*(?:,\s*(?P<order>\d+)\s*)?\)"
    r"|(?P<name>[A-Za-z_][A-Za-z0-9_.]*))\s*(?:\[\s*(?P<index>\d+)\s*\])?\s*$"
)


def element_name(name: str, size: int, index: int, order: int = 0) -> str:
    """Name of one element: ``p[0]``, ``der(p)[0]``, ``der(p,2)``, ``z``."""
    base = name if order == 0 else (f"der({name})" if order == 1 else f"der({name},{order})")
    return base if size == 1 else f"{base}[{index}]"


def parse_name(text: str) -> tuple[str, int, int | None]:
    """Parse ``"der(p,2)[1]"`` into ``("p", 2, 1)``; ``"p"`` into ``("p", 0, None)``.

    >>> parse_name("der(p)[0]")
    ('p', 1, 0)
    """
    mt = _REF_RE.match(text)
    if not mt:
        raise ModelError(
            f"cannot read the name {text!r}: use 'p', 'p[0]', 'der(p)', 'der(p)[0]' or 'der(p,2)'"
        )
    if mt.group("dname"):
        order = int(mt.group("order") or 1)
        if order < 1:
            raise ModelError(f"in {text!r}: the derivative order must be at least 1")
        name = mt.group("dname")
    else:
        order, name = 0, mt.group("name")
    idx = mt.group("index")
    return name, order, (int(idx) if idx is not None else None)


class NameNotFoundError(ModelError, KeyError):
    """A name asked of a trajectory or of initial values is not among the known ones."""

    def __str__(self) -> str:  # KeyError would otherwise quote the message
        return str(self.args[0]) if self.args else ""


def expand_name(name: str, keys, what: str = "the solution") -> list[str]:
    """The scalar element names meant by ``name`` among ``keys``.

    ``"p"`` -> ``["p[0]", "p[1]", "p[2]"]``, ``"p[1]"`` -> ``["p[1]"]``, ``"der(p,1)"`` ->
    the elements of ``"der(p)"``, and a scalar ``"z"`` -> ``["z"]``.

    >>> expand_name("p", ["p[0]", "p[1]", "z"])
    ['p[0]', 'p[1]']
    """
    if name in keys:
        return [name]
    try:
        base, order, idx = parse_name(name)
    except ModelError:
        raise NameNotFoundError(
            f"cannot read the name {name!r}: use 'p', 'p[0]', 'der(p)', 'der(p)[0]' or 'der(p,2)'"
        ) from None
    prefix = element_name(base, 1, 0, order)
    if idx is not None:
        cand = f"{prefix}[{idx}]"
        if cand in keys:
            return [cand]
        if idx == 0 and prefix in keys:
            return [prefix]
        size = 0
        while f"{prefix}[{size}]" in keys:
            size += 1
        if size or prefix in keys:
            size = max(size, 1)
            valid = f"{prefix}[0]" if size == 1 else f"{prefix}[0] .. {prefix}[{size - 1}]"
            raise NameNotFoundError(
                f"{what}: {name!r} is out of range: {prefix!r} has "
                f"{'1 element' if size == 1 else f'{size} elements'} ({valid})"
            )
    else:
        if prefix in keys:
            return [prefix]
        out = []
        while f"{prefix}[{len(out)}]" in keys:
            out.append(f"{prefix}[{len(out)}]")
        if out:
            return out
    known = sorted({k.rsplit("[", 1)[0] if k.endswith("]") else k for k in keys})
    shown = ", ".join(known[:30]) + (", ..." if len(known) > 30 else "")
    raise NameNotFoundError(f"{what} has no value named {name!r}; known names: {shown}")


def fit_elements(expr: ca.SX, n: int, what: str, error: type[Exception] = ModelError) -> ca.SX:
    """``expr`` as a dense column of ``n`` elements (one element is repeated ``n`` times): the
    one rule by which a value given for a vector name is broadcast (inputs, resets, RATTLE's
    inputs). Any other size raises ``error`` saying ``what`` needs how many values.

    >>> fit_elements(ca.SX(2.0), 3, "reset 'p'").shape
    (3, 1)
    >>> fit_elements(ca.SX.zeros(2), 3, "reset 'p'")
    Traceback (most recent call last):
    ...
    daekit.errors.ModelError: reset 'p': 3 values needed (one per element, or one for all), got 2
    """
    col = ca.densify(ca.vec(expr))
    if col.numel() == 1 and n > 1:
        col = ca.repmat(col, n, 1)
    if col.numel() != n:
        raise error(f"{what}: {count(n, 'value')} needed (one per element, or one for all), "
                    f"got {int(ca.vec(expr).numel())}")
    return col


def select_name(name: str, keys, what: str = "the solution") -> tuple[list[str], bool]:
    """The element names meant by ``name`` and whether ``name`` means a vector: the one rule
    every result (``Trajectory``, ``InitialValues``, ``OCPSolution``) reads values by. A vector
    name (``"p"`` of a vector ``p``, even of size 1) gives one column per element; an element
    (``"p[1]"``) or a scalar (``"z"``) gives one value.

    >>> select_name("p", ["p[0]", "p[1]", "z"]), select_name("p[1]", ["p[0]", "p[1]", "z"])
    ((['p[0]', 'p[1]'], True), (['p[1]'], False))
    >>> select_name("q", ["q[0]"]), select_name("z", ["p[0]", "z"])
    ((['q[0]'], True), (['z'], False))
    """
    elems = expand_name(name, keys, what)
    scalar = len(elems) == 1 and (elems[0] == name or "[" in name or not elems[0].endswith("]"))
    return elems, not scalar


@dataclass
class Variable:
    """One declared (vector) variable of a model."""

    name: str
    kind: str
    size: int
    sym: ca.SX
    default: np.ndarray | None = None
    ders: dict[int, ca.SX] = field(default_factory=dict)

    def der(self, order: int) -> ca.SX:
        """The SX symbol of the ``order``-th derivative (created on first use)."""
        if order == 0:
            return self.sym
        if order not in self.ders:
            if self.size == 1:
                self.ders[order] = ca.SX.sym(element_name(self.name, 1, 0, order))
            else:
                self.ders[order] = ca.vertcat(*[ca.SX.sym(element_name(self.name, self.size, i, order))
                                                for i in range(self.size)])
        return self.ders[order]

    def element(self, index: int, order: int = 0) -> str:
        return element_name(self.name, self.size, index, order)


@dataclass
class Equation:
    """One declared (vector) equation ``expr == 0``."""

    name: str
    expr: ca.SX  # column vector

    @property
    def size(self) -> int:
        return int(self.expr.numel())

    def element(self, index: int) -> str:
        return self.name if self.size == 1 else f"{self.name}[{index}]"


@dataclass
class Event:
    """One declared event (see :meth:`Model.event`): fires when ``expr`` crosses zero.

    ``reset`` maps element names (``"der(x)"``, ``"p[0]"``) to SX expressions of the values
    just before the event; ``direction`` is +1 (rising), -1 (falling) or 0 (both).
    """

    name: str
    expr: ca.SX
    direction: int = 0
    terminal: bool = False
    reset: dict[str, ca.SX] = field(default_factory=dict)


@dataclass
class Incidence:
    """Sparse Sigma matrix of a model: ``vals[k]`` is the highest derivative order of unknown
    ``cols[k]`` in equation element ``rows[k]``; absent entries are -infinity."""

    n_equations: int
    n_unknowns: int
    rows: np.ndarray
    cols: np.ndarray
    vals: np.ndarray


class Model:
    """A differential-algebraic model ``F(t, x, x', ..., z, u, p) = 0`` in residual form.

    Parameters
    ----------
    name : str
        A name for messages and reports.

    Declare unknowns with :meth:`state` (its derivative appears), :meth:`algebraic` (its
    derivative does not appear) or :meth:`variable` (either; daekit finds out), inputs with
    :meth:`control`, named constants with :meth:`parameter`; write equations with
    :meth:`equation` using :meth:`der` and :attr:`t`.

    Example
    -------
    >>> import daekit as dk
    >>> m = dk.Model("decay")
    >>> x = m.state("x")
    >>> k = m.parameter("k", 0.5)
    >>> _ = m.equation(m.der(x) + k * x, name="decay")
    >>> dk.analyze(m).index
    0
    """

    def __init__(self, name: str = "model") -> None:
        self.name = name
        self.t = ca.SX.sym("t")
        self.variables: dict[str, Variable] = {}
        self.equations: list[Equation] = []
        #: declared invariants (:meth:`invariant`): ``expr = 0`` along solutions starting on it
        self.declared_invariants: list[Equation] = []
        # element hash -> (variable, element index, derivative order)
        self._lookup: dict[int, tuple[Variable, int, int]] = {}
        self._elements: dict[tuple[str, int], list] = {}  # (name, order) -> scalar symbols
        self._cache: dict[str, object] = {}
        self.events: list[Event] = []

    def with_equations(self, equations: list[Equation]) -> Model:
        """A model with ``equations`` in place of this one's, sharing its variables (and their
        derivative symbols), parameters, invariants and events; this model is not changed.
        The reduction's amendments build on it.

        >>> import daekit as dk
        >>> m = dk.Model("m"); x = m.state("x"); _ = m.equation(m.der(x) + x, name="decay")
        >>> m2 = m.with_equations([dk.model.Equation("decay", m.der(x) + 2 * x)])
        >>> m2.equation_names, str(m.equations[0].expr), str(m2.equations[0].expr)
        (['decay'], '(der(x)+x)', '(der(x)+(2.*x))')
        """
        new = copy.copy(self)
        new.equations = list(equations)
        new._cache = {}
        return new

    # ------------------------------------------------------------------ declarations
    def _declare(self, name: str, kind: str, size: int, default=None) -> ca.SX:
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise ModelError(
                f"model {self.name!r}: {name!r} is not a valid variable name "
                "(letters, digits, '_' and '.', not starting with a digit)"
            )
        if name in self.variables or name == "t":
            raise ModelError(f"model {self.name!r}: the name {name!r} is declared twice")
        if not isinstance(size, (int, np.integer)) or size < 1:
            raise ModelError(f"model {self.name!r}: variable {name!r} needs a size >= 1, got {size!r}")
        size = int(size)
        elems = [ca.SX.sym(element_name(name, size, i)) for i in range(size)]
        sym = ca.vertcat(*elems)
        var = Variable(name, kind, size, sym, default)
        self.variables[name] = var
        for i, e in enumerate(elems):
            self._lookup[e.element_hash()] = (var, i, 0)
        self._elements[name, 0] = elems
        self._cache.clear()
        return sym

    def _whole_variable(self, x: ca.SX) -> tuple[Variable, int] | None:
        """``(var, order)`` when ``x`` is the whole symbol of a vector variable of a kind that
        has derivatives, or of one of its derivatives (``m.der(x)`` on a 2000-vector was
        2000 element lookups: 15 ms a call), else None (the element-wise path decides)."""
        if x.numel() <= 1 or x.size2() != 1:
            return None
        first = x[0]
        hit = self._lookup.get(first.element_hash()) if first.is_symbolic() else None
        if hit is None or hit[1] != 0:
            return None
        var, _, order = hit
        if var.size != x.numel() or var.kind in ("algebraic", "parameter"):
            return None
        return (var, order) if ca.is_equal(x, var.der(order)) else None

    def _order_elements(self, var: Variable, order: int) -> list:
        """The scalar symbols of ``var``'s order-``order`` derivative (created on first use and
        registered for :meth:`lookup`)."""
        key = (var.name, order)
        elems = self._elements.get(key)
        if elems is None:
            elems = ca.vertsplit(var.der(order)) if var.size > 1 else [var.der(order)]
            for i, e in enumerate(elems):
                self._lookup.setdefault(e.element_hash(), (var, i, order))
            self._elements[key] = elems
        return elems

    def state(self, name: str, size: int = 1) -> ca.SX:
        """Declare an unknown whose time derivative appears in the equations."""
        return self._declare(name, "state", size)

    def algebraic(self, name: str, size: int = 1) -> ca.SX:
        """Declare an unknown whose time derivative does not appear (e.g. a constraint force)."""
        return self._declare(name, "algebraic", size)

    def variable(self, name: str, size: int = 1) -> ca.SX:
        """Declare an unknown without saying whether it is differential or algebraic."""
        return self._declare(name, "variable", size)

    def control(self, name: str, size: int = 1) -> ca.SX:
        """Declare an input: a given function of time in simulation, optimized in an OCP."""
        return self._declare(name, "control", size)

    def parameter(self, name: str, value=0.0) -> ca.SX:
        """Declare a named constant with a default ``value`` (scalar or vector)."""
        try:
            arr = np.atleast_1d(np.asarray(value, dtype=float)).ravel()
        except (TypeError, ValueError):
            raise ModelError(
                f"model {self.name!r}: parameter {name!r} needs a number or a vector of numbers, "
                f"got {value!r}"
            ) from None
        if value is None or arr.size == 0:
            raise ModelError(
                f"model {self.name!r}: parameter {name!r} needs a number or a vector of numbers, "
                f"got {value!r}"
            )
        if not np.all(np.isfinite(arr)):
            raise ModelError(f"model {self.name!r}: parameter {name!r} has a non-finite value {value!r}")
        return self._declare(name, "parameter", arr.size, default=arr)

    def der(self, x, k: int = 1) -> ca.SX:
        """The ``k``-th time derivative of a model variable (or of some of its elements).

        ``m.der(p)`` is the derivative symbol of ``p``; ``m.der(p[0], 2)`` the second derivative
        of its first element; ``m.der(m.der(p))`` equals ``m.der(p, 2)``.
        """
        if not isinstance(k, (int, np.integer)) or k < 1:
            raise ModelError(f"model {self.name!r}: der(x, k) needs an integer k >= 1, got {k!r}")
        if not isinstance(x, ca.SX):
            raise ModelError(
                f"model {self.name!r}: der() takes a model variable (a CasADi SX symbol returned by "
                f"m.state/m.variable/m.control), got {type(x).__name__}"
            )
        whole = self._whole_variable(x)
        if whole is not None:  # a whole vector variable (or derivative): no per-element work
            var, order = whole
            self._order_elements(var, order + int(k))  # registered for lookup
            self._cache.clear()
            return var.der(order + int(k))
        out = []
        xs = ca.vertsplit(ca.vec(x)) if x.numel() > 1 else [x]
        for e in xs:
            hit = self._lookup.get(e.element_hash()) if e.is_symbolic() else None
            if hit is None:
                what = str(e) if e.numel() == 1 else "an expression"
                if e.is_symbolic():
                    raise ModelError(
                        f"model {self.name!r}: der({what}): {what!r} is not a variable of this model; "
                        "declare it with m.state(...) or m.variable(...)"
                    )
                raise ModelError(
                    f"model {self.name!r}: der({what}) is the derivative of an expression, not of a "
                    "model variable; introduce an algebraic variable w with the equation w - (expr) "
                    "and use der(w)"
                )
            var, idx, order = hit
            if var.kind == "algebraic":
                raise ModelError(
                    f"model {self.name!r}: the derivative of algebraic variable {var.name!r} is used; "
                    f"declare {var.name!r} with m.state(...) or m.variable(...) instead"
                )
            if var.kind == "parameter":
                raise ModelError(
                    f"model {self.name!r}: der({var.name}) is the derivative of a parameter "
                    "(a constant); use m.state or m.control for a time-varying quantity"
                )
            out.append(self._order_elements(var, order + int(k))[idx])
        self._cache.clear()
        return ca.vertcat(*out) if len(out) != 1 else out[0]

    def equation(self, expr, name: str | None = None) -> ca.SX:
        """Add the equation ``expr == 0`` (any shape; matrices are taken column by column).
        ``lhs == rhs`` is read as ``lhs - rhs == 0`` (element by element); an inequality is a
        :class:`ModelError`.

        >>> import daekit as dk
        >>> m = dk.Model("decay"); x = m.state("x")
        >>> m.equation(m.der(x) == 2 - x, name="rate")
        SX((der(x)-(2-x)))

        Returns the residual as an SX column. Raises :class:`ModelError` naming the equation
        when it uses a symbol the model did not declare or contains a NaN or infinite constant.
        """
        if name is None:
            name = f"eq{len(self.equations) + 1}"
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise ModelError(f"model {self.name!r}: {name!r} is not a valid equation name")
        if any(e.name == name for e in self.equations + self.declared_invariants):
            raise ModelError(f"model {self.name!r}: the equation name {name!r} is used twice")
        if isinstance(expr, (list, tuple)):
            try:
                expr = ca.vertcat(*[ca.vec(ca.SX(e)) for e in expr])
            except Exception:  # noqa: BLE001 - turned into a daekit error below
                raise ModelError(
                    f"model {self.name!r}, equation {name!r}: a list must hold CasADi SX "
                    "expressions or numbers"
                ) from None
        if isinstance(expr, ca.MX):
            raise ModelError(
                f"model {self.name!r}, equation {name!r}: MX expressions are not supported; "
                "build equations from the SX symbols the model returns"
            )
        try:
            sx = ca.SX(expr) if not isinstance(expr, ca.SX) else expr
        except Exception:  # noqa: BLE001 - turned into a daekit error
            raise ModelError(
                f"model {self.name!r}, equation {name!r}: cannot convert {type(expr).__name__} "
                "to a CasADi expression; give an SX expression built from the model's symbols, "
                "a number, or a NumPy array"
            ) from None
        if sx.numel() == 0:
            raise ModelError(f"model {self.name!r}, equation {name!r} is empty")
        sx = _as_residual(ca.vec(sx), self.name, name)
        zero = _zero_entries(sx)
        if zero:
            els = [name if sx.numel() == 1 else f"{name}[{k}]" for k in zero]
            shown = ", ".join(els[:8]) + (", ..." if len(els) > 8 else "")
            raise ModelError(
                f"model {self.name!r}, equation {name!r}: {shown} "
                f"{'is' if len(els) == 1 else 'are'} identically zero (a structural zero of a "
                "sparse matrix, or the constant 0); pass only the entries that are equations "
                "(e.g. the vector v itself rather than the diagonal matrix ca.diag(v))"
            )
        sx = ca.densify(sx)
        self._check_symbols(sx, f"equation {name!r}")
        bad = _nonfinite_constants(sx)
        if bad:
            raise ModelError(
                f"model {self.name!r}, equation {name!r} contains the constant {bad[0]!r}; "
                "check the data it was built from"
            )
        self.equations.append(Equation(name, sx))
        self._cache.clear()
        return sx

    def invariant(self, expr, name: str | None = None) -> ca.SX:
        """Declare that ``expr = 0`` holds along the model's exact solutions once it holds at
        the start (a unit quaternion's ``ca.dot(q, q) - 1``, a lifted state's ``w - x**2``).

        A vector ``expr`` declares one invariant per element (``name[0]``, ``name[1]``, ...).
        The claim is checked when the model is reduced (:func:`daekit.reduce_index`): the time
        derivative of ``expr`` along the dynamics must vanish where ``expr = 0`` (and the
        model's own consistency conditions) hold, else a :class:`ModelError` names the
        invariant and shows the residual of its derivative. Declared invariants then go where
        the found consistency conditions go: ``r.invariants``, ``initialize`` (held at ``t0``,
        one degree of freedom less each), the projection and Baumgarte remedies, the
        trajectory's invariants, and the OCP (imposed at ``t = 0`` only).

        Returns the expression as an SX column.

        >>> import casadi as ca, daekit as dk
        >>> m = dk.Model("rotation")
        >>> x = m.state("x", 2)
        >>> _ = m.equation(m.der(x) - ca.vertcat(-x[1], x[0]), name="rotate")
        >>> _ = m.invariant(ca.dot(x, x) - 1, name="circle")
        >>> dk.reduce_index(m).invariant_names
        ['circle']
        """
        if name is None:
            name = f"invariant{len(self.declared_invariants) + 1}"
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise ModelError(f"model {self.name!r}: {name!r} is not a valid invariant name")
        if any(e.name == name for e in self.equations + self.declared_invariants):
            raise ModelError(
                f"model {self.name!r}: the name {name!r} is already used by an equation or "
                "an invariant; give the invariant another name"
            )
        n_before = len(self.equations)
        try:
            sx = self.equation(expr, name=name)  # the same conversion and symbol checks
        except ModelError as exc:
            raise ModelError(str(exc).replace(f"equation {name!r}", f"invariant {name!r}")) from None
        finally:
            del self.equations[n_before:]
            self._cache.clear()
        known = {self.t.element_hash()} | {
            h for h, (var, _i, _o) in self._lookup.items() if var.kind in ("control", "parameter")}
        if all(s.element_hash() in known for s in ca.symvar(sx)):
            raise ModelError(
                f"model {self.name!r}, invariant {name!r} involves no unknown of the model "
                "(only time, inputs or parameters): it constrains nothing; write it in terms "
                "of the states"
            )
        self.declared_invariants.append(Equation(name, sx))
        return sx

    def _check_symbols(self, sx: ca.SX, where: str) -> None:
        """ModelError naming ``where`` if ``sx`` uses a symbol the model did not declare."""
        tname = self.t.element_hash()
        for s in ca.symvar(sx):
            h = s.element_hash()
            if h != tname and h not in self._lookup:
                raise ModelError(
                    f"model {self.name!r}, {where} uses the symbol {s.name()!r}, which this model "
                    "did not declare; create it with m.state/m.algebraic/m.variable/m.control/"
                    "m.parameter and build from the model's own symbols (m.der, m.t); symbols "
                    "made with ca.SX.sym directly are not model variables"
                )

    def event(self, expr, name: str | None = None, direction: int | None = None,
              terminal: bool = False,
              reset: dict | None = None) -> Event:
        """Declare an event: it fires when the scalar ``expr`` crosses zero. A condition
        ``a <= b`` (or ``a < b``, ``a >= b``, ``a > b``) fires when it becomes true: the event
        function ``a - b`` with ``direction=-1``; ``a == b`` is ``a - b`` crossing zero.

        Parameters
        ----------
        expr : casadi.SX
            Any scalar expression of the model's variables, derivatives, controls, parameters
            and ``m.t``.
        name : str, optional
            Name in ``traj.events`` and in messages (default ``event1``, ``event2``, ...).
        direction : +1, -1 or 0, optional
            +1 fires on a rising crossing (``expr`` from negative to positive), -1 on a falling
            one, 0 on both (the default; for a condition, -1: when it becomes true).
        terminal : bool
            Stop the simulation at the event (the trajectory ends there).
        reset : dict, optional
            ``{element name: expression}``: new values of states or their derivatives
            (``"der(x)"``, ``"p[0]"``, ``"der(p)"`` for a whole vector) as expressions of the
            values just before the event, e.g. ``{"der(x)": -0.8 * m.der(x)}``. After the reset
            the simulator restores consistency with the constraints (see
            :mod:`daekit.simulate.events`).

        Simultaneous events (located at the same time within the location tolerance) fire in
        the order they were declared; their resets are applied in that order, each to the
        values left by the previous one.

        Example
        -------
        >>> import daekit as dk
        >>> m = dk.examples.pendulum_planar()
        >>> x = m.variables["x"].sym; y = m.variables["y"].sym
        >>> ev = m.event(x, name="wall", direction=-1,
        ...              reset={"der(x)": -0.8 * m.der(x), "der(y)": -0.8 * m.der(y)})
        >>> ev.name, ev.direction, sorted(ev.reset)
        ('wall', -1, ['der(x)', 'der(y)'])
        """
        if name is None:
            name = f"event{len(self.events) + 1}"
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise ModelError(f"model {self.name!r}: {name!r} is not a valid event name")
        if any(e.name == name for e in self.events):
            raise ModelError(f"model {self.name!r}: the event name {name!r} is used twice")
        where = f"event {name!r}"
        if isinstance(expr, ca.MX):
            raise ModelError(f"model {self.name!r}, {where}: MX expressions are not supported; "
                             "build it from the SX symbols the model returns")
        try:
            sx = ca.SX(expr) if not isinstance(expr, ca.SX) else expr
        except Exception:  # noqa: BLE001 - turned into a daekit error
            raise ModelError(f"model {self.name!r}, {where}: cannot convert "
                             f"{type(expr).__name__} to a CasADi expression") from None
        if sx.numel() != 1:
            raise ModelError(
                f"model {self.name!r}, {where}: the event function must be a scalar, got shape "
                f"{sx.shape}; declare one event per condition"
            )
        sx = ca.densify(sx)
        self._check_symbols(sx, where)
        if direction is not None and direction not in (-1, 0, 1):
            raise ModelError(
                f"model {self.name!r}, {where}: direction must be +1 (rising), -1 (falling) or "
                f"0 (both), got {direction!r}"
            )
        parts = comparison_parts(sx)
        if parts is not None:  # a condition: fires where it becomes true
            (op,), lhs, rhs = parts
            if op not in ("==", "<=", "<"):
                raise ModelError(
                    f"model {self.name!r}, {where}: the condition {op!r} is not an event "
                    "function; give an expression that crosses zero (e.g. x - 1) or a "
                    "condition such as x <= 1 (it fires when it becomes true)"
                )
            sx = lhs - rhs
            if op != "==":
                if direction in (0, 1):
                    raise ModelError(
                        f"model {self.name!r}, {where}: the condition {lhs} {op} {rhs} fires "
                        f"when it becomes true (direction -1 of {sx}); direction={direction} "
                        f"contradicts it: give the expression {sx} itself with "
                        f"direction={direction} to fire when it {'rises' if direction else 'crosses'}"
                        " through zero"
                    )
                direction = -1
        direction = 0 if direction is None else int(direction)
        if not isinstance(terminal, (bool, np.bool_)):
            raise ModelError(f"model {self.name!r}, {where}: terminal must be True or False, "
                             f"got {terminal!r}")
        resets: dict[str, ca.SX] = {}
        for key, value in dict(reset or {}).items():
            if not isinstance(key, str):
                raise ModelError(f"model {self.name!r}, {where}: reset keys are names such as "
                                 f"'der(x)' or 'p[0]', got {key!r}")
            try:
                elems = self.resolve(key)
            except ModelError as exc:
                raise ModelError(f"model {self.name!r}, {where}, reset {key!r}: {exc}") from None
            for var, _i, _o in elems:
                if var.kind not in ("state", "variable"):
                    raise ModelError(
                        f"model {self.name!r}, {where}: reset {key!r} names the {var.kind} "
                        f"{var.name!r}; only states and their derivatives can be reset (a "
                        "control is given, a parameter constant, an algebraic unknown follows "
                        "from the equations)"
                    )
            try:
                val = ca.SX(value) if not isinstance(value, ca.SX) else value
            except Exception:  # noqa: BLE001 - turned into a daekit error
                raise ModelError(f"model {self.name!r}, {where}, reset {key!r}: cannot convert "
                                 f"{type(value).__name__} to a CasADi expression") from None
            val = fit_elements(val, len(elems), f"model {self.name!r}, {where}, reset {key!r}")
            self._check_symbols(val, f"{where}, reset {key!r}")
            bad = _nonfinite_constants(val)
            if bad:
                raise ModelError(f"model {self.name!r}, {where}, reset {key!r} contains the "
                                 f"constant {bad[0]!r}")
            for k, (var, i, o) in enumerate(elems):
                el = var.element(i, o)
                if el in resets:
                    raise ModelError(f"model {self.name!r}, {where}: {el!r} is reset twice")
                resets[el] = val[k]
        ev = Event(name, sx, int(direction), bool(terminal), resets)
        self.events.append(ev)
        return ev

    # ------------------------------------------------------------------ flattened views
    @property
    def unknown_variables(self) -> list[Variable]:
        """The unknowns' variables in declaration order (cached; do not mutate)."""
        hit = self._cache.get("unknown_variables")
        if hit is None:
            hit = self._cache["unknown_variables"] = [
                v for v in self.variables.values() if v.kind in UNKNOWN_KINDS]
        return hit

    @property
    def controls(self) -> list[Variable]:
        return [v for v in self.variables.values() if v.kind == "control"]

    @property
    def parameters(self) -> list[Variable]:
        return [v for v in self.variables.values() if v.kind == "parameter"]

    @property
    def unknowns(self) -> list[tuple[Variable, int]]:
        """Scalar unknowns (variable, element index) in declaration order (cached; do not mutate)."""
        if "unknowns" not in self._cache:
            self._cache["unknowns"] = [(v, i) for v in self.unknown_variables for i in range(v.size)]
        return self._cache["unknowns"]

    @property
    def unknown_names(self) -> list[str]:
        """Element names of the unknowns, ``"p[0]"``, ``"z"``, ... (cached; do not mutate)."""
        hit = self._cache.get("unknown_names")
        if hit is None:
            hit = []
            for v in self.unknown_variables:  # one comprehension per variable
                hit += [v.name] if v.size == 1 else [f"{v.name}[{i}]" for i in range(v.size)]
            self._cache["unknown_names"] = hit
        return hit

    @property
    def n_unknowns(self) -> int:
        return sum(v.size for v in self.unknown_variables)

    @property
    def n_equations(self) -> int:
        return sum(e.size for e in self.equations)

    @property
    def equation_names(self) -> list[str]:
        """Element names of the equations, ``"rod"``, ``"newton[0]"``, ... (cached; do not
        mutate)."""
        if "equation_names" not in self._cache:
            out: list[str] = []
            for e in self.equations:
                k = e.size
                out += [e.name] if k == 1 else [f"{e.name}[{i}]" for i in range(k)]
            self._cache["equation_names"] = out
        return self._cache["equation_names"]

    @property
    def residual(self) -> ca.SX:
        """All equation elements stacked into one SX column."""
        if "F" not in self._cache:
            self._cache["F"] = ca.vertcat(*[e.expr for e in self.equations])
        return self._cache["F"]

    def symbol(self, j: int, order: int = 0) -> ca.SX:
        """SX symbol of derivative ``order`` of scalar unknown ``j``."""
        var, i = self.unknowns[j]
        return var.der(order)[i]

    def symbols(self, js, order: int = 0) -> ca.SX:
        """SX column of derivative ``order`` of the scalar unknowns ``js`` (vectorized)."""
        if "elements" not in self._cache:
            self._cache["elements"] = {}
        cache = self._cache["elements"]
        if order not in cache:
            cache[order] = ca.vertcat(*[v.der(order) for v in self.unknown_variables])
        return cache[order][[int(j) for j in js]]

    def symbols_at(self, js, orders) -> ca.SX:
        """SX column of ``x_j^(o)`` for the pairs ``(j, o)`` in ``zip(js, orders)``, in that order.

        ``orders`` is a sequence as long as ``js`` or one int for all. Consecutive elements of the
        same variable and order are taken in one indexing operation (fast for long vectors);
        only the derivative symbols asked for are created.

        >>> m = Model("s"); p = m.state("p", 2); z = m.algebraic("z")
        >>> print(m.symbols_at([0, 1, 2, 0], [1, 1, 0, 0]))
        [der(p)[0], der(p)[1], z, p[0]]
        """
        js = np.asarray(js, dtype=np.int64).ravel()
        if isinstance(orders, (int, np.integer)):
            orders = np.full(js.size, int(orders), dtype=np.int64)
        orders = np.asarray(orders, dtype=np.int64).ravel()
        if orders.size != js.size:
            raise ModelError(
                f"model {self.name!r}: symbols_at needs one order per unknown "
                f"({count(int(js.size), 'unknown')}, {count(int(orders.size), 'order')})"
            )
        if not js.size:
            return ca.SX(0, 1)
        if js.size <= SMALL_SYMBOLS:  # a few: the scalar symbols, one vertcat
            unknowns = self.unknowns
            elems: dict[tuple[int, int], list] = {}
            out = []
            for j, o in zip(js.tolist(), orders.tolist(), strict=True):
                var, i = unknowns[j]
                key = (j - i, o)
                row = elems.get(key)
                if row is None:
                    row = elems[key] = self._order_elements(var, o)
                out.append(row[i])
            return ca.vertcat(*out)
        var_of, elem_of = self.unknown_arrays()
        variables = self.unknown_variables
        parts, base, pos = [], 0, np.empty(js.size, dtype=np.int64)
        for o in np.unique(orders):
            sel = np.nonzero(orders == o)[0]
            for vi in np.unique(var_of[js[sel]]):
                variables[vi].der(int(o))  # create the derivative symbols asked for
            stack, start = self._stack(int(o))
            pos[sel] = base + start[var_of[js[sel]]] + elem_of[js[sel]]
            parts.append(stack)
            base += int(stack.numel())
        big = parts[0] if len(parts) == 1 else ca.vertcat(*parts)
        return big[pos.tolist()]

    def unknown_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Per scalar unknown: index of its variable in ``unknown_variables`` and its element
        (cached; do not mutate).

        >>> m = Model("s"); p = m.state("p", 2); z = m.algebraic("z")
        >>> [a.tolist() for a in m.unknown_arrays()]
        [[0, 0, 1], [0, 1, 0]]
        """
        if "unknown_arrays" not in self._cache:
            sizes = np.array([v.size for v in self.unknown_variables], dtype=np.int64)
            var_of = np.repeat(np.arange(sizes.size), sizes)
            starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]) if sizes.size else sizes
            elem_of = np.arange(int(sizes.sum())) - np.repeat(starts, sizes)
            self._cache["unknown_arrays"] = (var_of, elem_of)
        return self._cache["unknown_arrays"]

    def _stack(self, order: int) -> tuple[ca.SX, np.ndarray]:
        """All existing order-``order`` symbols of the unknowns stacked in one SX column, and
        the start of each unknown variable in it (``-1`` for variables without that order):
        one indexing of this column gives many symbols (cached while no new derivative symbol
        appears)."""
        variables = self.unknown_variables
        have = tuple(order == 0 or order in v.ders for v in variables)
        cache = self._cache.setdefault("stacks", {})
        hit = cache.get(order)
        if hit is not None and hit[0] == have:
            return hit[1], hit[2]
        start = np.full(len(variables), -1, dtype=np.int64)
        pieces, off = [], 0
        for k, (v, h) in enumerate(zip(variables, have, strict=True)):
            if h:
                start[k] = off
                pieces.append(v.der(order))
                off += v.size
        stack = ca.vertcat(*pieces) if pieces else ca.SX(0, 1)
        cache[order] = (have, stack, start)
        return stack, start

    def lookup(self, sym: ca.SX) -> tuple[Variable, int, int] | None:
        """(variable, element, order) of a scalar symbol of this model, or None."""
        return self._lookup.get(sym.element_hash())

    @property
    def parameter_symbols(self) -> ca.SX:
        return ca.vertcat(*[v.sym for v in self.parameters]) if self.parameters else ca.SX(0, 1)

    @property
    def parameter_values(self) -> np.ndarray:
        if not self.parameters:
            return np.zeros(0)
        return np.concatenate([v.default for v in self.parameters])

    def max_order(self, var: Variable) -> int:
        return max(var.ders) if var.ders else 0

    def resolve(self, name: str) -> list[tuple[Variable, int, int]]:
        """Elements meant by a name such as ``"p"``, ``"p[0]"``, ``"der(p,2)[1]"``.

        Returns a list of (variable, element index, derivative order).
        """
        base, order, idx = parse_name(name)
        var = self.variables.get(base)
        if var is None:
            known = ", ".join(self.variables) or "none"
            raise ModelError(f"model {self.name!r} has no variable {base!r} (known: {known})")
        if idx is not None and idx >= var.size:
            raise ModelError(
                f"model {self.name!r}: {name!r} is out of range; {base!r} has "
                f"{count(var.size, 'element')}"
            )
        if order > 0 and var.kind == "parameter":
            raise ModelError(f"model {self.name!r}: {name!r} is the derivative of a parameter")
        idxs = [idx] if idx is not None else list(range(var.size))
        return [(var, i, order) for i in idxs]

    # ------------------------------------------------------------------ structure
    def incidence(self) -> Incidence:
        """The sparse Sigma matrix, read from CasADi Jacobian sparsity patterns order by order."""
        if "inc" in self._cache:
            return self._cache["inc"]
        F = self.residual
        unknowns = self.unknowns
        var_of, _ = self.unknown_arrays()
        rows_all, cols_all, vals_all = [], [], []
        max_ord = max((self.max_order(v) for v in self.unknown_variables), default=0)
        for order in range(max_ord + 1):
            has = np.array([order == 0 or order in v.ders for v in self.unknown_variables],
                           dtype=bool)
            cols_k = np.nonzero(has[var_of])[0] if var_of.size else np.zeros(0, np.int64)
            if not cols_k.size:
                continue
            X = self.symbols_at(cols_k, order)
            r, c = ca.jacobian_sparsity(F, X).get_triplet()
            rows_all.append(np.asarray(r, dtype=np.int64))
            cols_all.append(np.asarray(cols_k, dtype=np.int64)[np.asarray(c, dtype=np.int64)])
            vals_all.append(np.full(len(r), order, dtype=np.int64))
        n, m = self.n_equations, len(unknowns)
        if rows_all:
            rows = np.concatenate(rows_all)
            cols = np.concatenate(cols_all)
            vals = np.concatenate(vals_all)
            # keep the highest order for each (row, col)
            key = rows * m + cols
            order_idx = np.lexsort((-vals, key))
            key, rows, cols, vals = key[order_idx], rows[order_idx], cols[order_idx], vals[order_idx]
            first = np.ones(len(key), dtype=bool)
            first[1:] = key[1:] != key[:-1]
            rows, cols, vals = rows[first], cols[first], vals[first]
        else:
            rows = cols = vals = np.zeros(0, dtype=np.int64)
        inc = Incidence(n, m, rows, cols, vals)
        self._cache["inc"] = inc
        return inc

    def residual_jacobian(self, order: int) -> tuple[ca.SX, np.ndarray]:
        """``(J, cols)``: the symbolic sparse Jacobian of the residual with respect to
        derivative ``order`` of the scalar unknowns ``cols`` (those whose variable has that
        derivative), made once until the model changes (the analysis evaluates it at several
        points and for several tests).

        >>> import daekit as dk
        >>> J, cols = dk.examples.l3().residual_jacobian(2)
        >>> J.shape[1] == len(cols)
        True
        """
        cache = self._cache.setdefault("residual_jacobian", {})
        if order not in cache:
            var_of, _ = self.unknown_arrays()
            has = np.array([order == 0 or order in v.ders for v in self.unknown_variables],
                           dtype=bool)
            cols = np.nonzero(has[var_of])[0] if var_of.size else np.zeros(0, np.int64)
            J = ca.jacobian(self.residual, self.symbols(cols, order)) if cols.size else \
                ca.SX(self.n_equations, 0)
            cache[order] = (J, cols)
        return cache[order]

    def system_jacobian(self, c, d) -> ca.SX:
        """Pryce's system Jacobian for the offsets ``c`` (equations) and ``d`` (unknowns) as a
        symbolic sparse ``n x n`` matrix: ``J_ij = dF_i / dx_j^(d_j - c_i)`` (with
        ``d_j - c_i >= sigma_ij``, its nonzeros are the entries where ``sigma_ij = d_j - c_i``;
        it is also ``dF_i^(c_i) / dx_j^(d_j)``, without differentiating anything). One
        Jacobian per distinct offset ``c_i``; made once per ``(c, d)`` until the model changes
        (analysis, reduction and the elimination of explicit derivatives share it).

        >>> import daekit as dk
        >>> m = dk.examples.pendulum_planar(); s = m.sigma()
        >>> J = m.system_jacobian(s.c, s.d)
        >>> J.shape, J.nnz()
        ((3, 3), 6)
        """
        c = np.asarray(c, dtype=np.int64)
        d = np.asarray(d, dtype=np.int64)
        key = ("system_jacobian", c.tobytes(), d.tobytes())
        return self.memo(key, lambda: self._system_jacobian(c, d))

    def _system_jacobian(self, c: np.ndarray, d: np.ndarray) -> ca.SX:
        n_e, n_u = self.n_equations, self.n_unknowns
        F = self.residual
        rows_all, cols_all, parts = [], [], []
        inc = self.incidence()
        orders = np.unique((d[inc.cols] - c[inc.rows])[inc.vals == d[inc.cols] - c[inc.rows]])
        have = self._cache.get("residual_jacobian", {})
        if all(int(o) in have for o in orders):
            # the analysis has made the residual's Jacobians by order: their tight entries
            # (x_j^(o) in F_i with d_j - c_i = o), no new differentiation
            for o in orders.tolist():
                J, cols_o = have[o]
                r, cc = J.sparsity().get_triplet()
                r = np.asarray(r, dtype=np.int64)
                cj = np.asarray(cols_o, dtype=np.int64)[np.asarray(cc, dtype=np.int64)]
                sel = np.nonzero(d[cj] - c[r] == o)[0]
                if sel.size:
                    rows_all.append(r[sel])
                    cols_all.append(cj[sel])
                    parts.append(J.nz[sel.tolist()])
            cvs = []
        else:
            cvs = np.unique(c).tolist()
        for cv in cvs:
            rows = np.nonzero(c == cv)[0]
            cols = np.nonzero(d >= cv)[0]
            if not rows.size or not cols.size:
                continue
            Fr = F if rows.size == n_e else F[rows.tolist()]
            J = ca.jacobian(Fr, self.symbols_at(cols, d[cols] - cv))
            r, cc = J.sparsity().get_triplet()  # column-major: the order of J's nonzeros
            if not r:
                continue
            rows_all.append(rows[np.asarray(r, dtype=np.int64)])
            cols_all.append(cols[np.asarray(cc, dtype=np.int64)])
            parts.append(J.nz[:])
        if not parts:
            return ca.SX(n_e, n_u)
        R = np.concatenate(rows_all)
        C = np.concatenate(cols_all)
        nz = ca.vertcat(*[ca.vec(p) for p in parts])
        order = np.lexsort((R, C))  # the column-major order of the assembled matrix
        sparsity = ca.Sparsity.triplet(n_e, n_u, R[order].tolist(), C[order].tolist())
        return ca.SX(sparsity, nz[order.tolist()])

    def memo(self, key, make):
        """``make()``, computed once and kept until the model changes (for values built from
        the model that several steps need, e.g. the expansion by Pryce's offsets).

        >>> import daekit as dk
        >>> m = dk.examples.l3()
        >>> m.memo("n", lambda: m.n_equations) == m.memo("n", lambda: -1)
        True
        """
        memos = self._cache.setdefault("memo", {})
        if key not in memos:
            memos[key] = make()
        return memos[key]

    def sigma(self):
        """Pryce's Sigma-method on :meth:`incidence` (:func:`daekit.structure.sigma_method`),
        computed once until the model changes (analysis and reduction both need it).

        >>> import daekit as dk
        >>> dk.examples.l3().sigma().index
        3
        """
        if "sigma" not in self._cache:
            from .structure import sigma_method

            inc = self.incidence()
            self._cache["sigma"] = sigma_method(inc.n_equations, inc.rows, inc.cols, inc.vals)
        return self._cache["sigma"]

    @staticmethod
    def require(obj, where: str) -> Model:
        """``obj`` if it is a Model, its ``.model()`` if it is a
        :class:`~daekit.mechanics.LagrangianSystem` (the one rule of every entry point), else a
        :class:`ModelError` saying what ``where`` needs."""
        if isinstance(obj, Model):
            return obj
        if hasattr(obj, "index1") and callable(getattr(obj, "model", None)):
            return obj.model()
        raise ModelError(
            f"{where} needs a daekit.Model, got {type(obj).__name__} (a "
            "daekit.mechanics.LagrangianSystem is accepted too)"
        )

    def validate(self) -> None:
        """Check the model; raise :class:`ModelError` or :class:`StructuralError` naming the fault.

        Checks: at least one equation; every ``state`` has its derivative used; the system is
        square; it is structurally nonsingular (a perfect matching between equations and
        unknowns exists), else the Dulmage--Mendelsohn decomposition names the over- and
        under-determined parts.
        """
        from .structure import dulmage_mendelsohn, structurally_nonsingular

        if self._cache.get("valid"):  # checked already, and the model has not changed since
            return
        if not self.equations:
            raise ModelError(f"model {self.name!r} has no equations; add them with m.equation(...)")
        if not self.unknown_variables:
            raise ModelError(f"model {self.name!r} has no unknowns (states or algebraic variables)")
        inc = self.incidence()
        highest = np.full(inc.n_unknowns, -1, dtype=np.int64)
        np.maximum.at(highest, inc.cols, inc.vals)
        names = self.unknown_names
        for j, (var, _i) in enumerate(self.unknowns):
            if var.kind == "state" and highest[j] < 1:
                raise ModelError(
                    f"model {self.name!r}: state {names[j]!r} is declared with m.state but its "
                    "derivative never appears in an equation; declare it with m.algebraic(...) "
                    "(or m.variable(...)) or use m.der on it"
                )
        eq_names = self.equation_names
        if structurally_nonsingular(inc.n_equations, inc.n_unknowns, inc.rows, inc.cols):
            self._cache["valid"] = True
            return
        dm = dulmage_mendelsohn(inc.n_equations, inc.n_unknowns, inc.rows, inc.cols)
        over_e = [eq_names[i] for i in dm.over_rows]
        over_v = [names[j] for j in dm.over_cols]
        under_e = [eq_names[i] for i in dm.under_rows]
        under_v = [names[j] for j in dm.under_cols]
        lines = [
            f"model {self.name!r} is structurally singular: {_count(inc.n_equations, 'equation')}, "
            f"{_count(inc.n_unknowns, 'unknown')}, at most {dm.matching_size} can be matched."
        ]
        if over_e:
            if over_v:
                lines.append(
                    f"  Over-determined: the equations {listing(over_e, 12)} involve only the unknowns "
                    f"{listing(over_v, 12)}, too few for them; remove or merge an equation there, or "
                    "an unknown is missing."
                )
            else:
                lines.append(
                    f"  Over-determined: the equations {listing(over_e, 12)} involve no unknowns "
                    "(only time, inputs or parameters): they cannot be solved for anything; "
                    "remove them, or declare the unknown they should determine."
                )
        if under_v and under_e:
            lines.append(
                f"  Under-determined: the unknowns {listing(under_v, 12)} appear only in the equations "
                f"{listing(under_e, 12)}, too few to determine them; add an equation, or declare one "
                "of them as a control or parameter."
            )
        elif under_v:
            lines.append(
                f"  Under-determined: the unknowns {listing(under_v, 12)} appear in no equation; add "
                "an equation for them, or remove them, or declare them as controls or parameters."
            )
        raise StructuralError(
            "\n".join(lines),
            overdetermined_equations=over_e,
            overdetermined_variables=over_v,
            underdetermined_equations=under_e,
            underdetermined_variables=under_v,
        )

    def __repr__(self) -> str:
        kinds = {k: [v.name for v in self.variables.values() if v.kind == k] for k in KINDS}
        parts = ", ".join(f"{k}s={v}" for k, v in kinds.items() if v)
        return f"Model({self.name!r}: {self.n_equations} equations; {parts})"


def _count(n: int, noun: str) -> str:
    """``"1 equation"``, ``"3 equations"`` (:func:`daekit.wording.count`)."""
    return count(n, noun)


_COMPARISONS = {ca.OP_EQ: "==", ca.OP_LE: "<=", ca.OP_LT: "<", ca.OP_NE: "!=",
                ca.OP_AND: "and", ca.OP_OR: "or", ca.OP_NOT: "not"}


#: how a comparison operator is named in messages (CasADi stores ``a >= b`` as ``b <= a``)
_SHOWN = {"<=": "<= or >=", "<": "< or >"}


def comparison_parts(sx: ca.SX) -> tuple[list[str | None], ca.SX, ca.SX] | None:
    """Where the column ``sx`` holds comparisons (CasADi's ``a == b``, ``a <= b``, ``a < b``
    build 0/1 expressions, ``a >= b`` is ``b <= a``): ``(ops, lhs, rhs)``, each element's
    operator (``"=="``, ``"<="``, ``"<"``, ``"!="``, ``"and"``, ``"or"``, ``"not"``, or None
    where it is no comparison) and its two sides (``lhs = e``, ``rhs = 0`` where None); None
    where no element is a comparison. One place for :meth:`Model.equation`,
    :meth:`Model.event` and the OCP's constraints and objective.

    Every element is looked at (a 20,000-element vector in 70 ms, once, as the model is
    built): a single comparison among residuals must not pass as a 0/1 residual.

    >>> import casadi as ca
    >>> x = ca.SX.sym("x")
    >>> ops, lhs, rhs = comparison_parts(ca.vertcat(x >= 1, 2 * x))
    >>> ops, lhs, rhs
    (['<=', None], SX([1, (2.*x)]), SX([x, 0]))
    """
    elems = ca.vertsplit(ca.vec(sx))
    if not any(e.op() in _COMPARISONS for e in elems):
        return None
    ops, lhs, rhs = [], [], []
    for e in elems:
        op = _COMPARISONS.get(e.op())
        ops.append(op)
        if op is None:
            lhs.append(e)
            rhs.append(ca.SX(0))
        elif op == "not":
            lhs.append(e.dep(0))
            rhs.append(ca.SX(0))
        else:
            lhs.append(e.dep(0))
            rhs.append(e.dep(1))
    return ops, ca.vertcat(*lhs), ca.vertcat(*rhs)


def _as_residual(sx: ca.SX, model: str, name: str) -> ca.SX:
    """``sx`` with every element written ``a == b`` turned into the residual ``a - b`` (what
    ``m.equation(m.der(x) == v)`` means: CasADi's ``==`` alone is a 0/1 comparison whose
    value is no residual); an inequality or logical element is a :class:`ModelError`."""
    parts = comparison_parts(sx)
    if parts is None:
        return sx
    ops, lhs, rhs = parts
    for k, op in enumerate(ops):
        if op not in (None, "=="):
            el = name if len(ops) == 1 else f"{name}[{k}]"
            raise ModelError(
                f"model {model!r}, equation {el!r} is a comparison ({_SHOWN.get(op, op)}), not "
                "an equation: "
                "give the residual (lhs - rhs, meaning lhs - rhs == 0) or lhs == rhs; "
                "inequalities belong in an optimal control problem's bounds or path constraints"
            )
    return lhs - rhs


def _zero_entries(sx: ca.SX) -> list[int]:
    """Positions of a column that are structural zeros or the constant 0."""
    n = int(sx.numel())
    row, _ = sx.sparsity().get_triplet()
    present = np.zeros(n, dtype=bool)
    present[np.asarray(row, dtype=np.int64)] = True
    out = set(np.nonzero(~present)[0].tolist())
    nz = sx.nz[:]  # whole vector: the nonzeros that depend on no symbol are constants
    if nz.numel():
        syms = ca.symvar(nz)
        const = np.ones(nz.numel(), dtype=bool)
        if syms:
            dep, _ = ca.jacobian_sparsity(nz, ca.vertcat(*syms)).get_triplet()
            const[np.asarray(dep, dtype=np.int64)] = False
        k = np.nonzero(const)[0]
        if k.size:
            vals = np.asarray(ca.evalf(nz[k.tolist()]), dtype=float).ravel()
            rows = np.asarray(row, dtype=np.int64)
            out.update(rows[k[vals == 0.0]].tolist())
    return sorted(out)


def _nonfinite_constants(expr: ca.SX) -> list[float]:
    """Non-finite constants inside an SX expression (walking CasADi's instruction list)."""
    syms = ca.symvar(expr)
    if not syms:
        vals = np.asarray(ca.DM(ca.evalf(expr))).ravel()
        return [float(v) for v in vals if not math.isfinite(v)]
    f = ca.Function("constants", [ca.vertcat(*syms)], [expr])
    out = []
    for k in range(f.n_instructions()):
        if f.instruction_id(k) == ca.OP_CONST:
            v = f.instruction_constant(k)
            if not math.isfinite(v):
                out.append(v)
    return out
