"""Benchmark: a family of optimal control problems, cold starts vs nearest-neighbour warm starts.

The planar pendulum in Cartesian coordinates (index 3: unit mass and rod, a tangential force
``u``), swung from rest at the bottom to rest at the angle ``theta`` in 2 s with the least
``int u^2 dt`` (Radau collocation, 20 intervals, degree 3), for 12 angles from 0.3 to 2.5 rad.
``dk.ensemble_ocp(..., warm_start=False)`` solves each from daekit's default guess (a
simulation with zero control); ``warm_start=True`` (the default) solves them along a
nearest-neighbour path, each started from the nearest solved angle's solution.

Printed: IPOPT iterations per angle, failures, total iterations and wall time of both ways.
Iteration counts do not depend on the machine's load; wall times do.

Run: ``python benchmarks/ensemble_ocp.py``
"""

from __future__ import annotations

import casadi as ca
import numpy as np

import daekit as dk


def swing_model():
    m = dk.Model("swing")
    p = m.state("p", 2)
    z = m.algebraic("z")
    u = m.control("u")
    tangent = ca.vertcat(-p[1], p[0])
    m.equation(m.der(p, 2) - (u * tangent - ca.vertcat(0, 9.81) - z * p), name="newton")
    m.equation(0.5 * (ca.dot(p, p) - 1), name="rod")
    return m, u


def main() -> None:
    m, u = swing_model()

    def problem(theta: float):
        ocp = dk.OCP(m, t_final=2.0, intervals=20, degree=3)
        ocp.minimize(integral=u**2)
        ocp.initial({"p": [0, -1], "der(p)": [0, 0]})
        return ocp.final({"p": [np.sin(theta), -np.cos(theta)], "der(p)": [0, 0]})

    thetas = np.linspace(0.3, 2.5, 12)
    out = {}
    for warm in (False, True):
        ens = dk.ensemble_ocp(problem, {"theta": thetas}, warm_start=warm, progress=False)
        out[warm] = ens
    print(f"{len(thetas)} swing-up OCPs (planar pendulum, index 3), theta in [0.3, 2.5] rad")
    print(f"{'theta':>7} {'cold iter':>10} {'cold ok':>8} {'warm iter':>10} {'warm ok':>8} "
          f"{'from':>6} {'objective':>10}")
    cold, warm = out[False].summary(), out[True].summary()
    for k, th in enumerate(thetas):
        c, w = cold[k], warm[k]
        src = f"{thetas[w['warm_from']]:.2f}" if w["warm_from"] >= 0 else "-"
        print(f"{th:>7.2f} {c['iterations']:>10d} {str(c['success']):>8} {w['iterations']:>10d} "
              f"{str(w['success']):>8} {src:>6} {w['objective']:>10.4f}")
    for name, ens in (("cold", out[False]), ("warm", out[True])):
        rows = ens.summary()
        print(f"{name}: {sum(r['iterations'] for r in rows)} iterations, "
              f"{len(ens.failures)} failed, {ens.stats['wall_time']:.1f} s")


if __name__ == "__main__":
    main()
