"""What kind of DAE is this? Structural index, offsets, DOF, the true index, an explanation.

:func:`analyze` runs Pryce's Sigma-method on the model's sparse Sigma matrix, checks the
system Jacobian numerically (where it is singular, structural analysis has failed), and then
computes the differential index from the derivative array. :func:`is_index1` is the lecture's
"easy" test.

Tolerances: a matrix is judged singular from the SVD of its row- and column-equilibrated
form (rows and columns scaled by powers of two to unit max norm): singular values below
``RANK_RTOL * max(shape) * sigma_max`` count as zero, ``RANK_RTOL = 1e3 * machine epsilon``.
Big blocks (more than ``DENSE_LIMIT`` rows) are factorized by sparse LU instead, and a pivot
below the same relative tolerance counts as zero.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import ModelError
from .model import Model
from .structure import block_triangular, dulmage_mendelsohn, sigma_method
from .structure.sigma import NoTransversal

__all__ = ["Analysis", "EasyTest", "DerivativeArrayResult", "analyze", "differential_index",
           "is_index1"]

RANK_RTOL = 1e3 * np.finfo(float).eps
DENSE_LIMIT = 400  # largest BLT block of the system Jacobian checked by a dense SVD
EASY_DENSE_LIMIT = 120  # largest leading Jacobian checked by a dense SVD in the easy test


# ----------------------------------------------------------------------------- numerics
def _equilibrate(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    for axis in (1, 0):
        mx = np.max(np.abs(a), axis=axis, keepdims=True) if a.size else a
        scale = np.where(mx > 0, 2.0 ** -np.round(np.log2(np.where(mx > 0, mx, 1.0))), 1.0)
        a = a * scale
    return a


def numeric_rank(a: np.ndarray) -> tuple[int, float]:
    """Rank and reciprocal condition (sigma_min / sigma_max) of a dense matrix after
    equilibration; see the module docstring for the tolerance."""
    a = np.atleast_2d(np.asarray(a, dtype=float))
    if a.size == 0:
        return 0, 1.0
    s = np.linalg.svd(_equilibrate(a), compute_uv=False)
    if s[0] == 0:
        return 0, 0.0
    tol = RANK_RTOL * max(a.shape) * s[0]
    return int(np.sum(s > tol)), float(s[-1] / s[0]) if len(s) == min(a.shape) else 0.0


def _sparse_rcond(a: sp.csc_matrix) -> float:
    """Estimate of sigma_min / sigma_max of a big square sparse matrix via sparse LU pivots."""
    a = sp.csc_matrix(a)
    r = np.asarray(np.abs(a).max(axis=1).todense()).ravel()
    r[r == 0] = 1.0
    a = sp.diags(1.0 / r) @ a
    c = np.asarray(np.abs(a).max(axis=0).todense()).ravel()
    c[c == 0] = 1.0
    a = sp.csc_matrix(a @ sp.diags(1.0 / c))
    try:
        lu = spla.splu(a, permc_spec="COLAMD")
    except RuntimeError:
        return 0.0
    d = np.abs(lu.U.diagonal())
    return float(d.min() / d.max()) if d.size and d.max() > 0 else 0.0


# ----------------------------------------------------------------------------- points
def _random_value(rng: np.random.Generator, size: int) -> np.ndarray:
    # Small positive values: generic, and safe for sqrt, log and exp of differences.
    return rng.uniform(0.1, 0.3, size)


class _Point:
    """Numeric values for every symbol of a model (unknowns and derivatives, controls, t,
    parameters): the user's values where given, defaults for parameters, random elsewhere."""

    def __init__(self, model: Model, point: dict | None, seed: int = 0) -> None:
        self.model = model
        self.rng = np.random.default_rng(seed)
        self.values: dict[int, float] = {}  # element hash -> value
        self.t = float(point["t"]) if point and "t" in point else float(_random_value(self.rng, 1)[0])
        for var in model.parameters:
            for i in range(var.size):
                self.values[var.sym[i].element_hash()] = float(var.default[i])
        for name, val in (point or {}).items():
            if name == "t":
                continue
            elems = model.resolve(name)
            arr = np.broadcast_to(np.asarray(val, dtype=float).ravel(), (len(elems),))
            for (var, i, order), v in zip(elems, arr):
                self.values[var.der(order)[i].element_hash()] = float(v)

    def evaluate(self, syms: list[ca.SX]) -> np.ndarray:
        out = np.empty(len(syms))
        for k, s in enumerate(syms):
            h = s.element_hash()
            if h not in self.values:
                self.values[h] = float(_random_value(self.rng, 1)[0])
            out[k] = self.values[h]
        return out

    def jacobian(self, expr: ca.SX, wrt: ca.SX) -> np.ndarray:
        """Numeric (dense) Jacobian of ``expr`` w.r.t. ``wrt`` at this point."""
        th = self.model.t.element_hash()
        syms = [s for s in ca.symvar(ca.vertcat(expr, wrt)) if s.element_hash() != th]
        f = ca.Function("dense_jacobian", [self.model.t, ca.vertcat(*syms)], [ca.jacobian(expr, wrt)])
        return np.asarray(f(self.t, self.evaluate(syms)), dtype=float)


# ----------------------------------------------------------------------------- easy test
@dataclass
class EasyTest:
    """The lecture's "easy" (index-1) test: is ``[dF/dx' dF/dz]`` nonsingular?

    For higher-order models the columns are the highest derivatives of each unknown.
    ``bool(test)`` is the verdict; ``deficient_equations`` names the equations that combine
    to zero in the leading Jacobian (from its left null space).
    """

    passed: bool
    rank: int
    size: int
    condition: float
    deficient_equations: list[str] = field(default_factory=list)

    def __bool__(self) -> bool:
        return self.passed


def is_index1(model: Model, point: dict | None = None, seed: int = 0) -> EasyTest:
    """The lecture's easy test: rank and condition number of ``[dF/dx' dF/dz]``.

    The Jacobian is evaluated sparsely. Up to ``EASY_DENSE_LIMIT`` equations its rank comes
    from an SVD; beyond, from the structural rank (Dulmage--Mendelsohn) and the conditioning of
    each diagonal block of its block triangular form (dense SVD up to ``DENSE_LIMIT``, sparse LU
    beyond).

    Example
    -------
    >>> import daekit as dk
    >>> bool(dk.is_index1(dk.examples.l1()))
    True
    >>> dk.is_index1(dk.examples.l3()).rank
    6
    """
    Model.require(model, "is_index1")
    model.validate()
    inc = model.incidence()
    n = inc.n_unknowns
    highest = np.zeros(n, dtype=np.int64)
    np.maximum.at(highest, inc.cols, inc.vals)
    keep = inc.vals == highest[inc.cols]
    pt = _Point(model, point, seed)
    jac = _sparse_jacobian(model, inc.rows[keep], inc.cols[keep], inc.vals[keep], pt)
    eq_names = model.equation_names
    if n <= EASY_DENSE_LIMIT:
        u, sv, _ = np.linalg.svd(_equilibrate(jac.toarray()))
        tol = RANK_RTOL * n * sv[0] if sv.size and sv[0] > 0 else np.inf
        rank = int(np.sum(sv > tol))
        rcond = float(sv[-1] / sv[0]) if rank == n else 0.0
        names: list[str] = []
        if rank < n:
            weight = np.linalg.norm(u[:, rank:], axis=1)
            names = [eq_names[i] for i in np.nonzero(weight > 1e-8)[0]]
    else:
        coo = jac.tocoo()
        dm = dulmage_mendelsohn(n, n, coo.row, coo.col)
        if dm.is_square_nonsingular:
            rcond = _blockwise_rcond(jac, dm.row_match)
            rank, names = (n, []) if rcond > 0 else (n - 1, [])
        else:
            rank, rcond = dm.matching_size, 0.0
            names = [eq_names[i] for i in dm.over_rows]
    cond = 1.0 / rcond if rcond > 0 else float("inf")
    return EasyTest(rank == n, rank, n, cond, names)


# ----------------------------------------------------------------------------- derivative array
@dataclass
class DerivativeArrayResult:
    """Result of :func:`differential_index`: the index, the true number of degrees of freedom,
    and the ranks seen at each level of the derivative array."""

    index: int
    dof: int
    ranks: list[tuple[int, int, int]]  # (level, rank of J, rank of J without the targets)
    constraints_on_states: int

    def __int__(self) -> int:
        return self.index


def _time_derivative(expr: ca.SX, syms: list[ca.SX], next_syms: list[ca.SX], t: ca.SX) -> ca.SX:
    """Total time derivative by a directional derivative along (1, x', x'', ...)."""
    v = ca.vertcat(t, *syms)
    w = ca.vertcat(1, *next_syms)
    return ca.jtimes(expr, v, w)


def differential_index(
    model: Model, point: dict | None = None, max_index: int | None = None, seed: int = 0
) -> DerivativeArrayResult:
    """The differential index from the derivative array (Campbell & Gear, Numer. Math. 72, 1995).

    In first-order form every unknown ``x_j`` whose highest derivative in the model is
    ``m_j`` contributes the states ``x_j, ..., x_j^(s_j - 1)`` with ``s_j = max(m_j, 1)``.
    The index is the least ``k`` for which ``[F; F'; ...; F^(k)]`` determines every
    ``x_j^(s_j)`` uniquely, i.e. ``rank J_k = rank J_k' + n`` where ``J_k`` is the Jacobian of
    the array w.r.t. all derivatives of order ``>= s_j`` and ``J_k'`` omits the targets
    ``x_j^(s_j)``. Ranks are numeric (see the module docstring for the tolerance), at
    ``point`` or at a random point. The DOF is the number of states minus the rank of the
    array's Jacobian w.r.t. the states beyond that w.r.t. the derivatives (the independent
    constraints on the states at level ``k``).

    Example
    -------
    >>> import daekit as dk
    >>> differential_index(dk.examples.gear_petzold()).index
    2
    """
    Model.require(model, "differential_index")
    model.validate()
    inc = model.incidence()
    n = inc.n_unknowns
    m = np.zeros(n, dtype=np.int64)
    np.maximum.at(m, inc.cols, inc.vals)
    s_ord = np.maximum(m, 1)
    if max_index is None:
        max_index = 2 * n + 2
    pt = _Point(model, point, seed)
    t = model.t
    controls = model.controls
    levels = [model.residual]
    ranks: list[tuple[int, int, int]] = []
    for k in range(max_index + 1):
        if k > 0:
            # symbols present at level k-1: unknowns up to m_j + k - 1, controls up to k - 1
            syms, nxt = [], []
            for j in range(n):
                for r in range(int(m[j]) + k):
                    syms.append(model.symbol(j, r))
                    nxt.append(model.symbol(j, r + 1))
            for var in controls:
                top = max(var.ders) if var.ders else 0
                for r in range(top + 1):
                    syms.append(var.der(r))
                    nxt.append(var.der(r + 1))
            levels.append(_time_derivative(levels[-1], syms, nxt, t))
        array = ca.vertcat(*levels)
        unknown_cols, target = [], []
        for j in range(n):
            for r in range(int(s_ord[j]), int(m[j]) + k + 1):
                unknown_cols.append(model.symbol(j, r))
                target.append(r == s_ord[j])
        target = np.array(target)
        jac = pt.jacobian(array, ca.vertcat(*unknown_cols))
        r_all, _ = numeric_rank(jac)
        r_rest, _ = numeric_rank(jac[:, ~target])
        ranks.append((k, r_all, r_rest))
        if r_all - r_rest == n:
            state_cols = [model.symbol(j, r) for j in range(n) for r in range(int(s_ord[j]))]
            jac_s = pt.jacobian(array, ca.vertcat(*state_cols))
            r_full, _ = numeric_rank(np.hstack([jac, jac_s]))
            constraints = r_full - r_all
            return DerivativeArrayResult(k, len(state_cols) - constraints, ranks, constraints)
    raise ModelError(
        f"model {model.name!r}: the derivative array up to level {max_index} does not determine "
        "all derivatives; the model may be singular (not uniquely solvable) at the test point"
    )


# ----------------------------------------------------------------------------- analyze
@dataclass
class Analysis:
    """Result of :func:`analyze`. See :meth:`explain` for a plain-language account.

    Attributes
    ----------
    structural_index : int
        Pryce's structural index (an ODE has 0).
    index : int
        The differential index: the structural one where structural analysis succeeds, else
        from the derivative array.
    dof : int
        Dynamic degrees of freedom (initial values that can be chosen freely).
    structurally_ok : bool
        False where the system Jacobian is singular at the test point: structural analysis
        has failed, and its index and DOF are not to be trusted.
    equation_offsets, variable_offsets : dict
        Pryce's canonical offsets ``c_i`` (times each equation element is differentiated)
        and ``d_j`` (highest derivative of each unknown needed), by element name.
    input_derivatives : dict
        Input (control) elements whose time derivatives the reduction will need, with the
        highest order needed, e.g. ``{"u": 2}`` for lecture L2.
    definitions : list of str
        Differentiated equations that define a derivative explicitly (``p' = v``): the reduced
        form substitutes them, so they are not consistency conditions to watch.
    sigma : list of (equation, unknown, order)
        The sparse Sigma matrix by names (highest derivative order of each unknown in each
        equation); :meth:`plot_structure` draws it.
    """

    model_name: str
    structural_index: int
    index: int
    dof: int
    structural_dof: int
    structurally_ok: bool
    equation_offsets: dict[str, int]
    variable_offsets: dict[str, int]
    transversal: dict[str, str]
    highest_order: dict[str, int]
    jacobian_rcond: float
    blocks: list[tuple[list[str], list[str]]]
    easy: EasyTest
    numeric: DerivativeArrayResult | None
    n_inputs: int = 0
    input_derivatives: dict[str, int] = field(default_factory=dict)
    definitions: list[str] = field(default_factory=list)
    sigma: list[tuple[str, str, int]] = field(default_factory=list)

    def explain(self) -> str:
        """A plain-language account: the index and why, the DOF, the easy test."""
        return _explain(self)

    def plot_structure(self, ax=None):
        """The Sigma matrix as a figure: derivative orders, the highest-value transversal,
        and the offsets ``c`` (right) and ``d`` (top). See :func:`daekit.plot.plot_structure`."""
        from .plot import plot_structure

        return plot_structure(self, ax=ax)

    def to_dict(self) -> dict:
        """The machine-readable summary printed by ``daekit analyze --json``."""
        return {
            "model": self.model_name,
            "structural_index": self.structural_index,
            "index": self.index,
            "dof": self.dof,
            "structurally_ok": self.structurally_ok,
            "equation_offsets": self.equation_offsets,
            "variable_offsets": self.variable_offsets,
            "easy_test": bool(self.easy),
        }


def _sparse_jacobian(model: Model, rows, cols, orders, pt: _Point) -> sp.csr_matrix:
    """Numeric sparse matrix of the entries ``dF_rows[k] / d x_cols[k]^(orders[k])``."""
    n = model.n_unknowns
    data = np.zeros(len(rows))
    F = model.residual
    th = model.t.element_hash()
    for order in np.unique(orders):
        sel = np.nonzero(orders == order)[0]
        cols_k = np.unique(cols[sel])
        X = model.symbols(cols_k, int(order))
        J = ca.jacobian(F, X)
        syms = [s for s in ca.symvar(J) if s.element_hash() != th]
        f = ca.Function("sparse_jacobian", [model.t, ca.vertcat(*syms)], [J])
        val = ca.DM(f(pt.t, pt.evaluate(syms)))
        r, cc = val.sparsity().get_triplet()
        pos = {(a, int(cols_k[b])): k for k, (a, b) in enumerate(zip(r, cc))}
        nz = np.asarray(val.nonzeros())
        idx = np.array([pos.get((int(rows[s]), int(cols[s])), -1) for s in sel], dtype=np.int64)
        data[sel] = np.where(idx >= 0, nz[np.maximum(idx, 0)] if len(nz) else 0.0, 0.0)
    return sp.csr_matrix((data, (rows, cols)), shape=(model.n_equations, n))


def _blockwise_rcond(jac: sp.csr_matrix, row_match) -> float:
    """Smallest reciprocal condition over the diagonal blocks of the BLT form (0 = singular)."""
    n = jac.shape[0]
    coo = jac.tocoo()
    rcond = 1.0
    for brows, bcols in block_triangular(n, coo.row, coo.col, row_match):
        sub = jac[brows][:, bcols]
        if len(brows) <= DENSE_LIMIT:
            rank, rc = numeric_rank(sub.toarray())
            rc = rc if rank == len(brows) else 0.0
        else:
            rc = _sparse_rcond(sub)
            rc = rc if rc > RANK_RTOL * len(brows) else 0.0
        rcond = min(rcond, rc)
    return rcond


def analyze(model: Model, point: dict | None = None, seed: int = 0) -> Analysis:
    """Analyze a DAE: structural index and offsets (Pryce's Sigma-method), whether structural
    analysis is trustworthy here, the differential index, the DOF, and the easy test.

    Parameters
    ----------
    model : Model
    point : dict, optional
        Values of variables and derivatives by name (``"p"``, ``"der(p)"``, ``"t"``) at which
        Jacobians are evaluated; missing values are drawn at random (seeded by ``seed``).

    Example
    -------
    >>> import daekit as dk
    >>> a = dk.analyze(dk.examples.l3())
    >>> a.index, a.dof, a.equation_offsets["rod"]
    (3, 4, 2)
    """
    Model.require(model, "analyze")
    model.validate()
    inc = model.incidence()
    n = inc.n_unknowns
    try:
        sig = sigma_method(n, inc.rows, inc.cols, inc.vals)
    except NoTransversal:  # validate() guarantees a matching exists; keep a clear message
        raise ModelError(f"model {model.name!r} has no transversal (structurally singular)") from None
    c, d = sig.c, sig.d
    pt = _Point(model, point, seed)
    keep = inc.vals == d[inc.cols] - c[inc.rows]
    jac = _sparse_jacobian(model, inc.rows[keep], inc.cols[keep], inc.vals[keep], pt)
    eq_names, var_names = model.equation_names, model.unknown_names
    coo = jac.tocoo()
    blocks_idx = block_triangular(n, coo.row, coo.col, sig.transversal)
    rcond = _blockwise_rcond(jac, sig.transversal)
    ok = rcond > 0.0
    numeric = None
    index, dof = sig.index, sig.dof
    if not ok:
        numeric = differential_index(model, point, seed=seed)
        index, dof = numeric.index, numeric.dof
    highest = np.zeros(n, dtype=np.int64)
    np.maximum.at(highest, inc.cols, inc.vals)
    return Analysis(
        sigma=[(eq_names[i], var_names[j], int(k))
               for i, j, k in zip(inc.rows.tolist(), inc.cols.tolist(), inc.vals.tolist())],
        input_derivatives=_input_derivatives(model, c),
        definitions=[eq_names[i] for i in _definitions(model, inc, sig)],
        model_name=model.name,
        structural_index=sig.index,
        index=index,
        dof=dof,
        structural_dof=sig.dof,
        structurally_ok=ok,
        equation_offsets={eq_names[i]: int(c[i]) for i in range(n)},
        variable_offsets={var_names[j]: int(d[j]) for j in range(n)},
        transversal={eq_names[i]: var_names[int(sig.transversal[i])] for i in range(n)},
        highest_order={var_names[j]: int(highest[j]) for j in range(n)},
        jacobian_rcond=rcond,
        blocks=[([eq_names[i] for i in br], [var_names[j] for j in bc]) for br, bc in blocks_idx],
        easy=is_index1(model, point, seed),
        numeric=numeric,
        n_inputs=sum(v.size for v in model.controls),
    )


def _definitions(model: Model, inc, sig) -> list[int]:
    """Equations with c_i >= 1 that are affine with a constant coefficient in a derivative
    x_j^(k) with k = sigma_ij = d_j - c_i >= 1 (each j used once): explicit definitions such
    as ``p' = v``, which the reduction eliminates."""
    c, d = sig.c, sig.d
    k = d[inc.cols] - c[inc.rows]
    cand = np.nonzero((c[inc.rows] >= 1) & (k >= 1) & (inc.vals == k))[0]
    if cand.size == 0:
        return []
    rows_u = np.unique(inc.rows[cand])
    pairs = sorted({(int(inc.cols[e]), int(k[e])) for e in cand})
    col_of = {p: n for n, p in enumerate(pairs)}
    row_of = {int(i): n for n, i in enumerate(rows_u)}
    J = ca.jacobian(model.residual[[int(i) for i in rows_u]],
                    model.symbols_at([p[0] for p in pairs], [p[1] for p in pairs]))
    used: set[int] = set()
    out = []
    for e in cand[np.argsort(inc.rows[cand], kind="stable")]:
        i, j = int(inc.rows[e]), int(inc.cols[e])
        if (out and out[-1] == i) or j in used:
            continue
        entry = J[row_of[i], col_of[j, int(k[e])]]
        if entry.is_constant() and float(ca.evalf(entry)) != 0.0:
            out.append(i)
            used.add(j)
    return out


def _input_derivatives(model: Model, c: np.ndarray) -> dict[str, int]:
    """Highest derivative of each control element in the equations differentiated c_i times."""
    out: dict[str, int] = {}
    F = model.residual
    for var in model.controls:
        for order in range(0, (max(var.ders) if var.ders else 0) + 1):
            rows, cols = ca.jacobian_sparsity(F, var.der(order)).get_triplet()
            for i, k in zip(rows, cols):
                need = order + int(c[i])
                name = var.element(int(k))
                if need > 0 and need > out.get(name, 0):
                    out[name] = need
    return out


# ----------------------------------------------------------------------------- explain
def _group(names_values: dict[str, int]) -> list[tuple[str, int]]:
    """Group element names 'e[0]', 'e[1]' with equal values into 'e' (or 'e[0..2]')."""
    groups: dict[str, list[tuple[str, int]]] = {}
    for name, v in names_values.items():
        base = name.split("[")[0] if name.endswith("]") else name
        groups.setdefault(base, []).append((name, v))
    out = []
    for base, items in groups.items():
        vals = {v for _, v in items}
        if len(vals) == 1:
            out.append((base, items[0][1]))
        else:
            out.extend(items)
    return out


def _times(k: int) -> str:
    return {0: "not differentiated", 1: "differentiated once", 2: "differentiated twice"}.get(
        k, f"differentiated {k} times"
    )


def _der(name: str, k: int) -> str:
    if k == 0:
        return name
    return f"der({name})" if k == 1 else f"der({name},{k})"


def _explain(a: Analysis) -> str:
    n = len(a.equation_offsets)
    n_alg = sum(1 for v in a.highest_order.values() if v == 0)
    lines = [
        f"Model {a.model_name!r}: {n} equations in {n} unknowns "
        f"({n - n_alg} appear differentiated, {n_alg} only algebraically)"
        + (f", {a.n_inputs} input(s)." if a.n_inputs else "."),
        "",
    ]
    if a.structurally_ok:
        lines.append(
            f"Differential index {a.index}, from structural analysis (Pryce's Sigma-method); the "
            f"system Jacobian is nonsingular at the test point (reciprocal condition "
            f"{a.jacobian_rcond:.1e}), so the structural result is the true one."
        )
    else:
        lines.append(
            f"Differential index {a.index}, computed NUMERICALLY from the derivative array, "
            f"because structural analysis FAILS here: the system Jacobian is singular at the test "
            f"point although the structure admits a matching. Structural analysis claims index "
            f"{a.structural_index} and {a.structural_dof} degrees of freedom; both are wrong. "
            "(Typical causes: cancellations such as M*(x1' - x2') appearing in two equations, a "
            "singular mass matrix, or equations whose sum loses a derivative.)"
        )
        if a.numeric is not None:
            lev = ", ".join(f"level {k}: rank {r} vs {rr} without targets" for k, r, rr in a.numeric.ranks)
            lines.append(f"  Derivative array ranks ({lev}).")
    lines.append("")
    e = a.easy
    if e.passed:
        lines.append(
            f"Easy test (the lecture's): [dF/dx' dF/dz] has full rank {e.rank} "
            f"(condition {e.condition:.1e}): Newton can solve for the derivatives and algebraic "
            "unknowns directly; any index-1 solver (IDAS, collocation) accepts this model as is."
        )
    else:
        lines.append(
            f"Easy test (the lecture's): [dF/dx' dF/dz] has rank {e.rank} < {e.size}: the model "
            "is NOT index 1 as written; an index-1 solver will reject it or fail."
            + (f" The rank deficiency involves: {', '.join(e.deficient_equations)}."
               if e.deficient_equations else "")
        )
    lines.append("")
    if a.structurally_ok:
        diff = [(nm, c) for nm, c in _group(a.equation_offsets) if c > 0]
        if diff:
            lines.append("Why: to reach a system that determines every unknown's highest derivative,")
            for nm, c in diff:
                lines.append(f"  - {nm} must be {_times(c)}")
            lines.append("  (all other equations are used as they are).")
        else:
            lines.append("Why: no equation needs differentiating.")
        alg = [nm for nm, v in a.highest_order.items() if v == 0]
        d = a.variable_offsets
        for nm, dv in _group({k: d[k] for k in alg}):
            block = next((b for b in a.blocks if any(v.split("[")[0] == nm.split("[")[0] or v == nm
                                                     for v in b[1])), None)
            eqs = ", ".join(dict.fromkeys(
                _der_eq(x.split("[")[0], a.equation_offsets[x]) for x in block[0])) if block else ""
            if dv == 0:
                tail = "its derivative needs one more differentiation."
            else:
                tail = (f"its derivatives up to {_der(nm, dv)} are needed, so in the reduced "
                        f"form {nm} becomes a state although the model never differentiates it.")
            lines.append(f"  - algebraic {nm}: determined as {_der(nm, dv)} together with {eqs}; "
                         + tail)
        if a.index == 0:
            lines.append("  It is an ODE (index 0).")
        elif any(v == 0 for v in d.values()):
            lines.append(
                f"  Index = (most differentiations of an equation, {max(a.equation_offsets.values())})"
                " + 1, because some unknowns are only determined algebraically at the top level."
            )
        else:
            lines.append(
                f"  Index = most differentiations of an equation = {max(a.equation_offsets.values())}."
            )
    lines.append("")
    lines.append(
        f"Degrees of freedom: {a.dof} initial values can be chosen freely; the rest follow from "
        "the equations and their hidden consistency conditions."
    )
    if a.structurally_ok:
        defs = set(a.definitions)
        cons = [(nm, c) for nm, c in _group({k: v for k, v in a.equation_offsets.items()
                                             if k not in defs}) if c > 0]
        if cons:
            conds = []
            for nm, c in cons:
                conds.extend(_der_eq(nm, k) for k in range(c))
            lines.append(
                "Consistency conditions (must hold at the initial time): " + ", ".join(conds) + "."
            )
        if defs:
            names = ", ".join(nm for nm, _ in _group({k: 0 for k in a.definitions}))
            lines.append(
                f"(The equations {names} define derivatives explicitly; the reduced form substitutes them, "
                "so they hold by construction.)"
            )
    if a.input_derivatives:
        needs = ", ".join(_der(nm, k) for nm, k in _group(a.input_derivatives))
        lines.append(
            f"Inputs: the equations to differentiate contain inputs, so the reduction needs their "
            f"derivatives up to {needs}: give inputs as CasADi expressions of time when "
            "simulating (daekit differentiates them), and in optimal control they become a chain "
            "of integrators."
        )
    lines.append("")
    if a.index <= 1 and e.passed:
        lines.append("What to do: nothing special; simulate it directly.")
    elif a.structurally_ok:
        lines.append(
            "What to do: dk.reduce_index(model) gives an equivalent index-1 DAE with these "
            "consistency conditions; start from dk.initialize(...), and fight drift with "
            "stabilization='dummy_derivatives', 'projection' or 'baumgarte'."
        )
    else:
        lines.append(
            "What to do: dk.reduce_index(model) repairs cancellations with constant coefficients "
            "by itself (it replaces an equation by a combination in which the leading derivatives "
            "cancel, then reduces; see r.info['amendments']). Where the cancellation depends on "
            "the variables, rewrite the model so that the structure shows the true dependencies."
        )
    return "\n".join(lines)


def _der_eq(name: str, k: int) -> str:
    if k == 0:
        return name
    return f"d/dt {name}" if k == 1 else f"d{k}/dt{k} {name}"
