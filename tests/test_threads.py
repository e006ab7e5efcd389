"""daekit.threads: the BLAS limit and the paused garbage collector around daekit's calls.

The limit is read and set through OpenBLAS's own C functions in the main thread (cheap enough
for every initialize call of a sweep); what threadpoolctl reports must be what was asked for,
inside the block and after it.
"""

from __future__ import annotations

import gc
from concurrent.futures import ThreadPoolExecutor

import pytest
import scipy.linalg  # noqa: F401 - SciPy's own OpenBLAS, loaded here as daekit loads it
from threadpoolctl import threadpool_info, threadpool_limits

from daekit.threads import blas_threads, gc_paused


def blas_counts() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


@pytest.mark.skipif(not blas_counts(), reason="no BLAS library that threadpoolctl knows")
@pytest.mark.parametrize("outer", [1, 2, 3])
def test_limit_inside_and_restored_after(outer):
    with threadpool_limits(limits=outer, user_api="blas"):
        assert set(blas_counts()) == {outer}
        for _ in range(3):  # the first setting registers the main thread, later ones direct
            with blas_threads(1):
                assert set(blas_counts()) == {1}
                with blas_threads(2):  # nested: the outermost limit holds
                    assert set(blas_counts()) == {1}
                assert set(blas_counts()) == {1}
            assert set(blas_counts()) == {outer}
        with pytest.raises(ZeroDivisionError), blas_threads(1):
            raise ZeroDivisionError
        assert set(blas_counts()) == {outer}  # restored on an error too


def test_limit_from_another_thread_leaves_the_pool_as_it_was():
    before = blas_counts()

    def work():
        with blas_threads(1):
            return sum(range(10))

    with ThreadPoolExecutor(2) as ex:
        assert list(ex.map(lambda _: work(), range(4))) == [45] * 4
    assert blas_counts() == before


def test_gc_paused_nested_and_restored():
    assert gc.isenabled()
    with gc_paused():
        assert not gc.isenabled()
        with gc_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()  # only the outermost use enables it again
    assert gc.isenabled()
    gc.disable()
    try:
        with gc_paused():
            pass
        assert not gc.isenabled()  # it was off: stays off
    finally:
        gc.enable()
