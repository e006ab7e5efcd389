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

from collections.abc import Iterable, Mapping

import numpy as np

from ..errors import ModelError
from ..model import NameNotFoundError, expand_name
from ..wording import count

__all__ = ["Trajectory", "NameNotFoundError", "expand_name"]


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

    Attributes
    ----------
    t, invariants, invariant_names, stats : as given.
    names : list of str
        Vector names available (``"p"``, ``"der(p)"``, ``"z"``, ...).

    ``traj["p"]`` returns ``(N, size)`` for a vector, ``(N,)`` for a scalar or an element.
    """

    def __init__(
        self,
        t,
        values: Mapping[str, np.ndarray],
        invariants=None,
        invariant_names: Iterable[str] | None = None,
        stats: dict | None = None,
    ) -> None:
        self.t = np.asarray(t, dtype=float).ravel()
        n = self.t.size
        self.values: dict[str, np.ndarray] = {}
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
        inv = np.asarray(invariants, dtype=float).reshape(n, -1) if n else np.zeros((0, 0))
        self.invariants = inv
        self.stats = dict(stats or {})

    # ------------------------------------------------------------------ access
    def __getitem__(self, name: str) -> np.ndarray:
        if name == "t":
            return self.t
        elems = expand_name(name, self.values, "this trajectory")
        if len(elems) == 1 and (elems[0] == name or "[" in name or not elems[0].endswith("]")):
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
        """Values at the grid point nearest ``time`` (by element name)."""
        k = int(np.argmin(np.abs(self.t - time)))
        return {n: float(v[k]) for n, v in self.values.items()}

    def slice(self, stop: int) -> Trajectory:
        """The first ``stop`` time points."""
        return Trajectory(
            self.t[:stop],
            {k: v[:stop] for k, v in self.values.items()},
            self.invariants[:stop],
            self.invariant_names,
            self.stats,
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
        from .storage import save_trajectory

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
