"""The one rule of the entry points that need an index-1 system: what people pass is accepted.

:func:`daekit.simulate`, :func:`daekit.initialize` and :func:`daekit.ensemble` take a
:class:`~daekit.ReducedDAE`; given a :class:`~daekit.Model` they reduce it with the default
method (:func:`~daekit.reduction.reduce_index`, by dummy derivatives when the stabilization
asks for it), given a :class:`~daekit.mechanics.LagrangianSystem` they use its ``index1()``
form, and they say so in a note (``traj.stats["reduced"]``, ``init.notes``,
``ens.stats["notes"]``). The reduction is made once per model and method and reused by the
next call on the same, unchanged, model: ``initialize(m)`` then ``simulate(m, t, init)`` work
on the same reduced system.
"""

from __future__ import annotations

import weakref

from ..errors import ModelError
from ..model import Model
from ..reduced import ReducedDAE

__all__ = ["as_reduced"]

_AUTO: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _fingerprint(m: Model) -> tuple:
    return (len(m.equations), len(m.variables), tuple(m.equation_names))


def as_reduced(obj, where: str, stabilization: str | None = None, method: str = "idas",
               notes: list[str] | None = None) -> ReducedDAE:
    """``obj`` as a ReducedDAE for the entry point ``where``, reducing a Model automatically.

    A note saying what was done is appended to ``notes`` (when given).

    >>> import daekit as dk
    >>> from daekit.reduction import as_reduced
    >>> notes = []
    >>> m = dk.examples.pendulum_planar()
    >>> r = as_reduced(m, "simulate", notes=notes)
    >>> r.method, r is as_reduced(m, "initialize"), notes[0][:40]
    ('differentiate', True, 'simulate: the Model was reduced automati')
    """
    if isinstance(obj, ReducedDAE):
        return obj
    lagrangian = hasattr(obj, "index1") and callable(getattr(obj, "model", None))
    if not lagrangian and not isinstance(obj, Model):
        raise ModelError(
            f"{where} needs a daekit.ReducedDAE (r = dk.reduce_index(model)), a daekit.Model or "
            f"a daekit.mechanics.LagrangianSystem, got {type(obj).__name__}"
        )
    red = "dummy_derivatives" if stabilization == "dummy_derivatives" else "differentiate"
    if method == "rattle" and not lagrangian:
        raise ModelError(
            f"{where}(method='rattle') needs a mechanical system: RATTLE integrates "
            "M q'' = F(t, q, u) - G(q)^T z with c(q) = 0 and must know M, the potential and the "
            "constraints c separately, which a Model's equations do not say. Build it with "
            "daekit.mechanics.lagrangian(...) / LagrangianSystem (kinetic energy, potential, "
            "constraints) and pass that (or its .index1()), or use method='idas' with "
            "stabilization='projection' on this Model"
        )
    key_method = "index1" if (lagrangian and red == "differentiate") else red
    cached = _AUTO.get(obj)
    fp = (key_method, _fingerprint(obj.model() if lagrangian else obj))
    if cached is not None and cached[0] == fp:
        r = cached[1]
    else:
        from .reduce import reduce_index

        if lagrangian:
            r = obj.index1() if red == "differentiate" else reduce_index(obj.model(), method=red)
        else:
            r = reduce_index(obj, method=red)
        # the system is shared by every entry point that receives this model: its note says
        # what was done, not for whom (each call's own note goes to ``notes``)
        r.info.setdefault("notes", []).append(
            f"reduced automatically; the {'LagrangianSystem' if lagrangian else 'Model'} was "
            "given where a ReducedDAE is expected")
        try:
            _AUTO[obj] = (fp, r)
        except TypeError:  # not weak-referenceable: no reuse
            pass
    kind = "LagrangianSystem" if lagrangian else "Model"
    how = "its index1() form" if key_method == "index1" else f"dk.reduce_index(..., method={red!r})"
    note = (f"{where}: the {kind} was reduced automatically with {how}; reduce it once yourself "
            "(r = dk.reduce_index(model)) to choose the method and reuse it")
    if notes is not None:
        notes.append(note)
    return r
