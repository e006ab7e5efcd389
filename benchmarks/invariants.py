"""Benchmark: a free rigid body with a unit quaternion (an ODE invariant), 100 s, one run.

The axisymmetric body of ``reference-problems.md`` section 7 (I = (1, 1, 1.5),
w(0) = (1, 0, 2), q(0) = 1): the body rates have the closed form w = (cos t, sin t, 2), the
kinetic energy is conserved and |q| = 1 is the declared invariant ``unit``.

daekit (``m.invariant(q.q - 1)``; every remedy: none, Baumgarte with one pole, projection
by drift tolerance (the default, and ``drift_tol=1e-10`` on the integrated state, timed once),
dummy derivatives) against hand-written expert code on the explicit 7-state ODE in raw CasADi
(CVODES, BDF, the same tolerances, built once):

- plain integration (one run over the grid);
- renormalization ``q <- q / |q|`` at every output point (the usual remedy; one integrator
  over an output interval, built once and called per interval);
- the classic normalizing feedback ``q' = q ⊗ (0, w) / 2 - k (|q|^2 - 1) q`` (k = 1), which is
  what Baumgarte with one pole does for this invariant.

Columns: wall time (best of ``REPEAT``; daekit's integrators are built on the first call and
reused), steps, max |w - w_exact|, max | |q|^2 - 1 |, max |E - E(0)|.

Run: ``python benchmarks/invariants.py [--t-end 100] [--tol 1e-8] [--points 1001]``
"""

from __future__ import annotations

import argparse
import inspect

import casadi as ca
import numpy as np
from common import best_of  # noqa: E402 - benchmarks/ is the script directory

import daekit as dk
from daekit.examples import invariants as inv

REPEAT = 3


def errors(t, q, w):
    E = inv.rigid_body_energy(w)
    return (float(np.max(np.abs(w - inv.rigid_body_rates(t)))),
            float(np.max(np.abs(np.sum(q * q, axis=1) - 1.0))),
            float(np.max(np.abs(E - E[0]))))


def hand_written(t, tol, k_feedback=0.0):
    """The explicit ODE in raw CasADi CVODES; with k_feedback > 0 the normalizing feedback."""
    q = ca.SX.sym("q", 4)
    w = ca.SX.sym("w", 3)
    Id = ca.DM(inv.RIGID_BODY_DATA["I"])
    qdot = 0.5 * inv.quat_mul(q, ca.vertcat(0, w)) - k_feedback * (ca.dot(q, q) - 1) * q
    wdot = ca.cross(Id * w, w) / Id
    return {"x": ca.vertcat(q, w), "ode": ca.vertcat(qdot, wdot)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--t-end", type=float, default=100.0)
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--points", type=int, default=1001)
    args = ap.parse_args()
    T, tol, n = args.t_end, args.tol, args.points
    t = np.linspace(0.0, T, n)
    data = inv.RIGID_BODY_DATA
    fixed = {"q": list(data["q0"]), "w": list(data["w0"])}
    x0 = np.r_[data["q0"], data["w0"]]
    opts = {"abstol": tol, "reltol": tol, "max_num_steps": 10**6}
    rows = []

    # daekit, every remedy
    has_drift_tol = "drift_tol" in inspect.signature(dk.simulate).parameters
    runs = [("daekit, none", None, "differentiate", {}),
            ("daekit, baumgarte (pole -1)", "baumgarte", "differentiate", {"poles": (-1.0,)}),
            ("daekit, projection (default drift_tol)", "projection", "differentiate", {}),
            ("daekit, projection (drift_tol 1e-10)", "projection", "differentiate",
             {"drift_tol": 1e-10, "project_output": False} if has_drift_tol else {}),
            ("daekit, dummy derivatives", "dummy_derivatives", "dummy_derivatives", {})]
    for label, stab, method, kw in runs:
        r = dk.reduce_index(inv.rigid_body(), method=method, point=fixed)
        init = dk.initialize(r, fixed=fixed)

        def run(r=r, init=init, stab=stab, kw=kw):
            return dk.simulate(r, t, init, stabilization=stab, rtol=tol, atol=tol, **kw)

        slow = bool(kw.get("drift_tol"))
        if not slow:
            run()  # builds the integrators
        wall, tr = best_of(run, repeat=1 if slow else REPEAT)
        rows.append((label, wall, int(tr.stats.get("steps", 0)), *errors(t, tr["q"], tr["w"])))

    # hand-written, plain: one CVODES run over the grid
    F = ca.integrator("plain", "cvodes", hand_written(t, tol), 0.0, list(t[1:]), opts)
    wall, res = best_of(lambda: F(x0=x0))
    X = np.vstack([x0, np.asarray(res["xf"]).T])
    rows.append(("hand-written CVODES, plain", wall, int(F.stats()["nsteps"]),
                 *errors(t, X[:, :4], X[:, 4:])))

    # hand-written, renormalized at every output point (the ODE is autonomous: one
    # integrator over one output interval, built once)
    h = float(t[1] - t[0])
    Fh = ca.integrator("step", "cvodes", hand_written(t, tol), 0.0, h, opts)

    def renormalized():
        X = np.empty((n, 7))
        X[0] = x0
        steps = 0
        for k in range(n - 1):
            xk = np.asarray(Fh(x0=X[k])["xf"]).ravel()
            steps += Fh.stats()["nsteps"]
            xk[:4] /= np.linalg.norm(xk[:4])
            X[k + 1] = xk
        return X, steps

    wall, (X, steps) = best_of(renormalized)
    rows.append(("hand-written CVODES, q/|q| per output", wall, steps,
                 *errors(t, X[:, :4], X[:, 4:])))

    # hand-written normalizing feedback (k = 1)
    Fk = ca.integrator("feedback", "cvodes", hand_written(t, tol, 1.0), 0.0, list(t[1:]), opts)
    wall, res = best_of(lambda: Fk(x0=x0))
    X = np.vstack([x0, np.asarray(res["xf"]).T])
    rows.append(("hand-written CVODES, feedback k = 1", wall, int(Fk.stats()["nsteps"]),
                 *errors(t, X[:, :4], X[:, 4:])))

    print(f"Rigid body with a unit quaternion, {T:g} s, {n} output points, "
          f"rtol = atol = {tol:g}")
    head = (f"{'method':44s} {'wall [ms]':>10s} {'steps':>7s} {'rate err':>9s} "
            f"{'max|q.q-1|':>10s} {'energy err':>10s}")
    print(head)
    print("-" * len(head))
    for name, wall, steps, er, dr, ee in rows:
        print(f"{name:44s} {1e3 * wall:10.2f} {steps:7d} {er:9.2e} {dr:10.2e} {ee:10.2e}")


if __name__ == "__main__":
    main()
