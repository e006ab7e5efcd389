"""ReducedDAE: an index-1 semi-explicit DAE with its consistency conditions.

``x' = ode(t, x, z, u, p)``, ``0 = alg(t, x, z, u, p)`` with ``d alg / d z`` nonsingular, plus the
invariants (consistency conditions) ``0 = invariants(t, x, z, u, p)`` that must hold at the
initial time, and a map from the original model's names to expressions in these symbols.
"""

from __future__ import annotations

import copy
import pickle
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

import casadi as ca
import numpy as np

from .wording import count

__all__ = ["ReducedDAE", "Numel"]

T = TypeVar("T")


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
    stabilization : str or None
        The stabilization built into the equations (``"baumgarte"``, ``"ggl"``) or None.
    alg_names : list of str
        One name per element of ``alg``, in the model's words (``"newton[0]"``,
        ``"d2/dt2 rod"``); :attr:`alg_labels` falls back to ``"alg[i]"`` where it is empty.
    index : int
        The differential index of this form: 1, or 2 for the GGL form (integrate with
        ``suppress_algebraic``).
    origin : ReducedDAE or None
        The index-1 system an index-2 form was made from (GGL): consistent values are found
        there.
    chains : list of dict
        The invariant chains: per constraint ``{"equation", "row", "invariants", "alg"}`` (its
        name, its row, the indices of ``c, c', ...`` in ``invariants``, the row of ``alg``
        holding its highest derivative), what Baumgarte and GGL stabilize.
    offsets : dict or None
        Pryce's offsets ``{"c": ..., "d": ...}`` (equations, unknowns) of the reduction.
    amendments : list of str
        Notes on structural amendments made before the reduction (empty when none).
    eliminated, substituted : list of dict
        Would-be states eliminated through explicit definitions, and highest derivatives
        substituted (``{"variable", "equation", ...}``).
    lagrangian : daekit.mechanics.LagrangianSystem or None
        The mechanical system this was built from (``LagrangianSystem.index1()``).
    declared_invariants : list of str
        Names of invariants declared with ``Model.invariant`` (an ODE's quaternion norm, ...).
    selection_jacobian : casadi.Function or None
        Dummy derivatives: ``(t, x, z, u, p) -> `` the Jacobian whose blocks decide the state
        selection; ``selection_blocks`` lists the blocks ``(rows, cols, candidates)``.
    declared_selection : dict or None
        The state-selection block of declared invariants (for dummy derivatives).
    info : dict
        Reporting only (checks made, notes, Baumgarte poles): nothing branches on it.
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
    alg_names: list[str] = field(default_factory=list)
    index: int = 1
    origin: ReducedDAE | None = None
    chains: list[dict] = field(default_factory=list)
    offsets: dict | None = None
    amendments: list[str] = field(default_factory=list)
    eliminated: list[dict] = field(default_factory=list)
    substituted: list[dict] = field(default_factory=list)
    lagrangian: object = None
    declared_invariants: list[str] = field(default_factory=list)
    selection_jacobian: ca.Function | None = None
    selection_blocks: list = field(default_factory=list)
    declared_selection: dict | None = None
    info: dict = field(default_factory=dict)

    nx = Numel("x", "Number of differential states.")
    nz = Numel("z", "Number of algebraic unknowns.")
    nu = Numel("u", "Number of inputs (controls and input derivatives).")
    n_p = Numel("p", "Number of parameters.")

    @property
    def alg_labels(self) -> list[str]:
        """One label per element of ``alg``: :attr:`alg_names` when it names every element,
        otherwise ``"alg[i]"``."""
        if len(self.alg_names) == self.nz:
            return list(self.alg_names)
        return [f"alg[{i}]" for i in range(self.nz)]

    def derived(self, key: str, build: Callable[[ReducedDAE], T]) -> T:
        """``build(self)``, built once and kept on this system: the one cache of what is made
        from a ReducedDAE (integrators, projectors, initialization functions, event lists).

        The object lives as long as the system (freed with it), is never pickled, and is
        rebuilt when the symbolic content changes (an attribute such as ``alg`` or
        ``variables`` reassigned) or on a copy (``copy.copy``, ``dataclasses.replace``).

        >>> import daekit as dk
        >>> r = dk.reduce_index(dk.examples.pendulum_planar())
        >>> r.derived("demo", lambda r: r.nx) is r.derived("demo", lambda r: -1)
        True
        """
        # the content by identity: the objects themselves are kept, so no id can be reused
        refs = (self.t, self.x, self.z, self.u, self.p, self.ode, self.alg, self.invariants,
                self.variables)
        store = self.__dict__.setdefault("_derived", {})
        hit = store.get(key)
        if (hit is None or hit[1] != len(self.variables)
                or any(a is not b for a, b in zip(hit[0], refs, strict=True))):
            hit = store[key] = (refs, len(self.variables), build(self))
        return hit[2]

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
        new.__dict__.update({k: v for k, v in self.__dict__.items() if k != "_derived"})
        return new

    def __deepcopy__(self, memo: dict) -> ReducedDAE:
        new = object.__new__(type(self))
        memo[id(self)] = new
        state = {k: v for k, v in self.__dict__.items() if k != "_derived"}
        new.__dict__.update(copy.deepcopy(state, memo))
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
