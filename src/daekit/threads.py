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
when they return (OpenBLAS in the main thread: through its own C functions, which threadpoolctl
finds; limiting and restoring costs some 2 microseconds instead of 15, and a sweep makes
hundreds of such calls). The big systems take sparse paths (SuperLU, CasADi), which do not use the
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

import functools
import gc
import itertools
import os
import threading
from collections.abc import Callable
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

_state: dict = {"controller": None, "depth": 0, "gc_depth": 0, "pools": None}


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


class _Pool:
    """One BLAS library's thread count, read and set. OpenBLAS with its own (pthreads)
    threads, read and set by its C functions directly in the main thread: a fraction of a
    microsecond each, where threadpoolctl's methods take one to two (daekit limits the pool
    around every ``initialize`` call: a sweep makes hundreds). The first setting goes through
    threadpoolctl, which makes the main thread the one that controls that pool (threadpoolctl
    then ignores other threads' settings, as before); other threads and other libraries
    always go through threadpoolctl."""

    def __init__(self, lib) -> None:
        self.lib = lib
        self.get_c = self.set_c = None
        self.registered = False
        if getattr(lib, "internal_api", "") == "openblas" and \
                getattr(lib, "threading_layer", "") == "pthreads":
            dyn = getattr(lib, "dynlib", None)
            for pre, suf in itertools.product(("", "scipy_"), ("", "64_", "_64")):
                get = getattr(dyn, f"{pre}openblas_get_num_threads{suf}", None)
                put = getattr(dyn, f"{pre}openblas_set_num_threads{suf}", None)
                if get is not None and put is not None:
                    self.get_c, self.set_c = get, put
                    break

    def get(self) -> int:
        if self.get_c is not None and threading.current_thread() is threading.main_thread():
            return self.get_c()
        return self.lib.get_num_threads()

    def set(self, n: int) -> None:
        if (self.registered and self.set_c is not None
                and threading.current_thread() is threading.main_thread()):
            self.set_c(n)
            return
        self.lib.set_num_threads(n)
        # taken by threadpoolctl for the main thread (not ignored: no other thread controls
        # the pool): from now on set directly
        self.registered = (threading.current_thread() is threading.main_thread()
                           and self.get_c is not None and self.get_c() == n)


def _pools() -> list[_Pool]:
    """The BLAS libraries' :class:`_Pool` objects (made once, with the controller)."""
    pools = _state["pools"]
    if pools is None:
        ctrl = _controller()
        pools = _state["pools"] = [_Pool(lib) for lib in (ctrl.lib_controllers if ctrl else ())
                                   if lib.user_api == "blas"]
    return pools


class blas_threads:  # noqa: N801 - used as a function (a context manager)
    """Limit the BLAS/LAPACK thread pool to ``limit`` threads (default :data:`BLAS_THREADS`)
    inside the block; nested uses cost nothing (the outermost one sets the limit).

    >>> import numpy as np
    >>> with blas_threads(1):
    ...     float(np.linalg.svd(np.eye(3), compute_uv=False).sum())
    3.0
    """

    __slots__ = ("limit", "changed")

    def __init__(self, limit: int | None = None) -> None:
        self.limit = BLAS_THREADS if limit is None else int(limit)
        self.changed: list = []

    def __enter__(self) -> None:
        depth = _state["depth"]
        _state["depth"] = depth + 1
        if self.limit <= 0 or depth > 0:
            return
        try:
            for pool in _pools():
                before = pool.get()
                if before != self.limit:
                    pool.set(self.limit)
                    self.changed.append((pool, before))
        except BaseException:
            self.__exit__(None, None, None)
            raise

    def __exit__(self, *exc) -> None:
        changed, self.changed = self.changed, []
        for pool, before in reversed(changed):
            pool.set(before)
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
    for pool in _pools():
        if pool.get() != 1:
            pool.set(1)


class gc_paused:  # noqa: N801 - used as a function (a context manager)
    """Pause Python's cyclic garbage collector inside the block (the outermost use restores
    it, if it was enabled). A big model holds hundreds of thousands of CasADi objects, which
    every collection traverses again: measured 30% of ``reduce_index`` on a 10,000-link chain.
    Garbage made meanwhile is collected as usual afterwards.

    >>> import gc
    >>> with gc_paused():
    ...     gc.isenabled()
    False
    """

    __slots__ = ("was",)

    def __enter__(self) -> None:
        self.was = gc.isenabled() and _state["gc_depth"] == 0
        _state["gc_depth"] += 1
        if self.was:
            gc.disable()

    def __exit__(self, *exc) -> None:
        _state["gc_depth"] -= 1
        if self.was:
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
