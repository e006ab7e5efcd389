"""Test points on the solution manifold, for the numeric structural tests.

The index, the DOF and the rank of every Jacobian daekit tests (the system Jacobian, the easy
test, the derivative array) are properties *along solutions*: a constraint multiplied by
``2 + sin(y)``, or an equation plus ``z`` times another, leaves the solutions alone, yet
changes the Jacobians at points that do not satisfy the equations. The tests are therefore
evaluated at **consistent points**: values that satisfy the (differentiated) equations.

:func:`make_consistent` gets them: values not given are drawn at random (seeded), the
parameters take their defaults, time and the inputs (and their derivatives) are held at their
drawn or given values, and Gauss--Newton with minimum-norm steps
(:func:`gauss_newton`, dense below ``DENSE_UNKNOWNS`` unknowns, sparse LU beyond) moves the
unknowns onto ``G = 0``, first from the draws in the units the Jacobian suggests
(:func:`in_jacobian_units`: a solve does not depend on the units of the unknowns), then from
the draws as they are. The values of a user's ``point=`` are held and the others solved
for; where the given values admit no consistent completion the point is used as given (the
user asked for it) and the status says it is not consistent. When no consistent point is
found the caller falls back to the random point and says so (:attr:`PointStatus.consistent`
is False).

Example
-------
>>> import casadi as ca, daekit as dk
>>> from daekit.points import TestPoint, make_consistent
>>> m = dk.Model("circle"); x = m.state("x", 2)
>>> _ = m.equation(ca.dot(x, x) - 4, name="c")
>>> pt = TestPoint(m, None)
>>> st = make_consistent(pt, m.residual)
>>> st.consistent, round(float(sum(v**2 for v in pt.evaluate(ca.vertsplit(x)))), 9)
(True, 4.0)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np
import scipy.sparse as sp

from .errors import ModelError
from .numerics import FastFunction, PatternCache, Segments, SparseFunction, equilibrate, major_index
from .wording import count

__all__ = ["TestPoint", "PointFunction", "PointStatus", "check_point", "make_consistent", "consistent_point",
           "gauss_newton", "in_jacobian_units", "reduced_consistent_point", "remember_consistent",
           "reduced_point_functions", "system_jacobians", "SystemJacobians", "DRAWS"]

#: Distributions of the random values, tried in this order (until the Jacobians are finite).
DRAWS = (("uniform", 0.1, 0.3), ("uniform", 0.5, 1.5), ("normal", 0.0, 1.0),
         ("uniform", 1.5, 3.0), ("normal", 0.0, 3.0))
#: Below this many unknowns Gauss--Newton steps come from a dense SVD, above from sparse LU.
DENSE_UNKNOWNS = 300
#: Required residual of a consistent point, relative to each equation's scale.
POINT_TOL = 1e-10
#: Where the residual test cannot be met (a multiple root: ``h = x^2`` has a residual half
#: its row's terms at every iterate; rounding in a row whose terms nearly cancel), the
#: predicted remaining distance to the solution, per unknown and relative to the larger of
#: ``|w_j|`` and its start's value, that makes a converging Gauss--Newton iteration
#: consistent.
POINT_DIST = 1e-8
#: Largest ratio of successive steps taken as linear convergence (a root of multiplicity
#: ``m`` contracts by ``(m - 1) / m``: up to ``m = 10``).
LINEAR_RATE = 0.9


def check_point(model, point, error: type[Exception] = ModelError) -> dict[str, np.ndarray]:
    """The user's ``point`` as ``{name: values}``, each checked for type, size, finiteness:
    the one check of a ``point=`` argument (``analyze``, ``reduce_index``); ``error`` is the
    class the caller raises.

    >>> import daekit as dk
    >>> m = dk.Model("m"); p = m.state("p", 2)
    >>> check_point(m, {"p": 1.0})["p"].tolist()
    [1.0, 1.0]
    """
    if point is None:
        return {}
    if not isinstance(point, Mapping):
        raise error(
            f"model {model.name!r}: point must be a dict of values by name, e.g. "
            f"{{'p': [1, 0], 't': 0.0}}, got {type(point).__name__}"
        )
    out = {}
    for name, val in point.items():
        if not isinstance(name, str):
            raise error(f"model {model.name!r}: point key {name!r} is not a name such as 'p'")
        size = 1 if name == "t" else len(model.resolve(name))
        try:
            arr = np.asarray(val, dtype=float).ravel()
        except (TypeError, ValueError):
            raise error(
                f"model {model.name!r}: point[{name!r}] = {val!r} is not numeric: it must be numbers ("
                + ("a number" if size == 1 else f"a number or {size} numbers") + ")"
            ) from None
        if arr.size == 1:
            arr = np.full(size, arr[0])
        if arr.size != size:
            raise error(
                f"model {model.name!r}: point[{name!r}] has {count(arr.size, 'value')}, but {name!r} "
                f"has {count(size, 'element')}; give {count(size, 'value')} (or one for all)"
            )
        if not np.all(np.isfinite(arr)):
            raise error(f"model {model.name!r}: point[{name!r}] = {val!r} is not finite")
        out[name] = arr
    return out


class TestPoint:
    """Numeric values for every symbol of a model (unknowns and derivatives, controls, t,
    parameters): the user's values where given, defaults for parameters, random elsewhere
    (drawn from ``DRAWS[attempt]``, seeded by ``seed`` and ``attempt``).

    >>> import daekit as dk
    >>> m = dk.Model("m"); x = m.state("x")
    >>> TestPoint(m, {"x": 2.0}).evaluate([x]).tolist()
    [2.0]
    """

    __test__ = False  # not a pytest class

    def __init__(self, model, point: dict | None, seed: int = 0, attempt: int = 0) -> None:
        self.model = model
        self.point, self.seed, self.attempt = point, seed, attempt
        self.rng = np.random.default_rng(seed + 7919 * attempt)
        self.draw = DRAWS[attempt % len(DRAWS)]
        self.values: dict[int, float] = {}  # element hash -> value
        #: element hashes whose values were drawn at random and not solved for since
        #: (:func:`make_consistent` starts them in the Jacobian's own units)
        self.drawn: set[int] = set()
        point = check_point(model, point)
        self.given: set[int] = set()  # element hashes the user gave
        self.t = point["t"][0] if "t" in point else float(self._random(1)[0])
        for var in model.parameters:
            for i in range(var.size):
                self.values[var.sym[i].element_hash()] = float(var.default[i])
        for name, arr in point.items():
            if name == "t":
                continue
            for (var, i, order), v in zip(model.resolve(name), arr, strict=True):
                h = var.der(order)[i].element_hash()
                self.values[h] = float(v)
                self.given.add(h)
        self.status: PointStatus | None = None

    def _random(self, size: int) -> np.ndarray:
        kind, a, b = self.draw
        # the first draw: small positive values, generic and safe for sqrt, log and exp of
        # differences; the later ones reach other parts of a model's domain
        return self.rng.uniform(a, b, size) if kind == "uniform" else self.rng.normal(a, b, size)

    def evaluate(self, syms, hashes=None) -> np.ndarray:
        """Values of the scalar symbols ``syms`` (drawn where not set yet, in order);
        ``hashes``: their element hashes, when the caller keeps them."""
        if hashes is None:
            hashes = [s.element_hash() for s in syms]
        vals = self.values
        for h in hashes:
            if h not in vals:
                vals[h] = float(self._random(1)[0])
                self.drawn.add(h)
        return np.fromiter((vals[h] for h in hashes), dtype=float, count=len(hashes))

    def sibling(self, k: int) -> TestPoint:
        """Another test point with the same time, inputs and user values, and new random
        values elsewhere (seeded by ``k``)."""
        other = TestPoint(self.model, self.point, self.seed + 104729 * k, self.attempt + k)
        other.t = self.t
        held = _fixed_kinds(self.model)
        for h, v in self.values.items():
            if h in held:
                other.values[h] = v
        return other

    def random_copy(self) -> TestPoint:
        """The point as first drawn (before any :func:`make_consistent`): same seed, same
        draws, same user values."""
        return self.sibling(0)

    def perturbed(self, k: int = 1) -> TestPoint:
        """A point near this one in the model's own units: every value that is not held
        (time, parameters, inputs) multiplied by a factor from ``U(0.5, 1.5)`` (exact zeros
        and unset symbols drawn afresh). The reference for entries that vanish on the
        solutions (:data:`daekit.numerics.VANISH`): a genuine entry, a product of powers of
        the values, changes by a bounded factor between the two points whatever the units,
        while one that vanishes at a consistent point (a residual's multiple) does not
        vanish at the perturbed one. A random point in other units can make a genuine
        entry look vanishing (``(3996 x)^3`` at ``x = 5e-4`` against ``x = 0.7``)."""
        other = TestPoint(self.model, self.point, self.seed + 15485863 * k, self.attempt)
        other.t = self.t
        held = _fixed_kinds(self.model)
        for h, v in self.values.items():
            if h in held or h in self.given:
                other.values[h] = v
            elif v != 0.0:
                other.values[h] = v * float(other.rng.uniform(0.5, 1.5))
        return other

    def assign(self, syms, vals) -> None:
        for s, v in zip(syms, vals, strict=True):
            h = s.element_hash()
            self.values[h] = float(v)
            self.drawn.discard(h)

    def sparse(self, expr: ca.SX) -> sp.csr_matrix:
        """Numeric value of a (sparse) SX matrix at this point, as a SciPy sparse matrix
        (for several points, make a :class:`PointFunction` once)."""
        return PointFunction(self.model, expr).sparse(self)

    def hold_from(self, other: TestPoint) -> None:
        """Take ``other``'s values of the held symbols (time, parameters, inputs and their
        derivatives) where it has them."""
        self.t = other.t
        for h in _fixed_kinds(self.model):
            if h in other.values:
                self.values[h] = other.values[h]


class PointFunction:
    """A (sparse) SX expression of a model's symbols, made into a function once and
    evaluated at :class:`TestPoint` objects.

    >>> import casadi as ca, daekit as dk
    >>> m = dk.Model("m"); x = m.state("x")
    >>> f = PointFunction(m, ca.vertcat(2 * x, 0))
    >>> f.dense(TestPoint(m, {"x": 3.0})).tolist()
    [[6.0], [0.0]]
    """

    def __init__(self, model, expr: ca.SX) -> None:
        th = model.t.element_hash()
        self.syms = [s for s in ca.symvar(expr) if s.element_hash() != th]
        self.hashes = [s.element_hash() for s in self.syms]
        S = ca.vertcat(*self.syms) if self.syms else ca.SX(0, 1)
        self.f = SparseFunction([model.t, S], expr)

    def sparse(self, pt: TestPoint) -> sp.csr_matrix:
        return self.f(pt.t, pt.evaluate(self.syms, self.hashes))

    def dense(self, pt: TestPoint) -> np.ndarray:
        return self.f.dense(pt.t, pt.evaluate(self.syms, self.hashes))


@dataclass
class PointStatus:
    """How a test point was obtained: ``consistent``; ``residual``, the largest residual of an
    equation row relative to the size of its terms ``sum_j |J_ij w_j|``; ``iterations`` of
    Gauss--Newton; ``given`` (the user's point was already consistent); ``worst`` (the
    equation rows with the largest residual when not consistent); ``distance``, where the
    point was accepted by the distance its converging iteration predicts (a multiple root,
    rounding in rows whose terms cancel; see :func:`gauss_newton`), that distance relative
    to the values, else None."""

    consistent: bool
    residual: float
    iterations: int = 0
    given: bool = False
    worst: list[int] | None = None
    distance: float | None = None


def _fixed_kinds(model) -> set[int]:
    """Element hashes of the symbols held fixed: parameters, inputs and input derivatives
    (every derivative created so far)."""
    out = set()
    for var in model.variables.values():
        if var.kind not in ("parameter", "control"):
            continue
        for order in [0, *var.ders]:
            s = var.der(order)
            out.update(s[i].element_hash() for i in range(var.size))
    return out


def _movable(model, syms) -> list:
    """The symbols among ``syms`` that Gauss--Newton may move: unknowns and their derivatives
    (not time, parameters, or inputs and their derivatives)."""
    th = model.t.element_hash()
    held = _fixed_kinds(model)
    return [s for s in syms if s.element_hash() != th and s.element_hash() not in held]


def make_consistent(pt: TestPoint, equations: ca.SX, max_iter: int = 60,
                    tol: float = POINT_TOL, cache: dict | None = None) -> PointStatus:
    """Move the unknowns of ``pt`` (not time, inputs or parameters) onto ``equations = 0``.

    Gauss--Newton with minimum-norm steps from the point's current values (:func:`gauss_newton`).
    On success the point's values are replaced by the solution; on failure they are left as
    they were. Returns the :class:`PointStatus` (also stored as ``pt.status``). ``cache``: a
    dict kept by the caller for one ``equations`` (the same object each call): the CasADi
    functions of the iteration are made once for all points solved with it.

    >>> import casadi as ca, daekit as dk
    >>> m = dk.Model("m"); x = m.state("x"); z = m.algebraic("z")
    >>> _ = m.equation(z - 1e6 * x, name="e")
    >>> pt = TestPoint(m, None); make_consistent(pt, m.residual).consistent
    True
    """
    model = pt.model
    if cache is None:
        cache = {}
    if "G" not in cache:
        G = ca.vec(ca.SX(equations))
        cache["G"] = G
        cache["syms"] = _movable(model, ca.symvar(G))
    G, syms = cache["G"], cache["syms"]
    if pt.given and any(s.element_hash() in pt.given for s in syms):
        # the user's values are held; where they admit no consistent completion the point is
        # used as the user gave it (and the status says it is not consistent)
        held = [s for s in syms if s.element_hash() not in pt.given]
        st = _solve(pt, G, held, max_iter, tol, cache)
        st.given = True
        pt.status = st
        return st
    st = _solve(pt, G, syms, max_iter, tol, cache)
    pt.status = st
    return st


def _solve(pt: TestPoint, G: ca.SX, syms: list, max_iter: int, tol: float,
           cache: dict | None = None) -> PointStatus:
    """Gauss--Newton on ``G = 0`` in the symbols ``syms`` (the others held at their values)."""
    model = pt.model
    key = tuple(s.element_hash() for s in syms)
    made = cache.get(key) if cache is not None else None
    if made is None:
        moving = set(key)
        th = model.t.element_hash()
        fixed = [s for s in ca.symvar(G) if s.element_hash() not in moving and s.element_hash() != th]
        W = ca.vertcat(*syms) if syms else ca.SX(0, 1)
        Fx = ca.vertcat(*fixed) if fixed else ca.SX(0, 1)
        JG = ca.jacobian(G, W)
        if _is_dense(len(syms), G.numel()):
            # small: G and the nonzeros of its Jacobian from one function (one CasADi
            # Function made instead of two; the Jacobian at the point just evaluated is free)
            both = FastFunction(ca.Function("consistency", [model.t, Fx, W],
                                            [G, JG.nz[:] if JG.nnz() else ca.SX(0, 1)]))
            colind, row = JG.sparsity().get_ccs()
            rows = np.asarray(row, dtype=np.int64)
            cols = major_index(colind)
            made = (fixed, both, (JG.shape, rows, cols))
        else:
            f = FastFunction(ca.Function("consistency", [model.t, Fx, W], [G]))
            made = (fixed, f, SparseFunction([model.t, Fx, W], JG))
        if cache is not None:
            cache[key] = made
    fixed, f, fj = made
    fv = pt.evaluate(fixed)
    w0 = pt.evaluate(syms)

    if isinstance(fj, tuple):
        shape, rows, cols = fj
        last: dict = {}

        def both_at(w):
            kw = np.asarray(w, dtype=float).tobytes()
            if last.get("w") != kw:
                last["w"], last["out"] = kw, f(pt.t, fv, w)
            return last["out"]

        def fun(w):
            return both_at(w)[0]

        def jac(w):
            out = np.zeros(shape)
            out[rows, cols] = both_at(w)[1]
            return out
    else:
        def fun(w):
            return f(pt.t, fv, w)[0]

        def jac(w):
            return fj.csc(pt.t, fv, w)

    fresh = np.fromiter((h in pt.drawn for h in key), dtype=bool, count=len(key))
    for start in _starts(fun, jac, w0, fresh):
        w, st = gauss_newton(fun, start, tol=tol, max_iter=max_iter, jac=jac)
        if st.consistent:
            pt.assign(syms, w)
            break
    return st


def _starts(fun, jac, w0: np.ndarray, fresh: np.ndarray):
    """Starts of Gauss--Newton for :func:`_solve`, tried in turn. ``fresh``: which values of
    ``w0`` were drawn at random (the others were solved for before, e.g. the lower levels of a
    derivative array).

    * All drawn: first the draws *in the Jacobian's own units*, ``w_j = dc_j r_j`` with
      ``dc`` the column factors of the equilibrated Jacobian at that start (three rounds, the
      fixed point of a nonlinear model's scaling), then the draws as they are. A draw of
      ``U(0.1, 0.3)`` in a variable's unit of ``1e-6`` is ``2e5`` physically: Gauss--Newton
      from there spread the correction of such a row over the free values (an ODE state
      at ``1e9`` and its derivatives at ``1e19`` in the derivative array) or stalled; the column
      factors carry the units (a column of ``c x`` gets ``~1/c``), so the first start does not
      depend on them.
    * Some drawn (a new level of a derivative array on the last level's point): ``w0`` as
      it is. (Solving first for the drawn values alone, the others held, led Gauss--Newton
      onto the singular branch ``x2 = 0`` of lecture L6.)
    """
    if not fresh.any() or w0.size == 0:
        yield w0
        return
    if fresh.all():
        ws = in_jacobian_units(jac, w0)
        if ws is not w0:
            yield ws
    yield w0


def in_jacobian_units(jac, r: np.ndarray, rounds: int = 3) -> np.ndarray:
    """Random values ``r`` in the units the Jacobian suggests: ``w = dc * r`` with ``dc`` the
    column factors of the equilibrated ``jac(w)`` (:func:`daekit.numerics.equilibrate`), a few
    rounds from ``w = r`` (the fixed point of a nonlinear model's scaling); ``r`` itself where
    a Jacobian is not finite at once. A column of ``c x`` gets a factor ``~ 1/c``: the start
    does not depend on the units of the unknowns.

    >>> import numpy as np
    >>> w = in_jacobian_units(lambda w: np.array([[1e6, 1.0]]), np.array([0.2, 0.3]))
    >>> bool(w[0] < 1e-3 < w[1])
    True
    """
    ws = r
    for _ in range(rounds):
        J = jac(ws)
        if not np.all(np.isfinite(J.data if sp.issparse(J) else J)):
            break
        nxt = equilibrate(J)[1] * r
        if np.array_equal(nxt, ws):
            break
        ws = nxt
    return ws


def consistent_point(pt: TestPoint, equations: ca.SX, starts: int = 3,
                     cache: dict | None = None) -> PointStatus:
    """:func:`make_consistent` from ``pt``; where that fails, from up to ``starts - 1`` other
    random starts (same time and inputs), whose solution is then copied into ``pt``. The
    returned status says whether a consistent point was found. ``cache``: see
    :func:`make_consistent`.

    >>> import casadi as ca, daekit as dk
    >>> m = dk.Model("m"); x = m.state("x")
    >>> _ = m.equation(x**2 - 4, name="e")
    >>> pt = TestPoint(m, None); consistent_point(pt, m.residual).consistent
    True
    """
    if cache is None:
        cache = {}
    st = make_consistent(pt, equations, cache=cache)
    k = 1
    while not st.consistent and k < starts and not st.given:
        alt = pt.sibling(k)
        st2 = make_consistent(alt, equations, cache=cache)
        if st2.consistent:
            for h, v in alt.values.items():
                pt.values[h] = v
            pt.drawn = (pt.drawn - alt.values.keys()) | alt.drawn
            pt.status = st = st2
        k += 1
    return st


def gauss_newton(fun, w0: np.ndarray, tol: float = POINT_TOL, max_iter: int = 60, jac=None,
                 rescale: bool = True) -> tuple[np.ndarray, PointStatus]:
    """Solve the (under- or over-determined) ``h(w) = 0`` by Gauss--Newton with minimum-norm
    steps, a trust radius and a backtracking line search, in the coordinates of the
    equilibrated first Jacobian (rows and columns scaled, :func:`daekit.numerics.equilibrate`),
    so that the units of equations and unknowns do not matter. ``fun(w) -> h`` and
    ``jac(w) -> J`` (sparse); without ``jac``, ``fun(w) -> (h, J)``. ``rescale``: equilibrated
    afresh at every iterate (for starts far from the solutions in badly scaled units).

    Converged (``consistent``) when

    * every row's scaled residual is below ``tol`` times the size of the row's terms
      ``sum_j |J_ij w_j|`` (``tol`` where they are all zero), or
    * the iteration converges to a zero that this test cannot see, a multiple root
      (``h = x^2``: the residual stays half the row's terms) or rounding in a row whose
      terms cancel: the previous step was a full step, the step shrank
      (``q = |d_k| / |d_{k-1}| <= LINEAR_RATE``), it removes the residual to first order
      (``|h + J d| <= |h| / 2``: not a stationary point of ``|h|`` with ``h != 0``), and the
      distance to the limit it predicts, ``|d_j| / (1 - q)``, is below ``POINT_DIST`` times
      the larger of ``|w_j|`` and its start's value for every unknown (so that the test is
      the same in any units).

    >>> import numpy as np, scipy.sparse as sp
    >>> fun = lambda w: (np.array([w[0]**2 + w[1]**2 - 1]), sp.csr_matrix([[2*w[0], 2*w[1]]]))
    >>> w, st = gauss_newton(fun, np.array([0.3, 0.2]))
    >>> st.consistent, round(float(w @ w), 12)
    (True, 1.0)
    >>> w, st = gauss_newton(lambda w: (w**2, sp.csr_matrix([[2 * w[0]]])), np.array([0.5]))
    >>> st.consistent, bool(abs(w[0]) < 1e-7)  # a double root, converging linearly
    (True, True)
    """
    if jac is None:
        both = fun
        fun = lambda w: both(w)[0]  # noqa: E731
        jac = lambda w: both(w)[1]  # noqa: E731
    w = np.array(w0, dtype=float)
    h = np.asarray(fun(w), dtype=float)
    if h.size == 0:
        return w, PointStatus(True, 0.0, 0)
    n = w.size
    dense = _is_dense(n, h.size)
    if dense:
        jac_sparse = jac

        def jac(wv):
            Jv = jac_sparse(wv)
            return Jv.toarray() if sp.issparse(Jv) else np.asarray(Jv, dtype=float)

        def scaled(Jv):
            return Jv * dr[:, None] * dc[None, :]
    else:
        jac_any = jac

        def jac(wv):  # CSC throughout (the KKT matrix and the scaling are built from it)
            Jv = jac_any(wv)
            return Jv if getattr(Jv, "format", None) == "csc" else sp.csc_matrix(Jv)

        def scaled(Jv):
            return sp.csc_matrix((Jv.data * dr[Jv.indices] * dc[ops.cols_of(Jv)], Jv.indices,
                                  Jv.indptr), shape=Jv.shape)
    J = jac(w)
    Jdata = J if dense else J.data
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(Jdata))):
        return w, PointStatus(False, float("inf"), 0, worst=_worst(h, np.ones(h.size)))
    dr, dc = equilibrate(J)
    inv_dc = 1.0 / dc
    ops = None if dense else _CscOps(J)  # the row maxima and sums of the pattern, made once

    def col_scaled_row_max(Jv):
        """Largest ``|J_ij dc_j|`` of each row (NaN and inf as 0)."""
        if dense:
            return _row_max(Jv * dc[None, :])
        return ops.row_max(Jv, Jv.data * dc[ops.cols_of(Jv)])

    row_ref = col_scaled_row_max(J)  # at the equilibration

    def merit(hv):
        return np.abs(dr * hv)

    def level(wv, Jv):
        """Per row: ``tol`` times the size of the row's terms ``sum_j |dr_i J_ij w_j|`` (``tol``
        itself where they are all zero): a row of small terms among large values is held to
        its own scale (a tolerance relative to the largest value accepted points off by 0.05
        in rows whose terms are of order 1, and one with a floor from the largest value a
        point with a residual of 83 where Gauss-Newton had wandered to values of 1e12)."""
        if not n:
            return tol
        if ops is not None:
            terms = dr * ops.abs_dot(Jv, np.abs(wv))
        else:
            Ja = abs(Jv) if sp.issparse(Jv) else np.abs(Jv)
            terms = dr * np.asarray(Ja @ np.abs(wv), dtype=float).ravel()
        return tol * np.where(terms > 0, terms, 1.0)

    def finite(hv):
        return bool(np.isfinite(hv).all())

    def relative(wv, Jv, rv) -> float:
        """The largest row residual relative to the row's terms (``level`` over ``tol``)."""
        return float(np.max(rv / (level(wv, Jv) / tol))) if rv.size else 0.0

    r = merit(h)
    radius = 2.0 * (1.0 + float(np.max(np.abs(w / dc)))) if n else 1.0
    # the sizes the predicted distance to the limit is measured against: each unknown's own
    # value or its start's, whichever is larger (both scale with the unknown's unit; an
    # absolute floor of 1 did not: (x - 1)^2 with x in units of 1e-9 was accepted 1e-4 off),
    # the largest start where an unknown starts and stays at 0
    start_size = np.abs(w * inv_dc)
    if n:
        start_size = np.where(start_size > 0, start_size,
                              float(start_size.max()) if start_size.max() > 0 else 1.0)
    full_steps, last_size = 0, 0.0  # full steps taken in a row, the size of the last step
    for it in range(max_iter + 1):
        if it:
            J = jac(w)
            if not np.all(np.isfinite(J if dense else J.data)):
                break
        if np.all(r <= level(w, J)):
            # polish to rounding: full Newton steps while the residual drops tenfold (the
            # Jacobians at the point must not carry residue of terms that vanish there)
            for polish in range(4):
                if not (r.max() > 0 and n):
                    break
                if polish:  # (the first at the point whose Jacobian J is already)
                    J = jac(w)
                d = _min_norm_step(scaled(J), dr * h)
                if d is None or not np.all(np.isfinite(d)):
                    break
                hn = fun(w + dc * d)
                if not (finite(hn) and merit(hn).max() < 0.1 * r.max()):
                    break
                w, h, r = w + dc * d, hn, merit(hn)
            return w, PointStatus(True, relative(w, J, r), it)
        if it == max_iter or n == 0:
            break
        if it and rescale:
            # re-equilibrated at every iterate: the first Jacobian, at a start far from the
            # solutions, can scale a nonlinear equation (x + x^3 / 10 in a unit of 1e5) by
            # many orders of magnitude wrongly for the points where it holds
            # (the rows only: the columns' factors set the metric of the minimum-norm steps,
            # and changing it between iterates let a system with free unknowns drift)
            # (again only where a row's largest scaled entry moved by more than a factor of
            # 2 since the last equilibration: within that the powers of two stand as they are)
            rmax = col_scaled_row_max(J)
            if not (np.all((rmax == 0) == (row_ref == 0))
                    and np.all((rmax <= 2.0 * row_ref) & (row_ref <= 2.0 * rmax))):
                Jc = J * dc[None, :] if dense else sp.csc_matrix(
                    (J.data * dc[ops.cols_of(J)], J.indices, J.indptr), shape=J.shape)
                dr = equilibrate(Jc)[0]
                row_ref = rmax
                r = merit(h)
        Js = scaled(J)
        d = _min_norm_step(Js, dr * h)
        if d is None or not finite(d):
            break
        size = float(np.abs(d).max()) if d.size else 0.0
        if full_steps >= 1 and last_size > 0:
            q = size / last_size
            if q <= LINEAR_RATE and _norm(dr * h + Js @ d) <= 0.5 * _norm(dr * h):
                ahead = np.abs(d) / (1.0 - q) / np.maximum(np.abs(w * inv_dc), start_size)
                if np.all(ahead <= POINT_DIST):
                    # converging to a zero the residual test does not see (see above):
                    # the step taken where it does not raise the residual
                    hn = fun(w + dc * d)
                    if finite(hn) and merit(hn).max() <= r.max():
                        w, h, r = w + dc * d, hn, merit(hn)
                    return w, PointStatus(True, relative(w, J, r), it,
                                          distance=float(ahead.max()))
        alpha = min(1.0, radius / size) if size > 0 else 1.0
        norm0 = _norm(r)
        dw = dc * d
        for _ in range(30):
            wn = w + alpha * dw
            hn = fun(wn)
            if finite(hn):
                rn = merit(hn)
                if _norm(rn) <= (1 - 1e-4 * alpha) * norm0 or np.all(rn <= level(wn, J)):
                    break
            alpha *= 0.5
        else:
            break
        full_steps = full_steps + 1 if alpha == 1.0 else 0
        last_size = size
        radius = 4.0 * alpha * size if alpha * size * 1.5 >= radius else max(alpha * size, 1e-8)
        radius = max(radius, 1e-3 * (1.0 + float(np.abs(wn * inv_dc).max())))
        w, h, r = wn, hn, rn
    return w, PointStatus(False, relative(w, J, r), it, worst=_worst(h, dr))


class _CscOps:
    """Row maxima and row sums over the nonzeros of CSC matrices of one pattern (the
    Jacobians of one Gauss--Newton run), without making SciPy matrices: the column of each
    nonzero and the row segments (:class:`daekit.numerics.Segments`) are found once. A
    matrix of another pattern takes the general route."""

    def __init__(self, J: sp.csc_matrix) -> None:
        self.shape = J.shape
        self.indptr, self.indices = J.indptr, J.indices
        self.cols = major_index(J.indptr)
        self.seg = Segments(J.shape[0], J.shape[1], J.indices, self.cols)

    def same(self, J) -> bool:
        return J.shape == self.shape and (J.indices is self.indices or (
            J.indices.size == self.indices.size and np.array_equal(J.indptr, self.indptr)
            and np.array_equal(J.indices, self.indices)))

    def cols_of(self, J) -> np.ndarray:
        """The column of each nonzero of ``J``."""
        return self.cols if self.same(J) else major_index(J.indptr)

    def row_max(self, J, data: np.ndarray) -> np.ndarray:
        """Largest ``|data|`` of each row of ``J``'s pattern (NaN and inf as 0)."""
        if not self.same(J):
            return _row_max(sp.csc_matrix((data, J.indices, J.indptr), shape=J.shape))
        a = np.abs(data)
        a[~np.isfinite(a)] = 0.0
        return self.seg.row_max(a)

    def abs_dot(self, J, v: np.ndarray) -> np.ndarray:
        """``|J| @ v``."""
        if not self.same(J):
            return np.asarray(abs(J) @ v, dtype=float).ravel()
        return np.bincount(J.indices, np.abs(J.data) * v[self.cols], minlength=self.shape[0])


def _row_max(J) -> np.ndarray:
    """Largest magnitude in each row of ``J`` (dense, or sparse), NaN and inf as 0."""
    if not sp.issparse(J):
        a = np.abs(J)
        a[~np.isfinite(a)] = 0.0
        return a.max(axis=1) if a.shape[1] else np.zeros(a.shape[0])
    J = sp.csr_matrix(J)
    a = np.abs(J.data)
    a[~np.isfinite(a)] = 0.0
    out = np.zeros(J.shape[0])
    counts = np.diff(J.indptr)
    has = counts > 0
    if a.size:
        out[has] = np.maximum.reduceat(a, J.indptr[:-1][has])
    return out


def _norm(v: np.ndarray) -> float:
    """Euclidean norm of the finite ``v`` without overflow (residuals far from a solution
    can exceed 1e154)."""
    m = float(np.abs(v).max()) if v.size else 0.0
    if m == 0.0 or not np.isfinite(m):
        return m
    u = v / m
    return m * float(np.sqrt(u @ u))


def _worst(h, dr) -> list[int]:
    r = np.abs(dr * h)
    r = np.where(np.isfinite(r), r, np.inf)
    top = r.max() if r.size else 0.0
    return np.nonzero(r >= 1e-3 * top)[0].tolist() if top > 0 else []


def _is_dense(n: int, m: int) -> bool:
    """Whether Gauss--Newton on ``m`` equations in ``n`` unknowns uses dense linear algebra."""
    return n <= DENSE_UNKNOWNS and m <= 4 * DENSE_UNKNOWNS


_KKT = PatternCache(1)  # the last KKT pattern, per thread


def _kkt(J: sp.csc_matrix, mu: float) -> sp.csc_matrix:
    """``[[I, J^T], [J, -mu I]]`` (CSC) with its pattern assembled once per pattern of ``J``
    (the iterations of one Gauss--Newton run share it): each call only places the values."""
    J.sort_indices()
    m, n = J.shape

    def assemble():
        # markers: 1..nnz the entries of J, nnz+1..2 nnz those of J^T, -1 the identity,
        # -2 the -mu diagonal
        nnz = J.nnz
        Jm = sp.csc_matrix((np.arange(1, nnz + 1, dtype=float), J.indices, J.indptr), shape=(m, n))
        Jt = sp.csc_matrix(Jm.T)
        Jt.data = Jt.data + nnz
        K = sp.bmat([[-sp.identity(n, format="csc"), Jt], [Jm, -2 * sp.identity(m)]],
                    format="csc")
        K.sort_indices()
        mk = K.data.astype(np.int64)
        return dict(K=K, src=np.where(mk > nnz, mk - nnz - 1, mk - 1), ident=mk == -1,
                    reg=mk == -2, nnz=nnz)

    c = _KKT.get(PatternCache.key(m, n, J.nnz, J.indptr, J.indices), assemble)
    vals = J.data[np.clip(c["src"], 0, max(c["nnz"] - 1, 0))] if c["nnz"] else np.zeros(
        c["src"].size)
    vals = np.where(c["ident"], 1.0, np.where(c["reg"], -mu, vals))
    K = c["K"]
    return sp.csc_matrix((vals, K.indices, K.indptr), shape=K.shape)


_STEP_PATH = PatternCache(4)  # per pattern of J: whether the normal equations are sparse


def _normal_fits(J: sp.csc_matrix) -> bool:
    """Whether ``J J^T`` of the pattern of ``J`` has at most ``2 nnz(J) + m`` entries: those
    of ``P P^T``, ``P`` the pattern with ones (no entries cancel), not formed where one
    column of ``c`` entries alone puts a ``c``-by-``c`` block over the limit."""
    m = J.shape[0]
    limit = 2 * J.nnz + m
    widest = int(np.diff(J.indptr).max(initial=0))
    if widest * widest > limit:
        return False
    P = sp.csc_matrix((np.ones(J.nnz), J.indices, J.indptr), shape=J.shape)
    return (P @ P.T).nnz <= limit


def _min_norm_step(J, h: np.ndarray) -> np.ndarray | None:
    """``d`` with ``J d ~ -h`` of least norm: ``d = -J^T (J J^T + mu I)^{-1} h`` with a tiny
    ``mu`` (redundant rows do no harm), dense SVD for small problems."""
    m, n = J.shape
    if _is_dense(n, m):
        A = J.toarray() if sp.issparse(J) else J
        try:
            return -np.linalg.lstsq(A, h, rcond=1e-12)[0]
        except np.linalg.LinAlgError:
            return None
    mu = 1e-12
    J = sp.csc_matrix(J)
    # the normal equations (J J^T + mu I) y = h, d = -J^T y, where J J^T stays about as sparse
    # as J (chains, meshes: a symmetric positive definite matrix a fifth of the KKT system's
    # size, factorized in a quarter of its time, 200-link chain); else (a column shared by
    # many rows fills J J^T) the augmented system below; decided once per pattern of J before
    # J J^T is formed (:func:`_normal_fits`: one unknown in every row of a 20,000-row J would
    # have made it 4e8 entries)
    if _STEP_PATH.get(PatternCache.key(m, n, J.indptr, J.indices), lambda: _normal_fits(J)):
        JJ = (J @ J.T).tocsc()
        band = _band_solver(JJ, mu)  # narrow band after reordering: banded Cholesky
        if band is not None:
            y = band(h)
            y = y + band(h - JJ @ y - mu * y)  # one step of iterative refinement
            return -(J.T @ y)
        JJ = JJ + mu * sp.identity(m, format="csc")
        try:
            lu = sp.linalg.splu(JJ, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1,
                                options={"SymmetricMode": True})
        except RuntimeError:
            lu = None
        if lu is not None:
            y = lu.solve(h)
            y = y + lu.solve(h - JJ @ y)  # one step of iterative refinement
            return -(J.T @ y)
    # the augmented (quasi-definite) system [[I, J^T], [J, -mu I]] [d; y] = [0; -h]: its
    # sparse LU stays linear in the size for chains and meshes
    K = _kkt(J, mu)
    try:
        # threshold partial pivoting (0.1, as MA48 and UMFPACK): less fill than strict
        # partial pivoting; the refinement step below recovers the accuracy
        lu = sp.linalg.splu(K, permc_spec="COLAMD", diag_pivot_thresh=0.1)
    except RuntimeError:
        return None
    rhs = np.r_[np.zeros(n), -h]
    sol = lu.solve(rhs)
    sol = sol + lu.solve(rhs - K @ sol)  # one step of iterative refinement
    return sol[:n]


#: Widest band (after reverse Cuthill--McKee) of ``J J^T`` factorized as a band matrix.
BAND_LIMIT = 24
_BAND = PatternCache(1)  # the last pattern's ordering, per thread


def _band_solver(A: sp.csc_matrix, mu: float):
    """``b -> (A + mu I)^{-1} b`` for the symmetric positive semidefinite ``A = J J^T`` by a
    banded Cholesky factorization in the reverse Cuthill--McKee order (found once per
    pattern: the iterations of one Gauss--Newton run share it), or None where that order's
    band is wider than ``BAND_LIMIT`` or the factorization fails (then SuperLU). A chain's
    ``J J^T`` (600 rows, band 9 at 200 links) factorizes in a quarter of SuperLU's time."""
    m = A.shape[0]

    def order():
        perm = sp.csgraph.reverse_cuthill_mckee(A.tocsr(), symmetric_mode=True)
        inv = np.empty(m, dtype=np.int64)
        inv[perm] = np.arange(m)
        pr = inv[A.indices]
        pc = inv[major_index(A.indptr)]
        low = pr >= pc
        width = int((pr - pc)[low].max(initial=0))
        return perm, width, (pr - pc)[low], pc[low], np.nonzero(low)[0]

    hit = _BAND.get(PatternCache.key(m, A.indptr, A.indices), order)
    perm, width, band_row, band_col, take = hit
    if width > BAND_LIMIT:
        return None
    from scipy.linalg import LinAlgError, cho_solve_banded, cholesky_banded

    ab = np.zeros((width + 1, m))
    ab[band_row, band_col] = A.data[take]
    ab[0] += mu
    try:
        c = cholesky_banded(ab, lower=True, check_finite=False)
    except LinAlgError:
        return None
    if not np.all(np.isfinite(c)):
        return None

    def solve(b: np.ndarray) -> np.ndarray:
        out = np.empty(m)
        out[perm] = cho_solve_banded((c, True), b[perm], check_finite=False)
        return out

    return solve


def remember_consistent(model, pt: TestPoint) -> None:
    """Keep the values of the consistent point ``pt`` of ``model`` (the equations and their
    derivatives up to Pryce's offsets hold there: :func:`daekit.analyze`'s point) on the
    model until it changes, for :func:`reduced_consistent_point` of its reduced systems (a
    start that is consistent already: one check instead of a Gauss--Newton solve).

    >>> import daekit as dk
    >>> m = dk.examples.pendulum_planar()
    >>> _ = dk.analyze(m)  # keeps its consistent point here
    >>> t, values, params = m.memo("results", dict)["consistent_point"]
    >>> params.tolist(), len(values) > 0  # the parameter values it holds for, the values
    ([9.81, 1.0], True)
    """
    if pt.status is None or not pt.status.consistent:
        return
    model.memo("results", dict)["consistent_point"] = (
        float(pt.t), dict(pt.values), np.asarray(model.parameter_values, dtype=float).copy())


def _remembered_start(r):
    """``(t, w, u)`` of the remembered consistent point of ``r.model`` in the symbols of
    ``r`` (``w = (x, z)``), or None (none kept, other parameter values, a symbol it lacks)."""
    model = getattr(r, "model", None)
    if model is None or not hasattr(model, "memo"):
        return None
    got = model.memo("results", dict).get("consistent_point")
    if got is None:
        return None
    t, values, pv = got
    if pv.shape != np.shape(r.p_values) or not np.array_equal(pv, np.asarray(r.p_values, float)):
        return None
    w = ca.vertcat(r.x, r.z)
    if not (w.is_valid_input() and (r.u.numel() == 0 or r.u.is_valid_input())):
        return None
    out = []
    for v in (w, r.u):
        hashes = [e.element_hash() for e in ca.vertsplit(v)] if v.numel() else []
        if any(h not in values for h in hashes):
            return None
        out.append(np.array([values[h] for h in hashes], dtype=float))
    return t, out[0], out[1]


def reduced_point_functions(r) -> tuple:
    """``(f, jac)``: ``G = [alg; invariants]`` of the ReducedDAE ``r`` and its Jacobian with
    respect to ``w = (x, z)``, as functions of ``(t, u, w, p)`` (``f`` returns ``[G]``, ``jac``
    a dense array for small systems, else SciPy CSC), made once per system: the consistent
    points of :func:`reduced_consistent_point` and the index-1 check of
    :func:`daekit.reduction.check_index1` (rows ``:nz`` are ``d alg / dw``) share them.

    >>> import daekit as dk, numpy as np
    >>> r = dk.reduce_index(dk.examples.pendulum_planar())
    >>> f, jac = reduced_point_functions(r)
    >>> jac(0.0, np.zeros(0), np.ones(5), r.p_values).shape
    (3, 5)
    """
    return r.derived("reduced_point_functions", _reduced_point_functions)


class SystemJacobians(NamedTuple):
    """``[alg; invariants]`` of a ReducedDAE as dense columns and their Jacobians with
    respect to ``w = (x, z)``: see :func:`system_jacobians`."""

    w: ca.SX
    alg: ca.SX
    inv: ca.SX  # 0 x 1 without invariants
    J_alg: ca.SX
    J_inv: ca.SX | None  # None without invariants


def system_jacobians(r) -> SystemJacobians:
    """``[alg; invariants]`` of the ReducedDAE ``r`` as dense columns and their symbolic
    Jacobians with respect to ``w = (x, z)`` (``J_inv`` None without invariants), made once
    per system and shared by the consistent points (:func:`reduced_point_functions`) and
    :func:`daekit.initialize`. A system whose ``t``, ``x``, ``z``, ``u`` or ``p`` are not
    distinct plain symbols is a :class:`~daekit.errors.ModelError` naming the first culprit.

    >>> import daekit as dk
    >>> r = dk.reduce_index(dk.examples.pendulum_planar())
    >>> sj = system_jacobians(r)
    >>> sj.J_alg.shape, sj.J_inv.shape
    ((1, 5), (2, 5))
    """
    return r.derived("system_jacobians", _system_jacobians)


def _system_jacobians(r) -> SystemJacobians:
    w = ca.vertcat(r.x, r.z)
    for what, v, names in (("state", r.x, r.x_names), ("algebraic unknown", r.z, r.z_names),
                           ("input", r.u, r.u_names), ("parameter", r.p, r.p_names),
                           ("time", r.t, ["t"])):
        if v.numel() and not v.is_valid_input():
            raise ModelError(_not_plain(what, v, names))
    every = ca.vertcat(r.t, w, r.u, r.p)
    if len(ca.symvar(every)) != every.numel():  # (symvar lists each symbol once)
        raise ModelError("the system's time, states, algebraic unknowns, inputs and parameters "
                         "must be distinct symbols; one symbol is used as two of them")
    alg = ca.vec(ca.densify(ca.SX(r.alg)))
    inv = ca.vec(ca.densify(ca.SX(r.invariants))) if r.invariants.numel() else ca.SX(0, 1)
    # one Jacobian per block (CasADi's jacobian of the stacked rows costs more than both)
    Ja = ca.jacobian(alg, w)
    Ji = ca.jacobian(inv, w) if inv.numel() else None
    return SystemJacobians(w, alg, inv, Ja, Ji)


def _not_plain(what: str, v: ca.SX, names) -> str:
    """The message for a ``what`` vector ``v`` that is not distinct plain symbols."""
    seen = set()
    for i, e in enumerate(ca.vertsplit(v)):
        name = names[i] if i < len(names) else f"element {i}"
        if not e.is_symbolic():
            return (f"the system's {what} {name!r} is the expression {e} where a plain CasADi "
                    f"symbol is needed; make it a symbol (ca.SX.sym) and state the relation "
                    f"as an equation")
        h = e.element_hash()
        if h in seen:
            return f"the system's {what} {name!r} repeats a symbol used before it; each needs its own"
        seen.add(h)
    return f"the system's {what}s are not plain CasADi symbols"


def _reduced_point_functions(r):
    """The functions of :func:`reduced_consistent_point` for ``r`` (made once per system):
    ``(f, jac)`` of ``G = [alg; invariants]`` in ``(t, u, w, p)``."""
    sj = system_jacobians(r)
    args = [r.t, r.u, sj.w, r.p]
    G = ca.vertcat(sj.alg, sj.inv)
    J = ca.vertcat(sj.J_alg, sj.J_inv) if sj.J_inv is not None else sj.J_alg
    f = FastFunction(ca.Function("g", args, [G]))
    fj = SparseFunction(args, J)
    return f, (fj.dense if _is_dense(r.nx + r.nz, G.numel()) else fj.csc)


def reduced_consistent_point(r, seed: int = 0, t: float | None = None, starts: int = 5,
                             remembered: bool = False):
    """A point ``(t, x, z, u, p)`` of a ReducedDAE where ``alg = 0`` and every invariant
    holds (time and inputs random, parameters at their values), or None when Gauss--Newton
    finds none from ``starts`` random starts. ``remembered``: first from the consistent point
    the analysis of ``r.model`` kept (:func:`remember_consistent`; with ``t`` None), which
    satisfies the equations already where the reduction only rearranged them.

    >>> import casadi as ca, numpy as np
    >>> import daekit as dk
    >>> r = dk.reduce_index(dk.examples.l3())
    >>> t, x, z, u, p = reduced_consistent_point(r)
    >>> bool(abs(ca.Function("c", [r.t, r.x, r.z, r.u, r.p], [r.invariants])(t, x, z, u, p)[0]) < 1e-10)
    True
    """
    rng = np.random.default_rng(seed + 31)
    n = r.nx + r.nz
    f, jac = reduced_point_functions(r)
    pv = np.asarray(r.p_values, dtype=float)
    start = _remembered_start(r) if remembered and t is None else None
    if start is not None:
        tv, w0, uv = start
        wv, st = gauss_newton(lambda x: f(tv, uv, x, pv)[0], w0,
                              jac=lambda x: jac(tv, uv, x, pv))
        if st.consistent:
            return tv, wv[: r.nx], wv[r.nx:], uv, pv.copy()
    for k in range(starts):
        tv = float(rng.uniform(0.1, 1.0)) if t is None else float(t)
        uv = rng.uniform(0.2, 1.2, r.nu)
        # the later starts: normal draws, then small values, 1e-3 and 1e-6 (units where the
        # solutions are of order 1e-3 .. 1e-6 of the model's: a start at 1 diverged to 1e10)
        w0 = (rng.uniform(0.2, 1.2, n) if k == 0 else rng.standard_normal(n) if k < 3
              else rng.uniform(-1e-3, 1e-3, n) * 1e-3 ** (k - 3))
        if k == 1:  # in the Jacobian's units (see in_jacobian_units)
            w0 = in_jacobian_units(lambda x, tv=tv, uv=uv: jac(tv, uv, x, pv), np.abs(w0))
        wv, st = gauss_newton(lambda x, tv=tv, uv=uv: f(tv, uv, x, pv)[0],
                              w0, jac=lambda x, tv=tv, uv=uv: jac(tv, uv, x, pv))
        if st.consistent:
            return tv, wv[: r.nx], wv[r.nx:], uv, np.asarray(r.p_values, dtype=float)
    return None
