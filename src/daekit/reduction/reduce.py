"""``reduce_index``: any-index model -> index-1 semi-explicit DAE with its invariants.

Method ``"differentiate"`` (Pryce's Sigma-method scheme)
--------------------------------------------------------
1. ``model.validate()`` (a structurally singular model raises :class:`StructuralError` naming the
   equations), then Pryce's offsets ``c_i`` (equations) and ``d_j`` (unknowns).
2. Every equation ``F_i`` is differentiated ``c_i`` times (total time derivative, one
   ``casadi.jtimes`` sweep per level, see :mod:`daekit.reduction.differentiate`).
3. States ``x``: the derivatives ``x_j^(k)``, ``k < d_j``, with the trivial ODEs
   ``(x_j^(k))' = x_j^(k+1)``. Algebraic unknowns ``z``: the highest derivatives ``x_j^(d_j)``
   (for an algebraic variable, ``d_j = 0``: the variable itself). Algebraic equations:
   ``0 = F_i^(c_i)``; their Jacobian with respect to ``z`` is Pryce's system Jacobian.
4. Invariants: ``F_i^(k)`` for ``k < c_i``, named ``"rod"``, ``"d/dt rod"``, ...
5. Elimination (default, ``eliminate=True``; :mod:`daekit.reduction.eliminate`): an equation
   that says ``a x_j^(k) = g`` with a constant or parameter-only ``a`` defines ``x_j^(k)``:
   a would-be state (``p' = v``) is replaced, with its derivatives, by ``g/a`` and its
   derivatives, and the equation drops out of the invariants; a highest derivative
   (``m v' = f(p, z)``) is replaced by ``g/a`` and is no algebraic unknown. The first-order
   3D pendulum then has the lecture's minimal index-1 form: states ``(p, v)``, algebraic
   ``(z)`` only, invariants ``rod`` and ``d/dt rod``; ``r.variables`` still gives
   ``"der(p)"`` (as the expression ``v``) and ``"der(v)"`` (as ``(u - m g e3 - z p)/m``).
   ``eliminate="states"`` keeps the KKT form (``z = (v', z)``), ``False`` Pryce's scheme.
6. Index-1 check: ``d alg / d z`` is evaluated (sparse) at random points and must be
   nonsingular at one of them; otherwise the structural analysis failed on this model (its
   system Jacobian is singular) and a :class:`ReductionError` names the equations involved.
   Singularity is always judged after row and column equilibration (powers of two) with the
   relative tolerance of :mod:`daekit.numerics`, so a regular
   but badly scaled model (``1e-12 x' + x = 0``) is not mistaken for a singular one.

Inputs: where ``F_i^(c_i)`` needs derivatives of a control ``u``, the symbols ``der(u)``,
``der(u,2)``, ... are appended to ``r.u`` and listed in ``r.input_derivatives``.

Example
-------
>>> import casadi as ca, daekit as dk
>>> from daekit.reduction import reduce_index
>>> m = dk.Model("pendulum")
>>> q = m.state("q", 2); T = m.algebraic("T")
>>> _ = m.equation(m.der(q, 2) - T * q - ca.DM([0, -9.81]), name="newton")
>>> _ = m.equation(ca.dot(q, q) - 1, name="rod")
>>> r = reduce_index(m)
>>> r.x_names
['q[0]', 'q[1]', 'der(q)[0]', 'der(q)[1]']
>>> r.z_names, r.invariant_names     # der(q,2) = T q + g e2 is substituted
(['T'], ['rod', 'd/dt rod'])
>>> reduce_index(m, eliminate="states").z_names   # the KKT form
['der(q,2)[0]', 'der(q,2)[1]', 'T']
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import numpy as np
import scipy
import scipy.sparse as sp

from .. import numerics
from ..errors import DaekitError, ReductionError
from ..model import Model
from ..reduced import ReducedDAE
from ..structure import block_triangular, dulmage_mendelsohn
from ..threads import limit_blas_threads
from .assemble import (
    all_symbols,
    assemble,
    invariant_rows,
    pair_names,
    state_pairs,
    top_equations,
)
from .differentiate import Expansion, derivative_name, expand
from .eliminate import Elimination, find_eliminations
from .invariants import attach_declared

__all__ = ["reduce_index", "check_index1"]

_DENSE_LIMIT = 400

#: Reductions other than Pryce's scheme, by ``method=`` name: each registers itself here
#: (``reduction/dummy.py`` adds ``"dummy_derivatives"``), so that this module never imports
#: the modules built on it.
OTHER_METHODS: dict[str, Callable[..., ReducedDAE]] = {}


@limit_blas_threads
def reduce_index(
    model: Model,
    method: str = "differentiate",
    point: dict | None = None,
    check: bool = True,
    seed: int = 0,
    eliminate: bool | str = True,
) -> ReducedDAE:
    """Reduce a model of any index to an index-1 semi-explicit DAE with its invariants.

    Parameters
    ----------
    model : daekit.Model or daekit.mechanics.LagrangianSystem
        A LagrangianSystem is reduced as its :meth:`~daekit.mechanics.LagrangianSystem.model`
        (its ``index1()`` is the mass-matrix form of the same reduction).
    method : ``"differentiate"`` or ``"dummy_derivatives"``
        ``"differentiate"``: Pryce's scheme (all derivatives below the highest become states,
        the undifferentiated equations and their lower derivatives are the invariants, which
        drift numerically). ``"dummy_derivatives"``: Mattsson--Soderlind; keeps every equation
        and its derivatives and turns selected derivatives into algebraic "dummies", so nothing
        drifts; see :func:`daekit.reduction.dummy_derivatives`.
    point : dict, optional
        For ``"dummy_derivatives"``: values by original name (``{"p": [1, 0], "der(p)": [0, 1]}``)
        at which the state selection is made; missing values are random.
    check : bool
        Check that ``d alg / d z`` is nonsingular (index 1) at random points.
    seed : int
        Seed of the random points.
    eliminate : bool or ``"states"``
        For ``"differentiate"``: the minimal index-1 form (default ``True``; see
        :mod:`daekit.reduction.eliminate`): derivatives that an equation gives explicitly with
        a constant or parameter-only coefficient are substituted, both would-be states
        (``der(p)`` in ``p' = v``) and highest derivatives that would be algebraic unknowns
        (``der(v)`` in ``m v' = f(p, z)``). The 3D pendulum then has the lecture's form
        ``x = (p, v)``, ``z = (z)``. A coefficient that depends on the state (a mass matrix
        ``M(q)``) keeps the KKT form (``der(v)`` algebraic). ``"states"``: only the would-be
        states (``z = (der(v), z)`` for the pendulum). ``False``: Pryce's scheme as it is
        (every ``x_j^(k)``, ``k < d_j``, a state). ``r.eliminated`` lists the
        would-be states eliminated, ``r.substituted`` the highest derivatives
        substituted, each by which equation, as what; ``r.variables`` still gives every name
        (``"der(v)[0]"`` as an expression of ``p``, ``z``, ...).

    Returns
    -------
    ReducedDAE

    Raises
    ------
    StructuralError
        The model is structurally singular (names the equations and unknowns at fault).
    ReductionError
        The system Jacobian is singular (structural analysis fails on this model), naming the
        equations involved; or an unknown method.

    Example
    -------
    >>> import daekit as dk
    >>> from daekit.reduction import reduce_index
    >>> m = dk.Model("L2")
    >>> x1, x2 = m.state("x1"), m.state("x2"); z = m.algebraic("z"); u = m.control("u")
    >>> _ = m.equation(m.der(x1) - z); _ = m.equation(m.der(x2) - x1); _ = m.equation(x2 - u)
    >>> r = reduce_index(m)
    >>> r.input_derivatives, r.u_names
    (['der(u)', 'der(u,2)'], ['u', 'der(u)', 'der(u,2)'])
    """
    model = Model.require(model, "reduce_index")  # a LagrangianSystem: its .model()
    if method in OTHER_METHODS:
        return OTHER_METHODS[method](model, point=point, check=check, seed=seed)
    if method != "differentiate":
        raise ReductionError(
            f"unknown reduction method {method!r}: use 'differentiate' or 'dummy_derivatives'"
        )
    if eliminate not in (True, False, "states"):
        raise ReductionError(
            f"reduce_index: eliminate={eliminate!r} is not an option: use True (the minimal "
            "index-1 form), 'states' (eliminate only duplicated states such as p' = v) or "
            "False (Pryce's scheme as it is)"
        )
    if not check:
        ex, amendments = amended_expansion(model, seed=seed)
        return attach_declared(_differentiate(ex, amendments, eliminate), model, check=False)
    # The amendment machinery (left null vectors of Pryce's system Jacobian) only runs where
    # that Jacobian is singular, i.e. where the index-1 check of the plain reduction fails
    # (d alg / d z is the system Jacobian, or its Schur complement on the eliminated pivots)
    ex = expand(model)
    r = _differentiate(ex, [], eliminate)
    masked = None
    try:
        check_index1(r, seed=seed)
        if r.eliminated or r.substituted:
            masked = _masked_singular(model, ex, seed)
        if masked is None:
            return attach_declared(r, model, seed=seed)  # m.invariant(...): checked, appended
    except ReductionError:
        pass
    ex, amendments = amended_expansion(model, seed=seed)
    if amendments:
        r = _differentiate(ex, amendments, eliminate)
    elif masked is not None:
        raise ReductionError(
            f"model {getattr(model, 'name', 'model')!r}: Pryce's system Jacobian is singular "
            f"in the equations {', '.join(repr(e) for e in masked)} (structural analysis "
            "fails there), and no combination with constant coefficients repairs it; the "
            "reduced system with their derivatives substituted passes its own index-1 check "
            "but would have too many degrees of freedom, so it is not returned. Rewrite "
            "these equations so that the structure shows the true dependencies (see "
            "dk.analyze(model).explain())."
        )
    try:
        check_index1(r, seed=seed)
        if amendments:
            check_amendments(model, r, seed=seed)
    except ReductionError:
        if eliminate is True and r.substituted:
            # name every equation of the singular combination, including those whose
            # highest derivatives were substituted: the message of the KKT form
            reduce_index(model, seed=seed, eliminate="states")
        raise
    return attach_declared(r, model, seed=seed)


def _masked_singular(model: Model, ex: Expansion, seed: int) -> list[str] | None:
    """The equations where Pryce's system Jacobian is singular although the reduced system passed its
    index-1 check: a derivative substituted from an equation of a singular block (a constant
    mixing of a constraint with an equation that gives a derivative) removes the
    singularity from ``d alg / d z`` while the offsets stay too small, and the reduced system
    would have too many degrees of freedom (:func:`daekit.analysis.system_jacobian_singular`,
    at a random point)."""
    from ..analysis import system_jacobian_singular

    return system_jacobian_singular(model, ex.c, ex.d, seed)


def _differentiate(ex: Expansion, amendments: list[str], eliminate) -> ReducedDAE:
    """The ReducedDAE of Pryce's scheme on the expansion ``ex`` (eliminations made)."""
    n = ex.n
    c, d = ex.c, ex.d
    el = find_eliminations(ex, highest=eliminate is True) if eliminate else Elimination()
    gone = set(el.pairs)
    gone_eqs = set(el.equations)
    states = state_pairs(ex, skip=(lambda j, k: (j, k) in gone) if gone else None)
    top_gone = np.zeros(n, dtype=bool)
    for j, k in el.pairs:
        if k == int(d[j]):
            top_gone[j] = True
    zpairs = list(zip(np.nonzero(~top_gone)[0].tolist(), d[~top_gone].tolist(), strict=True))
    keep = np.ones(n, dtype=bool)
    keep[np.asarray(el.equations, dtype=np.int64)] = False
    rows = np.nonzero(keep)[0].tolist()
    alg = top_equations(ex)
    if gone_eqs:
        alg = alg[rows]
    eq_names = ex.equation_names
    alg_names = [derivative_name(eq_names[i], int(c[i])) for i in rows]
    inv, inv_names, chains = invariant_rows(ex, skip=gone_eqs)
    r = assemble(ex, states, zpairs, alg, inv, inv_names, "differentiate")
    if el.pairs:
        r.ode, r.alg, r.invariants = el.substitute([r.ode, r.alg, r.invariants])
        for nm, e in zip(pair_names(ex, el.pairs), ca.vertsplit(el.defs), strict=True):
            r.variables[nm] = e
    r.alg_names = alg_names
    r.chains = chains
    r.offsets = {"c": c.copy(), "d": d.copy()}
    r.amendments = amendments
    # "eliminated": would-be states (their equations are no invariants: what
    # analyze().definitions lists); "substituted": highest derivatives that would have been
    # algebraic unknowns (their equations of offset 0 were never invariants)
    done = [
        ({"variable": nm, "equation": ex.equation_names[i], "expression": r.variables[nm]},
         int(c[i]) == 0)
        for i, nm in zip(el.equations, pair_names(ex, zip(el.unknowns, el.orders)), strict=True)
    ]
    r.eliminated = [e for e, top in done if not top]
    r.substituted = [e for e, top in done if top]
    return r


def check_amendments(model: Model, r: ReducedDAE, seed: int = 0) -> None:
    """After the linear-combination amendment: the reduced system must have as many degrees
    of freedom as the model. For the connected parts of the model that contain the replaced
    equations, the amended system (structural analysis now succeeds on it, the index-1 check
    has passed) has ``sum d - sum c`` of its offsets; the model has the derivative array's
    DOF at consistent points (:func:`daekit.analysis.derivative_array_dof`). Where they differ
    the amended system is not equivalent (a hidden constraint was lost or one too many
    imposed) and a :class:`ReductionError` names the replaced equations instead of returning
    a wrong system. ``r.info["amendment_check"]`` says what was compared.
    """
    from ..analysis import derivative_array_dof

    names = model.equation_names
    replaced = []
    for note in r.amendments:
        if "equation " in note and " was replaced" in note:
            nm = note.split("equation ", 1)[1].split(" was replaced")[0].strip("'\"")
            if nm in names:
                replaced.append(nm)
    if not replaced:
        r.info["amendment_check"] = "not checked (replaced equations unknown)"
        return
    try:
        truth, rows, cols = derivative_array_dof(model, replaced, seed=seed)
    except DaekitError as exc:
        r.info["amendment_check"] = f"not checked ({exc})"
        return
    c, d = r.offsets["c"], r.offsets["d"]
    dof = int(d[cols].sum() - c[rows].sum())
    r.info["amendment_check"] = (f"amended system: {dof} DOF, derivative array: {truth} DOF "
                                 f"(in the {len(rows)} equations coupled to the replaced ones)")
    if dof == truth:
        bad = _unmet_equations(model, r, seed)
        if bad:
            r.info["amendment_check"] += f"; the model's {', '.join(bad)} fail at its solutions"
            raise ReductionError(
                f"model {model.name!r}: the linear-combination amendment of the equations "
                f"{', '.join(repr(x) for x in replaced)} gives a reduced system whose "
                f"consistent states violate the model's own equations {bad[:6]} (checked "
                "at a consistent point of the reduced system): the amended system is not "
                "equivalent, although its degrees of freedom agree. Rewrite these equations so "
                "that the structure shows the true dependencies (solve one of them for a "
                "variable and substitute it)."
            )
    if dof != truth:
        raise ReductionError(
            f"model {model.name!r}: the linear-combination amendment of the equations "
            f"{', '.join(repr(x) for x in replaced)} gives a reduced system with {dof} degrees "
            f"of freedom in the equations coupled to them, but the model has {truth} there "
            "(derivative array at consistent points): the amended system is not equivalent. "
            "The cancellation in these equations is not the constant combination the amendment "
            "assumes; rewrite them so that the structure shows the true dependencies (solve one "
            "of them for a variable and substitute it), or use daekit.analyze(model) for the "
            "numeric index and DOF."
        )


def _unmet_equations(model: Model, r: ReducedDAE, seed: int = 0) -> list[str]:
    """The model's equations that do not hold (to ``1e-6`` of their terms) at a consistent
    point of ``r``, every unknown and derivative they use taken from ``r.variables``; empty
    where that cannot be checked (a name ``r`` does not give, no consistent point)."""
    from ..points import reduced_consistent_point

    syms, vals = [], []
    inc = model.incidence()
    top = np.zeros(inc.n_unknowns, dtype=np.int64)
    np.maximum.at(top, inc.cols, inc.vals)
    names = model.unknown_names
    for j, nm in enumerate(names):
        var, i, _ = model.resolve(nm)[0]
        for k in range(int(top[j]) + 1):
            key = var.element(i, k)  # "p[0]", "der(p)[0]": the one naming rule (model.element_name)
            if key not in r.variables:
                return []
            syms.append(var.der(k)[i])
            vals.append(r.variables[key])
    F = ca.substitute([model.residual], [ca.vertcat(*syms)], [ca.vertcat(*vals)])[0]
    try:
        f = ca.Function("F", [r.t, r.x, r.z, r.u, r.p], [F, ca.jacobian(F, ca.vertcat(r.x, r.z))])
    except RuntimeError:  # other free symbols: not checkable here
        return []
    cp = reduced_consistent_point(r, seed + 77)
    if cp is None:
        return []
    Fv, Jv = f(*cp)
    Fv = np.abs(np.asarray(Fv.full(), dtype=float).ravel())
    terms = np.abs(np.asarray(Jv.full(), dtype=float)) @ np.abs(np.concatenate(cp[1:3]))
    bad = np.nonzero(~(Fv <= 1e-6 * terms + 1e-12))[0]
    return [model.equation_names[i] for i in bad.tolist()]


# ---------------------------------------------------------------------------- SA amendment
def _left_null(ex: Expansion, seed: int):
    """Constant left null vectors of Pryce's system Jacobian ``J``, found numerically.

    ``None`` when ``J`` is nonsingular at a random point. ``False`` when it is singular but no
    usable null vector was found (a singular block too big for a dense SVD, an ill-conditioned
    basis, a block that is singular at one point only). Otherwise ``(bases, dr, rows)``: two bases
    (``k x n`` arrays, reduced echelon form on pivot columns chosen at the first point) of the
    left null space at two random points, which the caller compares (constant vectors only),
    the row scaling ``dr`` of ``J`` (entry ``u_i`` matters relative to ``1 / dr_i``) and the
    rows of the singular block.

    Sparse throughout: ``J`` is put in block lower triangular form (the transversal gives the
    matching), and the null vector is looked for in the first singular diagonal block only,
    which is tiny in practice (a Gear--Petzold pair inside a 1000-equation chain is a 2-by-2
    block). Its rows get the left null vectors of the block; the rows of earlier blocks follow
    by one sparse solve with the (nonsingular) earlier part, ``J[R<, C<]^T u< = -J[Rk, C<]^T uk``;
    later blocks do not take part (their rows use columns of later blocks only through the
    triangular structure). Singularity is judged after row and column equilibration by powers
    of two, with the relative tolerance :data:`daekit.numerics.RANK_RTOL` ``* size *
    sigma_max`` (so ``1e-12 x' + x = 0`` is an ODE, not a singular system).
    """
    n = ex.n
    if n == 0:
        return None
    top = top_equations(ex)
    hi = ex.unknown(ex.d, range(n))
    X, U = all_symbols(ex)
    p = ex.model.parameter_symbols
    Jsym = ca.jacobian(top, hi)
    f = ca.Function("J", [ex.model.t, X, U, p], [Jsym])
    pr, pc = Jsym.sparsity().get_triplet()
    tv = np.asarray(ex.transversal, dtype=np.int64)
    if tv.size != n:  # no transversal kept: a maximum matching of the pattern
        dm = dulmage_mendelsohn(n, n, pr, pc)
        if not dm.is_square_nonsingular:
            return False
        tv = np.asarray(dm.row_match, dtype=np.int64)
    blocks = block_triangular(n, np.r_[np.asarray(pr, int), np.arange(n)],
                              np.r_[np.asarray(pc, int), tv], tv)
    rng = np.random.default_rng(seed + 17)
    bases, piv, where = [], None, None
    for _ in range(4):
        A = _to_scipy(ca.DM(f(rng.uniform(0.1, 1.0), rng.uniform(0.2, 1.2, X.numel()),
                              rng.uniform(0.2, 1.2, U.numel()), ex.model.parameter_values)))
        if not np.all(np.isfinite(A.data)):
            continue
        if _lu_nonsingular(A):
            return None
        A = A.tocsr()
        dr, _ = _scales(A)
        if where is None:
            for b, (rows, cols) in enumerate(blocks):
                W = _block_left_null(A, rows, cols)
                if W is None:
                    continue
                where = b
                break
            else:
                return None  # every diagonal block is nonsingular
        else:
            W = _block_left_null(A, *blocks[where])
        if W is None or (isinstance(W, str)):
            return False  # too big for a dense SVD, or not singular at the other point
        Nf = _extend_left_null(A, blocks, where, W)
        if Nf is None:
            return False
        k = Nf.shape[0]
        if piv is None:
            _, _, pv = scipy.linalg.qr(Nf / dr[None, :], mode="economic", pivoting=True)
            piv = np.sort(pv[:k])
        B = Nf[:, piv]
        if np.linalg.cond(B) > 1e8:
            return False
        basis = np.linalg.solve(B, Nf)
        bases.append((basis, dr))
        if len(bases) == 2:
            break
    if len(bases) < 2:
        return None if not bases else False
    return [b for b, _ in bases], bases[0][1], [int(i) for i in blocks[where][0]]


def _block_left_null(A: sp.csr_matrix, rows, cols):
    """Left null vectors (rows of a ``k x len(rows)`` array) of the square block
    ``A[rows, cols]``, or None when the block is nonsingular; ``"big"`` when it is singular
    but too big for a dense SVD."""
    rows, cols = np.asarray(rows), np.asarray(cols)
    Bs = A[rows][:, cols]
    if len(rows) > _DENSE_LIMIT:
        return None if _lu_nonsingular(Bs) else "big"
    info = numerics.rank_info(Bs)
    if info.rank == len(rows):
        return None
    # u^T B = 0: the left null vectors, in the block's own (unscaled) coordinates
    return info.left_null


def _extend_left_null(A: sp.csr_matrix, blocks, k: int, W: np.ndarray):
    """Full left null vectors ``u`` (``W.shape[0] x n``) from those ``W`` of diagonal block
    ``k`` (earlier blocks nonsingular): ``u`` is ``W`` on the rows of block ``k``, zero on later
    blocks, and solves ``J[R<, C<]^T u< = -J[Rk, C<]^T uk`` on the earlier ones."""
    n = A.shape[0]
    rows_k = np.asarray(blocks[k][0])
    out = np.zeros((W.shape[0], n))
    out[:, rows_k] = W
    if k == 0:
        return out
    R = np.concatenate([np.asarray(b[0]) for b in blocks[:k]])
    C = np.concatenate([np.asarray(b[1]) for b in blocks[:k]])
    rhs = -(A[rows_k][:, C].T @ W.T)  # len(C) x kdim
    if not np.any(rhs):
        return out
    try:
        lu = sp.linalg.splu(sp.csc_matrix(A[R][:, C].T))
    except RuntimeError:
        return None
    sol = lu.solve(np.asarray(rhs, dtype=float))
    out[:, R] = np.asarray(sol).reshape(len(R), -1).T
    return out


def amended_expansion(model: Model, seed: int = 0, max_rounds: int = 20):
    """:func:`expand`, amended where Pryce's system Jacobian is singular.

    Linear-combination method (Tan, Nedialkov & Pryce, "Symbolic-numeric methods for improving
    structural analysis of DAEs", 2017): where ``u^T J = 0`` for a *constant* vector ``u``
    (found numerically at two random points, in the first singular block of the block
    triangular form of ``J``, see :func:`_left_null`), take ``theta = min c_i`` over
    ``u_i != 0`` and an equation ``l`` there with ``c_l = theta``, and replace ``F_l`` by
    ``sum_i u_i F_i^(c_i - theta)``: the leading derivatives cancel, the Sigma-method runs
    again. Before the replacement, the cancellation is verified on the expressions themselves
    (symbolically, else at random points, relative to the size of the terms), so a badly
    scaled but regular model is never changed. Repeated until ``J`` is nonsingular.
    Non-constant null vectors are left alone; the index-1 check then reports the failure.

    Returns the expansion and a list of plain-language notes on the replaced equations.
    """
    from ..model import Equation
    from .differentiate import time_derivative

    ex = expand(model)
    notes: list[str] = []
    work = model
    for _ in range(max_rounds):
        found = _left_null(ex, seed)
        if not found:
            break  # nonsingular (None) or not amendable (False): the index-1 check reports
        (n0, n1), dr, block_rows = found
        big = max(float(np.max(np.abs(n0))), 1e-300)
        if n0.shape != n1.shape or not np.allclose(n0, n1, rtol=1e-8, atol=1e-10 * big):
            break  # not a constant combination: reported by the index-1 check
        u = n0[0]
        w = np.abs(u) / dr  # the weights in equilibrated rows: which equations take part
        I = np.nonzero(w > 1e-10 * w.max())[0]
        theta = int(ex.c[I].min())
        # the equation replaced: offset theta, from the singular block where possible
        cand = [int(i) for i in I if ex.c[i] == theta]
        l = next((i for i in cand if i in set(block_rows)), cand[0])
        if u[l] < 0:  # the replaced equation keeps its sign (the null vector's is arbitrary)
            u = -u
        F = work.residual
        parts, terms = [], []
        for i in I:
            k = int(ex.c[i]) - theta
            coef = float(f"{u[i]:.12g}")  # 12 significant digits: -0.99999999999998 -> -1
            parts.append(coef * time_derivative(F[int(i)], work, k))
            terms.append(f"{coef:+g}*{derivative_name(ex.equation_names[i], k)}")
        lead = [j for j in range(ex.n) if ex.d[j] >= theta]
        lead_syms = ex.unknown(ex.d - theta, lead)
        parts = ca.vertcat(*parts)
        if not _cancels(parts, lead_syms, work, seed):
            break  # the combination keeps its leading derivatives: reported by the check
        # u^T J = 0 identically: the combination does not depend on the derivatives
        # x_j^(d_j - theta); remove them (SX keeps cancelled terms like a - a symbolically)
        comb = ca.substitute(ca.sum1(parts), lead_syms, ca.SX.zeros(lead_syms.shape))
        names = ex.equation_names
        new_eqs = [Equation(names[i], F[i]) for i in range(ex.n)]
        new_eqs[l] = Equation(names[l], ca.SX(comb))
        notes.append(
            f"Pryce's system Jacobian is singular (structural analysis fails): equation "
            f"{names[l]!r} was replaced by the combination {' '.join(terms)}, in which the "
            "leading derivatives cancel (linear-combination method)"
        )
        work = work.with_equations(new_eqs)
        ex = expand(work, validate=False)
        ex.model = model
    return ex, notes


def _cancels(parts: ca.SX, lead: ca.SX, model: Model, seed: int, rtol: float = 1e-8) -> bool:
    """Whether ``sum(parts)`` is free of the symbols ``lead``: ``d sum / d lead`` is zero
    symbolically, or at three random points (parameters at their values) it is below ``rtol``
    times the size of the individual terms ``|d parts_i / d lead|`` (scale-free)."""
    Jp = ca.jacobian(parts, lead)
    total = ca.sum1(Jp)
    if total.nnz() == 0 or ca.simplify(total).is_zero():
        return True
    p = model.parameter_symbols
    if p.numel():
        Jp = ca.substitute(Jp, p, ca.DM(model.parameter_values))
    syms = ca.symvar(Jp)
    V = ca.vertcat(*syms) if syms else ca.SX(0, 1)
    f = ca.Function("cancel", [V], [ca.densify(Jp)])
    rng = np.random.default_rng(seed + 29)
    checked = 0
    for _ in range(6):
        M = np.asarray(f(rng.uniform(0.2, 1.2, V.numel())), dtype=float)
        if not np.all(np.isfinite(M)):
            continue
        if np.any(np.abs(M.sum(axis=0)) > rtol * np.abs(M).sum(axis=0)):
            return False
        checked += 1
        if checked == 3:
            return True
    return False


# ---------------------------------------------------------------------------- index-1 check
def _random_points(r: ReducedDAE, seed: int, count: int = 3):
    rng = np.random.default_rng(seed)
    for m in range(count):
        if m == 0:
            draw = lambda k: rng.uniform(0.2, 1.2, k)  # noqa: E731 - positive: sqrt/log safe
        else:
            draw = lambda k: rng.standard_normal(k)  # noqa: E731
        yield (
            float(rng.uniform(0.1, 1.0)),
            draw(r.nx),
            draw(r.nz),
            draw(r.nu),
            r.p_values if m < 2 else r.p_values * rng.uniform(0.5, 1.5, r.n_p),
        )


_to_scipy = numerics.to_scipy


def _scales(A) -> tuple[np.ndarray, np.ndarray]:
    """Row and column scale factors (powers of two) that equilibrate ``A`` (dense or sparse):
    :func:`daekit.numerics.equilibrate`. The equilibrated matrix is ``diag(dr) A diag(dc)``."""
    return numerics.equilibrate(A)


def _lu_nonsingular(A: sp.spmatrix) -> bool:
    """Cheap test (no dense SVD): :func:`daekit.numerics.sparse_nonsingular`."""
    return numerics.sparse_nonsingular(A)


def _singular_rows(A: sp.csc_matrix):
    """Rows taking part in a (numerical) rank deficiency of square A, or None if nonsingular.

    Small matrices: SVD. Big ones: block triangular form of the pattern, then per block a
    sparse LU and, where that finds the block singular, a dense SVD. Always after
    equilibration (:func:`_scales`).
    """
    n = A.shape[0]
    if n == 0 or _lu_nonsingular(A):
        return None
    if n <= _DENSE_LIMIT:
        return _dense_singular_rows(A.toarray(), np.arange(n))
    coo = A.tocoo()
    dm = dulmage_mendelsohn(n, n, coo.row, coo.col)
    if not dm.is_square_nonsingular:
        return sorted(set(dm.over_rows) | set(dm.under_rows))
    A = A.tocsr()
    blocks = block_triangular(n, coo.row, coo.col, dm.row_match)
    # scalar blocks all at once: singular exactly where the entry is zero (or not finite)
    one = [(int(rows[0]), int(cols[0])) for rows, cols in blocks if len(rows) == 1]
    zero_rows: set[int] = set()
    if one:
        r1, c1 = np.array(one).T
        vals = np.asarray(A[r1, c1]).ravel()
        zero_rows = set(r1[~(np.isfinite(vals) & (vals != 0))].tolist())
    for rows, cols in blocks:
        if len(rows) == 1:
            if int(rows[0]) in zero_rows:
                return [int(rows[0])]
            continue
        if len(rows) <= 16:  # small: the dense SVD at once (no sparse machinery per block)
            bad = _dense_singular_rows(A[rows][:, cols].toarray(), np.asarray(rows))
            if bad is not None:
                return bad
            continue
        blk = A[rows][:, cols]
        if _lu_nonsingular(blk):
            continue
        if len(rows) > 4 * _DENSE_LIMIT:
            return sorted(int(i) for i in rows)  # too big to say more
        bad = _dense_singular_rows(blk.toarray(), np.asarray(rows))
        if bad is not None:
            return bad
    return None


def _dense_singular_rows(M: np.ndarray, rows: np.ndarray, scales=None):
    """Rows of ``M`` (named by ``rows``) in its left null space after equilibration, or None
    when ``M`` is nonsingular (smallest singular value above ``RANK_RTOL * n * sigma_max``).
    ``scales``: see :func:`daekit.numerics.rank_info`."""
    if not np.all(np.isfinite(M)) or M.size == 0:
        return None
    info = numerics.rank_info(M, scales=scales)
    if info.rank == M.shape[0]:
        return None
    return sorted(rows[info.deficient_rows(1e-6)].tolist())


def _z_block_singular_rows(A: np.ndarray, nx: int):
    """:func:`_dense_singular_rows` of the z block ``A[:, nx:]`` of ``A = d alg / d(x, z)``,
    in the row and column factors of the whole ``A``."""
    Az = A[:, nx:]
    if not np.all(np.isfinite(A)) or Az.size == 0:
        return None
    dr, dc = numerics.equilibrate(A)
    return _dense_singular_rows(Az, np.arange(Az.shape[0]), scales=(dr, dc[nx:]))


#: Reduced systems with at most this many unknowns are checked at consistent points too.
CONSISTENT_CHECK_LIMIT = 1000


def _perturbed(cp, seed: int, at_random, f):
    """``f`` at the consistent point ``cp = (t, x, z, u, p)`` with ``x`` and ``z`` multiplied
    by factors from ``U(0.5, 1.5)``: the reference of :func:`daekit.numerics.vanishing_removed`
    in the units of the point (see :meth:`daekit.points.TestPoint.perturbed`); ``at_random``
    where that is not finite."""
    rng = np.random.default_rng(seed + 15485863)
    t, x, z, u, p = cp
    x1 = np.where(x != 0, x * rng.uniform(0.5, 1.5, x.size), rng.uniform(0.2, 1.2, x.size))
    z1 = np.where(z != 0, z * rng.uniform(0.5, 1.5, z.size), rng.uniform(0.2, 1.2, z.size))
    ref = f(t, x1, z1, u, p)
    return ref if np.all(np.isfinite(ref.data if sp.issparse(ref) else ref)) else at_random


def _singular_on_solutions(r: ReducedDAE, f, seed: int, at_random):
    """Rows of ``d alg / d z`` singular at two consistent points (alg = 0, invariants = 0),
    or None (nonsingular at one of them, or no consistent point found, or too big); sets
    ``r.info["index1_check"]``. ``f(t, x, z, u, p)``: the matrix the check ranks (see
    :func:`check_index1`). Entries that vanish on the solutions (below
    :data:`daekit.numerics.VANISH` of their value ``at_random``, the matrix at a random point)
    are zero there: equilibration would otherwise make their rounding residue count."""
    from ..points import reduced_consistent_point

    if r.nx + r.nz > CONSISTENT_CHECK_LIMIT:
        r.info["index1_check"] = "passed"
        r.info["index1_check_at"] = "a random point (too big for a consistent one)"
        return None
    bad = None
    for k in range(2):
        # the first from the analysis's consistent point of the model where there is one
        cp = reduced_consistent_point(r, seed + 1000 * k, remembered=k == 0)
        if cp is None:
            if bad is not None:  # singular at the one consistent point found: singular
                return bad
            r.info["index1_check"] = "passed"
            r.info["index1_check_at"] = "a random point (no consistent point found)"
            return None
        ref = _perturbed(cp, seed + k, at_random, f)
        A = f(*cp)
        if r.nz <= 64:  # small: dense SVD at once (no sparse machinery per call)
            if not np.all(np.isfinite(A)):
                continue
            bad = _z_block_singular_rows(numerics.vanishing_removed(A, ref), r.nx)
        else:
            if not np.all(np.isfinite(A.data)):
                continue
            bad = _singular_rows(numerics.vanishing_removed(A, ref).tocsc())
        if bad is None:
            r.info["index1_check"] = "passed"
            r.info["index1_check_at"] = "a consistent point"
            return None
    return bad


def _check_matrix(r: ReducedDAE, small: bool):
    """``f(t, x, z, u, p)``: what :func:`check_index1` ranks -- ``d alg / d(x, z)`` dense
    (``small``) or ``d alg / d z`` as SciPy CSC. Up to ``CONSISTENT_CHECK_LIMIT`` unknowns
    from the functions the consistent points use (:func:`daekit.points.reduced_point_functions`,
    rows ``:nz``), made once per system; beyond, one CasADi function of the block itself."""
    from ..points import reduced_point_functions

    w = ca.vertcat(r.x, r.z)
    nx, nz = r.nx, r.nz
    if w.is_valid_input() and nx + nz <= CONSISTENT_CHECK_LIMIT:
        _, jac = reduced_point_functions(r)

        def shared(t, x, z, u, p):
            A = jac(t, u, np.concatenate([np.ravel(x), np.ravel(z)]), p)
            if small:
                A = A.toarray() if sp.issparse(A) else np.asarray(A)
                return np.array(A[:nz], dtype=float)
            A = sp.csr_matrix(A)[:nz].tocsc()
            return A[:, nx:]

        return shared
    # small: d alg / d(x, z), and the z block ranked in the equilibration of the whole (an
    # entry of d alg / d z that is rounding residue of a cancelled term, 1e-16 beside the
    # row's x entries, must not be scaled up to unit size: the row does not involve z)
    J = ca.jacobian(r.alg, w) if small else ca.jacobian(r.alg, r.z)
    fn = ca.Function("Jz", [r.t, r.x, r.z, r.u, r.p], [J])

    def own(t, x, z, u, p):
        val = fn(t, x, z, u, p)
        return np.asarray(val.full(), dtype=float) if small else _to_scipy(val)

    return own


def check_index1(r: ReducedDAE, seed: int = 0, points: int = 3) -> None:
    """Raise :class:`ReductionError` unless ``d alg / d z`` of ``r`` is nonsingular.

    Evaluated (sparse) at ``points`` random points, and where it is nonsingular there, at up
    to two consistent points (``alg = 0`` and the invariants hold, :mod:`daekit.points`): the
    index is a property along solutions, and ``(2 + sin y) * c(y, z)`` as a constraint is
    regular at random points but singular wherever ``c = 0``. Nonsingular at one consistent
    point suffices. The message names the algebraic equations in the singular combination.
    """
    if r.nz == 0:  # an ODE (alg has as many rows as z)
        r.info["index1_check"] = "passed"
        return
    small = r.nz <= 64  # small: dense SVD at once (no sparse machinery per call)
    f = _check_matrix(r, small)
    bad, finite = None, False
    for t, x, z, u, p in _random_points(r, seed, points):
        A = f(t, x, z, u, p)
        if small:
            if not np.all(np.isfinite(A)):
                continue
            finite = True
            bad = _z_block_singular_rows(A, r.nx)
        else:
            if not np.all(np.isfinite(A.data)):
                continue
            finite = True
            bad = _singular_rows(A)
        if bad is None:
            break
    if finite and bad is None:
        # nonsingular at a random point; on the solutions (alg = 0 and the invariants) it may
        # still be singular (a constraint times a factor that vanishes there): check at
        # consistent points (daekit.points), up to CONSISTENT_CHECK_LIMIT unknowns
        bad = _singular_on_solutions(r, f, seed, A)
        if bad is None:
            return
    if not finite:
        r.info["index1_check"] = "inconclusive (no finite Jacobian at random points)"
        return
    names = r.alg_labels
    eqs = [names[i] for i in bad]
    shown = ", ".join(repr(e) for e in eqs[:12]) + (" ..." if len(eqs) > 12 else "")
    model = getattr(r.model, "name", "model")
    raise ReductionError(
        f"model {model!r}: the reduced system is not index 1: the Jacobian of the differentiated "
        f"equations {shown} with respect to their highest derivatives (Pryce's system "
        "Jacobian) is singular at every test point (on the solutions). Structural analysis (Sigma-method/"
        "Pantelides) fails on this model: it underestimates the index because these equations "
        "are dependent in their leading derivatives. Rewrite the model (e.g. substitute one "
        "of these equations into the others to eliminate the shared derivative), or use "
        "daekit.analyze(model) for the numeric (derivative-array) index."
    )

