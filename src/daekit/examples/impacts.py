"""Impacts, end stops and stop conditions: models with events (:meth:`daekit.Model.event`).

- :func:`pendulum_wall`: the planar Cartesian pendulum (index 3) hitting a wall at ``x = 0``
  (the bottom) with restitution ``e``; exact impact times in
  :func:`daekit.examples.exact.pendulum_wall_impacts`.
- :func:`crane_end_stop`: an overhead crane (trolley on a rail, load on a cable) as a
  :class:`daekit.mechanics.LagrangianSystem`; the trolley is pushed for a while, hits an end
  stop (restitution ``e``: the trolley's velocity is reversed, the cable constraint re-imposed
  by the mass-weighted projection, so the load feels the impulse through the cable), and a
  terminal event stops the simulation when the load is at rest (the mechanical energy of
  the swing below a threshold).

>>> import numpy as np, daekit as dk
>>> from daekit.examples.exact import pendulum_wall_impacts
>>> r = dk.reduce_index(pendulum_wall(0.8))
>>> init = dk.initialize(r, fixed={"x": 1.0, "y": 0.0, "der(x)": 0.0})
>>> traj = dk.simulate(r, np.linspace(0, 2, 21), init, rtol=1e-10, atol=1e-10)
>>> te = [t for t, name in traj.events]
>>> bool(np.max(np.abs(np.array(te) - pendulum_wall_impacts(len(te), 0.8))) < 1e-8)
True
"""

from __future__ import annotations

import casadi as ca

from ..model import Model

__all__ = ["pendulum_wall", "crane_end_stop", "CRANE_END_STOP_INIT"]


def pendulum_wall(e: float = 0.8, g: float = 9.81, L: float = 1.0) -> Model:
    """The planar pendulum (:func:`daekit.examples.pendulum_planar`) with a wall at ``x = 0``.

    Event ``wall``: ``x`` crosses zero falling; reset ``der(x) -> -e der(x)``,
    ``der(y) -> -e der(y)`` (restitution ``e``). Released at rest from horizontal
    (``x = L``, ``y = 0``) the impacts come at the times of
    :func:`daekit.examples.exact.pendulum_wall_impacts`. Index 3, DOF 2.

    >>> m = pendulum_wall(0.5)
    >>> [(ev.name, ev.direction) for ev in m.events]
    [('wall', -1)]
    """
    from .pendula import pendulum_planar

    m = pendulum_planar(g=g, L=L)
    m.name = "pendulum_wall"
    x = m.variables["x"].sym
    y = m.variables["y"].sym
    m.event(x, name="wall", direction=-1,
            reset={"der(x)": -e * m.der(x), "der(y)": -e * m.der(y)})
    return m


#: consistent-enough starting values of :func:`crane_end_stop` (trolley at 0, load hanging)
CRANE_END_STOP_INIT = {"q[0]": 0.0, "q[1]": 0.0, "q[2]": -1.0, "der(q)[0]": 0.0,
                       "der(q)[1]": 0.0}


def crane_end_stop(e: float = 0.5, stop: float = 0.5, push: float = 3.0, t_push: float = 0.5,
                   M: float = 1.0, m: float = 0.5, L: float = 1.0, g: float = 9.81,
                   friction: float = 1.0, drag: float = 0.4, rest: float = 1e-3):
    """An overhead crane whose trolley hits an end stop; the simulation stops at rest.

    Coordinates ``q = (s, x, y)``: trolley position ``s`` on the rail, load at ``(x, y)``;
    ``T = M s'^2 / 2 + m (x'^2 + y'^2) / 2``, ``V = m g y``, cable
    ``(x - s)^2 + y^2 - L^2 = 0``. Forces: a push ``push`` on the trolley while
    ``t < t_push`` (an ``if_else`` on time: a switch the simulator stops at), viscous friction
    ``-friction s'`` of the trolley and air drag ``-drag (x', y')`` of the load.

    Events on the model (``crane_end_stop().model().events``):

    - ``end_stop``: ``s - stop`` crosses zero rising; reset ``der(q)[0] -> -e der(q)[0]``
      (only the trolley's velocity: the cable's velocity constraint is then re-imposed by the
      mass-weighted projection, ``M = diag(M, m, m)``, the impulse through the cable);
    - ``at_rest`` (terminal): the mechanical energy ``T + m g (y + L)`` falls below ``rest``.

    Index 3, DOF 4. Start: :data:`CRANE_END_STOP_INIT` (trolley at 0, load hanging at rest).

    >>> ls = crane_end_stop()
    >>> [ev.name for ev in ls.model().events], ls.coordinate_names
    (['end_stop', 'at_rest'], ['q[0]', 'q[1]', 'q[2]'])
    """
    from ..mechanics import lagrangian

    q = ca.SX.sym("q", 3)
    dq = ca.SX.sym("dq", 3)
    t = ca.SX.sym("t")
    s, x, y = q[0], q[1], q[2]
    T = 0.5 * M * dq[0] ** 2 + 0.5 * m * (dq[1] ** 2 + dq[2] ** 2)
    V = m * g * y
    force = ca.vertcat(ca.if_else(t < t_push, push, 0.0) - friction * dq[0],
                       -drag * dq[1], -drag * dq[2])
    ls = lagrangian({"q": q}, {"q": dq}, T, V=V, constraints={"cable": (x - s) ** 2 + y**2 - L**2},
                    forces=force, t=t, name="crane_end_stop")
    mdl = ls.model()
    qq = mdl.variables["q"].sym
    vq = mdl.der(qq)
    mdl.event(qq[0] - stop, name="end_stop", direction=1, reset={"der(q)[0]": -e * vq[0]})
    energy = (0.5 * M * vq[0] ** 2 + 0.5 * m * (vq[1] ** 2 + vq[2] ** 2)
              + m * g * (qq[2] + L))
    mdl.event(energy - rest, name="at_rest", direction=-1, terminal=True)
    return ls
