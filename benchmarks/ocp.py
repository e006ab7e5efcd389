"""daekit's OCP against a hand-written, vectorized casadi.Opti collocation of the same NLP.

Three problems, each stated on the index-3 Cartesian model as a user writes it:

- ``swing``: the planar pendulum with a tangential force, rest at the bottom to rest at 30
  degrees in 2 s, min int u^2 (Radau IIA degree 3, piecewise constant controls);
- ``betts``: Betts (2010) problem 10.103, min int u^2 on [0, 3], Radau degree 3, 100
  intervals, polynomial controls (published optimum 12.8738850; angle form 12.8738889);
- ``cartpole``: the cart-pole swing-up, hanging at rest to upright at rest in 2 s, min
  int F^2, 50 intervals, piecewise constant controls.

The Opti side is what an expert writes: the same index-1 system (daekit's reduction, taken as
CasADi functions), the states at all collocation points as one matrix, the dynamics and
algebraic equations evaluated with ``Function.map`` over all collocation points and the
collocation equations as d matrix products, the invariants at t = 0, the same independent
boundary conditions, the same initial guess (daekit's, sampled on the grid), built both with
``expand=True`` (SX) and without (MX, the mapped call kept; cheaper to build), the faster of
the two counting, and daekit's IPOPT options (``mumps_permuting_scaling = 0``, ``max_iter = 1000``). daekit's
time is everything from ``OCP(...)`` (model reduction, boundary analysis, guess, transcription,
IPOPT) to the solution; Opti's is building and solving its NLP (its guess is given). Each side
runs ``REPEAT`` times alternately; the best wall times are shown. A second table splits
daekit's CPU time into its stages (model and reduction, compile, default guess, boundary
analysis, NLP: transcription, nlpsol, IPOPT, solution) beside Opti's build + solve; daekit's
NLP stage differs from Opti's in giving IPOPT the derivatives in closed form
(:data:`daekit.ocp.collocation.STRUCTURED`).

Run: ``python benchmarks/ocp.py [REPEAT]``
"""

from __future__ import annotations

import sys
import time

import casadi as ca
import numpy as np

import daekit as dk
from daekit.examples.ocp_examples import (
    betts_pendulum_ocp,
    cartpole_ocp,
    pendulum_with_tangential_force,
)
from daekit.ocp import OCP
from daekit.ocp.boundary import analyze
from daekit.ocp.collocation import radau_coefficients
from daekit.ocp.guess import make_guess
from daekit.ocp.run import solve_once

IPOPT = {"print_level": 0, "sb": "yes", "mumps_permuting_scaling": 0, "max_iter": 1000}


# ---------------------------------------------------------------------------- the problems
def swing():
    m = pendulum_with_tangential_force(L=1.0, g=9.81)
    u = m.variables["u"].sym
    ocp = OCP(m, t_final=2.0, intervals=100, degree=3)
    ocp.minimize(integral=u**2)
    ocp.initial({"p": [0.0, -1.0], "v": [0.0, 0.0]})
    ocp.final({"p": [np.sin(np.pi / 6), -np.cos(np.pi / 6)], "v": [0.0, 0.0]})
    return ocp


betts = betts_pendulum_ocp


def cartpole():
    return cartpole_ocp(final_all=True)


# ---------------------------------------------------------------------------- hand-written Opti
def opti_collocation(prob, sol, guess, expand: bool = True):
    """The expert's Opti NLP of the same discretization as daekit's solution ``sol``: the
    reduced system of ``prob``, the boundary conditions daekit imposed (``sol.boundary``: kept
    equalities, branch inequalities, pins),
    daekit's guess. Returns (objective, wall time, iterations)."""
    a = prob.aug
    N, d = prob.intervals, prob.degree
    T = prob.T_fixed
    tau, C, b, e0 = radau_coefficients(d)
    h = T / N
    t0, c0 = time.perf_counter(), time.process_time()
    opti = ca.Opti()
    nx, nz, nw = a.nx, a.nz, a.nw
    M = N * d
    X = opti.variable(nx, M + 1)
    Z = opti.variable(nz, M + 1)  # column 0: z at t = 0
    poly = prob.control_mode == "polynomial"
    U = opti.variable(nw, M if poly else N)
    P = ca.DM(prob.p_values)
    t_col = np.concatenate([[0.0], (np.arange(N).reshape(-1, 1) + tau[1:]).ravel() * h])
    Ucol = U if poly else ca.horzcat(*[ca.repmat(U[:, k], 1, d) for k in range(N)])
    f = ca.Function("f", [a.t, a.x, a.z, a.w, a.p], [a.ode, a.alg, prob.lagrange])
    ode, alg, L = f.map(M)(t_col[1:].reshape(1, -1), X[:, 1:], Z[:, 1:], Ucol,
                           ca.repmat(P, 1, M))
    for j in range(1, d + 1):
        xp = sum(float(C[r, j]) * X[:, r:r + M - d + 1:d] for r in range(d + 1))
        opti.subject_to(xp - h * ode[:, j - 1::d] == 0)
    opti.subject_to(ca.vec(alg) == 0)
    W0 = Ucol[:, 0] if not poly else sum(float(e0[j]) * U[:, j] for j in range(d))
    alg0 = ca.Function("alg0", [a.t, a.x, a.z, a.w, a.p], [a.alg, a.inv])
    g0, inv0 = alg0(0.0, X[:, 0], Z[:, 0], W0, P)
    opti.subject_to(g0 == 0)
    opti.subject_to(inv0 == 0)
    # the same boundary conditions daekit imposed (kept rows and pins)
    ba = sol.boundary
    v0 = ca.vertcat(X[:, 0], Z[:, 0], W0)
    vT = ca.vertcat(X[:, -1], Z[:, -1], Ucol[:, -1])
    rows = prob.bc_fun(v0, vT, P, T)
    for i in ba.kept:
        opti.subject_to(rows[i] == 0)
    if sol.stats.get("boundary_selectors_imposed"):
        for i, lo, hi in ba.selectors:  # daekit's branch inequalities: the same NLP
            opti.subject_to(opti.bounded(lo, rows[i], hi))
    for kind, i, val, _ in ba.pins:
        opti.subject_to((v0 if kind == "initial" else vT)[i] == val)
    for kind, V_ in (("x", X), ("z", Z), ("w", U)):
        lb, ub = prob.lb[kind], prob.ub[kind]
        for i in range(lb.size):
            if np.isfinite(lb[i]):
                opti.subject_to(V_[i, :] >= lb[i])
            if np.isfinite(ub[i]):
                opti.subject_to(V_[i, :] <= ub[i])
    J = h * sum(float(b[j - 1]) * ca.sum2(L[:, j - 1::d]) for j in range(1, d + 1))
    opti.minimize(J)
    gx, gz, gw = guess.fun(t_col * (guess.T / T))
    opti.set_initial(X, gx)
    opti.set_initial(Z, gz)
    if poly:
        opti.set_initial(U, gw[:, 1:])
    else:
        opti.set_initial(U, gw[:, 1:].reshape(nw, N, d).mean(axis=2))
    opti.solver("ipopt", {"print_time": False, "expand": expand}, dict(IPOPT))
    res = opti.solve()
    wall = (time.perf_counter() - t0, time.process_time() - c0)
    return float(res.value(J)), wall, int(opti.stats()["iter_count"])


def run_daekit(make):
    t0, c0 = time.perf_counter(), time.process_time()
    ocp = make()
    sol = ocp.solve()
    return sol, (time.perf_counter() - t0, time.process_time() - c0), ocp


def run_daekit_given(make, guess):
    """daekit with the guess handed over (as a Trajectory on the grid), like Opti's."""
    ocp = make()
    prob = ocp.compile()
    a = prob.aug
    t = np.linspace(0.0, guess.T, 2001)
    X, Z, W = guess.fun(t)
    vals = {**dict(zip(a.x_names, X)), **dict(zip(a.z_names, Z)), **dict(zip(a.w_names, W))}
    traj = dk.Trajectory(t, vals)
    t0, c0 = time.perf_counter(), time.process_time()
    ocp = make()
    sol = ocp.solve(guess=traj)
    return sol, (time.perf_counter() - t0, time.process_time() - c0)


def stages(make, repeat: int = 3) -> dict:
    """daekit's CPU seconds per stage (best of ``repeat``): the model and its reduction
    (``OCP(...)``), ``compile``, the default guess, the boundary analysis, and the NLP
    (transcription, nlpsol, IPOPT, the solution and its report)."""
    best: dict = {}
    for _ in range(repeat):
        c = time.process_time
        t = [c()]
        ocp = make()
        t.append(c())
        prob = ocp.compile()
        t.append(c())
        g = make_guess(prob, None)
        t.append(c())
        ba = analyze(prob, g)
        t.append(c())
        solve_once(prob, g, ba, "drop", True, time.perf_counter())
        t.append(c())
        for k, dt in zip(("model+reduction", "compile", "guess", "analysis", "NLP"),
                         np.diff(t)):
            best[k] = min(best.get(k, np.inf), dt)
    return best


def main(repeat: int = 3) -> None:
    run_daekit(swing)  # load IPOPT once so that neither side pays for it
    rows = []
    for name, make in (("swing", swing), ("betts", betts), ("cartpole", cartpole)):
        best_dk, best_op, best_gv = (np.full(2, np.inf) for _ in range(3))
        for _ in range(repeat):
            sol, wall, ocp = run_daekit(make)
            prob = ocp.compile()
            guess = make_guess(prob, None)
            J_op, wall_op, it_op = opti_collocation(prob, sol, guess, expand=True)
            # the expert also tries MX without expansion (cheaper to build, slower to run)
            # and keeps the faster: the best of both counts
            _, wall_mx, _ = opti_collocation(prob, sol, guess, expand=False)
            wall_op = np.minimum(wall_op, wall_mx)
            given, wall_gv = run_daekit_given(make, guess)
            best_dk, best_op = np.minimum(best_dk, wall), np.minimum(best_op, wall_op)
            best_gv = np.minimum(best_gv, wall_gv)
        assert sol.success, sol.report
        st = stages(make, repeat)
        rel = abs(sol.objective - J_op) / abs(J_op)
        rows.append((name, sol.objective, J_op, rel, sol.stats["iter_count"], it_op, best_dk,
                     best_op, best_gv, given.stats["iter_count"], st))
    print(f"{'problem':9s} {'daekit J':>16s} {'Opti J':>16s} {'rel diff':>9s} {'it dk':>6s} "
          f"{'it Opti':>7s} {'daekit s':>9s} {'Opti s':>8s} {'ratio':>6s} {'dk CPU':>7s} "
          f"{'Opti CPU':>8s} {'CPU ratio':>9s} "
          f"{'given: it':>9s} {'ratio':>6s} {'CPU':>5s}")
    for name, Jd, Jo, rel, itd, ito, td, to, tg, itg, _ in rows:
        print(f"{name:9s} {Jd:16.10f} {Jo:16.10f} {rel:9.1e} {itd:6d} {ito:7d} {td[0]:9.3f} "
              f"{to[0]:8.3f} {td[0] / to[0]:6.2f} {td[1]:7.3f} {to[1]:8.3f} {td[1] / to[1]:9.2f} "
              f"{itg:9d} "
              f"{tg[0] / to[0]:6.2f} {tg[1] / to[1]:5.2f}")
    print()
    keys = ("model+reduction", "compile", "guess", "analysis", "NLP")
    print(f"{'CPU s':9s} " + " ".join(f"{k:>15s}" for k in keys) + f" {'Opti':>8s}")
    for name, *_, to, _tg, _itg, st in rows:
        print(f"{name:9s} " + " ".join(f"{st[k]:15.4f}" for k in keys) + f" {to[1]:8.4f}")
    print("daekit: everything from OCP(...) to the solution; Opti: build + solve of the same "
          "NLP, vectorized, the faster of expand=True (SX) and MX, daekit's guess and IPOPT "
          "options (target ratio <= 1.0);"
          " 'given': daekit handed the same guess as Opti (a Trajectory), no guess simulation")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
