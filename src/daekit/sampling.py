"""Reproducible Monte Carlo samples for :func:`daekit.ensemble`: ``dk.sample(spec, n, seed)``.

Each name draws uniform numbers from its own stream (seeded by the seed and the name) and maps
them through the inverse CDF of its distribution (SciPy's ``ppf``); ``method="lhs"`` stratifies
the uniform numbers as a Latin hypercube (``scipy.stats.qmc``).
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from .errors import ModelError
from .wording import count

__all__ = ["sample"]

_DISTRIBUTIONS = {
    "uniform": 2, "normal": 2, "lognormal": 2, "truncnormal": 4, "triangular": 3,
    "loguniform": 2, "choice": 1, "constant": 1,
}


def _finite(name: str, a, dist) -> float:
    """``a`` as a finite float, else a ModelError naming the entry."""
    try:
        v = float(a)
        ok = not isinstance(a, (bool, str, bytes)) and np.isfinite(v)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ModelError(f"sample: {name!r}: {dist!r}: {a!r} is not a finite number")
    return v


def _choices(name: str, dist) -> list[float]:
    """The values of ``("choice", [values])``: a non-empty flat list of finite numbers."""
    vals = dist[1]
    if isinstance(vals, (str, bytes, Mapping)) or not hasattr(vals, "__len__"):
        raise ModelError(f"sample: {name!r}: {dist!r}: choice takes a list of values, e.g. "
                         "('choice', [0.5, 1.0, 2.0])")
    if len(vals) == 0:
        raise ModelError(f"sample: {name!r}: choice needs at least one value")
    return [_finite(name, v, dist) for v in vals]


def _check_shape(name: str, kind: str, nums: tuple, dist) -> None:
    """The parameters of a distribution are in range (SciPy would return NaN otherwise)."""
    if kind in ("uniform", "loguniform") and not nums[0] < nums[1]:
        raise ModelError(f"sample: {name!r}: {kind} needs lo < hi, got {dist!r}")
    if kind == "loguniform" and nums[0] <= 0:
        raise ModelError(f"sample: {name!r}: loguniform needs 0 < lo, got {dist!r}")
    if kind in ("normal", "lognormal", "truncnormal") and not nums[1] > 0:
        raise ModelError(f"sample: {name!r}: the standard deviation must be > 0, got {dist!r}")
    if kind == "truncnormal" and not nums[2] < nums[3]:
        raise ModelError(f"sample: {name!r}: truncnormal (mean, std, lo, hi) needs lo < hi, "
                         f"got {dist!r}")
    if kind == "triangular":
        lo, mode, hi = nums
        if not lo < hi:
            raise ModelError(f"sample: {name!r}: triangular (lo, mode, hi) needs lo < hi, "
                             f"got {dist!r}")
        if not lo <= mode <= hi:
            raise ModelError(f"sample: {name!r}: triangular (lo, mode, hi) needs the mode in "
                             f"[lo, hi], got {dist!r}")


def _ppf(name: str, spec: tuple, u: np.ndarray) -> np.ndarray:
    """The inverse CDF of distribution ``spec`` at the uniform numbers ``u``."""
    from scipy import stats

    kind = spec[0]
    args = spec[1:]
    if kind == "uniform":
        lo, hi = args
        return lo + (hi - lo) * u
    if kind == "loguniform":
        lo, hi = args
        return np.exp(np.log(lo) + (np.log(hi) - np.log(lo)) * u)
    if kind == "normal":
        mu, sigma = args
        return stats.norm.ppf(u, loc=mu, scale=sigma)
    if kind == "lognormal":  # mu, sigma of log(value)
        mu, sigma = args
        return np.exp(stats.norm.ppf(u, loc=mu, scale=sigma))
    if kind == "truncnormal":
        mu, sigma, lo, hi = args
        return stats.truncnorm.ppf(u, (lo - mu) / sigma, (hi - mu) / sigma, loc=mu, scale=sigma)
    if kind == "triangular":
        lo, mode, hi = args
        return stats.triang.ppf(u, (mode - lo) / (hi - lo), loc=lo, scale=hi - lo)
    if kind == "choice":
        values = list(args[0])
        idx = np.minimum((u * len(values)).astype(int), len(values) - 1)
        return np.array([values[i] for i in idx], dtype=float)
    raise ModelError(f"sample: unknown distribution {kind!r} for {name!r}")  # pragma: no cover


def sample(
    spec: Mapping[str, Any], n: int, seed: int = 0, method: str = "random"
) -> list[dict[str, float]]:
    """Draw ``n`` reproducible samples for :func:`ensemble` from distributions by name.

    Parameters
    ----------
    spec : dict
        ``{name: distribution}``: ``("uniform", lo, hi)``, ``("loguniform", lo, hi)``,
        ``("normal", mean, std)``, ``("lognormal", mu, sigma)`` (of the logarithm),
        ``("truncnormal", mean, std, lo, hi)``, ``("triangular", lo, mode, hi)``,
        ``("choice", [values])``, or a number (the same value in every sample).
    n : int
        Number of samples.
    seed : int
        A non-negative integer (default 0): the same seed gives the same samples, always.
        Each name draws from its own stream (seeded by ``seed`` and the name), so adding a
        name to ``spec`` does not change the values drawn for the others. ``None`` is
        refused (it would mean either a fixed seed or irreproducible draws); for fresh
        draws pick a seed and keep it, e.g. ``seed=secrets.randbits(32)``.
    method : ``"random"`` or ``"lhs"``
        Independent draws, or a Latin hypercube (each name's range cut into ``n`` equally
        probable strata, one draw in each, in random order; ``scipy.stats.qmc``).

    Returns
    -------
    list of dict
        One ``{name: value}`` per sample.

    Example
    -------
    >>> import daekit as dk
    >>> s = dk.sample({"L": ("uniform", 0.8, 1.2), "m": 2.0}, 4, seed=1)
    >>> len(s), s[0]["m"], all(0.8 <= x["L"] <= 1.2 for x in s)
    (4, 2.0, True)
    >>> s == dk.sample({"L": ("uniform", 0.8, 1.2), "m": 2.0}, 4, seed=1)
    True
    >>> lhs = dk.sample({"L": ("uniform", 0.0, 1.0)}, 10, seed=3, method="lhs")
    >>> sorted(int(x["L"] * 10) for x in lhs)     # one draw in each tenth
    [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    """
    if not isinstance(spec, Mapping) or not spec:
        raise ModelError("sample: spec must be a non-empty dict {name: distribution}, e.g. "
                         "{'L': ('uniform', 0.8, 1.2)}")
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
        raise ModelError(f"sample: n must be a positive integer, got {n!r}")
    if method not in ("random", "lhs"):
        raise ModelError(f"sample: method must be 'random' or 'lhs', got {method!r}")
    # numpy's None is fresh entropy; here it would silently break "the same seed gives the
    # same samples" (or silently be 0, as it once was): refused, as are negative and
    # fractional seeds (numpy refuses the first, int() would truncate the second)
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ModelError(
            f"sample: seed must be a non-negative integer (the same seed gives the same "
            f"samples), got {seed!r}"
            + ("; for fresh draws pick one and keep it, e.g. seed=secrets.randbits(32)"
               if seed is None else "")
        )
    n = int(n)
    base = int(seed)
    cols: dict[str, np.ndarray] = {}
    for name, dist in spec.items():
        if not isinstance(name, str):
            raise ModelError(f"sample: the names of spec are daekit names (str), got {name!r}")
        if isinstance(dist, (int, float, np.number)) and not isinstance(dist, bool):
            cols[name] = np.full(n, _finite(name, dist, dist))
            continue
        if (not isinstance(dist, (tuple, list)) or not dist or not isinstance(dist[0], str)
                or dist[0] not in _DISTRIBUTIONS):
            raise ModelError(
                f"sample: {name!r}: {dist!r} is not a distribution; use one of "
                + ", ".join(f"({k!r}, ...)" for k in _DISTRIBUTIONS if k != "constant")
                + " or a number"
            )
        kind, nargs = dist[0], _DISTRIBUTIONS[dist[0]]
        if len(dist) - 1 != nargs:
            what = "a list of values" if kind == "choice" else count(nargs, "number")
            raise ModelError(f"sample: {name!r}: {kind!r} takes {what}, got {dist!r}")
        if kind == "choice":
            nums = (_choices(name, dist),)
        else:
            nums = tuple(_finite(name, a, dist) for a in dist[1:])
        if kind == "constant":
            cols[name] = np.full(n, nums[0])
            continue
        _check_shape(name, kind, nums, dist)
        stream = [base, zlib.crc32(name.encode())]
        if method == "lhs":
            from scipy.stats import qmc

            u = qmc.LatinHypercube(d=1, seed=np.random.default_rng(stream)).random(n)[:, 0]
        else:
            u = np.random.default_rng(stream).random(n)
        cols[name] = np.asarray(_ppf(name, (kind, *nums), u), dtype=float)
    return [{k: float(v[i]) for k, v in cols.items()} for i in range(n)]
