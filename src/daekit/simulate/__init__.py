"""Simulation of reduced DAEs: IDAS through CasADi, drift control, and the Trajectory.

>>> from daekit.simulate import simulate, Trajectory
"""

from .idas import simulate
from .inputs import InputError
from .projection import Projector
from .storage import load_trajectory
from .trajectory import NameNotFoundError, Trajectory

__all__ = ["simulate", "Trajectory", "Projector", "InputError", "NameNotFoundError",
           "load_trajectory"]
