"""Scale-invariant numeric linear algebra: the ONE rank routine of daekit.

Every numeric structural decision in daekit -- the system Jacobian's rank (:func:`daekit.analyze`),
the easy test, the derivative-array index, the index-1 check and the amendment of
:func:`daekit.reduce_index`, the free and redundant values of :func:`daekit.initialize`, the
OCP's boundary analysis -- asks the functions of this module, so that they all agree and all
are invariant under the units of the model:

* Multiplying an equation by a nonzero constant scales a row of every Jacobian; changing a
  variable's unit scales a column. The matrices are therefore **equilibrated** before any
  rank decision: rows and columns are scaled by powers of two (exactly, no rounding), by
  Ruiz's iteration (Ruiz, "A scaling algorithm to equilibrate both rows and columns norms in
  matrices", RAL-TR-2001-034): ``A <- diag(r) A diag(c)`` with ``r_i = 1/sqrt(max_j |a_ij|)``,
  ``c_j = 1/sqrt(max_i |a_ij|)``, repeated until every nonzero row and column has its largest
  entry in ``[1/2, 2]`` (at most ``RUIZ_ITERATIONS`` sweeps). The result does not depend on
  a prior diagonal scaling of the matrix up to factors of two, so a rank computed from it is
  (to working precision) invariant under the units.
* The **relative tolerance**: a singular value ``s`` of the equilibrated matrix counts as zero
  when ``s <= RANK_RTOL * max(shape) * s_max`` with ``RANK_RTOL = 1e3 * machine epsilon``
  (about ``2.2e-13``); a pivot of a sparse LU factorization likewise.

Functions: :func:`equilibrate` (the scale factors), :func:`rank` / :func:`rank_info` (dense
SVD; sparse input is densified only up to ``DENSE_LIMIT`` rows, beyond that the LU-based
:func:`sparse_rank_deficiency` answers), :func:`null_space` and :func:`left_null_space`,
:func:`sparse_nonsingular` (the cheap sparse-LU test), :func:`to_scipy` (CasADi ``DM`` to a
SciPy CSC matrix). Also the one buffered CasADi call: :func:`fast_call` (once) and
:class:`FastFunction` (its buffers kept), with :class:`DenseFunction` and
:class:`SparseFunction` on it; and :class:`PatternCache`, the one per-thread cache of what is
built from a sparsity pattern.

Example
-------
>>> import numpy as np
>>> from daekit.numerics import rank
>>> A = np.array([[1.0, 2.0], [2.0, 4.0]])
>>> rank(A), rank(A * [[1e-9], [1e9]]), rank(np.diag([1e-12, 1.0]))
(1, 1, 2)
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

__all__ = ["RANK_RTOL", "DENSE_LIMIT", "RankInfo", "equilibrate", "equilibrated", "rank",
           "rank_info", "null_space", "left_null_space", "sparse_nonsingular",
           "sparse_rank_deficiency", "sparse_deficiency_rcond", "to_scipy", "SparseFunction",
           "FastFunction", "DenseFunction", "fast_call", "redundant_rows", "VANISH",
           "vanishing_removed", "major_index", "PatternCache", "Segments"]

#: Relative tolerance of every rank decision (see the module docstring).
RANK_RTOL = 1e3 * np.finfo(float).eps
#: Largest matrix (rows) whose rank is decided by a dense SVD; bigger sparse ones use LU pivots.
DENSE_LIMIT = 400
#: Most sweeps of Ruiz's equilibration.
RUIZ_ITERATIONS = 30
#: Entries below this fraction of their row's and column's largest (max-norm equilibrated)
#: do not steer the scaling (rounding residue of exact zeros).
NOISE = 1e-13
#: Entries below this fraction of their row's largest (unscaled) count as zero for the scaling.
ROW_NOISE = 1e-20
#: Matrices with at most this many entries are equilibrated as dense arrays (also when given
#: sparse, unless fewer than one in 50 of the entries beyond 2000 are nonzero: a 200 x 200
#: with 600 nonzeros took 1.95 ms dense, 0.64 ms sparse): the same arithmetic, without
#: SciPy's per-call overhead.
DENSE_EQUILIBRATE = 40000
#: Curtis--Reid's normal equations up to this size (rows plus columns) are solved densely.
DENSE_CR = 150


def major_index(indptr) -> np.ndarray:
    """The column of each nonzero of a CSC matrix (the row of each of a CSR one) from its
    ``indptr``, as int64: the one place for ``repeat(arange, diff(indptr))``.

    >>> major_index(np.array([0, 2, 2, 3])).tolist()
    [0, 0, 2]
    """
    indptr = np.asarray(indptr, dtype=np.int64)
    return np.repeat(np.arange(indptr.size - 1, dtype=np.int64), np.diff(indptr))


def equilibrate(A) -> tuple[np.ndarray, np.ndarray]:
    """Row and column factors ``(dr, dc)``, powers of two, such that ``diag(dr) A diag(dc)``
    is well scaled whatever the units: first Curtis--Reid's scaling (least squares on the
    logarithms of the entries' magnitudes: the scaled matrix is the same for ``A`` and for
    ``D1 A D2``, any nonsingular diagonal ``D1``, ``D2``), then Ruiz's iteration in the max
    norm until every nonzero row's and column's largest entry lies in ``[1/2, 2]``; zero rows
    and columns get factor 1. Dense or sparse ``A``.

    Example
    -------
    >>> import numpy as np
    >>> A = np.array([[1e6, 0.0], [1.0, 1e-6]])
    >>> dr, dc = equilibrate(A)
    >>> B = A * dr[:, None] * dc[None, :]
    >>> bool(np.all((np.abs(B).max(axis=1) >= 0.5) & (np.abs(B).max(axis=1) <= 2)))
    True
    """
    issparse = sp.issparse(A)
    if issparse and A.shape[0] * A.shape[1] <= min(DENSE_EQUILIBRATE, 2000 + 50 * A.nnz):
        A, issparse = A.toarray(), False
    if not issparse:
        return _equilibrate_dense(A)
    return _equilibrate_sparse(A)


def _equilibrate_sparse(A) -> tuple[np.ndarray, np.ndarray]:
    """:func:`equilibrate` of a sparse matrix in the exponents of its nonzeros, as
    :func:`_equilibrate_dense`: each Ruiz sweep is a segmented maximum over the nonzeros of
    each row (CSR order) and column (a fixed permutation), no sparse products."""
    B = sp.csr_matrix(A, dtype=float, copy=True)
    B.sum_duplicates()
    m, n = B.shape
    if m == 0 or n == 0:
        return np.ones(m), np.ones(n)
    data = np.abs(B.data)
    data[~np.isfinite(data)] = 0.0
    counts = np.diff(B.indptr)
    rows = major_index(B.indptr)
    cols = B.indices
    rmax0 = np.zeros(m)
    has = counts > 0
    if data.size:  # the rows' largest entries (CSR rows are contiguous segments)
        rmax0[has] = np.maximum.reduceat(data, B.indptr[:-1][has])
    keep = data > ROW_NOISE * rmax0[rows]  # also drops the zeros
    if not keep.all():
        rows, cols, data = rows[keep], cols[keep], data[keep]
    L = np.log2(data)
    seg = _segments(m, n, rows, cols)
    e = _ruiz_log_sparse(L, seg, np.zeros(m), np.zeros(n))
    big = L + e[0][rows] + e[1][cols] > _LOG2_NOISE
    lr, lc = _curtis_reid_log(m, n, rows[big], cols[big], L[big])
    er, ec = _ruiz_log_sparse(L, seg, np.round(lr), np.round(lc))
    return np.exp2(er), np.exp2(ec)


class PatternCache:
    """What is built from a sparsity pattern alone (orderings, symbolic factorizations), kept
    per thread for the last ``size`` patterns: the iterations of one Gauss--Newton run share
    one pattern, and threads never share an entry. The one per-thread cache of daekit's
    sparse linear algebra (the Curtis--Reid factorizations, the Ruiz segments, the KKT
    pattern, the banded ordering of ``J J^T``, the choice of the least-norm step's path).

    >>> import numpy as np
    >>> c = PatternCache(2)
    >>> key = c.key(3, np.array([0, 1, 1]))
    >>> c.get(key, lambda: "made"), c.get(key, lambda: "made again")
    ('made', 'made')
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self._local = threading.local()

    @staticmethod
    def key(*parts) -> tuple:
        """A hashable key of sizes and index arrays (arrays by their bytes)."""
        return tuple(p.tobytes() if isinstance(p, np.ndarray) else p for p in parts)

    def get(self, key: tuple, build, keep=None):
        """The entry of ``key``, made by ``build()`` when missing and kept unless
        ``keep(entry)`` is false (the oldest pattern leaves when ``size`` are kept). Keys are
        compared, never hashed (hashing a large pattern's bytes at every lookup cost more
        than the comparison with the few patterns kept)."""
        made = self._local.__dict__.get("made")
        if made is None:
            made = self._local.made = []
        for k, hit in reversed(made):
            if k == key:
                return hit
        hit = build()
        if keep is None or keep(hit):
            if len(made) >= self.size:
                del made[0]
            made.append((key, hit))
        return hit


_SEGMENTS = PatternCache(1)  # one pattern per Gauss-Newton run


def _segments(m: int, n: int, rows: np.ndarray, cols: np.ndarray) -> Segments:
    """:class:`Segments` of the pattern ``(rows, cols)``, reused for the same pattern."""
    return _SEGMENTS.get(PatternCache.key(m, n, rows, cols), lambda: Segments(m, n, rows, cols))


class Segments:
    """Row and column maxima over the nonzeros ``(rows, cols)`` of an ``m x n`` matrix (any
    order: the permutations to row and to column order are found once), for many value
    vectors of one pattern.

    >>> import numpy as np
    >>> s = Segments(3, 2, np.array([2, 0, 2]), np.array([0, 0, 1]))
    >>> s.maxima(np.array([1.0, 5.0, 3.0])).tolist(), s.row_max(np.array([1.0, 5.0, 3.0])).tolist()
    ([5.0, -inf, 3.0, 5.0, 3.0], [5.0, 0.0, 3.0])
    """

    def __init__(self, m: int, n: int, rows: np.ndarray, cols: np.ndarray) -> None:
        self.m, self.n = m, n
        self.rows, self.cols = rows, cols
        self.r_perm, self.r_start, self.r_has = _groups(rows, m)
        self.c_perm, self.c_start, self.c_has = _groups(cols, n)

    def maxima(self, S: np.ndarray) -> np.ndarray:
        """``[row maxima, column maxima]`` of the values ``S`` (``-inf`` for empty ones)."""
        out = np.full(self.m + self.n, -np.inf)
        if S.size:
            out[: self.m][self.r_has] = _reduce_max(S, self.r_perm, self.r_start)
            out[self.m:][self.c_has] = _reduce_max(S, self.c_perm, self.c_start)
        return out

    def row_max(self, S: np.ndarray) -> np.ndarray:
        """The row maxima of the values ``S`` (0 for empty rows)."""
        out = np.zeros(self.m)
        if S.size:
            out[self.r_has] = _reduce_max(S, self.r_perm, self.r_start)
        return out


def _groups(idx: np.ndarray, k: int):
    """``(perm, starts, has)``: the stable permutation that sorts ``idx`` (None where it is
    sorted already) and :func:`_starts` of the sorted indices."""
    perm = None if idx.size < 2 or bool((idx[1:] >= idx[:-1]).all()) else np.argsort(
        idx, kind="stable")
    return (perm, *_starts(idx if perm is None else idx[perm], k))


def _reduce_max(S: np.ndarray, perm, starts: np.ndarray) -> np.ndarray:
    return np.maximum.reduceat(S if perm is None else S[perm], starts)


def _starts(sorted_idx: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Start of each nonempty group of the sorted ``sorted_idx`` and which of ``0..k-1`` have
    one."""
    has = np.zeros(k, dtype=bool)
    if not sorted_idx.size:
        return np.zeros(0, dtype=np.int64), has
    first = np.ones(sorted_idx.size, dtype=bool)
    first[1:] = sorted_idx[1:] != sorted_idx[:-1]
    has[sorted_idx[first]] = True
    return np.nonzero(first)[0], has


def _ruiz_log_sparse(L, seg: Segments, er, ec) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_ruiz_log` over the nonzeros of a sparse matrix."""
    return _ruiz_sweeps(lambda er, ec: seg.maxima(L + er[seg.rows] + ec[seg.cols]),
                        seg.m, er, ec)


def _equilibrate_dense(A) -> tuple[np.ndarray, np.ndarray]:
    """:func:`equilibrate` of a dense matrix, in the exponents: with ``L = log2 |A|`` the
    scaled entries are ``L + e_r + e_c`` (integer exponents, added exactly), so that each
    Ruiz sweep is a few whole-array operations and no product is formed; the factors are
    those of the same iteration on ``|A|`` itself."""
    a = np.atleast_2d(np.asarray(A, dtype=float))
    m, n = a.shape
    if m == 0 or n == 0:
        return np.ones(m), np.ones(n)
    if m * n <= TINY_DENSE:  # the nonzeros picked in Python (no whole-array set-up)
        picked = _tiny_entries(a.tolist())
        if picked is not None:
            return _equilibrate_tiny(m, n, *picked)
    B = np.abs(a)
    ok = np.isfinite(B)
    if not ok.all():
        B = np.where(ok, B, 0.0)
    # entries below ROW_NOISE of their row's largest: rounding residue of exact zeros
    B = np.where(B > ROW_NOISE * B.max(axis=1, keepdims=True), B, 0.0)
    nz = B > 0
    L = np.log2(B, out=np.full(B.shape, -np.inf), where=nz)
    rows, cols = np.nonzero(nz)
    if rows.size <= TINY_EQUILIBRATE:
        return _equilibrate_tiny(m, n, rows, cols, L[rows, cols])
    e = _ruiz_log(L, np.zeros(m), np.zeros(n))
    # entries below NOISE of both their row's and column's largest after Ruiz: ignored by
    # Curtis--Reid (see equilibrate)
    keep = nz & (L + e[0][:, None] + e[1][None, :] > _LOG2_NOISE)
    rows, cols = np.nonzero(keep)
    lr, lc = _curtis_reid_log(m, n, rows, cols, L[rows, cols])
    er, ec = _ruiz_log(L, np.round(lr), np.round(lc))
    return np.exp2(er), np.exp2(ec)


_LOG2_NOISE = float(np.log2(NOISE))
#: Dense matrices with at most this many nonzeros are equilibrated by plain Python loops over
#: their nonzeros (the same arithmetic in the same order: the same factors, bit for bit),
#: where NumPy's per-call overhead is most of the time (Gauss--Newton on a pendulum
#: re-equilibrates a 5-by-7 Jacobian at every iterate).
TINY_EQUILIBRATE = 48


#: Dense matrices of at most this many entries have their nonzeros picked by
#: :func:`_tiny_entries`.
TINY_DENSE = 160


def _tiny_entries(rows_list: list[list[float]]):
    """``(rows, cols, log2 |a_ij|)`` of the entries of a small dense matrix (given as lists)
    that :func:`_equilibrate_dense` keeps -- finite, nonzero, above ``ROW_NOISE`` times
    their row's largest -- in row-major order; None when there are more than
    ``TINY_EQUILIBRATE``. The same selection as the array code, in Python floats."""
    rl, cl, vals = [], [], []
    for i, row in enumerate(rows_list):
        row = [abs(x) if math.isfinite(x) else 0.0 for x in row]
        top = ROW_NOISE * max(row)
        for j, x in enumerate(row):
            if x > top:  # (x > 0 also where the row is zero)
                rl.append(i)
                cl.append(j)
                vals.append(x)
        if len(vals) > TINY_EQUILIBRATE:
            return None
    return (np.array(rl, dtype=np.int64), np.array(cl, dtype=np.int64),
            np.log2(np.array(vals, dtype=float)))


def _equilibrate_tiny(m: int, n: int, rows: np.ndarray, cols: np.ndarray, logs: np.ndarray):
    """:func:`_equilibrate_dense` on the nonzeros ``(rows, cols)`` (row-major order) with log2
    magnitudes ``logs``, in Python floats (IEEE arithmetic as NumPy's, Python's ``round`` is
    NumPy's half-to-even).

    Why a third formulation of the Ruiz sweeps (beside the dense and the sparse array ones,
    which share :func:`_ruiz_sweeps`): on the 20 Jacobians the planar pendulum's analyze,
    reduce and initialize equilibrate (3 x 3 to 9 x 13, 4 to 42 nonzeros) this path took
    3.0-3.2 ms where the array path took 6.4-6.8 ms (same process, best of 5 x 300 calls,
    2-core machine under load), about a sixth of the whole pipeline's time saved; it
    gives the same factors bit for bit (tests/test_speed_sharing.py, 1200 matrices; 20,000
    random ones with ties, inf, NaN and zero rows when it was written)."""
    rl, cl, lv = rows.tolist(), cols.tolist(), logs.tolist()
    entries = list(zip(rl, cl, lv))
    ninf = -math.inf

    def ruiz(er: list, ec: list) -> tuple[list, list]:
        for _ in range(RUIZ_ITERATIONS):
            rmax = [ninf] * m
            cmax = [ninf] * n
            for i, j, v in entries:
                s_ = v + er[i] + ec[j]
                if s_ > rmax[i]:
                    rmax[i] = s_
                if s_ > cmax[j]:
                    cmax[j] = s_
            # -round(x / 2) is 0 for |x| <= 1 (half to even), as for x = -inf (a zero row)
            fr = [0.0 if -1.0 <= x <= 1.0 or x == ninf else float(-round(0.5 * x))
                  for x in rmax]
            fc = [0.0 if -1.0 <= x <= 1.0 or x == ninf else float(-round(0.5 * x))
                  for x in cmax]
            if not (any(fr) or any(fc)):
                break
            er = [a + b for a, b in zip(er, fr)]
            ec = [a + b for a, b in zip(ec, fc)]
        return er, ec

    er, ec = ruiz([0.0] * m, [0.0] * n)
    keep = [k for k, (i, j, v) in enumerate(entries) if v + er[i] + ec[j] > _LOG2_NOISE]
    if len(keep) == len(entries):
        lr, lc = _curtis_reid_log(m, n, rows, cols, logs)
    else:
        kr = rows[keep] if keep else rows[:0]
        kc = cols[keep] if keep else cols[:0]
        lr, lc = _curtis_reid_log(m, n, kr, kc, logs[keep] if keep else logs[:0])
    # (Python's round is NumPy's half to even)
    er, ec = ruiz([float(round(x)) for x in lr.tolist()], [float(round(x)) for x in lc.tolist()])
    return np.exp2(np.array(er, dtype=float)), np.exp2(np.array(ec, dtype=float))


def _ruiz_log(L, er, ec) -> tuple[np.ndarray, np.ndarray]:
    """Ruiz's iteration in the max norm on the exponents: ``L`` the log2 magnitudes (``-inf``
    for zeros), ``er``, ``ec`` the exponents of the row and column factors. Each sweep
    multiplies every row and column by the power of two nearest to ``1 / sqrt(its largest
    scaled entry)``, until every nonzero row's and column's largest entry lies in
    ``[1/2, 2]`` (then every update is 1)."""
    def maxima(er, ec):
        S = L + er[:, None] + ec[None, :]
        return np.concatenate([S.max(axis=1), S.max(axis=0)])

    return _ruiz_sweeps(maxima, L.shape[0], er, ec)


def _ruiz_sweeps(maxima, m: int, er, ec) -> tuple[np.ndarray, np.ndarray]:
    """The sweeps of :func:`_ruiz_log`, dense or sparse: ``maxima(er, ec)`` gives the log2
    of every row's and then every column's largest scaled entry."""
    for _ in range(RUIZ_ITERATIONS):
        # the factor 2**-round(log2(max) / 2); zero rows and columns (-inf) keep factor 1
        f = -np.round(0.5 * maxima(er, ec))
        f[~np.isfinite(f)] = 0.0
        if not f.any():
            break
        er = er + f[:m]
        ec = ec + f[m:]
    return er, ec


def _curtis_reid_log(m, n, rows, cols, vals) -> tuple[np.ndarray, np.ndarray]:
    """Log2 row and column factors minimizing ``sum (log2|a_ij| + r_i + c_j)^2`` over the
    nonzeros at ``(rows, cols)`` with log2 magnitudes ``vals`` (Curtis & Reid, "On the
    automatic scaling of matrices for Gaussian elimination", J. Inst. Maths Applics 10, 1972):
    a linear least-squares problem whose scaled matrix does not depend on any prior diagonal
    scaling at all. Its normal equations ``[[diag(row counts), P], [P^T, diag(column counts)]]
    [r; c] = -[...]`` (``P`` the pattern) are singular along ``(1, -1)`` per connected
    component: a tiny ridge picks the least-norm solution without changing the scaled matrix.
    Dense up to ``DENSE_CR`` rows and columns, SuperLU beyond."""
    k = rows.size
    if k == 0:
        return np.zeros(m), np.zeros(n)
    if m + n <= DENSE_CR:
        b = -np.concatenate([np.bincount(rows, vals, minlength=m),
                             np.bincount(cols, vals, minlength=n)])
        lu = _curtis_reid_dense(m, n, rows, cols)
        if lu is None:  # pragma: no cover - the ridge keeps K regular
            K = _curtis_reid_matrix(m, n, rows, cols)
            sol = np.linalg.lstsq(K, b, rcond=None)[0]
        else:
            from scipy.linalg.lapack import dgetrs

            sol = dgetrs(lu[0], lu[1], b)[0]
        return sol[:m], sol[m:]
    b = -np.r_[np.bincount(rows, vals, minlength=m), np.bincount(cols, vals, minlength=n)]
    sol = _curtis_reid_factor(m, n, rows, cols).solve(b)
    return sol[:m], sol[m:]


def _curtis_reid_matrix(m: int, n: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Curtis--Reid's normal equations (dense, with the ridge) for the nonzeros ``(rows,
    cols)`` of an ``m x n`` matrix."""
    K = np.zeros((m + n, m + n))
    K[rows, m + cols] = 1.0
    K[m + cols, rows] = 1.0
    idx = np.arange(m + n)
    K[idx, idx] = np.concatenate([np.bincount(rows, minlength=m),
                                  np.bincount(cols, minlength=n)]) + 1e-10
    return K


#: Dense Curtis--Reid factorizations kept per thread (by pattern): Gauss--Newton on a small
#: system equilibrates Jacobians of one or two patterns at every iterate.
CR_DENSE_PATTERNS = 32
_CR_DENSE = PatternCache(CR_DENSE_PATTERNS)


def _curtis_reid_dense(m: int, n: int, rows: np.ndarray, cols: np.ndarray):
    """LAPACK's LU (``getrf``) of :func:`_curtis_reid_matrix`, kept for the last
    ``CR_DENSE_PATTERNS`` patterns of this thread (the matrix depends on the pattern only);
    solved by ``getrs`` this is ``gesv``, bit for bit. None if singular (never: the ridge).
    (scipy.linalg is imported here: it loads on first use, not with daekit.)"""

    def factor():
        from scipy.linalg.lapack import dgetrf

        lu, piv, info = dgetrf(_curtis_reid_matrix(m, n, rows, cols))
        return (lu, piv) if info == 0 else None  # (never singular: the ridge)

    return _CR_DENSE.get(PatternCache.key(m, n, rows, cols), factor,
                         keep=lambda hit: hit is not None)


#: Patterns whose factorization is kept (per thread): Gauss--Newton re-equilibrates the
#: Jacobian of one pattern at every iterate.
CR_PATTERNS = 4
#: ... each with at most this many nonzeros in its factors (about 24 MB)
CR_KEEP_NNZ = 2_000_000
_CR_LU = PatternCache(CR_PATTERNS)


def _curtis_reid_factor(m: int, n: int, rows: np.ndarray, cols: np.ndarray):
    """SuperLU factorization of Curtis--Reid's normal equations for the nonzeros ``(rows,
    cols)`` of an ``m x n`` matrix (they depend on the pattern only, not on the values), kept
    for the last ``CR_PATTERNS`` patterns of this thread."""
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    cols = np.ascontiguousarray(cols, dtype=np.int64)

    def factor():
        k = rows.size
        P = sp.csr_matrix((np.ones(k), (rows, cols)), shape=(m, n))
        rc = np.bincount(rows, minlength=m).astype(float)
        cc = np.bincount(cols, minlength=n).astype(float)
        K = sp.bmat([[sp.diags(rc + 1e-10), P], [P.T, sp.diags(cc + 1e-10)]], format="csc")
        return sp.linalg.splu(K, permc_spec="COLAMD")

    # (kept only while it is small in memory)
    return _CR_LU.get(PatternCache.key(m, n, rows, cols), factor,
                      keep=lambda lu: lu.L.nnz + lu.U.nnz <= CR_KEEP_NNZ)


def equilibrated(A):
    """``diag(dr) A diag(dc)`` with the factors of :func:`equilibrate` (same kind as ``A``)."""
    dr, dc = equilibrate(A)
    if sp.issparse(A):  # the factors placed on the nonzeros (no sparse products)
        A = sp.csc_matrix(A)
        cols = major_index(A.indptr)
        return sp.csc_matrix((A.data * dr[A.indices] * dc[cols], A.indices, A.indptr),
                             shape=A.shape)
    return np.asarray(A, dtype=float) * dr[:, None] * dc[None, :]


#: An entry whose value at a consistent point is below this fraction of its value at a random
#: point vanishes on the solutions (``cos(x) (x' - v)`` where ``x' = v``): it is set to zero
#: before a rank decision there. The ratio of one entry at two points does not depend on units
#: (equilibration alone would scale such a rounding residue up to unit size).
VANISH = 1e-9


def vanishing_removed(at_consistent, at_random):
    """``at_consistent`` without the entries that vanish on the solutions (see ``VANISH``):
    both matrices are values of the same symbolic matrix (the same pattern), at a consistent
    and at a random point; dense arrays or SciPy sparse matrices (the result is CSR then).

    Example
    -------
    >>> import numpy as np
    >>> vanishing_removed(np.array([[1.0, 3e-14]]), np.array([[2.0, 0.5]]))
    array([[1., 0.]])
    """
    if not sp.issparse(at_consistent):
        c = np.array(at_consistent, dtype=float)
        rnd = np.asarray(at_random.toarray() if sp.issparse(at_random) else at_random,
                         dtype=float)
        if c.shape != rnd.shape:
            return c
        c[(c != 0) & (np.abs(c) <= VANISH * np.abs(rnd))] = 0.0
        return c
    c = sp.csr_matrix(at_consistent, dtype=float, copy=True)
    rnd = sp.csr_matrix(at_random)
    if c.nnz == 0 or c.shape != rnd.shape:
        return c
    r_, c_ = c.nonzero()
    ref = np.abs(np.asarray(rnd[r_, c_]).ravel())
    vals = np.asarray(c[r_, c_]).ravel()
    tiny = np.abs(vals) <= VANISH * ref
    if np.any(tiny):
        c[r_[tiny], c_[tiny]] = 0.0
        c.eliminate_zeros()
    return c


@dataclass
class RankInfo:
    """Result of :func:`rank_info`.

    ``rank``; ``rcond`` = ``s_min / s_max`` of the equilibrated matrix (0 when rank
    deficient); ``left_null`` (``k x m``) and ``null`` (``(n - rank) x n``): bases, as rows, of the
    left null space and the null space *of the original matrix* (not orthonormal after the
    scaling is undone); ``dr``, ``dc`` the equilibration factors; ``sv`` the singular values of
    the equilibrated matrix.
    """

    rank: int
    rcond: float
    left_null: np.ndarray
    null: np.ndarray
    dr: np.ndarray
    dc: np.ndarray
    sv: np.ndarray

    def deficient_rows(self, rtol: float = 1e-8) -> list[int]:
        """Rows with weight in the left null space (of the equilibrated matrix, so that every
        row counts equally): the equations that combine to zero."""
        if self.left_null.shape[0] == 0:
            return []
        w = np.linalg.norm(self.left_null / self.dr[None, :], axis=0)
        return np.nonzero(w > rtol * w.max())[0].tolist() if w.max() > 0 else []


def rank_info(A, rtol: float = RANK_RTOL, scales=None) -> RankInfo:
    """Rank, reciprocal condition and null spaces of a (dense, or small sparse) matrix after
    equilibration; see the module docstring for the tolerance. ``scales = (dr, dc)``: these
    factors in place of the matrix's own (those of a larger matrix it is a block of, so that
    an entry that is rounding residue beside the rest of its row stays negligible).

    Example
    -------
    >>> import numpy as np
    >>> info = rank_info(np.array([[1.0, 1.0], [1e6, 1e6]]))
    >>> info.rank, info.deficient_rows()
    (1, [0, 1])
    """
    a = A.toarray() if sp.issparse(A) else np.atleast_2d(np.asarray(A, dtype=float))
    m, n = a.shape
    dr, dc = equilibrate(a) if scales is None else (np.asarray(scales[0], dtype=float),
                                                    np.asarray(scales[1], dtype=float))
    if a.size == 0:
        return RankInfo(0, 1.0, np.eye(m), np.eye(n), dr, dc, np.zeros(0))
    B = a * dr[:, None] * dc[None, :]
    U, s, Vt = np.linalg.svd(B)
    if not s.size or s[0] == 0:
        return RankInfo(0, 0.0, (U.T * dr[None, :]), (Vt * dc[None, :]), dr, dc, s)
    r = int(np.sum(s > rtol * max(m, n) * s[0]))
    rcond = float(s[-1] / s[0]) if r == min(m, n) else 0.0
    # u^T B = 0 -> (dr * u)^T A = 0;  B v = 0 -> A (dc * v) = 0
    left = U[:, r:].T * dr[None, :]
    right = Vt[r:] * dc[None, :]
    return RankInfo(r, rcond, left, right, dr, dc, s)


def rank(A, rtol: float = RANK_RTOL) -> int:
    """Numeric rank of ``A`` (dense, or sparse) after equilibration.

    Sparse matrices with more than ``DENSE_LIMIT`` rows are not densified: for a square one
    the rank is ``n`` minus the count of tiny LU pivots (:func:`sparse_rank_deficiency`).

    Example
    -------
    >>> import numpy as np
    >>> rank(np.array([[1e-8, 1.0], [2e-8, 2.0]]))
    1
    """
    if sp.issparse(A) and A.shape[0] > DENSE_LIMIT and A.shape[0] == A.shape[1]:
        return A.shape[0] - sparse_rank_deficiency(A, rtol)
    return rank_info(A, rtol).rank


def null_space(A, rtol: float = RANK_RTOL) -> np.ndarray:
    """A basis (columns) of the null space of ``A`` (after equilibration)."""
    return rank_info(A, rtol).null.T


def left_null_space(A, rtol: float = RANK_RTOL) -> np.ndarray:
    """A basis (rows) of the left null space of ``A`` (after equilibration): ``W @ A ~ 0``.

    Example
    -------
    >>> import numpy as np
    >>> W = left_null_space(np.array([[1.0, 2.0], [3.0, 6.0]]))
    >>> W.shape, bool(np.allclose(W @ np.array([[1.0, 2.0], [3.0, 6.0]]), 0))
    ((1, 2), True)
    """
    return rank_info(A, rtol).left_null


def redundant_rows(C, F, rtol: float = 1e-8) -> list[int]:
    """Rows of ``F`` implied by the rows of ``C`` and by the rows of ``F`` before them that
    are not (in order), decided scale-invariantly.

    The columns are scaled as in the equilibrated ``C`` (stacked on ``F``); ``V`` is an
    orthonormal basis of the directions ``C`` leaves free (its null space); each row of
    ``F``, scaled and normalized, is projected on ``V``: when less than ``rtol`` of it is left
    it is redundant; else ``V`` loses that direction.

    Example
    -------
    >>> import numpy as np
    >>> C = np.array([[-1e6, 1.0]])             # z - 1e6 x = 0
    >>> redundant_rows(C, np.array([[1.0, 0.0], [0.0, 1.0]]))   # x fixed, then z
    [1]
    """
    C = C.toarray() if sp.issparse(C) else np.atleast_2d(np.asarray(C, dtype=float))
    F = F.toarray() if sp.issparse(F) else np.atleast_2d(np.asarray(F, dtype=float))
    n = F.shape[1]
    if F.shape[0] == 0:
        return []
    _, dc = equilibrate(np.vstack([C, F]) if C.size else F)
    if C.shape[0]:
        info = rank_info(C * dc[None, :])
        # null vectors of C diag(dc), orthonormalized in those same coordinates
        V = np.linalg.qr(info.null.T)[0] if info.null.shape[0] else np.zeros((n, 0))
    else:
        V = np.eye(n)
    out = []
    W = np.zeros((n, 0))  # accepted directions: orthonormal, inside span(V)
    for k, row in enumerate(F * dc[None, :]):
        nrm = np.linalg.norm(row)
        if nrm == 0 or V.shape[1] == W.shape[1]:
            out.append(k)
            continue
        row = row / nrm
        p = V @ (V.T @ row)
        for _ in range(2):  # twice, for orthogonality to working precision
            p = p - W @ (W.T @ p)
        pn = np.linalg.norm(p)
        if pn <= rtol:
            out.append(k)
        else:
            W = np.hstack([W, (p / pn)[:, None]])
    return out


def _splu_pivots(A) -> np.ndarray | None:
    try:
        lu = sp.linalg.splu(sp.csc_matrix(A), permc_spec="COLAMD")
    except RuntimeError:  # exactly singular
        return None
    return np.abs(lu.U.diagonal())


def sparse_rank_deficiency(A, rtol: float = RANK_RTOL) -> int:
    """Number of LU pivots of the equilibrated square sparse ``A`` at or below ``rtol * n``
    times the largest (at least 1 when SuperLU finds ``A`` exactly singular). An estimate of
    the rank deficiency: exact for a zero pivot, and LU with partial pivoting reveals the rank
    of all but contrived matrices.

    Example
    -------
    >>> import scipy.sparse as sp
    >>> sparse_rank_deficiency(sp.csc_matrix([[1.0, 1.0], [1.0, 1.0]]))
    1
    """
    n = A.shape[0]
    if n == 0:
        return 0
    d = _splu_pivots(equilibrated(sp.csc_matrix(A)))
    if d is None:
        return 1
    if not d.size or d.max() == 0:
        return n
    return max(int(np.sum(d <= rtol * n * d.max())), 0)


def sparse_nonsingular(A, rtol: float = RANK_RTOL) -> bool:
    """Cheap test, no dense SVD: every pivot of the sparse LU of the equilibrated square ``A``
    is above ``rtol * n`` times the largest.

    Example
    -------
    >>> import scipy.sparse as sp
    >>> sparse_nonsingular(sp.csc_matrix([[1e-12, 0.0], [0.0, 1e12]]))
    True
    """
    n = A.shape[0]
    if n == 0:
        return True
    d = _splu_pivots(equilibrated(sp.csc_matrix(A)))
    return bool(d is not None and (d.size == 0 or (d.max() > 0 and d.min() > rtol * n * d.max())))


def sparse_deficiency_rcond(A, rtol: float = RANK_RTOL) -> tuple[int, float]:
    """:func:`sparse_rank_deficiency` and :func:`sparse_rcond` from one LU factorization.

    Example
    -------
    >>> import scipy.sparse as sp
    >>> sparse_deficiency_rcond(sp.csc_matrix([[2.0, 0.0], [0.0, 1.0]]))
    (0, 0.5)
    """
    n = A.shape[0]
    if n == 0:
        return 0, 1.0
    d = _splu_pivots(equilibrated(sp.csc_matrix(A)))
    if d is None:
        return 1, 0.0
    if not d.size or d.max() == 0:
        return n, 0.0
    return max(int(np.sum(d <= rtol * n * d.max())), 0), float(d.min() / d.max())


def sparse_rcond(A) -> float:
    """``min |pivot| / max |pivot|`` of the sparse LU of the equilibrated square ``A`` (0 when
    singular): a cheap reciprocal-condition estimate."""
    n = A.shape[0]
    if n == 0:
        return 1.0
    d = _splu_pivots(equilibrated(sp.csc_matrix(A)))
    if d is None or not d.size or d.max() == 0:
        return 0.0
    return float(d.min() / d.max())


def to_scipy(M) -> sp.csc_matrix:
    """A CasADi ``DM`` (or anything ``casadi.DM`` accepts) as a SciPy CSC matrix, keeping its
    sparsity.

    Example
    -------
    >>> import casadi as ca
    >>> to_scipy(ca.DM(ca.Sparsity.diag(2), [1, 2])).nnz
    2
    """
    M = ca.DM(M)
    colind, row = M.sparsity().get_ccs()
    return sp.csc_matrix(
        (np.asarray(M.nonzeros(), dtype=float), np.asarray(row, dtype=np.int64),
         np.asarray(colind, dtype=np.int64)),
        shape=(M.size1(), M.size2()),
    )


def _bound(f: ca.Function, ins, outs):
    """``f.buffer()`` with input ``i`` read from ``ins[i]`` and output ``j`` written into
    ``outs[j]`` in place (contiguous float arrays of the nonzeros; None leaves one unbound:
    CasADi reads an unbound input as zeros and does not compute an unbound output). The one
    place where daekit binds CasADi's buffers: :func:`fast_call` and :class:`FastFunction`."""
    buf, trigger = f.buffer()
    for i, a in enumerate(ins):
        if a is not None:
            buf.set_arg(i, memoryview(a))
    for i, a in enumerate(outs):
        if a is not None:
            buf.set_res(i, memoryview(a))
    return buf, trigger


def fast_call(F: ca.Function, args: Mapping[str, np.ndarray], outs: Mapping[str, tuple] | None = None,
              want_stats: bool = False) -> dict:
    """Call a CasADi Function once, writing straight into NumPy arrays (``Function.buffer``;
    for repeated calls of one function :class:`FastFunction` keeps its buffers).

    Inputs and outputs are row-major ``(points, size)`` arrays, i.e. CasADi's column-major
    ``(size, points)``; ``outs`` maps output names to such shapes (None: every output, as the
    vector of its nonzeros). Inputs not given stay unbound (CasADi reads them as zeros) and
    outputs not asked for are not computed (an integrator's adjoint outputs cost a third of a
    short run). ``want_stats``: the Function's stats under ``"_stats"``.

    >>> import casadi as ca, numpy as np
    >>> x = ca.SX.sym("x", 2)
    >>> F = ca.Function("f", [x], [2 * x], ["x"], ["y"])
    >>> fast_call(F, {"x": np.array([1.0, 2.0])}, {"y": (2,)})["y"].tolist()
    [2.0, 4.0]
    """
    ins: list = [None] * F.n_in()
    for i, name in enumerate(F.name_in()):
        a = args.get(name)
        if a is None:
            continue
        a = np.ascontiguousarray(a, dtype=float).ravel()
        if a.size != F.nnz_in(i):
            raise ValueError(f"{F.name()}: input {name} has {a.size} values, needs {F.nnz_in(i)}")
        ins[i] = a
    res = {}
    ros: list = [None] * F.n_out()
    for i, name in enumerate(F.name_out()):
        shape = (F.nnz_out(i),) if outs is None else outs.get(name)
        if shape is None:
            continue
        r = np.zeros(shape)
        if r.size != F.nnz_out(i):
            raise ValueError(f"{F.name()}: output {name} has {F.nnz_out(i)} values")
        ros[i] = res[name] = r
    buf, ev = _bound(F, ins, ros)
    ev()
    if want_stats:
        try:
            res["_stats"] = buf.stats()
        except Exception:  # noqa: BLE001
            res["_stats"] = {}
    return res


class FastFunction:
    """A CasADi ``Function`` called through its raw buffers (``Function.buffer()``): the
    inputs are copied into NumPy arrays CasADi reads in place, and the outputs (their
    nonzeros, as dense vectors) come back as NumPy arrays. A call costs about a microsecond
    where ``f(*args)`` with NumPy arguments costs 30-80 (SWIG's conversions to and from
    ``DM``); for the many small evaluations of Gauss--Newton that is most of the time.
    One buffer per thread, so that threads may share the object; copies and pickles rebuild
    them.

    Example
    -------
    >>> import casadi as ca
    >>> x = ca.SX.sym("x", 2); t = ca.SX.sym("t")
    >>> f = FastFunction(ca.Function("f", [t, x], [t * x, ca.sum1(x)]))
    >>> [v.tolist() for v in f(2.0, [1.0, 3.0])]
    [[2.0, 6.0], [4.0]]
    """

    def __init__(self, f: ca.Function) -> None:
        self.f = f
        self.n_in, self.n_out = f.n_in(), f.n_out()
        self.sizes_in = [f.nnz_in(i) for i in range(self.n_in)]
        self.sizes_out = [f.nnz_out(i) for i in range(self.n_out)]
        self._local = threading.local()

    def _buffers(self):
        loc = self._local
        if not hasattr(loc, "trigger"):
            ins = [np.zeros(k) for k in self.sizes_in]
            outs = [np.zeros(k) for k in self.sizes_out]
            loc.buf, loc.trigger = _bound(self.f, ins, outs)
            loc.ins, loc.outs = ins, outs
        return loc

    def __call__(self, *args) -> list[np.ndarray]:
        loc = self._buffers()
        for a, v in zip(loc.ins, args, strict=True):
            a[:] = v
        loc.trigger()
        return [o.copy() for o in loc.outs]

    def __reduce__(self):  # the buffers are per process and thread: rebuilt from f
        return (FastFunction, (self.f,))


class DenseFunction:
    """A CasADi ``Function`` of dense inputs called through its raw buffers
    (:class:`FastFunction`), its outputs as dense NumPy arrays: the values of ``f(*args)``
    (as dense arrays) without SWIG's conversions to and from ``DM`` (measured on the
    planar swing's end-point function: 95 against 10 us per call with the conversion of the
    Jacobian). Inputs with ``k`` columns where the function takes one (the others repeated)
    are evaluated by ``f.map(k)``, one mapped call, outputs side by side as CasADi's own
    call gives them. One output: the array; several: a tuple.

    >>> import casadi as ca
    >>> x = ca.SX.sym("x", 2); a = ca.SX.sym("a")
    >>> f = DenseFunction(ca.Function("f", [x, a], [a * x, ca.jacobian(a * ca.sumsqr(x), x)]))
    >>> [v.tolist() for v in f([1.0, 2.0], 3.0)]
    [[[3.0], [6.0]], [[6.0, 12.0]]]
    >>> [v.tolist() for v in f(np.array([[1.0, 0.0], [2.0, 1.0]]), 1.0)]
    [[[1.0, 0.0], [2.0, 1.0]], [[2.0, 4.0, 0.0, 2.0]]]
    """

    def __init__(self, f: ca.Function) -> None:
        self.f = f
        self.n_in = f.n_in()
        self.cols_in = [f.size2_in(i) for i in range(self.n_in)]
        self.sizes_in = [f.numel_in(i) for i in range(self.n_in)]
        self._by_k: dict[int, tuple] = {}

    def _mapped(self, k: int):
        # a map of at least k columns (the extra columns repeat the first): the batched
        # projections evaluate ever fewer columns as their starts converge, and a new map
        # costs more to make (0.1-0.2 ms) than the few extra columns to evaluate
        wider = [K for K in self._by_k if K >= k and (K == 1) == (k == 1)]
        if wider:
            return min(wider), self._by_k[min(wider)]
        got = self._by_k.get(k)
        if got is None:
            g = self.f if k == 1 else self.f.map(k)
            outs = []
            for i in range(g.n_out()):
                pat = g.sparsity_out(i)
                r, c = (np.asarray(v, dtype=np.int64) for v in pat.get_triplet())
                outs.append((pat.size1(), pat.size2(), r * pat.size2() + c))
            got = self._by_k[k] = (FastFunction(g), outs)
        return k, got

    def __call__(self, *args):
        vals = [np.asarray(v, dtype=float) for v in args]
        k = 1
        for v, c, n in zip(vals, self.cols_in, self.sizes_in, strict=True):
            if v.size != n and v.ndim == 2 and v.shape[1] != c:
                k = max(k, v.shape[1] // c)
        K, (fast, outs) = self._mapped(k)
        ins = []
        for v, n in zip(vals, self.sizes_in, strict=True):
            flat = v.ravel(order="F")
            if flat.size == n:
                ins.append(np.tile(flat, K) if K > 1 else flat)
            else:
                ins.append(np.concatenate([flat, np.tile(flat[: flat.size // k], K - k)]))
        res = []
        for nz, (m, ncol, at) in zip(fast(*ins), outs, strict=True):
            d = np.zeros(m * ncol)
            d[at] = nz
            res.append(d.reshape(m, ncol)[:, : ncol // K * k])
        return res[0] if len(res) == 1 else tuple(res)


class SparseFunction:
    """A CasADi function of one sparse matrix output, evaluated straight into SciPy CSR: the
    pattern is converted once, each call returns the nonzeros as one dense vector (much
    faster than converting a ``DM`` element by element).

    Example
    -------
    >>> import casadi as ca
    >>> x = ca.SX.sym("x", 2)
    >>> f = SparseFunction([x], ca.diag(x))
    >>> f(np.array([1.0, 2.0])).toarray().tolist()
    [[1.0, 0.0], [0.0, 2.0]]
    """

    def __init__(self, inputs, expr: ca.SX) -> None:
        expr = ca.SX(expr)
        self.shape = expr.shape
        colind, row = expr.sparsity().get_ccs()
        # CSC of expr == CSR of its transpose
        self.indptr = np.asarray(colind, dtype=np.int64)
        self.indices = np.asarray(row, dtype=np.int64)
        self.f = ca.Function("sparse_f", list(inputs), [expr.nz[:] if expr.nnz() else ca.SX(0, 1)])
        self.fast = FastFunction(self.f)

    def values(self, *args) -> np.ndarray:
        """The nonzeros (in CSC order of the expression)."""
        return self.fast(*args)[0] if self.indices.size else np.zeros(0)

    def __call__(self, *args) -> sp.csr_matrix:
        data = self.values(*args)
        return sp.csc_matrix((data, self.indices, self.indptr), shape=self.shape).tocsr()

    def csc(self, *args) -> sp.csc_matrix:
        """The value as SciPy CSC (the expression's own order: no conversion)."""
        return sp.csc_matrix((self.values(*args), self.indices, self.indptr), shape=self.shape)

    def dense(self, *args) -> np.ndarray:
        """The value as a dense NumPy array (for small matrices: no SciPy object made).

        >>> import casadi as ca
        >>> x = ca.SX.sym("x", 2)
        >>> SparseFunction([x], ca.diag(x)).dense(np.array([1.0, 2.0])).tolist()
        [[1.0, 0.0], [0.0, 2.0]]
        """
        out = np.zeros(self.shape)
        if self.indices.size:
            if not hasattr(self, "_cols"):
                self._cols = major_index(self.indptr)
            out[self.indices, self._cols] = self.values(*args)
        return out
