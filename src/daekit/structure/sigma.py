"""Pryce's Sigma-method: highest-value transversal, canonical offsets, structural index.

References
----------
J. D. Pryce, "A simple structural analysis method for DAEs", BIT 41 (2001) 364-394.
N. S. Nedialkov and J. D. Pryce, "DAESA -- a Matlab tool for structural analysis of DAEs",
ACM Trans. Math. Softw. 41 (2015).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = [
    "SigmaAnalysis",
    "highest_value_transversal",
    "canonical_offsets",
    "structural_index",
    "sigma_method",
]


class NoTransversal(ValueError):
    """The Sigma matrix has no transversal (the system is structurally singular)."""


def highest_value_transversal(n: int, rows, cols, vals) -> np.ndarray:
    """A transversal (perfect matching) of the n-by-n Sigma matrix with the largest sum.

    Solved as a sparse linear assignment (LAPJVsp in SciPy) with the costs ``W - sigma_ij``,
    ``W = max sigma + 1``, so that every edge has a positive cost. Returns ``T`` with
    ``T[i]`` = unknown matched to equation ``i``. Raises :class:`NoTransversal` if none exists.

    >>> highest_value_transversal(2, [0, 0, 1], [0, 1, 0], [1, 2, 0]).tolist()
    [1, 0]
    """
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    vals = np.asarray(vals, dtype=np.int64)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    w = (vals.max() + 1 - vals).astype(float)
    a = sp.csr_matrix((w, (rows, cols)), shape=(n, n))
    try:
        r, c = sp.csgraph.min_weight_full_bipartite_matching(a)
    except ValueError as exc:
        raise NoTransversal(str(exc)) from None
    t = np.empty(n, dtype=np.int64)
    t[r] = c
    return t


def canonical_offsets(n: int, rows, cols, vals, transversal, max_iter: int | None = None):
    """Pryce's smallest (canonical) offsets ``c >= 0``, ``d`` for a highest-value transversal.

    Fixed-point iteration from ``c = 0``: ``d_j = max_i (sigma_ij + c_i)``,
    ``c_i = d_T(i) - sigma_i,T(i)``, until nothing changes (Pryce 2001, section 3.3).
    Each sweep costs O(nnz).

    >>> c, d = canonical_offsets(3, [0, 0, 1, 1, 2, 2], [0, 2, 1, 2, 0, 1],
    ...                          [2, 0, 2, 0, 0, 0], [2, 1, 0])
    >>> c.tolist(), d.tolist()
    ([0, 0, 2], [2, 2, 0])
    """
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    vals = np.asarray(vals, dtype=np.int64)
    t = np.asarray(transversal, dtype=np.int64)
    # sigma on the transversal
    lookup = dict(zip((rows * n + cols).tolist(), vals.tolist()))
    st = np.array([lookup[i * n + int(t[i])] for i in range(n)], dtype=np.int64)
    c = np.zeros(n, dtype=np.int64)
    limit = max_iter if max_iter is not None else 4 * n + 10
    for _ in range(limit):
        d = np.full(n, np.iinfo(np.int64).min, dtype=np.int64)
        np.maximum.at(d, cols, vals + c[rows])
        c_new = d[t] - st
        if np.array_equal(c_new, c):
            return c, d
        c = c_new
    raise RuntimeError("offset iteration did not converge (is the transversal highest-value?)")


def structural_index(c, d) -> int:
    """Pryce's structural index: ``max c_i``, plus one if some ``d_j = 0`` (an unknown that
    appears only undifferentiated needs one more differentiation to get its derivative).
    An ODE has index 0.

    >>> structural_index([0, 0, 2], [2, 2, 0])
    3
    """
    c = np.asarray(c)
    d = np.asarray(d)
    if c.size == 0:
        return 0
    return int(c.max()) + (1 if np.any(d == 0) else 0)


@dataclass
class SigmaAnalysis:
    """Result of :func:`sigma_method`."""

    transversal: np.ndarray  # unknown matched to each equation
    c: np.ndarray  # equation offsets
    d: np.ndarray  # variable offsets
    value: int  # sum of sigma over the transversal

    @property
    def index(self) -> int:
        return structural_index(self.c, self.d)

    @property
    def dof(self) -> int:
        return int(self.d.sum() - self.c.sum())


def sigma_method(n: int, rows, cols, vals) -> SigmaAnalysis:
    """Pryce's Sigma-method on a square sparse Sigma matrix: transversal, offsets, index, DOF.

    >>> s = sigma_method(3, [0, 0, 1, 1, 2, 2], [0, 2, 1, 2, 0, 1], [2, 0, 2, 0, 0, 0])
    >>> s.index, s.dof
    (3, 2)
    """
    t = highest_value_transversal(n, rows, cols, vals)
    c, d = canonical_offsets(n, rows, cols, vals, t)
    lookup = dict(zip((np.asarray(rows) * n + np.asarray(cols)).tolist(), np.asarray(vals).tolist()))
    value = int(sum(lookup[i * n + int(t[i])] for i in range(n)))
    return SigmaAnalysis(t, c, d, value)
