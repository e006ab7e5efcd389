"""Elimination of explicit derivatives: the minimal index-1 form of first-order models.

Pryce's scheme makes every derivative ``x_j^(k)``, ``k < d_j``, a state. A first-order model
written the usual way, ``p' = v`` ("kinematics") and ``m v' = f - z p`` ("newton") with a
constraint ``c(p) = 0``, has ``d_p = 2``: the reduced system carries ``p``, ``der(p)`` and ``v``
as states, ``der(p,2)`` as an algebraic unknown, and ``der(p) - v`` as extra invariants, although
``der(p)`` is just ``v``.

This module removes such duplicates. An equation element ``F_i`` with offset ``c_i >= 1`` is
*explicit* in a derivative ``x_j^(k)`` (``k >= 1``, ``k = d_j - c_i``, so ``x_j^(k)`` would be a
state) when

    ``F_i = a x_j^(k) - g``,  ``a`` a nonzero constant, ``g`` free of ``x_j^(k)``

(checked with CasADi: the Jacobian ``dF_i/dx_j^(k)`` is a constant, which makes ``F_i`` affine in
``x_j^(k)``). Then ``F_i^(s) = a x_j^(k+s) - g^(s)`` for ``s = 0..c_i``, and every symbol
``x_j^(k+s)`` is replaced by ``g^(s) / a``: the states ``x_j^(k..d_j-1)`` and the algebraic unknown
``x_j^(d_j)`` disappear, and with them the invariants ``F_i, ..., F_i^(c_i-1)`` and the
algebraic equation ``F_i^(c_i)`` (they hold identically). The count of states minus invariants
(the degrees of freedom) is unchanged, and the new algebraic Jacobian is the Schur complement
of Pryce's system Jacobian with respect to the constant pivots ``a``, so it is nonsingular
exactly where the old one was: the result is still index 1.

The ``g^(s)`` are read off the levels the expansion already holds (``F_i^(s)`` with
``x_j^(k+s)`` set to zero: no new differentiation). Where ``g`` contains other eliminated
symbols, the definitions are substituted into each other in dependency order; an elimination
whose definitions would depend on themselves (a cycle) is not made.

Example
-------
>>> import daekit as dk
>>> r = dk.reduce_index(dk.examples.pendulum3d())
>>> r.x_names
['p[0]', 'p[1]', 'p[2]', 'v[0]', 'v[1]', 'v[2]']
>>> r.invariant_names, str(r.variables["der(p)[0]"])
(['rod', 'd/dt rod'], 'v[0]')
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


def _candidates(ex: Expansion) -> list[tuple[int, int, int, float]]:
    """(i, j, k, a): equation element i is ``a x_j^(k) - g`` with a constant, k = d_j - c_i >= 1.

    One sparse Jacobian per distinct offset value ``c_i >= 1``, with respect to the symbols that
    would be states.
    """
    c, d = ex.c, ex.d
    F = ex.levels[0]
    out = []
    for cv in sorted(set(int(v) for v in c[c >= 1])):
        rows = np.nonzero(c == cv)[0]
        cols = np.nonzero(d - cv >= 1)[0]
        if not len(cols):
            continue
        X = ex.unknown(d - cv, cols)
        J = ca.jacobian(F[rows.tolist()], X)
        r_idx, c_idx = J.sparsity().get_triplet()
        nz = J.nonzeros()
        for r, cc, e in zip(r_idx, c_idx, nz, strict=True):
            if not e.is_constant():
                continue
            a = float(ca.DM(e))
            if a == 0.0 or not np.isfinite(a):
                continue
            j = int(cols[cc])
            out.append((int(rows[r]), j, int(d[j]) - cv, a))
    out.sort()
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
    plain = [r for r in range(n) if r not in set(mixed)]
    if plain:
        out[plain] = ca.substitute(F[plain], X[plain], ca.SX.zeros(len(plain)))
    for r in mixed:
        out[r] = ca.substitute(F[r], X[r], ca.SX(0))
    return out


def _definitions(ex: Expansion, chosen):
    """Pairs, symbols and raw definitions ``g^(s)/a`` of the chosen eliminations."""
    c = ex.c
    pairs, syms, defs = [], [], []
    maxc = max((int(c[i]) for i, _, _, _ in chosen), default=0)
    for s in range(maxc + 1):
        sel = [(i, j, k, a) for i, j, k, a in chosen if int(c[i]) >= s]
        if not sel:
            continue
        Fs = ex.equation(s, [i for i, _, _, _ in sel])
        Xs = ex.model.symbols_at([j for _, j, _, _ in sel], [k + s for _, _, k, _ in sel])
        G = _free_of_own_symbol(Fs, Xs)  # = -g^(s)
        inv_a = ca.DM([-1.0 / a for _, _, _, a in sel])
        defs.append(G * inv_a)
        syms.append(Xs)
        pairs += [(j, k + s) for _, j, k, _ in sel]
    if not pairs:
        return [], ca.SX(0, 1), ca.SX(0, 1)
    return pairs, ca.vertcat(*syms), ca.vertcat(*defs)


def _dependency_depth(sp: ca.Sparsity, n: int):
    """Longest dependency chain among definitions (rows depend on columns); None on a cycle,
    together with the rows that are part of (or depend on) a cycle."""
    r_idx, c_idx = sp.get_triplet()
    if not r_idx:
        return 0, []
    deps = [[] for _ in range(n)]  # deps[r]: columns r needs
    users = [[] for _ in range(n)]
    for r, cc in zip(r_idx, c_idx, strict=True):
        deps[r].append(cc)
        users[cc].append(r)
    missing = [len(x) for x in deps]
    depth = [0] * n
    ready = [r for r in range(n) if missing[r] == 0]
    done = 0
    while ready:
        nxt = []
        for cc in ready:
            done += 1
            for r in users[cc]:
                depth[r] = max(depth[r], depth[cc] + 1)
                missing[r] -= 1
                if missing[r] == 0:
                    nxt.append(r)
        ready = nxt
    if done < n:
        return None, [r for r in range(n) if missing[r] > 0]
    return max(depth), []


def find_eliminations(ex: Expansion) -> Elimination:
    """The explicit derivatives of ``ex`` to eliminate, with their resolved definitions.

    Greedy: equation elements in order, each takes its first candidate whose unknown is not
    taken yet. Eliminations whose definitions form a cycle are dropped (and listed in
    ``skipped``).
    """
    chosen, taken_j, taken_i = [], set(), set()
    for i, j, k, a in _candidates(ex):
        if i in taken_i or j in taken_j:
            continue
        chosen.append((i, j, k, a))
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
        skipped += [i for i, j, _, _ in chosen if j in bad_j]
        chosen = [e for e in chosen if e[1] not in bad_j]
    if not chosen:
        return Elimination(skipped=skipped)
    return Elimination(
        equations=[i for i, _, _, _ in chosen],
        unknowns=[j for _, j, _, _ in chosen],
        orders=[k for _, _, k, _ in chosen],
        coefficients=[a for _, _, _, a in chosen],
        pairs=pairs,
        syms=syms,
        defs=defs,
        skipped=sorted(skipped),
    )
