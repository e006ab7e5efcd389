"""ODEs with invariants: more state dimensions than the physics (the lecture's last slide).

"ODEs with consistency conditions occur when one defines a state-space that holds more
dimensions than the physical reality it represents": a unit quaternion for a rotation (four
numbers for three degrees of freedom), lifted states that make an ODE polynomial. Each model
declares its invariant with :meth:`daekit.Model.invariant`; the exact references are here too
(``reference-problems.md``, section 7).

- :func:`rigid_body` -- free rigid body, unit quaternion attitude, Euler's equations; for an
  axisymmetric body the body rates have a closed form (:func:`rigid_body_rates`).
- :func:`lifted_pendulum` -- the pendulum ``theta'' = -(g/L) sin(theta)`` made polynomial by
  the lifted states ``s = sin(theta)``, ``c = cos(theta)``, invariant ``s^2 + c^2 = 1``; exact
  through Jacobi's elliptic functions (:func:`lifted_pendulum_exact`).
- :func:`lifted_square` -- ``x' = x^2`` lifted with ``w = x^2``: ``x' = w``, ``w' = 2 x w``,
  invariant ``w - x^2``; exact ``x = x0 / (1 - x0 t)``.
- :func:`quadrotor` -- a quadrotor with quaternion attitude (thrust and body torques as
  controls) and :func:`quadrotor_yaw_ocp`, a rest-to-rest attitude change whose minimum-effort
  optimum is known in closed form (:func:`quadrotor_yaw_optimum`).

>>> import daekit as dk
>>> r = dk.reduce_index(rigid_body())
>>> r.invariant_names, dk.analyze(rigid_body()).dof
(['unit'], 6)
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model import Model

__all__ = [
    "quat_mul",
    "quat_rotate",
    "rigid_body",
    "rigid_body_rates",
    "rigid_body_energy",
    "RIGID_BODY_DATA",
    "lifted_pendulum",
    "lifted_pendulum_exact",
    "lifted_square",
    "lifted_square_exact",
    "quadrotor",
    "QUADROTOR_DATA",
    "quadrotor_yaw_ocp",
    "quadrotor_yaw_optimum",
    "yaw_quaternion",
]

#: The axisymmetric case of ``reference-problems.md`` section 7: ``I1 = I2 = 1``, ``I3 = 1.5``,
#: ``w(0) = (1, 0, 2)``, so ``lambda = (I3 - I1) w3 / I1 = 1`` and ``w = (cos t, sin t, 2)``.
RIGID_BODY_DATA = {"I": (1.0, 1.0, 1.5), "w0": (1.0, 0.0, 2.0), "q0": (1.0, 0.0, 0.0, 0.0)}


def quat_mul(a, b):
    """Hamilton product ``a ⊗ b`` of quaternions ``(w, x, y, z)`` (scalar first), CasADi or NumPy.

    >>> quat_mul(np.array([0.0, 1, 0, 0]), np.array([0.0, 0, 1, 0])).tolist()   # i j = k
    [0.0, 0.0, 0.0, 1.0]
    """
    a0, a1, a2, a3 = (a[i] for i in range(4))
    b0, b1, b2, b3 = (b[i] for i in range(4))
    parts = (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
             a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
             a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
             a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)
    if isinstance(a, (ca.SX, ca.MX, ca.DM)) or isinstance(b, (ca.SX, ca.MX, ca.DM)):
        return ca.vertcat(*parts)
    return np.array(parts, dtype=float)


def quat_rotate(q, v):
    """The vector ``v`` (body frame) rotated by the unit quaternion ``q``:
    ``R(q) v = vec(q ⊗ (0, v) ⊗ q*)``, written out as a polynomial in ``q``.

    >>> np.round(quat_rotate(np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]),
    ...                      np.array([1.0, 0, 0])), 12).tolist()          # 90 deg about z
    [0.0, 1.0, 0.0]
    """
    w, x, y, z = (q[i] for i in range(4))
    v0, v1, v2 = (v[i] for i in range(3))
    rows = ((1 - 2 * (y * y + z * z)) * v0 + 2 * (x * y - w * z) * v1 + 2 * (x * z + w * y) * v2,
            2 * (x * y + w * z) * v0 + (1 - 2 * (x * x + z * z)) * v1 + 2 * (y * z - w * x) * v2,
            2 * (x * z - w * y) * v0 + 2 * (y * z + w * x) * v1 + (1 - 2 * (x * x + y * y)) * v2)
    if isinstance(q, (ca.SX, ca.MX)) or isinstance(v, (ca.SX, ca.MX)):
        return ca.vertcat(*rows)
    return np.array(rows, dtype=float)


def rigid_body(I=RIGID_BODY_DATA["I"], invariant: bool = True) -> Model:  # noqa: B006 - a tuple
    """Free rigid body: unit quaternion ``q`` (scalar first) and body rates ``w``.

    ``q' = q ⊗ (0, w) / 2`` (``kinematics``); Euler's equations
    ``der(w) = ((I w) x w) / I`` (``euler``, principal inertias ``I = (I1, I2, I3)`` as
    parameters). Declares the invariant ``unit``: ``|q|^2 - 1`` (with ``invariant=False`` the
    plain 7-state ODE). ODE (index 0); 7 states, DOF 6 with the invariant.

    Conserved: the kinetic energy ``(I1 w1^2 + I2 w2^2 + I3 w3^2) / 2`` and ``|I w|``.
    Axisymmetric ``I1 = I2`` with ``w(0) = (W, 0, w3)``: ``w1 = W cos(lambda t)``,
    ``w2 = W sin(lambda t)``, ``w3`` constant, ``lambda = (I3 - I1) w3 / I1``
    (:func:`rigid_body_rates`). Source: ``reference-problems.md`` section 7; e.g. Landau &
    Lifshitz, *Mechanics*, section 33.

    >>> m = rigid_body()
    >>> [e.name for e in m.declared_invariants], m.n_equations
    (['unit'], 7)
    """
    m = Model("rigid_body")
    q = m.state("q", 4)
    w = m.state("w", 3)
    Ip = m.parameter("I", list(I))
    m.equation(m.der(q) - 0.5 * quat_mul(q, ca.vertcat(0, w)), name="kinematics")
    m.equation(m.der(w) - ca.cross(Ip * w, w) / Ip, name="euler")
    if invariant:
        m.invariant(ca.dot(q, q) - 1, name="unit")
    return m


def rigid_body_rates(t, W: float = 1.0, w3: float = 2.0, I1: float = 1.0,
                     I3: float = 1.5) -> np.ndarray:
    """Exact body rates ``(len(t), 3)`` of the axisymmetric body (``I1 = I2``) started with
    ``w(0) = (W, 0, w3)``: ``(W cos(lambda t), W sin(lambda t), w3)``, ``lambda = (I3 - I1) w3 / I1``.

    >>> rigid_body_rates(np.array([0.0, np.pi / 2])).round(12).tolist()   # lambda = 1
    [[1.0, 0.0, 2.0], [0.0, 1.0, 2.0]]
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    lam = (I3 - I1) * w3 / I1
    return np.column_stack([W * np.cos(lam * t), W * np.sin(lam * t), np.full(t.shape, w3)])


def rigid_body_energy(w, I=RIGID_BODY_DATA["I"]) -> np.ndarray:  # noqa: B006 - a tuple
    """Kinetic energy ``sum I_k w_k^2 / 2`` of body rates ``w`` (``(N, 3)``).

    >>> rigid_body_energy(np.array([[1.0, 0.0, 2.0]])).tolist()
    [3.5]
    """
    w = np.atleast_2d(np.asarray(w, dtype=float))
    return 0.5 * (w**2 @ np.asarray(I, dtype=float))


def lifted_pendulum(g: float = 9.8, L: float = 1.0) -> Model:
    """The pendulum ``theta'' = -(g/L) sin(theta)`` with the lifted states ``s = sin(theta)``,
    ``c = cos(theta)``: a polynomial ODE in ``(s, c, omega)``,

    ``s' = c omega``, ``c' = -s omega``, ``omega' = -(g/L) s``,

    with the declared invariant ``circle``: ``s^2 + c^2 - 1`` (two numbers for one angle).
    Exact solution released at rest from ``theta0``: ``sin(theta/2) = k cd(w t | k^2)``,
    ``k = sin(theta0/2)``, ``w = sqrt(g/L)`` (:func:`lifted_pendulum_exact`;
    ``reference-problems.md`` section 2: ``s = x / L``, ``c = -y / L`` of the Cartesian
    pendulum; case A, theta0 = pi/6, g = 9.8, at t = 5: ``s = -0.47657872558204044491``).

    >>> dk_names = lifted_pendulum().unknown_names
    >>> dk_names
    ['s', 'c', 'omega']
    """
    m = Model("lifted_pendulum")
    s = m.state("s")
    c = m.state("c")
    om = m.state("omega")
    gp = m.parameter("g", g)
    Lp = m.parameter("L", L)
    m.equation(m.der(s) - c * om, name="sine")
    m.equation(m.der(c) + s * om, name="cosine")
    m.equation(m.der(om) + gp / Lp * s, name="newton")
    m.invariant(s**2 + c**2 - 1, name="circle")
    return m


def lifted_pendulum_exact(t, theta0: float, g: float = 9.8, L: float = 1.0) -> dict:
    """``s``, ``c``, ``omega`` and ``theta`` of :func:`lifted_pendulum` released at rest from
    ``theta0`` (from :func:`daekit.examples.exact.pendulum_planar`).

    >>> round(float(lifted_pendulum_exact(5.0, np.pi / 6)["s"]), 12)
    -0.476578725582
    """
    from .exact import pendulum_planar

    e = pendulum_planar(t, theta0, g=g, L=L)
    theta = np.asarray(e["theta"], dtype=float)
    # omega = theta' from x' = L cos(theta) theta' and y' = L sin(theta) theta'
    omega = (np.cos(theta) * e["der(x)"] + np.sin(theta) * e["der(y)"]) / L
    return {"s": np.sin(theta), "c": np.cos(theta), "omega": omega, "theta": theta}


def lifted_square() -> Model:
    """``x' = x^2`` lifted with ``w = x^2``: ``x' = w``, ``w' = 2 x w`` (``der(w) = 2 x der(x)``),
    the declared invariant ``lift``: ``w - x^2``. Exact: ``x = x0 / (1 - x0 t)``, ``w = x^2``
    (:func:`lifted_square_exact`; for ``x0 < 0`` defined for all ``t > 0``).

    >>> import daekit as dk
    >>> dk.reduce_index(lifted_square()).invariant_names
    ['lift']
    """
    m = Model("lifted_square")
    x = m.state("x")
    w = m.state("w")
    m.equation(m.der(x) - w, name="square")
    m.equation(m.der(w) - 2 * x * w, name="lifted")
    m.invariant(w - x**2, name="lift")
    return m


def lifted_square_exact(t, x0: float) -> dict:
    """``x = x0 / (1 - x0 t)``, ``w = x^2``.

    >>> lifted_square_exact(1.0, -1.0)["x"].tolist()
    -0.5
    """
    t = np.asarray(t, dtype=float)
    x = x0 / (1.0 - x0 * t)
    return {"x": x, "w": x * x}


#: Quadrotor data: mass, gravity, principal inertias (a 0.5 kg craft; Mellinger & Kumar's
#: order of magnitude), hover thrust ``mass * g``.
QUADROTOR_DATA = {"mass": 0.5, "g": 9.81, "J": (2.3e-3, 2.3e-3, 4.0e-3)}


def quadrotor(mass: float = QUADROTOR_DATA["mass"], g: float = QUADROTOR_DATA["g"],
              J=QUADROTOR_DATA["J"]) -> Model:  # noqa: B006 - a tuple
    """A quadrotor with quaternion attitude: position ``p``, velocity ``v`` (world frame,
    ``z`` up), unit quaternion ``q`` (body to world, scalar first), body rates ``w``;
    controls the collective thrust ``f`` (along body ``z``) and the body torques ``tau``.

    ``p' = v``; ``mass v' = R(q) (0, 0, f) - mass g e3``; ``q' = q ⊗ (0, w) / 2``;
    ``J w' = tau - w x (J w)``. Declared invariant ``unit``: ``|q|^2 - 1``. 13 states, DOF 12.

    >>> m = quadrotor()
    >>> sorted(v.name for v in m.controls), m.n_equations
    (['f', 'tau'], 13)
    """
    m = Model("quadrotor")
    p = m.state("p", 3)
    v = m.state("v", 3)
    q = m.state("q", 4)
    w = m.state("w", 3)
    f = m.control("f")
    tau = m.control("tau", 3)
    mp = m.parameter("mass", mass)
    gp = m.parameter("g", g)
    Jp = m.parameter("J", list(J))
    m.equation(m.der(p) - v, name="kinematics")
    m.equation(m.der(v) - (quat_rotate(q, ca.vertcat(0, 0, f)) / mp - ca.vertcat(0, 0, gp)),
               name="newton")
    m.equation(m.der(q) - 0.5 * quat_mul(q, ca.vertcat(0, w)), name="attitude")
    m.equation(m.der(w) - (tau - ca.cross(w, Jp * w)) / Jp, name="euler")
    m.invariant(ca.dot(q, q) - 1, name="unit")
    return m


def yaw_quaternion(angle: float) -> np.ndarray:
    """The unit quaternion of a rotation by ``angle`` about ``z``: ``(cos(a/2), 0, 0, sin(a/2))``.

    >>> yaw_quaternion(np.pi).round(12).tolist()
    [0.0, 0.0, 0.0, 1.0]
    """
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


def quadrotor_yaw_ocp(angle: float = np.pi / 2, T: float = 2.0, intervals: int = 20,
                      sign: float = 1.0, up_to_sign: bool = True, **ocp_options):
    """Rest-to-rest yaw change of :func:`quadrotor`: from hover at the origin with ``q = 1`` to
    rest with the attitude ``sign * yaw_quaternion(angle)`` at ``t = T``, minimizing
    ``int |tau|^2 + (f - mass g)^2 dt`` (polynomial controls). With ``up_to_sign`` the final
    attitude is imposed up to the quaternion's sign (``q(T) = ±q_target``, the same
    rotation); otherwise the given sign decides which way round the craft turns.

    The optimum (:func:`quadrotor_yaw_optimum`) is the classic rest-to-rest profile about
    ``z``: ``f = mass g``, ``tau_z = J3 phi (6/T^2 - 12 t/T^3)``, objective
    ``12 J3^2 phi^2 / T^3`` for the turned angle ``phi``.

    Returns the :class:`daekit.OCP` (not solved).

    >>> ocp = quadrotor_yaw_ocp(intervals=4)
    >>> ocp.reduced.invariant_names
    ['unit']
    """
    from ..ocp import OCP

    d = QUADROTOR_DATA
    m = quadrotor()
    f, tau = m.variables["f"].sym, m.variables["tau"].sym
    ocp = OCP(m, t_final=T, intervals=intervals, degree=3, controls="polynomial", **ocp_options)
    ocp.minimize(integral=ca.sumsqr(tau) + (f - d["mass"] * d["g"]) ** 2)
    ocp.initial({"p": [0, 0, 0], "v": [0, 0, 0], "q": [1, 0, 0, 0], "w": [0, 0, 0]})
    ocp.final({"v": [0, 0, 0], "w": [0, 0, 0]})
    ocp.final({"q": sign * yaw_quaternion(angle)}, up_to_sign=up_to_sign)
    ocp.set_guess({"f": d["mass"] * d["g"]})
    return ocp


def quadrotor_yaw_optimum(phi: float, T: float = 2.0, J3: float = QUADROTOR_DATA["J"][2]) -> float:
    """Minimum of ``int tau_z^2 dt`` for a rest-to-rest turn by ``phi`` in time ``T`` about an
    axis of inertia ``J3``: ``12 J3^2 phi^2 / T^3`` (``phi(t) = phi (3 s^2 - 2 s^3)``, ``s = t/T``).

    >>> round(quadrotor_yaw_optimum(np.pi / 2, 2.0, 1.0), 6)
    3.701102
    """
    return 12.0 * J3**2 * phi**2 / T**3
