"""Simulation of a ReducedDAE with SUNDIALS IDAS (through CasADi), with drift control.

The integrator is built once from SX expressions. Without stabilization (or with Baumgarte,
which is a transform of the equations) a single IDAS run covers the whole output grid. With
``"projection"`` or ``"dummy_derivatives"`` the run is split at the output points: a second
integrator in scaled time ``t = ta + s h``, ``s in [0, 1]`` (``ta``, ``h`` passed as parameters) is
built once and called for every interval, so changing the interval costs no rebuild.
"""

from __future__ import annotations

import math
import re
import sys
import time
import weakref
from collections.abc import Mapping

import casadi as ca
import numpy as np

from .._cio import c_output, failure_time
from ..errors import SimulationError
from ..reduced import ReducedDAE
from ..reduction.accept import as_reduced
from ..wording import count
from .inputs import InputError, InputSignal, resolve_params
from .projection import Projector
from .trajectory import Trajectory

__all__ = ["simulate"]

STABILIZATIONS = (None, "baumgarte", "projection", "dummy_derivatives")

_IDA_REASONS = {
    "IDA_CONV_FAIL": "the Newton iteration failed to converge repeatedly (the algebraic "
    "equations may have no solution here, or their Jacobian d alg/dz is singular)",
    "IDA_ERR_FAIL": "the error test failed repeatedly (a fast transient, a discontinuity, or a "
    "singularity of the solution)",
    "IDA_TOO_MUCH_WORK": "too many steps (max_num_steps) in one output interval: the problem is "
    "stiff or has a singularity; raise max_num_steps or use a finer output grid",
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


def _reason(exc: Exception) -> str:
    msg = str(exc)
    for flag, text in _IDA_REASONS.items():
        if flag in msg:
            return f"{flag}: {text}"
    m = re.search(r"(IDA\w+|IDACalcIC\w*|[Cc]alc_?ic\w*)", msg)
    if "IDACalcIC" in msg or "calc_ic" in msg.lower():
        return "consistent initialization (IDACalcIC) failed: check the initial values"
    tail = msg.strip().splitlines()[-1] if msg.strip() else type(exc).__name__
    return (m.group(1) + ": " if m else "") + tail[-300:]


class _Evaluator:
    """Original variables and invariants of a ReducedDAE at many points.

    Variables that are plain elements of ``x``, ``z`` or ``u`` are read off the arrays; only the
    others (and the invariants) go through one mapped CasADi Function.
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
        inv = r.invariants if r.invariants.numel() else ca.SX(0, 1)
        allv = ca.vertcat(*rest) if rest else ca.SX(0, 1)
        self.nv = int(allv.numel())
        self.ninv = int(inv.numel())
        self.fun = ca.Function("evaluate", [r.t, r.x, r.z, r.u, r.p], [allv, inv])
        self._maps: dict[int, ca.Function] = {}

    def __call__(self, t, X, Z, U, p):
        """t (N,), X (N, nx), Z (N, nz), U (N, nu) -> (values dict, invariants (N, ninv))."""
        n = t.size
        if n == 0:
            return {k: np.zeros(0) for k in self.names}, np.zeros((0, self.ninv))
        arrays = {"x": X, "z": Z, "u": U}
        if self.nv or self.ninv:
            if n not in self._maps:
                if len(self._maps) > 4:
                    self._maps.clear()
                self._maps[n] = self.fun.map(n)
            fm = self._maps[n]
            P = np.repeat(np.asarray(p, dtype=float).reshape(1, -1), n, axis=0)
            ni = fm.name_in()
            out = _fast_call(fm, {ni[0]: t, ni[1]: X, ni[2]: Z, ni[3]: U, ni[4]: P},
                             {fm.name_out(0): (n, self.nv), fm.name_out(1): (n, self.ninv)})
            V = out[fm.name_out(0)].T
            I = out[fm.name_out(1)].T
        else:
            V, I = np.zeros((0, n)), np.zeros((0, n))
        rest = {k: V[i] for i, k in enumerate(self.rest_names)}
        out = {}
        for k in self.names:
            if k in self.direct:
                a, i = self.direct[k]
                out[k] = arrays[a][:, i]
            elif k in self.const:
                out[k] = np.full(n, self.const[k])
            else:
                out[k] = rest[k]
        return out, I.T


def _fast_call(F: ca.Function, args: Mapping[str, np.ndarray], outs: Mapping[str, tuple],
               want_stats: bool = False):
    """Call a CasADi Function writing straight into NumPy arrays (``Function.buffer``): no
    DM round trip. Inputs and outputs are row-major ``(points, size)`` arrays, i.e. CasADi's
    column-major ``(size, points)``; ``outs`` maps output names to such shapes. Returns
    ``{name: array}``; raises RuntimeError like a normal call."""
    buf, ev = F.buffer()
    keep = []
    for i, name in enumerate(F.name_in()):
        a = args.get(name)
        # arrays are (points, size) row-major = CasADi's (size, points) column-major
        a = np.zeros(F.nnz_in(i)) if a is None else np.ascontiguousarray(a, dtype=float).ravel()
        if a.size != F.nnz_in(i):
            raise ValueError(f"{F.name()}: input {name} has {a.size} values, needs {F.nnz_in(i)}")
        keep.append(a)
        buf.set_arg(i, memoryview(a))
    res = {}
    for i, name in enumerate(F.name_out()):
        shape = outs.get(name)
        r = np.zeros(shape if shape is not None else F.nnz_out(i))
        if r.size != F.nnz_out(i):
            raise ValueError(f"{F.name()}: output {name} has {F.nnz_out(i)} values")
        keep.append(r)
        buf.set_res(i, memoryview(r))
        if shape is not None:
            res[name] = r
    ev()
    if want_stats:
        try:
            res["_stats"] = buf.stats()
        except Exception:  # noqa: BLE001
            res["_stats"] = {}
    return res


_CACHE: dict[tuple, tuple] = {}
_CACHE_SIZE = 16


def _fingerprint(r) -> tuple:
    """Identity of a ReducedDAE's equations (a copy with replaced equations differs)."""
    return (id(r), id(r.ode), id(r.alg), id(r.invariants), id(r.variables), id(r.x), id(r.z))


def _cached_system(r, sig: InputSignal, rtol: float, atol: float, options: Mapping) -> _System:
    """The _System (functions, integrators, evaluator) of ``r`` for these inputs and settings,
    reused across calls of :func:`simulate` on the same system: the integrator is built once."""
    if sig.has_callables:
        return _System(r, sig, rtol, atol, options)
    try:
        # the input expression by its serialized function, not its printed form: printing
        # rounds constants to ~6 digits, and two different inputs must not share an integrator
        u_key = ca.Function("u_key", [r.t], [sig.expr]).serialize() if sig.expr is not None \
            else None
        key = (_fingerprint(r), u_key, float(rtol), float(atol), repr(sorted(options.items())))
    except Exception:  # noqa: BLE001 - unprintable option: no caching
        return _System(r, sig, rtol, atol, options)
    hit = _CACHE.get(key)
    if hit is not None and hit[0]() is r:
        return hit[1]
    sysm = _System(r, sig, rtol, atol, options)
    if len(_CACHE) >= _CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = (weakref.ref(r), sysm)
    return sysm


class _System:
    """A ReducedDAE with its inputs plugged in, ready for CasADi integrators."""

    def __init__(self, r, sig: InputSignal, rtol: float, atol: float, options: Mapping) -> None:
        self.r = r
        self.sig = sig
        self.nx, self.nz = r.nx, r.nz
        self.rtol, self.atol = rtol, atol
        self.options = dict(options)
        f = ca.Function("daefun", [r.t, r.x, r.z, r.p, r.u], [r.ode, r.alg])
        self.f = f
        self.use_mx = sig.has_callables
        self.ufun = sig.mx_function() if self.use_mx else None
        self._scaled = None
        self._grid: dict = {}
        self._evaluator = None
        self.alg_fun = ca.Function(
            "alg", [r.t, r.x, r.z, r.u, r.p], [r.alg, ca.jacobian(r.alg, r.z)]
        )

    def _opts(self, extra: Mapping | None = None) -> dict:
        o = {"abstol": self.atol, "reltol": self.rtol, "max_num_steps": 100000,
             "show_eval_warnings": False, "disable_internal_warnings": True}
        o.update(self.options)
        if extra:
            o.update(extra)
        return o

    def _exprs(self, sym, tt):
        """(t, x, z, p, ode, alg) with u(t) substituted, SX or MX."""
        r = self.r
        if self.use_mx:
            x = ca.MX.sym("x", self.nx)
            z = ca.MX.sym("z", self.nz)
            p = ca.MX.sym("p", r.n_p)
            u = self.ufun(tt(sym))
            ode, alg = self.f(tt(sym), x, z, p, u)
            return x, z, p, ode, alg
        u = ca.substitute(self.sig.expr, r.t, tt(sym))
        ode, alg = self.f(tt(sym), r.x, r.z, r.p, u)
        return r.x, r.z, r.p, ode, alg

    def grid_integrator(self, t: np.ndarray, extra: Mapping | None = None):
        key = (np.asarray(t, dtype=float).tobytes(), repr(sorted((extra or {}).items())))
        if key not in self._grid:
            sym = ca.MX.sym("t") if self.use_mx else self.r.t
            x, z, p, ode, alg = self._exprs(sym, lambda s: s)
            dae = {"t": sym, "x": x, "z": z, "p": p, "ode": ode, "alg": alg}
            if len(self._grid) >= 4:
                self._grid.pop(next(iter(self._grid)))
            self._grid[key] = ca.integrator("daekit_idas", "idas", dae, float(t[0]),
                                            [float(v) for v in t[1:]], self._opts(extra))
        return self._grid[key]

    @property
    def evaluator(self) -> _Evaluator:
        if self._evaluator is None:
            self._evaluator = _Evaluator(self.r)
        return self._evaluator

    def xdot(self, t, x, z, u, p) -> np.ndarray:
        return np.asarray(self.f(t, x, z, p, u)[0], dtype=float).ravel()

    def scaled_integrator(self, points: int = 1):
        """Integrator over s in [0, 1] with t = ta + s h, output at s = k/points, k = 1..points;
        p_full = (p, ta, h). Built once per ``points``."""
        if self._scaled is None:
            self._scaled = {}
        if points not in self._scaled:
            S = ca.MX if self.use_mx else ca.SX
            s = S.sym("s")
            ta = S.sym("ta")
            h = S.sym("h")
            x, z, p, ode, alg = self._exprs(s, lambda q: ta + q * h)
            dae = {"t": s, "x": x, "z": z, "p": ca.vertcat(p, ta, h), "ode": h * ode, "alg": alg}
            grid = [k / points for k in range(1, points + 1)]
            self._scaled[points] = ca.integrator(f"daekit_idas_step{points}", "idas", dae, 0.0,
                                                 grid, self._opts())
        return self._scaled[points]

    def solve_z(self, t, x, z, u, p, iters: int = 30) -> np.ndarray:
        """Newton on alg for z at fixed x (consistent algebraic values)."""
        z = np.asarray(z, dtype=float).ravel().copy()
        if self.nz == 0:
            return z
        for _ in range(iters):
            g, Jz = self.alg_fun(t, x, z, u, p)
            g = np.asarray(g, dtype=float).ravel()
            if np.max(np.abs(g)) < 1e-14 * (1 + np.max(np.abs(z))):
                break
            dz = np.linalg.lstsq(np.asarray(Jz.full(), float), -g, rcond=1e-13)[0]
            z = z + dz
            if np.max(np.abs(dz)) < 1e-15 * (1 + np.max(np.abs(z))):
                break
        return z


def _stats_of(F, wall: float, raw: dict | None = None) -> dict:
    s = raw
    if s is None:
        try:
            s = F.stats()
        except Exception:  # noqa: BLE001
            s = {}
    return {
        "steps": int(s.get("nsteps", 0)),
        "residual_evaluations": int(s.get("nfevals", 0)),
        "jacobian_evaluations": int(s.get("n_call_jacF", 0)),
        "error_test_failures": int(s.get("netfails", 0)),
        "newton_failures": int(s.get("nncfails", 0)),
        "integrator_wall_time": wall,
    }


def _add_stats(total: dict, part: dict) -> None:
    for k, v in part.items():
        total[k] = total.get(k, 0) + v


class _Progress:
    def __init__(self, enabled: bool, t0: float, tf: float, label: str) -> None:
        self.enabled = enabled and tf > t0
        self.t0, self.tf, self.label = t0, tf, label
        self.last = -1

    def update(self, t: float) -> None:
        if not self.enabled:
            return
        frac = min(max((t - self.t0) / (self.tf - self.t0), 0.0), 1.0)
        pct = int(frac * 100)
        if pct == self.last:
            return
        self.last = pct
        bar = "#" * (pct // 4) + "." * (25 - pct // 4)
        sys.stderr.write(f"\r{self.label} [{bar}] {pct:3d}%  t = {t:.4g}")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()


def _check_grid(t) -> np.ndarray:
    try:
        tg = np.asarray(t, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError("simulate: t must be an array of output times") from None
    if tg.size < 2:
        raise InputError(
            "simulate: t must hold at least two output times, e.g. np.linspace(0, 10, 1001)"
        )
    if not np.all(np.isfinite(tg)) or np.any(np.diff(tg) <= 0):
        raise InputError("simulate: the output times t must be finite and strictly increasing")
    return tg


def _initial_state(r, init, t0, inputs, params, sig, pv, system) -> tuple[np.ndarray, np.ndarray]:
    from ..initialize import InitialValues, initialize

    if init is None:
        raise InputError(
            "simulate: initial values are needed: init = dk.initialize(r, guess={...}, "
            "fixed={...})"
        )
    if isinstance(init, Mapping):
        init = initialize(r, t0, guess=init, inputs=inputs, params=params)
    if isinstance(init, InitialValues):
        ip = np.asarray(init.p, dtype=float).ravel()
        other_t0 = abs(float(init.t0) - t0) > 1e-12 * max(1.0, abs(t0))
        other_p = ip.size == np.size(pv) and not np.allclose(ip, pv, rtol=1e-12, atol=0.0)
        u0 = sig.value(t0)
        if list(init.x_names) == list(r.x_names):
            x0 = np.asarray(init.x0, dtype=float)
        else:
            try:
                x0 = np.array([init.values[n] for n in r.x_names], dtype=float)
            except KeyError as exc:
                raise InputError(
                    f"simulate: the initial values do not contain the state {exc.args[0]!r} of "
                    "this system; call dk.initialize on this system"
                ) from None
        if list(init.z_names) == list(r.z_names):
            z0 = np.asarray(init.z0, dtype=float)
        else:
            z0 = np.array([init.values.get(n, 0.0) for n in r.z_names], dtype=float)
        z0 = system.solve_z(t0, x0, z0, u0, pv)
        if (other_t0 or other_p) and r.invariants.numel():
            # made for another start time or other parameters: fine if still consistent
            inv = np.asarray(ca.Function("inv0", [r.t, r.x, r.z, r.u, r.p], [r.invariants])(
                t0, x0, z0, u0, pv), dtype=float).ravel()
            scale = 1.0 + np.max(np.abs(x0), initial=0.0)
            bad = [r.invariant_names[i] for i in np.nonzero(np.abs(inv) > 1e-8 * scale)[0]]
            if bad:
                why = (f"at t0 = {init.t0:g} while the grid starts at t = {t0:g}" if other_t0
                       else "with other parameter values")
                raise InputError(
                    f"simulate: the initial values were computed {why}, and at the grid's start "
                    f"they violate the consistency conditions {bad[:5]}; call dk.initialize with "
                    "the same t0 and params as dk.simulate"
                )
        return x0, z0
    try:
        arr = np.asarray(init, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError(
            f"simulate: init must be InitialValues (dk.initialize), a dict of guesses, or an "
            f"array of the {count(r.nx, 'state')}; got {type(init).__name__}"
        ) from None
    if arr.size == r.nx:
        x0 = arr
        z0 = system.solve_z(t0, x0, np.zeros(r.nz), sig.value(t0), pv)
        return x0, z0
    if arr.size == r.nx + r.nz:
        return arr[: r.nx], arr[r.nx:]
    raise InputError(
        f"simulate: init must be InitialValues (dk.initialize), a dict of guesses, or an array "
        f"of the {count(r.nx, 'state')}; got {count(arr.size, 'number')}"
    )


def simulate(
    r,
    t,
    init,
    inputs: Mapping | None = None,
    params: Mapping | None = None,
    stabilization: str | None = None,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    method: str = "idas",
    progress: bool = False,
    poles=(-1.0, -1.0),
    **options,
) -> Trajectory:
    """Simulate a reduced (index-1) DAE and return its :class:`Trajectory`.

    Parameters
    ----------
    r : ReducedDAE
        From :func:`daekit.reduce_index` (or by hand). A Model or a LagrangianSystem is reduced
        automatically (:func:`daekit.reduction.as_reduced`; ``traj.stats["reduced"]`` says how).
    t : array
        Output times, strictly increasing; ``t[0]`` is the initial time.
    init : InitialValues, dict or array
        Consistent initial values from :func:`daekit.initialize` (a dict is taken as guesses for
        it; an array as the state vector ``x0``, ``z0`` then solved from ``alg = 0``).
    inputs : dict, optional
        ``{control name: f}`` with ``f`` a Python callable of ``t`` or a CasADi SX expression of
        time (``r.t`` or the model's ``m.t``). Input derivatives the reduction needs are
        differentiated automatically from expressions; for callables give them explicitly
        (``{"u": f, "der(u)": df}``). Controls not given are zero.
    params : dict, optional
        Parameter values overriding the defaults (``{"L": 2.0}``).
    stabilization : None, "baumgarte", "projection" or "dummy_derivatives"
        Drift control. ``"baumgarte"`` integrates ``daekit.baumgarte(r, poles)``;
        ``"projection"`` projects (Gauss--Newton, minimum norm) onto ``{alg = 0, invariants = 0}``
        after every output step and restarts; ``"dummy_derivatives"`` needs ``r`` from
        ``reduce_index(model, method="dummy_derivatives")`` and re-selects the states when the
        selection's pivot degrades.
    rtol, atol : float
        IDAS tolerances.
    method : "idas" or "rattle"
        ``"rattle"`` dispatches to :func:`daekit.simulate.rattle.simulate_rattle`.
    progress : bool
        A progress bar on stderr (without stabilization the whole grid is one IDAS run, so the
        bar shows its start and end; projection and dummy derivatives advance it per step).
    poles : pair of float
        Baumgarte poles.
    **options
        Passed to the CasADi IDAS integrator (e.g. ``max_num_steps``). For an index-2 system
        (``dk.ggl(r)``) ``suppress_algebraic=True`` is the default.

    Raises
    ------
    SimulationError
        When IDAS fails: ``.t`` is the time, ``.trajectory`` the solution so far.
    daekit.simulate.inputs.InputError
        On bad inputs (a NaN from an input names that input).

    Example
    -------
    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> from daekit.initialize import initialize
    >>> from daekit.simulate import simulate
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x"); z = ca.SX.sym("z")
    >>> r = ReducedDAE(t, x, z, ca.SX(0, 1), ca.SX(0, 1), -z, z - x, ca.SX(0, 1), [], ["x"],
    ...     ["z"], [], [], np.zeros(0), {"x": x, "z": z, "der(x)": -z})
    >>> traj = simulate(r, np.linspace(0, 1, 11), initialize(r, fixed={"x": 1.0}))
    >>> bool(abs(traj["x"][-1] - np.exp(-1)) < 1e-7)
    True
    """
    wall0 = time.perf_counter()
    notes: list[str] = []
    if not isinstance(r, ReducedDAE) and not (method == "rattle" and hasattr(r, "index1")):
        # a Model (or LagrangianSystem): reduced once with the default method, noted in stats
        r = as_reduced(r, "simulate", stabilization=stabilization, method=method, notes=notes)
    if method == "rattle":
        from .rattle import simulate_rattle

        if stabilization is not None:
            raise InputError(
                f"simulate: method='rattle' keeps the constraints by construction and takes no "
                f"stabilization (got {stabilization!r}); drop stabilization= or use method='idas'"
            )
        traj = simulate_rattle(
            r, t, init, inputs=inputs, params=params, rtol=rtol, atol=atol, progress=progress,
            **options,
        )
        if notes:
            traj.stats["reduced"] = notes[0]
        return traj
    if method != "idas":
        raise InputError(f"simulate: unknown method {method!r}; use 'idas' or 'rattle'")
    if isinstance(stabilization, str) and stabilization.lower() == "none":
        stabilization = None
    if stabilization not in STABILIZATIONS:
        raise InputError(
            f"simulate: unknown stabilization {stabilization!r}; use None, 'baumgarte', "
            "'projection' or 'dummy_derivatives'"
        )
    for name, tol in (("rtol", rtol), ("atol", atol)):
        if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
            raise InputError(f"simulate: {name} must be a positive number, got {tol!r}")
    tg = _check_grid(t)

    r_int = r
    if stabilization == "baumgarte":
        from ..reduction import baumgarte

        r_int = baumgarte(r, poles=poles)
    if stabilization == "dummy_derivatives" and getattr(r, "method", "") != "dummy_derivatives":
        raise InputError(
            "simulate: stabilization='dummy_derivatives' needs a system from "
            "dk.reduce_index(model, method='dummy_derivatives'); this one was made by "
            f"{getattr(r, 'method', '?')!r}"
        )

    if r_int.info.get("index", 1) >= 2 and "suppress_algebraic" not in options:
        # an index-2 form (GGL): its algebraic unknowns are not controlled by the BDF error
        # test (the index-2 variables' errors do not converge at the order of the method),
        # else IDAS takes tiny steps (Brenan, Campbell, Petzold 1996, sec. 5.4)
        options = {**options, "suppress_algebraic": True}
    pv = resolve_params(r_int, params)
    sig = InputSignal(r_int, inputs)
    U = sig.values(tg)  # NaN check on the grid (names the input)
    system = _cached_system(r_int, sig, rtol, atol, options)
    x0, z0 = _initial_state(r_int, init, float(tg[0]), inputs, params, sig, pv, system)
    if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(z0))):
        raise InputError("simulate: the initial values contain NaN or infinity")

    if r_int.nx == 0:
        # nothing to integrate (e.g. Gear-Petzold, or L2 by dummy derivatives): the solution
        # is alg(t, z, u(t)) = 0 at each output time, solved by Newton from the previous point
        traj = _run_algebraic(r_int, system, tg, z0, U, pv)
    elif stabilization == "dummy_derivatives":
        from .dummy import simulate_dummy

        traj = simulate_dummy(r_int, tg, x0, z0, inputs, params, sig, pv, system, progress,
                              rtol, atol, options)
    elif stabilization == "projection":
        traj = _run_intervals(r_int, system, tg, x0, z0, U, pv, Projector(r_int), progress,
                              label="projection")
    else:
        # one IDAS run over the whole grid, also with progress=True: restarting at every output
        # point would change the method (BDF order back to 1) and the result
        bar = _Progress(progress, tg[0], tg[-1], "simulate")
        bar.update(tg[0])
        try:
            traj = _run_grid(r_int, system, tg, x0, z0, U, pv)
        finally:
            bar.update(tg[-1])
            bar.close()
    traj.stats["wall_time"] = time.perf_counter() - wall0
    traj.stats["stabilization"] = stabilization
    if notes:
        traj.stats["reduced"] = notes[0]
    return traj


def _make_trajectory(r, tg, X, Z, U, pv, stats, evaluator=None) -> Trajectory:
    ev = evaluator or _Evaluator(r)
    vals, inv = ev(tg, X, Z, U, pv)
    return Trajectory(tg, vals, inv, list(r.invariant_names), stats)


def _run_grid(r, system: _System, tg, x0, z0, U, pv) -> Trajectory:
    """One IDAS run over the whole grid (CasADi's defaults, IDACalcIC included). Should it
    fail, a second attempt starts from xdot0 = ode(x0, z0) without IDACalcIC (the initial values
    are consistent: z0 was solved from alg), excludes the algebraic unknowns from the error
    test and starts with a tiny step (fully implicit index-1 models with fast inputs, such as
    the transistor amplifier, need it); if that fails too, an interval-by-interval run locates
    the failure and returns the partial trajectory."""
    attempts: list[dict] = [{}]
    if r.info.get("index", 1) >= 2 and "calc_ic" not in system.options:
        # index 2 (GGL): the initial values are consistent (initialize works on the index-1
        # system), and IDACalcIC as well as very small first steps make the index-2 Newton
        # matrix (condition ~ 1/h) fail: start from xdot0 = ode(x0, z0) with a moderate step
        spacing = float(np.min(np.diff(tg)))
        attempts.insert(0, {"calc_ic": False, "init_xdot": None, "step0": 1e-4 * spacing})
    if "calc_ic" not in system.options and "suppress_algebraic" not in system.options:
        span = float(tg[-1] - tg[0])
        attempts.append({"calc_ic": False, "init_xdot": None,
                         "suppress_algebraic": True, "step0": 1e-12 * max(1.0, span)})
    first_error = None
    for k, extra in enumerate(attempts):
        if "init_xdot" in extra and extra["init_xdot"] is None:
            extra = {**extra, "init_xdot": list(system.xdot(tg[0], x0, z0, U[0], pv))}
        F = system.grid_integrator(tg, extra)
        w0 = time.perf_counter()
        n = tg.size
        X = np.empty((n, r.nx))
        Z = np.empty((n, r.nz))
        X[0], Z[0] = x0, z0
        try:
            if not system.use_mx:
                with c_output():  # SUNDIALS' messages; a failure is retried interval-wise
                    res = _fast_call(F, {"x0": x0, "z0": z0, "p": pv},
                                     {"xf": (n - 1, r.nx), "zf": (n - 1, r.nz)},
                                     want_stats=True)
                raw_stats = res["_stats"]
                X[1:], Z[1:] = res["xf"], res["zf"]
            else:
                res = F(x0=x0, z0=z0, p=pv)
                raw_stats = None
                X[1:] = np.asarray(res["xf"], dtype=float).reshape(r.nx, -1).T
                Z[1:] = np.asarray(res["zf"], dtype=float).reshape(r.nz, -1).T
        except RuntimeError as exc:
            _reraise_input_error(system)
            first_error = first_error or exc
            continue
        wall = time.perf_counter() - w0
        stats = _stats_of(F, wall, raw_stats)
        if k:
            stats["note"] = (f"first IDAS attempt failed ({_reason(first_error)}); succeeded "
                             "with the algebraic unknowns excluded from the error test")
        return _make_trajectory(r, tg, X, Z, U, pv, stats, system.evaluator)
    # locate the failure: interval by interval (only on failure)
    return _run_intervals(r, system, tg, x0, z0, U, pv, None, False, label="simulate",
                          first_error=first_error)


def _run_algebraic(r, system: _System, tg, z0, U, pv) -> Trajectory:
    """A system without differential states: Newton on ``alg = 0`` at every output time."""
    w0 = time.perf_counter()
    n = tg.size
    X = np.zeros((n, 0))
    Z = np.empty((n, r.nz))
    Z[0] = z0
    x = np.zeros(0)
    for k in range(1, n):
        Z[k] = system.solve_z(tg[k], x, Z[k - 1], U[k], pv)
        g = np.asarray(system.alg_fun(tg[k], x, Z[k], U[k], pv)[0], dtype=float).ravel()
        if not np.all(np.isfinite(g)) or np.max(np.abs(g), initial=0.0) > 1e-8 * (
            1 + np.max(np.abs(Z[k]), initial=0.0)
        ):
            partial = _make_trajectory(r, tg[:k], X[:k], Z[:k], U[:k], pv, {})
            raise SimulationError(
                f"simulate: no state to integrate, and Newton on the algebraic equations failed "
                f"at t = {tg[k]:g} (residual {np.max(np.abs(g)):.3g}); the trajectory up to "
                f"t = {tg[k - 1]:g} is attached as .trajectory.",
                t=float(tg[k]),
                trajectory=partial,
            )
    stats = {"steps": 0, "newton_solves": n - 1, "integrator_wall_time": time.perf_counter() - w0,
             "note": "no differential states: algebraic equations solved at each output time"}
    return _make_trajectory(r, tg, X, Z, U, pv, stats, system.evaluator)


def _check_inputs_at(system: _System, t: float) -> None:
    """Raise the InputError naming an input that is NaN or infinite at ``t`` (a failure inside an
    output interval is often an input's fault, e.g. sqrt of a negative number)."""
    if system.sig.has_callables:
        return
    system.sig.value(t)


def _reraise_input_error(system: _System) -> None:
    cb = getattr(system.ufun, "_daekit_cb", None) if system.ufun is not None else None
    if cb is not None and cb.error is not None:
        err = cb.error
        cb.error = None
        raise err


def _run_intervals(r, system: _System, tg, x0, z0, U, pv, proj, progress, label="simulate",
                   first_error=None) -> Trajectory:
    F = system.scaled_integrator()
    n = tg.size
    X = np.zeros((n, r.nx))
    Z = np.zeros((n, r.nz))
    X[0], Z[0] = x0, z0
    if proj is not None:
        X[0], Z[0], _ = proj(tg[0], x0, z0, U[0], pv)
    stats: dict = {}
    max_corr = 0.0
    bar = _Progress(progress, tg[0], tg[-1], label)
    w0 = time.perf_counter()
    try:
        for k in range(n - 1):
            h = tg[k + 1] - tg[k]
            try:
                with c_output() as said:
                    res = F(x0=X[k], z0=Z[k], p=np.concatenate([pv, [tg[k], h]]))
            except RuntimeError as exc:
                _reraise_input_error(system)
                # this integrator runs in scaled time tau in [0, 1]: t = t_k + h tau
                tau = failure_time(said.text)
                tfail = tg[k] + h * tau if tau is not None else tg[k]
                if not math.isfinite(tfail) or tfail < tg[k]:
                    tfail = tg[k]
                _check_inputs_at(system, tfail)
                partial = _make_trajectory(r, tg[: k + 1], X[: k + 1], Z[: k + 1], U[: k + 1],
                                           pv, stats)
                raise SimulationError(
                    f"simulate: IDAS failed at t = {tfail:.6g} (output interval "
                    f"[{tg[k]:g}, {tg[k + 1]:g}]): {_reason(first_error or exc)}. The "
                    "trajectory up to t = "
                    f"{tg[k]:g} is attached as .trajectory.",
                    t=float(tfail),
                    trajectory=partial,
                ) from None
            _add_stats(stats, _stats_of(F, 0.0))
            xk = np.asarray(res["xf"], dtype=float).ravel()
            zk = np.asarray(res["zf"], dtype=float).ravel()
            if proj is not None:
                try:
                    xk, zk, corr = proj(tg[k + 1], xk, zk, U[k + 1], pv)
                except SimulationError as exc:
                    exc.trajectory = _make_trajectory(r, tg[: k + 1], X[: k + 1], Z[: k + 1],
                                                      U[: k + 1], pv, stats)
                    raise
                max_corr = max(max_corr, corr)
            X[k + 1], Z[k + 1] = xk, zk
            bar.update(tg[k + 1])
    finally:
        bar.close()
    stats["integrator_wall_time"] = time.perf_counter() - w0
    stats["intervals"] = n - 1
    if proj is not None:
        stats["max_projection_correction"] = max_corr
    if first_error is not None:  # the grid run failed but the interval-wise run did not
        stats["note"] = f"one-run IDAS failed ({_reason(first_error)}); solved interval-wise"
    return _make_trajectory(r, tg, X, Z, U, pv, stats, system.evaluator)
