"""Index reduction of a planar chain of N links: daekit against ``casadi.dae_reduce_index``.

The model is :func:`daekit.examples.planar_chain` (first-order form, 5N equations, index 3).
daekit's :func:`daekit.reduction.reduce_index` (Pryce's offsets, one ``casadi.jtimes`` sweep
per differentiation level, sparse index-1 check) and CasADi's ``dae_reduce_index`` (implicit
form ``x_impl``, ``dx_impl``, ``z``, ``alg``) run on the same model, side by side; CasADi is
skipped for bigger N once one of its runs took longer than the limit (60 s) or its predicted
time (cubic growth from the previous size) exceeds the limit.

A second daekit column times ``reduce_index(model, method="dummy_derivatives")`` (state
selection per block on big stages, see :mod:`daekit.reduction.dummy`).

Run: ``python benchmarks/reduction_scaling.py [N ...]``. Targets: N = 1000 under 3 s for
daekit (both methods); at N = 200 daekit at least 20 times faster than CasADi.
"""

from __future__ import annotations

import sys
import time

import casadi as ca

import daekit.examples as ex
from daekit.reduction import reduce_index

CASADI_LIMIT = 60.0


def casadi_input(m) -> dict:
    """The implicit-form dict of ``casadi.dae_reduce_index`` for a first-order model."""
    xs = [v for v in m.unknown_variables if v.ders]
    zs = [v for v in m.unknown_variables if not v.ders]
    return {
        "x_impl": ca.vertcat(*[v.sym for v in xs]),
        "dx_impl": ca.vertcat(*[v.der(1) for v in xs]),
        "z": ca.vertcat(*[v.sym for v in zs]),
        "alg": m.residual,
        "t": m.t,
        "p": m.parameter_symbols,
    }


def run(sizes=(10, 20, 50, 100, 200, 500, 1000)) -> list[dict]:
    rows = []
    casadi_on = True
    prev = None
    print(f"{'N':>6} {'eqs':>6} {'daekit [s]':>11} {'dummy [s]':>10} {'casadi [s]':>11} "
          f"{'speed-up':>9}")
    for N in sizes:
        m = ex.planar_chain(N)
        t0 = time.perf_counter()
        r = reduce_index(m)
        t_dk = time.perf_counter() - t0
        assert r.nz == N and r.nx == 4 * N, r  # q' = v, v' = f eliminated: x = (q, v), z = lam
        t0 = time.perf_counter()
        rd = reduce_index(m, method="dummy_derivatives")
        t_dd = time.perf_counter() - t0
        assert rd.nx == 2 * N, rd  # the DOF
        t_ca = None
        if casadi_on and prev is not None and prev[1] * (N / prev[0]) ** 3 > CASADI_LIMIT:
            casadi_on = False
        if casadi_on:
            dae = casadi_input(m)
            t0 = time.perf_counter()
            ca.dae_reduce_index(dae, {})
            t_ca = time.perf_counter() - t0
            prev = (N, t_ca)
            if t_ca > CASADI_LIMIT:
                casadi_on = False
        ratio = f"{t_ca / t_dk:9.1f}" if t_ca is not None else f"{'-':>9}"
        tc = f"{t_ca:11.3f}" if t_ca is not None else f"{'skipped':>11}"
        print(f"{N:6d} {m.n_equations:6d} {t_dk:11.3f} {t_dd:10.3f} {tc} {ratio}", flush=True)
        rows.append({"N": N, "equations": m.n_equations, "daekit": t_dk, "dummy": t_dd,
                     "casadi": t_ca})
    return rows


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    run(tuple(args) if args else (10, 20, 50, 100, 200, 500, 1000))
