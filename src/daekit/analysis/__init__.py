"""What kind of DAE is this: :func:`analyze` (structural and differential index, offsets,
DOF, the easy test) in :mod:`.core`, and its plain-language account
(:meth:`Analysis.explain`) in :mod:`.explain`."""

from .core import (
    RANK_RTOL,
    Analysis,
    DerivativeArrayResult,
    EasyTest,
    analyze,
    derivative_array_dof,
    differential_index,
    is_index1,
    numeric_rank,
)

__all__ = ["Analysis", "EasyTest", "DerivativeArrayResult", "analyze", "differential_index",
           "is_index1", "derivative_array_dof", "numeric_rank", "RANK_RTOL"]
