"""Optimal control examples on index-3 mechanisms, each with a figure.

- :func:`crane_ocp`: an overhead crane (cart on a rail, load on a cable of length ``L`` in
  Cartesian coordinates, index 3) moved a distance in minimum time with a bounded force.
- :func:`delta_robot_ocp`: a delta robot pick-and-place minimizing the integral of the squared
  motor torques.
- :func:`pendulum3d_periodic_ocp`: a periodic orbit of the 3D pendulum with full periodicity
  requested, the case where boundary conditions are redundant with the invariants.

Each ``*_ocp`` function returns the :class:`daekit.ocp.OCP` (call ``.solve()``); each
``*_figure(sol, path)`` saves a figure of a solution. :func:`run_all` does everything.

Every ``*_ocp`` function takes ``method="collocation"`` (Radau IIA, the default) or
``method="shooting"`` (multiple shooting on IDAS).

>>> import numpy as np
>>> sol = crane_ocp(intervals=20).solve()
>>> sol.success, round(sol.T, 3)
(True, 1.97)

No faster than the rigid load (cart and load as one body, ``M + m = 1.5``) moved over the
distance 2 with the force bang-bang, ``T = 2 sqrt(2 * 1.5 / 5)``; the force stays in bounds:

>>> bool(sol.T > 2 * np.sqrt(2.0 * 1.5 / 5.0)), bool(np.max(np.abs(sol["F"])) <= 5.0 + 1e-8)
(True, True)

Multiple shooting, warm-started from the collocation solution, finds the same final time (the
two share the piecewise constant controls and differ by the collocation's truncation error):

>>> sh = crane_ocp(intervals=20, method="shooting").solve(guess=sol)
>>> sh.success, bool(abs(sh.T - sol.T) < 1e-5 * sol.T)
(True, True)
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model import Model

__all__ = [
    "pendulum_with_tangential_force",
    "swing_optimum_minimal_coordinates",
    "betts_pendulum_ocp",
    "CARTPOLE",
    "cartpole_ocp",
    "crane",
    "crane_ocp",
    "crane_figure",
    "delta_robot_ocp",
    "delta_robot_figure",
    "pendulum3d_periodic_ocp",
    "pendulum3d_periodic_figure",
    "run_all",
]


def pendulum_with_tangential_force(L: float = 1.0, g: float = 9.81) -> Model:
    """The Cartesian planar pendulum (index 3, unit mass) driven by a force ``u`` tangent to the
    circle: ``p' = v``, ``v' = u (-p_1, p_0)/L - g e_2 - z p``, ``(p.p - L^2)/2 = 0``.

    In the angle ``th`` (``p = L (sin th, -cos th)``) it is ``L th'' = -g sin th + u``, which
    makes it the test case for OCPs solved both on the index-3 model and in minimal
    coordinates (``tests/test_ocp.py``, ``benchmarks/ocp.py``).

    >>> pendulum_with_tangential_force().n_equations
    5
    """
    m = Model("pendulum_force")
    p = m.state("p", 2)
    v = m.state("v", 2)
    z = m.algebraic("z")
    u = m.control("u")
    Lp = m.parameter("L", L)
    gp = m.parameter("g", g)
    tangent = ca.vertcat(-p[1], p[0]) / Lp  # unit tangent (cos th, sin th), p = L (sin, -cos)
    m.equation(m.der(p) - v, name="kinematics")
    m.equation(m.der(v) - (u * tangent - ca.vertcat(0, gp) - z * p), name="newton")
    m.equation(0.5 * (ca.dot(p, p) - Lp**2), name="rod")
    return m


def swing_optimum_minimal_coordinates(th1: float, T: float, L: float = 1.0,
                                      g: float = 9.81) -> float:
    """Independent reference for :func:`pendulum_with_tangential_force`: the minimum of
    ``int u^2 dt`` that swings ``L th'' = -g sin th + u`` from rest at 0 to rest at ``th1`` in
    time ``T`` (continuous controls), by SciPy's ``solve_bvp`` on Pontryagin's conditions
    ``u = -lam2/(2L)``, ``lam1' = lam2 (g/L) cos th``, ``lam2' = -lam1`` -- no daekit inside.

    >>> round(swing_optimum_minimal_coordinates(np.pi / 6, 2.0), 6)
    2.610838
    """
    from scipy.integrate import solve_bvp

    def f(t, y):
        th, om, l1, l2, _ = y
        u = -l2 / (2 * L)
        return np.vstack([om, -g / L * np.sin(th) + u / L, l2 * g / L * np.cos(th), -l1, u**2])

    def bc(ya, yb):
        return np.array([ya[0], ya[1], yb[0] - th1, yb[1], ya[4]])

    t = np.linspace(0, T, 200)
    y0 = np.vstack([th1 * t / T, np.zeros((4, t.size))])
    s = solve_bvp(f, bc, t, y0, tol=1e-10, max_nodes=100000)
    if s.status != 0:  # pragma: no cover - a failure here is a broken reference, not daekit's
        raise RuntimeError(f"solve_bvp failed: {s.message}")
    return float(s.y[4, -1])


def betts_pendulum_ocp(initial_all: bool = True):
    """Betts (2010) problem 10.103 from the index-3 Cartesian model as written:
    ``x'' = -2 lam x + u y``, ``y'' = -g - 2 lam y - u x``, ``x^2 + y^2 = 1``, g = 9.81;
    minimize ``int u^2`` on [0, 3] from ``x = 1, y = 0`` at rest (all four values, redundant
    on the rod, or only ``x = 1, der(y) = 0`` with ``initial_all=False``) to ``x = 0,
    der(x) = 0``; ``-1 <= lam <= 15``, +-5 on positions and velocities; Radau degree 3, 100
    intervals, polynomial controls. Published optimum J = 12.8738850 (an independent
    angle-form solution: 12.8738889); it ends hanging at y = -1.
    """
    from ..ocp import OCP

    m = Model("betts")
    x, y = m.state("x"), m.state("y")
    lam, u = m.algebraic("lam"), m.control("u")
    m.equation(m.der(x, 2) - (-2 * lam * x + u * y), name="newton_x")
    m.equation(m.der(y, 2) - (-9.81 - 2 * lam * y - u * x), name="newton_y")
    m.equation(x**2 + y**2 - 1, name="rod")
    ocp = OCP(m, t_final=3.0, intervals=100, degree=3, controls="polynomial")
    ocp.minimize(integral=u**2)
    ocp.initial({"x": 1, "y": 0, "der(x)": 0, "der(y)": 0} if initial_all
                else {"x": 1, "der(y)": 0})
    ocp.final({"x": 0, "der(x)": 0})
    ocp.bound("lam", -1, 15)
    for n in ("x", "y", "der(x)", "der(y)"):
        ocp.bound(n, -5, 5)
    return ocp


#: the cart-pole swing-up's data: cart mass, tip mass, rod length, gravity, horizon, intervals
CARTPOLE = {"M": 1.0, "m": 0.3, "L": 0.5, "g": 9.81, "T": 2.0, "N": 50}


def cartpole_ocp(final_all: bool = True):
    """The cart-pole swing-up in Cartesian coordinates as a user writes it: cart position
    ``s``, pole tip ``p``, one rod (multiplier ``lam``), force ``F`` on the cart; from hanging at
    rest to upright at rest in ``T = 2`` s, minimize ``int F^2`` (Radau degree 3, 50 intervals,
    data in :data:`CARTPOLE`). The final state is given on every state (``final_all``) or as a
    user would, ``{"s": 0, "p[1]": L, "der(s)": 0, "der(p)": [0, 0]}``. The optimum equals the
    same problem in minimal coordinates (cart position and angle) to 1e-4: J = 67.1112 (a
    hand-written ``casadi.Opti`` collocation in ``tests/test_ocp.py``).
    """
    from ..ocp import OCP

    M, mp, L, g = CARTPOLE["M"], CARTPOLE["m"], CARTPOLE["L"], CARTPOLE["g"]
    m = Model("cartpole")
    s, p = m.state("s"), m.state("p", 2)
    lam, F = m.algebraic("lam"), m.control("F")
    r = ca.vertcat(p[0] - s, p[1])
    m.equation(M * m.der(s, 2) - (F + 2 * lam * r[0]), name="cart")
    m.equation(mp * m.der(p, 2) - (-mp * ca.vertcat(0, g) - 2 * lam * r), name="tip")
    m.equation(ca.dot(r, r) - L**2, name="rod")
    ocp = OCP(m, t_final=CARTPOLE["T"], intervals=CARTPOLE["N"], degree=3)
    ocp.minimize(integral=F**2)
    ocp.initial({"s": 0, "p": [0, -L], "der(s)": 0, "der(p)": [0, 0]})
    if final_all:
        ocp.final({"s": 0, "p": [0, L], "der(s)": 0, "der(p)": [0, 0]})
    else:
        ocp.final({"s": 0, "p[1]": L, "der(s)": 0, "der(p)": [0, 0]})
    return ocp


def crane(M: float = 1.0, m: float = 0.5, L: float = 1.0, g: float = 9.81) -> Model:
    """An overhead crane: a cart at ``s`` on a horizontal rail and a load at ``(x, y)`` hanging on
    a cable of length ``L`` (Cartesian coordinates, the cable as a constraint).

    ``M s'' = F + 2 lam (x - s)``, ``m x'' = -2 lam (x - s)``, ``m y'' = -m g - 2 lam y``,
    ``0 = (x - s)^2 + y^2 - L^2`` (``cable``); control ``F`` (force on the cart), algebraic
    ``lam`` (cable force multiplier). Differential index 3, DOF 4.

    >>> crane().equation_names
    ['cart', 'load_x', 'load_y', 'cable']
    """
    mod = Model("crane")
    s = mod.state("s")
    x = mod.state("x")
    y = mod.state("y")
    lam = mod.algebraic("lam")
    F = mod.control("F")
    Mp = mod.parameter("M", M)
    mp = mod.parameter("m", m)
    Lp = mod.parameter("L", L)
    gp = mod.parameter("g", g)
    mod.equation(Mp * mod.der(s, 2) - (F + 2 * lam * (x - s)), name="cart")
    mod.equation(mp * mod.der(x, 2) + 2 * lam * (x - s), name="load_x")
    mod.equation(mp * mod.der(y, 2) + mp * gp + 2 * lam * y, name="load_y")
    mod.equation((x - s) ** 2 + y**2 - Lp**2, name="cable")
    return mod


def crane_ocp(distance: float = 2.0, F_max: float = 5.0, intervals: int = 40, degree: int = 3,
              regularization: float = 1e-3, method: str = "collocation"):
    """Move the crane ``distance`` in minimum time, ``|F| <= F_max``, from rest to rest.

    Objective ``T + regularization * int F^2 dt`` (the small regularization makes the
    bang-bang optimum unique numerically). The full states at both ends are given (6 + 6
    conditions); on the 4-dimensional manifold of the cable constraint only 4 + 4 are
    independent, and the OCP keeps those (see ``sol.report``).
    """
    from ..ocp import OCP, Free

    mod = crane()
    F = mod.variables["F"].sym
    ocp = OCP(mod, t_final=Free(0.5, 10.0, 3.0), intervals=intervals, degree=degree,
              method=method)
    ocp.minimize(integral=regularization * F**2, final=mod.t)
    ocp.bound("F", -F_max, F_max)
    rest = {"der(s)": 0.0, "der(x)": 0.0, "der(y)": 0.0}
    ocp.initial({"s": 0.0, "x": 0.0, "y": -1.0, **rest})
    ocp.final({"s": distance, "x": distance, "y": -1.0, **rest})
    return ocp


def crane_figure(sol, path: str) -> None:
    """Cart and load positions, swing angle and force of a :func:`crane_ocp` solution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    t = sol.t
    ax[0].plot(t, sol["s"], label="cart s")
    ax[0].plot(t, sol["x"], "--", label="load x")
    ax[0].set_xlabel("t [s]")
    ax[0].set_ylabel("position [m]")
    ax[0].legend()
    ang = np.degrees(np.arctan2(sol["x"] - sol["s"], -sol["y"]))
    ax[1].plot(t, ang)
    ax[1].set_xlabel("t [s]")
    ax[1].set_ylabel("cable angle [deg]")
    ax[2].step(t, sol["F"], where="pre")
    ax[2].set_xlabel("t [s]")
    ax[2].set_ylabel("force F [N]")
    fig.suptitle(f"Overhead crane, minimum time: T = {sol.T:.4f} s (index 3, Cartesian)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def delta_robot_ocp(alpha_start=(0.3, 0.3, 0.3), alpha_end=(0.7, 0.1, 0.45), t_final: float = 0.8,
                    intervals: int = 30, degree: int = 3, method: str = "collocation"):
    """Pick-and-place with the delta robot (:func:`daekit.examples.delta_robot`): from rest at the
    configuration with arm angles ``alpha_start`` to rest at ``alpha_end`` in ``t_final``,
    minimizing ``int |u|^2 dt`` (squared motor torques). Both end configurations are consistent
    (:func:`daekit.examples.delta_robot_home`); all 12 states are given at each end, of which
    only 6 are independent on the constraint manifold: the OCP keeps an independent subset.
    """
    from ..ocp import OCP
    from .lecture import delta_robot, delta_robot_home

    mod = delta_robot()
    u = mod.variables["u"].sym
    a = delta_robot_home(alpha_start)
    b = delta_robot_home(alpha_end)
    ocp = OCP(mod, t_final=t_final, intervals=intervals, degree=degree, method=method)
    ocp.minimize(integral=ca.sumsqr(u))
    keys = ("alpha", "omega", "p", "v")
    ocp.initial({k: a[k] for k in keys})
    ocp.final({k: b[k] for k in keys})
    ocp.set_guess({"u": a["u"]})
    return ocp


def delta_robot_figure(sol, path: str) -> None:
    """Arm angles, torques and the platform path of a :func:`delta_robot_ocp` solution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 3.8))
    ax1 = fig.add_subplot(1, 3, 1)
    ax1.plot(sol.t, sol["alpha"])
    ax1.set_xlabel("t [s]")
    ax1.set_ylabel("arm angles [rad]")
    ax2 = fig.add_subplot(1, 3, 2)
    ax2.step(sol.t, sol["u"], where="pre")
    ax2.set_xlabel("t [s]")
    ax2.set_ylabel("motor torques [N m]")
    ax3 = fig.add_subplot(1, 3, 3, projection="3d")
    p = sol["p"]
    ax3.plot(p[:, 0], p[:, 1], p[:, 2])
    ax3.scatter(*p[0], color="g")
    ax3.scatter(*p[-1], color="r")
    ax3.set_title("platform path")
    fig.suptitle(f"Delta robot pick-and-place, min int |u|^2 = {sol.objective:.5g}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def pendulum3d_periodic_ocp(t_final: float = 2.0, cone_angle: float = np.pi / 6,
                            intervals: int = 30, degree: int = 3, method: str = "collocation"):
    """A periodic orbit of the 3D pendulum (:func:`daekit.examples.pendulum3d`) of period
    ``t_final`` through ``p(0) = (sin a, 0, -cos a)``, minimizing ``int |u|^2``, with full
    periodicity of ``p`` and ``v`` requested: 9 boundary conditions of which only 6 are
    independent on the manifold of the invariants (the redundancy case; see ``sol.report``).
    """
    from ..ocp import OCP
    from .lecture import pendulum3d

    mod = pendulum3d()
    u = mod.variables["u"].sym
    ocp = OCP(mod, t_final=t_final, intervals=intervals, degree=degree, method=method)
    ocp.minimize(integral=ca.sumsqr(u))
    ocp.initial({"p": [np.sin(cone_angle), 0.0, -np.cos(cone_angle)]})
    ocp.periodic(["p", "v"])
    ocp.set_guess({"v": [0.0, 1.5, 0.0]})
    return ocp


def pendulum3d_periodic_figure(sol, path: str) -> None:
    """Orbit and controls of a :func:`pendulum3d_periodic_ocp` solution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..plot import plot_in_plane

    fig = plt.figure(figsize=(13, 4.2))
    ax1 = fig.add_subplot(1, 3, 1)
    p = np.asarray(sol["p"], dtype=float)
    # the orbit is drawn in the plane it lies in (a planar swing: the plane y = 0), with the
    # pivot and the rod at t = 0, on equal scales
    _, plane = plot_in_plane(np.vstack([p, np.zeros((1, 3))]), ax=ax1, color="none")
    q = plane.project(p)
    piv = plane.project(np.zeros((1, 3)))[0]
    ax1.plot(q[:, 0], q[:, 1], color="tab:blue", lw=2, label="orbit p(t)")
    ax1.plot([piv[0], q[0, 0]], [piv[1], q[0, 1]], "-", color="0.3", lw=1.2, label="rod at t = 0")
    ax1.plot(*piv, "ks", ms=5)
    ax1.plot(*q[0], "o", color="k", ms=5, label="p(0) = p(T)")
    ax1.legend(fontsize=7, loc="upper right")
    ax1.set_title(f"orbit in the plane {plane.name} (off it by <= {plane.out_of_plane:.0e} m)",
                  fontsize=9)
    ax2 = fig.add_subplot(1, 3, 2)
    ax2.step(sol.t, sol["u"], where="pre")
    ax2.legend(["u[0]", "u[1]", "u[2]"], fontsize=7)
    ax2.set_xlabel("t [s]")
    ax2.set_ylabel("force u [N]")
    ax3 = fig.add_subplot(1, 3, 3)
    ax3.semilogy(sol.t, np.abs(sol.invariants) + 1e-18)
    ax3.legend(sol.invariant_names, fontsize=7)
    ax3.set_xlabel("t [s]")
    ax3.set_ylabel("|invariant| [m^2], [m^2/s]")
    ax3.set_title("invariants (imposed at t = 0 only)")
    fig.suptitle(f"3D pendulum periodic orbit, T = {sol.T:g} s, "
                 f"{sol.boundary.rank} of {sol.boundary.n_conditions} boundary conditions kept")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_all(directory: str = ".") -> dict:
    """Solve the three examples and save their figures in ``directory``; returns the solutions."""
    import os

    out = {}
    for name, make, fig in (
        ("crane", crane_ocp, crane_figure),
        ("delta_robot", delta_robot_ocp, delta_robot_figure),
        ("pendulum3d_periodic", pendulum3d_periodic_ocp, pendulum3d_periodic_figure),
    ):
        ocp = make()
        sol = ocp.solve()
        fig(sol, os.path.join(directory, f"ocp_{name}.png"))
        out[name] = sol
    return out
