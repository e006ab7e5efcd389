"""The Cartesian double pendulum (index 3) and its minimal-coordinates reference solution.

Point masses ``m1`` at ``p1`` and ``m2`` at ``p2`` (``y`` up) on massless rods ``L1`` (pivot to
``p1``) and ``L2`` (``p1`` to ``p2``), gravity ``g``; the multipliers ``lam`` of the rod
constraints ``(|p1|^2 - L1^2)/2`` and ``(|p2 - p1|^2 - L2^2)/2``. Issue 8 item 3: ``m1 = 1``,
``m2 = 0.5``, ``L1 = 1``, ``L2 = 0.7``, ``g = 9.81``, released at rest from the angles 0.8 and
-0.4 rad from the downward vertical. The motion is chaotic: compare over a few seconds only at
the tolerance asked for.

>>> m = double_pendulum()
>>> m.n_equations, m.n_unknowns
(10, 10)
>>> ref = double_pendulum_reference([0.0, 1.0])
>>> bool(abs(ref["p1"][0, 0] - np.sin(0.8)) < 1e-15)
True
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model import Model

__all__ = ["double_pendulum", "double_pendulum_start", "double_pendulum_reference"]

M1, M2, L1, L2, G = 1.0, 0.5, 1.0, 0.7, 9.81
THETA0 = (0.8, -0.4)


def double_pendulum(m1: float = M1, m2: float = M2, l1: float = L1, l2: float = L2,
                    g: float = G) -> Model:
    """The Cartesian double pendulum as a first-order index-3 Model (``p1, v1, p2, v2``,
    ``lam``)."""
    m = Model("double_pendulum")
    p1, v1 = m.state("p1", 2), m.state("v1", 2)
    p2, v2 = m.state("p2", 2), m.state("v2", 2)
    lam = m.algebraic("lam", 2)
    ma, mb = m.parameter("m1", m1), m.parameter("m2", m2)
    la, lb = m.parameter("L1", l1), m.parameter("L2", l2)
    grav = m.parameter("g", g)
    e2 = ca.DM([0, 1])
    d = p2 - p1
    m.equation(m.der(p1) - v1, name="kinematics1")
    m.equation(m.der(p2) - v2, name="kinematics2")
    m.equation(ma * m.der(v1) + ma * grav * e2 + lam[0] * p1 - lam[1] * d, name="newton1")
    m.equation(mb * m.der(v2) + mb * grav * e2 + lam[1] * d, name="newton2")
    m.equation(0.5 * (ca.dot(p1, p1) - la**2), name="rod1")
    m.equation(0.5 * (ca.dot(d, d) - lb**2), name="rod2")
    return m


def double_pendulum_start(theta=THETA0, l1: float = L1, l2: float = L2) -> dict:
    """Positions (and zero velocities) of the release at rest from the angles ``theta``."""
    a, b = theta
    p1 = np.array([l1 * np.sin(a), -l1 * np.cos(a)])
    p2 = p1 + np.array([l2 * np.sin(b), -l2 * np.cos(b)])
    return {"p1": p1, "p2": p2, "v1": np.zeros(2), "v2": np.zeros(2)}


def double_pendulum_reference(t, theta=THETA0, m1: float = M1, m2: float = M2, l1: float = L1,
                              l2: float = L2, g: float = G, rtol: float = 1e-12) -> dict:
    """``p1, p2`` at the times ``t`` from the angles' equations of motion (Lagrange in minimal
    coordinates), SciPy ``solve_ivp`` DOP853 at ``rtol = atol = rtol``."""
    from scipy.integrate import solve_ivp

    def rhs(_, y):
        a, b, da, db = y
        c, s = np.cos(a - b), np.sin(a - b)
        M = np.array([[(m1 + m2) * l1**2, m2 * l1 * l2 * c], [m2 * l1 * l2 * c, m2 * l2**2]])
        f = np.array([-m2 * l1 * l2 * db**2 * s - (m1 + m2) * g * l1 * np.sin(a),
                      m2 * l1 * l2 * da**2 * s - m2 * g * l2 * np.sin(b)])
        return [da, db, *np.linalg.solve(M, f)]

    t = np.asarray(t, dtype=float)
    sol = solve_ivp(rhs, (t[0], t[-1]), [theta[0], theta[1], 0.0, 0.0], method="DOP853",
                    t_eval=t, rtol=rtol, atol=rtol)
    a, b = sol.y[0], sol.y[1]
    p1 = np.column_stack([l1 * np.sin(a), -l1 * np.cos(a)])
    p2 = p1 + np.column_stack([l2 * np.sin(b), -l2 * np.cos(b)])
    return {"p1": p1, "p2": p2}
