"""A CasADi SX Function evaluated at many points at once with NumPy, one array operation per
instruction.

``F.map(n)`` evaluates a Function point after point, and on a small function (the pendulum's
invariants and their Jacobian: about 100 instructions) the per-point cost of the call dominates:
about 0.35 microseconds per point and call, as much as the integration itself when thousands
of output points are projected or polished. :class:`RowEvaluator` translates the SX algorithm
once into a Python function whose every line is one NumPy operation on a vector holding all
points, so the cost per point is that of the arithmetic (a few nanoseconds per instruction).
It pays off from about a hundred points; :func:`evaluate_rows` picks it there and the mapped
CasADi Function below that (or when the function uses an operation not translated).

Example
-------
>>> import casadi as ca, numpy as np
>>> x = ca.SX.sym("x", 2)
>>> F = ca.Function("f", [x], [ca.vertcat(ca.sin(x[0]) * x[1], 3.0)])
>>> X = np.array([[0.5, 2.0], [1.0, -1.0]])
>>> out = RowEvaluator(F)([X])[0]
>>> np.allclose(out, [[2 * np.sin(0.5), 3.0], [-np.sin(1.0), 3.0]])
True
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..numerics import fast_call  # (re-exported: the projection imports it from here)

__all__ = ["RowEvaluator", "evaluate_rows", "evaluate_columns", "fast_call", "rows_equal",
           "spd_inverse"]


_UNARY = {
    "OP_ASSIGN": "{0}", "OP_NEG": "-{0}", "OP_EXP": "np.exp({0})", "OP_LOG": "np.log({0})",
    "OP_SQRT": "np.sqrt({0})", "OP_SQ": "{0}*{0}", "OP_TWICE": "2.0*{0}",
    "OP_SIN": "np.sin({0})", "OP_COS": "np.cos({0})", "OP_TAN": "np.tan({0})",
    "OP_ASIN": "np.arcsin({0})", "OP_ACOS": "np.arccos({0})", "OP_ATAN": "np.arctan({0})",
    "OP_NOT": "np.logical_not({0}).astype(float)", "OP_FLOOR": "np.floor({0})",
    "OP_CEIL": "np.ceil({0})", "OP_FABS": "np.abs({0})", "OP_SIGN": "np.sign({0})",
    "OP_INV": "1.0/{0}", "OP_SINH": "np.sinh({0})", "OP_COSH": "np.cosh({0})",
    "OP_TANH": "np.tanh({0})", "OP_ASINH": "np.arcsinh({0})", "OP_ACOSH": "np.arccosh({0})",
    "OP_ATANH": "np.arctanh({0})", "OP_LOG1P": "np.log1p({0})", "OP_EXPM1": "np.expm1({0})",
}
_BINARY = {
    "OP_ADD": "{0}+{1}", "OP_SUB": "{0}-{1}", "OP_MUL": "{0}*{1}", "OP_DIV": "{0}/{1}",
    "OP_POW": "np.power({0},{1})", "OP_CONSTPOW": "np.power({0},{1})",
    "OP_LT": "np.less({0},{1}).astype(float)", "OP_LE": "np.less_equal({0},{1}).astype(float)",
    "OP_EQ": "np.equal({0},{1}).astype(float)", "OP_NE": "np.not_equal({0},{1}).astype(float)",
    "OP_AND": "np.logical_and({0},{1}).astype(float)",
    "OP_OR": "np.logical_or({0},{1}).astype(float)", "OP_FMOD": "np.fmod({0},{1})",
    "OP_COPYSIGN": "np.copysign({0},{1})", "OP_FMIN": "np.minimum({0},{1})",
    "OP_FMAX": "np.maximum({0},{1})", "OP_ATAN2": "np.arctan2({0},{1})",
    "OP_HYPOT": "np.hypot({0},{1})", "OP_IF_ELSE_ZERO": "np.where({0}!=0,{1},0.0)",
}
_OPS = {getattr(ca, k): k for k in dir(ca) if k.startswith("OP_")}


class RowEvaluator:
    """``F`` (an SX Function) at many points: inputs ``(N, nnz_in)`` arrays, outputs
    ``(N, nnz_out)`` (nonzeros in CasADi's column-major order, as ``fast_call`` on ``F.map``).
    ``ok`` is False when ``F`` uses an operation this translation lacks (then do not call)."""

    def __init__(self, F: ca.Function) -> None:
        self.F = F
        self._nnz_out = [F.nnz_out(j) for j in range(F.n_out())]
        self.ok = F.is_a("SXFunction")
        self._fn = None
        if not self.ok or F.n_instructions() > 50000:  # (a very long function: map it)
            self.ok = False
            return
        lines = []
        for k in range(F.n_instructions()):
            op = _OPS.get(F.instruction_id(k), "?")
            i, o = F.instruction_input(k), F.instruction_output(k)
            if op == "OP_INPUT":
                lines.append(f"w{o[0]}=a{i[0]}[{i[1]}]")
            elif op == "OP_OUTPUT":
                lines.append(f"r{o[0]}[{o[1]}]=w{i[0]}")
            elif op == "OP_CONST":
                lines.append(f"w{o[0]}={float(F.instruction_constant(k))!r}")
            elif op in _UNARY:
                lines.append(f"w{o[0]}=" + _UNARY[op].format(f"w{i[0]}"))
            elif op in _BINARY:
                lines.append(f"w{o[0]}=" + _BINARY[op].format(f"w{i[0]}", f"w{i[1]}"))
            else:
                self.ok = False
                return
        args = ",".join([f"a{j}" for j in range(F.n_in())] + [f"r{j}" for j in range(F.n_out())])
        body = "\n ".join(lines) or "pass"
        src = f"def _rows({args}):\n {body}\n"
        ns = {"np": np, "inf": np.inf, "nan": np.nan}
        with np.errstate(all="ignore"):
            exec(compile(src, f"<rows {F.name()}>", "exec"), ns)  # noqa: S102 - our own code
        self._fn = ns["_rows"]

    def __call__(self, inputs) -> list[np.ndarray]:
        F = self.F
        n = None
        args = []
        for j in range(F.n_in()):
            a = inputs[j] if j < len(inputs) else None
            if a is None:
                args.append(None)
                continue
            a = np.asarray(a, dtype=float)
            n = a.shape[0] if n is None else n
            # (nnz, n) with contiguous rows: the generated lines read whole rows
            args.append(a.reshape(1, n) if a.ndim == 1 else np.ascontiguousarray(
                a.reshape(n, -1).T))
        n = 1 if n is None else n
        args = [np.zeros((F.nnz_in(j), n)) if a is None else a for j, a in enumerate(args)]
        outs = [np.zeros((k, n)) for k in self._nnz_out]
        with np.errstate(all="ignore"):
            self._fn(*args, *outs)
        return [o.T for o in outs]

    def columns(self, inputs, n: int) -> list[np.ndarray]:
        """Like calling it, with inputs and outputs transposed: input ``j`` a ``(nnz_in, n)``
        array, or ``(nnz_in, 1)`` for a value shared by all points (broadcast: the operations
        on shared values alone stay scalar-sized); outputs ``(nnz_out, n)``."""
        outs = [np.zeros((k, n)) for k in self._nnz_out]
        with np.errstate(all="ignore"):
            self._fn(*inputs, *outs)
        return outs


def evaluate_rows(F: ca.Function, inputs, cache: dict,
                  min_rows: int | None = None) -> list[np.ndarray]:
    """``F`` at the rows of ``inputs`` (a list of ``(N, nnz_in)`` arrays, one per input): with
    :class:`RowEvaluator` where it is cheaper than the mapped Function (from ~32 rows on, and on
    fewer for short functions; ``min_rows``: from that many rows on instead), when it can
    translate ``F``, else with the mapped Function. ``cache`` (a dict kept by the caller)
    holds both. Returns ``(N, nnz_out)`` arrays.

    >>> import casadi as ca, numpy as np
    >>> x = ca.SX.sym("x")
    >>> F = ca.Function("f", [x], [x ** 2])
    >>> [float(evaluate_rows(F, [np.arange(n, dtype=float)], {})[0][-1, 0]) for n in (3, 200)]
    [4.0, 39601.0]
    """
    n = int(np.asarray(inputs[0]).shape[0])
    # a mapped CasADi call costs about 40 us plus ~12 ns per instruction and point; the
    # translation ~0.35 us per instruction plus ~1 ns per point (measured, casadi 3.7): the
    # translation wins from ~32 rows on, and on fewer rows for short functions
    if min_rows is None:
        k = cache.get("n_instructions")
        if k is None:
            k = cache["n_instructions"] = F.n_instructions() if F.is_a("SXFunction") else 10**9
        # (translating costs ~15 us per instruction once: long functions only from 96 rows)
        rows = n >= 96 or (k <= 2000 and k * max(0.35 - 0.011 * n, 0.0) < 40.0)
    else:
        rows = n >= min_rows
    if rows:
        ev = cache.get("rows")
        if ev is None:
            ev = cache["rows"] = RowEvaluator(F)
        if ev.ok:
            return ev(inputs)
    m = n if n <= 64 else 1 << (n - 1).bit_length()
    maps = cache.setdefault("maps", {})
    if m not in maps:
        if len(maps) > 8:
            maps.clear()
        maps[m] = F.map(m)
    Fm = maps[m]
    args = {}
    for j, a in enumerate(inputs):
        a = np.asarray(a, dtype=float).reshape(n, -1)
        if m > n:
            a = np.concatenate([a, np.repeat(a[-1:], m - n, axis=0)])
        args[Fm.name_in(j)] = a
    out = fast_call(Fm, args, {Fm.name_out(j): (m, F.nnz_out(j)) for j in range(F.n_out())})
    return [out[Fm.name_out(j)][:n] for j in range(F.n_out())]


def evaluate_columns(F: ca.Function, inputs, n: int, cache: dict) -> list[np.ndarray]:
    """:func:`evaluate_rows` with inputs and outputs transposed: input ``j`` a ``(nnz_in, n)``
    array or ``(nnz_in, 1)`` (the same for all ``n`` points); returns ``(nnz_out, n)`` arrays.
    The translated function reads such arrays as they are (no transposed copies).

    >>> import casadi as ca, numpy as np
    >>> x, c = ca.SX.sym("x"), ca.SX.sym("c")
    >>> F = ca.Function("f", [x, c], [c * x ** 2])
    >>> evaluate_columns(F, [np.array([[1.0, 2.0, 3.0]]), np.array([[2.0]])], 3, {})[0].tolist()
    [[2.0, 8.0, 18.0]]
    """
    ev = cache.get("rows")
    if ev is None:
        ev = cache["rows"] = RowEvaluator(F)
    if ev.ok:
        return ev.columns(inputs, n)
    rows = [np.broadcast_to(np.asarray(a, float), (np.shape(a)[0], n)).T for a in inputs]
    return [o.T for o in evaluate_rows(F, rows, cache)]


def spd_inverse(M: np.ndarray) -> np.ndarray:
    """The inverses of many small symmetric positive definite matrices ``M (N, k, k)``
    (Gauss--Jordan without pivoting, vectorized over ``N``: ``k^2`` NumPy operations on
    ``N``-vectors, where ``np.linalg.inv`` calls LAPACK once per matrix). A singular matrix
    gives ``inf``/``nan`` in its rows, never an exception.

    >>> import numpy as np
    >>> M = np.array([[[2.0, 1.0], [1.0, 3.0]], [[4.0, 0.0], [0.0, 1.0]]])
    >>> bool(np.allclose(spd_inverse(M) @ M, np.eye(2)))
    True
    """
    M = np.asarray(M, dtype=float)
    N, k, _ = M.shape
    a = [[np.array(M[:, i, j]) for j in range(k)] for i in range(k)]
    e = [[np.ones(N) if i == j else np.zeros(N) for j in range(k)] for i in range(k)]
    with np.errstate(all="ignore"):
        for c in range(k):
            piv = 1.0 / a[c][c]
            for j in range(k):
                a[c][j] = a[c][j] * piv
                e[c][j] = e[c][j] * piv
            for i in range(k):
                if i == c:
                    continue
                f = a[i][c]
                for j in range(k):
                    a[i][j] = a[i][j] - f * a[c][j]
                    e[i][j] = e[i][j] - f * e[c][j]
    return np.stack([np.stack(row, axis=1) for row in e], axis=1)


def rows_equal(U: np.ndarray) -> bool:
    """Whether every row of the 2-D ``U`` equals its first (constant inputs over a grid).

    >>> rows_equal(np.zeros((3, 2))), rows_equal(np.arange(4.0).reshape(2, 2))
    (True, False)
    """
    return bool((U == U[:1]).all())
