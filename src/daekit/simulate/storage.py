"""Saving and loading trajectories: ``traj.save(path)`` and ``dk.load_trajectory(path)``.

Two formats, both lossless (every float64 bit, the names in order, the invariants, the
statistics and any other data the trajectory carries, such as its events):

``.parquet`` (needs ``pyarrow``; ``pip install "daekit[parquet]"``)
    One row per time point. Columns: ``t``, then one float64 column per element name of the
    trajectory (``"p[0]"``, ``"der(p)[0]"``, ``"z"``) in the trajectory's order, then one
    column ``"invariant:NAME"`` per invariant. The file's key-value metadata ``daekit`` holds a
    JSON object ``{"format": "daekit-trajectory", "version": 1, "value_names": [...],
    "invariant_names": [...], "stats": {...}, "extra": {...}}``. Any Parquet reader (pandas,
    polars, Spark, DuckDB) reads the table; ``pandas.read_parquet(path)`` gives the same frame
    as ``traj.to_pandas()`` with ``t`` as a column.
``.npz`` (NumPy only)
    Arrays ``t``, ``values`` (N x number of names, columns in ``value_names`` order) and
    ``invariants`` (N x number of invariants), and ``meta``: the same JSON text as above.

In the JSON, NumPy arrays are stored as ``{"__ndarray__": [...], "dtype": ..., "shape": ...}``
and tuples as ``{"__tuple__": [...]}``, so that they come back as they were. Floats are
written with Python's shortest round-trip representation (``repr``), so nothing is rounded.

Example
-------
>>> import numpy as np, tempfile, os
>>> from daekit.simulate import Trajectory, load_trajectory
>>> t = np.linspace(0, 1, 4)
>>> tr = Trajectory(t, {"x": np.sin(t), "z": np.exp(t)}, np.c_[1e-17 * t], ["rod"], {"steps": 7})
>>> path = os.path.join(tempfile.mkdtemp(), "run.npz")
>>> tr.save(path) == path
True
>>> back = load_trajectory(path)
>>> bool(np.array_equal(back["z"], tr["z"])), back.invariant_names, back.stats["steps"]
(True, ['rod'], 7)
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from ..errors import ModelError

__all__ = ["save_trajectory", "read_trajectory"]

FORMAT = "daekit-trajectory"
VERSION = 1
_CORE = ("t", "values", "invariants", "invariant_names", "stats")


def _encode(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return {"__ndarray__": _encode(obj.tolist()), "dtype": str(obj.dtype),
                "shape": list(obj.shape)}
    if isinstance(obj, np.generic):
        return _encode(obj.item())
    if isinstance(obj, tuple):
        return {"__tuple__": [_encode(v) for v in obj]}
    if isinstance(obj, list):
        return [_encode(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): _encode(v) for k, v in obj.items()}
    if isinstance(obj, float):
        if obj != obj or obj in (float("inf"), float("-inf")):
            return {"__float__": repr(obj)}
        return obj
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    return {"__repr__": repr(obj)}  # not representable: kept as text


def _decode(obj: Any) -> Any:
    if isinstance(obj, list):
        return [_decode(v) for v in obj]
    if isinstance(obj, dict):
        if "__ndarray__" in obj:
            return np.array(_decode(obj["__ndarray__"]), dtype=obj["dtype"]).reshape(obj["shape"])
        if "__tuple__" in obj:
            return tuple(_decode(v) for v in obj["__tuple__"])
        if "__float__" in obj:
            return float(obj["__float__"])
        if "__repr__" in obj and len(obj) == 1:
            return obj["__repr__"]
        return {k: _decode(v) for k, v in obj.items()}
    return obj


def _meta(traj) -> dict:
    extra = {k: v for k, v in vars(traj).items() if k not in _CORE and not k.startswith("_")}
    return {
        "format": FORMAT, "version": VERSION,
        "value_names": list(traj.values),
        "invariant_names": list(traj.invariant_names),
        "stats": _encode(dict(traj.stats)),
        "extra": _encode(extra),
    }


def save_trajectory(traj, path: str | os.PathLike) -> str:
    """Write ``traj`` to ``path`` (``.parquet`` or ``.npz``, see the module docstring);
    returns the path written."""
    path = os.fspath(path)
    meta = json.dumps(_meta(traj), allow_nan=False)
    names = list(traj.values)
    if path.endswith(".npz"):
        V = (np.column_stack([traj.values[k] for k in names]) if names
             else np.zeros((traj.t.size, 0)))
        np.savez(path, t=traj.t, values=V, invariants=np.asarray(traj.invariants, float),
                 meta=np.array(meta))
        return path
    if path.endswith(".parquet"):
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise ImportError('saving to Parquet needs pyarrow: pip install "daekit[parquet]" '
                              "(or save to a .npz file, NumPy only)") from None
        cols = {"t": traj.t}
        for k in names:
            cols[k] = traj.values[k]
        for j, n in enumerate(traj.invariant_names):
            cols[f"invariant:{n}"] = traj.invariants[:, j]
        if len(cols) != 1 + len(names) + len(traj.invariant_names):
            raise ModelError("save: two columns would have the same name (an element called "
                             "'t' or 'invariant:...'); save to .npz instead")
        table = pa.table({k: pa.array(np.asarray(v, float)) for k, v in cols.items()})
        table = table.replace_schema_metadata({b"daekit": meta.encode()})
        pq.write_table(table, path)
        return path
    raise ModelError(f"save: {path!r}: use a .parquet (pyarrow) or a .npz (NumPy) file name")


def read_trajectory(path: str | os.PathLike) -> dict[str, Any]:
    """The parts of a trajectory file written by :func:`save_trajectory`: a dict with ``t``,
    ``values`` (name -> array), ``invariants``, ``invariant_names``, ``stats`` and ``extra``
    (:func:`daekit.load_trajectory` makes the :class:`~daekit.Trajectory` of them)."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ModelError(f"load_trajectory: no such file: {path}")
    if path.endswith(".npz"):
        try:
            with np.load(path, allow_pickle=False) as f:
                meta = json.loads(str(f["meta"]))
                _check(meta, path)
                t = f["t"]
                V = f["values"]
                inv = f["invariants"]
        except (ValueError, KeyError, OSError, json.JSONDecodeError) as exc:
            if isinstance(exc, ModelError):
                raise
            raise ModelError(f"load_trajectory: {path} is not a daekit trajectory file "
                             f"(.npz with t, values, invariants and meta): {exc}") from None
        values = {k: V[:, j] for j, k in enumerate(meta["value_names"])}
    elif path.endswith(".parquet"):
        try:
            import pyarrow.parquet as pq
        except ImportError:
            raise ImportError('reading Parquet needs pyarrow: pip install "daekit[parquet]"') \
                from None
        table = pq.read_table(path)
        raw = (table.schema.metadata or {}).get(b"daekit")
        if raw is None:
            raise ModelError(f"load_trajectory: {path} is a Parquet file but not a daekit "
                             "trajectory (no 'daekit' metadata)")
        meta = json.loads(raw.decode())
        _check(meta, path)
        t = table.column("t").to_numpy()
        values = {k: table.column(k).to_numpy() for k in meta["value_names"]}
        names = meta["invariant_names"]
        inv = (np.column_stack([table.column(f"invariant:{n}").to_numpy() for n in names])
               if names else np.zeros((t.size, 0)))
    else:
        raise ModelError(f"load_trajectory: {path!r}: a .parquet or .npz file is needed")
    return {"t": t, "values": values, "invariants": inv,
            "invariant_names": meta["invariant_names"], "stats": _decode(meta["stats"]),
            "extra": _decode(meta.get("extra", {}))}


def _check(meta: dict, path: str) -> None:
    if meta.get("format") != FORMAT:
        raise ModelError(f"load_trajectory: {path} is not a daekit trajectory")
    if int(meta.get("version", 0)) > VERSION:
        raise ModelError(f"load_trajectory: {path} was written by a newer daekit (format "
                         f"version {meta['version']}); upgrade daekit")
