"""Benchmark: simulation with and without drift remedies against hand-written raw CasADi IDAS.

Part 1, the 3D pendulum (lecture L3), 10 s from ``p = (sin 0.6, 0, -cos 0.6)``,
``v = (0, 1.5, 0)``, ``m = L = 1``, ``g = 9.81``, rtol = atol = 1e-8 (and 1e-6):

- ``hand``: the lecture's minimal index-1 form written by hand, ``x = (p, v)``, ``z = (z)``,
  ``p' = v``, ``v' = -g e3 - z p``, ``0 = -g p3 - z |p|^2 + |v|^2``, one raw
  ``casadi.integrator("idas")`` built once (outside the timing) on the output grid: the
  strongest fair alternative;
- ``daekit``: ``simulate(reduce_index(pendulum3d()), ...)`` (integrator reused from an
  earlier call, initialization outside the timing), plain, ``stabilization="projection"``
  (the default ``drift_tol``, 100 atol: the integration projected and restarted where its
  drift crosses it, the returned rows beyond it projected), the same with
  ``project_output=True`` ("proj., every row": every returned row on the manifold to
  rounding; printed, not judged) and, on ``reduce_index(..., method="dummy_derivatives")``,
  ``"dummy_derivatives"``;

The main table times every method from ``1 + K_STARTS`` starts: the benchmark's own and
``K_STARTS`` starts whose components are multiplied by ``1 + 1e-15 N(0, 1)`` (the same
perturbations for every method; each form computes its own consistent start there, outside
the timing). Each time is the best CPU time of the process (``time.process_time``: on a loaded
machine the wall time also holds the waiting for a core) over ``ROUNDS`` rounds in which every
method and start runs once in turn (a load change on the shared machine hits all alike).
The table prints the exact start's steps and time and, beside them, the median over the
perturbed starts of each side's steps and time, and their ratios. Why the medians: IDAS's
step count at one tolerance is not a smooth function of its inputs. From starts equal to 15
digits the hand form itself takes 1111 to 1570 steps at rtol 1e-8 (:func:`lottery`), and
daekit's form, the same equation to rounding (:func:`same_equations`), takes 1435 from the
exact start where the hand form happens to take 1184: one draw each, a coin flip rather than a
property of either form. The verdict (:func:`verdict`) is therefore taken on the medians; the
exact start's ratios are printed beside them. (Projection restarts IDAS where the drift
crosses ``drift_tol``; at rtol 1e-8 over 10 s the drift ends near 100 atol, so some starts
cross it and some do not: that is in its median too.) daekit's time includes reading
``traj["p"]`` (its trajectory evaluates the model's other variables and the invariants only
when they are read). The error is the largest position error over the grid against the hand
form at rtol 1e-12 (from the exact start). The table gives time, IDAS steps, error and max
|rod| for 21 .. 20001 output points. Then every method against the hand form at 13
tolerances from 1e-4 to 1e-10 on 21 and 2001 points (:func:`sweep`, the exact start: the
totals over the tolerances are a second way around the lottery), the step counts from 40
starts perturbed by one part in 1e15 (:func:`lottery`), and a check that the two algebraic
equations are the same function to rounding (:func:`same_equations`).

Part 2, the planar chain of 500 links, 1 s from a bent rest, rtol = atol = 1e-6: plain and
projection, wall time and steps.

At the end, the verdict on each of issue 8's speed targets, PASS or FAIL with its numbers.

Run: ``python benchmarks/simulation.py [--quick] [--chain] [--sweep]`` (``--chain``: part 2
only; ``--sweep``: the tolerance sweep and the perturbed starts only)
"""

from __future__ import annotations

import sys
import time

import casadi as ca
import numpy as np
from common import best_of  # noqa: E402 - benchmarks/ is the script directory

import daekit as dk

REPEAT = 15  # rounds of the tolerance sweep
ROUNDS = 5  # rounds of the main table, each over all its starts
K_STARTS = 10  # perturbed starts of the main table
T_END = 10.0
G = 9.81
P0 = [float(np.sin(0.6)), 0.0, float(-np.cos(0.6))]
V0 = [0.0, 1.5, 0.0]


def hand_integrator(t, tol):
    """The lecture's index-1 form, by hand, as one raw CasADi IDAS integrator on ``t``."""
    p, v, z = ca.SX.sym("p", 3), ca.SX.sym("v", 3), ca.SX.sym("z")
    e3 = ca.DM([0, 0, 1])
    dae = {"x": ca.vertcat(p, v), "z": z, "ode": ca.vertcat(v, -G * e3 - z * p),
           "alg": -G * p[2] - z * ca.dot(p, p) + ca.dot(v, v)}
    F = ca.integrator("hand", "idas", dae, float(t[0]), [float(s) for s in t[1:]],
                      {"abstol": tol, "reltol": tol, "max_num_steps": 100000})
    z0 = (np.dot(V0, V0) - G * P0[2]) / np.dot(P0, P0)
    return F, np.r_[P0, V0], np.array([z0])


def run_hand(F, x0, z0):
    res = F(x0=x0, z0=z0)
    X = np.asarray(res["xf"]).T
    return np.vstack([x0, X]), F.stats()["nsteps"]


CPU: dict = {}  # best process CPU time of each function of the last interleaved() call


def interleaved(fns: dict, repeat: int) -> tuple[dict, dict]:
    """Best wall time of each function over ``repeat`` rounds, the functions run in turn in
    every round (a load change on the shared machine hits all of them alike), and the last
    result of each. The best CPU time of this process (``time.process_time``: what the
    computation itself took, not the waiting for a core of the shared machine) is left in
    ``CPU``."""
    best = {k: np.inf for k in fns}
    CPU.clear()
    CPU.update({k: np.inf for k in fns})
    out = {}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0, c0 = time.perf_counter(), time.process_time()
            out[k] = fn()
            c1 = time.process_time()
            best[k] = min(best[k], time.perf_counter() - t0)
            CPU[k] = min(CPU[k], c1 - c0)
    return best, out


def perturbed_starts(k: int, seed: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """``k`` starts ``(p0, v0)``: the benchmark's start times ``1 + 1e-15 N(0, 1)``, component
    by component (one part in 1e15, below what any measurement could tell apart); the same
    perturbations for every method (see the module docstring)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(k):
        e = 1e-15 * rng.standard_normal(6)
        out.append((np.asarray(P0) * (1 + e[:3]), np.asarray(V0) * (1 + e[3:])))
    return out


def hand_start(p, v):
    """The hand form's consistent start at ``(p, v)``: ``x = (p, v)``, ``z`` from ``alg = 0``."""
    return np.r_[p, v], np.array([(np.dot(v, v) - G * p[2]) / np.dot(p, p)])


def part1(quick: bool) -> dict:
    """The main table (see the module docstring); returns the verdict's numbers."""
    r = dk.reduce_index(dk.examples.pendulum3d())
    rd = dk.reduce_index(dk.examples.pendulum3d(), method="dummy_derivatives",
                         point={"p": P0, "v": V0})
    fixed = {"p": P0, "v": V0}
    init, initd = dk.initialize(r, fixed=fixed), dk.initialize(rd, fixed=fixed)
    print(f"daekit's form: x = {r.x_names}, z = {r.z_names}")
    if "--sweep" in sys.argv:
        sweep(r, rd, init, initd, quick)
        return {}
    grids = (21, 201, 2001) if quick else (21, 201, 2001, 20001)
    starts = [(np.asarray(P0, float), np.asarray(V0, float))] + perturbed_starts(K_STARTS)
    # every start's consistent values for each form (outside the timing)
    inits = [(hand_start(p, v), dk.initialize(r, fixed={"p": p, "v": v}),
              dk.initialize(rd, fixed={"p": p, "v": v})) for p, v in starts]
    cases = [("daekit plain", r, 1, None, {}), ("daekit projection", r, 1, "projection", {}),
             ("proj., every row", r, 1, "projection", {"project_output": True}),
             ("dummy derivatives", rd, 2, "dummy_derivatives", {})]
    ratios: dict = {}
    for tol in ((1e-8,) if quick else (1e-8, 1e-6)):
        print(f"\n3D pendulum, {T_END:g} s, rtol = atol = {tol:g}: CPU time (best of {ROUNDS} "
              f"interleaved rounds) and IDAS steps from the benchmark's start ('exact') and the "
              f"median over {K_STARTS} starts perturbed by 1e-15 relative ('median'); daekit's "
              "time includes reading traj['p']")
        print(f"{'points':>7} {'method':<18} | {'exact:':>6} {'steps':>6} {'cpu ms':>7} "
              f"{'x hand':>6} | {'median:':>7} {'steps':>7} {'x hand':>6} {'cpu ms':>7} "
              f"{'x hand':>6} | {'max pos err':>11} {'max |rod|':>9} {'events':>6}")
        for n in grids:
            t = np.linspace(0.0, T_END, n)
            Fr, x0, z0 = hand_integrator(t, 1e-12)
            ref = run_hand(Fr, x0, z0)[0][:, :3]
            F, _, _ = hand_integrator(t, tol)
            fns = {}
            for k, ((xh, zh), ir, idd) in enumerate(inits):
                fns["hand", k] = lambda F=F, xh=xh, zh=zh: run_hand(F, xh, zh)
                for label, rr, which, stab, kw in cases:
                    ii = ir if which == 1 else idd

                    def go(rr=rr, ii=ii, stab=stab, t=t, tol=tol, kw=kw):
                        tr = dk.simulate(rr, t, ii, rtol=tol, atol=tol, stabilization=stab,
                                         **kw)
                        return tr, tr["p"]  # the positions, as the hand form's X

                    go()  # build the integrators once
                    fns[label, k] = go
            _, out = interleaved(fns, ROUNDS)
            ks = range(1, len(inits))
            steps = {"hand": [out["hand", k][1] for k in range(len(inits))]}
            cpu = {"hand": [CPU["hand", k] for k in range(len(inits))]}
            for label, *_ in cases:
                steps[label] = [out[label, k][0].stats["steps"] for k in range(len(inits))]
                cpu[label] = [CPU[label, k] for k in range(len(inits))]
            med_s = {m: float(np.median([steps[m][k] for k in ks])) for m in steps}
            med_c = {m: float(np.median([cpu[m][k] for k in ks])) for m in cpu}
            Xh = out["hand", 0][0]
            eh = np.max(np.abs(Xh[:, :3] - ref))
            rod_h = np.max(np.abs(0.5 * (np.sum(Xh[:, :3] ** 2, axis=1) - 1)))
            print(f"{n:>7} {'hand (raw IDAS)':<18} | {'':>6} {steps['hand'][0]:>6} "
                  f"{1e3 * cpu['hand'][0]:>7.2f} {1.0:>6.2f} | {'':>7} {med_s['hand']:>7.0f} "
                  f"{1.0:>6.3f} {1e3 * med_c['hand']:>7.2f} {1.0:>6.2f} | {eh:>11.2e} "
                  f"{rod_h:>9.1e} {'':>6}")
            for label, *_ in cases:
                tr, P = out[label, 0]
                e = np.max(np.abs(P - ref))
                rod = float(np.max(np.abs(tr.invariant("rod"))))
                ev = tr.stats.get("projections") or len(tr.stats.get("selection_switches", []))
                rx, rm = cpu[label][0] / cpu["hand"][0], med_c[label] / med_c["hand"]
                ratios[label, tol, n] = (rx, rm, steps[label][0] / steps["hand"][0],
                                         med_s[label] / med_s["hand"])
                print(f"{n:>7} {label:<18} | {'':>6} {steps[label][0]:>6} "
                      f"{1e3 * cpu[label][0]:>7.2f} {rx:>6.2f} | {'':>7} {med_s[label]:>7.0f} "
                      f"{med_s[label] / med_s['hand']:>6.3f} {1e3 * med_c[label]:>7.2f} "
                      f"{rm:>6.2f} | {e:>11.2e} {rod:>9.1e} {ev:>6}")
    sweep(r, rd, init, initd, quick)
    return ratios


def verdict(ratios: dict, chain: float | None) -> None:
    """Issue 8's speed targets, each with its numbers: the verdict is taken on the medians
    over the perturbed starts (the exact start's ratio beside it, for the record)."""
    if not ratios and chain is None:
        return
    print("\nverdict (issue 8's targets; CPU time over the hand form, median over the "
          f"{K_STARTS} perturbed starts; the exact start's in brackets)")
    tols = sorted({k[1] for k in ratios})
    grids = sorted({k[2] for k in ratios})

    def line(ok, text):
        print(f"  [{'PASS' if ok else 'FAIL'}] {text}")

    for tol in tols:
        if tol != 1e-8:
            continue
        for n in grids:
            rx, rm, sx, sm = ratios["daekit plain", tol, n]
            line(rm <= 1.3 and abs(sm - 1) <= 0.1,
                 f"plain simulate <= 1.3x at rtol 1e-8, steps within 10 %, {n} points: "
                 f"{rm:.2f}x, steps {sm:.3f}x  [{rx:.2f}x, steps {sx:.3f}x]")
    for tol in tols:
        rx, rm, _, _ = ratios["daekit projection", tol, 2001]
        line(rm <= 1.5, f"projection <= 1.5x at 2001 points, rtol {tol:g}: {rm:.2f}x  "
                        f"[{rx:.2f}x]")
    for tol in tols:
        for n in grids:
            rx, rm, _, _ = ratios["dummy derivatives", tol, n]
            line(rm <= 2.0, f"dummy derivatives <= 2x, rtol {tol:g}, {n} points: {rm:.2f}x  "
                            f"[{rx:.2f}x]")
    if chain is not None:
        line(chain <= 3.0, f"500-link chain, projection within 3x of plain: {chain:.2f}x")


def sweep(r, rd, init, initd, quick: bool) -> None:
    """All three methods against the hand form at 13 tolerances, 1e-4 .. 1e-10 (half decades),
    on 21 and 2001 output points: IDAS steps, CPU-time ratios (best of ``REPEAT`` interleaved
    rounds, both sides in the same run), the largest position error against the hand form at
    rtol 1e-12; the totals over the tolerances compare the forms, not the luck of one
    tolerance (see :func:`lottery`)."""
    tols = np.geomspace(1e-4, 1e-10, 7 if quick else 13)
    cases = [("plain", r, init, None), ("projection", r, init, "projection"),
             ("dummy derivatives", rd, initd, "dummy_derivatives")]
    for n in (21, 2001):
        t = np.linspace(0.0, T_END, n)
        Fr, x0, z0 = hand_integrator(t, 1e-12)
        ref = run_hand(Fr, x0, z0)[0][:, :3]
        print(f"\ntolerance sweep, {n} output points: steps, CPU time / hand's (same run), max "
              "position error")
        print(f"{'rtol':>8} | {'hand':>5} {'ms':>5} {'err':>7} | " + " | ".join(
            f"{lab[:10]:>10} {'x hand':>6} {'err':>7}" for lab, *_ in cases))
        tot = {k: np.zeros(2) for k in ["hand"] + [c[0] for c in cases]}
        logs = {c[0]: [] for c in cases}
        for tol in tols:
            F, x0, z0 = hand_integrator(t, tol)
            fns = {"hand": lambda F=F, x0=x0, z0=z0: run_hand(F, x0, z0)}
            for label, rr, ii, stab in cases:
                def go(rr=rr, ii=ii, stab=stab, t=t, tol=tol):
                    tr = dk.simulate(rr, t, ii, rtol=tol, atol=tol, stabilization=stab)
                    return tr, tr["p"]

                go()
                fns[label] = go
            _, out = interleaved(fns, REPEAT)
            Xh, sh = out["hand"]
            eh = np.max(np.abs(Xh[:, :3] - ref))
            tot["hand"] += [sh, CPU["hand"]]
            cells = []
            for label, *_ in cases:
                tr, P = out[label]
                st = tr.stats["steps"]
                tot[label] += [st, CPU[label]]
                logs[label].append(np.log(CPU[label] / CPU["hand"]))
                cells.append(f"{st:>10} {CPU[label] / CPU['hand']:>6.2f} "
                             f"{np.max(np.abs(P - ref)):>7.1e}")
            print(f"{tol:>8.1e} | {sh:>5} {1e3 * CPU['hand']:>5.2f} {eh:>7.1e} | "
                  + " | ".join(cells))
        print(f"{'total':>8} | {int(tot['hand'][0]):>5} {1e3 * tot['hand'][1]:>5.1f} "
              f"{'':>7} | " + " | ".join(
                  f"{int(tot[lab][0]):>10} {tot[lab][1] / tot['hand'][1]:>6.2f} {'':>7}"
                  for lab, *_ in cases))
        print("over the tolerances: " + "; ".join(
            f"{lab}: steps {tot[lab][0] / tot['hand'][0]:.3f}x the hand form's, CPU time "
            f"{tot[lab][1] / tot['hand'][1]:.2f}x in total, geometric mean of the ratios "
            f"{np.exp(np.mean(logs[lab])):.2f}x, largest {np.exp(np.max(logs[lab])):.2f}x"
            for lab, *_ in cases))
    lottery(r)
    same_equations(r)


def lottery(r, draws: int = 40) -> None:
    """IDAS's step count at one tolerance is not a smooth function of its inputs: the same run
    from starts that differ by one part in 1e15 (``x0 (1 + 1e-15 N(0, 1))``, ``z0`` consistent)
    takes different numbers of steps, by up to 30 % at rtol 1e-8 for the hand form itself. Over
    ``draws`` such starts the means compare the two forms; the unperturbed start is one draw."""
    t = np.linspace(0.0, T_END, 21)
    print(f"\nsteps from {draws} starts perturbed by 1e-15 relative (21 points; hand = raw "
          "IDAS on the hand form, daekit = plain simulate)")
    print(f"{'rtol':>8} {'hand mean':>10} {'min':>5} {'max':>5} {'daekit mean':>12} {'min':>5} "
          f"{'max':>5} {'ratio of means':>15}")
    for tol in (1e-6, 1e-7, 1e-8, 1e-9):
        F, x0, z0 = hand_integrator(t, tol)
        rng = np.random.default_rng(1)
        sh, sd = [], []
        for k in range(draws):
            x = x0 * (1 + 1e-15 * rng.standard_normal(6)) if k else x0.copy()
            z = np.array([(x[3:] @ x[3:] - G * x[2]) / (x[:3] @ x[:3])])
            sh.append(run_hand(F, x, z)[1])
            sd.append(dk.simulate(r, t, np.r_[x, z], rtol=tol, atol=tol).stats["steps"])
        print(f"{tol:>8.0e} {np.mean(sh):>10.1f} {min(sh):>5} {max(sh):>5} {np.mean(sd):>12.1f} "
              f"{min(sd):>5} {max(sd):>5} {np.mean(sd) / np.mean(sh):>15.3f}")


def same_equations(r) -> None:
    """daekit's algebraic equation and the hand form's are the same function, with the same
    scaling (coefficient of the multiplier ``-|p|^2 / m``), to rounding: their values and
    Jacobians at 10000 random points (``|p| = 1``, ``v`` normal, ``z`` in [0, 30])."""
    p, v, z = ca.SX.sym("p", 3), ca.SX.sym("v", 3), ca.SX.sym("z")
    hand = -G * p[2] - z * ca.dot(p, p) + ca.dot(v, v)
    w = ca.vertcat(p, v, z)
    Fh = ca.Function("h", [w], [hand, ca.jacobian(hand, w)]).map(10000)
    wd = ca.vertcat(r.x, r.z)
    Fd = ca.Function("d", [wd, r.p, r.u], [r.alg, ca.jacobian(r.alg, wd)]).map(10000)
    rng = np.random.default_rng(0)
    P = rng.normal(size=(3, 10000))
    P /= np.linalg.norm(P, axis=0)
    W = np.vstack([P, rng.normal(size=(3, 10000)), rng.uniform(0, 30, size=(1, 10000))])
    ah, jh = (np.asarray(a) for a in Fh(W))
    ad, jd = (np.asarray(a) for a in Fd(W, np.repeat(r.p_values[:, None], 10000, 1),
                                        np.zeros((r.nu, 10000))))
    print(f"daekit's alg against the hand form's at 10000 random points: max |difference| "
          f"{np.max(np.abs(ad - ah)):.1e} (values up to {np.max(np.abs(ah)):.0f}), of the "
          f"Jacobians {np.max(np.abs(jd - jh)):.1e}: the same equation to rounding")


def part2(quick: bool) -> float | None:
    N = 100 if quick else 500
    r = dk.reduce_index(dk.examples.planar_chain(N))
    ang = 0.3 + 0.2 * np.sin(np.arange(N))
    q = np.cumsum(np.column_stack([np.sin(ang), -np.cos(ang)]), axis=0).ravel()
    init = dk.initialize(r, fixed={"q": q, "v": np.zeros(2 * N)})
    t = np.linspace(0.0, 1.0, 101)
    print(f"\nplanar chain of {N} links ({r.nx} states, {r.nz} algebraic), 1 s, 101 points, "
          "rtol = atol = 1e-6")
    print(f"{'method':<18} {'wall s':>8} {'x plain':>8} {'steps':>7} {'projections':>12} "
          f"{'max |inv|':>10}")
    base = None
    for stab in (None, "projection"):
        def go(stab=stab):
            return dk.simulate(r, t, init, rtol=1e-6, atol=1e-6, stabilization=stab)

        go()
        tw, tr = best_of(go, 2)
        base = base or tw
        ratio = tw / base
        print(f"{stab or 'plain':<18} {tw:>8.3f} {tw / base:>8.2f} {tr.stats['steps']:>7} "
              f"{tr.stats.get('projections', 0):>12} {np.max(np.abs(tr.invariants)):>10.1e}")
    from daekit.simulate.projection import Projector

    P = Projector(r)
    x = init.x0 * (1 + 1e-6)
    tp, _ = best_of(lambda: P(0.0, x, init.z0, np.zeros(r.nu), r.p_values), 3)
    print(f"one projection of the {N}-link chain (sparse KKT, Gauss-Newton): {1e3 * tp:.1f} ms")
    return ratio if N == 500 else None


def main() -> None:
    quick = "--quick" in sys.argv
    ratios = part1(quick) if "--chain" not in sys.argv else {}
    chain = part2(quick) if "--sweep" not in sys.argv else None
    verdict(ratios, chain)


if __name__ == "__main__":
    main()
