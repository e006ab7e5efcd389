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
unknowns onto ``G = 0``. The values of a user's ``point=`` are held and the others solved
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

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from .errors import ModelError
from .numerics import SparseFunction, equilibrate, to_scipy
from .wording import count

__all__ = ["TestPoint", "PointStatus", "check_point", "make_consistent", "consistent_point",
           "gauss_newton", "reduced_consistent_point", "DRAWS"]

#: Distributions of the random values, tried in this order (until the Jacobians are finite).
DRAWS = (("uniform", 0.1, 0.3), ("uniform", 0.5, 1.5), ("normal", 0.0, 1.0),
         ("uniform", 1.5, 3.0), ("normal", 0.0, 3.0))
#: Below this many unknowns Gauss--Newton steps come from a dense SVD, above from sparse LU.
DENSE_UNKNOWNS = 300
#: Required residual of a consistent point, relative to each equation's scale.
POINT_TOL = 1e-10


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
    if not isinstance(point, dict):
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

    def evaluate(self, syms) -> np.ndarray:
        out = np.empty(len(syms))
        for k, s in enumerate(syms):
            h = s.element_hash()
            if h not in self.values:
                self.values[h] = float(self._random(1)[0])
            out[k] = self.values[h]
        return out

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

    def assign(self, syms, vals) -> None:
        for s, v in zip(syms, vals, strict=True):
            self.values[s.element_hash()] = float(v)

    def sparse(self, expr: ca.SX) -> sp.csr_matrix:
        """Numeric value of a (sparse) SX matrix at this point, as a SciPy sparse matrix."""
        th = self.model.t.element_hash()
        syms = [s for s in ca.symvar(expr) if s.element_hash() != th]
        f = ca.Function("at_point", [self.model.t, ca.vertcat(*syms)], [expr])
        val = ca.DM(f(self.t, self.evaluate(syms)))
        return to_scipy(val).tocsr()


@dataclass
class PointStatus:
    """How a test point was obtained: ``consistent`` (the equations hold to ``residual``,
    relative), ``iterations`` of Gauss--Newton, ``given`` (the user's point was already
    consistent), ``worst`` (the equation rows with the largest residual when not consistent)."""

    consistent: bool
    residual: float
    iterations: int = 0
    given: bool = False
    worst: list[int] | None = None


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
                    tol: float = POINT_TOL) -> PointStatus:
    """Move the unknowns of ``pt`` (not time, inputs or parameters) onto ``equations = 0``.

    Gauss--Newton with minimum-norm steps from the point's current values (:func:`gauss_newton`).
    On success the point's values are replaced by the solution; on failure they are left as
    they were. Returns the :class:`PointStatus` (also stored as ``pt.status``).

    >>> import casadi as ca, daekit as dk
    >>> m = dk.Model("m"); x = m.state("x"); z = m.algebraic("z")
    >>> _ = m.equation(z - 1e6 * x, name="e")
    >>> pt = TestPoint(m, None); make_consistent(pt, m.residual).consistent
    True
    """
    G = ca.vec(ca.SX(equations))
    model = pt.model
    syms = _movable(model, ca.symvar(G))
    if pt.given and any(s.element_hash() in pt.given for s in syms):
        # the user's values are held; where they admit no consistent completion the point is
        # used as the user gave it (and the status says it is not consistent)
        held = [s for s in syms if s.element_hash() not in pt.given]
        st = _solve(pt, G, held, max_iter, tol)
        st.given = True
        pt.status = st
        return st
    st = _solve(pt, G, syms, max_iter, tol)
    pt.status = st
    return st


def _solve(pt: TestPoint, G: ca.SX, syms: list, max_iter: int, tol: float) -> PointStatus:
    """Gauss--Newton on ``G = 0`` in the symbols ``syms`` (the others held at their values)."""
    model = pt.model
    moving = {s.element_hash() for s in syms}
    fixed = [s for s in ca.symvar(G)
             if s.element_hash() not in moving and s.element_hash() != model.t.element_hash()]
    W = ca.vertcat(*syms) if syms else ca.SX(0, 1)
    Fx = ca.vertcat(*fixed) if fixed else ca.SX(0, 1)
    f = ca.Function("consistency", [model.t, Fx, W], [G])
    fj = SparseFunction([model.t, Fx, W], ca.jacobian(G, W))
    fv = pt.evaluate(fixed)
    w0 = pt.evaluate(syms)

    def fun(w):
        return np.asarray(f(pt.t, fv, w), dtype=float).ravel()

    w, st = gauss_newton(fun, w0, tol=tol, max_iter=max_iter, jac=lambda w: fj(pt.t, fv, w))
    if st.consistent:
        pt.assign(syms, w)
    return st


def consistent_point(pt: TestPoint, equations: ca.SX, starts: int = 3) -> PointStatus:
    """:func:`make_consistent` from ``pt``; where that fails, from up to ``starts - 1`` other
    random starts (same time and inputs), whose solution is then copied into ``pt``. The
    returned status says whether a consistent point was found.

    >>> import casadi as ca, daekit as dk
    >>> m = dk.Model("m"); x = m.state("x")
    >>> _ = m.equation(x**2 - 4, name="e")
    >>> pt = TestPoint(m, None); consistent_point(pt, m.residual).consistent
    True
    """
    st = make_consistent(pt, equations)
    k = 1
    while not st.consistent and k < starts and not st.given:
        alt = pt.sibling(k)
        st2 = make_consistent(alt, equations)
        if st2.consistent:
            for h, v in alt.values.items():
                pt.values[h] = v
            pt.status = st = st2
        k += 1
    return st


def gauss_newton(fun, w0: np.ndarray, tol: float = POINT_TOL, max_iter: int = 60, jac=None
                 ) -> tuple[np.ndarray, PointStatus]:
    """Solve the (under- or over-determined) ``h(w) = 0`` by Gauss--Newton with minimum-norm
    steps, a trust radius and a backtracking line search, in the coordinates of the
    equilibrated first Jacobian (rows and columns scaled, :func:`daekit.numerics.equilibrate`),
    so that the units of equations and unknowns do not matter. ``fun(w) -> h`` and
    ``jac(w) -> J`` (sparse); without ``jac``, ``fun(w) -> (h, J)``. Converged when every
    scaled residual is below ``tol`` times ``1 + max |w|`` (scaled).

    >>> import numpy as np, scipy.sparse as sp
    >>> fun = lambda w: (np.array([w[0]**2 + w[1]**2 - 1]), sp.csr_matrix([[2*w[0], 2*w[1]]]))
    >>> w, st = gauss_newton(fun, np.array([0.3, 0.2]))
    >>> st.consistent, round(float(w @ w), 12)
    (True, 1.0)
    """
    if jac is None:
        both = fun
        fun = lambda w: both(w)[0]  # noqa: E731
        jac = lambda w: both(w)[1]  # noqa: E731
    w = np.array(w0, dtype=float)
    h = np.asarray(fun(w), dtype=float)
    if h.size == 0:
        return w, PointStatus(True, 0.0, 0)
    J = jac(w)
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(J.data))):
        return w, PointStatus(False, float("inf"), 0, worst=_worst(h, np.ones(h.size)))
    dr, dc = equilibrate(J)
    n = w.size

    def merit(hv):
        return np.abs(dr * hv)

    def level(wv):
        return tol * (1.0 + float(np.max(np.abs(wv / dc)))) if n else tol

    def finite(hv):
        return bool(np.all(np.isfinite(hv)))

    r = merit(h)
    radius = 2.0 * (1.0 + float(np.max(np.abs(w / dc)))) if n else 1.0
    for it in range(max_iter + 1):
        if r.max() <= level(w):
            # polish to rounding: full Newton steps while the residual drops tenfold (the
            # Jacobians at the point must not carry residue of terms that vanish there)
            for _ in range(4):
                if not (r.max() > 0 and n):
                    break
                J = jac(w)
                d = _min_norm_step(sp.diags(dr) @ J @ sp.diags(dc), dr * h)
                if d is None or not np.all(np.isfinite(d)):
                    break
                hn = fun(w + dc * d)
                if not (finite(hn) and merit(hn).max() < 0.1 * r.max()):
                    break
                w, h, r = w + dc * d, hn, merit(hn)
            return w, PointStatus(True, float(r.max()), it)
        if it == max_iter or n == 0:
            break
        if it:
            J = jac(w)
            if not np.all(np.isfinite(J.data)):
                break
        d = _min_norm_step(sp.diags(dr) @ J @ sp.diags(dc), dr * h)
        if d is None or not np.all(np.isfinite(d)):
            break
        size = float(np.max(np.abs(d))) if d.size else 0.0
        alpha = min(1.0, radius / size) if size > 0 else 1.0
        norm0 = np.linalg.norm(r)
        for _ in range(30):
            wn = w + alpha * dc * d
            hn = fun(wn)
            if finite(hn):
                rn = merit(hn)
                if np.linalg.norm(rn) <= (1 - 1e-4 * alpha) * norm0 or rn.max() <= level(wn):
                    break
            alpha *= 0.5
        else:
            break
        radius = 4.0 * alpha * size if alpha * size * 1.5 >= radius else max(alpha * size, 1e-8)
        radius = max(radius, 1e-3 * (1.0 + float(np.max(np.abs(wn / dc)))))
        w, h, r = wn, hn, rn
    return w, PointStatus(False, float(r.max()), it, worst=_worst(h, dr))


def _worst(h, dr) -> list[int]:
    r = np.abs(dr * h)
    r = np.where(np.isfinite(r), r, np.inf)
    top = r.max() if r.size else 0.0
    return np.nonzero(r >= 1e-3 * top)[0].tolist() if top > 0 else []


def _min_norm_step(J: sp.csr_matrix, h: np.ndarray) -> np.ndarray | None:
    """``d`` with ``J d ~ -h`` of least norm: ``d = -J^T (J J^T + mu I)^{-1} h`` with a tiny
    ``mu`` (redundant rows do no harm), dense SVD for small problems."""
    m, n = J.shape
    if n <= DENSE_UNKNOWNS and m <= 4 * DENSE_UNKNOWNS:
        A = J.toarray()
        try:
            return -np.linalg.lstsq(A, h, rcond=1e-12)[0]
        except np.linalg.LinAlgError:
            return None
    # the augmented (quasi-definite) system [[I, J^T], [J, -mu I]] [d; y] = [0; -h]: its
    # sparse LU stays linear in the size for chains and meshes (J J^T may fill in)
    mu = 1e-12
    K = sp.bmat([[sp.identity(n, format="csc"), J.T], [J, -mu * sp.identity(m)]], format="csc")
    try:
        lu = sp.linalg.splu(K, permc_spec="COLAMD")
    except RuntimeError:
        return None
    rhs = np.r_[np.zeros(n), -h]
    sol = lu.solve(rhs)
    sol = sol + lu.solve(rhs - K @ sol)  # one step of iterative refinement
    return sol[:n]


def reduced_consistent_point(r, seed: int = 0, t: float | None = None, starts: int = 3):
    """A point ``(t, x, z, u, p)`` of a ReducedDAE where ``alg = 0`` and every invariant
    holds (time and inputs random, parameters at their values), or None when Gauss--Newton
    finds none from ``starts`` random starts.

    >>> import casadi as ca, numpy as np
    >>> import daekit as dk
    >>> r = dk.reduce_index(dk.examples.l3())
    >>> t, x, z, u, p = reduced_consistent_point(r)
    >>> bool(abs(ca.Function("c", [r.t, r.x, r.z, r.u, r.p], [r.invariants])(t, x, z, u, p)[0]) < 1e-10)
    True
    """
    rng = np.random.default_rng(seed + 31)
    n = r.nx + r.nz
    w = ca.SX.sym("w", n)
    t_s = ca.SX.sym("t")
    u_s = ca.SX.sym("u", r.nu)
    G = ca.vertcat(ca.vec(r.alg), ca.vec(r.invariants) if r.invariants.numel() else ca.SX(0, 1))
    G = ca.substitute([G], [r.t, ca.vertcat(r.x, r.z), r.u, r.p],
                      [t_s, w, u_s, ca.DM(r.p_values)])[0]
    f = ca.Function("g", [t_s, u_s, w], [G])
    fj = SparseFunction([t_s, u_s, w], ca.jacobian(G, w))
    for k in range(starts):
        tv = float(rng.uniform(0.1, 1.0)) if t is None else float(t)
        uv = rng.uniform(0.2, 1.2, r.nu)
        w0 = rng.uniform(0.2, 1.2, n) if k == 0 else rng.standard_normal(n)
        wv, st = gauss_newton(lambda x, tv=tv, uv=uv: np.asarray(f(tv, uv, x), dtype=float).ravel(),
                              w0, jac=lambda x, tv=tv, uv=uv: fj(tv, uv, x))
        if st.consistent:
            return tv, wv[: r.nx], wv[r.nx:], uv, np.asarray(r.p_values, dtype=float)
    return None
