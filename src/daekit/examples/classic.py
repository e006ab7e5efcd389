"""Classic DAEs with exact solutions (Brenan et al., Jay, Arevalo) and two index-1 problems of
the Test Set for IVP Solvers (chemical Akzo Nobel, transistor amplifier).

See ``reference-problems.md``, sections 5 and 6; exact solutions and published final values are
in :mod:`daekit.examples.exact`.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model import Model

__all__ = [
    "brenan",
    "e1",
    "jay",
    "e2",
    "arevalo",
    "e3",
    "chemakzo",
    "transistor_amplifier",
    "CHEMAKZO_DATA",
    "TRANSISTOR_DATA",
]


def brenan() -> Model:
    """E1: ``y1' - t y2' + y1 - (1 + t) y2 = 0``, ``y2 - sin t = 0``.

    Source: Brenan, Campbell, Petzold, *Numerical Solution of IVPs in DAEs* (SIAM 1996), ch. 4.
    Differential index 1, DOF 1 (``y2'`` appears, but ``y2`` is fixed by the second equation,
    whose one differentiation gives ``y2'``). With ``y(0) = (1, 0)`` the exact solution is
    ``y1 = e^-t + t sin t``, ``y2 = sin t``.

    >>> brenan().equation_names
    ['dynamic', 'constraint']
    """
    m = Model("brenan")
    y1 = m.state("y1")
    y2 = m.state("y2")
    t = m.t
    m.equation(m.der(y1) - t * m.der(y2) + y1 - (1 + t) * y2, name="dynamic")
    m.equation(y2 - ca.sin(t), name="constraint")
    return m


e1 = brenan


def jay() -> Model:
    """E2: ``y1' = y1 y2 w``, ``y2' = y1^2 y2^2 - 3 y2^2 w``, ``0 = y1^2 y2 - 1``.

    Source: L. Jay, "Convergence of a class of Runge-Kutta methods for differential-algebraic
    systems of index 2", BIT 33 (1993), example 7. Differential index 2 (``w`` algebraic), DOF 1.
    With ``y(0) = (1, 1)``: ``y1 = e^t``, ``y2 = e^-2t``, ``w = e^2t``.

    >>> jay().unknown_names
    ['y1', 'y2', 'w']
    """
    m = Model("jay")
    y1 = m.state("y1")
    y2 = m.state("y2")
    w = m.algebraic("w")
    m.equation(m.der(y1) - y1 * y2 * w, name="ode1")
    m.equation(m.der(y2) - (y1**2 * y2**2 - 3 * y2**2 * w), name="ode2")
    m.equation(y1**2 * y2 - 1, name="constraint")
    return m


e2 = jay


def arevalo() -> Model:
    """E3: a particle on the unit circle, ``x' = u``, ``y' = v``, ``u' = 2 y + x l``,
    ``v' = -2 x + y l``, ``0 = x^2 + y^2 - 1``.

    Source: C. Arevalo, "Matching the structure of DAEs and multistep methods", PhD thesis,
    Lund (1995). Differential index 3, DOF 2. Exact solution on ``t in [1, 5]``:
    ``(x, y) = (sin t^2, cos t^2)``, ``(u, v) = (2t cos t^2, -2t sin t^2)``, ``l = -4 t^2``.

    >>> arevalo().equation_names
    ['kinematics_x', 'kinematics_y', 'dynamics_u', 'dynamics_v', 'circle']
    """
    m = Model("arevalo")
    x = m.state("x")
    y = m.state("y")
    u = m.state("u")
    v = m.state("v")
    lam = m.algebraic("l")
    m.equation(m.der(x) - u, name="kinematics_x")
    m.equation(m.der(y) - v, name="kinematics_y")
    m.equation(m.der(u) - (2 * y + x * lam), name="dynamics_u")
    m.equation(m.der(v) - (-2 * x + y * lam), name="dynamics_v")
    m.equation(x**2 + y**2 - 1, name="circle")
    return m


e3 = arevalo

#: Data of the chemical Akzo Nobel problem (Test Set for IVP Solvers, Bari).
CHEMAKZO_DATA = {
    "k1": 18.7,
    "k2": 0.58,
    "k3": 0.09,
    "k4": 0.42,
    "K": 34.4,
    "klA": 3.3,
    "Ks": 115.83,
    "pCO2": 0.9,
    "H": 737.0,
}


def chemakzo() -> Model:
    """The chemical Akzo Nobel problem: 5 ODEs and one algebraic equation, ``t in [0, 180]``.

    Unknowns ``y`` (5, states) and ``y6`` (algebraic); equations ``ode`` (5) and ``equilibrium``.
    The rates ``r1 = k1 y1^4 sqrt(y2)``, ``r2 = k2 y3 y4``, ``r3 = (k2/K) y1 y5``,
    ``r4 = k3 y1 y4^2``, ``r5 = k4 y6^2 sqrt(y2)``, ``Fin = klA (pCO2/H - y2)``; the data are
    parameters named as in :data:`CHEMAKZO_DATA`.

    Source: F. Mazzia, C. Magherini, F. Iavernaro, *Test Set for IVP Solvers*, University of
    Bari, problem "chemakzo". Differential index 1, DOF 5. The initial values and the published
    ``y(180)`` are :data:`daekit.examples.exact.CHEMAKZO_Y0` and ``CHEMAKZO_YEND``.

    >>> chemakzo().n_equations
    6
    """
    m = Model("chemakzo")
    y = m.state("y", 5)
    y6 = m.algebraic("y6")
    P = {k: m.parameter(k, v) for k, v in CHEMAKZO_DATA.items()}
    y1, y2, y3, y4, y5 = (y[i] for i in range(5))
    r1 = P["k1"] * y1**4 * ca.sqrt(y2)
    r2 = P["k2"] * y3 * y4
    r3 = P["k2"] / P["K"] * y1 * y5
    r4 = P["k3"] * y1 * y4**2
    r5 = P["k4"] * y6**2 * ca.sqrt(y2)
    fin = P["klA"] * (P["pCO2"] / P["H"] - y2)
    rhs = ca.vertcat(
        -2 * r1 + r2 - r3 - r4,
        -0.5 * r1 - r4 - 0.5 * r5 + fin,
        r1 - r2 + r3,
        -r2 + r3 - 2 * r4,
        r2 - r3 + r5,
    )
    m.equation(m.der(y) - rhs, name="ode")
    m.equation(P["Ks"] * y1 * y4 - y6, name="equilibrium")
    return m


#: Data of the transistor amplifier (Test Set for IVP Solvers, Bari).
TRANSISTOR_DATA = {
    "Ub": 6.0,
    "Uf": 0.026,
    "alpha": 0.99,
    "beta": 1e-6,
    "R0": 1000.0,
    **{f"R{k}": 9000.0 for k in range(1, 10)},
    **{f"C{k}": k * 1e-6 for k in range(1, 6)},
}


def transistor_amplifier() -> Model:
    """The transistor amplifier: 8 node voltages, ``M y' = f(t, y)`` with ``M`` of rank 5.

    Unknowns ``y`` (8, states: every voltage appears differentiated, in differences such as
    ``y1' - y2'``); equations ``node1`` ... ``node8`` as in the reference, input
    ``Ue(t) = 0.1 sin(200 pi t)`` written with ``m.t``, ``g(x) = beta (exp(x/Uf) - 1)``;
    the data are parameters named as in :data:`TRANSISTOR_DATA`.

    Source: F. Mazzia, C. Magherini, F. Iavernaro, *Test Set for IVP Solvers*, University of
    Bari, problem "transamp"; E. Hairer, G. Wanner, *Solving ODEs II*. Differential index 1,
    DOF 5 (three sums of node equations are algebraic). Structural analysis sees only the
    pattern: it matches each node equation to its own voltage derivative (index 0) and
    ``structurally_ok`` is False because ``M`` is singular. ``t in [0, 0.2]``; initial values
    and the published ``y(0.2)`` are in :mod:`daekit.examples.exact`.

    >>> transistor_amplifier().n_equations
    8
    """
    m = Model("transistor_amplifier")
    y = m.state("y", 8)
    P = {k: m.parameter(k, v) for k, v in TRANSISTOR_DATA.items()}
    dy = m.der(y)
    ue = 0.1 * ca.sin(200 * np.pi * m.t)

    def g(x):
        return P["beta"] * (ca.exp(x / P["Uf"]) - 1)

    Ub, al = P["Ub"], P["alpha"]
    R, C = (lambda k: P[f"R{k}"]), (lambda k: P[f"C{k}"])
    Y = [None] + [y[i] for i in range(8)]  # 1-based
    D = [None] + [dy[i] for i in range(8)]
    g23 = g(Y[2] - Y[3])
    g56 = g(Y[5] - Y[6])
    eqs = [
        C(1) * (D[1] - D[2]) + (Y[1] - ue) / R(0),
        -C(1) * (D[1] - D[2]) + Y[2] / R(1) + (Y[2] - Ub) / R(2) + (1 - al) * g23,
        C(2) * D[3] + Y[3] / R(3) - g23,
        C(3) * (D[4] - D[5]) + (Y[4] - Ub) / R(4) + al * g23,
        -C(3) * (D[4] - D[5]) + Y[5] / R(5) + (Y[5] - Ub) / R(6) + (1 - al) * g56,
        C(4) * D[6] + Y[6] / R(7) - g56,
        C(5) * (D[7] - D[8]) + (Y[7] - Ub) / R(8) + al * g56,
        -C(5) * (D[7] - D[8]) + Y[8] / R(9),
    ]
    for k, e in enumerate(eqs, start=1):
        m.equation(e, name=f"node{k}")
    return m
