"""Pure combinatorics of DAE structure on sparse integer data (no CasADi here).

The Sigma matrix is given as triplets ``(rows, cols, vals)``: ``vals[k]`` is the highest
derivative order of unknown ``cols[k]`` in equation ``rows[k]``; missing entries are -infinity.

- :func:`highest_value_transversal` -- a perfect matching maximizing the sum of Sigma entries.
- :func:`canonical_offsets` -- Pryce's smallest offsets ``c``, ``d``.
- :func:`structural_index` -- Pryce's structural index from the offsets.
- :func:`block_triangular` -- block lower triangular (BLT) order of a square system.
- :func:`dulmage_mendelsohn` -- over-, well- and under-determined parts of any system.
- :func:`structurally_nonsingular` -- whether a square pattern has a perfect matching.
"""

from .decompose import (
    DMDecomposition,
    block_triangular,
    dulmage_mendelsohn,
    structurally_nonsingular,
)
from .sigma import (
    SigmaAnalysis,
    canonical_offsets,
    highest_value_transversal,
    sigma_method,
    structural_index,
)

__all__ = [
    "DMDecomposition",
    "SigmaAnalysis",
    "block_triangular",
    "canonical_offsets",
    "dulmage_mendelsohn",
    "highest_value_transversal",
    "sigma_method",
    "structural_index",
    "structurally_nonsingular",
]
