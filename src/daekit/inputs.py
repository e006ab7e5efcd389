"""Inputs of a ReducedDAE as functions of time: Python callables or CasADi expressions.

The reduced system's input vector ``r.u`` holds the model's controls followed by the input
derivatives the index reduction needs (``"der(u)"``, ``"der(u,2)"``). Given a control as a
CasADi expression of time, its derivatives are taken symbolically (``casadi.jacobian`` with
respect to ``t``); given it as a Python callable, the derivatives must be supplied explicitly
(``inputs={"u": f, "der(u)": df}``) or daekit says so.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import casadi as ca
import numpy as np

from .errors import DaekitError, ModelError
from .model import NameNotFoundError, element_name, expand_name, fit_elements, parse_name
from .wording import count

__all__ = ["InputSignal", "InputError", "resolve_params", "signal_for"]


class InputError(DaekitError):
    """An input is missing, of the wrong size, not a function of time, or returns NaN."""


def _time_symbol_map(r) -> tuple[list[ca.SX], list[ca.SX]]:
    """Symbols that mean 'time' in user expressions (r.t, and the model's t if different)."""
    olds, news = [], []
    model = getattr(r, "model", None)
    mt = getattr(model, "t", None)
    if isinstance(mt, ca.SX) and mt.is_symbolic() and not ca.is_equal(mt, r.t):
        olds.append(mt)
        news.append(r.t)
    return olds, news


class InputSignal:
    """The input vector ``u(t)`` of a ReducedDAE built from the user's ``inputs`` dict.

    Attributes
    ----------
    expr : casadi.SX
        ``u`` as an SX expression of ``r.t`` where every element is given by an expression or a
        constant; elements given by callables are the symbols ``cb`` (see ``callable_index``).
    callable_index : list of int
        Positions of ``u`` supplied by Python callables, in order.
    """

    def __init__(self, r, inputs: Mapping | None) -> None:
        self.r = r
        inputs = dict(inputs or {})
        names = list(r.u_names)
        self.names = names
        nu = len(names)
        t = r.t
        olds, news = _time_symbol_map(r)
        # what the user gave, by scalar element name: ("expr", SX scalar) or ("call", f, k)
        given: dict[str, tuple] = {}
        self.sources: dict[str, str] = {}
        for key, val in inputs.items():
            if not isinstance(key, str):
                raise InputError(f"inputs: keys must be names such as 'u' or 'u[0]', got {key!r}")
            try:
                base, order, idx = parse_name(key)
            except ModelError as exc:
                raise InputError(f"inputs: {exc}") from None
            prefix = element_name(base, 1, 0, order)
            if idx is not None:
                elems = [f"{prefix}[{idx}]"] if f"{prefix}[{idx}]" in names else [prefix]
            else:
                elems = [prefix] if prefix in names else []
                while f"{prefix}[{len(elems)}]" in names:
                    elems.append(f"{prefix}[{len(elems)}]")
            elems = [e for e in elems if e in names]
            if not elems:
                raise InputError(
                    f"inputs: {key!r} is not an input of this system; its inputs are "
                    f"{', '.join(names) or 'none'}"
                )
            if callable(val) and not isinstance(val, (ca.SX, ca.MX, ca.DM)):
                for k, e in enumerate(elems):
                    given[e] = ("call", val, k, len(elems), key)
                continue
            if isinstance(val, ca.MX):
                raise InputError(f"inputs: {key!r} is an MX expression; give an SX expression of t")
            try:
                sx = ca.SX(val) if not isinstance(val, ca.SX) else val
            except Exception:  # noqa: BLE001
                raise InputError(
                    f"inputs: {key!r} must be a callable f(t), a CasADi SX expression of t or "
                    f"numbers, got {type(val).__name__}"
                ) from None
            sx = ca.vec(ca.densify(sx))
            if olds:
                sx = ca.substitute(sx, ca.vertcat(*olds), ca.vertcat(*news))
            sx = fit_elements(sx, len(elems), f"inputs: {key!r}", InputError)
            others = [s for s in ca.symvar(sx) if not ca.is_equal(s, t)]
            if others:
                raise InputError(
                    f"inputs: the expression for {key!r} depends on {others[0].name()!r}; an input "
                    "may depend on time only (use r.t or the model's m.t)"
                )
            for k, e in enumerate(elems):
                given[e] = ("expr", sx[k], key)

        # elements: given directly, or a derivative of a given expression
        exprs: list[ca.SX] = []
        self.callable_index: list[int] = []
        self._calls: list[tuple] = []
        self.missing: list[str] = []
        for i, e in enumerate(names):
            if e in given:
                g = given[e]
                if g[0] == "expr":
                    exprs.append(g[1])
                    self.sources[e] = g[2]
                else:
                    exprs.append(ca.SX.sym(f"cb_{i}"))
                    self.callable_index.append(i)
                    self._calls.append(g)
                    self.sources[e] = g[4]
                continue
            base, order, idx = parse_name(e)
            found = None
            for lower in range(order - 1, -1, -1):
                le = element_name(base, 1, 0, lower)
                le = f"{le}[{idx}]" if idx is not None else le
                if le in given:
                    found = (lower, given[le])
                    break
            if found is None:
                if order == 0:
                    # a control nobody gave: zero (documented)
                    self.missing.append(e)
                    exprs.append(ca.SX(0))
                    self.sources[e] = e
                    continue
                raise InputError(
                    f"inputs: the reduced system needs {e!r}, a derivative of an input, but "
                    f"{element_name(base, 1, 0, 0)!r} was not given; give it as a CasADi "
                    "expression of time so daekit can differentiate it"
                )
            lower, g = found
            if g[0] == "call":
                raise InputError(
                    f"inputs: the reduced system needs {e!r}, the derivative of order "
                    f"{order - lower} of input {g[4]!r}, which is a Python callable; daekit cannot "
                    f"differentiate it. Give {g[4]!r} as a CasADi expression of time (e.g. "
                    f"ca.sin(r.t)), or give the derivative too: inputs={{{g[4]!r}: f, "
                    f"'{element_name(base, 1, 0, order)}': df}}"
                )
            d = g[1]
            for _ in range(order - lower):
                d = ca.jacobian(d, t)
            exprs.append(d)
            self.sources[e] = g[2]
        self.expr = ca.vertcat(*exprs) if exprs else ca.SX(0, 1)
        self.cb_syms = ca.vertcat(*[exprs[i] for i in self.callable_index]) if self.callable_index \
            else ca.SX(0, 1)
        self._fexpr = ca.Function("u_of_t", [t, self.cb_syms], [self.expr])
        self.nu = nu
        self._constant: bool | None = None

    @property
    def has_callables(self) -> bool:
        return bool(self.callable_index)

    def callable_values(self, t: float) -> np.ndarray:
        """Values of the elements given by callables at time ``t`` (NaN-checked)."""
        out = np.zeros(len(self._calls))
        cache: dict[int, np.ndarray] = {}
        for j, (_, f, k, n, key) in enumerate(self._calls):
            if id(f) not in cache:
                try:
                    v = np.atleast_1d(np.asarray(f(float(t)), dtype=float)).ravel()
                except DaekitError:
                    raise
                except Exception as exc:  # noqa: BLE001
                    raise InputError(
                        f"input {key!r}: calling it at t = {t:g} raised {type(exc).__name__}: {exc}"
                    ) from exc
                if v.size == 1 and n > 1:
                    v = np.repeat(v, n)
                if v.size != n:
                    raise InputError(
                        f"input {key!r} returned {count(v.size, 'value')} at t = {t:g}; it has "
                        f"{count(n, 'element')}"
                    )
                cache[id(f)] = v
            out[j] = cache[id(f)][k]
        return out

    def _constant_value(self) -> np.ndarray | None:
        """The input vector when it does not change with time (the default: zero), else None
        (worked out once)."""
        if self.has_callables:
            return None
        if self._constant is None:
            self._constant = (not ca.depends_on(self.expr, self.r.t)) and self.expr.is_constant()
        if not self._constant:
            return None
        u0 = self.__dict__.get("_u0")
        if u0 is None:
            u0 = self._u0 = np.asarray(ca.DM(self.expr), dtype=float).ravel()
            self._u0_finite = bool(np.isfinite(u0).all())  # (checked once, not per call)
        return u0

    def value(self, t: float) -> np.ndarray:
        """The numeric input vector at time ``t``; a NaN raises :class:`InputError` naming it."""
        u0 = self._constant_value()
        if u0 is not None:
            if not self._u0_finite:
                self.check_finite(u0, t)
            return u0.copy()
        cb = self.callable_values(t)
        u = np.asarray(self._fexpr(float(t), cb), dtype=float).ravel()
        self.check_finite(u, t)
        return u

    def values(self, ts) -> np.ndarray:
        """Input vectors at many times, shape (N, nu)."""
        ts = np.asarray(ts, dtype=float).ravel()
        if self.nu == 0:
            return np.zeros((ts.size, 0))
        u0 = self._constant_value()
        if u0 is not None:
            # inputs that do not change (the default: zero): one evaluation
            if not self._u0_finite:
                self.check_finite(u0, float(ts[0]) if ts.size else 0.0)
            return np.repeat(u0[None, :], ts.size, axis=0)
        if not self.has_callables:
            n = ts.size
            m = n if n <= 64 else 1 << (n - 1).bit_length()  # few distinct mapped Functions
            maps = self.__dict__.setdefault("_maps", {})
            if m not in maps:
                if len(maps) > 8:
                    maps.clear()
                maps[m] = self._fexpr.map(m)
            tp = np.concatenate([ts, np.repeat(ts[-1:], m - n)]) if m > n else ts
            u = np.asarray(maps[m](tp, np.zeros((0, m))), dtype=float)
            u = u.reshape(self.nu, m).T[:n]
            if not np.isfinite(u).all():
                k = int(np.argmin(np.isfinite(u).all(axis=1)))
                self.check_finite(u[k], ts[k])
            return u
        return np.vstack([self.value(tk) for tk in ts])

    def check_finite(self, u: np.ndarray, t: float) -> None:
        for i, v in enumerate(u):
            if not math.isfinite(v):
                e = self.names[i]
                src = self.sources.get(e, e)
                raise InputError(
                    f"input {src!r} is {v} at t = {t:g} (element {e!r}); inputs must be finite "
                    "over the whole time span - check the function or expression you gave"
                )

    def mx_function(self):
        """``u(t)`` as a CasADi Function usable inside an MX integrator (callables via a
        CasADi Callback with finite differences)."""
        if not self.has_callables:
            return ca.Function("u_of_t", [self.r.t], [self.expr])
        cb = _InputCallback(self)
        tm = ca.MX.sym("t")
        u = self._fexpr(tm, cb(tm))
        f = ca.Function("u_of_t", [tm], [u])
        f._daekit_cb = cb  # keep the callback alive
        return f


class _InputCallback(ca.Callback):
    def __init__(self, sig: InputSignal) -> None:
        ca.Callback.__init__(self)
        self.sig = sig
        self.error: Exception | None = None
        self.construct("daekit_inputs", {"enable_fd": True})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_out(self, i):  # noqa: ARG002
        return ca.Sparsity.dense(len(self.sig.callable_index), 1)

    def eval(self, arg):
        t = float(arg[0])
        try:
            v = self.sig.callable_values(t)
            if not np.all(np.isfinite(v)):
                full = np.zeros(self.sig.nu)
                full[self.sig.callable_index] = v
                self.sig.check_finite(full, t)
        except Exception as exc:  # noqa: BLE001 - kept and re-raised by simulate
            if self.error is None:
                self.error = exc
            raise
        return [ca.DM(v)]


def resolve_params(r, params: Mapping | None) -> np.ndarray:
    """Parameter vector: ``r.p_values`` overridden by ``params`` (names ``"m"``, ``"L"``,
    elements ``"k[1]"``); unknown names raise :class:`InputError` listing the known ones."""
    names, index, n_p = r.derived("inputs.param_index", _param_index)
    if names is not r.p_names:  # the names were replaced: not what the cache was made of
        names, index, n_p = _param_index(r)
    pv = np.asarray(r.p_values, dtype=float).ravel()
    if pv.size != n_p:
        raise InputError(f"the system has {count(n_p, 'parameter')} but p_values has "
                         f"{count(pv.size, 'value')}")
    return override_params(pv, names, params, index=index)


def _param_index(r) -> tuple[list[str], dict[str, int], int]:
    """``(p_names, {name: position}, number of parameters)`` of ``r`` (made once per system:
    every initialize and simulate call resolves its parameters by them)."""
    names = r.p_names
    return names, {n: i for i, n in enumerate(names)}, r.n_p


def override_params(p_values, p_names: list[str], params: Mapping | None,
                    where: str = "params", index: Mapping[str, int] | None = None
                    ) -> np.ndarray:
    """A copy of ``p_values`` (one per name in ``p_names``) with ``params`` put in, by name
    (``"m"``, a vector ``"k"`` with one value or one per element) or element (``"k[1]"``): the
    one parameter override of every entry point. Unknown names raise :class:`InputError`
    listing the known ones. ``index``: ``{name: position}`` of ``p_names`` when the caller
    keeps it (made here otherwise).

    >>> override_params([1.0, 2.0, 3.0], ["m", "k[0]", "k[1]"], {"k": 5.0}).tolist()
    [1.0, 5.0, 5.0]
    """
    pv = np.array(p_values, dtype=float).ravel()
    if not params:
        return pv
    if index is None:
        index = {n: i for i, n in enumerate(p_names)}
    for key, val in params.items():
        i = index.get(key) if isinstance(key, str) and isinstance(val, float) else None
        if i is not None and math.isfinite(val):  # one number for one element (a sweep's)
            pv[i] = val
            continue
        try:
            elems = expand_name(key, index, "the parameter list")
        except NameNotFoundError as exc:
            raise InputError(f"{where}: {exc}") from None
        try:
            arr = np.atleast_1d(np.asarray(val, dtype=float)).ravel()
        except (TypeError, ValueError):
            raise InputError(f"{where}: {key!r} must be numbers, got {val!r}") from None
        if arr.size == 1 and len(elems) > 1:
            arr = np.repeat(arr, len(elems))
        if arr.size != len(elems):
            raise InputError(f"{where}: {key!r} has {count(len(elems), 'element')}, got "
                             f"{count(arr.size, 'value')}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{where}: {key!r} is not finite ({val!r})")
        for e, v in zip(elems, arr, strict=False):
            pv[index[e]] = v
    return pv


def signal_for(r, inputs: Mapping | None) -> InputSignal:
    """The :class:`~daekit.inputs.InputSignal` of ``r`` for ``inputs``; without inputs (all
    controls zero, the common case) built once and kept on ``r`` (simulate and initialize
    share it).

    >>> import casadi as ca, numpy as np
    >>> from daekit.reduced import ReducedDAE
    >>> t = ca.SX.sym("t"); x = ca.SX.sym("x")
    >>> r = ReducedDAE(t, x, ca.SX(0, 1), ca.SX(0, 1), ca.SX(0, 1), -x, ca.SX(0, 1),
    ...     ca.SX(0, 1), [], ["x"], [], [], [], np.zeros(0), {"x": x})
    >>> signal_for(r, None) is signal_for(r, {})
    True
    """
    if inputs:
        return InputSignal(r, inputs)

    def build(r) -> InputSignal:
        sig = InputSignal(r, None)
        sig.default = True  # no inputs given: the key of system_for needs no serialization
        return sig

    return r.derived("inputs.default_signal", build)
