"""Initial guesses for the OCP: a simulation with given controls, or a previous solution.

The simulation starts from a consistent point: the closest point (least squares on the
initial conditions, then on the distance to the user's guesses) that satisfies the algebraic
equations and the invariants, found with a small IPOPT problem. It then integrates the
index-1 system with IDAS interval by interval with the guessed controls held constant.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import OCPError

__all__ = ["Guess", "make_guess"]


@dataclass
class Guess:
    fun: object  # t array -> (X (nx, n), Z (nz, n), W (nw, n))
    T: float
    p: np.ndarray
    V: np.ndarray | None = None
    key: tuple | None = None
    note: str = ""


def _interp_fun(t: np.ndarray, X: np.ndarray, Z: np.ndarray, W: np.ndarray):
    t = np.asarray(t, float)
    order = np.argsort(t, kind="stable")
    t = t[order]
    X, Z, W = X[:, order], Z[:, order], W[:, order]

    def fun(tq):
        tq = np.atleast_1d(np.asarray(tq, float))
        out = []
        for M in (X, Z, W):
            out.append(np.array([np.interp(tq, t, row) for row in M]).reshape(M.shape[0], tq.size))
        return tuple(out)

    return fun


def make_guess(ocp, guess) -> Guess:
    """Build the initial guess of ``ocp`` (see the module docstring)."""
    from . import OCPSolution

    a = ocp._aug
    if isinstance(guess, OCPSolution):
        if guess._aug is not a:
            # a solution of another OCP object on the same model: interpolate by names
            X = np.vstack([guess[n] for n in a.x_names]) if a.nx else np.zeros((0, guess.t.size))
            Z = np.vstack([guess[n] for n in a.z_names]) if a.nz else np.zeros((0, guess.t.size))
            W = np.vstack([guess[n] for n in a.w_names]) if a.nw else np.zeros((0, guess.t.size))
            return Guess(_interp_fun(guess.t, X, Z, W), guess.T, ocp._p_guess(),
                         note="interpolated from a previous solution")
        T = guess.T if ocp._T_free is not None else ocp._T_guess
        tt = guess.t * (T / guess.T)
        p = guess._P.copy()
        return Guess(_interp_fun(tt, guess._X, guess._Z, guess._W), T, p, guess._V, guess._key,
                     "warm start from a previous solution")
    if guess is not None and not isinstance(guess, dict):
        raise OCPError(
            f"solve(guess=...): expected None, a previous OCPSolution or a dict, got "
            f"{type(guess).__name__}"
        )
    guess = dict(guess or {})
    T = ocp._T_guess
    p = ocp._p_guess()
    xlb, xub, zlb, zub, wlb, wub = ocp._simple_bounds()
    xg = np.clip(np.zeros(a.nx), xlb, xub)
    zg = np.clip(np.zeros(a.nz), zlb, zub)
    w_const = np.clip(np.zeros(a.nw), wlb, wub)
    w_call: dict[int, object] = {}
    for name, val in guess.items():
        els = a.elements(name, f"solve(guess={{{name!r}: ...}})")
        for k, e in enumerate(els):
            w = a.which(a.names[e])
            if w is None:
                continue
            if callable(val):
                if w[0] == "w":
                    w_call[w[1]] = (val, k, len(els))
                continue
            v = np.broadcast_to(np.asarray(val, float).ravel(), (len(els),))[k]
            {"x": xg, "z": zg, "w": w_const}.get(w[0], np.zeros(a.np_ + 1))[w[1]] = v
    for kind, _label, ex, val in ocp._bc_user:
        w = a.which(ex)
        if kind == "initial" and w is not None and w[0] == "x":
            xg[w[1]] = val

    def w_at(t: float) -> np.ndarray:
        w = w_const.copy()
        for i, (fn, k, n) in w_call.items():
            v = np.asarray(fn(t), float).ravel()
            w[i] = v[k] if v.size == n else v[0]
        return np.clip(w, wlb, wub)

    x0, z0 = _consistent_start(ocp, xg, zg, w_at(0.0), p)
    N = ocp.intervals
    if ocp.method == "collocation":
        from .collocation import radau_coefficients

        tau = radau_coefficients(ocp.degree)[0][1:]
    else:
        tau = np.array([1.0])
    ts, Xs, Zs, Ws = [0.0], [x0], [z0], [w_at(0.0)]
    sim = _interval_integrator(a, tau)
    x, z = x0, z0
    failed = None
    for k in range(N):
        tk, h = k * T / N, T / N
        wk = w_at(tk + 0.5 * h)
        if failed is None and sim is not None:
            try:
                res = sim(x0=x, z0=z, p=np.concatenate([wk, p, [tk, h]]))
                xf = np.asarray(res["xf"]).reshape(a.nx, -1)
                zf = np.asarray(res["zf"]).reshape(a.nz, -1)
                if not (np.all(np.isfinite(xf)) and np.all(np.isfinite(zf))):
                    raise RuntimeError("non-finite values")
                if np.max(np.abs(xf), initial=0.0) > 1e6:
                    raise RuntimeError("diverging")
            except RuntimeError as exc:
                failed = (tk, str(exc).splitlines()[-1] if str(exc) else "")
                xf = np.repeat(x.reshape(-1, 1), tau.size, axis=1)
                zf = np.repeat(z.reshape(-1, 1), tau.size, axis=1)
        else:
            xf = np.repeat(x.reshape(-1, 1), tau.size, axis=1)
            zf = np.repeat(z.reshape(-1, 1), tau.size, axis=1)
        for j, tj in enumerate(tau):
            ts.append(tk + h * tj)
            Xs.append(xf[:, j])
            Zs.append(zf[:, j])
            Ws.append(wk)
        x, z = xf[:, -1], zf[:, -1]
    note = "simulation with the guessed controls"
    if failed is not None:
        note += f" (stopped at t = {failed[0]:.4g}; held constant afterwards)"
    fun = _interp_fun(np.array(ts), np.array(Xs).T.reshape(a.nx, -1),
                      np.array(Zs).T.reshape(a.nz, -1), np.array(Ws).T.reshape(a.nw, -1))
    return Guess(fun, T, p, note=note)


def _interval_integrator(a, tau: np.ndarray):
    """IDAS over one interval in scaled time ``s in [0, 1]``, outputs at ``tau``."""
    tk = ca.SX.sym("tk")
    h = ca.SX.sym("h")
    s = ca.SX.sym("s")
    t_of_s = tk + h * s
    ode = ca.substitute([a.ode], [a.t], [t_of_s])[0]
    alg = ca.substitute([a.alg], [a.t], [t_of_s])[0]
    dae = {"t": s, "x": a.x, "z": a.z, "p": ca.vertcat(a.w, a.p, tk, h), "ode": h * ode,
           "alg": alg}
    plugin = "idas" if a.nz else "cvodes"
    if a.nz == 0:
        dae.pop("z")
        dae.pop("alg")
    try:
        return ca.integrator("guess_sim", plugin, dae, 0.0, list(map(float, tau)),
                             {"abstol": 1e-8, "reltol": 1e-6, "max_num_steps": 20000})
    except RuntimeError:  # pragma: no cover
        return None


def _consistent_start(ocp, xg, zg, w0, p):
    """Closest point to the initial conditions and guesses on ``alg = 0, invariants = 0``."""
    a = ocp._aug
    n = a.nx + a.nz
    if n == 0:
        return xg, zg
    v = ca.SX.sym("v", n)
    x, z = v[: a.nx], v[a.nx:]
    vw = ca.vertcat(x, z, ca.DM(w0))
    rows = ocp._bc_fun(vw, vw, ca.DM(p), 0.0)
    init = [i for i, k in enumerate(ocp._bc_kinds) if k == "initial"]
    obj = ca.sumsqr(ca.vertcat(*[rows[i] for i in init])) if init else 0
    obj = obj + 1e-4 * ca.sumsqr(x - xg) + 1e-8 * ca.sumsqr(z - zg)
    man = ocp._man_fun(0.0, vw, ca.DM(p))
    xlb, xub, zlb, zub, _, _ = ocp._simple_bounds()
    try:
        solver = ca.nlpsol("init", "ipopt", {"x": v, "f": obj, "g": man},
                           {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                            "ipopt.max_iter": 200})
        res = solver(x0=np.concatenate([xg, zg]), lbx=np.concatenate([xlb, zlb]),
                     ubx=np.concatenate([xub, zub]), lbg=0, ubg=0)
        sol = np.asarray(res["x"]).ravel()
        if not np.all(np.isfinite(sol)):
            raise RuntimeError("non-finite")
    except RuntimeError:
        return xg, zg
    return sol[: a.nx], sol[a.nx:]
