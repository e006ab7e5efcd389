"""Exception classes of daekit.

Every error daekit raises on bad input is a :class:`DaekitError`, and its message names the
equation or variable at fault and says what to do.

One rule for all of them: a daekit error says that something the user gave (a model, values,
options, a problem statement) cannot be used as given -- an argument with the right type and an
inappropriate value -- so every :class:`DaekitError` is also a :class:`ValueError`. Code that
guards against bad input in general catches ``ValueError``; code that wants daekit's own
diagnosis catches ``DaekitError`` or one of its subclasses below. Bugs inside daekit surface as
other exceptions, never as a ``DaekitError``.

>>> import daekit as dk
>>> all(issubclass(e, ValueError) for e in (dk.ModelError, dk.ReductionError,
...     dk.InitializationError, dk.SimulationError, dk.OCPError))
True
"""

from __future__ import annotations


class DaekitError(ValueError):
    """Base class of all daekit errors."""


class ModelError(DaekitError):
    """The model is malformed: an undeclared symbol, a bad ``der``, a duplicate name, ..."""


class StructuralError(ModelError):
    """The model is not square or is structurally singular.

    Attributes
    ----------
    overdetermined_equations, underdetermined_variables : list of str
        Names from the Dulmage--Mendelsohn decomposition: equations of the over-determined
        part, variables of the under-determined part.
    """

    def __init__(
        self,
        message: str,
        overdetermined_equations: list[str] | None = None,
        overdetermined_variables: list[str] | None = None,
        underdetermined_equations: list[str] | None = None,
        underdetermined_variables: list[str] | None = None,
    ) -> None:
        super().__init__(message)
        self.overdetermined_equations = overdetermined_equations or []
        self.overdetermined_variables = overdetermined_variables or []
        self.underdetermined_equations = underdetermined_equations or []
        self.underdetermined_variables = underdetermined_variables or []


class ReductionError(DaekitError):
    """Index reduction could not produce an index-1 system."""


class InitializationError(DaekitError):
    """No consistent initial values for the given fixed values and guesses."""


class SimulationError(DaekitError):
    """The integrator failed. ``.t`` is the time, ``.trajectory`` the part computed so far."""

    def __init__(self, message: str, t: float | None = None, trajectory=None) -> None:
        super().__init__(message)
        self.t = t
        self.trajectory = trajectory


class OCPError(DaekitError):
    """An optimal control problem is ill-posed or its solver failed."""
