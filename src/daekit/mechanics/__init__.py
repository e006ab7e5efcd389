"""Mechanical systems: the Lagrangian front end (:class:`LagrangianSystem`, kinetic and
potential energy, constraints and forces -> a :class:`daekit.Model` or the index-1 KKT form)
and the constrained-mechanics type RATTLE integrates (:class:`ConstrainedMechanics`).

>>> import daekit as dk
>>> from daekit.mechanics import ConstrainedMechanics, as_constrained_mechanics
>>> sysm = as_constrained_mechanics(dk.examples.lagrangian_pendulum3d())
>>> isinstance(sysm, ConstrainedMechanics), sysm.n, sysm.m
(True, 3, 1)
"""

from .constrained import ConstrainedMechanics, acceleration_name, as_constrained_mechanics
from .lagrangian import LagrangianSystem, lagrangian

__all__ = ["LagrangianSystem", "lagrangian", "ConstrainedMechanics", "as_constrained_mechanics",
           "acceleration_name"]
