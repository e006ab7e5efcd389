"""Elimination of explicit derivatives: the minimal index-1 form of first-order models.

Pryce's scheme makes every derivative ``x_j^(k)``, ``k < d_j``, a state. A first-order model
written the usual way, ``p' = v`` ("kinematics") and ``m v' = f - z p`` ("newton") with a
constraint ``c(p) = 0``, has ``d_p = 2``: the reduced system carries ``p``, ``der(p)`` and ``v``
as states, ``der(p,2)`` as an algebraic unknown, and ``der(p) - v`` as extra invariants, although
``der(p)`` is just ``v``.

This module removes such duplicates, and the algebraic unknowns an equation gives
explicitly. An equation element ``F_i`` is *explicit* in a derivative ``x_j^(k)`` when

    ``F_i = a x_j^(k) - g``,  ``a`` a nonzero constant or an expression of the parameters
    only (``m`` in ``m v' = f``), ``g`` free of ``x_j^(k)``

(checked with CasADi, whole-vector: the nonzeros of the Jacobian ``dF/dx^(k)`` that depend on
no symbol but parameters, nonzero at the parameters' default values). Two kinds:

1. *Would-be states* (``c_i >= 1``, ``k = d_j - c_i >= 1``, as ``der(p)`` in ``p' = v``):
   ``F_i^(s) = a x_j^(k+s) - g^(s)`` for ``s = 0..c_i``, and every symbol ``x_j^(k+s)`` is
   replaced by ``g^(s) / a``: the states ``x_j^(k..d_j-1)`` and the algebraic unknown
   ``x_j^(d_j)`` disappear, and with them the invariants ``F_i, ..., F_i^(c_i-1)`` and the
   algebraic equation ``F_i^(c_i)`` (they hold identically).
2. *Highest derivatives* (``c_i = 0``, ``k = d_j >= 1``, as ``der(v)`` in ``m v' = f(p, z)``;
   ``highest=True``, the default of :func:`daekit.reduce_index`): ``x_j^(d_j) = g / a`` is
   substituted into the ODE right-hand side and the other algebraic equations; it is no
   algebraic unknown, and ``F_i`` no algebraic equation. The 3D pendulum then has the
   lecture's hand-written form: ``x = (p, v)``, ``z = (z)``, ``alg = d2/dt2 rod`` with
   ``v' = (u - m g e3 - z p)/m`` substituted.

Either way the count of states minus invariants (the degrees of freedom) is unchanged, and
the new algebraic Jacobian is the Schur complement of Pryce's system Jacobian with respect to
the pivots ``a``, so it is nonsingular exactly where the old one was: the result is still
index 1. A coefficient that depends on the state (a mass matrix ``M(q) v' = f``) is not a
pivot that can be taken once for all: such a ``v'`` stays an algebraic unknown (the KKT form).
A parameter-only coefficient is divided by symbolically; a parameter value that makes it zero
makes the model singular in either form.

The ``g^(s)`` are read off the levels the expansion already holds (``F_i^(s)`` with
``x_j^(k+s)`` set to zero: no new differentiation). Where ``g`` contains other eliminated
symbols, the definitions are substituted into each other in dependency order; an elimination
whose definitions would depend on themselves (a cycle, as for a constant but non-diagonal
mass matrix) is not made.

Example
-------
>>> import daekit as dk
>>> r = dk.reduce_index(dk.examples.pendulum3d())
>>> r.x_names
['p[0]', 'p[1]', 'p[2]', 'v[0]', 'v[1]', 'v[2]']
>>> r.z_names, r.invariant_names, str(r.variables["der(p)[0]"])
(['z'], ['rod', 'd/dt rod'], 'v[0]')
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .differentiate import Expansion

__all__ = ["Elimination", "find_eliminations"]


@dataclass
class Elimination:
    """Eliminated derivatives of an :class:`~daekit.reduction.differentiate.Expansion`.

    ``equations[e]`` (element ``i``) defines ``x_j^(k)`` with ``j = unknowns[e]``,
    ``k = orders[e]``, coefficient ``coefficients[e]``. ``pairs`` lists every eliminated
    ``(j, order)``, ``k <= order <= d_j``; ``syms`` are their symbols and ``defs`` their
    expressions, free of eliminated symbols.
    """

    equations: list[int] = field(default_factory=list)
    unknowns: list[int] = field(default_factory=list)
    orders: list[int] = field(default_factory=list)
    coefficients: list[float] = field(default_factory=list)
    pairs: list[tuple[int, int]] = field(default_factory=list)
    syms: ca.SX = field(default_factory=lambda: ca.SX(0, 1))
    defs: ca.SX = field(default_factory=lambda: ca.SX(0, 1))
    skipped: list[int] = field(default_factory=list)  # equations left out (cyclic definitions)

    def __len__(self) -> int:
        return len(self.equations)

    def substitute(self, exprs: list[ca.SX]) -> list[ca.SX]:
        """The expressions with every eliminated symbol replaced by its definition."""
        if not self.pairs:
            return list(exprs)
        return ca.substitute([ca.SX(e) for e in exprs], [self.syms], [self.defs])


def _constant_coefficients(J: ca.SX, model) -> tuple[np.ndarray, np.ndarray, list, np.ndarray]:
    """The nonzeros of the sparse Jacobian ``J`` that are constants or depend on parameters
    only, whole-vector: ``(rows, cols, exprs, values)`` with ``values`` at the parameters'
    default values (entries that vanish there are left out)."""
    r_idx, c_idx = J.sparsity().get_triplet()
    if not r_idx:
        return np.zeros(0, int), np.zeros(0, int), [], np.zeros(0)
    nz = J.nz[:]  # the nonzeros as one column (no Python object per element)
    p = model.parameter_symbols
    phash = {p[i].element_hash() for i in range(p.numel())}
    others = [s for s in ca.symvar(nz) if s.element_hash() not in phash]
    if others:
        dep_rows, _ = ca.jacobian_sparsity(nz, ca.vertcat(*others)).get_triplet()
        free = np.ones(nz.numel(), dtype=bool)
        free[np.asarray(dep_rows, dtype=np.int64)] = False
    else:
        free = np.ones(nz.numel(), dtype=bool)
    keep = np.nonzero(free)[0]
    if not keep.size:
        return np.zeros(0, int), np.zeros(0, int), [], np.zeros(0)
    sel = nz[keep.tolist()]
    if p.numel():
        vals = np.asarray(ca.Function("coef", [p], [sel])(model.parameter_values),
                          dtype=float).ravel()
    else:
        vals = np.asarray(ca.evalf(sel), dtype=float).ravel()
    good = (vals != 0.0) & np.isfinite(vals)
    # constants as numbers; only the parameter-dependent coefficients as expressions
    if p.numel():
        prow, _ = ca.jacobian_sparsity(sel, p).get_triplet()
        has_p = np.zeros(sel.numel(), dtype=bool)
        has_p[np.asarray(prow, dtype=np.int64)] = True
    else:
        has_p = np.zeros(sel.numel(), dtype=bool)
    sel_idx = np.nonzero(good)[0]
    exprs: list = [None] * sel_idx.size
    pk = np.nonzero(has_p[sel_idx])[0]
    if pk.size:
        for k, e in zip(pk.tolist(), ca.vertsplit(sel[sel_idx[pk].tolist()]), strict=True):
            exprs[k] = e
    keep, vals = keep[good], vals[good]
    return (np.asarray(r_idx, dtype=np.int64)[keep], np.asarray(c_idx, dtype=np.int64)[keep],
            exprs, vals)


def _candidates(ex: Expansion, highest: bool = False) -> list[tuple]:
    """(i, j, k, a, a_expr): equation element i is ``a x_j^(k) - g`` with ``a`` a nonzero
    constant (``a_expr`` None) or an expression ``a_expr`` of the parameters only (``a`` its
    value at the defaults), and ``g`` free of ``x_j^(k)``.

    ``c_i >= 1``: ``k = d_j - c_i >= 1`` (``x_j^(k)`` would be a state, as ``der(p)`` in
    ``p' = v``). ``c_i = 0`` (``highest``): ``k = d_j >= 1``, a highest derivative that would
    be an algebraic unknown (``der(v)`` in ``m v' = f``). One sparse Jacobian per distinct
    offset value, with respect to those symbols; the coefficients are sorted out whole-vector.
    """
    c, d = ex.c, ex.d
    F = ex.levels[0]
    # the model's own equations (not amended): the rows of its system Jacobian, made once
    Jsys = ex.model.system_jacobian(c, d) if F is ex.model.residual else None
    out = []
    values = sorted(set(int(v) for v in c[c >= (0 if highest else 1)]))
    for cv in values:
        rows = np.nonzero(c == cv)[0]
        cols = np.nonzero(d - cv >= 1)[0] if cv >= 1 else np.nonzero(d >= 1)[0]
        if not len(cols) or not len(rows):
            continue
        if Jsys is not None:  # dF_i / dx_j^(d_j - c_i) with c_i = cv: the same entries
            J = Jsys[rows.tolist(), cols.tolist()]
        else:
            J = ca.jacobian(F[rows.tolist()], ex.unknown(d - cv, cols))
        rr, cc, exprs, vals = _constant_coefficients(J, ex.model)
        for r, col, e, a in zip(rr, cc, exprs, vals, strict=True):
            j = int(cols[col])
            out.append((int(rows[r]), j, int(d[j]) - cv, float(a), e))
    out.sort(key=lambda t: t[:3])
    return out


def _free_of_own_symbol(F: ca.SX, X: ca.SX) -> ca.SX:
    """Row-wise ``F_r`` with ``X_r`` set to zero (each row only its own symbol)."""
    n = int(F.numel())
    if n == 0:
        return ca.SX(0, 1)
    r_idx, c_idx = ca.jacobian_sparsity(F, X).get_triplet()
    mixed = sorted({r for r, cc in zip(r_idx, c_idx, strict=True) if r != cc})
    if not mixed:
        return ca.substitute(F, X, ca.SX.zeros(n))
    out = ca.SX(F)
    mixed_set = set(mixed)
    plain = [r for r in range(n) if r not in mixed_set]
    if plain:
        out[plain] = ca.substitute(F[plain], X[plain], ca.SX.zeros(len(plain)))
    for r in mixed:
        out[r] = ca.substitute(F[r], X[r], ca.SX(0))
    return out


def _definitions(ex: Expansion, chosen):
    """Pairs, symbols and raw definitions ``g^(s)/a`` of the chosen eliminations."""
    c = ex.c
    pairs, syms, defs = [], [], []
    maxc = max((int(c[e[0]]) for e in chosen), default=0)
    for s in range(maxc + 1):
        sel = [e for e in chosen if int(c[e[0]]) >= s]
        if not sel:
            continue
        Fs = ex.equation(s, [e[0] for e in sel])
        Xs = ex.model.symbols_at([e[1] for e in sel], [e[2] + s for e in sel])
        G = _free_of_own_symbol(Fs, Xs)  # = -g^(s)
        if all(e[4] is None for e in sel):
            defs.append(G * ca.DM([-1.0 / e[3] for e in sel]))
        else:  # parameter-dependent coefficients stay symbolic
            defs.append(-G / ca.vertcat(*[e[3] if e[4] is None else e[4] for e in sel]))
        syms.append(Xs)
        pairs += [(e[1], e[2] + s) for e in sel]
    if not pairs:
        return [], ca.SX(0, 1), ca.SX(0, 1)
    return pairs, ca.vertcat(*syms), ca.vertcat(*defs)


def _dependency_depth(sp: ca.Sparsity, n: int):
    """Longest dependency chain among definitions (rows depend on columns); None on a cycle,
    together with the rows that are part of (or depend on) a cycle. Level by level on index
    arrays (Kahn's algorithm, one frontier at a time)."""
    import scipy.sparse as sps

    r_idx, c_idx = sp.get_triplet()
    if not r_idx:
        return 0, []
    r_idx = np.asarray(r_idx, dtype=np.int64)
    c_idx = np.asarray(c_idx, dtype=np.int64)
    users = sps.csr_matrix((np.ones(r_idx.size), (c_idx, r_idx)), shape=(n, n))  # col -> rows
    missing = np.bincount(r_idx, minlength=n)
    ready = np.nonzero(missing == 0)[0]
    done, depth = 0, 0
    while ready.size:
        done += ready.size
        nxt_rows = users[ready].indices
        if not nxt_rows.size:
            break
        np.subtract.at(missing, nxt_rows, 1)
        ready = np.unique(nxt_rows[missing[nxt_rows] == 0])
        if ready.size:
            depth += 1
    if done < n:
        return None, np.nonzero(missing > 0)[0].tolist()
    return depth, []


def find_eliminations(ex: Expansion, highest: bool = False) -> Elimination:
    """The explicit derivatives of ``ex`` to eliminate, with their resolved definitions.

    ``highest``: also the highest derivatives that an equation of offset 0 gives explicitly
    (``der(v)`` in ``m v' = f``), which would otherwise be algebraic unknowns.

    Greedy: equation elements in order, each takes its first candidate whose unknown is not
    taken yet. Eliminations whose definitions form a cycle are dropped (and listed in
    ``skipped``): a constant but non-diagonal mass matrix keeps its accelerations as
    algebraic unknowns.
    """
    chosen, taken_j, taken_i = [], set(), set()
    for cand in _candidates(ex, highest):
        i, j = cand[0], cand[1]
        if i in taken_i or j in taken_j:
            continue
        chosen.append(cand)
        taken_i.add(i)
        taken_j.add(j)
    skipped: list[int] = []
    while chosen:
        pairs, syms, defs = _definitions(ex, chosen)
        depth, cyclic = _dependency_depth(ca.jacobian_sparsity(defs, syms), len(pairs))
        if depth is not None:
            for _ in range(depth):
                defs = ca.substitute(defs, syms, defs)
            break
        bad_j = {pairs[r][0] for r in cyclic}
        skipped += [e[0] for e in chosen if e[1] in bad_j]
        chosen = [e for e in chosen if e[1] not in bad_j]
    if not chosen:
        return Elimination(skipped=skipped)
    return Elimination(
        equations=[e[0] for e in chosen],
        unknowns=[e[1] for e in chosen],
        orders=[e[2] for e in chosen],
        coefficients=[e[3] for e in chosen],
        pairs=pairs,
        syms=syms,
        defs=defs,
        skipped=sorted(skipped),
    )
