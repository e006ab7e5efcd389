"""Initial guesses for the OCP: a simulation with given controls, or a previous solution.

Four sources, all ending as a function ``t -> (X, Z, W)`` that the transcriptions sample on
their own grid:

- none or a dict: daekit simulates. The simulation starts from a consistent point: a point
  near the user's guesses where the initial conditions, the algebraic equations and the
  invariants hold, found by a Gauss-Newton projection with least-norm steps; only when that
  does not meet them all, the closest point in the least-squares sense (on the initial
  conditions, then on the distance to the guesses), by a small IPOPT problem.
  It then integrates the index-1 system with IDAS interval by interval with the guessed
  controls held constant (the algebraic unknowns re-solved by Newton at each interval start,
  see :class:`_GuessSimulator`). Should the integration fail, the rest of the guess is a
  straight line to the nearest point that satisfies the algebraic equations, the invariants
  and the final conditions at ``t = T`` (held constant when there is no such point nearby);
  the guess's note (in the report) says so. When the simulation runs through but does not
  reach the final conditions (a pendulum to be swung up stays hanging), the guess *blends*
  from the initial point to the consistent final point nearest the simulation's end (with the
  variables that final conditions fix by name at their values: :func:`consistent_end`), along
  the invariant manifold (:func:`_manifold_blend`: a small least-squares NLP for states,
  algebraic unknowns and controls on the interval boundaries), so that the default guess
  respects the boundary conditions.
- a :class:`daekit.Trajectory` from :func:`daekit.simulate` (the user's own simulation with
  the controls of their choice): its values, read by the original model's names, are
  interpolated linearly onto the NLP's grid.
- a previous :class:`~daekit.ocp.OCPSolution` of the same OCP object: its decision vector is
  reused as is when the NLP has the same structure (a warm start in the strict sense);
  otherwise, and for a solution of another OCP on the same model (e.g. collocation to
  shooting), it is interpolated by names like a trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import OCPError
from .nlp import call_buffered, quiet

__all__ = ["Guess", "make_guess", "consistent_end"]


@dataclass
class Guess:
    fun: object  # t array -> (X (nx, n), Z (nz, n), W (nw, n))
    T: float
    p: np.ndarray
    V: np.ndarray | None = None
    key: tuple | None = None
    note: str = ""
    lam: tuple | None = None  # (lam_x, lam_g) of a previous solution: IPOPT's warm start


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


def make_guess(prob, guess) -> Guess:
    """Build the initial guess of ``ocp`` (see the module docstring)."""
    from ..simulate import Trajectory
    from .solution import OCPSolution

    a = prob.aug
    if isinstance(guess, OCPSolution):
        if guess._aug is not a:
            # a solution of another OCP object on the same model: interpolate by names
            vals = {}
            for n in a.x_names + a.z_names + a.w_names + a.p_names:
                try:
                    vals[n] = np.asarray(guess[n], float).reshape(-1)
                except OCPError:
                    pass
            return _from_values(prob, guess.t, guess.T, vals,
                                f"interpolated from a previous solution ({guess.method})")
        T = guess.T if prob.T_free is not None else prob.T_guess
        tt = guess.t * (T / guess.T)
        p = guess._P.copy()
        return Guess(_interp_fun(tt, guess._X, guess._Z, guess._W), T, p, guess._V, guess._key,
                     "warm start from a previous solution", getattr(guess, "_lam", None))
    if isinstance(guess, Trajectory):
        if guess.t.size < 1:
            raise OCPError("solve(guess=trajectory): the trajectory is empty")
        t = guess.t - guess.t[0]
        return _from_values(prob, t, float(t[-1]), guess.values,
                            "interpolated from a simulation (Trajectory, "
                            f"{guess.t.size} points on [{guess.t[0]:g}, {guess.t[-1]:g}])")
    if guess is not None and not isinstance(guess, dict):
        raise OCPError(
            f"solve(guess=...): expected None, a daekit.Trajectory (from daekit.simulate), a "
            f"previous OCPSolution or a dict, got {type(guess).__name__}"
        )
    guess = dict(guess or {})
    T = prob.T_guess
    p = prob.p_guess()
    xlb, xub, zlb, zub, wlb, wub = prob.simple_bounds()
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
            {"x": xg, "z": zg, "w": w_const}.get(w[0], np.zeros(a.n_p + 1))[w[1]] = v
    for c in prob.conditions:
        w = a.which(c.expr)
        if c.kind == "initial" and w is not None and w[0] == "x":
            xg[w[1]] = c.value

    def w_at(t: float) -> np.ndarray:
        w = w_const.copy()
        for i, (fn, k, n) in w_call.items():
            v = np.asarray(fn(t), float).ravel()
            w[i] = v[k] if v.size == n else v[0]
        return np.clip(w, wlb, wub)

    x0, z0 = _consistent_start(prob, xg, zg, w_at(0.0), p)
    N = prob.intervals
    if prob.method == "collocation":
        from .collocation import radau_coefficients

        tau = radau_coefficients(prob.degree)[0][1:]
    else:
        tau = np.array([1.0])
    ts, Xs, Zs, Ws = [0.0], [x0], [z0], [w_at(0.0)]
    sim = _GuessSimulator(a, tau, p)
    x, z = x0, z0
    failed = None
    whole = None
    if not w_call and N > 1:
        # constant controls: one integration over the whole horizon with outputs at every grid
        # time (measured: 100 interval calls cost 0.05-0.08 s); on any failure the interval
        # by interval loop below runs and finds where it fails
        grid = tuple(float(v) for v in ((np.arange(N).reshape(-1, 1) + tau) / N).ravel())
        try:
            with quiet():
                whole = sim.horizon(x, z, w_at(0.5 * T / N), T, grid)
        except RuntimeError:
            whole = None
    if whole is not None:  # constant controls: the same at every time
        wk = w_at(0.5 * T / N)
        ts = [0.0, *(np.asarray(grid) * T).tolist()]
        Xs, Zs = [x0, *whole[0].T], [z0, *whole[1].T]
        Ws = Ws + [wk] * len(grid)
    with quiet():  # SUNDIALS' messages on a failed interval (set up once, not per interval)
        for k in range(N if whole is None else 0):
            tk, h = k * T / N, T / N
            wk = w_at(tk + 0.5 * h)
            if failed is None:
                try:
                    xf, zf = sim.interval(x, z, wk, tk, h)
                except RuntimeError as exc:
                    failed = (tk, str(exc).splitlines()[-1] if str(exc) else "")
            if failed is not None:
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
        tf = failed[0]
        i0 = next(i for i, t in enumerate(ts) if t > tf)
        xe, ze, ok = consistent_end(prob, Xs[i0 - 1], Zs[i0 - 1], Ws[-1], p, T)
        if ok:
            for i in range(i0, len(ts)):
                s_ = (ts[i] - tf) / (T - tf)
                Xs[i] = (1 - s_) * Xs[i0 - 1] + s_ * xe
                Zs[i] = (1 - s_) * Zs[i0 - 1] + s_ * ze
            note += (f" (the integration failed at t = {tf:.4g}: {failed[1]}; from there a "
                     "straight line to a consistent final point that meets the final conditions)")
        else:
            note += f" (stopped at t = {tf:.4g}: {failed[1]}; held constant afterwards)"
    else:
        miss = _final_miss(prob, Xs[-1], Zs[-1], Ws[-1], p, T)
        if miss > 1e-3:
            xe, ze, ok = consistent_end(prob, Xs[-1], Zs[-1], Ws[-1], p, T)
            # on the interval boundaries (and the ends), interpolated in between
            # (at most BLEND_NODES of them: a guess needs no finer path)
            step = tau.size * max(1, int(np.ceil(N / (BLEND_NODES - 1))))
            nodes = np.unique(np.r_[0, np.arange(step, len(ts), step), len(ts) - 1])
            tn = np.array(ts)[nodes]
            path = _manifold_blend(prob, tn, x0, z0, xe, ze, [Ws[i] for i in nodes], p) \
                if ok else None
            if path is not None:
                fn = _interp_fun(tn, *path)
                Xn, Zn, Wn = fn(np.array(ts))
                Xs, Zs, Ws = list(Xn.T), list(Zn.T), list(Wn.T)
                note = (f"a path along the invariant manifold from the initial point to the final "
                        f"conditions (the simulation with the guessed controls missed them by "
                        f"{miss:.3g}): the smoothest one whose positions, velocities and "
                        f"invariants agree, ending at the consistent final point nearest the "
                        f"simulation's end with the given final values")

    def cols(vs, n):  # list of (n,) arrays -> (n, len) even when n == 0
        return np.asarray(vs, float).reshape(len(vs), n).T

    fun = _interp_fun(np.array(ts), cols(Xs, a.nx), cols(Zs, a.nz), cols(Ws, a.nw))
    return Guess(fun, T, p, note=note)


#: Largest number of times of the manifold blend (the guess is interpolated in between).
#: Measured, IPOPT iterations of the OCP with 26 / 51 nodes: cart-pole swing-up 9 / 32 (full
#: state) and 10 / 14 (the user's form), Betts 10.103 14 / 13, crane 20 / 19, planar swing,
#: 3D pendulum (periodic, rest to rest) and delta robot equal; the same objectives; the blend
#: itself costs about half. Fewer nodes are not cheaper in the end: with 11 / 16 / 21 nodes the
#: cart-pole swing-up (full state) took 27 / 920 (failed) / 9 OCP iterations, Betts 10.103 11 /
#: 21 / 15 (measured in round 6).
BLEND_NODES = 26
#: Weight of the OCP's own integral objective in the blend (prefers paths the controls can
#: afford; measured on Betts 10.103 with the minimal index-1 form: 815 IPOPT iterations to a
#: far worse local optimum without it, 13 to the published one with it).
BLEND_LAGRANGE = 1e-3
#: Symbolic type of the blend NLP ("SX": expanded; "MX": one mapped model call, cheaper to
#: build but measured slower overall on the cart-pole, 101 blend iterations).
BLEND_SYMBOLIC = "SX"
#: "closed form": IPOPT gets the blend's derivatives by the chain rule through the mapped
#: model (daekit.ocp.derivatives.quadratic_composite); "AD": CasADi differentiates the
#: expanded NLP (BLEND_SYMBOLIC).
BLEND_DERIVATIVES = "closed form"
#: IPOPT's stopping tolerances for the blend: a guess needs no more than 1e-2 on the manifold
#: (it is interpolated between the blend's times anyway). Measured against ``tol = 1e-6``
#: (blend iterations; then the OCP's iterations from the guess): cart-pole swing-up 70 -> 39
#: (OCP 9 -> 8, both forms), Betts 10.103 25 -> 23 (OCP 14 -> 13, both forms), planar swing
#: 20 -> 16 (OCP 5), crane 12 -> 9 (OCP 20), delta robot 22 -> 14 (OCP 11 -> 7), 3D pendulum
#: rest to rest 20 -> 16 (OCP 5); the same optima. Looser on the manifold (1e-1) cost OCP
#: iterations (cart-pole 9, 3D pendulum 6). It is also more robust: the cart-pole swing-up
#: with 30, 40, 60, 80 intervals takes 11, 8, 8, 8 OCP iterations in both forms, where
#: ``tol = 1e-6`` took 14, 33, 7 and failed at 80 (426 and 833 iterations, infeasible).
#: The adaptive barrier update (Betts 10.103's bounds): OCP iterations from the guess 13 -> 11
#: (both forms), crane 20 -> 19, the others equal (cart-pole with 30-80 intervals too).
#: The constraint multipliers start at zero (``constr_mult_init_max = 0``): the blend starts far
#: from a motion of the model, so IPOPT's least-squares estimate of the multipliers is large and
#: makes the Hessian of the Lagrangian strongly indefinite (regularized by 1e2 in most of the
#: cart-pole's first iterations). Measured, blend iterations (then OCP iterations): planar swing
#: 16 -> 8 (5), Betts 10.103 16 -> 12 (11, both forms), cart-pole swing-up 39 -> 29 (8, both
#: forms), 3D pendulum rest to rest 16 -> 10 (5), delta robot 14 -> 5 (7), crane 4 -> 5 (19 ->
#: 20); the same optima. Over the cart-pole with T = 1.5, 2, 2.5, 3 s, N = 30, 50 and both
#: forms of the final state (16 problems) every solve reaches the upright state either way;
#: OCP iterations 532 -> 594 in all, CPU 7.2 -> 4.7 s (one case each needs the run without the
#: branch inequalities: T = 1.5, N = 30 before; T = 2, N = 40 after).
#: MUMPS' own scaling is off (``mumps_scaling = 0``): the blend's KKT systems are small and the
#: scaling is computed at every factorization (IPOPT refactorizes about twice per iteration
#: here, for the inertia correction). Measured with callgrind (instructions per default guess,
#: deterministic where wall times on this shared machine vary by 30 %): cart-pole swing-up
#: 262 -> 247 million; the same blend and OCP iterations on the swing, Betts 10.103, the
#: cart-pole, the crane, the delta robot, and over the 16 cart-pole variants (one of them 72 ->
#: 71 OCP iterations).
#: Measured in round 6 and not kept (blend iterations, then OCP iterations; swing / Betts 10.103 /
#: cart-pole): the inertia-free curvature test (``neg_curv_test_tol`` 1e-12) 71 / 110 / 70 (OCP
#: 5 / 14 / 33); a fixed proximal shift ``sigma I`` in the blend's Hessian (fewer inertia
#: corrections) with sigma = 0.01, 0.1, 1: cart-pole OCP 15, 80, 226; ``perturb_dec_fact`` 0.1:
#: Betts 23 blend iterations; CasADi's ``sqpmethod`` with ``qrqp`` and the same closed-form
#: derivatives: 18 / 72 / not converged in 100. ``first_hessian_perturbation = 1`` and the
#: MUMPS orderings give the same blend (the two saved factorizations are below callgrind's
#: noise); a dense (LAPACK) or banded factorization of the 268 x 268 KKT system costs 2.6 /
#: 0.4 ms against MUMPS' about 0.3 ms, so a hand-written dense or banded SQP would not be cheaper
#: per iteration.
BLEND_TOLERANCES = {"ipopt.tol": 1e-1, "ipopt.constr_viol_tol": 1e-2, "ipopt.dual_inf_tol": 1.0,
                    "ipopt.mu_strategy": "adaptive", "ipopt.constr_mult_init_max": 0.0,
                    "ipopt.mumps_scaling": 0}


def _final_miss(prob, x, z, w, p, T) -> float:
    """Largest residual of the final conditions at ``(x, z, w)`` (scaled by the state size)."""
    idx = [i for i, k in enumerate(prob.bc_kinds) if k == "final"]
    if not idx:
        return 0.0
    v = np.concatenate([x, z, w])
    r = np.asarray(prob.bc_fun(v, v, p, T), float).ravel()[idx]
    return float(np.max(np.abs(r))) / max(1.0, float(np.max(np.abs(x), initial=0.0)))


def _manifold_blend(prob, ts, x0, z0, xe, ze, Ws, p):
    """States, algebraic unknowns and controls from ``x0`` to ``xe`` along the manifold.

    A small NLP (IPOPT) on the times ``ts``: at every time the algebraic equations and the
    invariants hold (the controls are free there, within their bounds), the end points are
    ``x0`` and ``xe``, and the objective is the least-squares mismatch of the dynamics
    ``x' = ode(t, x, z, w)`` (trapezoidal rule, each state scaled by its size) plus a little
    smoothness (sum of squared differences between neighbouring times) and ``1e-3`` times the
    OCP's integral objective (:data:`BLEND_LAGRANGE`). As constraints the
    trapezoidal rule and exact invariants at every time would force, e.g., a constant angular
    speed on a rotation; in the least-squares sense they give a path that is nearly a motion
    of the model. Started from the straight line with a small seeded perturbation (a straight
    line through a symmetric configuration, hanging to upright through the pivot, is a
    saddle). Returns ``(X, Z, W)`` or None when it does not converge."""
    a = prob.aug
    K = ts.size
    if K < 3 or a.nx == 0:
        return None
    W0 = np.asarray(Ws, float).reshape(K, a.nw).T
    sc = np.maximum(1.0, np.maximum(np.abs(x0), np.abs(xe)))
    P = np.repeat(np.reshape(p, (-1, 1)), K, 1)
    nX, nZ = a.nx * K, a.nz * K
    outs = [ca.vertcat(a.alg, a.inv), a.ode, prob.lagrange]
    if BLEND_DERIVATIVES == "closed form":
        # the model's outputs per time as symbols Q: the objective is quadratic in (V, Q) and
        # the manifold rows are entries of Q (daekit.ocp.derivatives.quadratic_composite)
        Vs = ca.MX.sym("V", nX + nZ + a.nw * K)
        X = ca.reshape(Vs[:nX], a.nx, K)
        Z = ca.reshape(Vs[nX:nX + nZ], a.nz, K)
        Wv = ca.reshape(Vs[nX + nZ:], a.nw, K)
        q = ca.vertcat(*[ca.reshape(o, o.numel(), 1) for o in outs])
        nman = int(outs[0].numel())
        Q = ca.MX.sym("Q", q.numel(), K)
        man, ode, lag = Q[:nman, :], Q[nman:nman + a.nx, :], Q[nman + a.nx:, :]
    else:
        S = ca.MX if BLEND_SYMBOLIC == "MX" else ca.SX
        X = S.sym("X", a.nx, K)
        Z = S.sym("Z", a.nz, K)
        Wv = S.sym("W", a.nw, K)
        fm = ca.Function("m", [a.t, a.x, a.z, a.w, a.p], outs)
        man, ode, lag = fm.map(K)(ts.reshape(1, -1), X, Z, Wv, P)
    # the manifold at the interior times (the fixed end points are on it already)
    G = ca.vec(man[:, 1:-1])
    h = np.diff(ts).reshape(1, -1)
    Hh = ca.DM(np.repeat(0.5 * h, a.nx, axis=0))
    Sc = ca.DM(np.repeat(1.0 / sc.reshape(-1, 1), K - 1, axis=1))
    dX = X[:, 1:] - X[:, :-1]
    E = (dX - Hh * (ode[:, 1:] + ode[:, :-1])) * Sc
    D = dX * Sc
    # f = |r|^2 + c: the dynamics mismatch and the smoothness (each interval weighted by
    # 1 / h), a little of the controls' size, and the (linear in Q) integral objective
    rh = ca.DM(np.repeat(1.0 / np.sqrt(h), a.nx, axis=0))
    r = ca.vertcat(ca.vec(E * rh), np.sqrt(1e-3) * ca.vec(D * rh), np.sqrt(1e-6 / K) * ca.vec(Wv))
    c = 0
    if prob.has_lagrange and BLEND_LAGRANGE:
        c = BLEND_LAGRANGE * ca.sum2(0.5 * ca.DM(h) * (lag[:, 1:] + lag[:, :-1]))
    f = ca.sumsqr(r) + c
    xlb, xub, zlb, zub, wlb, wub = prob.simple_bounds()

    def rep(v):
        return np.repeat(np.reshape(v, (-1, 1)), K, 1)

    Xlb, Xub = rep(xlb), rep(xub)
    Xlb[:, 0] = Xub[:, 0] = x0
    Xlb[:, -1] = Xub[:, -1] = xe
    lbx = np.concatenate([Xlb.ravel("F"), rep(zlb).ravel("F"), rep(wlb).ravel("F")])
    ubx = np.concatenate([Xub.ravel("F"), rep(zub).ravel("F"), rep(wub).ravel("F")])
    s_ = (ts - ts[0]) / (ts[-1] - ts[0])
    Xg = (1 - s_) * x0.reshape(-1, 1) + s_ * xe.reshape(-1, 1)
    rng = np.random.default_rng(3)
    Xg = Xg + 0.05 * sc.reshape(-1, 1) * np.sin(np.pi * s_) * rng.standard_normal((a.nx, 1))
    Zg = (1 - s_) * z0.reshape(-1, 1) + s_ * ze.reshape(-1, 1)
    x_init = np.clip(np.concatenate([Xg.ravel("F"), Zg.ravel("F"), W0.ravel("F")]), lbx, ubx)
    extra = {}
    if BLEND_DERIVATIVES == "closed form":
        from .derivatives import quadratic_composite

        k = np.arange(K).reshape(-1, 1)
        pts = np.hstack([k * a.nx + np.arange(a.nx), nX + k * a.nz + np.arange(a.nz),
                         nX + nZ + k * a.nw + np.arange(a.nw)]).astype(int)
        xv = Vs
        f, G, extra = quadratic_composite(
            Vs, Q, f, G, q, ca.vertcat(a.x, a.z, a.w), [a.t, a.x, a.z, a.w, a.p],
            (ts.reshape(1, -1), X, Z, Wv, P), pts, residuals=(r, c))
    else:
        xv = ca.vertcat(ca.vec(X), ca.vec(Z), ca.vec(Wv))
    try:
        solver = ca.nlpsol("blend", "ipopt",
                           {"x": xv, "f": f, "g": G},
                           {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                            "ipopt.max_iter": 300, "ipopt.mumps_permuting_scaling": 0,
                            "calc_lam_p": False, "no_nlp_grad": True,  # (run.ipopt_options)
                            **BLEND_TOLERANCES, **extra})
        with quiet():
            res, stats = call_buffered(solver, x0=x_init, lbx=lbx, ubx=ubx, lbg=0, ubg=0)
    except RuntimeError:
        return None
    if not stats.get("success", False):
        return None
    sol = np.asarray(res["x"]).ravel()
    return (sol[:nX].reshape(K, a.nx).T, sol[nX:nX + nZ].reshape(K, a.nz).T,
            sol[nX + nZ:].reshape(K, a.nw).T)


def seg(v, start: int, stop: int):
    """``v[start:stop]`` as a column, empty ``(0, 1)`` when ``start == stop`` (CasADi slices a
    1-by-1 symbol into a 1-by-0 row)."""
    return v[start:stop] if stop > start else type(v)(0, 1)


def _from_values(prob, t: np.ndarray, t_end: float, values: dict, note: str) -> Guess:
    """A guess from values by element name on the times ``t`` (starting at 0).

    Fixed final time: the values are read at the OCP's own times (held constant after the
    last point when they end early). Free final time: the guess's horizon is ``t_end`` (clipped
    to the bounds). Elements missing from ``values`` start at zero (controls clipped to their
    bounds); free parameters take the values' constant when present.
    """
    a = prob.aug
    t = np.asarray(t, float).ravel()
    if t.size == 0 or not np.all(np.isfinite(t)):
        raise OCPError("solve(guess=...): the guess has no (finite) time points")
    if prob.T_free is not None:
        lo, hi, _ = prob.T_free
        T = float(np.clip(t_end, lo, hi)) if t_end > 0 else prob.T_guess
    else:
        T = prob.T_guess
    xlb, xub, zlb, zub, wlb, wub = prob.simple_bounds()
    missing = []

    def rows(names, lb, ub):
        out = np.zeros((len(names), t.size))
        for i, n in enumerate(names):
            v = values.get(n)
            if v is None or np.asarray(v).size != t.size:
                missing.append(n)
                out[i] = np.clip(0.0, lb[i], ub[i])
            else:
                out[i] = np.asarray(v, float).ravel()
        return out

    X = rows(a.x_names, xlb, xub)
    Z = rows(a.z_names, zlb, zub)
    W = np.clip(rows(a.w_names, wlb, wub), wlb.reshape(-1, 1), wub.reshape(-1, 1))
    if t.size == 1:  # a single point: hold it
        t = np.array([0.0, T])
        X, Z, W = (np.repeat(M, 2, axis=1) for M in (X, Z, W))
    p = prob.p_guess()
    for i, n in enumerate(a.p_names):
        v = values.get(n)
        if n in prob.free_params and v is not None and np.size(v):
            lo, hi, _ = prob.free_params[n]
            p[i] = float(np.clip(np.asarray(v, float).ravel()[0], lo, hi))
    if missing:
        note += f"; not in it, started at 0: {', '.join(missing[:8])}"
        note += ", ..." if len(missing) > 8 else ""
    if t[-1] < T * (1 - 1e-9):
        note += f"; it ends at t = {t[-1]:g} < T = {T:g}, held constant after"
    return Guess(_interp_fun(t, X, Z, W), T, p, note=note)


class _GuessSimulator:
    """Integrates the index-1 system interval by interval (IDAS, CVODES without algebraic
    unknowns) in scaled time ``s in [0, 1]`` with outputs at ``tau``.

    Each interval starts from the previous one's end state, which lies on the manifold, with
    the algebraic unknowns re-solved for the interval's control by Newton's method on
    ``alg = 0`` (to roundoff). IDAS is therefore called without its own consistent
    initialization (``calc_ic=False``): IDACalcIC's line search fails ("IDA_LINESEARCH_FAIL",
    "too small a step") when handed values that are already consistent to roundoff, which is
    what stopped the guess simulation of a swinging 3D pendulum after a few intervals. Only if
    Newton's method does not converge (or the integration fails), IDACalcIC is tried.
    """

    def __init__(self, a, tau: np.ndarray, p: np.ndarray) -> None:
        self.a, self.tau, self.p = a, np.asarray(tau, float), np.asarray(p, float)
        self._F: dict[tuple, object] = {}
        if a.nz:
            self.alg = ca.Function("alg_z", [a.t, a.x, a.z, a.w, a.p],
                                   [a.alg, ca.jacobian(a.alg, a.z)])

    def _integrator(self, calc_ic: bool, grid: tuple | None = None):
        grid = tuple(map(float, self.tau)) if grid is None else grid
        if (calc_ic, grid) not in self._F:
            a = self.a
            tk, h, s = ca.SX.sym("tk"), ca.SX.sym("h"), ca.SX.sym("s")
            ode, alg = ca.substitute([a.ode, a.alg], [a.t], [tk + h * s])
            dae = {"t": s, "x": a.x, "p": ca.vertcat(a.w, a.p, tk, h), "ode": h * ode}
            opts = {"abstol": 1e-8, "reltol": 1e-6, "max_num_steps": 20000}
            if a.nz:
                dae.update(z=a.z, alg=alg)
                opts["calc_ic"] = calc_ic
            plugin = "idas" if a.nz else "cvodes"
            self._F[calc_ic, grid] = ca.integrator("guess_sim", plugin, dae, 0.0, list(grid),
                                                   opts)
        return self._F[calc_ic, grid]

    def _newton_z(self, t: float, x, z, w):
        """Algebraic unknowns consistent with ``x`` and the control ``w`` (None if Newton fails)."""
        z = np.asarray(z, float).copy()
        for _ in range(30):
            r, J = self.alg(t, x, z, w, self.p)
            r = np.asarray(r, float).ravel()
            if np.max(np.abs(r), initial=0.0) < 1e-12 * max(1.0, float(np.max(np.abs(z)))):
                return z
            try:
                z = z - np.linalg.solve(np.asarray(J, float), r)
            except np.linalg.LinAlgError:
                return None
            if not np.all(np.isfinite(z)):
                return None
        r = np.asarray(self.alg(t, x, z, w, self.p)[0], float).ravel()
        return z if np.max(np.abs(r), initial=0.0) < 1e-8 * max(1.0, float(np.max(np.abs(z)))) \
            else None

    def interval(self, x, z, w, tk: float, h: float):
        """``(X, Z)`` at the points ``tk + h tau``; RuntimeError when the integration fails."""
        return self._integrate(x, z, w, tk, h, None)

    def horizon(self, x, z, w, T: float, grid: tuple):
        """``(X, Z)`` at the times ``T grid`` of one integration from ``t = 0`` with the
        constant control ``w``; RuntimeError when it fails."""
        return self._integrate(x, z, w, 0.0, T, grid)

    def _integrate(self, x, z, w, tk: float, h: float, grid: tuple | None):
        a = self.a
        ns = self.tau.size if grid is None else len(grid)
        pv = np.concatenate([w, self.p, [tk, h]])
        attempts = [False, True]
        if a.nz:
            zc = self._newton_z(tk, x, z, w)
            if zc is None:
                attempts = [True]
            else:
                z = zc
        else:
            attempts = [False]
        err = None
        for calc_ic in attempts:
            try:
                res = self._integrator(calc_ic, grid)(x0=x, z0=z, p=pv)
            except RuntimeError as exc:
                err = exc
                continue
            xf = np.asarray(res["xf"]).reshape(a.nx, ns)
            zf = np.asarray(res["zf"]).reshape(a.nz, ns)
            if not (np.all(np.isfinite(xf)) and np.all(np.isfinite(zf))):
                err = RuntimeError("non-finite values")
                continue
            if np.max(np.abs(xf), initial=0.0) > 1e6:
                err = RuntimeError("diverging")
                continue
            return xf, zf
        raise err if err is not None else RuntimeError("integration failed")


def _given_final_values(prob, x, z):
    """``(x, z)`` with every state or algebraic unknown that a final condition fixes by name
    (``final s = 0``) set to its value."""
    a = prob.aug
    x, z = np.array(x, float), np.array(z, float)
    for c in prob.conditions:
        w = a.which(c.expr) if c.kind == "final" else None
        if w is not None and w[0] in ("x", "z"):
            (x if w[0] == "x" else z)[w[1]] = c.value
    return x, z


def consistent_end(prob, x, z, w, p, T):
    """The point nearest ``(x, z)`` (Gauss-Newton, least-norm steps) where the algebraic
    equations, the invariants and the final conditions hold at ``t = T``; ``ok`` is False when
    they cannot be met (the caller then holds the state constant).

    The projection starts with the variables that a final condition fixes by name at their
    values (:func:`_given_final_values`). From the simulation's end alone it could start at a
    symmetric point: the cart-pole hanging exactly below its pivot, projected onto
    ``p[1] = L``, has no gradient towards either side (the circle's tangent there is
    horizontal), so Gauss-Newton stalled or left the side to roundoff and converged only
    linearly to a degenerate root (a final point 1e-3 off the upright one). Set to the given
    ``s = 0, p[1] = L`` first, the upright point holds exactly from the start. The rows are
    those of the compiled end-point function (:attr:`~daekit.ocp.compiled.Problem.ends_fun`).

    >>> import numpy as np
    >>> from daekit.examples.ocp_examples import cartpole_ocp
    >>> prob = cartpole_ocp(final_all=False).compile(); a = prob.aug
    >>> hanging = np.where(np.array(a.x_names) == "p[1]", -0.5, 0.0)
    >>> xe, ze, ok = consistent_end(prob, hanging, [0.0], [0.0], prob.p_guess(), 2.0)
    >>> ok, np.round(xe, 12).tolist(), np.round(ze, 12).tolist()   # lam = -m g / (2 L)
    (True, [0.0, 0.0, 0.0, 0.5, 0.0, 0.0], [-2.943])
    """
    from .consistency import project_ends, rows_of

    a = prob.aug
    x, z = _given_final_values(prob, x, z)
    n = a.nx + a.nz + a.nw
    nman = int(prob.man_fun.size1_out(0))
    # the manifold at t = T and the final conditions: rows of the compiled end-point function
    rows = list(range(nman, 2 * nman)) + [2 * nman + i for i, k in enumerate(prob.bc_kinds)
                                          if k == "final"]
    if not rows:
        return x, z, False
    sub = rows_of(prob.dense("ends_fun"), rows)

    def fun(v0, vT, p_, T_):  # only the final point moves; w is held at its value
        r, J = sub(v0, vT, p_, T_)
        J[:, :n] = 0.0
        J[:, 2 * n - a.nw:] = 0.0
        return r, J

    v0 = np.concatenate([x, z, w])
    _, vT, res = project_ends(fun, v0, v0, p, T, tol=1e-9)
    if not (res < 1e-6 and np.all(np.isfinite(vT))):
        return x, z, False
    return vT[: a.nx], vT[a.nx:a.nx + a.nz], True


def _start_by_projection(prob, w0, p, vg, lb, ub):
    """The point ``(x, z)`` where the initial conditions and the manifold at ``t = 0`` hold
    (with the controls ``w0``), by Gauss-Newton from ``vg`` with least-norm steps in which the
    algebraic unknowns move 100 times more cheaply than the states (the weights of
    :func:`_consistent_start`'s least squares); None unless all rows hold to 1e-10 (scaled)
    within the bounds ``lb, ub`` (then the least-squares problem decides). A few
    evaluations of the compiled end-point function (its rows at ``t = 0``) instead of
    building and running an IPOPT problem."""
    from .consistency import project_ends, rows_of

    a = prob.aug
    nman = int(prob.man_fun.size1_out(0))
    rows = [2 * nman + i for i, k in enumerate(prob.bc_kinds) if k == "initial"]
    rows += list(range(nman))
    if not rows:
        return None
    n = vg.size
    s = np.ones(n)
    s[a.nx:] = 100.0
    sub = rows_of(prob.dense("ends_fun"), rows)
    w0 = np.asarray(w0, float)

    def fun(u, _vT, _p, _T):
        v0 = np.concatenate([vg + s * u, w0])
        r, J = sub(v0, v0, p, 0.0)
        J = J[:, :n] * s
        return r, np.hstack([J, np.zeros_like(J)])

    u, _, res = project_ends(fun, np.zeros(n), np.zeros(n), None, 0.0, tol=1e-10)
    sol = vg + s * u
    if not (res < 1e-10 and np.all(np.isfinite(sol)) and np.all(sol >= lb)
            and np.all(sol <= ub)):
        return None
    return sol


def _consistent_start(prob, xg, zg, w0, p):
    """Closest point to the initial conditions and guesses on ``alg = 0, invariants = 0``
    (by projection when that meets them all, else by least squares)."""
    a = prob.aug
    n = a.nx + a.nz
    if n == 0:
        return xg, zg
    xlb, xub, zlb, zub, _, _ = prob.simple_bounds()
    vg = np.concatenate([xg, zg])
    lb, ub = np.concatenate([xlb, zlb]), np.concatenate([xub, zub])
    sol = _start_by_projection(prob, w0, p, vg, lb, ub)
    if sol is not None:
        return sol[: a.nx], sol[a.nx:]
    # the least-squares problem (on the initial conditions, then the distance to the guesses)
    v = ca.SX.sym("v", n)
    x, z = seg(v, 0, a.nx), seg(v, a.nx, n)
    vw = ca.vertcat(x, z, ca.DM(w0))
    rows = prob.bc_fun(vw, vw, ca.DM(p), 0.0)
    init = [i for i, k in enumerate(prob.bc_kinds) if k == "initial"]
    obj = ca.sumsqr(ca.vertcat(*[rows[i] for i in init])) if init else 0
    obj = obj + 1e-4 * ca.sumsqr(x - xg) + 1e-8 * ca.sumsqr(z - zg)
    man = prob.man_fun(0.0, vw, ca.DM(p))
    try:
        solver = ca.nlpsol("init", "ipopt", {"x": v, "f": obj, "g": man},
                           {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                            "ipopt.max_iter": 200, "calc_lam_p": False, "no_nlp_grad": True})
        res = solver(x0=np.concatenate([xg, zg]), lbx=np.concatenate([xlb, zlb]),
                     ubx=np.concatenate([xub, zub]), lbg=0, ubg=0)
        sol = np.asarray(res["x"]).ravel()
        if not np.all(np.isfinite(sol)):
            raise RuntimeError("non-finite")
    except RuntimeError:
        return xg, zg
    return sol[: a.nx], sol[a.nx:]
