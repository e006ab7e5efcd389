"""daekit's OCP against a hand-written casadi.Opti collocation of the same problem.

Problem: swing the Cartesian planar pendulum (index 3, unit mass and length, a tangential force
u on the mass) from rest at the bottom to rest at 30 degrees in T = 2 s, minimizing int u^2.
Both solve the same index-1 system (daekit's reduction of the model) with the same
discretization: Radau IIA degree 3, N intervals, piecewise constant controls, the algebraic
unknowns at t = 0, the invariants imposed at t = 0 only, and the same independent subset of
the boundary conditions (p[0], v[0] at both ends). Prints both objectives (equal to 1e-8) and
wall times (build + solve, and IPOPT alone).

Opti is run twice: with daekit's IPOPT options (``mumps_permuting_scaling = 0``), the fair
comparison, and with IPOPT's defaults, which are far slower on this KKT structure.

daekit's multiple shooting on IDAS (``method="shooting"``) is shown alongside: the same
piecewise constant controls on the same N intervals, the dynamics integrated to 1e-10 instead
of collocated, so its objective differs from the collocation's by the collocation's truncation
error (order 5 in h), not by 1e-8; and the minimal-coordinates optimum with continuous
controls (SciPy's solve_bvp on the optimality conditions) shows the larger error of the control
discretization that both share.

Run: ``python benchmarks/ocp.py [N]``
"""

from __future__ import annotations

import sys
import time

import casadi as ca
import numpy as np

from daekit.examples.ocp_examples import (
    pendulum_with_tangential_force,
    swing_optimum_minimal_coordinates,
)
from daekit.ocp import OCP
from daekit.ocp.collocation import radau_coefficients
from daekit.reduction import reduce_index

G, L, T, TH1 = 9.81, 1.0, 2.0, np.pi / 6


def model():
    m = pendulum_with_tangential_force(L=L, g=G)
    return m, m.variables["u"].sym


def run_daekit(N: int, d: int = 3, method: str = "collocation"):
    m, u = model()
    t0 = time.perf_counter()
    ocp = OCP(m, t_final=T, intervals=N, degree=d, method=method)
    ocp.minimize(integral=u**2)
    ocp.initial({"p": [0.0, -L], "v": [0.0, 0.0]})
    ocp.final({"p": [L * np.sin(TH1), -L * np.cos(TH1)], "v": [0.0, 0.0]})
    sol = ocp.solve()
    wall = time.perf_counter() - t0
    return sol, wall, ocp


def run_opti(N: int, d: int = 3, guess=None, ipopt_options=None):
    """Hand-written Radau collocation in casadi.Opti on the same reduced system."""
    m, _ = model()
    t0 = time.perf_counter()
    r = reduce_index(m)
    f = ca.Function("f", [r.t, r.x, r.z, r.u, r.p], [r.ode, r.alg, r.u[0] ** 2])
    inv = ca.Function("inv", [r.t, r.x, r.z, r.u, r.p], [r.invariants])
    ix = {n: i for i, n in enumerate(r.x_names)}
    P = ca.DM(r.p_values)
    tau, C, b, _ = radau_coefficients(d)
    h = T / N
    opti = ca.Opti()
    X0 = opti.variable(r.nx)
    Z0 = opti.variable(r.nz)
    Xk, J = X0, 0
    xvars, xtimes, zvars, ztimes = [X0], [0.0], [Z0], [0.0]
    for k in range(N):
        U = opti.variable(r.nu)
        if k == 0:
            opti.subject_to(f(0, X0, Z0, U, P)[1] == 0)
            opti.subject_to(inv(0, X0, Z0, U, P) == 0)
        Xs = [Xk] + [opti.variable(r.nx) for _ in range(d)]
        xvars.extend(Xs[1:])
        xtimes.extend(h * (k + tau[j]) for j in range(1, d + 1))
        for j in range(1, d + 1):
            Zj = opti.variable(r.nz)
            zvars.append(Zj)
            ztimes.append(h * (k + tau[j]))
            ode, alg, q = f(h * (k + tau[j]), Xs[j], Zj, U, P)
            opti.subject_to(sum(C[i, j] * Xs[i] for i in range(d + 1)) - h * ode == 0)
            opti.subject_to(alg == 0)
            J = J + h * b[j - 1] * q
        Xk = Xs[d]
    opti.subject_to(X0[ix["p[0]"]] == 0.0)
    opti.subject_to(X0[ix["v[0]"]] == 0.0)
    opti.subject_to(Xk[ix["p[0]"]] == L * np.sin(TH1))
    opti.subject_to(Xk[ix["v[0]"]] == 0.0)
    opti.minimize(J)
    # a consistent start at rest at the bottom, held constant
    # the same initial guess as daekit's (its simulation with u = 0, evaluated at the nodes)
    for var, tv in zip(xvars, xtimes, strict=True):
        opti.set_initial(var, guess(np.array([tv]))[0][:, 0])
    for var, tv in zip(zvars, ztimes, strict=True):
        opti.set_initial(var, guess(np.array([tv]))[1][:, 0])
    opti.solver("ipopt", {"print_time": False},
                {"print_level": 0, "sb": "yes", **(ipopt_options or {})})
    ts = time.perf_counter()
    sol = opti.solve()
    t_solve = time.perf_counter() - ts
    wall = time.perf_counter() - t0
    return float(sol.value(J)), wall, t_solve, opti.stats()


def minimal_coordinates_optimum() -> float:
    return swing_optimum_minimal_coordinates(TH1, T, L=L, g=G)


def main(N: int = 100) -> None:
    from daekit.ocp.guess import make_guess

    run_daekit(10)  # load IPOPT once so that neither run pays for it
    sol, wall_dk, ocp = run_daekit(N)
    guess = make_guess(ocp, None).fun
    J_opti, wall_opti, ts_opti, st = run_opti(
        N, guess=guess, ipopt_options={"mumps_permuting_scaling": 0, "max_iter": 1000})
    J_def, wall_def, ts_def, st_def = run_opti(N, guess=guess)
    run_daekit(5, method="shooting")  # load IDAS once
    sh, wall_sh, _ = run_daekit(N, method="shooting")
    print(f"Planar pendulum swing, Radau IIA degree 3, N = {N} intervals")
    print(f"  daekit : objective {sol.objective:.12f}  {sol.stats['iter_count']:3d} it  "
          f"wall {wall_dk:.3f} s (solve {sol.stats['t_solve']:.3f} s)")
    print(f"  Opti   : objective {J_opti:.12f}  {st['iter_count']:3d} it  "
          f"wall {wall_opti:.3f} s (solve {ts_opti:.3f} s)  [same IPOPT options as daekit]")
    print(f"  Opti   : objective {J_def:.12f}  {st_def['iter_count']:3d} it  "
          f"wall {wall_def:.3f} s (solve {ts_def:.3f} s)  [IPOPT defaults]")
    print(f"  shooting: objective {sh.objective:.12f}  {sh.stats['iter_count']:3d} it  "
          f"wall {wall_sh:.3f} s (solve {sh.stats['t_solve']:.3f} s)  [IDAS, rtol 1e-10, "
          "limited-memory Hessian]")
    J_ref = minimal_coordinates_optimum()
    print(f"  continuous controls (solve_bvp, minimal coordinates): {J_ref:.12f}")
    rel_sh = abs(sh.objective - sol.objective) / abs(sol.objective)
    print(f"  shooting vs collocation: relative difference {rel_sh:.2e} (collocation's "
          f"truncation error); both vs continuous controls: {abs(sh.objective - J_ref) / J_ref:.2e}"
          " (control discretization)")
    rel = abs(sol.objective - J_opti) / abs(J_opti)
    print(f"  daekit (collocation) vs Opti: relative difference {rel:.2e} (target 1e-8)")
    print(f"  time ratio daekit / Opti: {wall_dk / wall_opti:.2f} in all, "
          f"{sol.stats['t_solve'] / ts_opti:.2f} for the solve (target <= 1.5)")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 100)
