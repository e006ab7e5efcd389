"""Projection onto the consistency manifold ``{alg = 0, invariants = 0}``.

After an integration step the states of an index-1 reduction drift off the manifold on which
the invariants hold (the pendulum's ``c`` and ``c'``). A Gauss--Newton *minimum-norm*
projection moves the states back by the smallest change in ``x`` (the algebraic unknowns ``z``
follow freely, as they are defined by ``alg = 0``): each iteration solves
``min ||dx||^2 + eps ||dz||^2  s.t.  J_x dx + J_z dz = -h`` with ``h = [alg; invariants]``
through the pseudo-inverse. See Hairer, Lubich, Wanner, *Geometric Numerical Integration*,
ch. IV.4.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import SimulationError

__all__ = ["Projector"]


class Projector:
    """Projects ``(x, z)`` onto ``{alg = 0, invariants = 0}`` at a given time, inputs, params.

    Parameters
    ----------
    r : ReducedDAE
    z_weight : float
        How cheap a change in ``z`` is relative to ``x`` (``z`` columns are scaled by it).

    Example
    -------
    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> from daekit.simulate.projection import Projector
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x", 2); z = ca.SX.sym("z")
    >>> r = ReducedDAE(t, x, z, ca.SX(0, 1), ca.SX(0, 1), ca.vertcat(-x[1], x[0]), z - x[0],
    ...     ca.dot(x, x) - 1, ["circle"], ["x[0]", "x[1]"], ["z"], [], [], np.zeros(0))
    >>> xp, zp, dist = Projector(r)(0.0, np.array([1.1, 0.0]), np.array([1.1]), [], [])
    >>> np.round(xp, 12).tolist(), round(float(zp[0]), 12)
    ([1.0, 0.0], 1.0)
    """

    def __init__(self, r, z_weight: float = 1e4) -> None:
        self.nx, self.nz = r.nx, r.nz
        h = ca.vertcat(r.alg, r.invariants) if r.invariants.numel() else r.alg
        w = ca.vertcat(r.x, r.z)
        self.fun = ca.Function("proj", [r.t, w, r.u, r.p], [h, ca.jacobian(h, w)])
        self.scale = np.concatenate([np.ones(self.nx), np.full(self.nz, z_weight)])

    def __call__(self, t, x, z, u, p, tol: float = 1e-13, max_iter: int = 20):
        """Return ``(x, z, |dx|)``; raises :class:`SimulationError` if it cannot converge."""
        w = np.concatenate([np.asarray(x, float).ravel(), np.asarray(z, float).ravel()])
        w0 = w.copy()
        u = np.asarray(u, dtype=float).ravel()
        p = np.asarray(p, dtype=float).ravel()
        res = np.inf
        for _ in range(max_iter):
            hv, J = self.fun(t, w, u, p)
            hv = np.asarray(hv, dtype=float).ravel()
            res = float(np.max(np.abs(hv), initial=0.0))
            if res <= tol * (1.0 + float(np.max(np.abs(w), initial=0.0))):
                break
            Js = np.asarray(J.full(), dtype=float) * self.scale
            dy = np.linalg.lstsq(Js, -hv, rcond=1e-12)[0]
            w = w + self.scale * dy
            if not np.all(np.isfinite(w)):
                break
        else:
            hv = np.asarray(self.fun(t, w, u, p)[0], dtype=float).ravel()
            res = float(np.max(np.abs(hv), initial=0.0))
        if not np.isfinite(res) or res > 1e-8 * (1.0 + float(np.max(np.abs(w), initial=0.0))):
            raise SimulationError(
                f"projection onto the invariants failed at t = {t:g} (residual {res:.3g}); the "
                "constraint Jacobian may have lost rank there, or the step left the manifold too "
                "far: use a finer output grid or tighter tolerances",
                t=float(t),
            )
        dx = float(np.max(np.abs(w[: self.nx] - w0[: self.nx]), initial=0.0))
        return w[: self.nx], w[self.nx:], dx
