"""Ensembles and parameter sweeps: many simulations of one system, locally or on a Dask cluster.

:func:`ensemble` runs ``initialize`` then ``simulate`` for every sample of a sweep or a Monte
Carlo study. A sample is a dict of daekit names: a parameter name sets that parameter, a
variable name (``"p[0]"``, ``"der(p)[1]"``) a fixed initial value. The system is reduced once
(when a Model is given) and shipped to the workers once, as CasADi's own serialization of its
expressions; every worker builds its integrator once and reuses it for all the samples it
runs (parameters are integrator inputs, not rebuilt). A sample that fails (inconsistent
initial values, an integrator failure) is recorded in :attr:`Ensemble.failures` and the sweep
goes on.

Where the samples run (``executor=``):

- ``None``: local worker processes (:class:`concurrent.futures.ProcessPoolExecutor`, one per
  core); the system is installed in every worker by its initializer. Where processes are
  forked (Linux), the workers write their trajectories' arrays into shared memory maps (one
  per chunk of samples) and only a few hundred bytes a trajectory travel as messages: the
  trajectories here read their arrays in place (views of their chunk's map, which lives as
  long as any of its trajectories).
- ``"serial"``: in this process, one after the other.
- a :class:`dask.distributed.Client`: the system is scattered to every worker once
  (``client.scatter(..., broadcast=True)``); chunks of samples are submitted as tasks.
- any :class:`concurrent.futures.Executor` (a thread pool, ``client.get_executor()``, an MPI
  pool, ...): chunks of samples are submitted with the serialized system; each worker process
  deserializes it once (a cache keyed by its digest).

Callables in the options (``reduce=lambda traj: ...``, inputs given as Python functions) are
shipped with ``cloudpickle`` where it is installed (it comes with Dask): functions of your
script travel by value, so workers that cannot import your script (a Dask cluster, spawned
processes) run them too. Without it they go by plain pickle, and a ``reduce`` that cannot be
pickled runs here on the returned trajectories.

Example: the period of a planar pendulum for three rod lengths, released at rest from 60
degrees (the exact period is :func:`daekit.examples.exact.pendulum_planar_period`):

>>> import numpy as np, daekit as dk
>>> r = dk.reduce_index(dk.examples.pendulum_planar())
>>> th = np.pi / 3
>>> samples = [{"L": L, "x": L * np.sin(th), "y": -L * np.cos(th)} for L in (0.5, 1.0, 2.0)]
>>> def half_period(traj):          # x changes sign at T/4 and 3T/4
...     x, t = traj["x"], traj.t
...     k = np.where(np.diff(np.sign(x)) != 0)[0][:2]
...     tc = t[k] - x[k] * (t[k + 1] - t[k]) / (x[k + 1] - x[k])
...     return {"period": 2 * (tc[1] - tc[0])}
>>> ens = dk.ensemble(r, np.linspace(0, 3.5, 3501), samples, executor="serial",
...                   fixed={"der(x)": 0.0}, reduce=half_period, rtol=1e-10, atol=1e-10)
>>> len(ens), ens.failures
(3, {})
>>> exact = [dk.examples.exact.pendulum_planar_period(th, L=s["L"]) for s in samples]
>>> bool(np.allclose([row["period"] for row in ens.summary()], exact, rtol=1e-4))
True
"""

from __future__ import annotations

import contextlib
import copyreg
import hashlib
import math
import multiprocessing
import os
import pickle
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Executor, as_completed
from typing import Any

import numpy as np

from .errors import DaekitError, ModelError
from .sampling import sample
from .threads import blas_threads, single_threaded_worker

__all__ = ["Ensemble", "ensemble", "ensemble_ocp", "sample"]

KEEP = ("trajectory", "summary")


# ----------------------------------------------------------------------------------------------
# samples
def _as_sample_list(samples) -> list[dict]:
    """A list of dicts from a list of dicts, a dict of equal-length arrays or a
    ``pandas.DataFrame`` (one sample per row; duck-typed, pandas is not imported here).

    Every key must be a name (a str) and every value a number or a flat list of numbers:
    checked here, before anything runs, so that a bad value is named by its sample and key
    instead of surfacing from NumPy after the sweep."""
    if hasattr(samples, "columns") and hasattr(samples, "to_dict") \
            and not isinstance(samples, Mapping):
        for c in samples.columns:
            _check_key(c, "a column of the DataFrame of samples")
        # a missing cell (NaN) is a name that row does not set: pd.DataFrame([{"L": 1.0},
        # {"g": 9.0}]) means what the list of those two dicts means
        samples = [{k: v for k, v in row.items()
                    if not (isinstance(v, (float, np.floating)) and math.isnan(v))}
                   for row in samples.to_dict(orient="records")]
    if isinstance(samples, Mapping):
        if not samples:
            raise ModelError("ensemble: samples is an empty dict; give e.g. {'L': [0.5, 1.0]}")
        lengths = {}
        cols = {}
        for k, v in samples.items():
            _check_key(k, "a key of the dict of samples")
            arr = _numbers(v, f"samples[{k!r}] is", max_ndim=2)
            if arr.ndim == 0:
                raise ModelError(
                    f"ensemble: samples[{k!r}] is a single number; a dict of samples maps each "
                    "name to one value per sample (an array), e.g. {'L': np.linspace(0.5, 2, 16)}"
                )
            lengths[k], cols[k] = arr.shape[0], arr
        if len(set(lengths.values())) != 1:
            raise ModelError(
                "ensemble: the arrays of a dict of samples must have equal lengths, got "
                + ", ".join(f"{k}: {n}" for k, n in lengths.items())
            )
        n = next(iter(lengths.values()))
        return [{k: _plain(cols[k][i]) for k in cols} for i in range(n)]
    if isinstance(samples, (str, bytes)) or not isinstance(samples, Iterable):
        raise ModelError(
            f"ensemble: samples must be a list of dicts, a dict of arrays or a DataFrame, got "
            f"{type(samples).__name__}"
        )
    out = []
    for i, s in enumerate(samples):
        if not isinstance(s, Mapping):
            raise ModelError(
                f"ensemble: sample {i} is a {type(s).__name__}, not a dict of names and values "
                "(e.g. {'L': 1.0, 'p[0]': 0.3})"
            )
        for k, v in s.items():
            _check_key(k, f"a key of sample {i}")
            _numbers(v, f"sample {i} sets {k!r} to", max_ndim=1)
        out.append(dict(s))
    return out


def _check_key(k, where: str) -> None:
    if not isinstance(k, str):
        raise ModelError(
            f"ensemble: {where} is {k!r} (of type {type(k).__name__}); the keys are daekit names "
            "(str), e.g. 'L', 'p[0]' or 'der(x)'"
        )


def _numbers(v, what: str, max_ndim: int) -> np.ndarray:
    """``v`` as a float array of at most ``max_ndim`` dimensions, else a ModelError saying
    ``what`` was given (strings are refused: ``"1.5"`` is text, not a number)."""
    try:
        raw = np.asarray(v)
        ok = raw.dtype.kind in "biuf" and raw.ndim <= max_ndim
    except (ValueError, TypeError):  # ragged nesting: NumPy refuses it
        ok = False
    if not ok:
        shape = ("a number or a flat list of numbers (a vector)" if max_ndim == 1 else
                 "one number (or one flat list of numbers) per sample")
        raise ModelError(f"ensemble: {what} {_short(v)}, which is not {shape}")
    out = raw.astype(float)
    if not np.isfinite(out).all():
        raise ModelError(f"ensemble: {what} {_short(v)}, which is not finite")
    return out


def _short(v) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def _plain(v):
    a = np.asarray(v, dtype=float)
    return float(a) if a.ndim == 0 else a.tolist()


def _names(name: str, keys) -> bool:
    """Whether ``name`` names elements among ``keys`` (:func:`daekit.model.expand_name`)."""
    from .model import NameNotFoundError, expand_name

    try:
        expand_name(name, keys)
    except NameNotFoundError:
        return False
    return True


def _split_keys(r, samples: list[dict], source: str = "sample") -> tuple[set[str], set[str]]:
    """(parameter keys, variable keys) used by the samples; unknown names and inputs raise
    ModelError. ``source`` says where the names come from in the messages: ``"sample"``
    (``"sample 3 sets 'x'"``) or e.g. ``"fixed"`` (``"fixed sets 'x'"``, for one dict)."""
    from .model import NameNotFoundError, expand_name

    pmap = dict.fromkeys(r.p_names, 0)
    umap = dict.fromkeys(r.u_names, 0)
    params, variables = set(), set()
    for i, s in enumerate(samples):
        who = f"sample {i}" if source == "sample" else source
        for k in s:
            if k in params or k in variables:
                continue
            _check_key(k, f"a key of {who}")
            if _names(k, pmap):
                params.add(k)
                continue
            if _names(k, umap):  # an input is a function of time, not an initial value
                raise ModelError(
                    f"ensemble: {who} sets {k!r}, an input of the model; give inputs with "
                    "inputs={...}"
                )
            try:
                expand_name(k, r.variables)
                variables.add(k)
            except NameNotFoundError:
                known = sorted(_vector_names(r.p_names))
                others = set(r.p_names) | set(r.u_names)
                names = _vector_names([n for n in r.variables if n not in others])
                shown = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")
                raise ModelError(
                    f"ensemble: {who} sets {k!r}, which is neither a parameter "
                    f"({', '.join(known) or 'none'}) nor a variable of the model "
                    f"({shown or 'none'})"
                ) from None
    return params, variables


def _vector_names(names) -> list[str]:
    out: list[str] = []
    for k in names:
        v = k.rsplit("[", 1)[0] if k.endswith("]") else k
        if v not in out:
            out.append(v)
    return out


# ----------------------------------------------------------------------------------------------
# the result
class Ensemble:
    """The results of :func:`ensemble`: one entry per sample, in the order of the samples.

    Attributes
    ----------
    samples : list of dict
        The samples as given (names and values).
    failures : dict of int to str
        ``{sample index: message}`` of the samples that could not be initialized or
        simulated: ``"sample 3 (L = 1, x = 1.5): "`` and the daekit error's message, which
        names the culprit.
    rows : list of dict
        One row per sample (see :meth:`summary`).
    t : numpy.ndarray
        The output times of the sweep (every trajectory has a row at each of them, up to a
        terminal event; events add rows, see :meth:`values`).
    stats : dict
        ``wall_time`` (s, the whole sweep), ``executor`` (what ran it), ``workers``,
        ``chunks`` (tasks), ``system_bytes`` and ``system_transfers`` (the size of the
        serialized system and how often it was sent), ``pipe_bytes`` (the results' bytes
        that came back as messages) and, with local processes, ``shared_bytes`` (the
        trajectories' arrays that came back through shared memory instead), ``notes`` (e.g.
        that the model was reduced automatically).

    ``len(ens)`` is the number of samples; ``ens[i]`` the :class:`~daekit.Trajectory` of sample
    ``i`` (None when it failed, also when only its ``reduce`` raised); iterating gives the
    trajectories in order. With ``keep="summary"`` the trajectories were not kept and indexing
    raises.
    """

    def __init__(self, samples, results, t, keep, stats, system=None) -> None:
        self.samples = samples
        self.t = np.asarray(t, dtype=float)
        self.keep = keep
        self.stats = stats
        self.system = system
        # a failed sample has no entry, whatever was computed before it failed (a trajectory
        # whose reduce raised, an OCP solution that did not converge): values() and plot()
        # then leave it out with the others
        self._traj = [None if res.get("error") else res.get("trajectory") for res in results]
        self.rows = [res["row"] for res in results]
        self.failures = {i: f"sample {i} ({_describe(samples[i])}): {res['error']}"
                         for i, res in enumerate(results) if res.get("error")}

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i: int):
        if self.keep == "summary":
            raise ModelError(
                "this ensemble was run with keep='summary': the trajectories were not kept; "
                "use ens.summary() / ens.to_pandas(), or run again with keep='trajectory'"
            )
        return self._traj[i]

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    @property
    def succeeded(self) -> list[int]:
        """Indices of the samples that succeeded."""
        return [i for i in range(len(self)) if i not in self.failures]

    def summary(self) -> list[dict]:
        """One dict per sample: the sample's values, ``success``, ``error`` (message or ""),
        ``max_invariant`` (max |invariant| over the trajectory and all invariants),
        ``max|NAME|`` per invariant, ``steps``, ``wall_time`` and ``cpu_time`` (s,
        initialize + simulate in the worker; the CPU time of the worker's process), and the
        columns returned by the user's ``reduce(traj)``."""
        return [dict(r) for r in self.rows]

    def to_pandas(self):
        """:meth:`summary` as a ``pandas.DataFrame`` indexed by sample number."""
        try:
            import pandas as pd
        except ImportError:
            raise ImportError(
                "Ensemble.to_pandas needs pandas: pip install pandas (or use ens.summary())"
            ) from None
        df = pd.DataFrame(self.summary())
        df.index.name = "sample"
        return df

    @staticmethod
    def summary_format(path: str | os.PathLike, where: str | None = None) -> str:
        """``"csv"`` or ``"parquet"``: the format :meth:`save_summary` writes to ``path`` (by
        its extension, in any case), checked before anything runs: a ModelError for another
        extension, a folder that does not exist (or cannot be written) and, for Parquet,
        pandas or pyarrow missing. The messages begin with ``where`` (default
        ``"save_summary: 'PATH'"``; the command line's is ``"--out PATH"``).

        >>> Ensemble.summary_format("sweep.CSV")
        'csv'
        """
        path = os.fspath(path)
        where = where or f"save_summary: {path!r}"
        ext = os.path.splitext(path)[1].lower()
        if ext not in (".csv", ".parquet"):
            raise ModelError(f"{where}: write a .csv or a .parquet file")
        folder = os.path.dirname(path) or "."
        if not os.path.isdir(folder):
            raise ModelError(f"{where}: the folder {folder!r} does not exist")
        if not os.access(folder, os.W_OK):
            raise ModelError(f"{where}: the folder {folder!r} cannot be written")
        if ext == ".parquet":
            try:
                import pandas  # noqa: F401
                import pyarrow  # noqa: F401
            except ImportError:
                raise ModelError(
                    f"{where}: Parquet needs pandas and pyarrow (pip install "
                    "pandas pyarrow); or write a .csv file"
                ) from None
        return ext[1:]

    def save_summary(self, path: str | os.PathLike) -> str:
        """Write :meth:`summary` to ``path``: ``.csv`` (no extra dependency) or ``.parquet``
        (pandas and pyarrow), the extension in any case (:meth:`summary_format`). Vector
        values are Parquet lists (null where a sample has none). Returns the path written."""
        path = os.fspath(path)
        fmt = self.summary_format(path)
        rows = self.summary()
        if fmt == "parquet":
            df = self.to_pandas()
            for c in df.columns:  # vector values: keep them as lists (Parquet list columns)
                if df[c].map(lambda v: isinstance(v, (list, tuple))).any():
                    df[c] = df[c].map(_parquet_list)
            df.to_parquet(path)
            return path
        import csv

        cols: list[str] = []
        for r in rows:
            cols += [k for k in r if k not in cols]
        with open(path, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["sample", *cols])
            for i, r in enumerate(rows):
                w.writerow([i, *[_csv_value(r.get(c, "")) for c in cols]])
        return path

    @property
    def grid(self) -> np.ndarray:
        """The times of :meth:`values`, :meth:`percentiles` and :meth:`plot`: :attr:`t` for
        :func:`ensemble`; for :func:`ensemble_ocp` the solutions' own grid when they all
        share one (else a ModelError: read them one at a time, ``ens[i].t``)."""
        return self._rows_on_grid()[0]

    def _rows_on_grid(self) -> tuple[np.ndarray, list]:
        """``(grid, rows)``: :attr:`grid` and, for every entry, its rows at those times
        (:func:`_rows_on`; None for a failed sample)."""
        entries = list(self)
        kept = [(i, tr) for i, tr in enumerate(entries) if tr is not None]
        if self.t.ndim == 1 and self.t.size >= 2 and bool(np.all(np.diff(self.t) > 0)):
            rows = [None if tr is None else _rows_on(_times_of(tr), self.t) for tr in entries]
            if all(rows[i] is not None for i, _ in kept):
                return self.t, rows
        elif not kept:
            return self.t, [None] * len(entries)
        grids = [_times_of(tr) for _, tr in kept]
        if all(g.shape == grids[0].shape and np.array_equal(g, grids[0]) for g in grids[1:]):
            every = np.arange(grids[0].size)
            return grids[0], [None if tr is None else every for tr in entries]
        shown = "; ".join(f"sample {i}: {g.size} times from {g[0]:g} to {g[-1]:g}"
                          for (i, _), g in list(zip(kept, grids, strict=True))[:3] if g.size)
        raise ModelError(
            f"ensemble: the entries do not share one time grid ({shown}, ...); read them one "
            "at a time: ens[i].t and ens[i][name]"
        )

    def values(self, name: str) -> np.ndarray:
        """``(samples, N)`` (or ``(samples, N, size)``) array of ``name`` at the times
        :attr:`grid` (the output times :attr:`t`); failed samples are NaN rows.

        A trajectory with events has more rows than the output times (two at every jump:
        before and after it); each is read at the output times, the value of its last row at
        or before each time (so a jump exactly at an output time gives the value after it),
        and is NaN at the output times after a terminal event stopped it."""
        return self._values_on_grid(name)[1]

    def _values_on_grid(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(grid, values)`` of :meth:`values`."""
        grid, rows = self._rows_on_grid()
        got = []
        for tr, idx in zip(self, rows, strict=True):
            if tr is None:
                got.append(None)
                continue
            v = np.asarray(tr[name], dtype=float)
            out = v[np.maximum(idx, 0)]
            out[idx < 0] = np.nan
            got.append(out)
        tail = next((g.shape[1:] for g in got if g is not None), None)
        if tail is None:
            raise ModelError(f"ensemble: no successful trajectory holds {name!r}")
        return grid, np.stack([g if g is not None else np.full((grid.size, *tail), np.nan)
                               for g in got])

    def percentiles(self, name: str, q: Sequence[float] = (5, 50, 95)) -> np.ndarray:
        """Percentiles ``q`` of ``name`` across the successful samples at every time of
        :attr:`grid`: an array ``(len(q), N[, size])``; NaN where no sample has a value (all
        stopped by a terminal event)."""
        return _nanpercentile(self.values(name), q)

    def plot(self, name: str, bands: Sequence[tuple[float, float]] = ((5, 95), (25, 75)),
             ax=None, faint: bool = True, color: str = "C0", max_lines: int = 400):
        """All trajectories of ``name`` faint, with percentile bands and the median, at the
        times :attr:`grid` (the samples still running at each time: see :meth:`values`).

        ``bands``: pairs of percentiles shaded (darker for inner ones). A vector name gives one
        panel per element: ``ax``, when given, is one Axes per element (a sequence for a
        vector). Returns the matplotlib Figure.
        """
        import matplotlib.pyplot as plt

        grid, V = self._values_on_grid(name)
        if V.ndim == 2:
            V = V[:, :, None]
        k = V.shape[2]
        if ax is None:
            fig, axes = plt.subplots(k, 1, figsize=(7.5, 2.6 * k + 0.6), sharex=True,
                                     squeeze=False)
            axes = axes[:, 0]
        else:
            axes = list(np.ravel(ax)) if isinstance(ax, (list, tuple, np.ndarray)) else [ax]
            if len(axes) != k:
                raise ModelError(
                    f"ensemble.plot: {name!r} has {k} element{'s' if k > 1 else ''}, one "
                    f"panel each: give ax= {'a sequence of ' + str(k) + ' axes' if k > 1 else 'one axes'} "
                    f"(got {len(axes)}), or no ax for a new figure"
                )
            fig = axes[0].figure
        ok = ~np.all(np.isnan(V), axis=(1, 2))  # failed samples are all NaN
        for j in range(k):
            a = axes[j]
            Vj = V[ok, :, j]
            if faint:
                for row in Vj[:max_lines]:
                    a.plot(grid, row, color="0.4", lw=0.5, alpha=min(0.6, 8.0 / max(len(Vj), 1)))
            for b, (lo, hi) in enumerate(sorted(bands, key=lambda p: p[1] - p[0], reverse=True)):
                plo, phi = _nanpercentile(Vj, [lo, hi])
                a.fill_between(grid, plo, phi, color=color, alpha=0.18 + 0.17 * b, lw=0,
                               label=f"{lo:g}-{hi:g} %")
            a.plot(grid, _nanpercentile(Vj, [50])[0], color=color, lw=1.6, label="median")
            label = name if k == 1 else f"{name}[{j}]"
            a.set_ylabel(label)
            a.grid(alpha=0.3)
        axes[0].legend(loc="upper right", fontsize=8, framealpha=0.8)
        axes[0].set_title(f"{name}: {int(ok.sum())} of {len(self)} samples"
                          + (f" ({len(self.failures)} failed)" if self.failures else ""))
        axes[-1].set_xlabel("t [s]")
        fig.tight_layout()
        return fig

    def __repr__(self) -> str:
        return (f"Ensemble({len(self)} samples, {len(self.failures)} failed, "
                f"{self.stats.get('executor', '?')}, {self.stats.get('wall_time', 0.0):.3g} s)")


def _describe(s: Mapping) -> str:
    def one(v):
        a = np.asarray(v, dtype=float).ravel()  # numbers: checked by _as_sample_list
        return f"{a[0]:g}" if a.size == 1 else "[" + ", ".join(f"{x:g}" for x in a) + "]"

    return ", ".join(f"{k} = {one(v)}" for k, v in s.items()) or "defaults"


def _times_of(entry) -> np.ndarray:
    """The time grid of an entry: a Trajectory's or an OCPSolution's ``t``."""
    return np.asarray(entry.t, dtype=float).ravel()


def _rows_on(tt: np.ndarray, grid: np.ndarray) -> np.ndarray | None:
    """For each time of ``grid``, the last row of ``tt`` at or before it (a jump's second row
    when it is at that time), -1 where ``grid`` is outside ``tt``'s span (after a terminal
    event); None when a grid time inside the span is not a row of ``tt`` (another grid).

    >>> _rows_on(np.array([0.0, 0.5, 0.7, 0.7, 1.0]), np.array([0.0, 0.5, 1.0]))
    array([0, 1, 4])
    >>> _rows_on(np.array([0.0, 0.5, 0.5]), np.array([0.0, 0.5, 1.0]))
    array([ 0,  2, -1])
    """
    if tt.shape == grid.shape and np.array_equal(tt, grid):
        return np.arange(grid.size)
    if tt.size == 0:
        return None
    idx = np.searchsorted(tt, grid, side="right") - 1
    inside = (grid >= tt[0]) & (grid <= tt[-1])
    if not np.array_equal(tt[idx[inside]], grid[inside]):
        return None
    idx[~inside] = -1
    return idx


def _nanpercentile(V: np.ndarray, q) -> np.ndarray:
    """Percentiles over the samples (axis 0), NaN where no sample has a value, silently
    (NumPy warns on an all-NaN column: times after every sample stopped)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanpercentile(V, q, axis=0)


def _parquet_list(v):
    """A cell of a Parquet list column: the vector, or null where there is none (a failed
    sample's NaN), never a list of one NaN."""
    if isinstance(v, (list, tuple)):
        return list(v)
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return None
    return [v]


def _csv_value(v):
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return " ".join(repr(float(x)) for x in v)
    return v


# ----------------------------------------------------------------------------------------------
# workers
_SYSTEMS: dict[str, Any] = {}  # digest -> (ReducedDAE, inputs), in each worker process
_LOCK = threading.RLock()


def _dumps(obj) -> bytes:
    """``obj`` as bytes for another process: by cloudpickle where it is installed (it comes
    with Dask), so that functions of the user's script (``__main__``), lambdas and local
    functions travel by value and a worker that is not a fork of this process (Dask, spawn)
    can run them; by plain pickle otherwise (raises when it cannot)."""
    try:
        import cloudpickle
    except ImportError:
        return pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    return cloudpickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)


def _has_cloudpickle() -> bool:
    try:
        import cloudpickle  # noqa: F401
    except ImportError:
        return False
    return True


def _shippable(obj) -> bool:
    """Whether :func:`_dumps` can serialize ``obj`` alone (to name an input that cannot)."""
    import casadi as ca

    try:
        with ca.global_pickle_context():
            _dumps(obj)
    except Exception:  # noqa: BLE001
        return False
    return True


def _pack_system(r, inputs) -> bytes:
    """The system and the inputs in one CasADi serialization: input expressions of ``r.t``
    (or of the model's ``m.t``) keep their symbols shared with the system. The system alone
    by plain pickle (nothing of the user's in it); with inputs by :func:`_dumps`."""
    import casadi as ca

    with ca.global_pickle_context():
        if inputs is None:
            return pickle.dumps((r, None), protocol=pickle.HIGHEST_PROTOCOL)
        return _dumps((r, inputs))


def _packed_alone(r) -> tuple[bytes, str]:
    """:func:`_pack_system` of ``r`` without inputs, and its digest (the workers' key)."""
    blob = _pack_system(r, None)
    return blob, hashlib.sha1(blob).hexdigest()


def _install(key: str, blob: bytes) -> None:
    """Worker initializer: one BLAS thread for the worker's life (see
    :func:`daekit.threads.single_threaded_worker`), then deserialize the system (and the
    inputs) once."""
    import casadi as ca

    single_threaded_worker()
    if key not in _SYSTEMS:
        if len(_SYSTEMS) >= 4:
            _SYSTEMS.pop(next(iter(_SYSTEMS)))
        with ca.global_unpickle_context():
            _SYSTEMS[key] = pickle.loads(blob)  # noqa: S301 - our own serialization


def _run_chunk(key: str, blob: bytes | None, payload: bytes):
    """Run a chunk of samples in a worker: ``[(index, result dict), ...]`` as
    :func:`_dump_results` bytes (with ``(bytes, spans)`` when the chunk's arrays went into the
    shared block of :class:`_SharedBlock`).

    CasADi's symbolic objects are not thread-safe (initialize builds SX expressions): chunks
    given to threads of one process (a thread pool, a Dask worker with several threads) run
    one after the other under a lock; processes run in parallel."""
    with _LOCK:
        if key not in _SYSTEMS:
            if blob is None:
                raise RuntimeError("daekit.ensemble: the system was not installed in this worker")
            _install(key, blob)
        r, inputs = _SYSTEMS[key]
        job = pickle.loads(payload)  # noqa: S301 - our own serialization
        job["inputs"] = inputs
        # one BLAS thread while the samples run (a no-op in daekit's own workers, which have
        # one already): the workers share the cores, and more threads only compete for them
        with blas_threads(1):
            # the trajectories are kept for the chunk's result anyway: their invariants and
            # rows after the chunk's samples, in one loop whose code and data stay in the cache
            # (measured on the 3D pendulum: 0.07-0.09 ms a sample instead of 0.17-0.23 ms
            # between samples); with keep="summary" sample by sample, holding none
            batch = job["keep"] == "trajectory"
            pairs = [(i, _run_one(r, s, job, finish=not batch)) for i, s in job["samples"]]
            if batch:
                for _, out in pairs:
                    _finish_one(out, job)
        region = job.get("shared")
        block = _BLOCKS.get(region[0]) if region else None
        if block is None:
            return _dump_results(pairs, r)
        return _dump_results(pairs, r, grid=job["t"],
                             writer=_BlockWriter(block, region[1], region[2]))


# ----------------------------------------------------------------------------------------------
# trajectories through shared memory (local forked workers)
_BLOCKS: dict[str, _SharedBlock] = {}  # token -> block, made before the workers are forked


class _SharedBlock:
    """One anonymous shared memory map for the arrays of a chunk's trajectories, made in this
    process before its workers are forked (they inherit the mapping). The worker that runs
    the chunk writes its trajectories' arrays there (pickle protocol 5's
    out-of-band buffers) and sends through the pipe only the rest (a few hundred bytes a
    trajectory). This process reads the arrays in place: the trajectories' arrays are views of
    the map, which lives as long as any of them does. Measured on the 3D pendulum (1001
    points): 72.1 KB a trajectory go this way and 0.5 KB as a message (129 KB through the
    pipe before); taking in 25 of them costs this process 0.5 ms (2.0 ms before).
    """

    def __init__(self, size: int) -> None:
        import mmap

        self.map = mmap.mmap(-1, max(int(size), 1))  # MAP_SHARED | MAP_ANONYMOUS
        self.view = memoryview(self.map)
        self.token = os.urandom(8).hex()
        self.used = 0  # bytes the workers wrote (as reported with their results)


def _sample_bytes(r, n: int) -> int:
    """Room for one trajectory's arrays of ``n`` rows in a shared block: the states ``x``,
    ``z``, the inputs, the invariants (one row of inputs when constant), the parameters,
    every buffer aligned to 64 bytes, and two grids' worth of slack (events add rows; what
    does not fit travels through the pipe as before)."""
    ninv = max(int(r.invariants.numel()), len(r.invariant_names))
    per_row = r.nx + r.nz + r.nu + ninv + 2
    return 8 * (n * per_row + 2 * (r.nu + int(r.p.numel()))) + 64 * 12


class _BlockWriter:
    """``buffer_callback`` of the worker's pickler: each buffer into the chunk's region of the
    shared block (aligned to 64 bytes), its place recorded in :attr:`spans`; a buffer that
    does not fit stays in the pickle stream (returns True)."""

    def __init__(self, block: _SharedBlock, start: int, end: int) -> None:
        self.view, self.pos, self.end = block.view, int(start), int(end)
        self.spans: list[tuple[int, int]] = []

    def __call__(self, buf: pickle.PickleBuffer) -> bool:
        raw = buf.raw()
        n = raw.nbytes
        off = (self.pos + 63) & ~63
        if off + n > self.end:
            return True
        self.view[off:off + n] = raw
        self.spans.append((off, n))
        self.pos = off + n
        return False


_RECEIVING = threading.local()  # .system, .grid: what the references resolve to while loading


def _received_system():
    return _RECEIVING.system


def _received_grid():
    if getattr(_RECEIVING, "grid", None) is None:
        raise pickle.UnpicklingError("daekit.ensemble: a grid reference without the grid")
    return _RECEIVING.grid.copy()  # each trajectory owns its times, as a serial run's do


class _SendPickler(pickle.Pickler):
    """Results of a worker: the system by reference (the receiver has it), the output grid by
    reference when given (every trajectory's times are the sweep's), trajectories as their
    state arrays and a recipe for the other columns
    (:func:`daekit.simulate.trajectory.compact_pickling`); arrays out of band through
    ``buffer_callback`` when given. The references go through a dispatch table of the two
    types concerned (looked up in C), not ``persistent_id`` (a Python call for every object:
    some 160 a trajectory)."""

    def __init__(self, file, system, grid=None, buffer_callback=None) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL, buffer_callback=buffer_callback)
        self.system = system
        self.grid = None
        if grid is not None:
            g = np.ascontiguousarray(grid, dtype=float)
            self.grid, self.grid_bits, self.grid_shape = g, g.view(np.int64), g.shape
        table = dict(copyreg.dispatch_table)
        table[type(system)] = self._reduce_system
        if self.grid is not None:
            table[np.ndarray] = self._reduce_array
        self.dispatch_table = table

    def _reduce_system(self, obj):
        if obj is self.system:
            return (_received_system, ())
        return obj.__reduce_ex__(pickle.HIGHEST_PROTOCOL)

    def _reduce_array(self, obj):
        if (obj.shape == self.grid_shape and obj.dtype == np.float64 and obj.flags.c_contiguous
                and (obj is self.grid or np.array_equal(obj.view(np.int64), self.grid_bits))):
            return (_received_grid, ())  # the same bits: the receiver's own grid
        return obj.__reduce_ex__(pickle.HIGHEST_PROTOCOL)


def _dump_results(pairs: list, system, grid=None, writer: _BlockWriter | None = None):
    """The chunk's results as bytes: measured on 25 3D-pendulum trajectories of 1001 points,
    2.5 MB instead of 5.0 MB, and no column computed in the worker (8-20 ms a chunk). With a
    ``writer`` the arrays go into the shared block instead: ``(bytes, spans)``, about 0.5 KB a
    trajectory through the pipe."""
    import io

    from .simulate.trajectory import compact_pickling

    buf = io.BytesIO()
    with compact_pickling():
        _SendPickler(buf, system, grid, writer).dump(pairs)
    if writer is None:
        return buf.getvalue()
    return buf.getvalue(), writer.spans


def _load_results(blob, system, grid=None, block: _SharedBlock | None = None) -> list:
    """The results of :func:`_dump_results`, their trajectories computing the other columns
    with ``system`` (this process's own) when first read; their arrays views of ``block``
    when they came through it."""
    import io

    buffers = None
    if isinstance(blob, tuple):
        blob, spans = blob
        if block is None:
            raise RuntimeError("daekit.ensemble: results in a shared block that is not here")
        buffers = [block.view[o:o + n] for o, n in spans]
        block.used += sum(n for _, n in spans)
    before = getattr(_RECEIVING, "system", None), getattr(_RECEIVING, "grid", None)
    _RECEIVING.system, _RECEIVING.grid = system, grid
    try:
        return pickle.Unpickler(io.BytesIO(blob), buffers=buffers).load()  # noqa: S301
    finally:
        _RECEIVING.system, _RECEIVING.grid = before


def _run_one(r, s: dict, job: dict, finish: bool = True) -> dict:
    """initialize + simulate one sample; errors are recorded, never raised. ``finish=False``
    leaves the row's invariants, steps and ``reduce`` columns to :func:`_finish_one`."""
    from .initialize import initialize
    from .simulate import simulate

    params = dict(job["params_base"])
    fixed = dict(job["fixed"] or {})
    elements = job["elements"]
    for k, v in s.items():
        if k in job["param_keys"]:
            params[k] = v
        else:  # over the shared fixed values, element by element ("p[0]" over "p")
            for e in elements.get(k, ()):
                fixed.pop(e, None)
            fixed[k] = v
    row: dict[str, Any] = dict(s)
    w0, c0 = time.perf_counter(), time.process_time()
    out: dict[str, Any] = {"row": row, "error": ""}
    try:
        init = initialize(r, t0=float(job["t"][0]), guess=job["guess"], fixed=fixed,
                          params=params or None, inputs=job["inputs"])
        traj = simulate(r, job["t"], init, params=params or None, inputs=job["inputs"],
                        progress=False, **job["options"])
    except Exception as exc:  # noqa: BLE001 - one failing sample must not stop the sweep
        what = "" if isinstance(exc, DaekitError) else f"{type(exc).__name__}: "
        out["error"] = what + str(exc)
        row.update(success=False, error=out["error"], max_invariant=math.nan, steps=0,
                   wall_time=time.perf_counter() - w0, cpu_time=time.process_time() - c0)
        return out
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    out["trajectory"], out["times"] = traj, (wall, cpu)
    if finish:
        _finish_one(out, job)
    return out


def _finish_one(out: dict, job: dict) -> None:
    """The row of a simulated sample (max |invariant|, steps, times, the ``reduce`` columns);
    the trajectory dropped unless kept."""
    if "times" not in out:  # failed: its row is complete
        return
    traj, row = out["trajectory"], out["row"]
    wall, cpu = out.pop("times")
    maxinv = traj.max_invariant()
    row.update(success=True, error="",
               max_invariant=max(maxinv.values()) if maxinv else 0.0)
    for k, v in maxinv.items():
        row[f"max|{k}|"] = v
    row.update(steps=int(traj.stats.get("steps", 0) or 0), wall_time=wall, cpu_time=cpu)
    red = job["reduce"]
    if red is not None:
        try:
            extra = red(traj)
            if not isinstance(extra, Mapping):
                raise TypeError(f"reduce must return a dict of columns, got {type(extra).__name__}")
            row.update({str(k): _plain_value(v) for k, v in extra.items()})
        except Exception as exc:  # noqa: BLE001 - recorded like a failure
            out["error"] = f"reduce(traj) raised {type(exc).__name__}: {exc}"
            row.update(success=False, error=out["error"])
    if job["keep"] != "trajectory":
        del out["trajectory"]


def _plain_value(v):
    if isinstance(v, (np.generic, np.ndarray)):
        a = np.asarray(v)
        return a.item() if a.ndim == 0 else a.tolist()
    return v


# ----------------------------------------------------------------------------------------------
# progress over samples (a terminal only)
class _SampleProgress:
    """The bar over samples: daekit's one progress bar (:class:`daekit.simulate.progress.
    Progress`, drawn only when stderr is a terminal) counting samples, with failures and the
    time left."""

    def __init__(self, enabled: bool, total: int, label: str = "ensemble") -> None:
        from .simulate.progress import Progress

        self.bar = Progress(enabled, 0.0, float(total), label)
        self.enabled = self.bar.enabled
        self.total = total
        self.t0 = time.perf_counter()

    def update(self, done: int, failed: int) -> None:
        if not self.enabled:
            return
        el = time.perf_counter() - self.t0
        frac = done / self.total
        left = f", about {el / frac - el:.0f} s left" if 0 < frac < 1 else ""
        self.bar.update(float(done), f"{done}/{self.total} samples"
                        f"{f', {failed} failed' if failed else ''}, {el:.1f} s{left}   ")

    def close(self) -> None:
        self.bar.close()


# ----------------------------------------------------------------------------------------------
# the sweep
def _is_dask_client(ex) -> bool:
    mod = type(ex).__module__ or ""
    return mod.startswith("distributed") and type(ex).__name__ == "Client"


def _workers_of(ex) -> int:
    if _is_dask_client(ex):
        try:
            info = ex.scheduler_info()["workers"]
            return max(1, sum(int(w.get("nthreads", 1)) for w in info.values()))
        except Exception:  # noqa: BLE001
            return os.cpu_count() or 1
    return int(getattr(ex, "_max_workers", 0) or os.cpu_count() or 1)


def _chunks(items: list, n_chunks: int) -> list[list]:
    n_chunks = max(1, min(n_chunks, len(items)))
    size = math.ceil(len(items) / n_chunks)
    return [items[k:k + size] for k in range(0, len(items), size)]


def _guided_chunks(items: list, workers: int) -> list[list]:
    """Chunks that shrink as the sweep goes (OpenMP's *guided* schedule): each takes the
    remaining samples over twice the workers, so the first ones are large (few transfers) and
    the last ones small (the workers finish together). Measured on 200 3D-pendulum samples
    with 2 workers, equal chunks of 25 left one worker idle 36-94 ms at the end.

    >>> [len(c) for c in _guided_chunks(list(range(20)), 2)]
    [5, 4, 3, 2, 2, 1, 1, 1, 1]
    """
    out, k, n = [], 0, len(items)
    while k < n:
        size = max(1, math.ceil((n - k) / (2 * max(1, workers))))
        out.append(items[k:k + size])
        k += size
    return out


def _make_chunks(indexed: list, chunksize: int | None, workers: int) -> list[list]:
    if chunksize:
        return _chunks(indexed, math.ceil(len(indexed) / chunksize))
    return _guided_chunks(indexed, workers)


def _shared_blocks_for(r, n_rows: int, chunks: list[list]) -> list:
    """One :class:`_SharedBlock` per chunk (room for its samples' arrays), registered for the
    workers about to be forked: a trajectory kept after the sweep holds its chunk's map, not
    the whole sweep's. None for a chunk whose map cannot be made (its arrays travel through
    the pipe)."""
    per = _sample_bytes(r, n_rows)
    blocks = []
    for c in chunks:
        try:
            block = _SharedBlock(per * len(c))
        except (OSError, ValueError, OverflowError):  # no room for the map: the pipe
            block = None
        else:
            _BLOCKS[block.token] = block
        blocks.append(block)
    return blocks


def ensemble(
    system,
    t,
    samples,
    *,
    executor: Executor | str | None = None,
    fixed: Mapping | None = None,
    guess: Mapping | None = None,
    progress: bool = True,
    keep: str = "trajectory",
    reduce: Callable | None = None,
    params: Mapping | None = None,
    inputs: Mapping | None = None,
    chunksize: int | None = None,
    **simulate_options,
) -> Ensemble:
    """Initialize and simulate ``system`` once per sample; failures are recorded, not raised.

    Parameters
    ----------
    system : ReducedDAE, Model or LagrangianSystem
        A Model (or LagrangianSystem) is reduced once here with the default method (noted in
        ``ens.stats["notes"]``); with ``stabilization="dummy_derivatives"`` by dummy
        derivatives.
    t : array
        Output times, shared by all samples.
    samples : list of dict, dict of equal-length arrays, or a pandas DataFrame (a row a sample)
        Keys are daekit names: a parameter (``"L"``) sets that parameter, a variable
        (``"p[0]"``, ``"der(p)"``) a fixed initial value, merged over ``fixed`` element by
        element (a sample's ``"p[0]"`` replaces that element of a shared ``fixed={"p": ...}``).
    executor : None, "serial", a concurrent.futures.Executor, or a dask.distributed.Client
        Where the samples run (see the module docstring). None: local processes, one per core.
    fixed, guess : dict, optional
        Fixed initial values and guesses shared by all samples (as for
        :func:`daekit.initialize`); their names, ``params``' names and the stabilization are
        checked once, before any sample runs.
    progress : bool
        A bar over samples on stderr, drawn only on a terminal.
    keep : "trajectory" or "summary"
        ``"summary"`` drops the trajectories in the workers (bounded memory): only
        :meth:`Ensemble.summary` rows come back.
    reduce : callable, optional
        ``reduce(traj) -> dict`` of extra summary columns, run in the worker.
    params, inputs : dict, optional
        Parameter values and inputs shared by all samples (as for :func:`daekit.simulate`).
    chunksize : int, optional
        Samples per task (default: chunks that shrink as the sweep goes, the first the
        samples over twice the workers, the last single samples).
    **simulate_options
        Passed to :func:`daekit.simulate` (``stabilization``, ``rtol``, ``atol``, ...).

    Returns
    -------
    Ensemble

    Example
    -------
    >>> import numpy as np, daekit as dk
    >>> r = dk.reduce_index(dk.examples.pendulum_planar())
    >>> ens = dk.ensemble(r, np.linspace(0, 1, 101), {"L": [1.0, 2.0], "x": [0.6, 3.0]},
    ...                   executor="serial", guess={"y": -1.0}, fixed={"der(x)": 0.0})
    >>> ens[0] is not None, ens[1] is None, sorted(ens.failures)
    (True, True, [1])
    >>> "rod" in ens.failures[1]
    True
    """
    from .reduced import ReducedDAE

    wall0 = time.perf_counter()
    if keep not in KEEP:
        raise ModelError(f"ensemble: keep must be 'trajectory' or 'summary', got {keep!r}")
    if reduce is not None and not callable(reduce):
        raise ModelError("ensemble: reduce must be a function traj -> dict of summary columns")
    notes: list[str] = []
    r = system
    if not isinstance(r, ReducedDAE):
        from .reduction import as_reduced

        r = as_reduced(system, "ensemble", stabilization=simulate_options.get("stabilization"),
                       method=simulate_options.get("method", "idas"), notes=notes)
    tg = np.array(t, dtype=float).ravel()  # a copy: the ensemble's, not the caller's array
    if tg.size < 2 or not np.all(np.isfinite(tg)) or np.any(np.diff(tg) <= 0):
        raise ModelError("ensemble: t must hold at least two finite, strictly increasing times")
    samp = _as_sample_list(samples)
    if not samp:
        raise ModelError("ensemble: no samples")
    for what, val in (("fixed", fixed), ("guess", guess), ("params", params)):
        if val is not None and not isinstance(val, Mapping):
            raise ModelError(f"ensemble: {what} must be a dict of names and values")
    _check_simulate_options(r, simulate_options)
    param_keys, var_keys = _split_keys(r, samp)
    if fixed:
        _split_keys(r, [dict(fixed)], source="fixed")
    fixed_values = _check_shared(r, fixed, guess, params)
    shared_fixed, elements = _fixed_under_samples(r, fixed_values, var_keys)
    job = {
        "t": tg, "fixed": shared_fixed, "guess": dict(guess) if guess else None,
        "params_base": dict(params or {}), "inputs": inputs, "options": simulate_options,
        "keep": keep, "reduce": reduce, "param_keys": param_keys, "elements": elements,
    }
    indexed = list(enumerate(samp))
    bar = _SampleProgress(progress, len(samp))
    results: list[dict | None] = [None] * len(samp)
    count = {"done": 0, "failed": 0}

    def take(pairs):
        for i, res in pairs:
            results[i] = res
            count["failed"] += bool(res.get("error"))
        count["done"] += len(pairs)
        bar.update(count["done"], count["failed"])

    stats: dict[str, Any] = {"notes": notes}
    local_reduce = None
    if isinstance(executor, str) and executor != "serial":
        raise ModelError(
            f"ensemble: executor={executor!r}; use None (local processes), 'serial', a "
            "concurrent.futures.Executor or a dask.distributed.Client"
        )
    if executor == "serial":
        stats.update(executor="serial", workers=1, chunks=len(samp))
        for i, s in indexed:
            take([(i, _run_one(r, s, job))])
        bar.close()
        ens = Ensemble(samp, results, tg, keep, stats, r)
        stats["wall_time"] = time.perf_counter() - wall0
        return ens
    try:
        if inputs:
            blob = _pack_system(r, inputs)
            key = hashlib.sha1(blob).hexdigest()
        else:  # the system alone: serialized once per system (22 ms for the 3D pendulum)
            blob, key = r.derived("ensemble-blob", _packed_alone)
    except Exception as exc:  # noqa: BLE001
        culprit = next((k for k, v in (inputs or {}).items() if not _shippable(v)), None)
        raise ModelError(
            "ensemble: the inputs cannot be sent to worker processes"
            + (f": input {culprit!r} cannot be pickled" if culprit else "")
            + f" ({type(exc).__name__}: {exc}); give them as CasADi expressions of time, "
            + ("" if _has_cloudpickle() else "install cloudpickle, ")
            + "or use executor='serial'"
        ) from None
    try:
        payload_job = dict(job, inputs=None)
        _dumps(payload_job)
    except Exception:  # noqa: BLE001 - reduce cannot be shipped: run it here
        if reduce is None:
            raise ModelError(
                "ensemble: the simulate options cannot be sent to worker processes; install "
                "cloudpickle, or use executor='serial'"
            ) from None
        local_reduce = reduce
        payload_job = dict(job, inputs=None, reduce=None, keep="trajectory")
        try:
            _dumps(payload_job)
        except Exception:  # noqa: BLE001
            raise ModelError(
                "ensemble: the options cannot be sent to worker processes; install "
                "cloudpickle, or use executor='serial'"
            ) from None
    stats["system_bytes"] = len(blob)
    # this process's BLAS threads come back last, after the ensemble is built (OpenBLAS
    # starts them again, a fork stopped them, and each spins some 100 ms), and on any error
    with contextlib.ExitStack() as single_blas:
        _run_elsewhere(r, executor, key, blob, inputs, indexed, chunksize, payload_job, tg,
                       stats, take, single_blas)
        if local_reduce is not None:
            for res in results:
                if res is not None and not res.get("error"):
                    _apply_reduce(res, local_reduce, keep)
        bar.close()
        ens = Ensemble(samp, results, tg, keep, stats, r)
        stats["wall_time"] = time.perf_counter() - wall0
    return ens


def _run_elsewhere(r, executor, key: str, blob: bytes, inputs, indexed: list, chunksize,
                   payload_job: dict, tg: np.ndarray, stats: dict, take,
                   single_blas: contextlib.ExitStack) -> None:
    """Run the chunks on ``executor`` (None: local processes), handing each chunk's results
    to ``take``; ``single_blas`` gets this process's one-BLAS-thread limit while local workers
    run (the caller closes it last, after the ensemble is built)."""
    own = inherited = None
    blocks: list = []
    ex = executor
    try:
        if ex is None:
            from concurrent.futures import ProcessPoolExecutor

            n_workers = max(1, min(_cpu_count(), len(indexed)))
            chunks = _make_chunks(indexed, chunksize, n_workers)
            ctx = multiprocessing.get_context()
            if ctx.get_start_method() == "fork" and key not in _SYSTEMS:
                # forked workers inherit the system as it is here, with whatever it has built
                # already (initialize's and simulate's functions): no unpickling, no warm-up;
                # the blob stays the fallback (a worker started otherwise unpickles it)
                _SYSTEMS[key] = (r, inputs)
                inherited = key
            # this process keeps one BLAS thread while its workers run: the forked workers
            # inherit that (no OpenBLAS thread is started, and none spins, in them), and this
            # process does not start its own threads again meanwhile (a started OpenBLAS thread
            # spins some 50-100 ms, taking a core from the workers)
            single_blas.enter_context(blas_threads(1))
            own = ex = ProcessPoolExecutor(n_workers, mp_context=ctx, initializer=_install,
                                           initargs=(key, blob))
            if ctx.get_start_method() == "fork" and payload_job["keep"] == "trajectory":
                # the trajectories' arrays come back through memory the workers inherit (they
                # are forked at the first submit, below)
                blocks = _shared_blocks_for(r, tg.size, chunks)
            stats.update(executor="processes", workers=n_workers)
        elif _is_dask_client(ex):
            stats.update(executor=f"dask ({getattr(ex.scheduler, 'address', '?')})",
                         workers=_workers_of(ex))
        elif isinstance(ex, Executor):
            stats.update(executor=type(ex).__name__, workers=_workers_of(ex))
        else:
            raise ModelError(
                f"ensemble: executor must be None, 'serial', a concurrent.futures.Executor or a "
                f"dask.distributed.Client, got {type(executor).__name__}"
            )
        if own is None:
            chunks = _make_chunks(indexed, chunksize, stats["workers"])
        stats["chunks"] = len(chunks)
        # how many times the serialized system travels: once per worker process (initializer
        # or scatter); with a foreign executor once per chunk (deserialized once per process)
        stats["system_transfers"] = (stats["workers"] if own is not None or _is_dask_client(ex)
                                     else len(chunks))
        block_of: dict = {}  # future -> its chunk's shared block
        if _is_dask_client(ex):
            from distributed import as_completed as dask_completed

            blob_f = ex.scatter(blob, broadcast=True, hash=False)
            futs = [ex.submit(_run_chunk, key, blob_f, _dumps(dict(payload_job, samples=c)),
                              pure=False) for c in chunks]
            done_iter = dask_completed(futs)
        else:
            ship = None if own is not None else blob
            futs = []
            for k, c in enumerate(chunks):
                blk = blocks[k] if blocks else None
                region = (blk.token, 0, len(blk.map)) if blk is not None else None
                f = ex.submit(_run_chunk, key, ship, _dumps(dict(payload_job, samples=c,
                                                                 shared=region)))
                block_of[f] = blk
                futs.append(f)
            done_iter = as_completed(futs)
        for f in done_iter:
            got = f.result()
            stats["pipe_bytes"] = stats.get("pipe_bytes", 0) + len(
                got[0] if isinstance(got, tuple) else got)
            take(_load_results(got, r, tg, block_of.get(f)))
    finally:
        if inherited is not None:
            _SYSTEMS.pop(inherited, None)  # the workers have their copies
        if blocks:
            for blk in blocks:
                if blk is not None:
                    _BLOCKS.pop(blk.token, None)  # the trajectories keep the maps alive
            stats.update(shared_bytes=sum(blk.used for blk in blocks if blk is not None))
        if own is not None:
            own.shutdown(wait=True)


def _check_simulate_options(r, opts: Mapping) -> None:
    """The options every sample shares, checked once here (not failing every sample)."""
    from .inputs import InputError
    from .simulate.dispatch import check_stabilization

    try:
        check_stabilization(r, opts.get("stabilization"))
    except InputError as exc:
        raise ModelError("ensemble: " + str(exc).removeprefix("simulate: ")) from None
    if opts.get("method", "idas") not in ("idas", "rattle"):
        raise ModelError(f"ensemble: unknown method {opts['method']!r}; use 'idas' or 'rattle'")
    if opts.get("method", "idas") == "idas":
        import inspect

        from .simulate.dispatch import simulate
        from .simulate.system import check_idas_options

        own = set(inspect.signature(simulate).parameters)
        check_idas_options({k: v for k, v in opts.items() if k not in own})
    for name in ("rtol", "atol"):
        v = opts.get(name, 1e-8)
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and v > 0):
            raise ModelError(f"ensemble: {name} must be a positive number, got {v!r}")


def _check_shared(r, fixed: Mapping | None, guess: Mapping | None,
                  params: Mapping | None) -> dict[str, tuple[list[str], np.ndarray]]:
    """The initial values, guesses and parameters every sample shares, checked once here (a
    mistake there would fail every sample with the same message): names (a parameter in
    ``fixed`` or ``guess`` is refused), values (initialize's own rule,
    :func:`daekit.initialize.checked_values`), an element fixed twice. Returns
    ``{key of fixed: (element names, values)}``."""
    from .initialize import InitializationError, checked_values
    from .inputs import InputError, resolve_params
    from .model import NameNotFoundError, expand_name

    pmap = dict.fromkeys(r.p_names, 0)
    fixed_values: dict[str, tuple[list[str], np.ndarray]] = {}
    by_quantity: dict = {}  # quantity -> the key of fixed that sets it
    for what, given in (("fixed", fixed), ("guess", guess)):
        for k, v in (given or {}).items():
            _check_key(k, f"a key of {what}")
            if _names(k, pmap):  # a parameter first, as for the samples' names (_split_keys)
                raise ModelError(
                    f"ensemble: {what} sets {k!r}, a parameter of the model; give parameter "
                    "values with params={...} (shared) or in the samples"
                )
            try:
                els = expand_name(k, r.variables, "the model's variables")
            except NameNotFoundError as exc:
                raise ModelError(f"ensemble: {what}: {exc}") from None
            try:  # its messages name `what` themselves
                vals = checked_values(len(els), els, k, v, what)
            except InitializationError as exc:
                raise ModelError(f"ensemble: {exc}") from None
            if what != "fixed":
                continue
            fixed_values[k] = (els, vals)
            for e in els:
                q = _quantity(r, e)
                if q in by_quantity:
                    raise ModelError(
                        f"ensemble: fixed sets {e!r} twice (by {by_quantity[q]!r} and {k!r}); "
                        "give each value once"
                    )
                by_quantity[q] = k
    try:
        resolve_params(r, params)
    except InputError as exc:
        raise ModelError(f"ensemble: {exc}") from None
    return fixed_values


def _quantity(r, element: str):
    """What an element name stands for: its symbol (``der(p)[1]`` and ``v[1]`` are one
    quantity where ``v = der(p)``), else the name."""
    sym = r.variables.get(element)
    if hasattr(sym, "is_symbolic") and sym.numel() == 1 and sym.is_symbolic():
        return sym.element_hash()
    return element


def _fixed_under_samples(r, fixed_values: Mapping, var_keys) -> tuple[dict, dict]:
    """``(fixed values, replaced)``: the shared fixed values (``fixed_values`` from
    :func:`_check_shared`), those that a sample's variable names overlap split into their
    elements, and for every variable name the samples set the shared elements it replaces,
    by quantity (a sample's ``"p[0]"`` replaces that element of a shared ``"p"``, a sample's
    ``"p"`` a shared ``"p[0]"``, a sample's ``"der(p)[1]"`` a shared ``"v[1]"`` where
    ``v = der(p)``)."""
    from .model import expand_name

    quantities = {k: {_quantity(r, e) for e in expand_name(k, r.variables)} for k in var_keys}
    covered = set().union(*quantities.values()) if quantities else set()
    out: dict = {}
    owner: dict = {}  # quantity -> the shared element name that sets it
    for k, (els, vals) in fixed_values.items():
        qs = [_quantity(r, e) for e in els]
        if covered.isdisjoint(qs):
            out[k] = vals.tolist() if len(els) > 1 else float(vals[0])
            continue
        for e, q, x in zip(els, qs, vals.tolist(), strict=True):
            out[e] = x
            owner[q] = e
    replaced = {k: [owner[q] for q in qs if q in owner] for k, qs in quantities.items()}
    return out, replaced


def _apply_reduce(res: dict, reduce: Callable, keep: str) -> None:
    traj = res.get("trajectory")
    try:
        extra = reduce(traj)
        res["row"].update({str(k): _plain_value(v) for k, v in dict(extra).items()})
    except Exception as exc:  # noqa: BLE001
        res["error"] = f"reduce(traj) raised {type(exc).__name__}: {exc}"
        res["row"].update(success=False, error=res["error"])
    if keep == "summary":
        res.pop("trajectory", None)


def _cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


# ----------------------------------------------------------------------------------------------
# optimal control
def ensemble_ocp(
    problem,
    samples,
    *,
    warm_start: bool = True,
    progress: bool = True,
    reduce: Callable | None = None,
    keep: str = "solution",
    **solve_options,
) -> Ensemble:
    """Solve a family of optimal control problems, each warm-started from its nearest solved
    neighbour.

    Parameters
    ----------
    problem : daekit.OCP or callable
        An OCP whose parameters the samples set (``ocp.set_parameters(sample)``), or a
        factory ``problem(**sample) -> OCP`` for anything else (targets, horizons, bounds).
    samples : list of dict or dict of arrays
        As for :func:`ensemble`.
    warm_start : bool
        Solve the samples along a nearest-neighbour path (in the sample values scaled to
        their ranges) and start each solve from the solution of the nearest sample already
        solved (``ocp.solve(guess=that_solution)``); ``False`` solves each from the default
        guess. Solves run in this process, one after the other.
    reduce : callable, optional
        ``reduce(solution) -> dict`` of extra summary columns.
    keep : "solution" or "summary"
        Keep the :class:`~daekit.OCPSolution` objects (``ens[i]``) or only the summary rows.
    **solve_options
        Passed to ``ocp.solve`` (``redundancy=``, ``check=``).

    Returns
    -------
    Ensemble
        ``ens[i]`` the OCPSolution of sample ``i`` (None when it failed); summary rows with
        ``success``, ``objective``, ``iterations``, ``warm_from`` (the sample it started
        from, -1 for none), ``wall_time`` and the ``reduce`` columns. A solve that does not
        succeed is listed in ``failures`` with its status.

    Example
    -------
    >>> import daekit as dk
    >>> m = dk.Model("cart"); s = m.state("s"); u = m.control("u")
    >>> _ = m.equation(m.der(s, 2) - u, name="newton")
    >>> def problem(target):
    ...     ocp = dk.OCP(m, t_final=1.0, intervals=10, controls="polynomial")
    ...     ocp.minimize(integral=u**2)
    ...     return ocp.initial({"s": 0, "der(s)": 0}).final({"s": target, "der(s)": 0})
    >>> ens = dk.ensemble_ocp(problem, {"target": [1.0, 2.0, 1.5]})
    >>> [round(row["objective"], 6) for row in ens.summary()]   # 12 target^2
    [12.0, 48.0, 27.0]
    >>> [row["warm_from"] for row in ens.summary()]
    [-1, 2, 0]
    """
    wall0 = time.perf_counter()
    if keep not in ("solution", "summary"):
        raise ModelError(f"ensemble_ocp: keep must be 'solution' or 'summary', got {keep!r}")
    samp = _as_sample_list(samples)
    if not samp:
        raise ModelError("ensemble_ocp: no samples")
    is_factory = callable(problem) and not hasattr(problem, "solve")
    if not is_factory and not hasattr(problem, "set_parameters"):
        raise ModelError("ensemble_ocp: problem must be a daekit.OCP or a factory "
                         "problem(**sample) -> OCP")
    keys = sorted({k for s in samp for k in s})
    X = np.array([[_scalar(s.get(k, np.nan)) for k in keys] for s in samp], dtype=float)
    span = np.nanmax(X, axis=0) - np.nanmin(X, axis=0) if X.size else np.zeros(0)
    Xs = np.nan_to_num((X - np.nanmin(X, axis=0)) / np.where(span > 0, span, 1.0))
    order = _nearest_path(Xs) if warm_start else list(range(len(samp)))
    results: list[dict | None] = [None] * len(samp)
    bar = _SampleProgress(progress, len(samp), "ocp sweep")
    # every sample starts from the OCP's own parameter values (a sample setting M must not
    # leave M set for the next sample, nor for the caller: restored at the end)
    base = {} if is_factory else problem.parameter_values()
    try:
        _solve_ocp_samples(problem, samp, order, Xs, is_factory, base, warm_start, reduce,
                           solve_options, results, bar)
    finally:
        if base:
            problem.set_parameters(base)
    bar.close()
    for res in results:
        sol = res.pop("solution_", None)
        if keep == "solution":
            res["trajectory"] = sol
    stats = {"executor": "serial", "workers": 1, "chunks": len(samp), "notes": [],
             "warm_start": warm_start, "order": order, "wall_time": time.perf_counter() - wall0}
    return Ensemble(samp, results, np.zeros(2), "trajectory" if keep == "solution" else "summary",
                    stats)


def _solve_ocp_samples(problem, samp: list[dict], order: list[int], Xs: np.ndarray,
                       is_factory: bool, base: dict, warm_start: bool, reduce, solve_options,
                       results: list, bar) -> None:
    """The solves of :func:`ensemble_ocp` in ``order``, each result into ``results``."""
    solved: list[int] = []
    failed = 0
    for done, i in enumerate(order, 1):
        s = samp[i]
        row: dict[str, Any] = dict(s)
        w0 = time.perf_counter()
        src = -1
        if warm_start and solved:
            d = np.linalg.norm(Xs[solved] - Xs[i], axis=1)
            src = solved[int(np.argmin(d))]
        res: dict[str, Any] = {"row": row, "error": ""}
        try:
            ocp = problem(**s) if is_factory else problem.set_parameters({**base, **s})
            guess = results[src].get("solution_") if src >= 0 else None
            sol = ocp.solve(guess=guess, **solve_options)
            ok = bool(sol.success)
            status = str(getattr(sol, "status", "") or sol.stats.get("return_status", "?"))
            row.update(success=ok, error="" if ok else f"solver status {status}",
                       objective=float(sol.objective), status=status,
                       iterations=int(sol.stats.get("iter_count", 0) or 0))
            if not ok:
                res["error"] = row["error"] + (": " + sol.report if getattr(sol, "report", "") else "")
            if reduce is not None:
                row.update({str(k): _plain_value(v) for k, v in dict(reduce(sol)).items()})
            res["solution_"] = sol
            if ok:
                solved.append(i)
        except Exception as exc:  # noqa: BLE001 - recorded, the sweep goes on
            what = "" if isinstance(exc, DaekitError) else f"{type(exc).__name__}: "
            res["error"] = what + str(exc)
            row.update(success=False, error=res["error"], objective=math.nan, iterations=0)
        row.update(warm_from=src, wall_time=time.perf_counter() - w0)
        results[i] = res
        failed += bool(res["error"])
        bar.update(done, failed)


def _scalar(v) -> float:
    a = np.asarray(v, dtype=float).ravel()
    return float(a[0]) if a.size == 1 else float(np.linalg.norm(a))


def _nearest_path(X: np.ndarray) -> list[int]:
    """A greedy path through the points: start at the first sample, then repeatedly the
    nearest unvisited point to any visited one (Prim's order), so each solve has a close
    solved neighbour."""
    n = X.shape[0]
    if n == 0:
        return []
    visited = [0]
    best = np.linalg.norm(X - X[0], axis=1) if X.shape[1] else np.zeros(n)
    best[0] = np.inf
    left = set(range(1, n))
    while left:
        j = min(left, key=lambda k: (best[k], k))
        visited.append(j)
        left.discard(j)
        if X.shape[1]:
            best = np.minimum(best, np.linalg.norm(X - X[j], axis=1))
        best[visited] = np.inf
    return visited
