"""Pendulums: the planar pendulum, Pryce's chained pendula, and a chain of N links.

See ``reference-problems.md``, sections 2 and 3.
"""

from __future__ import annotations

import casadi as ca

from ..errors import ModelError
from ..model import Model

__all__ = ["pendulum_planar", "chained_pendula", "planar_chain"]


def pendulum_planar(g: float = 9.81, L: float = 1.0) -> Model:
    """The planar pendulum in second-order Cartesian form (unit mass, pivot at the origin).

    ``x'' = x T`` (``newton_x``), ``y'' = y T - g`` (``newton_y``), ``0 = x^2 + y^2 - L^2``
    (``rod``); states ``x``, ``y`` (``y`` up), algebraic ``T`` (rod force per unit length,
    negative under tension); parameters ``g``, ``L``.

    Source: Hairer & Wanner, *Solving ODEs II*, ch. VII; Pryce, BIT 41 (2001).
    Differential index 3, DOF 2. Exact solution when released at rest from the angle
    ``theta0``: ``sin(theta/2) = k cd(w t | k^2)``, ``k = sin(theta0/2)``, ``w = sqrt(g/L)``,
    ``x = L sin theta``, ``y = -L cos theta``, ``T = g (3 y - 2 y0) / L^2``; see
    :func:`daekit.examples.exact.pendulum_planar`.

    >>> m = pendulum_planar()
    >>> m.unknown_names, m.equation_names
    (['x', 'y', 'T'], ['newton_x', 'newton_y', 'rod'])
    """
    m = Model("pendulum_planar")
    x = m.state("x")
    y = m.state("y")
    T = m.algebraic("T")
    grav = m.parameter("g", g)
    Lp = m.parameter("L", L)
    m.equation(m.der(x, 2) - x * T, name="newton_x")
    m.equation(m.der(y, 2) - (y * T - grav), name="newton_y")
    m.equation(x**2 + y**2 - Lp**2, name="rod")
    return m


def chained_pendula(p: int = 2, G: float = 9.8, L: float = 1.0, c: float = 0.1) -> Model:
    """Pryce's chain of ``p`` pendula whose rod lengths depend on the previous rod force.

    For ``i = 1..p``: ``x_i'' + x_i l_i = 0`` (``newton_x{i}``), ``y_i'' + y_i l_i - G = 0``
    (``newton_y{i}``), ``x_i^2 + y_i^2 - (L + c l_{i-1})^2 = 0`` (``rod{i}``), with ``l_0 = 0``.
    Unknowns in the order ``x1, y1, l1, x2, y2, l2, ...``; equations in the listed order.

    Source: J. D. Pryce, BIT 41 (2001); Nedialkov & Pryce, DAESA examples.
    Structural index ``2p + 1``, DOF ``2p``; the structural analysis succeeds. For ``p = 2`` the
    offsets are ``c = (2, 2, 4, 0, 0, 2)``, ``d = (4, 4, 2, 2, 2, 0)``.

    >>> chained_pendula(2).unknown_names
    ['x1', 'y1', 'l1', 'x2', 'y2', 'l2']
    """
    if int(p) != p or p < 1:
        raise ModelError(
            f"chained_pendula: p (the number of pendula) must be an integer >= 1, got {p!r}"
        )
    p = int(p)
    m = Model(f"chained_pendula_{p}")
    Gp = m.parameter("G", G)
    Lp = m.parameter("L", L)
    cp = m.parameter("c", c)
    xs, ys, ls = [], [], []
    for i in range(1, p + 1):
        xs.append(m.state(f"x{i}"))
        ys.append(m.state(f"y{i}"))
        ls.append(m.algebraic(f"l{i}"))
    prev = 0
    for i in range(p):
        x, y, lam = xs[i], ys[i], ls[i]
        m.equation(m.der(x, 2) + x * lam, name=f"newton_x{i + 1}")
        m.equation(m.der(y, 2) + y * lam - Gp, name=f"newton_y{i + 1}")
        m.equation(x**2 + y**2 - (Lp + cp * prev) ** 2, name=f"rod{i + 1}")
        prev = lam
    return m


def planar_chain(N: int = 5, g: float = 9.81) -> Model:
    """A planar chain of ``N`` unit point masses linked by massless rods of length 1.

    Link 1 hangs from a fixed pivot at the origin; mass ``k`` is at ``q_k`` (``y`` up), rod ``k``
    joins ``q_{k-1}`` and ``q_k`` (``q_0 = 0``) with the constraint
    ``0 = (|q_k - q_{k-1}|^2 - 1)/2`` and the multiplier ``lam_k``. First-order form:

    - ``kinematics``: ``q' = v`` (2N)
    - ``newton``: ``v_k' = -g e2 - lam_k (q_k - q_{k-1}) + lam_{k+1} (q_{k+1} - q_k)`` (2N)
    - ``rod``: ``0 = (|q_k - q_{k-1}|^2 - 1)/2`` (N)

    Unknowns ``q`` (2N, ``q[2k], q[2k+1]`` the position of mass ``k+1``), ``v`` (2N), ``lam``
    (N): ``5N`` equations. Built with vector (sliced) CasADi expressions, so ``N = 2000`` builds
    in a fraction of a second. Differential index 3, DOF ``2N``.

    >>> m = planar_chain(3)
    >>> m.n_equations, m.n_unknowns
    (15, 15)
    """
    if int(N) != N or N < 1:
        raise ModelError(
            f"planar_chain: N (the number of links) must be an integer >= 1, got {N!r}"
        )
    N = int(N)
    m = Model(f"planar_chain_{N}")
    q = m.state("q", 2 * N)
    v = m.state("v", 2 * N)
    lam = m.algebraic("lam", N)
    grav = m.parameter("g", g)
    Q = ca.reshape(q, 2, N)  # column k: position of mass k+1
    D = Q - ca.horzcat(ca.SX.zeros(2, 1), Q[:, : N - 1])  # rod vectors q_k - q_{k-1}
    lam_row = ca.repmat(lam.T, 2, 1)
    F = -D * lam_row  # force of rod k on mass k
    if N > 1:
        F = F + ca.horzcat(D[:, 1:] * lam_row[:, 1:], ca.SX.zeros(2, 1))  # rod k+1 on mass k
    gvec = ca.repmat(ca.vertcat(0, -grav), N, 1)
    m.equation(m.der(q) - v, name="kinematics")
    m.equation(m.der(v) - (gvec + ca.vec(F)), name="newton")
    m.equation(0.5 * (ca.sum1(D * D).T - 1), name="rod")
    return m
