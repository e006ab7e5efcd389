"""Mechanisms written with the Lagrangian front end (:mod:`daekit.mechanics`).

Each function returns a :class:`daekit.mechanics.LagrangianSystem`; call ``.model()`` for the
index-3 :class:`daekit.Model` and ``.index1()`` for the index-1 form (a
:class:`daekit.reduced.ReducedDAE` with the invariants ``c`` and ``dc/dt``).

- :func:`lagrangian_pendulum3d`: lecture L3, a point mass on a rod, driven by a force ``u``.
- :func:`lagrangian_planar_chain`: ``N`` point masses linked by rods, hanging from a pivot
  (``N = 1`` is the planar pendulum of reference-problems section 2).
- :func:`lagrangian_delta_robot`: lecture L4, three motor-driven arms carrying a platform;
  :func:`lagrangian_delta_robot_home` gives a consistent configuration held at rest.

>>> sys3 = lagrangian_pendulum3d()
>>> sys3.model().unknown_names
['p[0]', 'p[1]', 'p[2]', 'z']
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import ModelError
from ..mechanics import LagrangianSystem
from .lecture import DELTA_DEFAULTS, DELTA_GAMMA, delta_robot_home

__all__ = [
    "lagrangian_pendulum3d",
    "lagrangian_planar_chain",
    "lagrangian_delta_robot",
    "lagrangian_delta_robot_home",
    "DELTA_ROBOT_DATA",
]


def lagrangian_pendulum3d(
    mass: float = 1.0, length: float = 1.0, g: float = 9.81
) -> LagrangianSystem:
    """The 3D pendulum of lecture L3 from its energies: ``T = m |p'|^2 / 2``, ``V = m g p_3``.

    Coordinates ``p`` (3, Cartesian, pivot at the origin, ``e3`` up), constraint
    ``rod = (p.p - L^2)/2``, multiplier ``z`` (the rod tension divided by ``L``), input force
    ``u`` (3), parameters ``m``, ``L``, ``g``. Its index-1 form is the lecture's
    ``[m I, p; p^T, 0] [p''; z] = [u - m g e3; -p'.p']``; invariants ``rod = (p.p - L^2)/2``
    and ``d/dt rod = p.p'``. Differential index 3.

    >>> r = lagrangian_pendulum3d().index1()
    >>> r.x_names[:4], r.z_names[-1], r.u_names
    (['p[0]', 'p[1]', 'p[2]', 'der(p)[0]'], 'z', ['u[0]', 'u[1]', 'u[2]'])
    """
    p = ca.SX.sym("p", 3)
    v = ca.SX.sym("v", 3)
    u = ca.SX.sym("u", 3)
    m, L, gg = ca.SX.sym("m"), ca.SX.sym("L"), ca.SX.sym("g")
    return LagrangianSystem(
        {"p": p},
        v,
        T=0.5 * m * ca.dot(v, v),
        V=m * gg * p[2],
        constraints={"rod": 0.5 * (ca.dot(p, p) - L**2)},
        forces=u,
        inputs={"u": u},
        parameters={"m": (m, mass), "L": (L, length), "g": (gg, g)},
        multipliers="z",
        name="pendulum3d",
    )


def lagrangian_planar_chain(
    N: int = 5, mass: float = 1.0, length: float = 1.0, g: float = 9.81
) -> LagrangianSystem:
    """A planar chain of ``N`` point masses linked by massless rods, from its energies.

    Mass ``k`` (k = 1..N) sits at ``(q[2k-2], q[2k-1])`` (``y`` up); rod ``k`` joins mass
    ``k-1`` and mass ``k`` (mass 0 is the fixed pivot at the origin):
    ``rod[k-1] = (|q_k - q_{k-1}|^2 - L^2)/2``, multiplier ``lam[k-1]``.
    ``T = m |q'|^2 / 2``, ``V = m g sum_k y_k``; parameters ``m``, ``L``, ``g``; no inputs.
    ``N = 1`` is the planar pendulum of reference-problems section 2 (``q = (x, y)``,
    ``lam = -T`` there when ``m = L = 1``). Built with vector CasADi expressions, so large ``N``
    is cheap. Differential index 3, DOF ``2N``.

    >>> ch = lagrangian_planar_chain(3)
    >>> ch.n, ch.n_constraints, ch.is_separable
    (6, 3, True)
    """
    if int(N) != N or N < 1:
        raise ModelError(
            f"lagrangian_planar_chain: N (the number of links) must be an integer >= 1, got {N!r}"
        )
    N = int(N)
    q = ca.SX.sym("q", 2 * N)
    dq = ca.SX.sym("dq", 2 * N)
    m, L, gg = ca.SX.sym("m"), ca.SX.sym("L"), ca.SX.sym("g")
    P = ca.reshape(q, 2, N)  # column k: position of mass k+1
    D = P - ca.horzcat(ca.SX.zeros(2, 1), P[:, : N - 1])  # rod vectors
    rods = 0.5 * (ca.sum1(D * D).T - L**2)
    return LagrangianSystem(
        {"q": q},
        dq,
        T=0.5 * m * ca.dot(dq, dq),
        V=m * gg * ca.sum1(P[1, :].T),
        constraints={"rod": rods},
        parameters={"m": (m, mass), "L": (L, length), "g": (gg, g)},
        multipliers="lam",
        name=f"planar_chain_{N}" if N > 1 else "pendulum_planar",
    )


#: Data of the Lagrangian delta robot: the data of :func:`daekit.examples.delta_robot`, plus
#: the viscous friction ``b`` in the motors [N m s].
DELTA_ROBOT_DATA = {**DELTA_DEFAULTS, "b": 0.0}
_GAMMA = DELTA_GAMMA


def _rz_dm(gamma: float) -> ca.DM:
    c, s = np.cos(gamma), np.sin(gamma)
    return ca.DM([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def lagrangian_delta_robot(**data: float) -> LagrangianSystem:
    """The delta robot of lecture L4 from its energies: three arms driven by motor torques.

    Coordinates: the arm angles ``alpha`` (3, down positive) and the platform position ``p``
    (3, ``e3`` up). Arm ``k`` turns about a horizontal axis at distance ``r`` from the vertical
    axis at azimuth ``gamma_k`` = (0, 2pi/3, 4pi/3); its elbow is at
    ``p_k = R_z(gamma_k) [r + a cos alpha_k, 0, -a sin alpha_k]``; a massless rod of length
    ``L`` joins it to the platform (a point mass ``m_p``):

    - ``T = J |alpha'|^2 / 2 + m_p |p'|^2 / 2`` with ``J = m_arm a^2 / 3`` (uniform arm),
    - ``V = -m_arm g (a/2) sum_k sin alpha_k + m_p g p_3``,
    - constraints ``rods[k] = ||p - p_k||^2 - L^2`` with multipliers ``z`` (the force in rod
      ``k`` is ``2 L z_k``, pulling the platform towards the elbow when ``z_k > 0``),
    - generalized forces: motor torques ``u`` (3, inputs) minus viscous friction
      ``b alpha'`` on the arms.

    Data (keyword arguments, defaults in :data:`DELTA_ROBOT_DATA`): ``r = 0.2``, ``a = 0.3``,
    ``L = 0.6``, ``m_arm = 0.2``, ``m_p = 0.5``, ``g = 9.81``, ``b = 0`` -- the data of the
    hand-written Cartesian :func:`daekit.examples.delta_robot`, with the same ``z``. All are
    model parameters of the same names. Differential index 3, DOF 6.

    >>> robot = lagrangian_delta_robot()
    >>> robot.model().unknown_names[:4], robot.constraint_names
    (['alpha[0]', 'alpha[1]', 'alpha[2]', 'p[0]'], ['rods[0]', 'rods[1]', 'rods[2]'])
    """
    d = _delta_data(data, "lagrangian_delta_robot")
    alpha, dalpha = ca.SX.sym("alpha", 3), ca.SX.sym("dalpha", 3)
    p, dp = ca.SX.sym("p", 3), ca.SX.sym("dp", 3)
    u = ca.SX.sym("u", 3)
    par = {k: ca.SX.sym(k) for k in DELTA_ROBOT_DATA}
    r, a, L, ma, mp, g, b = (par[k] for k in ("r", "a", "L", "m_arm", "m_p", "g", "b"))
    J = ma * a**2 / 3
    rods = []
    for k, gamma in enumerate(_GAMMA):
        arm = ca.vertcat(r + a * ca.cos(alpha[k]), 0, -a * ca.sin(alpha[k]))
        pk = ca.mtimes(_rz_dm(gamma), arm)
        e = p - pk
        rods.append(ca.dot(e, e) - L**2)
    return LagrangianSystem(
        {"alpha": alpha, "p": p},
        {"alpha": dalpha, "p": dp},
        T=0.5 * J * ca.dot(dalpha, dalpha) + 0.5 * mp * ca.dot(dp, dp),
        V=-ma * g * a / 2 * ca.sum1(ca.sin(alpha)) + mp * g * p[2],
        constraints={"rods": ca.vertcat(*rods)},
        forces=ca.vertcat(u - b * dalpha, ca.SX.zeros(3, 1)),
        inputs={"u": u},
        parameters={k: (par[k], d[k]) for k in DELTA_ROBOT_DATA},
        multipliers="z",
        name="delta_robot_lagrangian",
    )


def _delta_data(data: dict, who: str) -> dict[str, float]:
    unknown = set(data) - set(DELTA_ROBOT_DATA)
    if unknown:
        raise ModelError(
            f"{who}: unknown data {sorted(unknown)}; use some of {sorted(DELTA_ROBOT_DATA)}"
        )
    d = dict(DELTA_ROBOT_DATA)
    d.update({k: float(v) for k, v in data.items()})
    for k in ("a", "L", "m_arm", "m_p"):
        if not d[k] > 0:
            raise ModelError(f"{who}: {k} must be positive, got {d[k]}")
    return d


def lagrangian_delta_robot_home(alpha=(0.3, 0.3, 0.3), **data: float) -> dict[str, np.ndarray]:
    """A consistent configuration of :func:`lagrangian_delta_robot` held at rest by the motors.

    Given the arm angles ``alpha`` (3), finds the platform position ``p`` below the elbows with
    every rod of length ``L`` (Newton's method), then the static equilibrium: the rod forces
    ``z`` that carry the platform's weight and the motor torques ``u`` that hold the arms.

    Returns a dict by model names: ``alpha``, ``p``, ``der(alpha)``, ``der(p)``,
    ``der(alpha,2)``, ``der(p,2)`` (zeros), ``z`` and ``u``: with the input ``u`` every
    equation of the model holds, and so do the invariants (``rods`` and their derivatives).

    >>> h = lagrangian_delta_robot_home()
    >>> bool(abs(h["p"][0]) < 1e-12 and h["p"][2] < 0)
    True
    """
    d = _delta_data(data, "lagrangian_delta_robot_home")
    h = delta_robot_home(alpha, **{k: v for k, v in d.items() if k != "b"})
    al, p, z, u = h["alpha"], h["p"], h["z"], h["u"]
    zero = np.zeros(3)
    return {
        "alpha": al,
        "p": p,
        "der(alpha)": zero.copy(),
        "der(p)": zero.copy(),
        "der(alpha,2)": zero.copy(),
        "der(p,2)": zero.copy(),
        "z": z,
        "u": u,
    }
