"""Dulmage--Mendelsohn decomposition and block lower triangular ordering.

References
----------
A. Pothen and C.-J. Fan, "Computing the block triangular form of a sparse matrix",
ACM Trans. Math. Softw. 16 (1990) 303-324.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["DMDecomposition", "dulmage_mendelsohn", "block_triangular", "structurally_nonsingular"]


@dataclass
class DMDecomposition:
    """Coarse Dulmage--Mendelsohn decomposition of a bipartite graph (rows = equations).

    ``over_rows``/``over_cols``: the over-determined part (more equations than unknowns);
    ``under_rows``/``under_cols``: the under-determined part; the rest is square.
    ``row_match[i]`` is the column matched to row ``i`` or -1.
    """

    over_rows: list[int]
    over_cols: list[int]
    under_rows: list[int]
    under_cols: list[int]
    row_match: np.ndarray
    col_match: np.ndarray

    @property
    def matching_size(self) -> int:
        return int(np.count_nonzero(self.row_match >= 0))

    @property
    def is_square_nonsingular(self) -> bool:
        n, m = len(self.row_match), len(self.col_match)
        return n == m and self.matching_size == n


def _pattern(n_rows: int, n_cols: int, rows, cols) -> sp.csr_matrix:
    data = np.ones(len(rows), dtype=np.int8)
    a = sp.csr_matrix((data, (np.asarray(rows), np.asarray(cols))), shape=(n_rows, n_cols))
    a.sum_duplicates()
    return a


#: Patterns up to this many rows are matched in Python by :func:`structurally_nonsingular`.
SMALL_MATCHING = 64


def structurally_nonsingular(n_rows: int, n_cols: int, rows, cols) -> bool:
    """Whether the square pattern ``(rows, cols)`` has a perfect matching (the answer of
    ``dulmage_mendelsohn(...).is_square_nonsingular``). Up to ``SMALL_MATCHING`` rows by
    augmenting paths in Python (SciPy's set-up costs more than the search), beyond by
    :func:`dulmage_mendelsohn`.

    >>> structurally_nonsingular(2, 2, [0, 1], [0, 0])
    False
    >>> structurally_nonsingular(2, 2, [0, 1, 1], [0, 0, 1])
    True
    """
    if n_rows != n_cols:
        return False
    if n_rows > SMALL_MATCHING:
        return dulmage_mendelsohn(n_rows, n_cols, rows, cols).is_square_nonsingular
    adj: list[list[int]] = [[] for _ in range(n_rows)]
    for i, j in zip(np.asarray(rows).tolist(), np.asarray(cols).tolist(), strict=True):
        adj[i].append(j)
    match_col = [-1] * n_cols  # row matched to each column

    def augment(i: int, seen: list[bool]) -> bool:
        for j in adj[i]:
            if not seen[j]:
                seen[j] = True
                if match_col[j] < 0 or augment(match_col[j], seen):
                    match_col[j] = i
                    return True
        return False

    return all(augment(i, [False] * n_cols) for i in range(n_rows))


def dulmage_mendelsohn(n_rows: int, n_cols: int, rows, cols) -> DMDecomposition:
    """Coarse Dulmage--Mendelsohn decomposition of the pattern given by ``(rows, cols)``.

    Rows reachable from an unmatched row by alternating paths (row -> any column -> its
    matched row) form the over-determined part; columns reachable from an unmatched column
    likewise form the under-determined part. O(nnz) after a maximum matching
    (Hopcroft--Karp, via SciPy).

    >>> d = dulmage_mendelsohn(3, 2, [0, 1, 2], [0, 0, 1])
    >>> d.over_rows, d.over_cols
    ([0, 1], [0])
    """
    a = _pattern(n_rows, n_cols, rows, cols)
    col_match = np.asarray(sp.csgraph.maximum_bipartite_matching(a, perm_type="row"))  # row of each col
    row_match = np.full(n_rows, -1, dtype=np.int64)
    ok = col_match >= 0
    row_match[col_match[ok]] = np.nonzero(ok)[0]
    at = a.tocsc()

    # over-determined: from unmatched rows, row -> its columns -> the columns' matched rows;
    # under-determined: the same search on the transpose, from unmatched columns
    over_rows, over_cols = _alternating_reach(a, row_match, col_match, n_rows, n_cols)
    under_cols, under_rows = _alternating_reach(at, col_match, row_match, n_cols, n_rows)
    return DMDecomposition(over_rows, over_cols, under_rows, under_cols, row_match, col_match)


def _alternating_reach(a, match_of_row, match_of_col, n_rows: int, n_cols: int):
    """Rows and columns reachable from the unmatched rows of the CSR pattern ``a`` by
    alternating paths (row -> any of its columns -> that column's matched row): the
    over-determined part of Dulmage--Mendelsohn (on the transpose: the under-determined)."""
    seen_r = np.zeros(n_rows, bool)
    seen_c = np.zeros(n_cols, bool)
    queue = deque(np.nonzero(match_of_row < 0)[0].tolist())
    seen_r[list(queue)] = True
    while queue:
        i = queue.popleft()
        for j in a.indices[a.indptr[i] : a.indptr[i + 1]]:
            if not seen_c[j]:
                seen_c[j] = True
                r = match_of_col[j]
                if r >= 0 and not seen_r[r]:
                    seen_r[r] = True
                    queue.append(r)
    return np.nonzero(seen_r)[0].tolist(), np.nonzero(seen_c)[0].tolist()


def block_triangular(n: int, rows, cols, row_match) -> list[tuple[list[int], list[int]]]:
    """Block lower triangular order of a square, structurally nonsingular pattern.

    ``row_match[i]`` is the column matched to row ``i``. Returns the diagonal blocks as
    (rows, columns) in an order in which each block needs only unknowns of earlier blocks
    (Tarjan's strongly connected components, via SciPy, then a topological order).

    >>> block_triangular(2, [0, 1, 1], [0, 0, 1], [0, 1])
    [([0], [0]), ([1], [1])]
    """
    rows = np.asarray(rows)
    cols = np.asarray(cols)
    row_match = np.asarray(row_match)
    col_to_row = np.empty(n, dtype=np.int64)
    col_to_row[row_match] = np.arange(n)
    # graph on equations: i -> k when equation i uses the unknown matched to equation k
    src, dst = rows, col_to_row[cols]
    keep = src != dst
    g = sp.csr_matrix((np.ones(int(keep.sum()), np.int8), (src[keep], dst[keep])), shape=(n, n))
    n_comp, labels = sp.csgraph.connected_components(g, directed=True, connection="strong")
    # condensed DAG: block a depends on block b if an edge a -> b; order dependencies first
    cs, cd = labels[src[keep]], labels[dst[keep]]
    inter = cs != cd
    dag = sp.csr_matrix(
        (np.ones(int(inter.sum()), np.int8), (cs[inter], cd[inter])), shape=(n_comp, n_comp)
    )
    dag.sum_duplicates()
    outdeg = np.diff(dag.indptr).astype(np.int64)
    rev = dag.T.tocsr()
    order = []
    queue = deque(np.nonzero(outdeg == 0)[0].tolist())
    while queue:
        b = queue.popleft()
        order.append(b)
        for a in rev.indices[rev.indptr[b] : rev.indptr[b + 1]]:
            outdeg[a] -= 1
            if outdeg[a] == 0:
                queue.append(a)
    members = [[] for _ in range(n_comp)]
    for i in range(n):
        members[labels[i]].append(i)
    return [(members[b], [int(row_match[i]) for i in members[b]]) for b in order]
