"""daekit's OCP against a hand-written, vectorized casadi.Opti collocation of the same NLP.

Three problems, each stated on the index-3 Cartesian model as a user writes it:

- ``swing``: the planar pendulum with a tangential force, rest at the bottom to rest at 30
  degrees in 2 s, min int u^2 (Radau IIA degree 3, piecewise constant controls);
- ``betts``: Betts (2010) problem 10.103, min int u^2 on [0, 3], Radau degree 3, 100
  intervals, polynomial controls (published optimum 12.8738850; angle form 12.8738889);
- ``cartpole``: the cart-pole swing-up, hanging at rest to upright at rest in 2 s, min
  int F^2, 50 intervals, piecewise constant controls.

The Opti side is what an expert writes: the same index-1 system (daekit's reduction, taken as
CasADi functions: an expert does the index reduction on paper, at no run time), the states at
all collocation points as one matrix, the dynamics and algebraic equations evaluated with
``Function.map`` over all collocation points and the collocation equations as d matrix
products, the invariants at t = 0, the same independent boundary conditions (also picked on
paper), built both with ``expand=True`` (SX) and without (MX, the mapped call kept; cheaper
to build), the faster of the two counting, and daekit's IPOPT options
(``mumps_permuting_scaling = 0``, ``max_iter = 1000``).

Opti starts from either of two guesses, in two labeled columns:

- **the expert's own guess** (the fair alternative; the target is judged on it): the angle
  linear in time between the end states, mapped onto the circle (Cartesian positions, the
  velocities its time derivative), the multiplier from statics (the rod force that holds
  each configuration at rest), the control zero (the cart-pole's ``F`` from statics too: the
  force that holds the cart). See :func:`swing_expert_guess`, :func:`betts_expert_guess`,
  :func:`cartpole_expert_guess`. These are the best, per row, of 12 simple variants tried
  (angle linear or smoothstep; control zero or from statics; multiplier from statics, from
  the radial balance with the centripetal term, or constant at its hanging value), counted in
  IPOPT iterations to daekit's optimum; several others fail or end at far worse local optima
  on Betts and the cart-pole (the table is in the round-6 report);
- **daekit's default guess** (:func:`daekit.ocp.guess.make_guess`, sampled on the grid), as
  before: the comparison of the two NLP stages alone.

daekit's time is everything from ``OCP(...)`` (model reduction, boundary analysis, guess,
transcription, IPOPT) to the solution; Opti's is building its NLP, evaluating its guess and
solving. Each side runs ``REPEAT`` times alternately; the best wall and CPU times are shown.
A third table splits daekit's CPU time into its stages (model and reduction, compile,
default guess, boundary analysis, NLP: transcription, nlpsol, IPOPT, solution) beside Opti's;
daekit's NLP stage differs from Opti's in giving IPOPT the derivatives in closed form
(:data:`daekit.ocp.collocation.STRUCTURED`). The verdict line judges the target on the CPU
ratio against Opti from the expert's guess, provided that Opti reaches daekit's optimum (to
1e-8 relative), and prints the ratio against Opti handed daekit's guess beside it.

Run: ``python benchmarks/ocp.py [REPEAT]``
"""

from __future__ import annotations

import sys
import time
from types import SimpleNamespace

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


# ---------------------------------------------------------------------------- the expert's guesses
def _arc(t, T, th0, th1):
    """An angle linear in time from ``th0`` to ``th1`` on [0, T]: (angle, its constant rate)."""
    return th0 + (th1 - th0) * t / T, np.full_like(t, (th1 - th0) / T)


def swing_expert_guess(t):
    """The swing's guess as an expert writes it: the angle ``th`` linear in time from 0
    (hanging) to 30 degrees, ``p = L (sin th, -cos th)``, ``v = p'``; the multiplier from
    statics (the rod force that holds ``p`` at rest: ``z = g cos th / L``); ``u = 0``."""
    L, g = 1.0, 9.81
    th, om = _arc(t, 2.0, 0.0, np.pi / 6)
    return {"p[0]": L * np.sin(th), "p[1]": -L * np.cos(th), "v[0]": L * om * np.cos(th),
            "v[1]": L * om * np.sin(th), "z": g * np.cos(th) / L, "u": 0 * t}


def betts_expert_guess(t):
    """Betts 10.103's guess as an expert writes it: the angle linear in time from the
    horizontal start (``x, y = 1, 0``) to hanging (``0, -1``), ``x = cos th``, ``y = sin th``
    and their time derivatives; the multiplier from statics (``lam = -g y / 2``, which holds
    the mass at rest on the rod); ``u = 0``."""
    g = 9.81
    th, om = _arc(t, 3.0, 0.0, -np.pi / 2)
    return {"x": np.cos(th), "der(x)": -om * np.sin(th), "y": np.sin(th),
            "der(y)": om * np.cos(th), "lam": -g * np.sin(th) / 2, "u": 0 * t}


def cartpole_expert_guess(t):
    """The cart-pole's guess as an expert writes it: the cart at rest at 0, the pole's angle
    linear in time from 0 (hanging) to pi (upright), the tip ``p = (L sin th, -L cos th)`` and
    ``der(p)`` its time derivative; the multiplier and the force from statics (``lam = m g cos
    th / (2 L)`` holds the tip on the rod at rest, ``F = -2 lam (p_0 - s)`` the cart)."""
    from daekit.examples.ocp_examples import CARTPOLE

    mp, L, g = CARTPOLE["m"], CARTPOLE["L"], CARTPOLE["g"]
    th, om = _arc(t, CARTPOLE["T"], 0.0, np.pi)
    zero = np.zeros_like(t)
    lam = mp * g * np.cos(th) / (2 * L)
    return {"s": zero, "der(s)": zero, "p[0]": L * np.sin(th), "p[1]": -L * np.cos(th),
            "der(p)[0]": L * om * np.cos(th), "der(p)[1]": L * om * np.sin(th), "lam": lam,
            "F": -2 * lam * L * np.sin(th)}


EXPERT = {"swing": swing_expert_guess, "betts": betts_expert_guess,
          "cartpole": cartpole_expert_guess}


def by_names(a, values_of):
    """``t -> (X, Z, W)`` in the reduced system's order from a ``t -> {name: values}``."""
    def fun(t):
        v = values_of(np.asarray(t, float))
        return tuple(np.array([v[n] for n in names]).reshape(len(names), -1)
                     for names in (a.x_names, a.z_names, a.w_names))
    return fun


# ---------------------------------------------------------------------------- hand-written Opti
def opti_collocation(prob, sol, guess, expand: bool = True):
    """The expert's Opti NLP of the same discretization as daekit's solution ``sol``: the
    reduced system of ``prob``, the boundary conditions daekit imposed (``sol.boundary``: kept
    equalities, branch inequalities, pins), started from ``guess`` (anything with ``fun: t ->
    (X, Z, W)`` and ``T``: daekit's guess or the expert's, evaluated inside the timed part).
    Returns (objective, (wall, CPU) time, iterations, IPOPT's success)."""
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
    try:
        res = opti.solve()
    except RuntimeError:  # IPOPT did not succeed: the last iterate
        res = opti.debug
    wall = (time.perf_counter() - t0, time.process_time() - c0)
    return (float(res.value(J)), wall, int(opti.stats()["iter_count"]),
            bool(opti.stats()["success"]))


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
        best = {k: np.full(2, np.inf) for k in ("dk", "ex", "op", "gv")}
        for _ in range(repeat):
            sol, wall, ocp = run_daekit(make)
            prob = ocp.compile()
            guess = make_guess(prob, None)
            expert = SimpleNamespace(fun=by_names(prob.aug, EXPERT[name]), T=prob.T_fixed)
            res = {}
            for key, g in (("ex", expert), ("op", guess)):
                # the expert tries expand=True (SX) and MX without expansion (cheaper to
                # build, slower to run) and keeps the faster: the best of both counts
                sx = opti_collocation(prob, sol, g, expand=True)
                mx = opti_collocation(prob, sol, g, expand=False)
                res[key] = sx
                best[key] = np.minimum(best[key], np.minimum(sx[1], mx[1]))
            given, wall_gv = run_daekit_given(make, guess)
            best["dk"] = np.minimum(best["dk"], wall)
            best["gv"] = np.minimum(best["gv"], wall_gv)
        assert sol.success, sol.report
        st = stages(make, repeat)
        rows.append((name, sol, res, given, best, st))
    print(f"{'problem':9s} {'daekit J':>15s} {'it':>3s} | {'Opti, expert guess J':>20s} "
          f"{'rel diff':>8s} {'it':>4s} {'ok':>3s} | {'Opti, daekit guess J':>20s} "
          f"{'rel diff':>8s} {'it':>3s} | {'given: it':>9s}")
    for name, sol, res, given, _, _ in rows:
        Jd = sol.objective
        line = f"{name:9s} {Jd:15.10f} {sol.stats['iter_count']:3d} |"
        for key in ("ex", "op"):
            J, _, it, ok = res[key]
            line += f" {J:20.10f} {abs(J - Jd) / abs(Jd):8.1e} {it:4d}"
            line += f" {'yes' if ok else 'NO':>3s} |" if key == "ex" else " |"
        print(line + f" {given.stats['iter_count']:9d}")
    print()
    print(f"{'best of':9s} {'daekit':>13s} | {'Opti, expert guess':>18s} {'ratio':>11s} | "
          f"{'Opti, daekit guess':>18s} {'ratio':>11s} | {'given: ratio':>12s}")
    print(f"{repeat:<3d}  (ms) {'wall':>6s} {'CPU':>6s} | {'wall':>8s} {'CPU':>9s} "
          f"{'wall':>5s} {'CPU':>5s} | {'wall':>8s} {'CPU':>9s} {'wall':>5s} {'CPU':>5s} | "
          f"{'wall':>5s} {'CPU':>6s}")
    for name, *_, t, _ in rows:
        d, e, o, g = (1e3 * t[k] for k in ("dk", "ex", "op", "gv"))
        print(f"{name:9s} {d[0]:6.1f} {d[1]:6.1f} | {e[0]:8.1f} {e[1]:9.1f} {d[0] / e[0]:5.2f} "
              f"{d[1] / e[1]:5.2f} | {o[0]:8.1f} {o[1]:9.1f} {d[0] / o[0]:5.2f} "
              f"{d[1] / o[1]:5.2f} | {g[0] / o[0]:5.2f} {g[1] / o[1]:6.2f}")
    print()
    keys = ("model+reduction", "compile", "guess", "analysis", "NLP")
    print(f"{'CPU ms':9s} " + " ".join(f"{k:>15s}" for k in keys)
          + f" {'Opti, expert':>12s} {'Opti, dk guess':>14s}")
    for name, *_, t, st in rows:
        print(f"{name:9s} " + " ".join(f"{1e3 * st[k]:15.1f}" for k in keys)
              + f" {1e3 * t['ex'][1]:12.1f} {1e3 * t['op'][1]:14.1f}")
    print()
    print("daekit: everything from OCP(...) to the solution. Opti: build + guess + solve of the "
          "same NLP, vectorized, the faster of expand=True (SX) and MX, daekit's IPOPT options, "
          "from the expert's own guess (the fair alternative) or handed daekit's default guess; "
          "'given': daekit handed its own guess like Opti (a Trajectory), no guess computed.")
    print("Verdict (target: daekit's total CPU time <= 1.0x Opti's, judged on the "
          "expert-guess column; the daekit-guess ratio beside it):")
    for name, sol, res, _, t, _ in rows:
        J, _, it, ok = res["ex"]
        same = ok and abs(J - sol.objective) <= 1e-8 * abs(sol.objective)
        r_ex, r_op = t["dk"][1] / t["ex"][1], t["dk"][1] / t["op"][1]
        if same:
            what = "met" if r_ex <= 1.0 else "NOT met"
        elif ok and J < sol.objective:  # Opti found a better optimum: daekit loses the row
            what = (f"NOT met: Opti from the expert's guess reached a better optimum, J = {J:.10g}"
                    f" against daekit's {sol.objective:.10g}")
        else:
            what = ("not judged: Opti from the expert's guess "
                    + (f"reached a worse optimum, J = {J:.10g}" if ok else "failed"))
        print(f"  {name:9s} expert-guess ratio {r_ex:5.2f} ({what}); "
              f"daekit-guess ratio {r_op:5.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
