"""Benchmark: 200 samples of the 3D pendulum, serial vs local processes vs a Dask LocalCluster.

Each sample is a Monte Carlo draw (``dk.sample``, seed 0) of the rod length ``L`` in [0.8, 1.2]
and the initial swing speed in [0.5, 2.0] m/s; it is initialized consistently (the position
and velocity fixed, redundantly: the rod and its derivative imply two of the six values) and
simulated for 10 s (1001 output points, rtol = atol = 1e-8, no stabilization).

Rows, all from one run:

1. *hand loop*: the strongest fair alternative, a plain Python loop calling
   ``dk.initialize`` and ``dk.simulate`` on the same reduced system (its integrator built
   once and reused, as daekit does): what an expert writes without an ensemble tool;
2. ``dk.ensemble(..., executor="serial")``: the same work through the ensemble machinery
   (the per-sample overhead of the ensemble against the hand loop);
3. ``dk.ensemble(...)`` with the default executor: local worker processes, one per core
   (the pool's start and the shipping of the system included);
4. ``dk.ensemble(..., executor=client)`` on a ``dask.distributed.LocalCluster`` with two worker
   processes (the cluster started before the timing, warmed up on a few samples).

Rows 1-3 and the simulate calls alone run in turn, REPEAT (5) rounds, the best round of each
kept (a new process pool in every round); the Dask row is the best of 5 on one cluster. This
machine's CPU is shared with other virtual machines (``top`` shows their steal time, up to
50 %), so single runs of one row scatter widely; the last lines give the overhead and the
speedup round by round too, with their medians (the rows of one round run seconds apart).

Printed: wall time, per-sample time, speedup against the hand loop, and whether the results
are bit-for-bit those of the hand loop. The per-sample time of a single ``simulate`` call
(initialization excluded) is printed too, and the same samples' ``simulate`` calls alone (their
initial values made beforehand: the like-for-like base of the per-sample overhead, as the
samples differ in their step counts). Targets: speedup >= 1.7 with 2 workers, overhead of
the ensemble per sample <= 20 %.

Run: ``python benchmarks/ensemble.py [N_SAMPLES]`` (default 200). Wall times on a shared
machine are noisy; the ratios come from this one run.
"""

from __future__ import annotations

import sys
import time

import numpy as np

import daekit as dk

T_END, N_OUT, TOL = 10.0, 1001, 1e-8
WORKERS = 2
REPEAT = 5


def make_samples(n: int) -> list[dict]:
    draws = dk.sample({"L": ("uniform", 0.8, 1.2), "speed": ("uniform", 0.5, 2.0)}, n, seed=0)
    out = []
    for d in draws:
        L, s = d["L"], d["speed"]
        out.append({"L": L, "p": [0.6 * L, 0.0, -0.8 * L], "der(p)": [0.0, s, 0.0]})
    return out


def hand_loop(r, t, samples):
    trajs = []
    for s in samples:
        init = dk.initialize(r, fixed={"p": s["p"], "der(p)": s["der(p)"]}, params={"L": s["L"]})
        trajs.append(dk.simulate(r, t, init, params={"L": s["L"]}, rtol=TOL, atol=TOL))
    return trajs


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    r = dk.reduce_index(dk.examples.pendulum3d())
    t = np.linspace(0.0, T_END, N_OUT)
    samples = make_samples(n)
    hand_loop(r, t, samples[:2])  # builds the integrator once (reused by every later call)

    # one simulate call, initialization excluded
    init = dk.initialize(r, fixed={"p": samples[0]["p"], "der(p)": samples[0]["der(p)"]},
                         params={"L": samples[0]["L"]})
    reps, creps = [], []
    for _ in range(10):
        w0, c0 = time.perf_counter(), time.process_time()
        dk.simulate(r, t, init, params={"L": samples[0]["L"]}, rtol=TOL, atol=TOL)
        reps.append(time.perf_counter() - w0)
        creps.append(time.process_time() - c0)
    t_sim, c_sim = float(np.median(reps)), float(np.median(creps))
    # the same samples' simulate calls alone (initial values made beforehand): the
    # like-for-like base of the per-sample overhead (the samples differ in their steps)
    inits = [dk.initialize(r, fixed={"p": s["p"], "der(p)": s["der(p)"]}, params={"L": s["L"]})
             for s in samples]
    rows = []
    opts = {"rtol": TOL, "atol": TOL, "progress": False}

    def timed(run):
        w0, c0 = time.perf_counter(), time.process_time()
        out = run()
        return out, time.perf_counter() - w0, time.process_time() - c0

    def sim_only():
        for s, i0 in zip(samples, inits, strict=True):
            dk.simulate(r, t, i0, params={"L": s["L"]}, rtol=TOL, atol=TOL)

    # every round runs all four in turn (this machine's CPU is shared with other virtual
    # machines: their steal time comes and goes, so the rows are interleaved and the best
    # of REPEAT rounds is kept for each; a new process pool is started in every round)
    runs: dict[str, list] = {"sim": [], "hand": [], "serial": [], "processes": []}
    for _ in range(REPEAT):
        runs["sim"].append(timed(sim_only))
        runs["hand"].append(timed(lambda: hand_loop(r, t, samples)))
        runs["serial"].append(timed(lambda: dk.ensemble(r, t, samples, executor="serial",
                                                        **opts)))
        runs["processes"].append(timed(lambda: dk.ensemble(r, t, samples, **opts)))
    best = {k: min(v, key=lambda x: x[1]) for k, v in runs.items()}
    t_sims, c_sims = best["sim"][1], min(x[2] for x in runs["sim"])
    ref = best["hand"][0]
    t_hand, c_hand = best["hand"][1], min(x[2] for x in runs["hand"])
    rows.append(("hand loop (initialize + simulate)", t_hand, c_hand, True, c_hand))

    def same(ens) -> bool:
        return ens.failures == {} and all(
            np.array_equal(a["p"], b["p"]) and np.array_equal(a.invariants, b.invariants)
            for a, b in zip(ref, ens, strict=True))

    def cpu(ens) -> float:  # CPU seconds of initialize + simulate, summed over the samples
        return float(sum(row["cpu_time"] for row in ens.summary()))

    ens_serial, w_ser, _ = best["serial"]
    c_ser = min(x[2] for x in runs["serial"])
    rows.append(("dk.ensemble serial", w_ser, c_ser, same(ens_serial), c_ser))
    ens, w_pro, c_pro = best["processes"]
    rows.append((f"dk.ensemble processes ({ens.stats['workers']} workers)", w_pro, cpu(ens),
                 same(ens), c_pro))

    try:
        from distributed import Client, LocalCluster
    except ImportError:
        print('(Dask not installed: pip install "daekit[dask]")')
    else:
        with LocalCluster(n_workers=WORKERS, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            dk.ensemble(r, t, samples[:2 * WORKERS], executor=client, **opts)  # warm-up
            ens, w_dask, c_dask = min(
                (timed(lambda: dk.ensemble(r, t, samples, executor=client, **opts))
                 for _ in range(REPEAT)), key=lambda x: x[1])
            rows.append((f"dk.ensemble Dask LocalCluster ({WORKERS} processes)",
                         w_dask, cpu(ens), same(ens), c_dask))

    print(f"{n} samples of the 3D pendulum, {T_END:g} s each ({N_OUT} points, rtol = atol = "
          f"{TOL:g}); one simulate call (no initialize): {1e3 * t_sim:.2f} ms wall, "
          f"{1e3 * c_sim:.2f} ms CPU")
    print(f"the {n} samples' simulate calls alone (initial values made beforehand): "
          f"{t_sims:.2f} s wall, {c_sims:.2f} s CPU, {1e3 * c_sims / n:.2f} ms CPU per sample")
    print(f"{'':<46} {'wall [s]':>9} {'wall/sample':>12} {'speedup':>8} "
          f"{'CPU/sample':>11} {'here CPU':>9} {'identical':>9}")
    for name, wall, cpu_s, ident, here in rows:
        print(f"{name:<46} {wall:>9.2f} {1e3 * wall / n:>9.2f} ms {t_hand / wall:>8.2f} "
              f"{1e3 * cpu_s / n:>8.2f} ms {here:>8.2f}s {'yes' if ident else 'NO':>9}")
    print(f"speedup: hand loop wall / row wall. CPU/sample: process CPU time of initialize + "
          f"simulate per sample (in the workers for the ensembles; Dask's worker threads "
          f"included). here CPU: CPU seconds of this (the submitting) process. Per-sample "
          f"overhead of the ensemble against the hand loop: "
          f"{100 * (rows[1][1] / t_hand - 1):+.1f} % wall, {100 * (rows[1][2] / c_hand - 1):+.1f} "
          f"% CPU (serial). Per-sample cost of initialize + simulate (serial ensemble) against "
          f"the simulate calls alone: {100 * (rows[1][1] / t_sims - 1):+.1f} % wall, "
          f"{100 * (rows[1][2] / c_sims - 1):+.1f} % CPU.")
    # the same ratios round by round (each round's rows run seconds apart, under the same
    # steal time): the median is the robust figure on a shared machine
    per_round = [(ser[1] / sim[1] - 1, hand[1] / pro[1]) for sim, hand, ser, pro in
                 zip(runs["sim"], runs["hand"], runs["serial"], runs["processes"], strict=True)]
    over = sorted(100 * o for o, _ in per_round)
    speed = sorted(sp for _, sp in per_round)
    print("round by round: initialize + simulate against simulate alone "
          + ", ".join(f"{o:+.1f} %" for o in over) + f" (median {np.median(over):+.1f} %); "
          "speedup of the processes " + ", ".join(f"{v:.2f}" for v in speed)
          + f" (median {np.median(speed):.2f})")
    print(f"load-independent estimate of the speedup on {WORKERS} idle cores (processes): "
          f"hand CPU / max(worker CPU / {WORKERS}, submitting CPU) = "
          f"{c_hand / max(rows[2][2] / WORKERS, rows[2][4]):.2f}")

if __name__ == "__main__":
    main()
