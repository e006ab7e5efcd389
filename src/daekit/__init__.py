"""daekit: differential-algebraic equations of any index.

Analysis (index, offsets, degrees of freedom, explanation), index reduction with consistency
conditions, consistent initialization, simulation with drift control, and optimal control.

>>> import daekit as dk
>>> m = dk.examples.pendulum_planar()
>>> dk.analyze(m).index
3
"""

from . import examples, structure
from .analysis import Analysis, EasyTest, analyze, differential_index, is_index1
from .errors import (
    DaekitError,
    InitializationError,
    ModelError,
    OCPError,
    ReductionError,
    SimulationError,
    StructuralError,
)
from .model import Model

__version__ = "0.1.0"

__all__ = [
    "Analysis",
    "DaekitError",
    "EasyTest",
    "InitializationError",
    "Model",
    "ModelError",
    "OCPError",
    "ReductionError",
    "SimulationError",
    "StructuralError",
    "analyze",
    "differential_index",
    "examples",
    "is_index1",
    "structure",
]
