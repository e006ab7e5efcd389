"""Consistent initialization of a planar chain of N links: dense path against sparse path.

The model is :func:`daekit.examples.planar_chain` (index 3) reduced to index 1 by
:func:`daekit.reduce_index` (4N states, N algebraic unknowns, 2N invariants). Two cases:

- ``stretched``: the chain along the x-axis at rest, all of ``q`` and ``v`` fixed (over-specified:
  the rods imply the 2N x-coordinates, which are accepted as redundant);
- ``guessed``: a random consistent state (link angles and rates) perturbed by 1e-2 as a guess,
  nothing fixed (least-squares pull onto the constraint manifold, about 6 Gauss--Newton steps).

:func:`daekit.initialize` takes the dense SVD/QR path below ``_SPARSE_MIN_UNKNOWNS`` unknowns and
the sparse path (SuperLU on the Gauss--Newton KKT systems, a matched basis of the consistency
rows for ``free`` and ``redundant``) from there on; here both are forced in turn on the same
problems. The dense path is skipped for bigger N once one of its runs took longer than the limit
(60 s) or its predicted time (cubic growth from the previous size) exceeds it. The last
column is the largest difference between the two paths' values.

Run: ``python benchmarks/initialize_scaling.py [N ...]`` (default 50 100 200 500 1000).
Targets: the sparse path at N = 500 under 3 s and at N = 1000 under 10 s, growing about
linearly.
"""

from __future__ import annotations

import importlib
import sys
import time

import numpy as np

import daekit as dk

INIT = importlib.import_module("daekit.initialize")
DENSE_LIMIT = 60.0


def cases(N: int) -> dict[str, dict]:
    pos = np.zeros(2 * N)
    pos[0::2] = np.arange(1, N + 1)
    rng = np.random.default_rng(0)
    th, om = rng.uniform(-1.0, 1.0, N), rng.uniform(-1.0, 1.0, N)
    q = np.cumsum(np.column_stack([np.sin(th), -np.cos(th)]), axis=0).ravel()
    v = np.cumsum(om[:, None] * np.column_stack([np.cos(th), np.sin(th)]), axis=0).ravel()
    guess = {"q": q + 1e-2 * rng.standard_normal(2 * N), "v": v + 1e-2 * rng.standard_normal(2 * N)}
    return {
        "stretched": {"fixed": {"q": pos, "v": np.zeros(2 * N)}},
        "guessed": {"guess": guess},
    }


def run(r, kw: dict, sparse: bool):
    INIT._SPARSE_MIN_UNKNOWNS = 0 if sparse else 10**12
    t0 = time.perf_counter()
    init = dk.initialize(r, **kw)
    return time.perf_counter() - t0, init


def main(sizes: list[int]) -> None:
    saved = INIT._SPARSE_MIN_UNKNOWNS
    print(f"{'case':>10} {'N':>5} {'unknowns':>8} {'dense [s]':>10} {'sparse [s]':>11} "
          f"{'iter':>5} {'dof':>5} {'redundant':>9} {'max |diff|':>10}")
    last_dense: dict[str, tuple[int, float]] = {}
    try:
        for N in sizes:
            r = dk.reduce_index(dk.examples.planar_chain(N))
            n = r.nx + r.nz
            for name, kw in cases(N).items():
                ts, s = run(r, kw, sparse=True)
                td_txt, diff_txt = "skipped", "-"
                prev = last_dense.get(name)
                if prev is None or (prev[1] < DENSE_LIMIT
                                    and prev[1] * (N / prev[0]) ** 3 < DENSE_LIMIT):
                    td, d = run(r, kw, sparse=False)
                    last_dense[name] = (N, td)
                    td_txt = f"{td:.3f}"
                    diff = np.abs(np.r_[d.x0, d.z0] - np.r_[s.x0, s.z0]).max()
                    diff_txt = f"{diff:.1e}"
                print(f"{name:>10} {N:>5} {n:>8} {td_txt:>10} {ts:>11.3f} {s.iterations:>5} "
                      f"{s.dof:>5} {len(s.redundant):>9} {diff_txt:>10}", flush=True)
    finally:
        INIT._SPARSE_MIN_UNKNOWNS = saved


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [50, 100, 200, 500, 1000])
