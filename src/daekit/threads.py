"""Thread settings of the dense linear algebra daekit runs.

daekit's structural work calls many *small* dense LAPACK routines (SVDs and LU factorizations
of blocks, Gauss--Newton steps of small systems). With OpenBLAS' default of one thread per
core, each such call wakes the other threads, and on a loaded machine a call that takes
microseconds single-threaded waits for a busy core: measured on a 2-core machine shared with
other jobs, ``analyze`` of a 50-link chain varied from 0.26 s to 2.66 s from call to call, and
a dense initialization of a 60-link chain took 140 s of wall time for 43 s of CPU time.

What daekit does: :func:`analyze`, :func:`reduce_index` and :func:`initialize` run with the
BLAS/LAPACK thread pool limited to :data:`BLAS_THREADS` threads (default 1; the environment
variable ``DAEKIT_BLAS_THREADS`` sets another number, ``0`` leaves the pool alone), through
`threadpoolctl <https://github.com/joblib/threadpoolctl>`_, and restore the previous setting
when they return. The big systems take sparse paths (SuperLU, CasADi), which do not use the
BLAS thread pool, so nothing is lost by this; your own NumPy code outside daekit's calls keeps
its settings. The same calls also pause Python's cyclic garbage collector while they run
(:func:`gc_paused`; a big model's many CasADi objects made each collection expensive).

Example
-------
>>> from daekit.threads import blas_threads
>>> with blas_threads():
...     pass
"""

from __future__ import annotations

import contextlib
import functools
import gc
import os
from collections.abc import Callable, Iterator
from typing import TypeVar

__all__ = ["BLAS_THREADS", "blas_threads", "gc_paused", "limit_blas_threads",
           "single_threaded_worker"]

F = TypeVar("F", bound=Callable)


def _threads_from_env() -> int:
    try:
        return max(0, int(os.environ.get("DAEKIT_BLAS_THREADS", "1")))
    except ValueError:
        return 1


#: Threads the BLAS/LAPACK pool may use inside daekit's analysis, reduction and
#: initialization (``DAEKIT_BLAS_THREADS``; ``0``: leave the pool as it is).
BLAS_THREADS: int = _threads_from_env()

_state: dict = {"controller": None, "depth": 0, "gc_depth": 0}


def _controller():
    if _state["controller"] is None:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl is a dependency
            _state["controller"] = False
        else:
            # SciPy's wheels bring their own OpenBLAS beside NumPy's, loaded with
            # scipy.linalg (which daekit imports lazily): load it first, so that the
            # controller, made once, knows both
            import scipy.linalg  # noqa: F401

            _state["controller"] = ThreadpoolController()
    return _state["controller"]


@contextlib.contextmanager
def blas_threads(limit: int | None = None) -> Iterator[None]:
    """Limit the BLAS/LAPACK thread pool to ``limit`` threads (default :data:`BLAS_THREADS`)
    inside the block; nested uses cost nothing (the outermost one sets the limit).

    >>> import numpy as np
    >>> with blas_threads(1):
    ...     float(np.linalg.svd(np.eye(3), compute_uv=False).sum())
    3.0
    """
    limit = BLAS_THREADS if limit is None else int(limit)
    if limit <= 0 or _state["depth"] > 0:
        _state["depth"] += 1
        try:
            yield
        finally:
            _state["depth"] -= 1
        return
    ctrl = _controller()
    _state["depth"] += 1
    changed = []
    try:
        # each BLAS library's own get/set calls (a microsecond; ThreadpoolController.limit
        # inspects every library again on each use)
        for lib in (ctrl.lib_controllers if ctrl else ()):
            if lib.user_api == "blas":
                before = lib.get_num_threads()
                if before != limit:
                    lib.set_num_threads(limit)
                    changed.append((lib, before))
        yield
    finally:
        for lib, before in reversed(changed):
            lib.set_num_threads(before)
        _state["depth"] -= 1


def single_threaded_worker() -> None:
    """Limit the BLAS/LAPACK pool of *this process* to one thread for the rest of its life: for
    the worker processes of an ensemble (one per core already, so more threads per worker only
    compete for the same cores).

    Why it matters: OpenBLAS shuts its threads down before a ``fork`` and starts them again at
    the next call that may use them, and every started thread spins for about 2**28 cycles
    (some 50-100 ms) before it sleeps. Measured on a 2-core machine: a forked worker's first
    five 3D-pendulum samples took 20-45 ms each instead of 6 ms, and so did the parent's next
    five. With one thread no thread is started. Nothing happens when ``DAEKIT_BLAS_THREADS``
    is ``0`` (leave the pool alone).

    >>> from threadpoolctl import threadpool_info
    >>> single_threaded_worker()
    >>> all(i["num_threads"] == 1 for i in threadpool_info() if i["user_api"] == "blas")
    True
    """
    if BLAS_THREADS <= 0:
        return
    ctrl = _controller()
    for lib in (ctrl.lib_controllers if ctrl else ()):
        if lib.user_api == "blas" and lib.get_num_threads() != 1:
            lib.set_num_threads(1)


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector inside the block (the outermost use restores
    it, if it was enabled). A big model holds hundreds of thousands of CasADi objects, which
    every collection traverses again: measured 30% of ``reduce_index`` on a 10,000-link chain.
    Garbage made meanwhile is collected as usual afterwards.

    >>> import gc
    >>> with gc_paused():
    ...     gc.isenabled()
    False
    """
    was = gc.isenabled() and _state["gc_depth"] == 0
    _state["gc_depth"] += 1
    if was:
        gc.disable()
    try:
        yield
    finally:
        _state["gc_depth"] -= 1
        if was:
            gc.enable()


def limit_blas_threads(func: F) -> F:
    """Decorator: run ``func`` inside :func:`blas_threads` and :func:`gc_paused`.

    >>> @limit_blas_threads
    ... def f(x):
    ...     return x + 1
    >>> f(1)
    2
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with blas_threads(), gc_paused():
            return func(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
