"""Helpers the benchmark scripts share (run them as ``python benchmarks/NAME.py``)."""

from __future__ import annotations

import time

import numpy as np


def best_of(fn, repeat: int = 3):
    """``(best wall time of repeat calls, the last result)``: the minimum is the least
    disturbed measurement on a shared machine."""
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out
