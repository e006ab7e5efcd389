"""The integrator wrapper shared by every simulation path: a ReducedDAE with its inputs plugged in.

:class:`System` holds the CasADi functions of one ReducedDAE (with ``u(t)`` substituted) and
makes SUNDIALS IDAS grid integrators on demand. One call of :meth:`System.run` is one
continuous IDAS run over a time grid: IDAS steps by its own error control and *interpolates*
the grid points (``IDA_NORMAL`` mode), so a grid point never restarts nor limits a step. Every
run starts without IDACalcIC from ``xdot0 = ode(x0, z0)`` (the driver only starts from values
it made consistent: ``z0`` solved from ``alg = 0``), with a first step that depends on the
tolerances and the state's derivative, not on the output grid (see :meth:`System.step0`).
What SUNDIALS prints is captured (:func:`daekit._cio.c_output`) and never reaches the console;
a failure raises :class:`IntegrationFailure` with the time SUNDIALS reported.

Systems are cached *on the ReducedDAE object itself* (:meth:`ReducedDAE.derived`), keyed by
its equations, inputs and settings: the cache lives and dies with the system it belongs to.

Example
-------
>>> import casadi as ca, numpy as np
>>> from daekit.reduced import ReducedDAE
>>> from daekit.inputs import InputSignal
>>> from daekit.simulate.system import system_for
>>> t = ca.SX.sym("t"); x = ca.SX.sym("x"); z = ca.SX.sym("z")
>>> r = ReducedDAE(t, x, z, ca.SX(0, 1), ca.SX(0, 1), -z, z - x, ca.SX(0, 1), [], ["x"],
...     ["z"], [], [], np.zeros(0), {"x": x, "z": z})
>>> s = system_for(r, InputSignal(r, None), 1e-10, 1e-10, {})
>>> X, Z, st = s.run(np.array([0.0, 0.5, 1.0]), np.array([1.0]), np.array([1.0]), np.zeros(0))
>>> bool(abs(X[-1, 0] - np.exp(-1)) < 1e-8), st["steps"] > 0
(True, True)
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Mapping

import casadi as ca
import numpy as np
import scipy.sparse as sp

from .._cio import c_output, failure_time
from ..inputs import InputError, InputSignal, signal_for
from ..numerics import FastFunction, fast_call
from .trajectory import LazyColumns, Trajectory
from .vectorized import evaluate_columns, evaluate_rows, rows_equal

__all__ = ["System", "system_for", "signal_for", "Evaluator", "IntegrationFailure", "reason",
           "make_trajectory", "reraise_input_error", "to_scipy", "stats_of", "evaluator_of",
           "StateColumns", "check_sized_options", "SIZED_OPTIONS"]

_IDA_REASONS = {
    "IDA_CONV_FAIL": "the Newton iteration failed to converge repeatedly (the algebraic "
    "equations may have no solution here, or their Jacobian d alg/dz is singular)",
    "IDA_ERR_FAIL": "the error test failed repeatedly (a fast transient, a discontinuity, or a "
    "singularity of the solution)",
    "IDA_TOO_MUCH_WORK": "too many steps (max_num_steps) between two grid points: the problem "
    "is stiff or has a singularity; raise max_num_steps",
    "IDA_TOO_MUCH_ACC": "the tolerances are too tight for double precision",
    "IDA_LSETUP_FAIL": "the linear solver setup failed (singular iteration matrix: the "
    "constraint Jacobian lost rank)",
    "IDA_LSOLVE_FAIL": "the linear solve failed (singular iteration matrix)",
    "IDA_RES_FAIL": "the residual function failed (a NaN or an exception while evaluating "
    "the equations)",
    "IDA_REP_RES_ERR": "repeated recoverable residual errors",
    "IDA_CONSTR_FAIL": "constraints could not be met",
    "IDA_FIRST_RES_FAIL": "the residual failed at the first call (NaN at the initial point?)",
    "IDA_NO_RECOVERY": "the Newton iteration could not recover (singular algebraic Jacobian)",
    "IDA_BAD_EWT": "an error weight became zero or negative (a component went to zero with "
    "atol = 0, or NaN)",
}


def reason(exc: BaseException | str) -> str:
    """A plain-language reason for an IDAS failure message.

    >>> reason("... IDA_CONV_FAIL ...").startswith("IDA_CONV_FAIL: the Newton iteration")
    True
    """
    msg = str(exc)
    for flag, text in _IDA_REASONS.items():
        if flag in msg:
            return f"{flag}: {text}"
    m = re.search(r"(IDA\w+)", msg)
    tail = msg.strip().splitlines()[-1] if msg.strip() else type(exc).__name__
    return (m.group(1) + ": " if m else "") + tail[-300:]


class IntegrationFailure(RuntimeError):
    """IDAS failed inside :meth:`System.run`: ``.t`` where SUNDIALS stopped (or the start),
    ``.text`` what it said (captured), ``.why`` the plain-language reason."""

    def __init__(self, message: str, t: float, text: str, why: str) -> None:
        super().__init__(message)
        self.t, self.text, self.why = t, text, why


def to_scipy(M: ca.DM) -> sp.csc_matrix:
    """A CasADi sparse DM as a SciPy CSC matrix (no dense intermediate).

    >>> import casadi as ca
    >>> to_scipy(ca.DM([[1, 0], [0, 2]])).toarray().tolist()
    [[1.0, 0.0], [0.0, 2.0]]
    """
    M = ca.DM(M)
    s = M.sparsity()
    colind, row = s.get_ccs()
    return sp.csc_matrix((np.asarray(M.nonzeros(), dtype=float), row, colind), shape=M.shape)


def stats_of(raw: Mapping | None) -> dict:
    """daekit's statistics names from CasADi's integrator statistics.

    >>> st = stats_of({"nsteps": 3, "nlinsetups": 2})
    >>> st["steps"], st["jacobian_evaluations"]
    (3, 2)
    """
    s = raw or {}
    return {
        "steps": int(s.get("nsteps", 0)),
        "residual_evaluations": int(s.get("nfevals", 0)),
        # (IDAS's Jacobian setups of this run: CasADi's n_call_jacF counts every call of the
        # integrator's Jacobian function since it was made, over all runs of a reused one)
        "jacobian_evaluations": int(s.get("nlinsetups", 0)),
        "error_test_failures": int(s.get("netfails", 0)),
        "newton_failures": int(s.get("nncfails", 0)),
    }


class Evaluator:
    """Original variables and invariants of a ReducedDAE at many points.

    Variables that are plain elements of ``x``, ``z`` or ``u`` are read off the arrays; only the
    others (and the invariants) go through one mapped CasADi Function.

    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x"); z = ca.SX.sym("z")
    >>> r = ReducedDAE(t, x, z, ca.SX(0, 1), ca.SX(0, 1), -z, z - x, x - 1, ["c"], ["x"],
    ...     ["z"], [], [], np.zeros(0), {"x": x, "z": z, "der(x)": -z})
    >>> vals, inv = Evaluator(r)(np.zeros(2), np.ones((2, 1)), np.ones((2, 1)),
    ...                          np.zeros((2, 0)), np.zeros(0))
    >>> vals["der(x)"].tolist(), inv[:, 0].tolist()
    ([-1.0, -1.0], [0.0, 0.0])
    """

    def __init__(self, r) -> None:
        names = list(r.variables)
        exprs = [ca.SX(r.variables[n]) for n in names]
        for i, nm in enumerate(r.u_names):
            if nm not in r.variables:
                names.append(nm)
                exprs.append(r.u[i])
        self.names = names
        where: dict[int, tuple[str, int]] = {}
        for key, vec in (("x", r.x), ("z", r.z), ("u", r.u)):
            for i in range(vec.numel()):
                where[vec[i].element_hash()] = (key, i)
        self.direct: dict[str, tuple[str, int]] = {}
        self.const: dict[str, float] = {}
        rest_names, rest = [], []
        for n, e in zip(names, exprs, strict=True):
            if e.numel() == 1 and e.is_symbolic() and e.element_hash() in where:
                self.direct[n] = where[e.element_hash()]
            elif e.numel() == 1 and e.is_constant():
                self.const[n] = float(ca.DM(e))
            else:
                rest_names.append(n)
                rest.append(e)
        self.rest_names = rest_names
        self._r = r
        inv = r.invariants if r.invariants.numel() else ca.SX(0, 1)
        allv = ca.vertcat(*rest) if rest else ca.SX(0, 1)
        self.nv = int(allv.numel())
        self.ninv = int(inv.numel())
        self.fun = ca.Function("evaluate", [r.t, r.x, r.z, r.u, r.p], [allv, inv])
        self.inv_fun = ca.Function("invariants", [r.t, r.x, r.z, r.u, r.p], [inv])
        self._maps: dict[tuple, ca.Function] = {}

    def _mapped(self, F: ca.Function, n: int) -> ca.Function:
        key = (F.name(), n)
        if key not in self._maps:
            if len(self._maps) > 8:
                self._maps.clear()
            self._maps[key] = F.map(n)
        return self._maps[key]

    def invariants(self, t, X, Z, U, p) -> np.ndarray:
        """Invariant values ``(N, ninv)`` at the points ``t (N,)``, ``X``, ``Z``, ``U``."""
        t = np.asarray(t, dtype=float).ravel()
        n = t.size
        if n == 0 or self.ninv == 0:
            return np.zeros((n, self.ninv))
        P = np.repeat(np.asarray(p, dtype=float).reshape(1, -1), n, axis=0)
        return evaluate_rows(self.inv_fun, [t, X, Z, U, P], self._maps.setdefault("inv", {}))[0]

    def values(self, t, X, Z, U, p):
        """``({name: (N,)} of the variables that are not plain elements, None)``: one mapped
        call of the rest (the invariants are :meth:`invariants`)."""
        n = t.size
        if n == 0 or not self.nv:
            return {k: np.zeros(n) for k in self.rest_names}, None
        if "rest" not in self.__dict__:
            r = self._r
            allv = ca.vertcat(*[ca.SX(r.variables[k]) if k in r.variables else
                                r.u[r.u_names.index(k)] for k in self.rest_names])
            self.rest = ca.Function("evaluate_rest", [r.t, r.x, r.z, r.u, r.p], [allv])
        P = np.repeat(np.asarray(p, dtype=float).reshape(1, -1), n, axis=0)
        V = evaluate_rows(self.rest, [t, X, Z, U, P], self._maps.setdefault("rest", {}))[0].T
        return {k: np.ascontiguousarray(V[i]) for i, k in enumerate(self.rest_names)}, None

    def __call__(self, t, X, Z, U, p):
        """t (N,), X (N, nx), Z (N, nz), U (N, nu) -> (values dict, invariants (N, ninv))."""
        n = t.size
        if n == 0:
            return {k: np.zeros(0) for k in self.names}, np.zeros((0, self.ninv))
        arrays = {"x": X, "z": Z, "u": U}
        if self.nv or self.ninv:
            fm = self._mapped(self.fun, n)
            P = np.repeat(np.asarray(p, dtype=float).reshape(1, -1), n, axis=0)
            ni = fm.name_in()
            out = fast_call(fm, {ni[0]: t, ni[1]: X, ni[2]: Z, ni[3]: U, ni[4]: P},
                            {fm.name_out(0): (n, self.nv), fm.name_out(1): (n, self.ninv)})
            V = out[fm.name_out(0)].T
            inv = out[fm.name_out(1)]
        else:
            V, inv = np.zeros((0, n)), np.zeros((n, 0))
        rest = {k: V[i] for i, k in enumerate(self.rest_names)}
        vals = {}
        for k in self.names:
            if k in self.direct:
                a, i = self.direct[k]
                vals[k] = arrays[a][:, i]
            elif k in self.const:
                vals[k] = np.full(n, self.const[k])
            else:
                vals[k] = rest[k]
        return vals, inv


def _padded(n: int) -> int:
    """Sizes of mapped Functions: up to 64 exact, then powers of two (few distinct maps)."""
    return n if n <= 64 else 1 << (n - 1).bit_length()


def _pad(A, m: int) -> np.ndarray:
    """Rows of ``A`` padded to ``m`` by repeating the last one."""
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    if n == m:
        return A
    reps = np.repeat(A[-1:], m - n, axis=0) if n else np.zeros((m,) + A.shape[1:])
    return np.concatenate([A, reps], axis=0)


def evaluator_of(r) -> Evaluator:
    """The :class:`Evaluator` of ``r``, made once per system (it depends on ``r`` alone)."""
    return r.derived("simulate.evaluator", Evaluator)


def make_trajectory(r, tg, X, Z, U, pv, stats, evaluator: Evaluator | None = None) -> Trajectory:
    """The :class:`Trajectory` of ``r`` from state arrays on the grid ``tg``: the values that
    are elements of ``x``, ``z``, ``u`` at once, the other variables and the invariants when
    first read (:class:`~daekit.simulate.trajectory.LazyColumns`, one mapped CasADi call)."""
    ev = evaluator or evaluator_of(r)
    tg = np.asarray(tg, dtype=float).ravel()
    n = tg.size
    X = np.array(X, dtype=float, copy=True).reshape(n, r.nx)
    Z = np.array(Z, dtype=float, copy=True).reshape(n, r.nz)
    U = np.array(U, dtype=float, copy=True).reshape(n, r.nu)
    pv = np.asarray(pv, dtype=float).ravel()
    recipe = StateColumns(r, tg, X, Z, U, pv, ev)
    cols = LazyColumns(recipe.ready(), ev.rest_names, recipe.rest, order=ev.names, recipe=recipe)
    inv = (lambda: ev.invariants(tg, X, Z, U, pv)) if ev.ninv else None
    return Trajectory(tg, cols, inv, list(r.invariant_names), stats)


class StateColumns:
    """A trajectory's columns from its state arrays: ``ready()`` those that are elements of
    ``x``, ``z``, ``u`` (views) or constants, ``rest()`` the others (one mapped CasADi call).
    Pickled as the system and the arrays (inside
    :func:`~daekit.simulate.trajectory.compact_pickling` only); unpickled, it evaluates with
    that system's own :class:`Evaluator`, made once per system."""

    def __init__(self, r, tg, X, Z, U, pv, ev: Evaluator | None = None) -> None:
        self.r, self.tg, self.X, self.Z, self.U, self.pv = r, tg, X, Z, U, pv
        self.ev = ev if ev is not None else evaluator_of(r)

    def ready(self) -> dict:
        n = self.tg.size
        arrays = {"x": self.X, "z": self.Z, "u": self.U}
        out = {k: arrays[a][:, i] for k, (a, i) in self.ev.direct.items()}
        out.update({k: np.full(n, v) for k, v in self.ev.const.items()})
        return out

    def rest(self) -> dict:
        vals, _ = self.ev.values(self.tg, self.X, self.Z, self.U, self.pv)
        return vals

    def __reduce__(self):
        U = self.U
        if U.ndim == 2 and U.shape[0] > 1 and U.shape[1] and rows_equal(U):
            # constant inputs (zero, the common case) as one row: a fifth of the bytes of a
            # 3D-pendulum trajectory an ensemble's worker sends
            return (_with_constant_inputs, (self.r, self.tg, self.X, self.Z, U[0].copy(),
                                            U.shape[0], self.pv))
        return (StateColumns, (self.r, self.tg, self.X, self.Z, U, self.pv))


def _with_constant_inputs(r, tg, X, Z, u_row, n, pv) -> StateColumns:
    """A :class:`StateColumns` whose inputs are ``u_row`` at every one of the ``n`` rows."""
    return StateColumns(r, tg, X, Z, np.repeat(u_row[None, :], n, axis=0), pv)


def reraise_input_error(system: System) -> None:
    """Re-raise the InputError a Python input callable raised inside an integrator call."""
    cb = getattr(system.ufun, "_daekit_cb", None) if system.ufun is not None else None
    if cb is not None and cb.error is not None:
        err = cb.error
        cb.error = None
        raise err


def _fingerprint(r) -> tuple:
    """Identity of a ReducedDAE's equations (a copy with replaced equations differs)."""
    return (id(r.ode), id(r.alg), id(r.invariants), id(r.variables), id(r.x), id(r.z))


def system_for(r, sig: InputSignal, rtol: float, atol: float, options: Mapping) -> System:
    """The :class:`System` of ``r`` for these inputs and settings, built once and kept on ``r``
    (no global cache: it is freed with ``r``). Callable inputs are never cached."""
    if sig.has_callables:
        return System(r, sig, rtol, atol, options)
    try:
        # the input by its serialized function, not its printed form: printing rounds
        # constants to ~6 digits, and two different inputs must not share an integrator
        u_key = "none" if getattr(sig, "default", False) else \
            ca.Function("u_key", [r.t], [sig.expr]).serialize()
        key = (_fingerprint(r), u_key, float(rtol), float(atol), repr(sorted(options.items())))
    except Exception:  # noqa: BLE001 - unprintable option: no caching
        return System(r, sig, rtol, atol, options)
    cache = r.derived("simulate.systems", lambda r: {})
    hit = cache.get(key)
    if hit is not None:
        return hit
    sysm = System(r, sig, rtol, atol, options)
    if len(cache) >= 8:
        cache.pop(next(iter(cache)))
    cache[key] = sysm
    return sysm


class System:
    """A ReducedDAE with its inputs plugged in, ready for CasADi IDAS integrators.

    Parameters
    ----------
    r : ReducedDAE
    sig : InputSignal
        The inputs ``u(t)``.
    rtol, atol : float
        IDAS tolerances.
    options : dict
        Extra CasADi IDAS options (``max_num_steps``, ``suppress_algebraic``, ...).
    """

    #: steps IDAS may take between two grid points in a first attempt (a failing attempt gives
    #: up early; the driver's grids have check points, so intervals are short; the last retry
    #: gets the user's ``max_num_steps``, default 100000)
    first_budget = 3000

    def __init__(self, r, sig: InputSignal, rtol: float, atol: float, options: Mapping) -> None:
        self.r = r
        self.sig = sig
        self.nx, self.nz, self.nu = r.nx, r.nz, r.nu
        self.rtol, self.atol = float(rtol), float(atol)
        self.options = dict(options)
        ode = ca.vec(r.ode) if r.ode.numel() else ca.SX(0, 1)  # 1x0 and 0x1 alike
        alg = ca.vec(r.alg) if r.alg.numel() else ca.SX(0, 1)
        self.f = ca.Function("daefun", [r.t, r.x, r.z, r.p, r.u], [ode, alg])
        self.use_mx = sig.has_callables
        self.ufun = sig.mx_function() if self.use_mx else None
        self._grid: dict = {}
        self._alg_fun = None
        self._alg_res: FastFunction | None = None
        self._alg_newton: ca.Function | bool | None = None
        self._alg_newton_fast: FastFunction | bool | None = None
        self._f_fast = FastFunction(self.f)  # (a restart evaluates it: microseconds, not SWIG)
        self._oracle = None

    # ------------------------------------------------------------------ functions
    @property
    def evaluator(self) -> Evaluator:
        return evaluator_of(self.r)

    @property
    def alg_fun(self) -> ca.Function:
        """``(t, x, z, u, p) -> (alg, d alg/dz)`` (sparse)."""
        if self._alg_fun is None:
            r = self.r
            alg = ca.vec(r.alg) if r.alg.numel() else ca.SX(0, 1)
            self._alg_fun = ca.Function("alg", [r.t, r.x, r.z, r.u, r.p],
                                        [alg, ca.jacobian(alg, r.z)])
        return self._alg_fun

    def xdot(self, t, x, z, u, p) -> np.ndarray:
        """``ode(t, x, z, u, p)`` as a NumPy vector."""
        return self._f_fast(t, np.ravel(x), np.ravel(z), np.ravel(p), np.ravel(u))[0]

    def solve_z(self, t, x, z, u, p, iters: int = 30) -> np.ndarray:
        """Newton on ``alg = 0`` for ``z`` at fixed ``x`` (sparse LU of ``d alg/dz``)."""
        z = np.asarray(z, dtype=float).ravel().copy()
        if self.nz == 0:
            return z
        if self._alg_res is None:
            r = self.r
            alg = ca.vec(r.alg) if r.alg.numel() else ca.SX(0, 1)
            # raw buffers, one per thread: a residual check costs microseconds
            self._alg_res = FastFunction(ca.Function("alg_res", [r.t, r.x, r.z, r.u, r.p],
                                                     [alg]))
        out = self._alg_res(*(np.ravel(v) for v in (t, x, z, u, p)))[0]
        gmax = float(np.abs(out).max())  # (NaN propagates: the test below fails)
        if gmax < 1e-14 * (1 + float(np.abs(z).max())):
            return z  # already consistent (the common case: one cheap evaluation)
        step = self._newton_step()
        for _ in range(iters):
            if step is not None:  # (residual and Newton step in one buffered call)
                g, dz = step(*(np.ravel(v) for v in (t, x, z, u, p)))
            else:
                g, Jz = self.alg_fun(t, x, z, u, p)
                g, dz = np.asarray(g, dtype=float).ravel(), None
            if not np.all(np.isfinite(g)):
                break
            if np.max(np.abs(g)) < 1e-14 * (1 + np.max(np.abs(z))):
                break
            if dz is None or not np.all(np.isfinite(dz)):
                dz = _sparse_solve(to_scipy(self.alg_fun(t, x, z, u, p)[1]), -g)
            z = z + dz
            if np.max(np.abs(dz)) < 1e-15 * (1 + np.max(np.abs(z))):
                break
        return z

    def _newton_function(self) -> ca.Function | None:
        """``(t, x, z, u, p) -> (alg, -(d alg/dz)^-1 alg)``: the Newton step on ``alg = 0`` as
        one generated function (CasADi's symbolic sparse QR of ``d alg/dz``) for up to 16
        algebraic unknowns; None beyond, or where it is structurally singular or long (then
        sparse LU in SciPy)."""
        if self._alg_newton is None:
            self._alg_newton = False
            if self.nz <= 16:
                r = self.r
                alg = ca.vec(r.alg) if r.alg.numel() else ca.SX(0, 1)
                try:
                    f = ca.Function("alg_step", [r.t, r.x, r.z, r.u, r.p],
                                    [alg, ca.densify(-ca.solve(ca.jacobian(alg, r.z), alg))])
                except RuntimeError:
                    f = None
                if f is not None and f.n_instructions() <= 5000:
                    self._alg_newton = f
        return self._alg_newton or None

    def _newton_step(self) -> FastFunction | None:
        """:meth:`_newton_function` through raw buffers (one point: microseconds)."""
        if self._alg_newton_fast is None:
            f = self._newton_function()
            self._alg_newton_fast = FastFunction(f) if f is not None else False
        return self._alg_newton_fast or None

    def polish_z(self, T, X, Z, U, p, iters: int = 4) -> np.ndarray:
        """``Z`` re-solved from ``alg = 0`` at many points at once (rows of ``T, X, Z, U``):
        batched Newton with the dense ``d alg/dz`` blocks (``nz <= 64``; else row by row)."""
        Z = np.array(Z, dtype=float, copy=True)
        n = np.size(T)
        if self.nz == 0 or n == 0:
            return Z
        if self.nz > 64:
            for i in range(n):
                Z[i] = self.solve_z(T[i], X[i], Z[i], U[i], p)
            return Z
        if getattr(self, "_alg_dense", None) is None:
            r = self.r
            alg = ca.vec(r.alg) if r.alg.numel() else ca.SX(0, 1)
            Jz = ca.jacobian(alg, r.z)
            self._alg_dense = ca.Function("alg_dense", [r.t, r.x, r.z, r.u, r.p],
                                          [alg, ca.densify(Jz)])
            self._alg_maps = {}
            # few unknowns: the Newton step itself as one function (CasADi's symbolic sparse
            # QR of d alg/dz), evaluated for all rows at once in column layout
            self._alg_step, self._alg_step_maps = self._newton_function(), {}
        if self._alg_step is not None:
            return self._polish_columns(T, X, Z, U, p, iters)
        P = np.repeat(np.asarray(p, dtype=float).reshape(1, -1), n, axis=0)
        nz = self.nz
        T, X, U = np.asarray(T, float).ravel(), np.asarray(X, float), np.asarray(U, float)
        for _ in range(iters):
            g, Jnz = evaluate_rows(self._alg_dense, [T, X, Z, U, P], self._alg_maps)
            if not np.all(np.isfinite(g)):
                break
            if np.max(np.abs(g)) < 1e-15 * (1 + np.max(np.abs(Z))):
                break
            J = np.transpose(Jnz.reshape(n, nz, nz), (0, 2, 1))  # column-major blocks
            try:
                dz = np.linalg.solve(J, -g[..., None])[..., 0]
            except np.linalg.LinAlgError:
                break
            if not np.all(np.isfinite(dz)):
                break
            Z += dz
        return Z

    def _polish_columns(self, T, X, Z, U, p, iters: int) -> np.ndarray:
        """:meth:`polish_z` by the generated Newton step, in column layout."""
        n = np.size(T)
        Tc = np.asarray(T, float).reshape(1, n)
        Xc = np.ascontiguousarray(np.asarray(X, float).reshape(n, -1).T)
        Zc = np.ascontiguousarray(np.asarray(Z, float).reshape(n, -1).T)
        U = np.asarray(U, float).reshape(n, -1)
        Uc = U[:1].T.copy() if not U.size or rows_equal(U) else np.ascontiguousarray(U.T)
        Pc = np.asarray(p, float).reshape(-1, 1)
        for _ in range(iters):
            g, dz = evaluate_columns(self._alg_step, [Tc, Xc, Zc, Uc, Pc], n,
                                     self._alg_step_maps)
            if not np.isfinite(g).all():
                break
            if np.abs(g).max() < 1e-15 * (1 + np.abs(Zc).max()):
                break
            if not np.isfinite(dz).all():
                break
            Zc += dz
        return np.ascontiguousarray(Zc.T)

    def step0(self, x0, xdot0, span: float, xddot0=None) -> float:
        """The first step: IDAS's own rule ``min(1e-3 span, 0.5 / ||xdot0||_wrms)`` with ``span``
        the whole simulated time span, never the first output interval (see issue 8 item 6);
        ``5e-7 span`` for index-2 systems (GGL). Given an estimate ``xddot0`` of the second
        derivative (a restart where the solution goes on smoothly), CVODE's rule for a first
        step of order 1 instead (``CVHin``, Hindmarsh et al. 2005): ``0.5 sqrt(2 /
        ||xddot0||_wrms)``, the step whose local error estimate ``h^2 |x''| / 2`` is a quarter
        of the tolerance (at most ``1e-3 span``). IDAS's rule ignores the curvature and starts
        far smaller (the 3D pendulum at rtol 1e-8: 5e-9 against 3e-5); measured on it, a run of
        10 s cut into 4 segments from 10 starts: 14742 -> 13934 steps at rtol 1e-8, 8900 -> 7730
        at 1e-6 (8 segments: 17334 -> 16379, 9940 -> 9460).

        >>> import casadi as ca, numpy as np
        >>> from daekit.reduced import ReducedDAE
        >>> from daekit.inputs import InputSignal
        >>> t = ca.SX.sym("t"); x = ca.SX.sym("x", 2)
        >>> r = ReducedDAE(t, x, ca.SX(0, 1), ca.SX(0, 1), ca.SX(0, 1), ca.vertcat(x[1], -x[0]),
        ...     ca.SX(0, 1), ca.SX(0, 1), [], ["x", "v"], [], [], [], np.zeros(0))
        >>> s = System(r, InputSignal(r, None), 1e-6, 1e-6, {})
        >>> x0, xd, xdd = np.array([1.0, 0.0]), np.array([0.0, -1.0]), np.array([-1.0, 0.0])
        >>> h = s.step0(x0, xd, 10.0, xdd)   # ||x''||_wrms = 1 / (2e-6 sqrt(2))
        >>> bool(np.isclose(h, 0.5 * np.sqrt(2 * 2e-6 * np.sqrt(2))))
        True
        >>> s.step0(x0, xd, 10.0) < h          # IDAS's rule: 0.5 / ||x'||_wrms
        True
        """
        if self.r.index >= 2:
            # index 2 (GGL): the Newton matrix has condition ~ 1/h, and tiny first steps fail
            # (measured: the pendulum's GGL form at rtol 1e-10): a moderate step, 5e-7 of the
            # span (never of the output spacing: with one output interval it used to fail)
            return 5e-7 * span
        w = 1.0 / (self.rtol * np.abs(np.asarray(x0, float)) + self.atol)
        nrm = float(np.sqrt(np.mean((np.asarray(xdot0, float) * w) ** 2))) if w.size else 0.0
        h = 1e-3 * span
        if nrm * h > 0.5:
            h = 0.5 / nrm
        if xddot0 is not None and w.size:
            n2 = float(np.sqrt(np.mean((np.asarray(xddot0, float) * w) ** 2)))
            if math.isfinite(n2) and n2 > 0:
                h = max(h, min(0.5 * math.sqrt(2.0 / n2), 1e-3 * span))
        return max(h, 1e-14 * max(1.0, span))

    # ------------------------------------------------------------------ integrators
    def _dae(self) -> ca.Function:
        """The DAE as one CasADi Function (IDAS's oracle), built once: every integrator made
        from it shares its derivative functions, so a new integrator costs about a millisecond."""
        if self._oracle is None:
            r = self.r
            S = ca.MX if self.use_mx else ca.SX
            if self.use_mx:
                t = ca.MX.sym("t")
                x, z, p = ca.MX.sym("x", self.nx), ca.MX.sym("z", self.nz), ca.MX.sym("p", r.n_p)
                ode, alg = self.f(t, x, z, p, self.ufun(t))
            else:
                t, x, z, p = r.t, r.x, r.z, r.p
                ode, alg = self.f(t, x, z, p, self.sig.expr)
            self._oracle = ca.Function("daekit_dae", [t, x, z, p, S(0, 1)],
                                       [ode, alg, S(0, 1), S(0, 1)],
                                       ["t", "x", "z", "p", "u"], ["ode", "alg", "quad", "zero"])
        return self._oracle

    def options_for(self, extra: Mapping | None = None) -> dict:
        o = {"abstol": self.atol, "reltol": self.rtol, "max_num_steps": 100000,
             "show_eval_warnings": False, "disable_internal_warnings": True}
        o.update(self.options)
        if extra:
            o.update(extra)
        return o

    def integrator(self, grid: np.ndarray, extra: Mapping | None = None) -> ca.Function:
        """A CasADi IDAS integrator from ``grid[0]`` with output at ``grid[1:]`` (kept for reuse:
        the last few grids)."""
        grid = np.asarray(grid, dtype=float)
        key = (grid.tobytes(), repr(sorted((extra or {}).items())))
        F = self._grid.get(key)
        if F is None:
            if len(self._grid) >= 6:
                self._grid.pop(next(iter(self._grid)))
            opts = self.options_for(extra)
            try:
                F = ca.integrator("daekit_idas", "idas", self._dae(), float(grid[0]),
                                  [float(v) for v in grid[1:]], opts)
            except RuntimeError as exc:
                raise _option_error(exc, opts) from None
            self._grid[key] = F
        return F

    def run(self, grid, x0, z0, p, extra: Mapping | None = None, consistent: bool = True,
            span: float | None = None, xddot0=None):
        """One continuous IDAS run over ``grid`` from ``(x0, z0)`` at ``grid[0]``.

        ``consistent=True``: no IDACalcIC; IDAS starts from ``xdot0 = ode(x0, z0)`` with the
        first step :meth:`step0` (``span``: the time scale, default the grid's). ``extra``:
        further IDAS options for this run. Returns ``(X, Z, stats)`` with ``X (len(grid), nx)``
        (row 0 the start); raises :class:`IntegrationFailure`.
        """
        grid = np.asarray(grid, dtype=float)
        n = grid.size
        x0 = np.asarray(x0, dtype=float).ravel()
        z0 = np.asarray(z0, dtype=float).ravel()
        opts = dict(extra or {})
        if consistent and "calc_ic" not in self.options:
            u0 = self.sig.value(float(grid[0])) if not self.use_mx else \
                np.asarray(self.ufun(float(grid[0])), dtype=float).ravel()
            xd = self.xdot(float(grid[0]), x0, z0, u0, p)
            opts.setdefault("calc_ic", False)
            if "init_xdot" not in opts:
                opts["init_xdot"] = [float(v) for v in xd]
            if "step0" not in self.options:
                opts.setdefault("step0", self.step0(x0, xd, float(span or (grid[-1] - grid[0])),
                                                    xddot0))
        F = self.integrator(grid, _hashable(opts))
        X = np.empty((n, self.nx))
        Z = np.empty((n, self.nz))
        X[0], Z[0] = x0, z0
        with c_output() as said:
            try:
                if not self.use_mx:
                    res = fast_call(F, {"x0": x0, "z0": z0, "p": p},
                                    {"xf": (n - 1, self.nx), "zf": (n - 1, self.nz)},
                                    want_stats=True)
                    raw = res["_stats"]
                    X[1:], Z[1:] = res["xf"], res["zf"]
                else:
                    res = F(x0=x0, z0=z0, p=p)
                    try:
                        raw = F.stats()
                    except Exception:  # noqa: BLE001
                        raw = {}
                    X[1:] = np.asarray(res["xf"], dtype=float).reshape(self.nx, -1).T
                    Z[1:] = np.asarray(res["zf"], dtype=float).reshape(self.nz, -1).T
                failed = None
            except RuntimeError as exc:
                failed = exc
        if failed is not None:
            reraise_input_error(self)
            tf = failure_time(said.text)
            if tf is None or not math.isfinite(tf) or tf < grid[0]:
                tf = float(grid[0])
            why = reason(said.text if "IDA_" in said.text else failed)
            raise IntegrationFailure(f"IDAS failed at t = {tf:.6g}: {why}", tf, said.text, why)
        return X, Z, stats_of(raw)


def _hashable(opts: Mapping) -> dict:
    return {k: (list(v) if isinstance(v, (list, tuple, np.ndarray)) else v)
            for k, v in opts.items()}


def _sparse_solve(A: sp.csc_matrix, b: np.ndarray) -> np.ndarray:
    """``A x = b`` by sparse LU; least squares where ``A`` is singular or not square."""
    if A.shape[0] == A.shape[1]:
        try:
            with np.errstate(all="ignore"):
                x = sp.linalg.splu(A.tocsc()).solve(b)
            if np.all(np.isfinite(x)):
                return x
        except RuntimeError:
            pass
    return sp.linalg.lsqr(A, b, atol=1e-15, btol=1e-15, iter_lim=10 * max(A.shape))[0]


#: Keywords of ``simulate`` that are not IDAS options (the events path's own settings).
EVENT_KEYWORDS = ("event_spacing", "zeno_count", "zeno_window", "max_events", "use_driver")


#: IDAS options with one value per unknown: ``{name: which unknowns}`` ("xz": the states then
#: the algebraic unknowns, "x": the states)
SIZED_OPTIONS = {"abstolv": "xz", "constraints": "xz", "init_xdot": "x"}


def check_sized_options(r, options: Mapping, reselects: bool = False) -> None:
    """Raise :class:`~daekit.inputs.InputError` unless every IDAS option with one value per
    unknown (``abstolv``, ``constraints``, ``init_xdot``) has one for each unknown of ``r``
    (CasADi does not check ``abstolv``: a wrong length corrupts memory). ``reselects``: the
    system changes its unknowns during the run (dummy derivatives), so such options cannot
    apply.

    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x"); z = ca.SX.sym("z")
    >>> r = ReducedDAE(t, x, z, ca.SX(0, 1), ca.SX(0, 1), -z, z - x, ca.SX(0, 1), [], ["x"],
    ...     ["z"], [], [], np.zeros(0), {"x": x, "z": z})
    >>> check_sized_options(r, {"abstolv": [1e-8, 1e-6]})
    >>> try:
    ...     check_sized_options(r, {"abstolv": [1e-8]})
    ... except ValueError as err:
    ...     print(str(err)[:86])
    simulate: abstolv needs one value per unknown, in this order: ['x', 'z'] (2); got 1
    """
    for name, which in SIZED_OPTIONS.items():
        if name not in options:
            continue
        if reselects:
            raise InputError(
                f"simulate: {name} gives one value per unknown, but dummy derivatives change "
                f"the unknowns at every re-selection of the states; use atol= and rtol= (or "
                f"another stabilization)")
        names = list(r.x_names) + (list(r.z_names) if which == "xz" else [])
        try:
            values = np.asarray(options[name], dtype=float)
            n = values.size if values.ndim == 1 else -1
        except (TypeError, ValueError):
            n = -1
        if n != len(names):
            raise InputError(
                f"simulate: {name} needs one value per unknown, in this order: {names[:20]}"
                f"{' ...' if len(names) > 20 else ''} ({len(names)}); got "
                f"{n if n >= 0 else _described(options[name])}")


def _described(value) -> str:
    """What a sized option was given instead of a vector: an array's shape, else its type."""
    shape = getattr(value, "shape", None)
    return f"an array of shape {tuple(shape)}" if shape is not None else type(value).__name__


def check_idas_options(options: Mapping) -> None:
    """Raise :class:`~daekit.inputs.InputError` naming the first keyword of ``options`` that
    CasADi's IDAS does not take (or takes with another type), before any work is done: a
    trivial integrator is built with them (about a millisecond).

    >>> check_idas_options({"max_num_steps": 1000})
    >>> try:
    ...     check_idas_options({"max_num_stepz": 1000})
    ... except ValueError as err:
    ...     print(str(err)[:90])
    simulate: 'max_num_stepz' is not an option of CasADi's IDAS integrator. Did you mean 'max_
    """
    opts = {k: v for k, v in options.items() if k not in EVENT_KEYWORDS}
    # (options with one value per unknown are checked against the system itself, see
    # check_sized_options: on the trivial system a wrong length is no error, and an abstolv
    # of the wrong length corrupts SUNDIALS' memory: the process aborts)
    opts = {k: v for k, v in opts.items() if k not in SIZED_OPTIONS}
    if not opts:
        return
    x = ca.SX.sym("x")
    try:
        ca.integrator("daekit_check", "idas", {"x": x, "ode": -x}, 0.0, [1.0], opts)
    except RuntimeError as exc:
        raise _option_error(exc, opts) from None


_UNKNOWN_OPTION = re.compile(r"Unknown option: (\w+)")
_SUGGESTION = re.compile(r'> "(\w+)"')


def _option_error(exc: RuntimeError, opts: Mapping) -> Exception:
    """CasADi's refusal of an integrator option as a daekit error naming it (other failures
    are passed on unchanged: they are not the user's options)."""
    text = str(exc)
    hit = _UNKNOWN_OPTION.search(text)
    if hit is None:
        if "option" in text.lower() and any(str(k) in text for k in opts):
            bad = [str(k) for k in opts if str(k) in text]
            return InputError(f"simulate: the IDAS option(s) {bad} were refused by CasADi: "
                              f"{text.splitlines()[0][-200:]}")
        return exc
    name = hit.group(1)
    near = difflib.get_close_matches(name, _SUGGESTION.findall(text), n=3, cutoff=0.6)
    hint = f" Did you mean {' or '.join(repr(n) for n in near)}?" if near else ""
    return InputError(
        f"simulate: {name!r} is not an option of CasADi's IDAS integrator.{hint} daekit's own "
        "settings are rtol=, atol=, stabilization=, drift_tol=, inputs=, params=; other keywords "
        "go to IDAS (see casadi.integrator's documentation, e.g. max_num_steps, max_order)."
    )
