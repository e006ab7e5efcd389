"""The examples of S. Gros, "Numerical Optimal Control with DAEs", lecture 11 (2016).

L1 and L5 are index-1 DAEs ("easy" and "not an ODE but one differentiation away"), L2 is the
index-3 chain of integrators driven through an algebraic output, L3 the 3D pendulum, L4 the
delta robot and L6 an index-2 constraint on a double integrator. See
``reference-problems.md``, section 1.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model import Model

__all__ = [
    "l1",
    "l2",
    "l3",
    "l4",
    "l5",
    "l6",
    "pendulum3d",
    "delta_robot",
    "delta_robot_home",
    "DELTA_GAMMA",
]


def l1() -> Model:
    """Lecture 11, example L1: ``x - x' + 1 = 0``, ``x' z + 2 = 0``.

    Source: S. Gros, lecture 11 (2016). Differential index 1, DOF 1. The DAE is "easy": the
    matrix ``[dF/dx' dF/dz] = [[-1, 0], [z, x']]`` has full rank where ``x' != 0``.
    Exact solution: ``x = (x0 + 1) e^t - 1``, ``x' = x + 1``, ``z = -2 / (x + 1)``.

    >>> m = l1()
    >>> m.n_equations, m.unknown_names
    (2, ['x', 'z'])
    """
    m = Model("L1")
    x = m.state("x")
    z = m.algebraic("z")
    m.equation(x - m.der(x) + 1, name="growth")
    m.equation(m.der(x) * z + 2, name="coupling")
    return m


def l2() -> Model:
    """Lecture 11, example L2: ``x1' - z = 0``, ``x2' - x1 = 0``, ``x2 - u = 0`` (input ``u``).

    Source: S. Gros, lecture 11 (2016). Differential index 3, DOF 0: the output ``x2`` is
    prescribed, so ``x1 = u'`` and ``z = u''``; reducing the index needs derivatives of the input.

    >>> m = l2()
    >>> m.equation_names
    ['integrator1', 'integrator2', 'output']
    """
    m = Model("L2")
    x1 = m.state("x1")
    x2 = m.state("x2")
    z = m.algebraic("z")
    u = m.control("u")
    m.equation(m.der(x1) - z, name="integrator1")
    m.equation(m.der(x2) - x1, name="integrator2")
    m.equation(x2 - u, name="output")
    return m


def pendulum3d(mass: float = 1.0, length: float = 1.0, g: float = 9.81) -> Model:
    """The 3D pendulum of lecture 11 (example L3), a point mass on a massless rod.

    ``p' = v``, ``m v' = u - m g e3 - z p``, ``0 = (p.p - L^2)/2``; states ``p``, ``v`` (3 each),
    algebraic ``z`` (rod force per unit length), control ``u`` (3, a force on the mass),
    parameters ``m``, ``L``, ``g``.

    Source: S. Gros, lecture 11 (2016); Hairer & Wanner, *Solving ODEs II*, ch. VII.
    Differential index 3, DOF 4. Invariants ``c = (p.p - L^2)/2`` and ``c' = p.v``; the index-1
    form is ``[m I, p; p^T, 0] [v'; z] = [u - m g e3; -v.v]``.

    >>> m = pendulum3d()
    >>> [e.name for e in m.equations]
    ['kinematics', 'newton', 'rod']
    """
    m = Model("pendulum3d")
    p = m.state("p", 3)
    v = m.state("v", 3)
    z = m.algebraic("z")
    u = m.control("u", 3)
    mass = m.parameter("m", mass)
    L = m.parameter("L", length)
    grav = m.parameter("g", g)
    m.equation(m.der(p) - v, name="kinematics")
    m.equation(mass * m.der(v) - (u - mass * grav * ca.DM([0, 0, 1]) - z * p), name="newton")
    m.equation(0.5 * (ca.dot(p, p) - L**2), name="rod")
    return m


l3 = pendulum3d

#: Angles of the three arms of the delta robot about the vertical axis.
DELTA_GAMMA = (0.0, 2.0 * np.pi / 3.0, 4.0 * np.pi / 3.0)
#: Default geometry and masses of the lecture's delta robot (SI units).
DELTA_DEFAULTS = {
    "r": 0.2,  # distance of the motor axes from the vertical axis [m]
    "a": 0.3,  # length of an upper arm [m]
    "L": 0.6,  # length of a lower (parallel) rod [m]
    "m_arm": 0.2,  # mass of an upper arm, a uniform rod [kg]
    "m_p": 0.5,  # mass of the platform (a point mass) [kg]
    "g": 9.81,
}


def _rz(gamma: float) -> np.ndarray:
    c, s = np.cos(gamma), np.sin(gamma)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def delta_robot(
    r: float = 0.2,
    a: float = 0.3,
    L: float = 0.6,
    m_arm: float = 0.2,
    m_p: float = 0.5,
    g: float = 9.81,
) -> Model:
    """The delta robot of lecture 11 (example L4): three motor-driven arms carry a platform.

    Arm ``k`` turns about a horizontal axis at distance ``r`` from the vertical axis, at the
    azimuth ``gamma_k`` (0, 2pi/3, 4pi/3); its angle ``alpha_k`` (down is positive) puts the elbow
    at ``p_k = R_z(gamma_k) [r + a cos alpha_k, 0, -a sin alpha_k]``. A massless rod of length
    ``L`` links each elbow to the platform, a point mass at ``p``. Lagrange's equations with the
    constraints ``c_k = ||p - p_k||^2 - L^2 = 0`` and their multipliers ``z_k`` (the rod forces):

    - ``arm_kinematics``: ``alpha' = omega``; ``platform_kinematics``: ``p' = v``
    - ``arms``: ``J omega_k' = u_k + m_arm g (a/2) cos alpha_k - z_k dc_k/dalpha_k``,
      ``J = m_arm a^2 / 3`` (a uniform rod turning about its end), ``u`` the motor torques
    - ``platform``: ``m_p v' = -m_p g e3 - sum_k z_k dc_k/dp``
    - ``rods``: ``0 = ||p - p_k||^2 - L^2``

    Unknowns ``alpha``, ``omega``, ``p``, ``v`` (states, 3 each), ``z`` (algebraic, 3); control
    ``u`` (3). Source: S. Gros, lecture 11 (2016); the physical data here are our choice.
    Differential index 3 (``d rods / d z = 0``: the rods cannot be solved for the forces),
    DOF 6 (six coordinates, three constraints, each with its velocity).
    :func:`delta_robot_home` gives a consistent configuration at rest.

    >>> m = delta_robot()
    >>> m.n_equations, [e.name for e in m.equations]
    (15, ['arm_kinematics', 'platform_kinematics', 'arms', 'platform', 'rods'])
    """
    m = Model("delta_robot")
    alpha = m.state("alpha", 3)
    omega = m.state("omega", 3)
    p = m.state("p", 3)
    v = m.state("v", 3)
    z = m.algebraic("z", 3)
    u = m.control("u", 3)
    r_ = m.parameter("r", r)
    a_ = m.parameter("a", a)
    L_ = m.parameter("L", L)
    ma = m.parameter("m_arm", m_arm)
    mp = m.parameter("m_p", m_p)
    g_ = m.parameter("g", g)
    J = ma * a_**2 / 3
    arm_res, rod_res = [], []
    force = ca.SX.zeros(3, 1)
    for k, gamma in enumerate(DELTA_GAMMA):
        R = ca.DM(_rz(gamma))
        ca_, sa = ca.cos(alpha[k]), ca.sin(alpha[k])
        pk = ca.mtimes(R, ca.vertcat(r_ + a_ * ca_, 0, -a_ * sa))
        dpk = ca.mtimes(R, ca.vertcat(-a_ * sa, 0, -a_ * ca_))  # d p_k / d alpha_k
        e = p - pk
        dc_dalpha = -2 * ca.dot(e, dpk)
        arm_res.append(J * m.der(omega[k]) - (u[k] + ma * g_ * a_ / 2 * ca_ - z[k] * dc_dalpha))
        force = force - z[k] * 2 * e
        rod_res.append(ca.dot(e, e) - L_**2)
    m.equation(m.der(alpha) - omega, name="arm_kinematics")
    m.equation(m.der(p) - v, name="platform_kinematics")
    m.equation(ca.vertcat(*arm_res), name="arms")
    m.equation(mp * m.der(v) - (-mp * g_ * ca.DM([0, 0, 1]) + force), name="platform")
    m.equation(ca.vertcat(*rod_res), name="rods")
    return m


l4 = delta_robot


def delta_robot_home(alpha=(0.3, 0.3, 0.3), **data: float) -> dict[str, np.ndarray]:
    """A consistent configuration of :func:`delta_robot` at rest, held by the motors.

    Given the arm angles ``alpha`` (3), solves the three rod constraints for the platform
    position ``p`` (the solution below the elbows), then the static equilibrium for the rod
    forces ``z`` and the motor torques ``u``. ``data`` overrides the robot's data (``r``, ``a``,
    ``L``, ``m_arm``, ``m_p``, ``g``) as in :func:`delta_robot`.

    Returns a dict with the keys ``alpha``, ``omega`` (zeros), ``p``, ``v`` (zeros), ``z``, ``u``,
    ``der(alpha)``, ``der(omega)``, ``der(p)``, ``der(v)`` (zeros): every equation of
    ``delta_robot(**data)`` holds at these values with the input ``u``.

    >>> h = delta_robot_home()
    >>> bool(abs(h["p"][0]) < 1e-12 and h["p"][2] < 0)
    True
    """
    d = dict(DELTA_DEFAULTS)
    unknown = set(data) - set(d)
    if unknown:
        from ..errors import ModelError

        raise ModelError(
            f"delta_robot_home: unknown data {sorted(unknown)}; use some of {sorted(d)}"
        )
    d.update(data)
    r, a, L, ma, mp, g = (float(d[k]) for k in ("r", "a", "L", "m_arm", "m_p", "g"))
    alpha = np.asarray(alpha, dtype=float).ravel()
    if alpha.shape != (3,):
        from ..errors import ModelError

        raise ModelError(f"delta_robot_home: alpha needs 3 angles, got {alpha.tolist()}")
    R = [_rz(gm) for gm in DELTA_GAMMA]
    pk = np.array([R[k] @ [r + a * np.cos(alpha[k]), 0.0, -a * np.sin(alpha[k])] for k in range(3)])
    dpk = np.array([R[k] @ [-a * np.sin(alpha[k]), 0.0, -a * np.cos(alpha[k])] for k in range(3)])
    # Newton on ||p - p_k||^2 = L^2 from a point well below the elbows
    p = np.array([pk[:, 0].mean(), pk[:, 1].mean(), pk[:, 2].min() - L])
    for _ in range(50):
        e = p - pk
        res = np.sum(e * e, axis=1) - L**2
        step = np.linalg.solve(2 * e, res)
        p = p - step
        if np.max(np.abs(step)) < 1e-15 * (1 + np.max(np.abs(p))):
            break
    e = p - pk
    if np.max(np.abs(np.sum(e * e, axis=1) - L**2)) > 1e-12:
        from ..errors import ModelError

        raise ModelError(
            f"delta_robot_home: no platform position reaches the elbows for alpha = "
            f"{alpha.tolist()} with rods of length {L}; choose other angles"
        )
    # platform at rest: 0 = -m_p g e3 - sum_k z_k 2 e_k
    z = np.linalg.solve((2 * e).T, np.array([0.0, 0.0, -mp * g]))
    dc_dalpha = -2 * np.sum(e * dpk, axis=1)
    u = -ma * g * a / 2 * np.cos(alpha) + z * dc_dalpha
    zero = np.zeros(3)
    return {
        "alpha": alpha,
        "omega": zero.copy(),
        "p": p,
        "v": zero.copy(),
        "z": z,
        "u": u,
        "der(alpha)": zero.copy(),
        "der(omega)": zero.copy(),
        "der(p)": zero.copy(),
        "der(v)": zero.copy(),
    }


def l5() -> Model:
    """Lecture 11, example L5: ``x1 - x1' + 1 = 0``, ``x1' x2 + 2 = 0``.

    Source: S. Gros, lecture 11 (2016). Differential index 1, DOF 1: ``dF/dx'`` is singular for
    ``x = (x1, x2)`` (``x2'`` does not appear), so it is a DAE; one differentiation of the second
    equation gives ``x2'``. Exact solution ``x1 = (x1(0) + 1) e^t - 1``, ``x2 = -2/(x1 + 1)``.
    ``x2`` is declared with ``m.variable`` (daekit finds that it is algebraic).

    >>> l5().unknown_names
    ['x1', 'x2']
    """
    m = Model("L5")
    x1 = m.state("x1")
    x2 = m.variable("x2")
    m.equation(x1 - m.der(x1) + 1, name="growth")
    m.equation(m.der(x1) * x2 + 2, name="coupling")
    return m


def l6() -> Model:
    """Lecture 11, example L6: ``x1' = x2``, ``x2' = z``, ``0 = (x1^2 + x2^2 - 1)/2``.

    Source: S. Gros, lecture 11 (2016). Differential index 2, DOF 1: ``dG/dt = x1 x2 + x2 z``
    is solvable for ``z`` where ``x2 != 0`` (``z = -x1``); then ``x1 = sin(t + phi)``,
    ``x2 = cos(t + phi)``, ``z = -sin(t + phi)``.

    >>> [e.name for e in l6().equations]
    ['integrator1', 'integrator2', 'circle']
    """
    m = Model("L6")
    x1 = m.state("x1")
    x2 = m.state("x2")
    z = m.algebraic("z")
    m.equation(m.der(x1) - x2, name="integrator1")
    m.equation(m.der(x2) - z, name="integrator2")
    m.equation(0.5 * (x1**2 + x2**2 - 1), name="circle")
    return m
