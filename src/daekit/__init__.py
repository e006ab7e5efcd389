"""daekit: differential-algebraic equations of any index.

Analysis (index, offsets, degrees of freedom, explanation), index reduction with consistency
conditions, consistent initialization, simulation with drift control, and optimal control.

>>> import daekit as dk
>>> m = dk.examples.pendulum_planar()
>>> dk.analyze(m).index
3
"""

from . import events, mechanics, structure
from .analysis import Analysis, EasyTest, analyze, differential_index, is_index1
from .ensemble import Ensemble, ensemble, ensemble_ocp, sample
from .errors import (
    DaekitError,
    InitializationError,
    ModelError,
    OCPError,
    ReductionError,
    SimulationError,
    StructuralError,
)
from .initialize import InitialValues, initialize
from .mechanics import LagrangianSystem, lagrangian
from .model import Model
from .ocp import OCP, Free, OCPSolution
from .reduced import ReducedDAE
from .reduction import (
    BaumgarteStiffnessWarning,
    baumgarte,
    format_reduced,
    ggl,
    reduce_index,
    reselect,
    selection_condition,
)
from .simulate import InputError, Trajectory, load_trajectory, simulate

__version__ = "0.1.0"


def __getattr__(name: str):
    # The example library (and SciPy's special functions its exact solutions need) is imported
    # on first use, so that ``import daekit`` costs little more than CasADi, NumPy and SciPy.
    if name == "examples":
        import importlib

        return importlib.import_module(".examples", __name__)
    raise AttributeError(f"module 'daekit' has no attribute {name!r}")


__all__ = [
    "OCP",
    "Analysis",
    "BaumgarteStiffnessWarning",
    "Free",
    "InitialValues",
    "InputError",
    "LagrangianSystem",
    "OCPSolution",
    "ReducedDAE",
    "Trajectory",
    "baumgarte",
    "format_reduced",
    "ggl",
    "initialize",
    "lagrangian",
    "load_trajectory",
    "mechanics",
    "reduce_index",
    "reselect",
    "selection_condition",
    "simulate",
    "DaekitError",
    "EasyTest",
    "Ensemble",
    "ensemble",
    "ensemble_ocp",
    "sample",
    "InitializationError",
    "Model",
    "ModelError",
    "OCPError",
    "ReductionError",
    "SimulationError",
    "StructuralError",
    "analyze",
    "differential_index",
    "events",
    "examples",
    "is_index1",
    "structure",
]
