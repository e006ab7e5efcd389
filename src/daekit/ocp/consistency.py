"""Boundary conditions against the invariant manifold: redundancy detection and diagnosis.

A reduced (index-1) DAE is equivalent to the original model only on the manifold where its
invariants vanish; the transcription imposes them at the initial time, and exact dynamics
keep them at every later time, the final time included. Boundary conditions are therefore
only meaningful *along* the manifold: at each end point the admissible directions are the
null space ``N`` of the Jacobian of ``[alg; invariants]`` with respect to ``(x, z, w)``.

Full periodicity ``x(T) = x(0)`` of a pendulum imposes ``dim x`` conditions, but the states
at both ends live on manifolds of dimension ``dim x - (number of invariants)``, so only that
many of the periodicity conditions are independent: the rest are implied and, imposed
anyway, make the NLP's constraint Jacobian (nearly) rank deficient, which IPOPT punishes
with failed restorations.

:func:`analyze_boundary` computes ``A = J_bc * blockdiag(N_0, N_T)`` at the initial guess and
keeps an independent subset of the rows (column-pivoted QR of ``A^T``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

__all__ = ["BoundaryAnalysis", "independent_rows", "analyze_boundary", "null_basis"]


@dataclass
class BoundaryAnalysis:
    """Result of :func:`analyze_boundary`.

    Attributes
    ----------
    labels : list of str
        One label per boundary condition, e.g. ``"periodic p[0]"``.
    rank : int
        Rank of the boundary conditions' Jacobian restricted to the invariant manifold.
    kept, dropped : list of int
        Indices of the conditions imposed and of those implied by the others (redundant).
    singular_values : numpy.ndarray
        Of the restricted Jacobian (shows how close to rank deficient it is).
    restricted : numpy.ndarray
        The restricted Jacobian itself (rows = conditions).
    manifold_dims : tuple of int
        Dimension of the manifold at the initial and final point.
    """

    labels: list[str]
    rank: int
    kept: list[int]
    dropped: list[int]
    singular_values: np.ndarray
    restricted: np.ndarray
    manifold_dims: tuple[int, int] = (0, 0)
    notes: list[str] = field(default_factory=list)

    @property
    def n_conditions(self) -> int:
        return len(self.labels)

    @property
    def redundant(self) -> bool:
        return bool(self.dropped)


def null_basis(J: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis of the null space of ``J`` (columns)."""
    J = np.atleast_2d(np.asarray(J, dtype=float))
    if J.shape[0] == 0:
        return np.eye(J.shape[1])
    return sla.null_space(J, rcond=tol)


def independent_rows(A: np.ndarray, tol: float = 1e-7) -> tuple[int, list[int], list[int]]:
    """Rank of ``A`` and an independent subset of its rows (column-pivoted QR of ``A^T``).

    Returns ``(rank, kept, dropped)`` with index lists in increasing order. A row is dropped
    when it is (numerically) a combination of the kept ones; the threshold is relative to the
    largest pivot, ``tol * max(1, |R_00|)``.

    >>> independent_rows(np.array([[1.0, 0.0], [2.0, 0.0], [0.0, 1.0]]))
    (2, [1, 2], [0])
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    m = A.shape[0]
    if m == 0:
        return 0, [], []
    if A.shape[1] == 0:
        return 0, [], list(range(m))
    _, R, piv = sla.qr(A.T, pivoting=True, mode="economic")
    d = np.abs(np.diag(R))
    ref = max(1.0, float(d[0])) if d.size else 1.0
    rank = int(np.sum(d > tol * ref))
    return rank, sorted(int(i) for i in piv[:rank]), sorted(int(i) for i in piv[rank:])


def analyze_boundary(
    labels: list[str],
    J_bc: np.ndarray,
    J_man0: np.ndarray,
    J_manT: np.ndarray,
    tol: float = 1e-7,
) -> BoundaryAnalysis:
    """Rank of boundary conditions on the manifold and an independent subset.

    Parameters
    ----------
    labels : list of str
        One per condition.
    J_bc : array (n_bc, 2 n)
        Jacobian of the conditions with respect to ``(v_0, v_T)``, ``v = (x, z, w)``.
    J_man0, J_manT : array (n_man, n)
        Jacobians of ``[alg; invariants]`` with respect to ``v`` at the initial and final point.

    >>> # one state, no manifold constraint: x(0) = 1 and 2 x(0) = 2 are one condition
    >>> a = analyze_boundary(["a", "b"], np.array([[1.0, 0], [2.0, 0]]), np.zeros((0, 1)),
    ...                      np.zeros((0, 1)))
    >>> a.rank, a.dropped
    (1, [0])
    """
    N0 = null_basis(J_man0)
    NT = null_basis(J_manT)
    n = J_man0.shape[1]
    J_bc = np.atleast_2d(np.asarray(J_bc, dtype=float)).reshape(len(labels), 2 * n)
    A = np.hstack([J_bc[:, :n] @ N0, J_bc[:, n:] @ NT])
    rank, kept, dropped = independent_rows(A, tol)
    sv = np.linalg.svd(A, compute_uv=False) if A.size else np.zeros(0)
    return BoundaryAnalysis(
        labels=list(labels),
        rank=rank,
        kept=kept,
        dropped=dropped,
        singular_values=sv,
        restricted=A,
        manifold_dims=(N0.shape[1], NT.shape[1]),
    )
