"""The minimal index-1 form against the hand-written lecture form (issue 8, item 4).

``reduce_index`` substitutes every derivative an equation gives explicitly with a constant or
parameter-only coefficient: ``p' = v`` and ``m v' = u - m g e3 - z p``. The 3D pendulum then
reduces to ``x = (p, v)``, ``z = (z)``, ``0 = p.a + v.v`` with ``a = (u - m g e3 - z p)/m``,
the form an expert writes by hand (lecture L3). The KKT form (``eliminate="states"``, daekit's
form before: ``z = (v', z)``, ``0 = [m v' - f; p.v' + v.v]``) is shown alongside.

Part 1, simulation: the same raw CasADi IDAS call (``casadi.integrator("idas")``, one output
time, built once, best of 3) on

- ``hand``: the lecture's index-1 form written by hand in CasADi;
- ``minimal``: daekit's reduction, ``r.dae_dict()``;
- ``kkt``: daekit's reduction with ``eliminate="states"``;

for the 3D pendulum (10 s from ``p = (sin 0.6, 0, -cos 0.6)``, ``v = (0, 1.5, 0)``) and the
planar chain of N links (1 s from rest, angles ``0.3 + 0.2 sin k``), at rtol = atol =
1e-6, 1e-8, 1e-10: IDAS steps, wall time, and the largest difference of the final state from
the hand form's.

Part 2, optimal control: IPOPT iterations and wall time of
:func:`daekit.examples.ocp_examples.pendulum3d_periodic_ocp` (a periodic orbit, 30 Radau
intervals of degree 3) transcribed from the minimal form, from the KKT form and from the
hand-written form (a ReducedDAE built by hand), from the same guess.

Run: ``python benchmarks/minimal_form.py [--quick]``.
"""

from __future__ import annotations

import sys
import time

import casadi as ca
import numpy as np

import daekit as dk
from daekit.reduced import ReducedDAE

G = 9.81
REPEAT = 3


# ----------------------------------------------------------------------------- hand forms
def hand_pendulum3d(m: float = 1.0, L: float = 1.0, g: float = G) -> ReducedDAE:
    """Lecture L3 in its minimal index-1 form by hand: x = (p, v), z = (lambda)."""
    t = ca.SX.sym("t")
    p, v, u, lam = ca.SX.sym("p", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 3), ca.SX.sym("z")
    a = (u - m * g * ca.DM([0, 0, 1]) - lam * p) / m
    alg = ca.dot(p, a) + ca.dot(v, v)
    inv = ca.vertcat((ca.dot(p, p) - L**2) / 2, ca.dot(p, v))
    names = {f"p[{i}]": p[i] for i in range(3)}
    names.update({f"v[{i}]": v[i] for i in range(3)})
    names.update({f"der(p)[{i}]": v[i] for i in range(3)})
    names.update({f"der(v)[{i}]": a[i] for i in range(3)})
    names["z"] = lam
    names.update({f"u[{i}]": u[i] for i in range(3)})
    return ReducedDAE(
        t, ca.vertcat(p, v), lam, u, ca.SX(0, 1), ca.vertcat(v, a), alg, inv,
        ["rod", "d/dt rod"], [f"p[{i}]" for i in range(3)] + [f"v[{i}]" for i in range(3)],
        ["z"], [f"u[{i}]" for i in range(3)], [], np.zeros(0), names, control_names=["u"],
        method="hand",
    )


def hand_chain(N: int, g: float = G) -> dict:
    """The planar chain's minimal index-1 form by hand (vectorized SX)."""
    q, v, lam = ca.SX.sym("q", 2 * N), ca.SX.sym("v", 2 * N), ca.SX.sym("lam", N)
    Q = ca.reshape(q, 2, N)
    V = ca.reshape(v, 2, N)
    D = Q - ca.horzcat(ca.DM.zeros(2, 1), Q[:, : N - 1])  # link vectors d_k
    DV = V - ca.horzcat(ca.DM.zeros(2, 1), V[:, : N - 1])
    Lr = ca.repmat(lam.T, 2, 1) * D  # lam_k d_k
    nxt = ca.horzcat(Lr[:, 1:], ca.DM.zeros(2, 1))  # lam_{k+1} d_{k+1}
    A = -Lr + nxt - ca.repmat(ca.DM([0, g]), 1, N)
    DA = A - ca.horzcat(ca.DM.zeros(2, 1), A[:, : N - 1])
    alg = ca.sum1(D * DA).T + ca.sum1(DV * DV).T
    return {"x": ca.vertcat(q, v), "z": lam, "ode": ca.vertcat(v, ca.vec(A)), "alg": alg}


# ----------------------------------------------------------------------------- simulation
def idas_run(dae: dict, x0, z0, p, t_end: float, tol: float):
    F = ca.integrator("F", "idas", dae, 0.0, [t_end],
                      {"abstol": tol, "reltol": tol, "max_num_steps": 10**6})
    best, res = np.inf, None
    for _ in range(REPEAT):
        t0 = time.perf_counter()
        res = F(x0=x0, z0=z0, p=p)
        best = min(best, time.perf_counter() - t0)
    return int(F.stats()["nsteps"]), best, np.asarray(res["xf"]).ravel()


def chain_start(N: int):
    k = np.arange(N)
    th = 0.3 + 0.2 * np.sin(k)
    q = np.cumsum(np.column_stack([np.sin(th), -np.cos(th)]), axis=0).ravel()
    return q, np.zeros(2 * N)


def simulation_rows(sizes, tols) -> list[dict]:
    rows = []
    cases = [("pendulum3d", None)] + [(f"chain N={N}", N) for N in sizes]
    for label, N in cases:
        if N is None:
            model = dk.examples.pendulum3d()
            a = 0.6
            fixed = {"p": [np.sin(a), 0.0, -np.cos(a)], "v": [0.0, 1.5, 0.0]}
            hr = hand_pendulum3d()
            hand = hr.dae_dict()
            t_end = 10.0
        else:
            model = dk.examples.planar_chain(N)
            q0, v0 = chain_start(N)
            fixed = {"q": q0, "v": v0}
            hand = hand_chain(N)
            t_end = 1.0
        rm = dk.reduce_index(model)
        rk = dk.reduce_index(model, eliminate="states")
        im, ik = dk.initialize(rm, fixed=fixed), dk.initialize(rk, fixed=fixed)
        pm = np.r_[rm.p_values, np.zeros(rm.nu)]
        pk = np.r_[rk.p_values, np.zeros(rk.nu)]
        if N is None:
            ph = np.zeros(3)  # u = 0
        else:
            hand["p"] = ca.SX(0, 1)
            ph = np.zeros(0)
        for tol in tols:
            sh, th, xh = idas_run(hand, im.x0, im.z0, ph, t_end, tol)
            sm, tm, xm = idas_run(rm.dae_dict(), im.x0, im.z0, pm, t_end, tol)
            sk, tk, xk = idas_run(rk.dae_dict(), ik.x0, ik.z0, pk, t_end, tol)
            rows.append({"case": label, "rtol": tol, "hand_steps": sh, "hand_s": th,
                         "minimal_steps": sm, "minimal_s": tm, "kkt_steps": sk, "kkt_s": tk,
                         "minimal_diff": float(np.max(np.abs(xm - xh))),
                         "kkt_diff": float(np.max(np.abs(xk - xh)))})
    return rows


def print_simulation(rows) -> None:
    print("IDAS (raw CasADi, same call) on the hand-written form, daekit's minimal form and the "
          "KKT form")
    print(f"{'case':>14} {'rtol':>6} | {'hand':>7} {'[ms]':>8} | {'minimal':>7} {'[ms]':>8} "
          f"{'x/hand':>7} {'diff':>8} | {'kkt':>7} {'[ms]':>8} {'x/hand':>7} {'diff':>8}")
    for r in rows:
        print(f"{r['case']:>14} {r['rtol']:6.0e} | {r['hand_steps']:7d} {1e3 * r['hand_s']:8.2f} | "
              f"{r['minimal_steps']:7d} {1e3 * r['minimal_s']:8.2f} "
              f"{r['minimal_s'] / r['hand_s']:7.2f} {r['minimal_diff']:8.1e} | "
              f"{r['kkt_steps']:7d} {1e3 * r['kkt_s']:8.2f} {r['kkt_s'] / r['hand_s']:7.2f} "
              f"{r['kkt_diff']:8.1e}")


# ----------------------------------------------------------------------------- optimal control
def periodic_ocp(system, u, intervals: int = 30):
    from daekit.ocp import OCP

    a = np.pi / 6
    ocp = OCP(system, t_final=2.0, intervals=intervals, degree=3)
    ocp.minimize(integral=ca.sumsqr(u))
    ocp.initial({"p": [np.sin(a), 0.0, -np.cos(a)]})
    ocp.periodic(["p", "v"])
    ocp.set_guess({"v": [0.0, 1.5, 0.0]})
    return ocp


def ocp_rows() -> list[dict]:
    model = dk.examples.pendulum3d()
    u = model.variables["u"].sym
    rk = dk.reduce_index(model, eliminate="states")
    hr = hand_pendulum3d()
    out = []
    for label, system, uu in (("minimal (default)", model, u), ("kkt", rk, u),
                              ("hand", hr, hr.u)):
        t0 = time.perf_counter()
        sol = periodic_ocp(system, uu).solve()
        wall = time.perf_counter() - t0
        out.append({"form": label, "iterations": int(sol.stats.get("iter_count", -1)),
                    "objective": float(sol.objective), "success": bool(sol.success),
                    "wall_s": wall})
    return out


def print_ocp(rows) -> None:
    print("\nPeriodic 3D pendulum OCP (30 Radau intervals, degree 3), IPOPT from the same guess")
    print(f"{'form':>18} {'iterations':>10} {'objective':>14} {'wall [s]':>9} {'ok':>4}")
    for r in rows:
        print(f"{r['form']:>18} {r['iterations']:10d} {r['objective']:14.8f} {r['wall_s']:9.2f} "
              f"{'yes' if r['success'] else 'no':>4}")


def main(argv: list[str]) -> None:
    quick = "--quick" in argv
    sizes = (20,) if quick else (20, 100, 500)
    tols = (1e-6, 1e-8) if quick else (1e-6, 1e-8, 1e-10)
    print_simulation(simulation_rows(sizes, tols))
    print_ocp(ocp_rows())


if __name__ == "__main__":
    main(sys.argv[1:])
