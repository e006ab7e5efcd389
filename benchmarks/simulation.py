"""Benchmark: the 3D pendulum (lecture L3), 10 s, rtol = atol = 1e-8, three ways in one run.

1. ``daekit.simulate`` on ``reduce_index(pendulum3d())`` (initialization excluded: it is done
   once before the timing; reduction excluded too);
2. raw ``casadi.integrator("idas")`` on the same reduced equations (same x0, z0, grid);
3. SciPy ``solve_ivp(method="Radau")`` on the ODE form: state (p, v), and inside the right-hand
   side the 4x4 KKT system ``[m I, p; p^T, 0] [v'; z] = [u - m g e3; -v.v]`` solved for v', z.

Each is timed as the best of ``REPEAT`` runs. daekit builds its integrator on the first call
and reuses it on later calls on the same system; raw IDAS is timed both ways: built and run,
and run only (built once). The ratio compares like with like: daekit's reused call against
the raw integrator's call alone, and daekit's first call against raw build + run. Prints a
table with wall times, steps, the final-point difference to daekit, the max rod drift, and
the ratio daekit / raw IDAS (target <= 1.3).

Run: ``python benchmarks/simulation.py``
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
from scipy.integrate import solve_ivp

import daekit as dk
from daekit.initialize import initialize
from daekit.reduction import reduce_index
from daekit.simulate import simulate

REPEAT = 5
T_END, N_OUT, TOL = 10.0, 1001, 1e-8
M, L, G = 1.0, 1.0, 9.81


def best_of(fn, repeat=REPEAT):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    r = reduce_index(dk.examples.pendulum3d())
    t = np.linspace(0.0, T_END, N_OUT)
    p0, v0 = [0.6, 0.0, -0.8], [0.0, 1.5, 0.0]
    init = initialize(r, fixed={"p": p0, "der(p)": v0})
    x0, z0 = init.x0, init.z0
    pv = np.concatenate([r.p_values, np.zeros(r.nu)])  # parameters, then the inputs u = 0

    # 1. daekit (the first call builds the integrator; later calls on the same system reuse it)
    t0 = time.perf_counter()
    simulate(r, t, init, rtol=TOL, atol=TOL)
    t_cold = time.perf_counter() - t0
    t_dk, traj = best_of(lambda: simulate(r, t, init, rtol=TOL, atol=TOL))
    p_dk = traj["p"][-1]

    # 2. raw CasADi IDAS on the same equations
    def raw():
        F = ca.integrator("raw", "idas", r.dae_dict(), 0.0, list(t[1:]),
                          {"abstol": TOL, "reltol": TOL, "max_num_steps": 100000})
        res = F(x0=x0, z0=z0, p=pv)
        return F, np.asarray(res["xf"])

    t_raw_build, (F, xf) = best_of(raw)
    # the fair comparison: raw IDAS built once, only the integration timed
    t_raw, res = best_of(lambda: F(x0=x0, z0=z0, p=pv))
    xf = np.asarray(res["xf"])
    ip = [r.x_names.index(f"p[{i}]") for i in range(3)]
    p_raw = xf[ip, -1]
    raw_steps = F.stats()["nsteps"]

    # 3. SciPy Radau on the ODE form (KKT solve in the right-hand side)
    def rhs(_t, y):
        p, v = y[:3], y[3:]
        K = np.zeros((4, 4))
        K[:3, :3] = M * np.eye(3)
        K[:3, 3] = p
        K[3, :3] = p
        b = np.r_[-M * G * np.array([0.0, 0.0, 1.0]), -v @ v]
        sol = np.linalg.solve(K, b)
        return np.r_[v, sol[:3]]

    y0 = np.r_[p0, v0]
    t_sp, sp = best_of(lambda: solve_ivp(rhs, (0.0, T_END), y0, method="Radau", t_eval=t,
                                         rtol=TOL, atol=TOL), repeat=1)
    p_sp = sp.y[:3, -1]

    def drift(P):
        return float(np.max(np.abs(0.5 * (np.sum(P * P, axis=1) - L**2))))

    rows = [
        ("daekit.simulate, first call (build)", t_cold, traj.stats["steps"], 0.0,
         drift(traj["p"])),
        ("daekit.simulate (IDAS)", t_dk, traj.stats["steps"], 0.0, drift(traj["p"])),
        ("raw casadi IDAS, build + run", t_raw_build, raw_steps, float(np.max(np.abs(p_raw - p_dk))),
         drift(xf[ip].T)),
        ("raw casadi IDAS, run (built once)", t_raw, raw_steps, float(np.max(np.abs(p_raw - p_dk))),
         drift(xf[ip].T)),
        ("scipy solve_ivp Radau (ODE form)", t_sp, int(sp.nfev), float(np.max(np.abs(p_sp - p_dk))),
         drift(sp.y[:3].T)),
    ]
    print(f"3D pendulum, {T_END:g} s, {N_OUT} output points, rtol = atol = {TOL:g}")
    print(f"{'method':36s} {'wall [ms]':>10s} {'steps/nfev':>11s} {'|p - p_daekit|':>15s} "
          f"{'max |c|':>10s}")
    for name, wall, steps, dp, c in rows:
        print(f"{name:36s} {1e3 * wall:10.2f} {steps:11d} {dp:15.2e} {c:10.2e}")
    ratio = t_dk / t_raw
    print(f"daekit / raw IDAS, both built once = {ratio:.2f} (target <= 1.3): "
          f"{'OK' if ratio <= 1.3 else 'MISSED'}")
    print(f"daekit first call / raw IDAS build + run = {t_cold / t_raw_build:.2f}")


if __name__ == "__main__":
    main()
