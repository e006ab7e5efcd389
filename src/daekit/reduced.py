"""ReducedDAE: an index-1 semi-explicit DAE with its consistency conditions.

``x' = ode(t, x, z, u, p)``, ``0 = alg(t, x, z, u, p)`` with ``d alg / d z`` nonsingular, plus the
invariants (consistency conditions) ``0 = invariants(t, x, z, u, p)`` that must hold at the
initial time, and a map from the original model's names to expressions in these symbols.
"""

from __future__ import annotations

import copy
import pickle
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .wording import count

__all__ = ["ReducedDAE", "Numel"]


class Numel:
    """A read-only size attribute: the number of elements of the SX attribute ``attr``
    (``nx = Numel("x")`` gives ``obj.nx == obj.x.numel()``), shared by the systems that
    carry symbol vectors (this ReducedDAE, the OCP's augmented system)."""

    def __init__(self, attr: str, doc: str = "") -> None:
        self.attr = attr
        self.__doc__ = doc or f"Number of elements of ``{attr}``."

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return int(getattr(obj, self.attr).numel())


@dataclass
class ReducedDAE:
    """An index-1 DAE in semi-explicit form together with its invariants.

    Attributes
    ----------
    t, x, z, u, p : casadi.SX
        Time, differential states, algebraic unknowns, inputs (the model's controls followed by
        the input derivatives the reduction needs), parameters.
    ode, alg : casadi.SX
        Right-hand side of ``x' = ode`` and residual ``0 = alg``.
    invariants : casadi.SX
        Consistency conditions; they hold along exact solutions and must hold initially.
    invariant_names : list of str
        One name per invariant element, e.g. ``["rod", "d/dt rod"]``.
    x_names, z_names, u_names, p_names : list of str
        Element names of ``x``, ``z``, ``u``, ``p`` in the original model's naming
        (``"p[0]"``, ``"der(p)[0]"``, ``"der(u,2)"``).
    p_values : numpy.ndarray
        Default parameter values.
    variables : dict of str to casadi.SX
        Every element of the original model (unknowns and their derivatives up to the order used)
        as an expression of ``t, x, z, u, p``: how to read original names off a solution.
    input_derivatives : list of str
        Names of input derivatives the reduction needs (also the tail of ``u_names``).
    control_names : list of str
        The original model's control variables (vector names, e.g. ``["u"]``).
    state_selection : dict or None
        For dummy derivatives: which derivatives stayed states and which became dummies.
    method : str
        How it was made: ``"differentiate"``, ``"dummy_derivatives"``, ``"lagrangian"``, ...
    model : daekit.Model or None
        The original model.
    """

    t: ca.SX
    x: ca.SX
    z: ca.SX
    u: ca.SX
    p: ca.SX
    ode: ca.SX
    alg: ca.SX
    invariants: ca.SX
    invariant_names: list[str]
    x_names: list[str]
    z_names: list[str]
    u_names: list[str]
    p_names: list[str]
    p_values: np.ndarray
    variables: dict[str, ca.SX] = field(default_factory=dict)
    input_derivatives: list[str] = field(default_factory=list)
    control_names: list[str] = field(default_factory=list)
    state_selection: dict | None = None
    method: str = "differentiate"
    model: object = None
    stabilization: str | None = None
    info: dict = field(default_factory=dict)

    nx = Numel("x", "Number of differential states.")
    nz = Numel("z", "Number of algebraic unknowns.")
    nu = Numel("u", "Number of inputs (controls and input derivatives).")
    n_p = Numel("p", "Number of parameters.")

    def dae_dict(self) -> dict:
        """The ``{'t','x','z','p','ode','alg'}`` dict of ``casadi.integrator`` (inputs u go
        into ``p`` after the parameters)."""
        return {
            "t": self.t,
            "x": self.x,
            "z": self.z,
            "p": ca.vertcat(self.p, self.u),
            "ode": self.ode,
            "alg": self.alg,
        }

    # ------------------------------------------------------------------ pickling
    # CasADi SX pickle only inside a casadi pickle context (one serializer for all of them, so
    # that shared symbols stay shared). A ReducedDAE opens its own when none is open: it can be
    # pickled as is, e.g. to ship it to worker processes once (daekit.ensemble).
    # copy.copy / copy.deepcopy as before (shared symbols), not through the serialization
    def __copy__(self) -> ReducedDAE:
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        return new

    def __deepcopy__(self, memo: dict) -> ReducedDAE:
        new = object.__new__(type(self))
        memo[id(self)] = new
        new.__dict__.update(copy.deepcopy(self.__dict__, memo))
        return new

    def __getstate__(self) -> dict:
        # private caches (``_initialize_cache``, ...) hold local functions and are rebuilt on
        # first use: not pickled
        state = {k: v for k, v in self.__dict__.items() if not k.startswith("_")}
        if _casadi_context_open("pickle"):
            return state
        with ca.global_pickle_context():
            blob = pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
        return {"casadi_blob": blob}

    def __setstate__(self, state: dict) -> None:
        if set(state) == {"casadi_blob"}:
            with ca.global_unpickle_context():
                state = pickle.loads(state["casadi_blob"])  # noqa: S301 - our own blob
        self.__dict__.update(state)

    def __repr__(self) -> str:
        return (
            f"ReducedDAE({self.method}: {count(self.nx, 'state')}, {self.nz} algebraic, "
            f"{count(self.nu, 'input')}, {count(len(self.invariant_names), 'invariant')})"
        )


def _casadi_context_open(kind: str) -> bool:
    """Whether a ``casadi.global_pickle_context`` (``kind="pickle"``) or
    ``global_unpickle_context`` is open in this thread."""
    probe = getattr(ca.casadi, f"_current_{kind}_context", None)
    try:
        return probe is not None and probe() is not None
    except Exception:  # noqa: BLE001 - another CasADi version: open our own
        return False
