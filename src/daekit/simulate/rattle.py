"""RATTLE: a symplectic integrator for mechanical systems with holonomic constraints.

The equations of motion of a conservative mechanical system with constraints ``c(q) = 0``
(Lagrange multipliers ``lambda``, constraint Jacobian ``G(q) = dc/dq``) are

    q' = M^{-1} p,    p' = -grad V(q) + F(t, q) - G(q)^T lambda,    0 = c(q).

They are index 3. Index-1 integrators need the reduced form and then drift off ``c = 0`` and
``c' = G q' = 0``; RATTLE (Andersen 1983; Hairer, Lubich, Wanner, *Geometric Numerical
Integration*, ch. VII.1) does not. One step of size ``h`` with ``f(t, q) = -grad V + F``:

    p_{n+1/2} = p_n + h/2 (f(t_n, q_n) - G(q_n)^T lambda_n)
    q_{n+1}   = q_n + h M^{-1} p_{n+1/2}
    0         = c(q_{n+1})                                  (Newton in lambda_n)
    p_{n+1}   = p_{n+1/2} + h/2 (f(t_{n+1}, q_{n+1}) - G(q_{n+1})^T mu_n)
    0         = G(q_{n+1}) M^{-1} p_{n+1}                   (linear in mu_n)

Both the position constraint and the velocity constraint hold to Newton tolerance after every
step, the method is second order, symmetric and symplectic, so for a conservative system the
energy error stays bounded (it oscillates at ``O(h^2)``) over very long times instead of drifting.

For a position-dependent mass matrix ``M(q)`` the generalized (implicit) form for the
Hamiltonian ``H = p^T M(q)^{-1} p / 2 + V(q)`` is used (HLW VII, eq. 1.26): the first half step
is one nonlinear system in ``(p_{n+1/2}, q_{n+1}, lambda_n)``, the second stays linear.

Speed: the whole time loop runs inside CasADi. One step is an SX function (the Newton
iterations unrolled); ``Function.fold`` repeats it between two output times and
``Function.mapaccum`` strings many output intervals together, so Python calls CasADi once per
chunk of about 50,000 steps. Two million pendulum steps take a few seconds.

Example
-------
>>> import casadi as ca, numpy as np
>>> from daekit.simulate.rattle import ConstrainedMechanics, simulate_rattle
>>> q = ca.SX.sym("q", 2)
>>> sys = ConstrainedMechanics(q=q, M=ca.DM.eye(2), V=9.8 * q[1],
...                            c=0.5 * (ca.dot(q, q) - 1), q_names=["x", "y"])
>>> th = np.pi / 6
>>> tr = simulate_rattle(sys, np.linspace(0, 5, 51),
...                      {"x": np.sin(th), "y": -np.cos(th)}, dt=1e-3)
>>> bool(abs(tr["x"][-1] - (-0.47657872558204044491)) < 1e-5)
True
"""

from __future__ import annotations

import time
from typing import Any

import casadi as ca
import numpy as np

from ..errors import InitializationError, ModelError, SimulationError
from ..mechanics.constrained import ConstrainedMechanics, acceleration_name, as_constrained_mechanics
from ..model import fit_elements
from ..wording import count
from .progress import Progress
from .trajectory import Trajectory

__all__ = ["ConstrainedMechanics", "simulate_rattle", "as_constrained_mechanics",
           "rattle_stepper"]

#: default largest step when neither ``dt`` nor a fine output grid is given
DEFAULT_DT = 1e-2
#: steps per CasADi call (a chunk of output intervals runs in one call)
_CHUNK_STEPS = 50_000


def _inv_small(M: ca.SX) -> ca.SX:
    return ca.solve(M, ca.SX.eye(M.shape[0]))


def _trace_callable(key: str, f: Any, t: ca.SX, t_check: Any) -> ca.SX:
    """``f(t)`` as an SX expression, checked against numeric calls at ``t_check``."""
    why = ""
    try:
        got = f(t)
        if isinstance(got, (list, tuple)):
            expr = ca.vertcat(*[ca.SX(e) for e in got])
        else:
            expr = ca.vec(ca.SX(got))
        fe = ca.Function("u", [t], [expr])
        for tc in t_check:
            ref = np.atleast_1d(np.asarray(f(float(tc)), float)).ravel()
            val = np.array(fe(float(tc))).ravel()
            if ref.size != val.size or not np.allclose(val, ref, rtol=1e-12, atol=1e-12):
                why = f"at t = {float(tc):g} the traced function gives {val} instead of {ref}"
                break
        else:
            return expr
    except Exception as exc:  # noqa: BLE001
        why = f"{type(exc).__name__}: {exc}"
    raise SimulationError(
        f"RATTLE: the input {key!r} is a Python function that CasADi cannot trace ({why}); "
        "RATTLE runs its time loop inside CasADi, so give the input as numbers or as a CasADi "
        "expression of time (e.g. ca.sin(t)), or use method='idas'"
    )


def _bind_inputs(
    sysm: ConstrainedMechanics, inputs: Any, t_check: Any = (0.0, 1.0)
) -> tuple[ca.SX, ca.SX]:
    """The force with the inputs replaced by expressions of time, and those expressions.

    ``inputs`` maps names (``"u"``, ``"u[0]"``) to numbers, CasADi SX expressions of one time
    symbol, or Python callables ``f(t)`` built from operations CasADi understands (called once
    with a symbol, then compared with numeric calls at the times ``t_check``). Missing inputs
    are an error.
    """
    nu = sysm.u.numel()
    if not nu:
        if inputs:
            raise SimulationError(
                f"RATTLE: inputs {sorted(inputs)} were given but the mechanical system has none"
            )
        return sysm.force, ca.SX(0, 1)
    inputs = dict(inputs or {})
    vals: list[ca.SX | None] = [None] * nu
    names = sysm.u_names
    for key, val in inputs.items():
        elems = [i for i, nm in enumerate(names) if nm == key or nm.startswith(key + "[")]
        if not elems:
            raise SimulationError(
                f"RATTLE: {key!r} is not an input of this system; its inputs are {names}"
            )
        if callable(val) and not isinstance(val, (ca.SX, ca.DM, ca.MX)):
            expr = _trace_callable(key, val, sysm.t, t_check)
        else:
            if isinstance(val, ca.MX):
                raise SimulationError(f"RATTLE: input {key!r} is MX; give an SX expression")
            expr = ca.vec(val if isinstance(val, ca.SX)
                          else ca.SX(ca.DM(np.atleast_1d(np.asarray(val, float)))))
            free = ca.symvar(expr)
            if len(free) > 1:
                raise SimulationError(
                    f"RATTLE: the input {key!r} depends on {[s.name() for s in free]}; an input "
                    "may depend on time only"
                )
            if free:
                expr = ca.substitute(expr, free[0], sysm.t)
        expr = fit_elements(expr, len(elems), f"RATTLE: input {key!r}", SimulationError)
        for k, i in enumerate(elems):
            vals[i] = expr[k]
    for i in range(nu):  # inputs not given are zero (as in daekit.simulate)
        if vals[i] is None:
            vals[i] = ca.SX(0)
    uexpr = ca.vertcat(*vals)
    return ca.substitute(sysm.force, sysm.u, uexpr), uexpr


# ----------------------------------------------------------------------------------------------
# the step


def _build_step(
    sysm: ConstrainedMechanics, newton_iter: int, force: ca.SX | None = None
) -> tuple[ca.Function, dict]:
    """One RATTLE step ``X -> X+`` with ``X = [t; q; p; lam; max|c|; max|c'|]``, input ``h``.

    ``force``: the applied force with the inputs already replaced (default ``sysm.force``).
    """
    n, m = sysm.n, sysm.m
    pv = ca.DM(sysm.p_values)
    qs, ts = sysm.q, sysm.t
    # substitute parameter values: they are constants during a run
    sub = (lambda e: ca.substitute(e, sysm.p, pv)) if sysm.p.numel() else (lambda e: e)
    force = sysm.force if force is None else force
    Mq, Vq, cq, Fq = sub(sysm.M), sub(sysm.V), sub(sysm.c), sub(force)
    Gq = ca.jacobian(cq, qs)
    fq = -ca.gradient(Vq, qs) + Fq  # applied generalized force
    constant_M = not ca.depends_on(Mq, qs)

    f_fun = ca.Function("f", [ts, qs], [fq])
    c_fun = ca.Function("c", [qs], [cq])
    G_fun = ca.Function("G", [qs], [Gq])

    X = ca.SX.sym("X", 1 + 2 * n + m + 2)
    h = ca.SX.sym("h")
    t0, q0, p0 = X[0], X[1 : 1 + n], X[1 + n : 1 + 2 * n]
    lam = X[1 + 2 * n : 1 + 2 * n + m]
    cmax, cdmax = X[1 + 2 * n + m], X[2 + 2 * n + m]
    t1 = t0 + h
    G0 = G_fun(q0)
    if constant_M:
        Minv = ca.evalf(_inv_small(Mq))
        base = p0 + h / 2 * f_fun(t0, q0)
        W = ca.mtimes(Minv, G0.T)  # n x m
        qfree = q0 + h * ca.mtimes(Minv, base)
        for _ in range(newton_iter):
            Q = qfree - h * h / 2 * ca.mtimes(W, lam)
            J = -h * h / 2 * ca.mtimes(G_fun(Q), W)
            lam = lam - ca.solve(J, c_fun(Q))
        ph = base - h / 2 * ca.mtimes(G0.T, lam)
        q1 = q0 + h * ca.mtimes(Minv, ph)
        G1 = G_fun(q1)
        b = ph + h / 2 * f_fun(t1, q1)
        A = ca.mtimes([G1, Minv, G1.T])
        mu = 2 / h * ca.solve(A, ca.mtimes([G1, Minv, b]))
        p1 = b - h / 2 * ca.mtimes(G1.T, mu)
        cdot = ca.mtimes([G1, Minv, p1])
    else:
        # implicit form for H = p' M(q)^{-1} p / 2 + V(q) - F.q (F frozen)
        ps = ca.SX.sym("ps", n)
        Hp = ca.solve(Mq, ps)  # M^{-1} p
        T = 0.5 * ca.dot(ps, Hp)
        Tq = ca.gradient(T, qs)
        Hp_fun = ca.Function("Hp", [qs, ps], [Hp])
        Tq_fun = ca.Function("Tq", [qs, ps], [Tq])
        Y = ca.SX.sym("Y", 2 * n + m)  # [p_half; q1; lam]
        ph_, q1_, lam_ = Y[:n], Y[n : 2 * n], Y[2 * n :]
        res = ca.vertcat(
            ph_ - p0 - h / 2 * (f_fun(t0, q0) - Tq_fun(q0, ph_) - ca.mtimes(G0.T, lam_)),
            q1_ - q0 - h / 2 * (Hp_fun(q0, ph_) + Hp_fun(q1_, ph_)),
            c_fun(q1_),
        )
        # scale the constraint rows so that the Jacobian is well conditioned for small h
        res = ca.vertcat(res[: 2 * n], res[2 * n :] / (h * h))
        Jres = ca.jacobian(res, Y)
        y = ca.vertcat(p0, q0 + h * Hp_fun(q0, p0), lam)
        step_fun = ca.Function("newton", [Y, X, h], [Y - ca.solve(Jres, res)])
        for _ in range(newton_iter):
            y = step_fun(y, X, h)
        ph, q1, lam = y[:n], y[n : 2 * n], y[2 * n :]
        G1 = G_fun(q1)
        b = ph + h / 2 * (f_fun(t1, q1) - Tq_fun(q1, ph))
        M1 = ca.substitute(Mq, qs, q1)
        MiG = ca.solve(M1, G1.T)
        A = ca.mtimes(G1, MiG)
        mu = 2 / h * ca.solve(A, ca.mtimes(G1, ca.solve(M1, b)))
        p1 = b - h / 2 * ca.mtimes(G1.T, mu)
        cdot = ca.mtimes(G1, ca.solve(M1, p1))
    cres = ca.mmax(ca.fabs(c_fun(q1))) if m else ca.SX(0)
    cdres = ca.mmax(ca.fabs(cdot)) if m else ca.SX(0)
    Xn = ca.vertcat(t1, q1, p1, lam, ca.fmax(cmax, cres), ca.fmax(cdmax, cdres))
    step = ca.Function("rattle_step", [X, h], [Xn], ["X", "h"], ["Xn"])

    # output helpers: velocity, energy, invariants, consistent multiplier and acceleration
    # (index-1 formula): M q'' + M' q' - grad_q T = f - G^T lam,  G q'' + (G q')_q q' = 0
    ps = ca.SX.sym("p", n)
    v = ca.solve(Mq, ps)
    vs = ca.SX.sym("v", n)
    Tv = 0.5 * ca.dot(vs, ca.mtimes(Mq, vs))
    E = 0.5 * ca.dot(ps, v) + Vq
    cd = ca.mtimes(Gq, vs)
    curv = ca.jtimes(cd, qs, vs)
    vel = ca.jtimes(ca.mtimes(Mq, vs), qs, vs) - ca.gradient(Tv, qs) if not constant_M else 0
    rhs = fq - vel
    if m:
        MiGt = ca.solve(Mq, Gq.T)
        lam_c = ca.solve(ca.mtimes(Gq, MiGt), ca.mtimes(Gq, ca.solve(Mq, rhs)) + curv)
        acc = ca.solve(Mq, rhs - ca.mtimes(Gq.T, lam_c))
    else:
        lam_c = ca.SX(0, 1)
        acc = ca.solve(Mq, rhs)
    outs = [ca.substitute(e, vs, v) for e in (cd, lam_c, acc)]
    out = ca.Function("rattle_out", [ts, qs, ps], [v, E, cq] + outs)
    p_of_v = ca.Function("p_of_v", [qs, vs], [ca.mtimes(Mq, vs)])
    helpers = {
        "out": out,
        "p_of_v": p_of_v,
        "c": c_fun,
        "G": G_fun,
        "M": ca.Function("M", [qs], [Mq]),
        "constant_M": constant_M,
    }
    return step, helpers


# ----------------------------------------------------------------------------------------------
# initial values


def _read_init(sysm: ConstrainedMechanics, init: Any) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates and velocities from ``init``: a dict of names (vector or element names),
    an object with ``.values`` (dict), or an array ``[q; v]``."""
    n = sysm.n
    if hasattr(init, "values") and isinstance(init.values, dict):
        init = init.values
    if isinstance(init, dict):
        flat: dict[str, float] = {}
        for k, val in init.items():
            arr = np.atleast_1d(np.asarray(val, float)).ravel()
            if arr.size == 1:
                flat[k] = float(arr[0])
            for i, a in enumerate(arr):
                flat[f"{k}[{i}]"] = float(a)

        def pick(names: list[str], what: str) -> np.ndarray:
            missing = [s for s in names if s not in flat]
            if missing:
                raise InitializationError(
                    f"RATTLE: no initial value for {missing} ({what}); give them in init, "
                    "e.g. from daekit.initialize"
                )
            return np.array([flat[s] for s in names])

        q0 = pick(sysm.q_names, "coordinates")
        if all(s in flat for s in sysm.v_names):
            v0 = pick(sysm.v_names, "velocities")
        else:
            missing = [s for s in sysm.v_names if s not in flat]
            if len(missing) < n:
                pick(sysm.v_names, "velocities")  # raises with the names
            v0 = np.zeros(n)  # no velocities given: start at rest
        return q0, v0
    arr = np.asarray(init, float).ravel()
    if arr.size != 2 * n:
        raise InitializationError(
            f"RATTLE: init has {count(arr.size, 'number')}; give a dict of names or {2 * n} numbers "
            f"[{', '.join(sysm.q_names)}, {', '.join(sysm.v_names)}]"
        )
    return arr[:n], arr[n:]


def _make_consistent(
    sysm: ConstrainedMechanics, helpers: dict, q0: np.ndarray, v0: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Project ``(q0, v0)`` onto ``c = 0, G v = 0`` when they are off by rounding only;
    raise when they are off by more than ``tol``."""
    if sysm.m == 0:
        return q0, v0
    c0 = np.array(helpers["c"](q0)).ravel()
    G0 = np.array(helpers["G"](q0))
    cd0 = G0 @ v0
    names = sysm.constraint_names
    bad = [
        f"{names[i]} = {c0[i]:.3g}" for i in range(sysm.m) if abs(c0[i]) > tol
    ] + [f"d/dt {names[i]} = {cd0[i]:.3g}" for i in range(sysm.m) if abs(cd0[i]) > tol]
    if bad:
        raise InitializationError(
            "RATTLE: the initial values are not consistent: " + ", ".join(bad)
            + "; compute consistent values with daekit.initialize (or fix the coordinates "
            "and velocities so that the constraints and their time derivatives vanish)"
        )
    sv = np.linalg.svd(G0, compute_uv=False)
    if sv.size < sysm.m or sv[-1] <= 1e-10 * max(1.0, sv[0]):
        rows = np.linalg.norm(G0, axis=1)
        weak = [names[i] for i in range(sysm.m) if rows[i] <= 1e-10 * max(1.0, sv[0])]
        raise InitializationError(
            "RATTLE: the constraint Jacobian G = dc/dq does not have full rank at the initial "
            f"point (smallest singular value {sv[-1]:.3g}"
            + (f"; zero rows: {', '.join(weak)}" if weak else "")
            + "): remove redundant constraints or write them so that their gradients are "
            "independent (e.g. not squared)"
        )
    q = q0.copy()
    for _ in range(5):  # Gauss-Newton, minimum norm
        c = np.array(helpers["c"](q)).ravel()
        if np.max(np.abs(c)) < 1e-15:
            break
        G = np.array(helpers["G"](q))
        q = q - G.T @ np.linalg.solve(G @ G.T, c)
    G = np.array(helpers["G"](q))
    Mq = np.array(helpers["M"](q))
    MiGt = np.linalg.solve(Mq, G.T)
    v = v0 - MiGt @ np.linalg.solve(G @ MiGt, G @ v0)  # M-orthogonal projection
    return q, v


# ----------------------------------------------------------------------------------------------
# the driver


def rattle_stepper(system: Any, t_range, params: dict | None = None, inputs: Any = None,
                   newton_iter: int = 8) -> tuple[ConstrainedMechanics, ca.Function, dict]:
    """``(sysm, step, helpers)`` for stepping RATTLE one step at a time (used for events).

    ``step(X, h)`` maps ``X = [t; q; p; lam; max|c|; max|c'|]`` (``p = M q'`` the momenta)
    over one step ``h``; ``helpers["out"](t, q, p)`` gives ``(v, E, c, c', lam, q'')``,
    ``helpers["p_of_v"](q, v)`` the momenta. ``t_range`` (start, end) is where inputs are
    checked.

    >>> import numpy as np
    >>> from daekit.examples.mechanisms import lagrangian_pendulum3d
    >>> sysm, step, helpers = rattle_stepper(lagrangian_pendulum3d(), (0.0, 1.0))
    >>> sysm.n, sysm.m
    (3, 1)
    """
    sysm = as_constrained_mechanics(system, params)
    t0, t1 = float(t_range[0]), float(t_range[1])
    force, uexpr = _bind_inputs(sysm, inputs, (t0, 0.5 * (t0 + t1), t1))
    step, helpers = _build_step(sysm, newton_iter, force)
    helpers["u"] = ca.Function("u", [sysm.t], [uexpr])
    return sysm, step, helpers


def simulate_rattle(
    system: Any,
    t: Any,
    init: Any,
    *,
    dt: float | None = None,
    params: dict | None = None,
    inputs: Any = None,
    newton_iter: int = 4,
    max_newton_iter: int = 16,
    tol: float = 1e-10,
    init_tol: float = 1e-6,
    progress: bool = False,
    rtol: float | None = None,
    atol: float | None = None,
    **unknown: Any,
) -> Any:
    """Simulate a constrained mechanical system with RATTLE on the output grid ``t``.

    Parameters
    ----------
    system : ConstrainedMechanics or a mechanics object (see :func:`as_constrained_mechanics`)
    t : array
        Increasing output times; the first is the initial time.
    init : dict or array
        Initial coordinates and velocities by name (``{"p": [...], "der(p)": [...]}`` or element
        names), an object with a ``values`` dict, or an array ``[q; v]``. They must satisfy
        ``c = 0`` and ``G v = 0`` to ``init_tol``; the remaining rounding is projected away.
    dt : float, optional
        Step size. Each output interval is divided into ``ceil(interval / dt)`` equal steps, so
        when ``dt`` divides the output spacing the steps are exactly ``dt``. Default: the
        output spacing, but at most ``1e-2``.
    params : dict, optional
        Parameter values by name, overriding the defaults.
    inputs : dict, optional
        Values of the system's inputs ``u`` (in the force) by name: numbers, CasADi SX
        expressions of time, or callables ``f(t)`` that CasADi can trace (called once with a
        symbol: ``lambda t: [0, 0, ca.sin(t)]``). RATTLE runs its loop inside CasADi, so an
        opaque Python function is refused with a clear error. Inputs not given are zero.
    newton_iter : int
        Newton iterations per step for the multiplier (unrolled; the starting guess is the
        previous multiplier, so 3-4 iterations reach rounding level). Where that is not enough
        the chunk is redone with twice as many, up to ``max_newton_iter``.
    tol : float
        Largest accepted ``|c|`` and ``|G q'|`` after a step; above it a
        :class:`~daekit.errors.SimulationError` is raised (with the trajectory so far).
    progress : bool
        A progress bar on stderr.

    Returns
    -------
    Trajectory
        Values by name (coordinates, velocities, multipliers), ``invariants`` (the constraints
        and their time derivatives at the output times), and ``stats``: ``steps``, ``dt``,
        ``wall_time``, ``max_c`` and ``max_cdot`` (the largest ``|c|``, ``|c'|`` over *every*
        step, not only the output times), ``energy`` (at the output times) and
        ``energy_error_max``.
    """
    if unknown:
        raise ModelError(
            f"simulate(method='rattle'): unknown {'option' if len(unknown) == 1 else 'options'} "
            f"{sorted(unknown)}; RATTLE takes dt, "
            "params, inputs, newton_iter, max_newton_iter, tol, init_tol, progress (rtol and "
            "atol do not apply: the step size dt sets the accuracy)"
        )
    del rtol, atol  # passed by dk.simulate for every method; RATTLE's accuracy is set by dt
    wall0 = time.perf_counter()
    sysm = as_constrained_mechanics(system, params)
    tt = np.asarray(t, float).ravel()
    if tt.size < 2 or np.any(np.diff(tt) <= 0) or not np.all(np.isfinite(tt)):
        raise SimulationError(
            "RATTLE: the output times t must be finite, increasing and at least two"
        )
    force, uexpr = _bind_inputs(sysm, inputs, (tt[0], 0.5 * (tt[0] + tt[-1]), tt[-1]))
    spacing = np.diff(tt)
    if dt is None:
        dt = min(float(np.min(spacing)), DEFAULT_DT)
    if not dt > 0:
        raise SimulationError(f"RATTLE: the step dt must be positive, got {dt}")
    ratio = spacing / dt
    near = np.round(ratio)
    # a ratio within rounding of an integer is that integer (grids like arange(n) * 0.1)
    ratio = np.where(np.abs(ratio - near) <= 1e-8 * np.maximum(1.0, near), near, ratio)
    nsteps = np.maximum(1, np.ceil(ratio)).astype(int)
    hs = spacing / nsteps

    step, helpers = _build_step(sysm, newton_iter, force)
    helpers["u"] = ca.Function("u", [sysm.t], [uexpr])
    n, m = sysm.n, sysm.m
    q0, v0 = _read_init(sysm, init)
    q0, v0 = _make_consistent(sysm, helpers, q0, v0, init_tol)
    p0 = np.array(helpers["p_of_v"](q0, v0)).ravel()
    X0 = np.concatenate([[tt[0]], q0, p0, np.zeros(m), [0.0, 0.0]])

    # first step's multiplier guess: the consistent multiplier at t0
    lam0 = np.array(helpers["out"](tt[0], q0, p0)[4]).ravel()
    X0[1 + 2 * n : 1 + 2 * n + m] = lam0

    Xs = np.zeros((tt.size, X0.size))
    Xs[0] = X0
    folds: dict[tuple[int, int], ca.Function] = {}
    i = 0
    nout = tt.size - 1
    Xcur = ca.DM(X0)
    bar = Progress(progress, tt[0], tt[-1], "RATTLE") if progress else None
    while i < nout:
        k = int(nsteps[i])
        j = i
        while j < nout and nsteps[j] == k and (j - i + 1) * k <= max(_CHUNK_STEPS, k):
            j += 1
        K = j - i
        if (k, K) not in folds and K > 1:
            K = 1 << (K.bit_length() - 1)  # powers of two: few distinct CasADi Functions
            j = i + K
        key = (k, K)
        if key not in folds:
            Xm = ca.MX.sym("X", X0.size)
            Hm = ca.MX.sym("h")
            Tm = ca.MX.sym("t0")
            Xin = ca.vertcat(Tm, Xm[1:])
            interval = ca.Function(
                "interval", [Xm, Hm, Tm], [step.fold(k)(Xin, ca.repmat(Hm, 1, k))]
            )
            folds[key] = interval.mapaccum(K) if K > 1 else interval
        Xout = folds[key](Xcur, ca.DM(hs[i:j]).T, ca.DM(tt[i:j]).T)
        block = np.array(Xout).T
        nonfinite = ~np.isfinite(block).all(axis=1)
        bad = nonfinite | (block[:, -2] > tol) | (block[:, -1] > tol)
        if np.any(bad) and newton_iter < max_newton_iter:
            # redo this chunk with more Newton iterations before giving up
            newton_iter = min(2 * newton_iter, max_newton_iter)
            step, _ = _build_step(sysm, newton_iter, force)
            folds.clear()
            continue
        Xs[i + 1 : j + 1] = block
        Xcur = Xout[:, -1]
        if np.any(bad):
            first = i + 1 + int(np.argmax(bad))
            if nonfinite[first - i - 1]:
                partial = _assemble(sysm, helpers, tt[:first], Xs[:first], nsteps[: first - 1],
                                    wall0, dt, newton_iter)
                raise SimulationError(
                    f"RATTLE: NaN or Inf between t = {tt[first - 1]:.6g} and {tt[first]:.6g}: "
                    "check the inputs and forces there (a force or input that is NaN) or the "
                    "constraint Jacobian (it must keep full rank)",
                    t=float(tt[first - 1]),
                    trajectory=partial,
                )
            partial = _assemble(sysm, helpers, tt[:first], Xs[:first], nsteps[: first - 1],
                                wall0, dt, newton_iter)
            raise SimulationError(
                f"RATTLE: the Newton iteration for the constraint multipliers did not reach "
                f"|c|, |c'| <= {tol:g} between t = {tt[first - 1]:.6g} and {tt[first]:.6g} "
                f"(max |c| = "
                f"{block[first - i - 1, -2]:.3g}, max |c'| = {block[first - i - 1, -1]:.3g}): "
                "take a smaller dt or more newton_iter, or check that the constraint Jacobian "
                "keeps full rank",
                t=float(tt[first - 1]),
                trajectory=partial,
            )
        if bar is not None:
            bar.update(tt[j])
        i = j
    if bar is not None:
        bar.close()
    return _assemble(sysm, helpers, tt, Xs, nsteps, wall0, dt, newton_iter)


def _assemble(sysm, helpers, tt, Xs, nsteps, wall0, dt, newton_iter):
    n, m = sysm.n, sysm.m
    q = Xs[:, 1 : 1 + n]
    p = Xs[:, 1 + n : 1 + 2 * n]
    N = tt.size
    outm = helpers["out"].map(N) if N > 0 else helpers["out"]
    v, E, c, cd, lam, acc = (np.array(a) for a in outm(tt.reshape(1, -1), q.T, p.T))
    values: dict[str, np.ndarray] = {}
    for i, s in enumerate(sysm.q_names):
        values[s] = q[:, i].copy()
    for i, s in enumerate(sysm.v_names):
        values[s] = v[i].copy()
    for i, s in enumerate(sysm.multiplier_names):
        values[s] = lam[i].copy()
    for i, s in enumerate(sysm.q_names):
        a_name = acceleration_name(s)
        if a_name is not None and a_name not in values:
            values[a_name] = acc[i].copy()
    if sysm.u.numel():
        uval = np.array(helpers["u"].map(N)(tt.reshape(1, -1))) if N else np.zeros((0, 0))
        for i, s in enumerate(sysm.u_names):
            values.setdefault(s, uval[i].copy())
    E = E.ravel()
    inv = np.vstack([c, cd]).T if m else np.zeros((N, 0))
    inv_names = list(sysm.constraint_names) + [f"d/dt {s}" for s in sysm.constraint_names]
    stats = {
        "method": "rattle",
        "steps": int(np.sum(nsteps)),
        "dt": float(dt),
        "newton_iterations": int(np.sum(nsteps)) * newton_iter,
        "wall_time": time.perf_counter() - wall0,
        "max_c": float(Xs[-1, -2]) if N else 0.0,
        "max_cdot": float(Xs[-1, -1]) if N else 0.0,
        "energy": E,
        "energy_error_max": float(np.max(np.abs(E - E[0]))) if N else 0.0,
    }
    return Trajectory(
        t=tt.copy(), values=values, invariants=inv, invariant_names=inv_names, stats=stats
    )
