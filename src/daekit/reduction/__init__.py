"""Index reduction: any-index model -> index-1 DAE with its consistency conditions.

- :func:`reduce_index` -- Pryce's differentiation scheme (with explicit derivatives such as
  ``p' = v`` eliminated, :mod:`daekit.reduction.eliminate`), or dummy derivatives.
- :func:`dummy_derivatives`, :func:`reselect`, :func:`selection_condition` -- state selection.
- :func:`baumgarte`, :func:`ggl` -- stabilizations of a :class:`~daekit.ReducedDAE`.
- :func:`time_derivative` -- total time derivative of a model expression.
- :func:`format_reduced` -- a readable account of a reduced DAE.
- :func:`as_reduced` -- the entry points' rule: a Model or LagrangianSystem is reduced for you.
"""

from .accept import as_reduced
from .differentiate import time_derivative
from .dummy import dummy_derivatives, map_values, reselect, selection_condition
from .format import format_reduced
from .reduce import check_index1, reduce_index
from .stabilize import BaumgarteStiffnessWarning, baumgarte, ggl, time_scale

__all__ = [
    "as_reduced",
    "BaumgarteStiffnessWarning",
    "baumgarte",
    "ggl",
    "time_scale",
    "check_index1",
    "dummy_derivatives",
    "format_reduced",
    "map_values",
    "reduce_index",
    "reselect",
    "selection_condition",
    "time_derivative",
]
