"""The flexible slider crank (Simeon; the "crank" problem of the Test Set for IVP Solvers).

A rigid crank (angle ``phi1``, driven at the constant speed ``Omega``), an elastic connecting rod
(angle ``phi2`` of its floating frame, four modal coordinates ``q1 .. q4``) and a slider
(position ``x3``) on the ground line. The model is a constrained mechanical system

    p' = v,   v' = a,   M(p) a = f(p, v) - G(p)^T lam,   0 = g(p) + r(t)   (index 3)

with ``p = (phi1, phi2, x3, q1, q2, q3, q4)``, ``G = dg/dp``; the Test Set's default form (index
2) replaces the position constraints by the velocity constraints ``0 = G(p) v + r'(t)``. First
order and semi-explicit: 7 positions, 7 velocities, 7 accelerations (algebraic), 3 multipliers:
24 unknowns, as in the Test Set.

Derived here (not transcribed from the Test Set's Fortran, which could not be consulted; the
geometry and material data are Simeon's): material point ``s in [0, L2]`` of the rod at

    r(s) = l1 (cos phi1, sin phi1) + R(phi2) (s + u(s), w(s)),
    w = q1 sin(pi s / L2) + q2 sin(2 pi s / L2)          (bending, pinned at both joints)
    u = q3 sin(pi s / (2 L2)) + q4 sin(3 pi s / (2 L2))    (axial, fixed at the crank joint)

kinetic energy ``T = J1 phi1'^2 / 2 + rho A / 2 int |r_t|^2 ds + m3 x3'^2 / 2``, strain energy
``V = 1/2 int (E I w''^2 + E A u'^2) ds`` (Euler--Bernoulli, ``A = b h``, ``I = b h^3 / 12``),
the integrals by 24-point Gauss--Legendre quadrature (exact to rounding for these integrands);
``M = d^2 T / dv^2`` and ``f = dT/dp - (d^2 T / dv dp) v - dV/dp`` (Lagrange's equations,
by CasADi's derivatives). Constraints: the rod's end on the slider,
``l1 cos phi1 + (L2 + u(L2)) cos phi2 - x3 = 0``, ``l1 sin phi1 + (L2 + u(L2)) sin phi2 = 0``,
and the drive ``phi1 - Omega t = 0``.

Index and DOF (derived, for every Young's modulus ``EE > 0``: ``EE`` scales the stiffness
terms of ``f`` only, never the structure): ``M`` is positive definite and ``G`` has full rank
3 (the drive row is ``e1``; the slider rows contain ``-x3`` and ``(L2 + u) cos phi2`` in
``phi2``'s column), so ``[[M, G^T], [G, 0]]`` is nonsingular.

* Index-3 form: ``g + r = 0`` differentiated once gives ``G v + r' = 0``, twice
  ``G a + (G' v) + r'' = 0``, which with the equations of motion determines ``a`` and ``lam``;
  their derivatives need one more differentiation: **index 3**, and ``14 - 3 - 3 =`` **8 DOF**
  (positions and velocities less the position and the velocity constraints).
* Index-2 form (the Test Set's default): ``G v + r' = 0`` differentiated once determines ``a``
  and ``lam``, once more their derivatives: **index 2**, ``14 - 3 =`` **11 DOF** (the position
  constraints are not imposed: they hold only through the initial values).

Sources: B. Simeon, "Modelling a flexible slider crank mechanism by a mixed system of DAEs and
PDEs", Math. Modelling of Systems 2 (1996) 1-18; F. Mazzia, C. Magherini, F. Iavernaro, *Test
Set for IVP Solvers*, University of Bari, problem "crank" (contributed by B. Simeon).

>>> import daekit as dk
>>> m = slider_crank()
>>> m.n_unknowns, m.n_equations
(24, 24)
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model import Model

#: Simeon's data: crank length and inertia, rod length, cross-section (b, h), density,
#: Young's modulus, slider mass, crank speed.
SLIDER_CRANK_DATA = {
    "l1": 0.15, "L2": 0.30, "J1": 0.002727, "b": 0.008, "h": 0.008, "rho": 7870.0,
    "EE": 2.0e11, "m3": 0.075552, "Omega": 150.0,
}

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(24)


def slider_crank(EE: float = 2.0e11, index: int = 2) -> Model:
    """The flexible slider crank in first-order form, 24 unknowns (see the module docstring).

    Parameters
    ----------
    EE : float
        Young's modulus of the connecting rod (a model parameter ``EE``; the Test Set's value
        is ``2e11``; ``2e5`` makes the rod soft).
    index : int
        ``2``: velocity constraints (the Test Set's default form; index 2, 11 DOF); ``3``:
        position constraints (index 3, 8 DOF).

    Unknowns: states ``p`` (7: ``phi1, phi2, x3, q1 .. q4``) and ``v`` (7), algebraic ``a``
    (7, the accelerations) and ``lam`` (3); equations ``kin`` (``p' = v``), ``acc``
    (``v' = a``), ``motion`` (``M a - f + G^T lam``) and ``joint`` (constraints).

    >>> import daekit as dk
    >>> a = dk.analyze(slider_crank(EE=2e8))
    >>> a.index, a.dof
    (2, 11)
    """
    if index not in (2, 3):
        raise ValueError(f"slider_crank: index must be 2 or 3, got {index!r}")
    m = Model("slider_crank" if index == 2 else "slider_crank_index3")
    P = {k: m.parameter(k, float(EE) if k == "EE" else v) for k, v in SLIDER_CRANK_DATA.items()}
    p = m.state("p", 7)
    v = m.state("v", 7)
    acc = m.algebraic("a", 7)
    lam = m.algebraic("lam", 3)
    T_kin, V_el, g = _energies(p, v, P)
    M = ca.hessian(T_kin, v)[0]
    f = ca.gradient(T_kin, p) - ca.mtimes(ca.jacobian(ca.gradient(T_kin, v), p), v) \
        - ca.gradient(V_el, p)
    G = ca.jacobian(g, p)
    r = ca.vertcat(0, 0, -P["Omega"] * m.t)
    m.equation(m.der(p) - v, name="kin")
    m.equation(m.der(v) - acc, name="acc")
    m.equation(ca.mtimes(M, acc) - f + ca.mtimes(G.T, lam), name="motion")
    if index == 3:
        m.equation(g + r, name="joint")
    else:
        m.equation(ca.mtimes(G, v) + ca.jacobian(r, m.t), name="joint")
    return m


def _energies(p, v, P):
    """Kinetic and strain energy and the position constraints ``g`` (see the module
    docstring), with the integrals over the rod by Gauss--Legendre quadrature."""
    phi1, phi2, x3 = p[0], p[1], p[2]
    q = p[3:7]
    L, l1 = P["L2"], P["l1"]
    area = P["b"] * P["h"]
    inertia = P["b"] * P["h"] ** 3 / 12
    rot = ca.vertcat(ca.horzcat(ca.cos(phi2), -ca.sin(phi2)),
                     ca.horzcat(ca.sin(phi2), ca.cos(phi2)))
    crank = l1 * ca.vertcat(ca.cos(phi1), ca.sin(phi1))
    T_rod = 0
    V_el = 0
    for xi, wgt in zip(_NODES, _WEIGHTS):
        s = L * (xi + 1) / 2  # node on [0, L]
        dw = wgt * L / 2  # its weight
        k1, k2 = np.pi / L, 2 * np.pi / L
        c1, c3 = np.pi / (2 * L), 3 * np.pi / (2 * L)
        w = q[0] * ca.sin(k1 * s) + q[1] * ca.sin(k2 * s)
        u = q[2] * ca.sin(c1 * s) + q[3] * ca.sin(c3 * s)
        w_ss = -q[0] * k1**2 * ca.sin(k1 * s) - q[1] * k2**2 * ca.sin(k2 * s)
        u_s = q[2] * c1 * ca.cos(c1 * s) + q[3] * c3 * ca.cos(c3 * s)
        r_s = crank + ca.mtimes(rot, ca.vertcat(s + u, w))
        r_t = ca.jtimes(r_s, p, v)
        T_rod = T_rod + dw * ca.dot(r_t, r_t)
        V_el = V_el + dw * (P["EE"] * inertia * w_ss**2 + P["EE"] * area * u_s**2)
    T_kin = (P["J1"] * v[0] ** 2 + P["rho"] * area * T_rod + P["m3"] * v[2] ** 2) / 2
    V_el = V_el / 2
    u_end = q[2] * np.sin(np.pi / 2) + q[3] * np.sin(3 * np.pi / 2)  # u(L) = q3 - q4
    g = ca.vertcat(l1 * ca.cos(phi1) + (L + u_end) * ca.cos(phi2) - x3,
                   l1 * ca.sin(phi1) + (L + u_end) * ca.sin(phi2),
                   phi1)
    return T_kin, V_el, g
