"""Scaling of daekit's pipeline on the planar chain, N = 100 .. 20,000 links (issue 14).

The model is :func:`daekit.examples.planar_chain` (5N equations, index 3). Stages, each timed
on its own (one run; wall times on a shared machine are noisy, ratios come from one run):

- ``analyze``: :func:`daekit.analyze`;
- ``reduce``: :func:`daekit.reduce_index` (the minimal index-1 form: 4N states, N algebraic);
- ``dummy``: ``reduce_index(method="dummy_derivatives")``;
- ``init guess``: :func:`daekit.initialize` from the rough guess of issue 14 (a straight chain
  at 0.3 rad, each position moved by 1 cm: ``x_i = (i+1) sin 0.3 + 0.01 sin i``, ...), nothing
  fixed, *with* the rank analysis of the result (``init.free``, ``init.redundant``: made on
  first access, included here so that the stage does what it did before it was deferred);
  ``init call``: the ``initialize`` call alone (what a sweep that only simulates pays);
- ``init fixed``: all of ``q`` and ``v`` fixed (the chain along the x-axis at rest; half of the
  values are implied by the rods and reported redundant), with the rank analysis;
- ``simulate``: :func:`daekit.simulate` over 1 s (rtol = atol = 1e-6, 11 output points) from
  the guessed initial values, and ``raw IDAS``: ``casadi.integrator("idas")`` on the same
  reduced system (``r.dae_dict()``, built once, not timed), same tolerances and start.

Between successive N the growth exponent ``log(t2/t1) / log(N2/N1)`` is printed for each
stage. A stage is skipped for bigger N once its predicted time (from the last growth) exceeds
``LIMIT`` seconds. Also printed: ``casadi.dae_reduce_index`` on 200 links against daekit's
``reduce_index`` (the comparison row of issue 14), and the fixed per-call cost on the planar
pendulum (analyze + reduce + initialize, best of 30).

Run: ``python benchmarks/scaling.py [N ...] [--cpu] [--figure PATH] [--stages a,b,...]``
(``--cpu``: CPU time of this process instead of wall time; ``--stages``: only these of
``dummy``, ``init fixed``, ``simulate`` (with ``raw IDAS``), ``analyze`` beside reduce and
initialize) (default sizes 100 200 500 1000 2000 5000 10000 20000; the figure, a log-log plot
of the stages, goes to ``benchmarks/scaling.png``).
"""

from __future__ import annotations

import math
import sys
import time

import casadi as ca
import numpy as np

import daekit as dk

LIMIT = 120.0
STAGES = ("analyze", "reduce", "dummy", "init guess", "init call", "init fixed", "simulate",
          "raw IDAS")


def rough_guess(N: int, eps: float = 1e-2) -> np.ndarray:
    i = np.arange(N)
    x = (i + 1) * np.sin(0.3) + eps * np.sin(i)
    y = -(i + 1) * np.cos(0.3) + eps * np.cos(i)
    return np.column_stack([x, y]).ravel()


CLOCK = time.perf_counter  # --cpu: time.process_time (this process's CPU time: less
# sensitive to other jobs on a shared machine; IDAS and CasADi run in this process)


def timed(fn):
    t0 = CLOCK()
    out = fn()
    return CLOCK() - t0, out


def run_size(N: int, skip: set[str]) -> dict[str, float]:
    m = dk.examples.planar_chain(N)
    out: dict[str, float] = {}
    if "analyze" not in skip:
        out["analyze"], _ = timed(lambda: dk.analyze(m))
        m = dk.examples.planar_chain(N)  # a new model (analyze's caches not carried over)
    out["reduce"], r = timed(lambda: dk.reduce_index(m))
    assert (r.nx, r.nz) == (4 * N, N), r
    if "dummy" not in skip:
        out["dummy"], _ = timed(lambda: dk.reduce_index(m, method="dummy_derivatives"))
    out["init call"], init = timed(lambda: dk.initialize(r, guess={"q": rough_guess(N)}))
    t_rank, _ = timed(lambda: init.free)  # the deferred rank analysis
    out["init guess"] = out["init call"] + t_rank
    if "init fixed" not in skip:
        pos = np.zeros(2 * N)
        pos[0::2] = np.arange(1, N + 1)
        out["init fixed"], _ = timed(
            lambda: dk.initialize(r, fixed={"q": pos, "v": np.zeros(2 * N)}).redundant)
    if "simulate" not in skip:
        grid = np.linspace(0.0, 1.0, 11)
        out["simulate"], _ = timed(lambda: dk.simulate(r, grid, init, rtol=1e-6, atol=1e-6))
        F = ca.integrator("F", "idas", r.dae_dict(), 0.0, list(grid[1:]),
                          {"abstol": 1e-6, "reltol": 1e-6, "max_num_steps": 100000})
        p = np.r_[r.p_values, np.zeros(r.nu)]
        out["raw IDAS"], _ = timed(lambda: F(x0=init.x0, z0=init.z0, p=p))
    return out


def casadi_row(N: int = 200) -> tuple[float, float]:
    sys.path.insert(0, __file__.rsplit("/", 1)[0])
    from reduction_scaling import casadi_input

    times = []
    for _ in range(3):  # best of 3, a new model each time
        m = dk.examples.planar_chain(N)
        times.append(timed(lambda m=m: dk.reduce_index(m))[0])
    t_dk = min(times)
    m = dk.examples.planar_chain(N)
    dae = casadi_input(m)
    t_ca, _ = timed(lambda: ca.dae_reduce_index(dae, {}))
    return t_dk, t_ca


def pendulum_fixed_cost(repeat: int = 30) -> dict[str, float]:
    """Best of ``repeat`` of each stage on a *new* model each time (built outside the timing;
    nothing carried over from an earlier call), and of their sum; ``initialize`` with and
    without its deferred rank analysis."""
    m = dk.examples.pendulum_planar()
    dk.initialize(dk.reduce_index(m), fixed={"x": 0.6, "der(x)": 0.0}, guess={"y": -0.8})
    dk.analyze(m)
    rows: list[tuple[float, float, float, float]] = []
    for _ in range(repeat):
        m = dk.examples.pendulum_planar()
        ta, _ = timed(lambda m=m: dk.analyze(m))
        tr, r = timed(lambda m=m: dk.reduce_index(m))
        ti, init = timed(lambda r=r: dk.initialize(
            r, fixed={"x": 0.6, "der(x)": 0.0}, guess={"y": -0.8}))
        tf, _ = timed(lambda init=init: init.free)
        rows.append((ta, tr, ti, tf))
    a = np.array(rows)
    return {"analyze": a[:, 0].min(), "reduce": a[:, 1].min(), "initialize": a[:, 2].min(),
            "rank analysis": a[:, 3].min(), "sum": a[:, :3].sum(axis=1).min(),
            "sum with rank analysis": a.sum(axis=1).min(),
            "median sum": float(np.median(a[:, :3].sum(axis=1)))}


def main(argv: list[str]) -> None:
    global CLOCK
    if "--cpu" in argv:
        CLOCK = time.process_time
        argv = [a for a in argv if a != "--cpu"]
    fig_path = "benchmarks/scaling.png"
    only = None
    if "--stages" in argv:  # e.g. --stages analyze,reduce,init guess
        k = argv.index("--stages")
        only = set(argv[k + 1].split(","))
        argv = argv[:k] + argv[k + 2:]
    if "--figure" in argv:
        k = argv.index("--figure")
        fig_path = argv[k + 1]
        argv = argv[:k] + argv[k + 2:]
    sizes = [int(a) for a in argv] or [100, 200, 500, 1000, 2000, 5000, 10000, 20000]
    what = "CPU seconds" if CLOCK is time.process_time else "seconds (wall)"
    print(f"planar chain, {what} per stage (growth exponent to the previous N in parentheses)")
    print(f"{'N':>6} {'eqs':>7} " + " ".join(f"{s:>17}" for s in STAGES), flush=True)
    results: list[tuple[int, dict[str, float]]] = []
    skip: set[str] = set(STAGES) - only - {"reduce", "init guess", "init call"} if only else set()
    for N in sizes:
        if results:
            prevN, prev = results[-1]
            for s in STAGES:
                if s in prev:
                    expo = 1.0
                    if len(results) > 1 and s in results[-2][1]:
                        pN, pp = results[-2]
                        expo = max(1.0, math.log(prev[s] / pp[s]) / math.log(prevN / pN))
                    if prev[s] * (N / prevN) ** expo > LIMIT:
                        skip.add(s)
        res = run_size(N, skip)
        cells = []
        for s in STAGES:
            if s not in res:
                cells.append(f"{'skipped':>17}")
                continue
            g = ""
            if results and s in results[-1][1]:
                pN, pp = results[-1]
                g = f"({math.log(res[s] / pp[s]) / math.log(N / pN):.2f})"
            cells.append(f"{res[s]:9.3f} {g:>7}")
        print(f"{N:6d} {5 * N:7d} " + " ".join(cells), flush=True)
        results.append((N, res))
    t_dk, t_ca = casadi_row()
    print(f"\n200 links: daekit reduce_index {t_dk:.3f} s, casadi.dae_reduce_index {t_ca:.3f} s: "
          f"{t_ca / t_dk:.0f}x")
    cost = pendulum_fixed_cost()
    print("planar pendulum, a new model each time, best of 30 [ms]: "
          + ", ".join(f"{k} {1e3 * v:.1f}" for k, v in cost.items()))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover
        return
    fig, ax = plt.subplots(figsize=(7, 5))
    for s in STAGES:
        pts = [(N, res[s]) for N, res in results if s in res]
        if pts:
            ax.loglog(*zip(*pts, strict=True), "o-", label=s)
    Ns = np.array([N for N, _ in results], dtype=float)
    ax.loglog(Ns, 1e-4 * Ns, "k:", label="linear")
    ax.set_xlabel("links N (5N equations)")
    ax.set_ylabel("CPU seconds" if CLOCK is time.process_time else "seconds (wall)")
    ax.set_title("daekit on the planar chain")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(fig_path, dpi=120)
    print(f"figure: {fig_path}")


if __name__ == "__main__":
    main(sys.argv[1:])
