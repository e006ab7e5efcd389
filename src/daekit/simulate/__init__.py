"""Simulation of reduced DAEs: IDAS through CasADi on an event-driven driver, drift control,
RATTLE, and the Trajectory.

>>> from daekit.simulate import simulate, Trajectory
"""

from ..inputs import InputError
from .dispatch import NothingToStabilizeWarning, simulate
from .driver import Action, Driver, Firing, Monitor, Segment
from .projection import Projector
from .trajectory import NameNotFoundError, Trajectory, load_trajectory

__all__ = ["simulate", "Trajectory", "Projector", "InputError", "NameNotFoundError", "Driver",
           "Monitor", "Segment", "Firing", "Action", "NothingToStabilizeWarning",
           "load_trajectory"]
