"""Trajectory: a simulated (or optimized) solution, read by the original model's names.

A :class:`Trajectory` holds the time grid, one array per scalar element name (``"p[0]"``,
``"der(p)[1]"``, ``"z"``), the invariants (consistency conditions) along the solution, and
solver statistics. Vector names are gathered on access: ``traj["p"]`` is an ``(N, 3)`` array.

Example
-------
>>> import numpy as np
>>> from daekit.simulate import Trajectory
>>> t = np.linspace(0, 1, 3)
>>> tr = Trajectory(t, {"p[0]": t, "p[1]": 2 * t, "z": -t})
>>> tr["p"].shape, float(tr["p[1]"][-1]), float(tr["z"][0])
((3, 2), 2.0, -0.0)
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping, MutableMapping

import numpy as np

from ..errors import ModelError
from ..model import NameNotFoundError, expand_name, select_name
from ..wording import count
from .storage import read_trajectory, save_trajectory

__all__ = ["Trajectory", "LazyColumns", "NameNotFoundError", "expand_name", "load_trajectory",
           "compact_pickling"]

_COMPACT = threading.local()
_FILL_LOCK = threading.RLock()


@contextlib.contextmanager
def compact_pickling() -> Iterator[None]:
    """Inside the block, trajectories whose columns are still pending pickle as their state
    arrays and a *recipe* for the rest (:class:`LazyColumns` with ``recipe=``), not as every
    column computed: about half the bytes, and no column computed by the sender. The recipe
    holds the system it was made from, so the receiver must know that system (an ensemble's
    workers send to the process that gave them the system; see :mod:`daekit.ensemble`).
    Outside the block a trajectory pickles with every value computed, readable anywhere.

    >>> import pickle
    >>> with compact_pickling():
    ...     blob = pickle.dumps(LazyColumns({"x": np.ones(2)}, [], dict))
    >>> pickle.loads(blob)["x"].tolist()
    [1.0, 1.0]
    """
    before = getattr(_COMPACT, "on", False)
    _COMPACT.on = True
    try:
        yield
    finally:
        _COMPACT.on = before


def _compact() -> bool:
    return getattr(_COMPACT, "on", False)


class LazyColumns(MutableMapping):
    """A trajectory's columns by name where some are computed only when first read (all of
    those together, by one call of ``compute``): a simulation hands over its states at once
    and evaluates the other variables of the model only if someone reads them.

    >>> import numpy as np
    >>> calls = []
    >>> cols = LazyColumns({"x": np.ones(2)}, ["y"], lambda: calls.append(1) or {"y": np.zeros(2)})
    >>> list(cols), calls
    (['x', 'y'], [])
    >>> cols["y"].tolist(), calls
    ([0.0, 0.0], [1])
    """

    def __init__(self, ready: Mapping[str, np.ndarray], pending: Iterable[str],
                 compute: Callable[[], Mapping[str, np.ndarray]], order: Iterable[str] | None = None,
                 recipe=None) -> None:
        self._d = dict(ready)
        self._pending = set(pending)
        self._compute: Callable | None = compute if self._pending else None
        self._order = list(order) if order is not None else [*self._d, *pending]
        # optional: a picklable object with ready() and rest(), the same columns as ``ready``
        # and ``compute`` (pickled in its place inside compact_pickling())
        self._recipe = recipe

    def _fill(self) -> None:
        with _FILL_LOCK:  # two threads reading a pending column: one computes, both read
            fn, self._compute = self._compute, None
            if fn is not None:
                for k, v in fn().items():
                    if k in self._pending:
                        self._d[k] = v
                self._pending.clear()

    def __getitem__(self, key: str) -> np.ndarray:
        try:
            return self._d[key]
        except KeyError:
            if key in self._pending:
                self._fill()
                return self._d[key]
            raise

    def __contains__(self, key) -> bool:
        return key in self._d or key in self._pending

    def __iter__(self):
        return iter(self._order)

    def __len__(self) -> int:
        return len(self._order)

    def __setitem__(self, key: str, value) -> None:
        self._recipe = None  # changed: no longer what the recipe makes
        if key not in self:
            self._order.append(key)
        self._pending.discard(key)
        self._d[key] = value

    def __delitem__(self, key: str) -> None:
        if key not in self:
            raise KeyError(key)
        self._recipe = None
        self._pending.discard(key)
        self._d.pop(key, None)
        self._order.remove(key)

    def __reduce__(self):  # pickled (and deep-copied) as the plain dict of all columns
        if _compact() and self._recipe is not None and self._pending:
            return (_lazy_from_recipe, (self._recipe, sorted(self._pending), self._order))
        return (dict, (dict(self.items()),))


def _lazy_from_recipe(recipe, pending: list[str], order: list[str]) -> LazyColumns:
    return LazyColumns(recipe.ready(), pending, recipe.rest, order, recipe)


def _derivative_name(element: str) -> str:
    """The name of the time derivative of an element: ``p[0]`` -> ``der(p)[0]``,
    ``der(p)[0]`` -> ``der(p,2)[0]``, ``x`` -> ``der(x)``."""
    base, idx = (element.rsplit("[", 1)[0], "[" + element.rsplit("[", 1)[1]) \
        if element.endswith("]") else (element, "")
    if base.startswith("der(") and base.endswith(")"):
        inner = base[4:-1]
        if "," in inner:
            var, k = inner.rsplit(",", 1)
            try:
                return f"der({var},{int(k) + 1}){idx}"
            except ValueError:
                return f"der({base}){idx}"
        return f"der({inner},2){idx}"
    return f"der({base}){idx}"


def _vector_name(element: str) -> str:
    return element.rsplit("[", 1)[0] if element.endswith("]") else element


class Trajectory:
    """Values of a solution on a time grid, by the original model's names.

    Parameters
    ----------
    t : array (N,)
        Time points.
    values : dict of str to array (N,)
        One array per scalar element name (``"p[0]"``, ``"der(p)[0]"``, ``"z"``, ``"u[1]"``).
    invariants : array (N, n_inv), optional
        Consistency conditions evaluated along the solution (zero on exact solutions).
    invariant_names : list of str, optional
        One name per invariant column, e.g. ``["rod", "d/dt rod"]``.
    stats : dict, optional
        Solver statistics (``steps``, ``residual_evaluations``, ``wall_time``, ...).
    events : list of (float, str), optional
        Events that fired, ``(t, name)`` in time order. At an event with a jump the trajectory
        has two rows at that time: the values just before and just after it.

    Attributes
    ----------
    t, invariants, invariant_names, stats : as given.
    names : list of str
        Vector names available (``"p"``, ``"der(p)"``, ``"z"``, ...).

    ``traj["p"]`` returns ``(N, size)`` for a vector, ``(N,)`` for a scalar or an element.
    """

    #: events ``[(t, name), ...]`` (from the simulation driver)
    events: list

    def __init__(
        self,
        t,
        values: Mapping[str, np.ndarray],
        invariants=None,
        invariant_names: Iterable[str] | None = None,
        stats: dict | None = None,
        events: Iterable[tuple[float, str]] | None = None,
    ) -> None:
        self.t = np.asarray(t, dtype=float).ravel()
        self.events: list[tuple[float, str]] = [(float(te), str(n)) for te, n in (events or [])]
        n = self.t.size
        self.values: MutableMapping[str, np.ndarray]
        if isinstance(values, LazyColumns):
            self.values = values  # made by a simulation: sizes known to match
        else:
            self.values = {}
            for k, v in values.items():
                arr = np.asarray(v, dtype=float).ravel()
                if arr.size != n:
                    raise ModelError(
                        f"Trajectory: {k!r} has {arr.size} values but there are {n} time points"
                    )
                self.values[k] = arr
        self.invariant_names = list(invariant_names or [])
        if invariants is None:
            invariants = np.zeros((n, len(self.invariant_names)))
        if callable(invariants):  # evaluated when first read (see LazyColumns)
            self._invariants = None
            self._invariants_fn = invariants
        else:
            self.invariants = invariants
        self.stats = dict(stats or {})

    @property
    def invariants(self) -> np.ndarray:
        """The invariants along the solution, ``(N, n_inv)``."""
        inv = self.__dict__.get("_invariants")
        if inv is None:
            fn = self.__dict__.pop("_invariants_fn", None)
            inv = fn() if fn is not None else np.zeros((self.t.size, len(self.invariant_names)))
            self.invariants = inv
            inv = self._invariants
        return inv

    @invariants.setter
    def invariants(self, value) -> None:
        n = self.t.size
        self._invariants = np.asarray(value, dtype=float).reshape(n, -1) if n else \
            np.zeros((0, 0))
        self.__dict__.pop("_invariants_fn", None)

    def __getstate__(self) -> dict:  # pickled with every value computed
        state = dict(self.__dict__)
        state["_invariants"] = self.invariants
        state.pop("_invariants_fn", None)
        state["values"] = self.values if _compact() and isinstance(self.values, LazyColumns) \
            else dict(self.values.items())
        return state

    # ------------------------------------------------------------------ access
    def __getitem__(self, name: str) -> np.ndarray:
        if name == "t":
            return self.t
        elems, vector = select_name(name, self.values, "this trajectory")
        if not vector:
            return self.values[elems[0]]
        return np.column_stack([self.values[e] for e in elems])

    def __contains__(self, name: str) -> bool:
        try:
            expand_name(name, self.values)
        except NameNotFoundError:
            return False
        return True

    def __len__(self) -> int:
        return self.t.size

    @property
    def names(self) -> list[str]:
        out: list[str] = []
        for k in self.values:
            v = _vector_name(k)
            if v not in out:
                out.append(v)
        return out

    def invariant(self, name: str) -> np.ndarray:
        """The column of invariant ``name`` (e.g. ``"rod"`` or ``"d/dt rod"``)."""
        if name not in self.invariant_names:
            raise NameNotFoundError(
                f"no invariant named {name!r}; known: {', '.join(self.invariant_names) or 'none'}"
            )
        return self.invariants[:, self.invariant_names.index(name)]

    def max_invariant(self) -> dict[str, float]:
        """``{invariant name: max |value| over the trajectory}``."""
        if not self.invariant_names or self.t.size == 0:
            return {}
        m = np.max(np.abs(self.invariants), axis=0)
        return {n: float(v) for n, v in zip(self.invariant_names, m, strict=False)}

    def at(self, time: float) -> dict[str, float]:
        """Values at any ``time`` in ``[t[0], t[-1]]`` (by element name), interpolated.

        Cubic Hermite interpolation on the output interval containing ``time``: the slopes
        are the stored derivatives where the trajectory has them (``"der(p)[0]"`` for
        ``"p[0]"``: the DAE's own values, so the interpolant is third-order accurate), else
        second-order finite differences of the neighbouring points. At an event time (two rows
        with the same ``t``) the values after the event are returned.

        >>> import numpy as np
        >>> t = np.linspace(0.0, 1.0, 11)
        >>> tr = Trajectory(t, {"x": np.sin(t), "der(x)": np.cos(t)})
        >>> bool(abs(tr.at(0.55)["x"] - np.sin(0.55)) < 1e-6)
        True
        """
        t = self.t
        n = t.size
        try:
            tq = float(time)
        except (TypeError, ValueError):
            raise ModelError(f"Trajectory.at: time must be one number, got {time!r}") from None
        if n == 0 or not (t[0] <= tq <= t[-1]):
            span = f"[{t[0]:g}, {t[-1]:g}]" if n else "an empty trajectory"
            raise ModelError(f"Trajectory.at: t = {tq:g} is outside {span}; it interpolates only")
        k = int(np.searchsorted(t, tq, side="right")) - 1
        if k >= n - 1 or t[k] == tq:
            k = min(k, n - 1)
            return {nm: float(v[k]) for nm, v in self.values.items()}
        h = t[k + 1] - t[k]
        s = (tq - t[k]) / h
        h00, h10 = (1 + 2 * s) * (1 - s) ** 2, s * (1 - s) ** 2
        h01, h11 = s * s * (3 - 2 * s), s * s * (s - 1)
        out = {}
        for nm, v in self.values.items():
            d = self.values.get(_derivative_name(nm))
            m0 = d[k] if d is not None else self._fd_slope(v, k)
            m1 = d[k + 1] if d is not None else self._fd_slope(v, k + 1)
            out[nm] = float(h00 * v[k] + h10 * h * m0 + h01 * v[k + 1] + h11 * h * m1)
        return out

    def _fd_slope(self, v: np.ndarray, i: int) -> float:
        """Slope at row ``i`` from its neighbours (one-sided at the ends and at jumps)."""
        t = self.t
        lo = i - 1 if i > 0 and t[i - 1] < t[i] else i
        hi = i + 1 if i + 1 < t.size and t[i + 1] > t[i] else i
        if hi == lo:
            return 0.0
        if lo < i < hi:  # second order on a non-uniform grid
            h1, h2 = t[i] - t[lo], t[hi] - t[i]
            return float((h1**2 * v[hi] - h2**2 * v[lo] + (h2**2 - h1**2) * v[i])
                         / (h1 * h2 * (h1 + h2)))
        return float((v[hi] - v[lo]) / (t[hi] - t[lo]))

    def slice(self, stop: int) -> Trajectory:
        """The first ``stop`` time points."""
        return Trajectory(
            self.t[:stop],
            {k: v[:stop] for k, v in self.values.items()},
            self.invariants[:stop],
            self.invariant_names,
            self.stats,
            [e for e in self.events if self.t.size and stop > 0 and e[0] <= self.t[:stop][-1]],
        )

    # ------------------------------------------------------------------ export and figures
    def to_pandas(self):
        """A ``pandas.DataFrame`` indexed by time, one column per element and invariant.

        Raises :class:`ImportError` with advice when pandas is not installed.
        """
        try:
            import pandas as pd
        except ImportError:
            raise ImportError(
                "Trajectory.to_pandas needs pandas: pip install pandas "
                "(or use traj.t, traj['name'] and traj.invariants directly)"
            ) from None
        cols = dict(self.values)
        for j, n in enumerate(self.invariant_names):
            cols[f"invariant:{n}"] = self.invariants[:, j]
        return pd.DataFrame(cols, index=pd.Index(self.t, name="t"))

    def save(self, path) -> str:
        """Write this trajectory to ``path``, ``.parquet`` (pyarrow) or ``.npz`` (NumPy), a
        lossless documented format (:mod:`daekit.simulate.storage`); read it back with
        :func:`daekit.load_trajectory`. Returns the path written."""
        return save_trajectory(self, path)

    def plot(self, names: Iterable[str] | str | None = None, ax=None):
        """Plot the named variables over time (all states when ``names`` is None).

        Returns the matplotlib Figure; see :func:`daekit.plot.plot_trajectory`.
        """
        from ..plot import plot_trajectory

        return plot_trajectory(self, names=names, ax=ax)

    def plot_invariants(self, axes=None):
        """The lecture's drift figure: ``|c|`` and ``|c'|`` over time on log scales.

        Returns the matplotlib Figure; see :func:`daekit.plot.plot_invariants`.
        """
        from ..plot import plot_invariants

        return plot_invariants(self, axes=axes)

    def __repr__(self) -> str:
        span = f"t in [{self.t[0]:g}, {self.t[-1]:g}]" if self.t.size else "empty"
        return (
            f"Trajectory({count(self.t.size, 'point')}, {span}; {', '.join(self.names[:8])}"
            f"{', ...' if len(self.names) > 8 else ''}; "
            f"{count(len(self.invariant_names), 'invariant')})"
        )


def load_trajectory(path: str | os.PathLike) -> Trajectory:
    """Read a trajectory written by :meth:`Trajectory.save` (``.parquet`` or ``.npz``; the
    format is documented in :mod:`daekit.simulate.storage`).

    Returns the :class:`Trajectory`, equal to the one saved (the same arrays bit for bit,
    names, invariants, statistics and extra data such as events).
    """
    parts = read_trajectory(path)
    traj = Trajectory(parts["t"], parts["values"], parts["invariants"], parts["invariant_names"],
                      parts["stats"])
    for k, v in parts["extra"].items():
        setattr(traj, k, v)
    return traj
