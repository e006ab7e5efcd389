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

Rows 1-3 and the simulate calls alone run in turn, ROUNDS (9) rounds (a new process pool in
every round; the order in a round: simulate calls alone, serial, simulate calls alone, hand
loop, processes, hand loop); the Dask row is the best of 5 on one cluster. This machine's two cores are
shared with other jobs, which come and go within seconds, so every round also records how
much CPU *other* processes took while each row ran (``/proc/stat``'s busy time minus this
process's and its reaped workers' own): a round is *quiet* when that stayed under 0.15 of a
core during both the hand loop and the processes row. After the processes row the script
waits 0.3 s: OpenBLAS restarts this process's threads when the pool is done (a fork stops
them) and each spins some 100 ms, which would otherwise land on the next row measured.

Printed: the best round of each row (wall time, per-sample time, speedup against the hand
loop, CPU per sample, whether the results are bit-for-bit those of the hand loop); every
round's ratios with their medians; the load-independent estimate of the speedup (hand CPU /
max(worker CPU / 2, this process's CPU), round by round); and one verdict line per target:

- speedup of the default executor (2 workers) against the hand loop >= 1.7: judged on the
  median of the quiet rounds (at least 3 needed, else "not judged: machine busy");
- per-sample overhead of the serial ensemble (initialize + simulate) against the same
  samples' simulate calls alone <= 20 %: judged on the median CPU ratio of the rounds where
  no other job ran during the three rows (at least 3; else on all rounds, said so: other
  jobs inflate CPU time too, through the shared caches); the wall ratio is printed beside.

Each ratio compares a row with the mean of its base's two runs just before and just after
it (the simulate calls alone around the serial ensemble, the hand loop around the
processes): the machine's speed drifts by 10-25 % within seconds even when no other process
runs (other virtual machines on the host). No row keeps its results (a growing process
makes every later fork slower).

Run: ``python benchmarks/ensemble.py [N_SAMPLES] [--rounds R] [--no-dask]`` (default 200, 9).
"""

from __future__ import annotations

import argparse
import os
import resource
import time

import numpy as np

import daekit as dk

T_END, N_OUT, TOL = 10.0, 1001, 1e-8
WORKERS = 2
ROUNDS = 9
QUIET = 0.15  # cores of other processes' CPU below which a round counts as quiet
SPEEDUP_TARGET, OVERHEAD_TARGET = 1.7, 0.20


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


_TICK = os.sysconf("SC_CLK_TCK")


def _busy() -> float:
    """CPU seconds all processes of the machine have used (``/proc/stat``), 0 elsewhere."""
    try:
        with open("/proc/stat") as fh:
            f = [int(v) for v in fh.readline().split()[1:]]
    except OSError:
        return 0.0
    idle = f[3] + (f[4] if len(f) > 4 else 0)
    return (sum(f[:8]) - idle) / _TICK


def _children() -> float:
    """CPU seconds of this process's reaped children (the pool's workers, their whole life)."""
    b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return b.ru_utime + b.ru_stime


def timed(run):
    """``(result, wall, CPU of this process, other processes' CPU in cores meanwhile, CPU of
    the workers this process started and reaped meanwhile)``."""
    b0, k0 = _busy(), _children()
    w0, c0 = time.perf_counter(), time.process_time()
    out = run()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    kids = _children() - k0
    foreign = max(0.0, (_busy() - b0) - cpu - kids) / wall
    return out, wall, cpu, foreign, kids


def main() -> None:
    ap = argparse.ArgumentParser(description="daekit ensemble benchmark (issue 13)")
    ap.add_argument("n", nargs="?", type=int, default=200, help="samples (default 200)")
    ap.add_argument("--rounds", type=int, default=ROUNDS, help=f"rounds (default {ROUNDS})")
    ap.add_argument("--no-dask", action="store_true", help="skip the Dask LocalCluster row")
    a = ap.parse_args()
    n, rounds = a.n, a.rounds
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
    opts = {"rtol": TOL, "atol": TOL, "progress": False}

    def sim_only():
        for s, i0 in zip(samples, inits, strict=True):
            dk.simulate(r, t, i0, params={"L": s["L"]}, rtol=TOL, atol=TOL)

    def cpu(ens) -> float:  # CPU seconds of initialize + simulate, summed over the samples
        return float(sum(row["cpu_time"] for row in ens.summary()))

    ref = hand_loop(r, t, samples)  # the reference results (bit for bit)

    def same(ens) -> bool:
        return ens.failures == {} and all(
            np.array_equal(a["p"], b["p"]) and np.array_equal(a["z"], b["z"])
            and np.array_equal(a.invariants, b.invariants)
            for a, b in zip(ref, ens, strict=True))

    def timed_ens(run):
        """timed(run) for an ensemble, keeping only (identical, worker CPU, workers), not the
        trajectories: a growing process makes every later fork slower"""
        ens, *times = timed(run)
        return ((same(ens), cpu(ens), ens.stats["workers"]), *times)

    def timed_only(run):
        return (None, *timed(run)[1:])

    # every round: the serial ensemble between two runs of the simulate calls alone, the
    # processes between two hand loops (a new process pool in every round). The machine's
    # speed drifts by 10-25 % within seconds even with no other process running (other
    # virtual machines on the host), so each ratio compares a row with the mean of the two
    # runs of its base just before and just after it
    runs: dict[str, list] = {"sim": [], "sim2": [], "hand": [], "hand2": [], "serial": [],
                             "processes": []}
    for _ in range(rounds):
        runs["sim"].append(timed_only(sim_only))
        runs["serial"].append(timed_ens(lambda: dk.ensemble(r, t, samples, executor="serial",
                                                            **opts)))
        runs["sim2"].append(timed_only(sim_only))
        runs["hand"].append(timed_only(lambda: hand_loop(r, t, samples)))
        runs["processes"].append(timed_ens(lambda: dk.ensemble(r, t, samples, **opts)))
        time.sleep(0.3)  # this process's restarted OpenBLAS threads spin down (see above)
        runs["hand2"].append(timed_only(lambda: hand_loop(r, t, samples)))
    best = {k: min(v, key=lambda x: x[1]) for k, v in runs.items()}
    t_sims = min(best["sim"][1], best["sim2"][1])
    c_sims = min(x[2] for x in runs["sim"] + runs["sim2"])
    t_hand = min(best["hand"][1], best["hand2"][1])
    c_hand = min(x[2] for x in runs["hand"] + runs["hand2"])
    rows = [("hand loop (initialize + simulate)", t_hand, c_hand, True, c_hand)]
    (ident_ser, _, _), w_ser = best["serial"][0], best["serial"][1]
    c_ser = min(x[2] for x in runs["serial"])
    rows.append(("dk.ensemble serial", w_ser, c_ser, ident_ser, c_ser))
    (_, cpu_pro, n_workers), w_pro, c_pro = best["processes"][:3]
    identical = all(x[0][0] for x in runs["processes"] + runs["serial"])
    rows.append((f"dk.ensemble processes ({n_workers} workers)", w_pro, cpu_pro,
                 identical, c_pro))

    try:
        if a.no_dask:
            raise ImportError
        from distributed import Client, LocalCluster
    except ImportError:
        print('(no Dask row: pip install "daekit[dask]", or --no-dask given)')
    else:
        with LocalCluster(n_workers=WORKERS, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            dk.ensemble(r, t, samples[:2 * WORKERS], executor=client, **opts)  # warm-up
            (ident_d, cpu_d, _), w_dask, c_dask = min(
                (timed_ens(lambda: dk.ensemble(r, t, samples, executor=client, **opts))
                 for _ in range(5)), key=lambda x: x[1])[:3]
            rows.append((f"dk.ensemble Dask LocalCluster ({WORKERS} processes)",
                         w_dask, cpu_d, ident_d, c_dask))

    print(f"{n} samples of the 3D pendulum, {T_END:g} s each ({N_OUT} points, rtol = atol = "
          f"{TOL:g}); one simulate call (no initialize): {1e3 * t_sim:.2f} ms wall, "
          f"{1e3 * c_sim:.2f} ms CPU")
    print(f"the {n} samples' simulate calls alone (initial values made beforehand): "
          f"{t_sims:.2f} s wall, {c_sims:.2f} s CPU, {1e3 * c_sims / n:.2f} ms CPU per sample")
    print(f"best of {rounds} rounds (each row's best, from different rounds: its speedup column "
          f"is indicative only; the verdict uses the round-by-round ratios below):")
    print(f"{'':<46} {'wall [s]':>9} {'wall/sample':>12} {'speedup':>8} "
          f"{'CPU/sample':>11} {'here CPU':>9} {'identical':>9}")
    for name, wall, cpu_s, ident, here in rows:
        print(f"{name:<46} {wall:>9.3f} {1e3 * wall / n:>9.2f} ms {t_hand / wall:>8.2f} "
              f"{1e3 * cpu_s / n:>8.2f} ms {here:>8.3f}s {'yes' if ident else 'NO':>9}")
    print("speedup: hand loop wall / row wall. CPU/sample: process CPU time of initialize + "
          "simulate per sample (in the workers for the ensembles; Dask's worker threads "
          "included). here CPU: CPU seconds of this (the submitting) process. identical: "
          "every trajectory's p, z and invariants bit for bit those of the hand loop (for "
          "the processes: in every round).")

    # round by round (each round's rows run seconds apart, under the same other jobs)
    print("\nround by round (base: the mean of the runs just before and just after the row):")
    print(f"{'round':>5} {'sim s':>13} {'serial s':>9} {'hand s':>13} {'proc s':>7} "
          f"{'overhead wall':>14} {'overhead CPU':>13} {'speedup':>8} {'estimate':>9} "
          f"{'bound':>6} {'others (cores): hand / proc':>28}")
    over_w, over_c, speed, est, quiet, quiet_over, bound = [], [], [], [], [], [], []
    for k in range(rounds):
        sim, sim2, ser = runs["sim"][k], runs["sim2"][k], runs["serial"][k]
        hand, hand2, pro = runs["hand"][k], runs["hand2"][k], runs["processes"][k]
        ow = ser[1] / ((sim[1] + sim2[1]) / 2) - 1
        oc = ser[2] / ((sim[2] + sim2[2]) / 2) - 1
        sp = (hand[1] + hand2[1]) / 2 / pro[1]
        es = (hand[2] + hand2[2]) / 2 / max(pro[0][1] / WORKERS, pro[2])
        wb = (hand[2] + hand2[2]) / 2 / ((pro[4] + pro[2]) / WORKERS)
        bound.append(wb)
        busy_hand = max(hand[3], hand2[3])
        q = busy_hand < QUIET and pro[3] < QUIET
        over_w.append(ow)
        over_c.append(oc)
        speed.append(sp)
        est.append(es)
        if q:
            quiet.append(sp)
        if max(sim[3], sim2[3], ser[3]) < QUIET:
            quiet_over.append(oc)
        print(f"{k + 1:>5} {sim[1]:>6.3f}/{sim2[1]:.3f} {ser[1]:>9.3f} "
              f"{hand[1]:>6.3f}/{hand2[1]:.3f} {pro[1]:>7.3f} "
              f"{100 * ow:>+13.1f}% {100 * oc:>+12.1f}% {sp:>8.2f} {es:>9.2f} {wb:>6.2f} "
              f"{busy_hand:>16.2f} / {pro[3]:.2f}{'' if q else '  (busy)'}")
    print(f"{'median':>5} {'':>13} {'':>9} {'':>13} {'':>7} {100 * np.median(over_w):>+13.1f}% "
          f"{100 * np.median(over_c):>+12.1f}% {np.median(speed):>8.2f} {np.median(est):>9.2f} "
          f"{np.median(bound):>6.2f}")
    print("overhead: serial ensemble (initialize + simulate) / the simulate calls alone - 1. "
          "speedup: hand loop / processes. estimate: the load-independent speedup on 2 idle "
          "cores, hand CPU / max(worker CPU in the samples / 2, this process's "
          "CPU). bound: the same with all the work counted, hand CPU / ((the workers' CPU "
          "over their whole life + this process's CPU) / 2): the most 2 cores could give at the "
          "CPU costs of that round (which other jobs inflate, through the shared caches). "
          "others: CPU of other processes while the row ran (for the hand loop, the larger "
          "of its two runs).")

    print("\nverdict:")
    if len(quiet) >= 3:
        m = float(np.median(quiet))
        print(f"  speedup >= {SPEEDUP_TARGET} with {WORKERS} workers: "
              f"{'MET' if m >= SPEEDUP_TARGET else 'NOT MET'} (median of {len(quiet)} quiet "
              f"rounds {m:.2f}; of all {rounds} rounds {np.median(speed):.2f}; best "
              f"{max(speed):.2f}; load-independent estimate {np.median(est):.2f}, bound "
              f"{np.median(bound):.2f})")
    else:
        print(f"  speedup >= {SPEEDUP_TARGET} with {WORKERS} workers: NOT JUDGED (machine busy: "
              f"{len(quiet)} quiet rounds of {rounds}; median of all rounds "
              f"{np.median(speed):.2f}, best {max(speed):.2f}, load-independent estimate "
              f"{np.median(est):.2f}, bound {np.median(bound):.2f})")
    mc = float(np.median(over_c))
    if len(quiet_over) >= 3:
        mq = float(np.median(quiet_over))
        print(f"  per-sample overhead <= {100 * OVERHEAD_TARGET:.0f} %: "
              f"{'MET' if mq <= OVERHEAD_TARGET else 'NOT MET'} (median of {len(quiet_over)} "
              f"quiet rounds {100 * mq:+.1f} % CPU; of all {rounds} rounds {100 * mc:+.1f} % "
              f"CPU, {100 * np.median(over_w):+.1f} % wall)")
    else:
        print(f"  per-sample overhead <= {100 * OVERHEAD_TARGET:.0f} %: "
              f"{'MET' if mc <= OVERHEAD_TARGET else 'NOT MET'} on all {rounds} rounds, "
              f"machine busy ({len(quiet_over)} quiet rounds; other jobs inflate CPU time "
              f"too): median {100 * mc:+.1f} % CPU, {100 * np.median(over_w):+.1f} % wall")
    print(f"  results bit for bit those of the hand loop: {'yes' if identical else 'NO'}")


if __name__ == "__main__":
    main()
