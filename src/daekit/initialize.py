"""Consistent initial values for a reduced (index-1) DAE.

A :class:`~daekit.reduced.ReducedDAE` is equivalent to the original model only on the manifold
where its algebraic equations ``alg = 0`` *and* its invariants (the consistency conditions, e.g.
the pendulum's ``c = (p.p - L^2)/2`` and ``c' = p.v``) hold. :func:`initialize` finds a point on
that manifold: values you *fix* are held exactly, values you *guess* are pulled to in a weighted
least-squares sense, and everything else is found.

Method (Newton--Lagrange on the constraints, with CasADi derivatives): unknowns ``w = (x, z)``;
constraints ``h(w) = [alg; invariants; fixed(w) - fixed values] = 0``; objective
``||G(w) - guess||^2 / 2``. Each iteration solves the quadratic problem
``min ||G + J_G d - guess||^2 / 2 + d^T C d / 2  s.t.  h + J_h d = 0``, ties broken by the
smallest ``||d_x||`` (``z`` is not weighted: it follows from ``alg``), so redundant but
consistent constraints do no harm. ``C`` is the curvature of the Lagrangian (the invariants'
and the used values' second derivatives times their multipliers, from the last step): plain
Gauss--Newton (``C = 0``) converges slowly or diverges where the constraints are curved and
the guesses off them, as for a 200-link chain guessed 1 cm off its rods, whose multipliers
are large; with ``C`` the iteration is Newton's on the optimality conditions and converges in
a handful of steps at any size (the first step, and any step the line search would cut below
1/8, is Gauss--Newton's). After every step ``z`` is re-solved from ``alg(x, z) = 0`` at the
new ``x`` (one linear solve when ``alg`` is affine in ``z``, as for mechanical systems), so the
iteration runs on ``x`` alone, where the problem lives. Trial points are accepted when they
reduce ``||h||`` or the exact penalty ``f + rho ||h||_1``.
Values that cannot be made consistent leave a residual; the rows carrying it (at a
stationary point the residual lies in the left null space of ``J_h``) name the conflicting
fixed values and consistency conditions.

Everything that depends only on the system (the vector of every named value as an expression,
the name-to-row map, the CasADi functions of ``[alg; invariants]`` and of the values, their
sparse Jacobians, the Hessian of the invariants) is made once and kept on the system, and so
is what a call's *names* decide, per set of fixed and guessed names (:class:`_Plan`: their rows,
index arrays, the functions of the rows that are expressions, which fixed values name one
quantity twice, where the values go in ``w``, which curvature terms the steps need): a sweep, an
ensemble or a loop fixes the same names in every sample, and its later calls only check their
values and do the numerics (the checks that depend on values, such as two names of one
quantity given different values, are made on every call). The parameters are inputs of those
functions, not baked in. The CasADi functions are called through their raw buffers
(:class:`daekit.numerics.FastFunction`). The rank analysis of the result (free, redundant and
determined values) is made on first access to those fields of :class:`InitialValues`.

Two implementations of the same method, chosen by the number of unknowns ``nx + nz``:

- small systems (below ``_SPARSE_MIN_UNKNOWNS = 300``): dense NumPy throughout: ``z``
  eliminated with an LU of ``d alg / d z``, SVDs for the step, an SVD projection plus in-order
  Gram--Schmidt for the redundant fixed values, a column-pivoted QR for the free states;
- big systems: CasADi's sparse Jacobians as SciPy CSC matrices; the step from the KKT system
  ``[[W, J^T], [J, 0]]`` (``W = J_G^T J_G + C + eps D_x``, or ``D_x`` without guesses)
  factorized by SuperLU as it is (regularized and refined only when redundant rows make it
  singular); ``z`` re-solved by SuperLU on ``d alg / d z``; a minimum-weight bipartite matching
  picks a well-conditioned square basis ``C_D`` of the consistency rows (the dependent states
  ``D``; the others are free), and a fixed row is redundant when its coordinates on the free
  states ``f_N - f_D C_D^{-1} C_N`` depend on those of the fixed rows before it. The values
  are linear in the size for mechanisms such as long chains; the redundancy analysis of many
  fixed *dependent* states (all of a chain's ``q`` and ``v`` fixed) is not (``C_D^{-1}`` is
  dense for a chain). Degenerate consistency rows (numerically rank deficient at the
  solution) fall back to the dense analysis for ``free`` and ``redundant``.

Both give the same values, the same ``redundant`` values and messages; ``free`` is a valid
choice of the same size on both (they may pick different, equally valid, sets).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import scipy
import scipy.sparse as sp

from .errors import InitializationError
from .numerics import FastFunction, equilibrate, major_index
from .points import system_jacobians
from .threads import blas_threads, gc_paused, limit_blas_threads
from .wording import count

__all__ = ["InitialValues", "checked_values", "initialize"]

#: Systems with at least this many unknowns ``nx + nz`` take the sparse path (sparse
#: Jacobians, SuperLU on KKT systems, a matched basis of the consistency rows); smaller ones
#: the dense SVD/QR path. Both give the same values; tests force either by changing this.
_SPARSE_MIN_UNKNOWNS = 300


@dataclass
class InitialValues:
    """Consistent initial values of a ReducedDAE.

    Attributes
    ----------
    t0 : float
    x0, z0 : numpy.ndarray
        States and algebraic unknowns of the reduced system (orders ``r.x_names``, ``r.z_names``).
    u0, p : numpy.ndarray
        Inputs at ``t0`` and the parameter values used.
    values : dict of str to float
        Every element of the original model (``"p[0]"``, ``"der(p)[0]"``, ``"z"``, inputs).
    free : list of str
        The state values that are still free: they could be fixed in addition to ``fixed``
        (in the order of ``x_names``). Together with the fixed values they form
        ``dof_names``.
    fixed : list of str
        The element names you fixed, in your order (the implied ones also in ``redundant``).
    dof_names : list of str
        One choice of dynamic degrees of freedom, ``dof`` state names in state order: a set of
        values that can be fixed freely (found by a column-pivoted QR of the consistency
        Jacobian, or for big systems by a matched sparse basis of it). States you fixed are
        preferred.
    dof : int
        Number of dynamic degrees of freedom (``len(dof_names)``).
    redundant : list of str
        Fixed values that were implied by the others (consistent, hence accepted).
    residual : float
        Max |alg|, |invariant| at the solution.
    iterations : int
    notes : list of str
        What was done for you (e.g. a Model given instead of a ReducedDAE was reduced), and
        remarks such as a determined value that is fixed only up to its sign (``q[3]`` of a
        unit quaternion with the other three components fixed: the guess's sign is taken).
    determined : list of str
        States (and dummy states) that are not fixed but locally determined by the fixed
        values and the consistency conditions (unit vectors orthogonal to the null space of
        their Jacobian; systems below 300 unknowns). Empty when nothing is determined.

    ``init["p"]`` returns the values of ``p`` as an array, ``init["p[0]"]`` a float.

    ``free``, ``dof``, ``dof_names``, ``redundant``, ``determined`` and ``notes`` come from a
    rank analysis at the solution that is made on first access to any of them (a sweep that
    only simulates from the values does not pay for it); the result is the same whenever it
    is made.
    """

    t0: float
    x0: np.ndarray
    z0: np.ndarray
    u0: np.ndarray
    p: np.ndarray
    values: dict[str, float]
    free: list[str] = field(default_factory=list)
    dof: int = 0
    redundant: list[str] = field(default_factory=list)
    residual: float = 0.0
    iterations: int = 0
    x_names: list[str] = field(default_factory=list)
    z_names: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    fixed: list[str] = field(default_factory=list)
    dof_names: list[str] = field(default_factory=list)
    determined: list[str] = field(default_factory=list)
    _deferred: object = field(default=None, repr=False, compare=False)

    def _resolve(self) -> None:
        """Run the deferred analysis (free, redundant, determined values) once."""
        d = self.__dict__
        make = d.get("_deferred")
        if make is None:
            return
        with blas_threads(), gc_paused():  # as initialize itself runs
            found = make()
        d.update(found)
        d["_deferred"] = None

    def __getstate__(self) -> dict:
        self._resolve()
        return dict(self.__dict__)

    def __getitem__(self, name: str):
        from .model import select_name

        elems, vector = select_name(name, self.values, "these initial values")
        if not vector:
            return float(self.values[elems[0]])
        return np.array([self.values[e] for e in elems])

    def __repr__(self) -> str:
        shown = ", ".join(f"{n}={v:.6g}" for n, v in zip(self.x_names, self.x0, strict=False))
        return (
            f"InitialValues(t0={self.t0:g}: {shown}; dof={self.dof}, "
            f"residual={self.residual:.1e})"
        )


class _DeferredField:
    """A field of :class:`InitialValues` filled by the deferred analysis: reading it (or
    writing it, so that the analysis does not overwrite the value later) runs the analysis
    first if it is still pending. A data descriptor on six fields only: reading any other
    attribute runs no Python."""

    def __init__(self, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        d = obj.__dict__
        if d.get("_deferred") is not None:
            obj._resolve()
        return d[self.name]

    def __set__(self, obj, value) -> None:
        if obj.__dict__.get("_deferred") is not None:
            obj._resolve()
        obj.__dict__[self.name] = value


#: InitialValues fields filled by the deferred analysis.
_DEFERRED = frozenset({"free", "dof", "dof_names", "redundant", "determined", "notes"})
for _name in _DEFERRED:  # after @dataclass: its __init__ then stores through them
    setattr(InitialValues, _name, _DeferredField(_name))
del _name


def _name_values(r, key: str, val, what: str, row_of, names_of: dict | None = None
                 ) -> list[tuple[str, int, float]]:
    """(element name, row in the system's variable vector, value) for each element meant by
    ``key``; ``names_of``: a cache of the elements of each key already resolved."""
    from .model import NameNotFoundError, expand_name

    elems = names_of.get(key) if names_of is not None and isinstance(key, str) else None
    if elems is not None:
        return _with_values(elems, key, val, what, row_of)

    pnames = list(getattr(r, "p_names", []) or [])
    if pnames and isinstance(key, str):
        try:
            expand_name(key, dict.fromkeys(pnames), "the parameters")
        except NameNotFoundError:
            pass
        else:
            raise InitializationError(
                f"{what}: {key} is a parameter, not a variable: use params={{{key!r}: {val!r}}}"
            )
    try:
        elems = expand_name(key, r.variables, "the model")
    except NameNotFoundError as exc:
        raise InitializationError(f"{what}: {exc}") from None
    if names_of is not None:
        names_of[key] = elems
    return _with_values(elems, key, val, what, row_of)


def _with_values(elems: list[str], key: str, val, what: str, row_of
                 ) -> list[tuple[str, int, float]]:
    """The values ``val`` given for ``key`` (elements ``elems``), checked."""
    arr = checked_values(len(elems), elems, key, val, what)
    return [(e, row_of[e], float(v)) for e, v in zip(elems, arr.tolist(), strict=True)]


def checked_values(size: int, elems: list[str], key: str, val, what: str) -> np.ndarray:
    """The ``size`` values ``val`` given for ``key`` (elements ``elems``) as floats: one
    number for all of them or one per element, finite; else InitializationError."""
    try:
        arr = np.asarray(val, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InitializationError(
            f"{what}: the value of {key!r} must be a number or a list of numbers, got {val!r}"
        ) from None
    if arr.size == 1 and size > 1:
        arr = np.repeat(arr, size)
    if arr.size != size:
        raise InitializationError(
            f"{what}: {key!r} has {count(size, 'element')} ({', '.join(elems)}) but "
            f"{count(arr.size, 'value')} {'was' if arr.size == 1 else 'were'} given"
        )
    if not np.isfinite(arr).all():
        raise InitializationError(f"{what}: the value of {key!r} is not finite: {val!r}")
    return arr


class _SystemCache:
    """What :func:`initialize` needs of a system, made once per system and kept on it (a
    system's names and expressions do not change): the vector ``V`` of every named value as
    an expression of ``w = (x, z)``, ``t``, ``u``, ``p``; the name-to-row map; CasADi functions
    for ``[alg; invariants]``, ``V`` and their sparse Jacobians; the symbol hash and the
    position in ``w`` of every row of ``V`` that is a plain symbol."""

    def __init__(self, r) -> None:
        self.nx, self.nz = nx, _ = r.nx, r.nz
        self._refs = (r.x, r.z, r.alg, r.invariants, r.variables, r.u, r.t)  # ids stay unique
        names = list(r.variables)
        exprs = list(r.variables.values())
        known = set(names)
        u_split = ca.vertsplit(r.u) if r.nu else []
        for i, nm in enumerate(r.u_names):
            if nm not in known:
                names.append(nm)
                exprs.append(u_split[i])
        self.names = names
        self.row_of = {nm: i for i, nm in enumerate(names)}
        V = ca.vertcat(*[ca.SX(e) if not isinstance(e, ca.SX) else e for e in exprs]) \
            if exprs else ca.SX(0, 1)
        # the system's own Jacobians (made once, shared with its consistent points)
        sj = system_jacobians(r)
        w, self.alg, self.inv, Jalg, Jinv = sj.w, sj.alg, sj.inv, sj.J_alg, sj.J_inv
        self.w = w
        self.V = ca.vec(ca.densify(V))
        self.args = [w, r.t, r.u, r.p]
        core = ca.vertcat(self.alg, self.inv)
        self.core = core
        self.jacobians = {"alg": Jalg, "inv": Jinv}  # symbolic, for the Hessians
        self.Jz = Jalg[:, nx:]  # d alg / d z (for settle)
        # [core, J_alg, J_inv]: the stacked Jacobian's nonzeros placed numerically (the
        # symbolic vertcat of the two copied every nonzero: 0.15 s at 10,000 links)
        blocks = [Jalg] if Jinv is None else [Jalg, Jinv]
        self.core_fun = FastFunction(ca.Function("core", self.args, [core, *blocks]))
        self.core_ccs, self._core_dest = _stacked_ccs([J.sparsity() for J in blocks])
        self.v_fun = FastFunction(ca.Function("values", self.args, [self.V]))
        # per set of used rows (a call's fixed values and guesses): their values' Jacobian and
        # Hessian functions (the names a sweep fixes are the same in every sample)
        self.used_funs: dict[tuple, tuple] = {}
        self.curved_funs: dict[tuple, tuple] = {}
        # rows of V that are plain symbols: hash (two names of one quantity) and w position,
        # found for the rows that fixed values and guesses use, on first use (-2: not yet)
        nv = int(self.V.numel())
        self.sym_hash = np.full(nv, -2, dtype=np.int64)
        self.w_pos = np.full(nv, -1, dtype=np.int64)
        self.elems: dict[int, ca.SX] = {}
        self._w_elems = None  # the elements of w, split on first use
        self.settle = {}
        self.hess: dict = {}
        self.zdep = None
        self.names_of: dict = {}  # a fixed/guessed key -> its elements and rows
        self.plans: dict[tuple, _Plan] = {}  # (fixed keys, guess keys) -> what they decide

    def core_nonzeros(self, parts: list[np.ndarray]) -> np.ndarray:
        """The nonzeros of ``[J_alg; J_inv]`` (CCS order of ``core_ccs``) from those of the
        blocks as ``core_fun`` returns them."""
        if len(parts) == 1:
            return parts[0]
        out = np.empty(self.core_ccs[1].size)
        for dest, part in zip(self._core_dest, parts, strict=True):
            out[dest] = np.asarray(part, dtype=float).ravel()
        return out

    def describe(self, rows: np.ndarray) -> None:
        """Fill ``sym_hash``, ``w_pos`` and ``elems`` for ``rows`` (one slice of ``V``)."""
        todo = np.unique(rows[self.sym_hash[rows] == -2]) if rows.size else rows
        if not todo.size:
            return
        part = self.V[todo.tolist()]
        # the rows that are symbols of w: one dependency on w, and (one comparison of the
        # whole slice) the symbol itself; the others (expressions, inputs, parameters) one
        # by one
        is_w = np.zeros(todo.size, dtype=bool)
        col = np.full(todo.size, -1, dtype=np.int64)
        if self.w.numel():
            rr, cc = ca.jacobian_sparsity(part, self.w).get_triplet()
            rr = np.asarray(rr, dtype=np.int64)
            cnt = np.bincount(rr, minlength=todo.size)
            col[rr] = np.asarray(cc, dtype=np.int64)
            one = np.nonzero(cnt == 1)[0]
            if one.size and ca.is_equal(part[one.tolist()], self.w[col[one].tolist()], 0):
                is_w[one] = True
        if is_w.any():
            if self._w_elems is None:
                self._w_elems = ca.vertsplit(self.w)
            ws = self._w_elems
            for i, k in zip(todo[is_w].tolist(), col[is_w].tolist(), strict=True):
                self.sym_hash[i] = ws[k].element_hash()
                self.w_pos[i] = k
        rest = np.nonzero(~is_w)[0]
        if not rest.size:
            return
        sub = part[rest.tolist()]
        elems = ca.vertsplit(sub) if rest.size > 1 else [sub]
        for i, k, e in zip(todo[rest].tolist(), rest.tolist(), elems, strict=True):
            self.elems[i] = e
            if e.is_symbolic():
                self.sym_hash[i] = e.element_hash()
                self.w_pos[i] = col[k] if col[k] >= 0 and ca.is_equal(e, self.w[int(col[k])]) \
                    else -1
            else:
                self.sym_hash[i] = -1

    def hessian(self, part: str):
        """Hessian functions, made on first use: ``"inv"``: ``H(w, t, u, p, y)`` of
        ``y^T invariants``; ``"alg"``: of ``y^T alg``."""
        if part not in self.hess:
            # the Jacobian of J^T y, J the Jacobian made above: the gradient of y^T expr
            # without a reverse sweep (a 10,000-link chain's invariants: 0.70 s against
            # ca.hessian's 0.83 s)
            J = self.jacobians[part]
            y = ca.SX.sym("y", J.shape[0])
            f = ca.Function(f"hess_{part}", [*self.args, y],
                            [ca.jacobian(ca.mtimes(J.T, y), self.w)])
            self.hess[part] = (FastFunction(f), _ccs(f.sparsity_out(0)))
        return self.hess[part]

    def used_values(self, rows: np.ndarray):
        """``(function, ccs)``: the values of the rows ``rows`` of ``V`` and their Jacobian
        in ``w``; made once per set of rows."""
        key = tuple(rows.tolist())
        if key not in self.used_funs:
            Ve = self.V[list(key)]
            f = ca.Function("used_values", self.args, [Ve, ca.jacobian(Ve, self.w)])
            self.used_funs[key] = (FastFunction(f), _ccs(f.sparsity_out(1)))
        return self.used_funs[key]

    def curved_hessian(self, rows: np.ndarray):
        """``(function, ccs)``: the Hessian in ``w`` of ``yv^T V[rows]``; made once per set of
        rows."""
        key = tuple(rows.tolist())
        if key not in self.curved_funs:
            yv = ca.SX.sym("yv", len(key))
            Vc = self.V[list(key)]
            f = ca.Function("hess_values", [*self.args, yv], [ca.hessian(ca.dot(yv, Vc), self.w)[0]])
            self.curved_funs[key] = (FastFunction(f), _ccs(f.sparsity_out(0)))
        return self.curved_funs[key]

    def z_dependent(self, nx: int) -> tuple[bool, np.ndarray]:
        """Whether the invariants depend on ``z``, and which rows of ``V`` do."""
        if self.zdep is None:
            zs = self.w[nx:]
            if zs.numel():
                inv_z = bool(self.inv.numel()) and bool(ca.depends_on(self.inv, zs))
                rows, _ = ca.jacobian_sparsity(self.V, zs).get_triplet()
            else:
                inv_z, rows = False, []
            mask = np.zeros(int(self.V.numel()), dtype=bool)
            mask[np.asarray(rows, dtype=np.int64)] = True
            self.zdep = (inv_z, mask)
        return self.zdep


def _system_cache(r) -> _SystemCache:
    return r.derived("initialize", _SystemCache)


#: Plans (:class:`_Plan`) kept per system: the sets of fixed and guessed names of its most
#: recent calls.
_PLANS_PER_SYSTEM = 64


class _Plan:
    """What an :func:`initialize` call's *names* decide, made once per system and set of
    fixed and guessed names (``fixed`` and ``guess`` keys, in order) and kept on the system
    (:attr:`_SystemCache.plans`): a sweep, an ensemble or a user's loop fixes the same names
    in every call, and its later calls only check and place their values. Nothing here
    depends on the values, the parameters, ``t0`` or the inputs.

    Holds: each key's elements; the rows of ``V`` of the fixed values and guesses; the pairs
    of fixed values that are one quantity under two names (``der(p)`` and ``v``: their
    values must agree, checked per call); the row names of the messages; the maps of the
    used rows (unit rows for plain symbols of ``w``, the CasADi function of the rows that are
    expressions); the positions in ``w`` the values start and pin; which curvature terms the
    Newton steps need; the ``z`` solver.
    """

    def __init__(self, r, sc: _SystemCache, fixed_items: list, guess_items: list,
                 fixed_keys: list, guess_keys: list) -> None:
        nx, nz = r.nx, r.nz
        n = nx + nz
        self.fixed_keys, self.guess_keys = fixed_keys, guess_keys
        self.fixed_names = [f[0] for f in fixed_items]
        self.guess_names = [g[0] for g in guess_items]
        self.fix_idx = fix_idx = np.array([f[1] for f in fixed_items], dtype=np.int64)
        self.g_idx = g_idx = np.array([g[1] for g in guess_items], dtype=np.int64)
        sc.describe(np.concatenate([fix_idx, g_idx]))
        # two names for the same quantity (e.g. "der(p)" and "v" after elimination): symbols
        # are compared by their hash (made once per system), other expressions pairwise
        seen: dict[int, int] = {}
        others: list[tuple[int, ca.SX]] = []
        later, earlier = [], []
        for i, ri in enumerate(fix_idx.tolist()):
            hsh = int(sc.sym_hash[ri])
            if hsh != -1:
                j = seen.setdefault(hsh, i)
                pairs = [j] if j != i else []
            else:
                e = sc.elems[ri]
                pairs = [j for j, ej in others if ca.is_equal(e, ej, 2)]
                others.append((i, e))
            later += [i] * len(pairs)
            earlier += pairs
        self.same_later = np.array(later, dtype=np.int64)
        self.same_earlier = np.array(earlier, dtype=np.int64)

        self.n_alg = n_alg = int(sc.alg.numel())
        self.n_inv = int(sc.inv.numel())
        alg_names = r.alg_names
        if not alg_names or len(alg_names) != n_alg:
            alg_names = [f"alg[{i}]" for i in range(n_alg)]
        self.row_names = list(alg_names) + list(r.invariant_names) + self.fixed_names
        self.use_sparse = use_sparse = n >= _SPARSE_MIN_UNKNOWNS

        # the rows of V the fixed values and guesses use, and their Jacobian: unit rows for
        # plain symbols of w, zero rows for other symbols (inputs, parameters), a sparse
        # CasADi Jacobian only for the rows that are expressions
        used, inv_used = (np.unique(np.concatenate([fix_idx, g_idx]), return_inverse=True)
                          if fix_idx.size + g_idx.size else (fix_idx, fix_idx))
        self.fix_k, self.g_k = inv_used[: fix_idx.size], inv_used[fix_idx.size:]
        self.expr_k = expr_k = np.nonzero(sc.sym_hash[used] == -1)[0] if used.size else used
        unit_k = np.nonzero((sc.sym_hash[used] != -1) & (sc.w_pos[used] >= 0))[0] \
            if used.size else used
        self.used_fun = self.used_ccs = self.P_expr = None
        if expr_k.size:
            self.used_fun, self.used_ccs = sc.used_values(used[expr_k])
        if use_sparse:
            self.S_unit = sp.csr_matrix((np.ones(unit_k.size), (unit_k, sc.w_pos[used[unit_k]])),
                                        shape=(used.size, n))
            if expr_k.size:
                self.P_expr = sp.csr_matrix(
                    (np.ones(expr_k.size), (expr_k, np.arange(expr_k.size))),
                    shape=(used.size, expr_k.size))
        else:  # small systems: dense NumPy throughout (no sparse objects: 75 us a call)
            S_unit = np.zeros((used.size, n))
            S_unit[unit_k, sc.w_pos[used[unit_k]]] = 1.0
            S_unit.flags.writeable = False  # shared by the calls of this plan
            self.S_unit = S_unit
            if expr_k.size:
                P_expr = np.zeros((used.size, expr_k.size))
                P_expr[expr_k, np.arange(expr_k.size)] = 1.0
                P_expr.flags.writeable = False
                self.P_expr = P_expr

        # where the values go in w: the start takes the guesses, then the fixed values (the
        # later of two for one position), and the fixed values are pinned at the end
        def last_of(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            pos = sc.w_pos[rows] if rows.size else np.zeros(0, dtype=np.int64)
            last: dict[int, int] = {}
            for i, k in enumerate(pos.tolist()):
                if k >= 0:
                    last[k] = i
            return (np.array(list(last), dtype=np.int64),
                    np.array(list(last.values()), dtype=np.int64))

        self.start_pos, self.start_src = last_of(np.concatenate([g_idx, fix_idx]))
        self.given = np.zeros(n, dtype=bool)
        self.given[self.start_pos] = True
        self.pin_pos, self.pin_src = last_of(fix_idx)

        # rows that the guesses and fixed values use and that are not plain symbols (those
        # have curvature); with z the curvature of alg matters only where some used row (or
        # an invariant) depends on z: otherwise alg's multipliers vanish at the solution
        self.curved = used[sc.sym_hash[used] == -1] if used.size else used
        inv_z, v_z = sc.z_dependent(nx)
        self.with_alg = bool(nz) and (inv_z or bool(np.any(v_z[used])) if used.size else inv_z)
        self.decoupled = bool(nz) and n_alg == nz and not self.with_alg
        self.z_solve = None
        if nz and n_alg == nz:
            key = bool(use_sparse)
            if key not in sc.settle:
                sc.settle[key] = _z_solver(sc, nx, use_sparse)
            self.z_solve = sc.settle[key]


def _checked_array(keys: list, values: Mapping, what: str) -> np.ndarray:
    """The values of ``keys`` (a plan's ``(name, elements)`` pairs), checked and concatenated
    in the plan's element order."""
    parts = [checked_values(len(el), el, k, values[k], what) for k, el in keys]
    return np.concatenate(parts) if parts else np.zeros(0)


def _named_items(r, sc: _SystemCache, values: Mapping, what: str
                 ) -> tuple[list[tuple[str, int, float]], list]:
    """``(items, keys)`` of a mapping of names to values: its ``(element name, row, value)``
    items and its ``(name, element names)`` pairs, the plan's order of the values."""
    items: list[tuple[str, int, float]] = []
    keys = []
    for k, v in values.items():
        got = _name_values(r, k, v, what, sc.row_of, sc.names_of)
        items += got
        keys.append((k, [g[0] for g in got]))
    return items, keys


def _plan_for(r, sc: _SystemCache, fixed: Mapping, guess: Mapping
              ) -> tuple[_Plan, np.ndarray, np.ndarray]:
    """``(plan, fixed values, guessed values)`` of a call: the plan of its names (made on the
    first call with these names, with the first call's checks and messages), the values as
    arrays in the plan's element order, checked."""
    key = (tuple(fixed), tuple(guess))
    plan = sc.plans.get(key)
    if plan is not None:
        return (plan, _checked_array(plan.fixed_keys, fixed, "fixed"),
                _checked_array(plan.guess_keys, guess, "guess"))
    fixed_items, fixed_keys = _named_items(r, sc, fixed, "fixed")
    guess_items, guess_keys = _named_items(r, sc, guess, "guess")
    dup = {nm for nm, c in Counter(f[0] for f in fixed_items).items() if c > 1}
    if dup:
        raise InitializationError(f"fixed: {sorted(dup)} given more than once")
    plan = _Plan(r, sc, fixed_items, guess_items, fixed_keys, guess_keys)
    if len(sc.plans) >= _PLANS_PER_SYSTEM:
        sc.plans.pop(next(iter(sc.plans)))
    sc.plans[key] = plan
    return (plan, np.array([f[2] for f in fixed_items], dtype=float),
            np.array([g[2] for g in guess_items], dtype=float))


def _fmt(names_vals: list[tuple[str, float]]) -> str:
    return ", ".join(f"{n} = {v:g}" for n, v in names_vals)


@limit_blas_threads
def initialize(
    r,
    t0: float = 0.0,
    guess: Mapping | None = None,
    fixed: Mapping | None = None,
    inputs: Mapping | None = None,
    params: Mapping | None = None,
    tol: float = 1e-12,
    max_iter: int = 100,
) -> InitialValues:
    """Consistent initial values: ``alg = 0`` and every invariant hold, ``fixed`` values exactly.

    Parameters
    ----------
    r : ReducedDAE
        A Model or LagrangianSystem is reduced automatically (see
        :func:`daekit.reduction.as_reduced`; ``init.notes`` says how).
    t0 : float
        Initial time (invariants and inputs may depend on time).
    guess : dict, optional
        ``{name: value}`` pulled to in the least-squares sense (names of the original model:
        ``"p"``, ``"p[0]"``, ``"der(p)"``, ``"z"``). Unguessed states start at 0.
    fixed : dict, optional
        ``{name: value}`` held exactly. Fix at most the dynamic degrees of freedom
        (``InitialValues.free`` shows one valid choice); values implied by the others are
        accepted when consistent, and a contradiction raises :class:`InitializationError`
        naming the fixed values and consistency conditions in conflict.
    inputs, params : dict, optional
        As for :func:`daekit.simulate` (input values and derivatives at ``t0`` enter the
        invariants).
    tol : float
        Required max |residual| (scaled by ``1 + |values|``).

    Method: Newton--Lagrange steps (Gauss--Newton plus the constraints' curvature) with CasADi
    derivatives, ``z`` re-solved from ``alg`` after each step, dense NumPy for small systems and
    sparse SuperLU factorizations from 300 unknowns on (see the module docstring); no IPOPT
    needed. A start that is consistent already and meets every guess (every state fixed to
    consistent values, as in a sweep over initial states) takes no step (``iterations`` 0).
    What depends only on ``r`` is computed once and cached on it.

    Example
    -------
    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> from daekit.initialize import initialize
    >>> t = ca.SX.sym("t"); p = ca.SX.sym("p", 2); v = ca.SX.sym("v", 2); T = ca.SX.sym("T")
    >>> acc = T * p - ca.vertcat(0, 9.81)          # planar pendulum, index-1 form
    >>> alg = ca.dot(p, acc) + ca.dot(v, v)          # second derivative of the rod constraint
    >>> names = {"p[0]": p[0], "p[1]": p[1], "v[0]": v[0], "v[1]": v[1], "T": T}
    >>> r = ReducedDAE(t, ca.vertcat(p, v), T, ca.SX(0, 1), ca.SX(0, 1), ca.vertcat(v, acc),
    ...     alg, ca.vertcat((ca.dot(p, p) - 1) / 2, ca.dot(p, v)), ["rod", "d/dt rod"],
    ...     ["p[0]", "p[1]", "v[0]", "v[1]"], ["T"], [], [], np.zeros(0), names)
    >>> init = initialize(r, guess={"p": [0.9, 0.1]}, fixed={"v[0]": 0.0})
    >>> bool(abs(np.linalg.norm(init["p"]) - 1) < 1e-12), init.dof
    (True, 2)
    >>> init.fixed, len(init.free)        # one more value (e.g. p[1]) could be fixed
    (['v[0]'], 1)
    """
    from .inputs import resolve_params, signal_for
    from .reduced import ReducedDAE

    notes: list[str] = []
    if not isinstance(r, ReducedDAE):  # a Model or LagrangianSystem: reduced (and noted)
        from .reduction.accept import as_reduced

        r = as_reduced(r, "initialize", notes=notes)
        out = initialize(r, t0, guess=guess, fixed=fixed, inputs=inputs, params=params,
                         tol=tol, max_iter=max_iter)
        out.notes = notes + out.notes
        return out
    base = r.origin if r.index >= 2 else None
    if base is not None:
        # an index-2 form (GGL): alg = 0 leaves its multipliers underdetermined; initialize
        # the index-1 system it came from (same x, z first) and set the GGL multipliers mu = 0
        b = initialize(base, t0, guess=guess, fixed=fixed, inputs=inputs, params=params,
                       tol=tol, max_iter=max_iter)
        extra = list(r.z_names[len(base.z_names):])
        return dataclasses.replace(
            b,
            z0=np.concatenate([b.z0, np.zeros(len(extra))]),
            z_names=list(r.z_names),
            values={**b.values, **dict.fromkeys(extra, 0.0)},
        )

    try:
        t0 = float(t0)
    except (TypeError, ValueError):
        raise InitializationError(f"initialize: t0 must be a number, got {t0!r}") from None
    if not math.isfinite(t0):
        raise InitializationError(f"initialize: t0 must be a finite number, got {t0!r}")
    pv = resolve_params(r, params)
    sc = _system_cache(r)
    nx, nz = sc.nx, sc.nz
    n = nx + nz
    sig = signal_for(r, inputs)  # the default inputs (zero): made once per system
    u0 = sig.value(t0)

    args = (t0, u0, pv)

    for what, given in (("fixed", fixed), ("guess", guess)):
        if given is not None and not isinstance(given, Mapping):
            raise InitializationError(
                f"{what} must be a dict of names and values, e.g. {{'p[0]': 1.0}}, "
                f"got {type(given).__name__}"
            )
    # what the *names* decide (rows, index arrays, functions of the used rows, which
    # quantities are the same): made once per set of fixed and guessed names, kept on the
    # system; this call only checks and places its values
    plan, fix_val, gval = _plan_for(r, sc, fixed or {}, guess or {})
    fixed_names = plan.fixed_names
    fix_idx, g_idx = plan.fix_idx, plan.g_idx
    if plan.same_later.size:
        # two names of one quantity (e.g. "der(p)" and "v" after elimination) must agree
        vi, vj = fix_val[plan.same_later], fix_val[plan.same_earlier]
        bad = np.nonzero(np.abs(vi - vj) > 1e-12 * (1 + np.abs(vi)))[0]
        if bad.size:
            k = int(bad[0])
            ni, nj = fixed_names[plan.same_later[k]], fixed_names[plan.same_earlier[k]]
            raise InitializationError(
                f"initialize: the fixed values {nj} = {vj[k]:g} and {ni} = {vi[k]:g} "
                "contradict each other: in this system both are the same quantity; fix only one"
            )

    n_alg, n_inv = plan.n_alg, plan.n_inv
    row_names = plan.row_names
    use_sparse = plan.use_sparse
    fix_k, g_k, expr_k = plan.fix_k, plan.g_k, plan.expr_k
    used_fun, used_ccs = plan.used_fun, plan.used_ccs
    S_unit, P_expr = plan.S_unit, plan.P_expr

    def fixed_items() -> list[tuple[str, int, float]]:
        """(element name, row of V, value) of each fixed value (for the messages)."""
        return list(zip(fixed_names, fix_idx.tolist(), fix_val.tolist(), strict=True))

    last_v: list = [None, None]  # the last point V was evaluated at (a copy), and V there

    def values_and_jac(wv, jac: bool = True):
        """All named values at ``wv``, and the Jacobian of the used rows (CSR, or dense on
        the dense path)."""
        Vv = sc.v_fun(wv, *args)[0]
        last_v[0], last_v[1] = wv.copy(), Vv
        if not jac:
            return Vv, None
        if expr_k.size:
            _, Je = used_fun(wv, *args)
            if not use_sparse:
                return Vv, S_unit + P_expr @ _to_dense(Je, used_ccs)
            return Vv, (S_unit + P_expr @ _to_csc(Je, used_ccs)).tocsr()
        return Vv, S_unit

    def gfun(wv):
        """Guessed values and their Jacobian (sparse CSC, or dense on the dense path)."""
        Vv, JU = values_and_jac(wv)
        return Vv[g_idx], (JU[g_k].tocsc() if use_sparse else JU[g_k])

    # starting point: x, z from guesses/fixed values that name them directly, else 0
    w0 = np.zeros(n)
    given = plan.given
    if plan.start_pos.size:
        w0[plan.start_pos] = np.concatenate([gval, fix_val])[plan.start_src]
    # z is a function of x wherever d alg / d z is nonsingular (index 1): after every step it
    # is re-solved from alg at the new x, so that the iteration is Gauss-Newton on x alone
    # (quadratic from a rough guess; a joint step on (x, z) is spoiled by the bilinear terms
    # such as lam * q of mechanical systems)
    settled = {"ok": False}
    if nz and n_alg == nz:
        z_solve = plan.z_solve

        def settle(wv):
            out = z_solve(wv, args)
            settled["ok"] = out is not wv  # False where d alg / d z was singular (unchanged)
            return out
    else:
        def settle(wv):
            return wv
    w0 = settle(w0)
    metric_nx = nx if (nz and n_alg == nz) else n

    def hval(wv):
        c, *Jparts = sc.core_fun(wv, *args)
        Jc = sc.core_nonzeros(Jparts)
        Vv, JU = values_and_jac(wv)
        hv = np.concatenate([c, Vv[fix_idx] - fix_val])
        if use_sparse:
            return hv, sp.vstack([_to_csc(Jc, sc.core_ccs), JU[fix_k]], format="csc")
        return hv, np.vstack([_to_dense(Jc, sc.core_ccs), JU[fix_k]])

    def jac_finite(J) -> bool:
        return bool(np.isfinite(J.data if sp.issparse(J) else J).all())

    scale = 1.0 + np.abs(np.concatenate([fix_val, gval, [0.0]])).max()

    def objective(wv) -> float:
        if not gval.size:
            return 0.0
        return 0.5 * float(np.sum((values_and_jac(wv, False)[0][g_idx] - gval) ** 2))

    curved, with_alg, decoupled = plan.curved, plan.with_alg, plan.decoupled

    def gfun_x(_wx):
        """The guesses' values and Jacobian on x (decoupled steps; evaluated at the current
        full point, set by the loop)."""
        Gv, JG = gfun(current["w"])
        return Gv, JG[:, :nx]

    current: dict = {}

    def curvature(wv, y):
        """Curvature of the Lagrangian ``f + y^T h`` beyond Gauss--Newton's ``J_G^T J_G``:
        ``sum y_i h_i'' + sum (G_j - guess_j) G_j''`` (sparse; the CasADi functions are made on
        first use, the invariants' once per system). Without it Gauss--Newton is slow or
        diverges where the constraints are curved and the guesses off them (a 200-link chain
        from 1 cm off: the rods' multipliers are large), with it the iteration is Newton's on
        the KKT conditions."""
        conv = _to_csc if use_sparse else _to_dense
        H = sp.csc_matrix((n, n)) if use_sparse else np.zeros((n, n))
        if n_inv:
            f, ccs = sc.hessian("inv")
            H = H + conv(f(wv, *args, y[n_alg:n_alg + n_inv])[0], ccs)
        if with_alg and n_alg:
            f, ccs = sc.hessian("alg")
            H = H + conv(f(wv, *args, y[:n_alg])[0], ccs)
        if curved.size:
            f, ccs = sc.curved_hessian(curved)
            yv = np.zeros(int(sc.V.numel()))
            np.add.at(yv, fix_idx, y[n_alg + n_inv:])
            np.add.at(yv, g_idx, values_and_jac(wv, False)[0][g_idx] - gval)
            H = H + conv(f(wv, *args, yv[curved])[0], ccs)
        return H.tocsc() if use_sparse else H

    def scales(J):
        """Row and column factors of ``J`` (:func:`daekit.numerics.equilibrate`): the step,
        the line search and the convergence test work on ``diag(dr) h`` and ``w / dc``, so
        that units of equations and variables (1e-6 .. 1e6) change neither the steps' rank
        decisions nor when the iteration stops."""
        if not J.shape[0] or not n or use_sparse:
            # the sparse path (from 300 unknowns) keeps the model's coordinates: there the
            # KKT step's proximal term and SuperLU's pivoting already tolerate the scales,
            # and re-equilibrating every iterate cost a 1000-link chain 16 iterations (was <= 12)
            return np.ones(J.shape[0]), np.ones(n)
        dr, dc = equilibrate(J)
        return dr, dc

    def small(hv, wv, J, rtol) -> bool:
        """Every residual is below ``rtol`` times the size of the terms of its row,
        ``|h_i| <= rtol sum_j |J_ij w_j|`` (plus ``1e-30``): invariant under the units of
        equations and variables, and row by row (a tolerance relative to the largest value
        would let rows of small terms stop early: values off by 1e-6)."""
        if not hv.size:
            return True
        Ja = abs(J) if sp.issparse(J) else np.abs(J)
        terms = np.asarray(Ja @ np.abs(wv), dtype=float).ravel()
        return bool((np.abs(hv) <= rtol * terms + 1e-30).all())

    def scaled_step(kind, dec_k, hv, J, wv, y, dr, dc):
        """The (Gauss-)Newton step in the equilibrated coordinates ``u = w / dc`` and rows
        ``dr h``, mapped back: ``(d, y)`` in the model's units."""
        C = curvature(wv, y) if kind == "newton" else None
        if dec_k:
            rx, cx = dr[n_alg:], dc[:nx]
            Jx = J[n_alg:, :nx]
            if use_sparse:
                Jx = (sp.diags(rx) @ Jx @ sp.diags(cx)).tocsc()
                Cx = (sp.diags(cx) @ C[:nx, :nx] @ sp.diags(cx)).tocsc() if C is not None \
                    else None
            else:
                Jx = Jx * rx[:, None] * cx[None, :]
                Cx = C[:nx, :nx] * cx[:, None] * cx[None, :] if C is not None else None
            hx = rx * hv[n_alg:]

            def gx(_u):
                Gv, JG = gfun_x(None)
                return Gv, (JG @ sp.diags(cx)).tocsc() if use_sparse else JG * cx[None, :]

            if use_sparse:
                du, yx = _gn_step_sparse(hx, Jx, gx, wv[:nx] / cx, gval, nx, Cx)
            else:
                du, yx = _gn_step(hx, Jx, gx, wv[:nx] / cx, gval, nx, 0, Cx)
            return (np.concatenate([cx * du, np.zeros(nz)]),
                    np.concatenate([np.zeros(n_alg), rx * yx]))

        def gs(_u):
            Gv, JG = gfun(wv)
            return Gv, (JG @ sp.diags(dc)).tocsc() if use_sparse else JG * dc[None, :]

        if use_sparse:
            Js = (sp.diags(dr) @ J @ sp.diags(dc)).tocsc()
            Cs = (sp.diags(dc) @ C @ sp.diags(dc)).tocsc() if C is not None else None
            du, ys = _gn_step_sparse(dr * hv, Js, gs, wv / dc, gval, metric_nx, Cs)
        else:
            Js = J * dr[:, None] * dc[None, :]
            Cs = C * dc[:, None] * dc[None, :] if C is not None else None
            du, ys = _gn_step(dr * hv, Js, gs, wv / dc, gval, metric_nx, n_alg, Cs)
        return dc * du, dr * ys

    def gauss_newton(wv):
        """Damped (Gauss-)Newton from ``wv``: (point, residual, Jacobian, converged, iterations).

        With guesses, from the second iteration on the step includes the curvature of the
        Lagrangian at the last multipliers (Newton-Lagrange, SQP); a step that the line search
        cuts below 1/8 is replaced by the Gauss-Newton step. A trial point is accepted when it
        reduces ``||dr h||`` sufficiently or the exact penalty ``f + rho ||dr h||_1``
        (``rho = 2 max |y / dr| + 1``). Steps, norms and the stopping test are in the
        equilibrated coordinates of :func:`scales` (recomputed at every iterate)."""
        it = 0
        hv, J = hval(wv)
        fv = objective(wv)
        if (fv == 0.0 and np.isfinite(hv).all() and jac_finite(J)
                and small(hv, wv, J, tol)):
            # the start is consistent already and meets every guess (all states fixed and
            # consistent, as in a sweep over initial states): a step could only move it by
            # rounding, and would cost a factorization and a line search
            return wv, hv, J, True, 0
        y = None
        history: list[float] = []
        for it in range(1, max_iter + 1):  # noqa: B007
            if not np.all(np.isfinite(hv)) or not jac_finite(J):
                bad = [row_names[i] for i in np.where(~np.isfinite(hv))[0]][:5]
                raise InitializationError(
                    f"initialize: the equations {bad or '(Jacobian)'} are not finite at the "
                    "current point; give guesses closer to a consistent state"
                )
            dr, dc = scales(J)
            use_c = gval.size and y is not None and np.any(y)
            normh = np.linalg.norm(dr * hv)
            stop = tol * (1.0 + float(np.max(np.abs(wv / dc), initial=0.0)))
            # decoupled: neither the invariants nor the used values depend on z, and alg holds
            # (z was re-solved): the step is found on x alone, without alg's rows (the
            # densest) and z's columns in the KKT system; z follows by re-solving alg
            dec = (decoupled and settled["ok"]
                   and small(hv[:n_alg], wv, J[:n_alg], 1e-8))
            current["w"] = wv
            # first choice, then the fallback when the line search cuts it below 1/8: the
            # joint Gauss-Newton step on (x, z)
            first = ("newton" if use_c else "gn", dec)
            candidates = [first] if first == ("gn", False) else [first, ("gn", False)]
            for kind, dec_k in candidates:
                d, yn = scaled_step(kind, dec_k, hv, J, wv, y, dr, dc)
                rho = 2.0 * float(np.max(np.abs(yn / dr), initial=0.0)) + 1.0
                phi = fv + rho * float(np.sum(np.abs(dr * hv)))
                alpha = 1.0
                for _ in range(30):
                    wn = settle(wv + alpha * d)
                    hn, Jn = hval(wn)
                    if np.all(np.isfinite(hn)):
                        nh = np.linalg.norm(dr * hn)
                        if nh <= max(normh * (1 - 1e-4 * alpha), stop) or alpha < 1e-3:
                            break
                        if gval.size and objective(wn) + rho * float(
                                np.sum(np.abs(dr * hn))) < phi:
                            break
                    alpha *= 0.5
                if alpha >= 0.125:
                    break
            y = yn
            # the last step, relative to each value (its own scale where it is zero)
            step = (float(np.max(np.abs(wn - wv) / (np.abs(wn) + np.abs(dc) * 1e-3)))
                    if n else 0.0)
            if not np.all(np.isfinite(hn)) or np.linalg.norm(dr * hn) > 1e3 * max(normh, 1.0):
                break  # diverging: analyse the best point reached
            wv, hv, J = wn, hn, Jn
            fv = objective(wv)
            # converged: the last step is negligible against every value, and every residual
            # is negligible against the terms of its row, or (rows whose terms are rounding
            # residue or that no free unknown moves: all values of a chain fixed) the
            # equilibrated residual is below the stopping level
            if step <= 1e-9 and (small(hv, wv, J, tol)
                                 or np.linalg.norm(dr * hv) <= 1e-3 * stop):
                return wv, hv, J, True, it
            history.append(float(np.linalg.norm(dr * hv)))
            if len(history) > 10 and history[-1] > 0.999 * history[-10] and history[-1] > 1e-6:
                break  # stagnating far from zero: inconsistent
        return wv, hv, J, False, it

    def inconsistent(wv, hv, J) -> bool:
        """The residual at the end is not negligible in the equilibrated coordinates."""
        if not np.all(np.isfinite(hv)):
            return True
        return not small(hv, wv, J, 1e-8)

    wv, hv, J, converged, it = gauss_newton(w0.copy())
    if not converged and inconsistent(wv, hv, J) and not given.all():
        # The default start (0 for values nobody gave) can be a singular point of the
        # constraints (p = 0 for a rod): try once from a generic point before giving up.
        rng = np.random.default_rng(0)
        w1 = w0.copy()
        w1[~given] += rng.uniform(0.1, 0.3, int((~given).sum()))
        w1 = settle(w1)
        second = gauss_newton(w1)
        if second[3]:
            wv, hv, J, converged, it = second
    res = float(np.max(np.abs(hv), initial=0.0))
    if not converged and inconsistent(wv, hv, J):
        # which conditions the fixed values break: evaluated with every fixed state or
        # algebraic value held exactly (z re-solved), the rest at the least-squares point
        held = wv.copy()
        held[plan.pin_pos] = fix_val[plan.pin_src]
        try:
            hv_held = np.asarray(hval(settle(held))[0], dtype=float)
        except Exception:  # noqa: BLE001 - only a better message is at stake
            hv_held = None
        _raise_conflict(hv, J, row_names, n_alg, n_inv, fixed_items(), res, it,
                        hv_held)

    # fixed values of states / algebraic unknowns themselves are held to the last bit (the
    # iteration leaves them within rounding of the value)
    wv[plan.pin_pos] = fix_val[plan.pin_src]
    wf = wv.copy()

    def dof_analysis() -> dict:
        """Free states, redundant fixed values, determined states (deferred: made on first
        access to any of them)."""
        Jd = J
        found = None
        if use_sparse:
            # free states and redundant fixed values from a sparse basis of the consistency
            # rows
            found = _sparse_free_redundant(Jd, n_alg, n_inv, nx, list(r.x_names), fixed_names)
            if found is None:  # degenerate (rank-deficient) consistency rows: dense analysis
                Jd = Jd.toarray()
        if found is not None:
            free, redundant = found
        else:
            # redundant fixed values: rows of J dependent on the rows before them
            redundant = _dependent_fixed(Jd, n_alg + n_inv, fixed_names)
            free = _free_states(r, Jd[: n_alg + n_inv], nx, set(fixed_names))
        determined, notes = [], []
        if not use_sparse and fixed_names:
            pinned = set(plan.pin_pos.tolist())
            determined, notes = _determined(r, wf, Jd, hval, scale, set(fixed_names), pinned,
                                            set(plan.guess_names))
        # one choice of the dynamic degrees of freedom (the fixed states preferred), in state
        # order; the free values are those of it that were not fixed (also under another
        # name)
        dof_names = [nm for nm in r.x_names if nm in free]
        fixed_x = {k for k in plan.pin_pos.tolist() if k < nx}
        free_only = [nm for i, nm in enumerate(r.x_names) if nm in free and i not in fixed_x]
        return {"free": free_only, "dof": len(dof_names), "dof_names": dof_names,
                "redundant": redundant, "determined": determined, "notes": notes}

    x0, z0 = wv[:nx].copy(), wv[nx:].copy()
    # every named value at the result: those of the last evaluation where that was the point
    # itself (a consistent start: the only one), else evaluated
    Vv = last_v[1] if last_v[0] is not None and np.array_equal(last_v[0], wv) else \
        values_and_jac(wv, False)[0]
    values = dict(zip(sc.names, Vv.tolist(), strict=True))
    cons = float(np.max(np.abs(hv[: n_alg + n_inv]), initial=0.0))
    return InitialValues(
        t0, x0, z0, u0, pv, values, [], 0, [], cons, it,
        list(r.x_names), list(r.z_names), fixed=list(fixed_names), dof_names=[],
        determined=[], notes=[], _deferred=dof_analysis,
    )


def _other_sign(wv, i: int, hval, scale: float, iters: int = 12) -> bool:
    """Whether the equations ``hval(w) = 0`` also hold with ``w[i] = -wv[i]`` (the other
    values re-solved by a few minimum-norm Gauss--Newton steps from the flipped point)."""
    w = wv.copy()
    w[i] = -wv[i]
    last, stalled = np.inf, 0
    for _ in range(iters):
        hv, J = hval(w)
        if not (np.all(np.isfinite(hv)) and np.all(np.isfinite(J))):
            return False
        if np.max(np.abs(hv), initial=0.0) <= 1e-10 * scale:
            return True
        # full minimum-norm steps that leave the residual where it was twice running: the
        # rest cannot hold with the flipped value (a fixed value of that very quantity)
        nh = float(np.linalg.norm(hv))
        stalled = stalled + 1 if nh >= (1 - 1e-3) * last else 0
        if stalled >= 2:
            return False
        last = nh
        J = np.array(J, dtype=float)
        J[:, i] = 0.0  # w[i] stays at the flipped value
        d = np.linalg.lstsq(J, -hv, rcond=1e-12)[0]
        d[i] = 0.0
        w = w + d
    return False


def _determined(r, wv, J, hval, scale, fixed: set[str], pinned: set[int], guessed: set[str]):
    """States (and dummy states) not fixed but locally determined: their unit vectors are
    orthogonal to the null space of the Jacobian of ``[alg; invariants; fixed]``. A determined
    value whose negative satisfies the equations too (a quaternion component from
    ``|q| = 1``) is noted: the sign of the guess (or of the start) decided it. ``pinned``:
    positions in ``w`` that a fixed value holds directly (under another name, e.g. ``v[0]``
    by ``der(p)[0]``): their other sign breaks that fixed value, no search needed."""
    J = np.asarray(J, dtype=float)
    if J.size == 0:
        return [], []
    nx = r.nx
    dummies = set((r.state_selection or {}).get("dummies", []))
    cand = [(i, nm) for i, nm in enumerate(r.x_names)] + [
        (nx + j, nm) for j, nm in enumerate(r.z_names) if nm in dummies]
    _, sv, vt = np.linalg.svd(J, full_matrices=True)
    rank = int(np.sum(sv > 1e-9 * max(sv.max(initial=0.0), 1e-300)))
    N = vt[rank:]
    determined, notes = [], []
    for i, nm in cand:
        if nm in fixed or (N.shape[0] and np.linalg.norm(N[:, i]) > 1e-8):
            continue
        determined.append(nm)
        v = float(wv[i])
        if abs(v) <= 1e-9 * scale or i in pinned:
            continue
        if _other_sign(wv, i, hval, scale):
            whose = "the guess" if nm in guessed else "the starting point"
            notes.append(
                f"{nm} = {v:.6g} is determined only up to its sign: {-v:.6g} satisfies the "
                f"fixed values and the consistency conditions too; the sign of {whose} was "
                "taken (give a guess of the other sign for the other branch)"
            )
    return determined, notes


def _qp_min_norm(A, h, H, g) -> np.ndarray:
    """``argmin d^T H d / 2 + g^T d`` subject to ``A d = -h`` (least squares where
    inconsistent), the minimum-norm choice among equals: the minimum-norm particular step
    (SVD of ``A``) plus a least-squares step in its null space. ``H = None``: ``d`` is the
    minimum-norm solution of the constraints alone."""
    n = A.shape[1]
    if A.shape[0]:
        U, S, Vt = np.linalg.svd(A, full_matrices=True)
        k = int(np.sum(S > 1e-11 * max(S[0], 1e-300))) if S.size else 0
        dp = -(Vt[:k].T @ ((U[:, :k].T @ h) / S[:k]))
        N = Vt[k:].T
    else:
        dp = np.zeros(n)
        N = np.eye(n)
    if H is not None and N.shape[1]:
        M = N.T @ H @ N
        lam, Q = np.linalg.eigh(0.5 * (M + M.T))
        # directions of the null space where the objective has curvature, relative to the
        # scale of H itself (not of the reduced matrix: where the guesses do not reach a
        # direction, e.g. velocities when only positions are guessed, its curvature is
        # rounding residue, which a relative cutoff would invert into huge steps); negative
        # curvature (the constraints' curvature times multipliers of either sign) is no
        # step direction either
        keep = lam > 1e-12 * float(np.abs(H).max())
        Qk = Q[:, keep]
        y = Qk @ ((Qk.T @ -(N.T @ (H @ dp + g))) / lam[keep])
        return dp + N @ y
    return dp


def _gn_step(hv, J, gfun, wv, gval, nx=None, n_alg=0, C=None):
    """The dense (Gauss--)Newton step and the constraints' multipliers ``(d, y)``.

    ``min (G + J_G d - guess)^2 / 2 + d^T C d / 2`` s.t. ``h + J d = 0``, ties broken by the
    smallest ``||d_x||``; ``C`` is the curvature of the Lagrangian (``sum y_i h_i''`` and the
    guesses' own curvature; ``None``: Gauss--Newton). With ``nx < n`` the first
    ``n_alg = n - nx`` rows are ``alg``, solvable for ``d_z`` (``A_z`` nonsingular):
    ``d_z = -A_z^{-1} (h_a + A_x d_x)`` is eliminated and the step is found in ``x`` alone
    (z is a function of x); where ``A_z`` is singular, on ``w = (x, z)`` jointly. The
    multipliers solve ``J^T y = -(grad f + H d)`` in the least-squares sense."""
    n = wv.size
    nx = n if nx is None else nx
    H = gradf = None
    if gval.size:
        Gv, JG = gfun(wv)
        gradf = JG.T @ (np.asarray(Gv, dtype=float).ravel() - gval)
        H = JG.T @ JG
        if C is not None:
            H = H + (C.toarray() if sp.issparse(C) else C)
    d = None
    if nx < n and n_alg == n - nx:
        Az, Ax = J[:n_alg, nx:], J[:n_alg, :nx]
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
                lu = scipy.linalg.lu_factor(Az, check_finite=True)
            rc = 1.0 / max(np.linalg.cond(Az, 1), 1e-300)
        except (ValueError, np.linalg.LinAlgError, scipy.linalg.LinAlgWarning):
            rc = 0.0
        if rc > 1e-13:
            T = -scipy.linalg.lu_solve(lu, Ax)
            t0 = -scipy.linalg.lu_solve(lu, hv[:n_alg])
            R = J[n_alg:]
            Rx = R[:, :nx] + R[:, nx:] @ T
            hr = hv[n_alg:] + R[:, nx:] @ t0
            if H is not None:
                P = np.vstack([np.eye(nx), T])
                p0 = np.concatenate([np.zeros(nx), t0])
                Hx, gx = P.T @ H @ P, P.T @ (H @ p0 + gradf)
            else:
                Hx = gx = None
            dx = _qp_min_norm(Rx, hr, Hx, gx)
            d = np.concatenate([dx, T @ dx + t0])
    if d is None:
        d = _qp_min_norm(J, hv, H, gradf)
    if H is None or not J.shape[0]:
        return d, np.zeros(J.shape[0])
    y = np.linalg.lstsq(J.T, -(gradf + H @ d), rcond=1e-12)[0]
    return d, y


def _z_solver(sc: _SystemCache, nx: int, sparse: bool, iters: int = 12):
    """``settle(w, (t, u, p))``: ``w`` with its ``z`` part re-solved from ``alg(x, z) = 0`` at
    fixed ``x``
    (Newton with SuperLU or dense LU on ``d alg / d z``; one step when ``alg`` is affine in
    ``z``, as for mechanical systems). Where ``d alg / d z`` is singular or Newton does not
    converge, ``w`` is returned unchanged (the joint step stands). Small (dense) systems take
    ``alg`` and ``d alg / dz`` from the system's ``core_fun`` (one CasADi function fewer to
    make; evaluating the invariants beside them costs microseconds); big ones have a function
    of their own (evaluating a 1000-link chain's invariants at every settle cost a repeated
    initialization 7 % more than making the function once)."""
    zs = sc.w[nx:]
    affine = not ca.depends_on(sc.Jz, zs)
    n_alg = int(sc.alg.numel())
    if sparse:
        own = FastFunction(ca.Function("alg_z", list(sc.args), [sc.alg, sc.Jz]))
        ccs = _ccs(own.f.sparsity_out(1))
        afun = own
    else:
        # d alg / dz: the columns nx: of d alg / dw, contiguous in its CCS order
        colind, row, shape, _ = _ccs(sc.jacobians["alg"].sparsity())
        start = int(colind[nx])
        z_colind = colind[nx:] - start
        ccs = (z_colind, row[start:], (shape[0], shape[1] - nx),
               major_index(z_colind))

        def afun(wv, *vals):
            c, Ja, *_ = sc.core_fun(wv, *vals)
            return c[:n_alg], Ja[start:]
    count = 1 if affine else iters
    scalar = not sparse and int(zs.numel()) == 1 and n_alg == 1

    def settle_scalar(wv: np.ndarray, vals) -> np.ndarray:
        """One algebraic unknown (small systems): Python floats, no LAPACK call."""
        w1 = np.array(wv, dtype=float)
        g0 = None
        for _ in range(count):
            g, A = afun(w1, *vals)
            gv, a = float(g[0]), float(A[0]) if A.size else 0.0
            if not (math.isfinite(gv) and math.isfinite(a)):
                return wv
            ng = abs(gv)
            if g0 is None:
                g0 = ng
            elif ng > 2 * g0:
                return wv  # Newton diverging: keep the joint step
            if a == 0.0:
                return wv  # z is not determined by alg here (singular)
            if ng == 0.0:
                break
            dz = -gv / a
            w1[nx] += dz
            if abs(dz) <= 1e-13 * (1.0 + abs(w1[nx])):
                break
        return w1

    def settle(wv: np.ndarray, vals) -> np.ndarray:
        w1 = np.array(wv, dtype=float)
        g0 = None
        for _ in range(count):
            g, A = afun(w1, *vals)
            A = _to_csc(A, ccs) if sparse else _to_dense(A, ccs)
            if not (np.all(np.isfinite(g)) and np.all(np.isfinite(A.data if sparse else A))):
                return wv
            ng = float(np.max(np.abs(g), initial=0.0))
            if g0 is None:
                g0 = ng
            elif ng > 2 * g0:
                return wv  # Newton diverging: keep the joint step
            if ng == 0.0 and not sparse and np.linalg.cond(A) > 1e12:
                return wv  # alg holds, but z is not determined by it here (singular)
            if ng == 0.0:
                break
            try:
                if sparse:
                    dz = sp.linalg.splu(A.tocsc()).solve(-g)
                else:
                    with warnings.catch_warnings():
                        warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
                        dz = scipy.linalg.solve(A, -g, check_finite=False)
            except (RuntimeError, np.linalg.LinAlgError, ValueError,
                    scipy.linalg.LinAlgWarning):
                return wv
            if not np.all(np.isfinite(dz)):
                return wv
            w1[nx:] += dz
            if np.max(np.abs(dz)) <= 1e-13 * (1.0 + np.max(np.abs(w1[nx:]))):
                break
        return w1

    return settle_scalar if scalar else settle


def _ccs(pattern: ca.Sparsity) -> tuple[np.ndarray, np.ndarray, tuple[int, int], np.ndarray]:
    """The CCS pattern of a CasADi output: ``(colind, row, shape, col)`` (``col``: the column
    of each nonzero)."""
    colind, row = pattern.get_ccs()
    colind = np.asarray(colind, dtype=np.int64)
    col = major_index(colind)
    return (colind, np.asarray(row, dtype=np.int64), (pattern.size1(), pattern.size2()), col)


def _stacked_ccs(patterns: list[ca.Sparsity]):
    """``(ccs, dest)``: the :func:`_ccs` of the patterns stacked vertically (same number of
    columns) and, per pattern, the position of each of its nonzeros in the stack's CCS
    order (within a column, the rows of the first pattern come first)."""
    ccs = [_ccs(p) for p in patterns]
    ncol = patterns[0].size2()
    counts = np.array([np.diff(c[0]) for c in ccs])  # nonzeros per (pattern, column)
    colind = np.concatenate([[0], np.cumsum(counts.sum(axis=0))]).astype(np.int64)
    before = np.cumsum(counts, axis=0) - counts  # in each column: the earlier patterns' rows
    rows, dest, offset = [], [], 0
    for k, (ci, row, shape, col) in enumerate(ccs):
        within = np.arange(row.size) - ci[col]  # position inside its column
        dest.append(colind[col] + before[k][col] + within)
        rows.append(row + offset)
        offset += shape[0]
    row_all = np.empty(int(colind[-1]), dtype=np.int64)
    for d, r in zip(dest, rows, strict=True):
        row_all[d] = r
    col_all = major_index(colind)
    return (colind, row_all, (offset, ncol), col_all), dest


def _to_csc(M, ccs) -> sp.csc_matrix:
    """The nonzeros ``M`` (a NumPy vector, or a CasADi DM) of the CCS pattern ``ccs`` (from
    :func:`_ccs`) as a SciPy CSC matrix."""
    colind, row, shape, _ = ccs
    data = np.asarray(M.nonzeros() if isinstance(M, ca.DM) else M, dtype=float).ravel()
    return sp.csc_matrix((data, row, colind), shape=shape)


def _to_dense(M, ccs) -> np.ndarray:
    """:func:`_to_csc` as a dense NumPy array."""
    _, row, shape, col = ccs
    out = np.zeros(shape)
    out[row, col] = np.asarray(M.nonzeros() if isinstance(M, ca.DM) else M, dtype=float).ravel()
    return out


def _gn_step_sparse(hv, J, gfun, wv, gval, nx=None, C=None, refine: int = 10):
    """The step of :func:`_gn_step`, sparse: ``(d, y)``.

    ``min (G + J_G d - guess)^2 / 2 + d^T C d / 2 + eps ||d_x||^2 / 2  s.t.  h + J d = 0``
    through its KKT system ``[[W, J^T], [J, 0]] [d; y] = [-J_G^T (G - guess); -h]``,
    ``W = J_G^T J_G + C + eps D_x`` (``D_x`` the identity on the first ``nx`` unknowns, zero on
    ``z``; without guesses ``W = D_x``: the step of least ``||d_x||``; ``z`` is not weighted,
    it follows from the ``alg`` rows). The proximal term ``eps ||d_x||^2`` does not move the
    solution (the iteration's fixed points, ``d = 0``, are the same), and the constraints are
    met exactly: the KKT matrix is factorized by SuperLU as it is. Only when that fails
    (redundant constraint rows make it singular) is it regularized,
    ``[[W + eps I, J^T], [J, -mu I]]``, and refined against the unregularized system."""
    n, m = wv.size, J.shape[0]
    nx = n if nx is None else nx
    dx = np.zeros(n)
    dx[:nx] = 1.0
    if gval.size:
        Gv, JG = gfun(wv)
        W = (JG.T @ JG).tocsc()
        if C is not None:
            W = (W + C).tocsc()
        b1 = -(JG.T @ (np.asarray(Gv, dtype=float).ravel() - gval))
        sW = max(1.0, float(abs(W).max())) if W.nnz else 1.0
        eps = 1e-6 * sW
    else:
        W = sp.csc_matrix((n, n))
        b1 = np.zeros(n)
        sW, eps = 1.0, 1.0
    if m == 0:
        d = sp.linalg.splu((W + eps * sp.identity(n)).tocsc()).solve(b1) if n else np.zeros(0)
        return d, np.zeros(0)
    Wx = (W + eps * sp.diags(dx)).tocsc()
    Jc = J.tocsc()
    K = sp.bmat([[Wx, Jc.T], [Jc, sp.csc_matrix((m, m))]], format="csc")
    b = np.concatenate([b1, -hv])
    nb = max(np.linalg.norm(b), 1e-300)
    # more constraint rows than unknowns (fixed values the consistency conditions imply, as
    # when all of a chain's q and v are fixed): the KKT matrix is singular (rank <= 2n < n + m),
    # the unregularized factorization would only fail at the cost of a full LU
    try:
        if m > n:
            raise RuntimeError("redundant rows")
        lu = sp.linalg.splu(K)  # COLAMD + partial pivoting: little fill on KKT matrices
        sol = lu.solve(b)
        if np.all(np.isfinite(sol)):
            sol = sol + lu.solve(b - K @ sol)
            if np.all(np.isfinite(sol)) and np.linalg.norm(b - K @ sol) <= 1e-10 * nb:
                return sol[:n], sol[n:]
    except RuntimeError:  # exactly singular: redundant rows
        pass
    sJ = max(1.0, float(abs(J).max())) if J.nnz else 1.0
    mu = 1e-8 * sJ**2 / sW
    K_reg = sp.bmat(
        [[W + eps * sp.identity(n), Jc.T], [Jc, -mu * sp.identity(m)]], format="csc"
    )
    try:
        lu = sp.linalg.splu(K_reg)
    except RuntimeError:  # pragma: no cover - the regularized matrix is nonsingular
        return sp.linalg.lsmr(J, -hv, atol=1e-14, btol=1e-14)[0], np.zeros(m)
    sol = lu.solve(b)
    for _ in range(refine):
        res = b - K @ sol
        if np.linalg.norm(res) <= 1e-15 * nb:
            break
        sol = sol + lu.solve(res)
    return sol[:n], sol[n:]


def _raise_conflict(hv, J, row_names, n_alg, n_inv, fixed_items, res, it, hv_held=None
                    ) -> None:
    n_cons = n_alg + n_inv
    if (hv_held is not None and fixed_items and hv_held.size >= n_cons
            and np.all(np.isfinite(hv_held[:n_cons]))):
        cons = np.abs(hv_held[:n_cons])
        top = float(cons.max(initial=0.0))
        broken = [i for i in np.nonzero(cons > 1e-3 * top)[0]] if top > 1e-8 * (1 + res) else []
        if broken:
            fx = [(nm, v) for nm, _, v in fixed_items]
            # one mention per name (a dummy-derivative system has its invariants among its
            # algebraic equations: 'rod' would be named twice)
            seen: set[str] = set()
            first = [i for i in broken if not (row_names[i] in seen or seen.add(row_names[i]))]
            shown = ", ".join(f"{row_names[i]} = {hv_held[i]:.3g}" for i in first[:6])
            raise InitializationError(
                f"initialize: the fixed values {_fmt(fx)} contradict the consistency "
                f"conditions {[row_names[i] for i in first]} (their residuals with the fixed "
                f"values held: {shown}; the others hold). Fix fewer values - fix only dynamic "
                "degrees of freedom - or make them consistent, and give the rest as guesses."
            )
    # at a Gauss-Newton stationary point J^T h ~ 0: h lies in the left null space; the rows
    # carrying it are the ones in conflict
    mag = np.abs(hv)
    involved = np.where(mag > 1e-6 * mag.max())[0] if mag.size else np.zeros(0, int)
    fixed_rows = [i for i in involved if i >= n_alg + n_inv]
    cond_rows = [row_names[i] for i in involved if n_alg <= i < n_alg + n_inv]
    alg_rows = [row_names[i] for i in involved if i < n_alg and mag[i] > 1e-3 * mag.max()]
    lhs = (J.T @ hv) if J.size else np.zeros(0)
    jnorm = sp.linalg.norm(J) if sp.issparse(J) else np.linalg.norm(J)
    stationary = np.linalg.norm(lhs) <= 1e-6 * max(np.linalg.norm(hv), 1e-300) * max(
        1.0, jnorm
    )
    if fixed_rows:
        fx = [(fixed_items[i - n_alg - n_inv][0], fixed_items[i - n_alg - n_inv][2])
              for i in fixed_rows]
        conds = cond_rows + alg_rows
        raise InitializationError(
            f"initialize: the fixed values {_fmt(fx)} contradict "
            + (f"the consistency conditions {conds}" if conds else "each other")
            + f" (max residual {res:.3g} after {count(it, 'iteration')}). Fix fewer values - fix only "
            "dynamic degrees of freedom - or make them consistent, and give the rest as guesses."
        )
    what = cond_rows + alg_rows
    hint = (
        "the equations cannot all hold" if stationary
        else "Gauss-Newton did not converge; give guesses closer to a consistent state"
    )
    raise InitializationError(
        f"initialize: no consistent values found: {what} keep a residual of {res:.3g} after "
        f"{count(it, 'iteration')} ({hint})."
    )


def _dependent_fixed(J, n_cons, fixed_names) -> list[str]:
    """Fixed values whose rows of ``J`` lie in the span of the consistency rows and of the
    (independent) fixed rows before them, decided scale-invariantly
    (:func:`daekit.numerics.redundant_rows`): each fixed row, in the equilibrated
    coordinates of the consistency rows and normalized, is projected on the directions the
    consistency rows and the accepted fixed rows leave free; it is redundant when nothing of
    it is left (below ``1e-8``). Units of equations and variables do not matter."""
    if not fixed_names:
        return []
    if J.shape[1] == 0:
        return list(fixed_names)
    from .numerics import redundant_rows

    return [fixed_names[k] for k in redundant_rows(J[:n_cons], J[n_cons:])]


def _free_states(r, Jc, nx, fixed: set[str]) -> set[str]:
    """A set of state names that can be fixed freely.

    The algebraic unknowns are eliminated first (``alg`` is solvable for ``z``):
    ``J = J_inv,x - J_inv,z J_alg,z^+ J_alg,x``; entries that cancel to rounding (below
    ``1e-10`` of the terms that make them; the invariants of a dummy-derivative system, which
    its algebraic equations contain, vanish entirely) are dropped. The number of dependent
    states is the scale-invariant rank (:func:`daekit.numerics.rank`) of ``Jc`` less that of
    its ``z`` columns (where ``d alg / d z`` is square and nonsingular: the rank of ``J``
    itself); a column-pivoted QR of the equilibrated ``J`` picks them (the pivots);
    the remaining states are free. The user's fixed states are weighted down so that they are
    reported free whenever they can be.
    """
    from .numerics import RANK_RTOL, equilibrate, rank, rank_info

    nz = Jc.shape[1] - nx
    n_alg = r.nz if r.alg.numel() == r.nz else int(r.alg.numel())
    # in the coordinates of the equilibrated Jc (ranks and pivots below are scale-invariant,
    # and there an entry of the Schur complement below 1e-10 is rounding residue whatever
    # the units: the dummy-derivative pendulum's invariant, a copy of one of its algebraic
    # equations, left 9e-17 where J_inv,x and the computed inverse's entries are 0 too, and
    # der(y) was reported dependent on y at some points: dof 1, not 2)
    er, ec = equilibrate(Jc)
    Jc = Jc * er[:, None] * ec[None, :]
    Ja, Ji = Jc[:n_alg], Jc[n_alg:]
    if Ji.shape[0] == 0 or nx == 0:
        return set(r.x_names)
    regular = False  # d alg / d z square and nonsingular (scale-invariant test)
    if nz and n_alg:
        dr, dc = equilibrate(Ja[:, nx:])
        Bz = Ja[:, nx:] * dr[:, None] * dc[None, :]
        if n_alg == nz:
            sv = np.linalg.svd(Bz, compute_uv=False)
            regular = bool(sv.size and sv[-1] > RANK_RTOL * nz * sv[0])
        if regular:
            Y = dc[:, None] * np.linalg.solve(Bz, Ja[:, :nx] * dr[:, None])
        else:
            Y = dc[:, None] * np.linalg.lstsq(Bz, Ja[:, :nx] * dr[:, None], rcond=1e-12)[0]
        T = Ji[:, nx:] @ Y
        Jred = Ji[:, :nx] - T
        Jred[(np.abs(Jred) <= 1e-10 * (np.abs(Ji[:, :nx]) + np.abs(T)))
             | (np.abs(Jred) <= 1e-10)] = 0.0
    else:
        Jred = Ji[:, :nx].copy()
    if regular or not nz:
        # rank Jc - rank Jc_z = rank of the Schur complement Jred (z eliminated exactly)
        info = rank_info(Jred)
        k, dr, dc = info.rank, info.dr, info.dc
    else:
        k = rank(Jc) - (rank(Jc[:, nx:]) if nz else 0)
        dr = dc = None
    k = max(0, min(k, nx))
    if k == 0:
        return set(r.x_names)
    if dr is None:
        dr, dc = equilibrate(Jred)
    colw = np.array([1e-2 if nm in fixed else 1.0 for nm in r.x_names])
    _, _, piv = scipy.linalg.qr(Jred * dr[:, None] * dc[None, :] * colw[None, :],
                                mode="economic", pivoting=True)
    dependent = set(piv[:k].tolist())
    return {r.x_names[i] for i in range(nx) if i not in dependent}


def _greedy_dependent_rows(A: np.ndarray, tol: float) -> list[int]:
    """Rows of the dense ``A`` within ``tol`` of the span of the *accepted* rows before them.

    Gram--Schmidt in row order (twice, for orthogonality to working precision): row ``k`` is
    accepted when its distance from the span of the accepted rows exceeds ``tol``."""
    k, n = A.shape
    Q = np.zeros((min(k, n), n))
    rank = 0
    dependent = []
    for i in range(k):
        a = np.array(A[i], dtype=float)
        if rank:
            Qr = Q[:rank]
            a -= Qr.T @ (Qr @ a)
            a -= Qr.T @ (Qr @ a)
        nrm = float(np.linalg.norm(a))
        if nrm <= tol or rank == Q.shape[0]:
            dependent.append(i)
        else:
            Q[rank] = a / nrm
            rank += 1
    return dependent


def _greedy_dependent_sparse(F: sp.csr_matrix, tol: float) -> list[int]:
    """:func:`_greedy_dependent_rows` for a sparse ``F`` whose rows are mostly (multiples of)
    unit vectors, as fixed states give.

    The accepted rows' span is kept as unit vectors ``e_j`` (``j`` in ``U``) plus an orthonormal
    set ``Q`` with zeros on ``U``. A single-entry row in column ``j`` that no vector of ``Q``
    touches is accepted into ``U`` (or is dependent when ``j`` is in ``U``) in O(1); any other
    row loses its ``U`` entries, then Gram--Schmidt against ``Q`` (twice) decides. When the rows
    of several entries all depend on the unit rows before them, as for over-specified chains,
    ``Q`` stays empty and the whole pass is linear in the number of entries."""
    F = F.tocsr()
    F.sum_duplicates()
    k, ncol = F.shape
    in_U = np.zeros(ncol, dtype=bool)
    Q = np.zeros((0, ncol))
    q_touch = np.zeros(ncol, dtype=bool)  # columns where some vector of Q is nonzero
    dependent: list[int] = []
    for i in range(k):
        lo, hi = F.indptr[i], F.indptr[i + 1]
        cols, vals = F.indices[lo:hi], F.data[lo:hi]
        keep = ~in_U[cols]
        cols, vals = cols[keep], vals[keep]
        if cols.size == 0 or np.max(np.abs(vals)) <= tol and not q_touch[cols].any():
            dependent.append(i)
            continue
        if cols.size == 1 and not q_touch[cols[0]]:
            in_U[cols[0]] = True
            continue
        a = np.zeros(ncol)
        a[cols] = vals
        if Q.shape[0]:
            a -= Q.T @ (Q @ a)
            a -= Q.T @ (Q @ a)
        a[in_U] = 0.0
        nrm = float(np.linalg.norm(a))
        if nrm <= tol:
            dependent.append(i)
        else:
            Q = np.vstack([Q, a / nrm])
            q_touch |= Q[-1] != 0.0
    return dependent


def _fixed_state_columns(Jf: sp.csr_matrix, nx: int) -> np.ndarray | None:
    """The state column of each fixed row when every fixed row is a unit row of a state (a
    fixed value of a state itself), else None."""
    Jf = Jf.tocsr()
    if Jf.shape[0] == 0 or not np.all(np.diff(Jf.indptr) == 1):
        return None
    cols = Jf.indices[Jf.indptr[:-1]]
    if np.any(cols >= nx) or np.any(Jf.data[Jf.indptr[:-1]] == 0.0):
        return None
    return cols.astype(np.int64)


def _redundant_fixed_states(C: sp.csr_matrix, fixed_cols: np.ndarray, rtol: float = 1e-9,
                            fill_limit: int = 50) -> list[int] | None:
    """Positions ``k`` of the fixed states ``fixed_cols[k]`` (in the user's order) that the
    consistency rows ``C`` and the fixed states before them imply; None where the elimination
    fills more than ``fill_limit`` times the entries of ``C`` (the caller then takes the general
    route).

    Why it works: ``e_j`` lies in the span of the rows of ``C`` and of ``e_i`` (``i`` in the set
    ``S`` fixed before) iff column ``j`` of ``C`` restricted to the columns outside ``S`` is not
    a combination of the others there (removing it lowers the rank). So, with the columns in
    the order *unfixed states, then the fixed ones in reverse*, a fixed state is implied iff
    its column enters the greedy column basis of ``C``: one pass of Gaussian elimination by
    columns with partial pivoting (a column whose remainder is below ``rtol`` times its own
    largest entry is dependent; both are invariant under the units of that state). The
    remainders stay within the band of a chain, so the pass is linear in its length.

    >>> import scipy.sparse as sp
    >>> C = sp.csr_matrix([[1.0, 1.0, 0.0]])          # x0 + x1 is constrained, x2 free
    >>> _redundant_fixed_states(C, np.array([0, 2, 1]))  # x1, fixed last, is implied
    [2]
    """
    import heapq

    n_c, nx = C.shape
    Cc = C.tocsc()
    Cc.sum_duplicates()
    redundant: list[int] = []
    first: dict[int, int] = {}
    for k, j in enumerate(fixed_cols.tolist()):
        if j in first:
            redundant.append(k)  # the same state fixed twice: implied by the first
        else:
            first[j] = k
    fixed_set = set(first)
    order = [j for j in range(nx) if j not in fixed_set] + list(reversed(list(first)))
    pivot_of: dict[int, int] = {}  # row -> index of its pivot column vector
    pivots: list[tuple[int, dict[int, float]]] = []
    stored, limit = 0, fill_limit * (Cc.nnz + n_c + 1)
    indptr, indices, data = Cc.indptr, Cc.indices, Cc.data
    for j in order:
        lo, hi = int(indptr[j]), int(indptr[j + 1])
        if lo == hi:
            continue  # a state no consistency row involves: never implied
        col = dict(zip(indices[lo:hi].tolist(), data[lo:hi].tolist()))
        big = max(abs(v) for v in col.values())
        heap = [pivot_of[i] for i in col if i in pivot_of]
        heapq.heapify(heap)
        applied: set[int] = set()
        while heap:
            p = heapq.heappop(heap)
            if p in applied:
                continue
            applied.add(p)
            row, u = pivots[p]
            a = col.get(row, 0.0)
            if a == 0.0:
                continue
            f = a / u[row]
            for i, v in u.items():
                if i not in col:
                    col[i] = 0.0
                    q = pivot_of.get(i)
                    if q is not None:
                        heapq.heappush(heap, q)
                col[i] -= f * v
            col[row] = 0.0
        rest = {i: v for i, v in col.items() if i not in pivot_of and v != 0.0}
        if rest:
            row = max(rest, key=lambda i: abs(rest[i]))
            if abs(rest[row]) > rtol * big:
                pivot_of[row] = len(pivots)
                pivots.append((row, rest))
                stored += len(rest)
                if stored > limit:
                    return None
                if j in fixed_set:
                    redundant.append(first[j])  # enters the basis: implied (see above)
    return sorted(redundant)


def _drop_small(A: sp.csr_matrix, tol: float) -> sp.csr_matrix:
    A = A.tocsr(copy=True)
    A.data[np.abs(A.data) <= tol] = 0.0
    A.eliminate_zeros()
    return A


def _place_rows(idx: np.ndarray, rows: np.ndarray, n_rows: int) -> sp.csr_matrix:
    """Sparse ``n_rows``-row matrix with the dense ``rows`` at row positions ``idx``."""
    P = sp.csr_matrix((np.ones(idx.size), (idx, np.arange(idx.size))), shape=(n_rows, idx.size))
    return (P @ sp.csr_matrix(rows)).tocsr()


def _well_conditioned_lu(A: sp.csc_matrix):
    """SuperLU factors of the square ``A``, or None when it is singular or ill conditioned
    (:func:`_well_conditioned`)."""
    try:
        lu = sp.linalg.splu(A)
    except RuntimeError:
        return None
    return lu if _well_conditioned(lu, A) else None


def _well_conditioned(lu, A: sp.csc_matrix, limit: float = 1e10) -> bool:
    """1-norm condition estimate of the square ``A`` from its SuperLU factors."""
    nA = A.shape[0]
    if nA == 0:
        return True
    inv = sp.linalg.LinearOperator(
        (nA, nA), matvec=lu.solve, rmatvec=lambda b: lu.solve(b, trans="T"), dtype=float
    )
    try:
        cond = sp.linalg.onenormest(inv) * sp.linalg.norm(A, 1)
    except Exception:  # pragma: no cover - estimator trouble: take the dense path
        return False
    return bool(np.isfinite(cond) and cond < limit)


#: Consistency rows above which the sparse basis is first tried with a greedy matching.
GREEDY_MATCHING_ROWS = 5000


def _greedy_matching(B: sp.csr_matrix) -> np.ndarray | None:
    """Columns matched to the rows of the cost matrix ``B`` (CSR, costs as stored), each row
    taking its cheapest column not taken yet, in row order; None when some row finds none."""
    taken = [False] * B.shape[1]
    out = [0] * B.shape[0]
    indptr, indices, data = B.indptr.tolist(), B.indices.tolist(), B.data.tolist()
    for i in range(B.shape[0]):  # plain Python: rows have a handful of entries
        best, best_cost = -1, np.inf
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            if not taken[j] and data[k] < best_cost:
                best, best_cost = j, data[k]
        if best < 0:
            return None
        out[i] = best
        taken[best] = True
    return np.asarray(out, dtype=np.int64)


def _sparse_free_redundant(J, n_alg, n_inv, nx, x_names, fixed_names):
    """Free states and redundant fixed values of the sparse path, or ``None`` when the
    consistency rows are degenerate (then the caller falls back to the dense analysis).

    1. ``z`` is eliminated with SuperLU on ``d alg / d z`` (square and nonsingular in a
       ReducedDAE): a row ``(r_x, r_z)`` becomes ``r_x - r_z A_z^{-1} A_x`` (solves only for
       rows that involve ``z``).
    2. The reduced consistency rows ``C`` (invariants on ``x``) get a basis: a minimum-weight
       full bipartite matching of rows to states (cost ``-log |c_ij|`` relative to the row's
       largest entry, plus a penalty on states the user fixed, so that those stay free when
       they can) chooses the dependent states ``D``; ``C_D`` must be well conditioned
       (SuperLU + a 1-norm condition estimate). The other states are free: fixing them
       determines the rest through ``C_D``.
    3. A fixed row ``f`` lies in the span of the consistency rows iff its coordinates on the
       free states, ``f_N - f_D C_D^{-1} C_N``, vanish; redundant fixed values are the rows
       whose coordinates depend on those of the rows before them
       (:func:`_greedy_dependent_sparse`).
    """
    J = J.tocsr()
    n = J.shape[1]
    nz = n - nx
    n_cons = n_alg + n_inv
    if n_alg != nz:
        return None
    scale = max(1.0, float(abs(J).max())) if J.nnz else 1.0
    Ji, Jf = J[n_alg:n_cons], J[n_cons:]
    if nz:
        Az = J[:n_alg, nx:].tocsc()
        lu_a = _well_conditioned_lu(Az)
        if lu_a is None:
            return None
        Ax = J[:n_alg, :nx].tocsc()

        def elim(rows: sp.csr_matrix) -> sp.csr_matrix:
            rx, rz = rows[:, :nx].tocsr(), rows[:, nx:].tocsr()
            idx = np.unique(rz.nonzero()[0])
            if idx.size == 0:
                return rx
            Y = lu_a.solve(np.asarray(rz[idx].T.toarray()), trans="T")
            corr = np.asarray((Ax.T @ Y).T)
            return (rx - _place_rows(idx, corr, rows.shape[0])).tocsr()
    else:

        def elim(rows: sp.csr_matrix) -> sp.csr_matrix:
            return rows[:, :nx].tocsr()

    drop = 1e-14 * scale
    C = _drop_small(elim(Ji), drop)
    # consistency rows that vanish once z is eliminated are implied by alg (e.g. invariants
    # that repeat an algebraic equation): they constrain nothing more
    cmax = np.asarray(abs(C).max(axis=1).toarray()).ravel() if C.shape[0] else np.zeros(0)
    C = C[np.where(cmax > 1e-9 * scale)[0]]
    n_c = C.shape[0]
    fixed_set = set(fixed_names)
    if n_c:
        if n_c > nx:
            return None
        A = abs(C).tocsr()
        rowmax = np.asarray(A.max(axis=1).toarray()).ravel()
        if np.any(rowmax <= 0):
            return None
        rows_of = major_index(A.indptr)
        penalty = np.array([np.log(1e2) if nm in fixed_set else 0.0 for nm in x_names])
        cost = np.log(rowmax[rows_of]) - np.log(A.data) + 1.0 + penalty[A.indices]
        B = sp.csr_matrix((cost, A.indices, A.indptr), shape=A.shape)
        lu_c = None
        if n_c > GREEDY_MATCHING_ROWS:
            # big: a greedy matching first (each row its cheapest free state, in row order;
            # linear), kept when complete and well conditioned; the optimal matching below is
            # superlinear (0.7 s for 20,000 rows of a chain)
            D = _greedy_matching(B)
            if D is not None:
                CD = C[:, D].tocsc()
                lu_c = _well_conditioned_lu(CD)
        if lu_c is None:
            try:
                _, D = sp.csgraph.min_weight_full_bipartite_matching(B)
            except ValueError:  # structurally rank deficient
                return None
            D = np.asarray(D)
            CD = C[:, D].tocsc()
            lu_c = _well_conditioned_lu(CD)
            if lu_c is None:
                return None
    else:
        D = np.zeros(0, dtype=int)
    in_D = np.zeros(nx, dtype=bool)
    in_D[D] = True
    free = {x_names[i] for i in range(nx) if not in_D[i]}
    if not fixed_names:
        return free, []
    unit = _fixed_state_columns(Jf, nx)
    if unit is not None:
        # fixed values of states only (unit rows): decided on C itself, linear for chains
        # (the coordinates below are dense for them: quadratic, 4.3 s at 3000 links)
        dependent = _redundant_fixed_states(C, unit)
        if dependent is not None:
            return free, [fixed_names[k] for k in dependent]
    Ncols = np.where(~in_D)[0]
    F = _drop_small(elim(Jf), drop)
    FN = F[:, Ncols].tocsr()
    if D.size:
        FD = F[:, D].tocsr()
        idx = np.unique(FD.nonzero()[0])
        if idx.size:
            Y = lu_c.solve(np.asarray(FD[idx].T.toarray()), trans="T")
            corr = np.asarray((C[:, Ncols].T @ Y).T)
            FN = (FN - _place_rows(idx, corr, F.shape[0])).tocsr()
    Ft = _drop_small(FN, drop)
    dependent = _greedy_dependent_sparse(Ft, 1e-9 * scale)
    return free, [fixed_names[k] for k in dependent]
