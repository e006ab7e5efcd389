"""Model library: the lecture examples, pendulums, chains, delta robot, test-set problems.

Every function returns a fresh :class:`daekit.Model`; its docstring names the source, the known
differential index and DOF, and the exact solution where one is known
(:mod:`daekit.examples.exact`). :func:`catalog` lists them all with their published numbers.

>>> import daekit as dk
>>> m = dk.examples.pendulum3d()
>>> a = dk.analyze(m)
>>> a.index, a.dof
(3, 4)
>>> sorted(catalog())[:3]
['arevalo', 'brenan', 'chained_pendula']
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from ..model import Model
from . import exact
from .classic import (
    CHEMAKZO_DATA,
    TRANSISTOR_DATA,
    arevalo,
    brenan,
    chemakzo,
    e1,
    e2,
    e3,
    jay,
    transistor_amplifier,
)
from .failures import f1, f2, f3, gear_petzold, iwata_nonlinear, oki_linear
from .impacts import CRANE_END_STOP_INIT, crane_end_stop, pendulum_wall
from .invariants import (
    lifted_pendulum,
    lifted_square,
    quadrotor,
    quadrotor_yaw_ocp,
    rigid_body,
)
from .lecture import (
    DELTA_GAMMA,
    delta_robot,
    delta_robot_home,
    l1,
    l2,
    l3,
    l4,
    l5,
    l6,
    pendulum3d,
)
from .mechanisms import (
    DELTA_ROBOT_DATA,
    lagrangian_delta_robot,
    lagrangian_delta_robot_home,
    lagrangian_pendulum3d,
    lagrangian_planar_chain,
)
from .pendula import chained_pendula, pendulum_planar, planar_chain
from .slider_crank import SLIDER_CRANK_DATA, slider_crank

__all__ = [
    "CRANE_END_STOP_INIT",
    "crane_end_stop",
    "pendulum_wall",
    "DELTA_ROBOT_DATA",
    "lagrangian_delta_robot",
    "lagrangian_delta_robot_home",
    "lagrangian_pendulum3d",
    "lagrangian_planar_chain",
    "CHEMAKZO_DATA",
    "DELTA_GAMMA",
    "TRANSISTOR_DATA",
    "CatalogEntry",
    "arevalo",
    "brenan",
    "catalog",
    "chained_pendula",
    "chemakzo",
    "delta_robot",
    "delta_robot_home",
    "e1",
    "e2",
    "e3",
    "exact",
    "f1",
    "f2",
    "f3",
    "gear_petzold",
    "iwata_nonlinear",
    "jay",
    "lifted_pendulum",
    "lifted_square",
    "quadrotor",
    "quadrotor_yaw_ocp",
    "rigid_body",
    "l1",
    "l2",
    "l3",
    "l4",
    "l5",
    "l6",
    "oki_linear",
    "pendulum3d",
    "pendulum_planar",
    "planar_chain",
    "SLIDER_CRANK_DATA",
    "slider_crank",
    "transistor_amplifier",
]


class CatalogEntry(NamedTuple):
    """One entry of :func:`catalog`: how to build the model and what the literature says."""

    factory: Callable[[], Model]
    index: int  # known differential index
    dof: int  # known number of dynamic degrees of freedom
    source: str


def catalog() -> dict[str, CatalogEntry]:
    """All example models: name -> ``(factory, known index, known DOF, source)``.

    The index and DOF are the published (true) values; for F1-F3 the structural analysis
    claims less (see their docstrings). Chains come with small default sizes.

    >>> entry = catalog()["pendulum_planar"]
    >>> entry.index, entry.dof, entry.factory().name
    (3, 2, 'pendulum_planar')
    """
    gros = 'S. Gros, "Numerical Optimal Control with DAEs", lecture 11 (2016)'
    testset = "Test Set for IVP Solvers (Mazzia, Magherini, Iavernaro), Univ. Bari"
    return {
        "l1": CatalogEntry(l1, 1, 1, gros + ", L1"),
        "l2": CatalogEntry(l2, 3, 0, gros + ", L2"),
        "l3": CatalogEntry(l3, 3, 4, gros + ", L3 (3D pendulum)"),
        "l4": CatalogEntry(l4, 3, 6, gros + ", L4 (delta robot)"),
        "l5": CatalogEntry(l5, 1, 1, gros + ", L5"),
        "l6": CatalogEntry(l6, 2, 1, gros + ", L6"),
        "pendulum3d": CatalogEntry(pendulum3d, 3, 4, gros + ", L3"),
        "delta_robot": CatalogEntry(delta_robot, 3, 6, gros + ", L4"),
        "pendulum_planar": CatalogEntry(
            pendulum_planar, 3, 2, "Hairer & Wanner, Solving ODEs II, ch. VII"
        ),
        "pendulum_wall": CatalogEntry(
            pendulum_wall, 3, 2, "planar pendulum with a wall at x = 0 (restitution 0.8)"
        ),
        "crane_end_stop": CatalogEntry(
            lambda: crane_end_stop().model(), 3, 4,
            "overhead crane: trolley end stop (restitution 0.5), terminal at rest",
        ),
        "chained_pendula": CatalogEntry(
            lambda: chained_pendula(3), 7, 6, "Pryce, BIT 41 (2001); DAESA (p = 3)"
        ),
        "planar_chain": CatalogEntry(
            lambda: planar_chain(5), 3, 10, "chain of N = 5 rigid links (Lagrange, first order)"
        ),
        "gear_petzold": CatalogEntry(gear_petzold, 2, 0, "F1: Ascher & Petzold (1998)"),
        "f2": CatalogEntry(f2, 3, 0, "F2: T. Oki, DAE preprocessing toolbox demo"),
        "f3": CatalogEntry(f3, 2, 0, "F3: Iwata, Oki, Takamatsu, J. ACM 66(5) (2019)"),
        "brenan": CatalogEntry(brenan, 1, 1, "E1: Brenan, Campbell, Petzold (1996), ch. 4"),
        "jay": CatalogEntry(jay, 2, 1, "E2: L. Jay, BIT 33 (1993), example 7"),
        "arevalo": CatalogEntry(arevalo, 3, 2, "E3: C. Arevalo (1995), particle on a circle"),
        "chemakzo": CatalogEntry(chemakzo, 1, 5, testset + ", chemakzo"),
        "transistor_amplifier": CatalogEntry(transistor_amplifier, 1, 5, testset + ", transamp"),
        "slider_crank": CatalogEntry(
            slider_crank, 2, 11,
            testset + ", crank (index-2 form; Simeon's model, equations derived here)",
        ),
        "rigid_body": CatalogEntry(
            rigid_body, 0, 6, "free rigid body, unit quaternion (reference-problems.md, sec. 7)"
        ),
        "lifted_pendulum": CatalogEntry(
            lifted_pendulum, 0, 2, "pendulum lifted to (sin, cos): Hairer & Wanner, ch. VII"
        ),
        "lifted_square": CatalogEntry(lifted_square, 0, 1, "x' = x^2 lifted with w = x^2"),
        "quadrotor": CatalogEntry(quadrotor, 0, 12, "quadrotor, quaternion attitude"),
    }
