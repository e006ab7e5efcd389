"""A small NLP builder shared by the transcriptions: decision blocks, constraint rows with
labels (so that a failed solve can name the constraint at fault), and the solution grid."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .._cio import c_output
from ..numerics import fast_call

__all__ = ["NLPBuilder", "RowGroup", "quiet", "call_buffered"]


@dataclass
class RowGroup:
    """Constraint rows ``start:stop`` that come from one source (``label``) at time ``time``."""

    start: int
    stop: int
    label: str
    time: float | ca.SX | None = None
    kind: str = "path"
    names: list[str] | None = None
    times: np.ndarray | None = None  # per row (fraction of T), when the rows differ in time


@dataclass
class NLPBuilder:
    """Collects decision variables (SX or MX blocks) and labelled constraints."""

    sym: type = ca.SX
    vars: list = field(default_factory=list)
    lbx: list = field(default_factory=list)
    ubx: list = field(default_factory=list)
    x0: list = field(default_factory=list)
    g: list = field(default_factory=list)
    lbg: list = field(default_factory=list)
    ubg: list = field(default_factory=list)
    groups: list[RowGroup] = field(default_factory=list)
    nv: int = 0
    ng: int = 0

    def var(self, name: str, n: int, lb=-np.inf, ub=np.inf, guess=0.0):
        """A new block of ``n`` decision variables; returns (symbol, first index)."""
        v = self.sym.sym(name, n)
        self.vars.append(v)
        self.lbx.append(np.broadcast_to(np.asarray(lb, float), (n,)).copy())
        self.ubx.append(np.broadcast_to(np.asarray(ub, float), (n,)).copy())
        self.x0.append(np.broadcast_to(np.asarray(guess, float), (n,)).copy())
        start = self.nv
        self.nv += n
        return v, start

    def con(self, expr, lb, ub, label: str, time=None, kind: str = "path", names=None,
            times=None) -> None:
        """Rows ``lb <= expr <= ub`` with a label for diagnostics (``names``, ``times``: per
        row)."""
        n = int(expr.numel())
        if n == 0:
            return
        self.g.append(expr)
        self.lbg.append(np.broadcast_to(np.asarray(lb, float), (n,)).copy())
        self.ubg.append(np.broadcast_to(np.asarray(ub, float), (n,)).copy())
        self.groups.append(RowGroup(self.ng, self.ng + n, label, time, kind, names,
                                    None if times is None else np.asarray(times, float)))
        self.ng += n

    def arrays(self):
        cat = lambda a: np.concatenate(a) if a else np.zeros(0)  # noqa: E731
        return cat(self.lbx), cat(self.ubx), cat(self.x0), cat(self.lbg), cat(self.ubg)

    def V(self):
        return ca.vertcat(*self.vars) if self.vars else self.sym(0, 1)

    def G(self):
        return ca.vertcat(*self.g) if self.g else self.sym(0, 1)


def call_buffered(solver: ca.Function, **given) -> tuple[dict, dict]:
    """``solver(**given)`` through its raw buffers (NumPy in and out, no SWIG conversion of the
    decision-sized vectors: 0.14 ms each way per 1600-vector); inputs not given take their
    defaults. Returns the outputs by name (``f`` as a float) and the solver's stats.

    >>> x = ca.SX.sym("x", 2)
    >>> s = ca.nlpsol("s", "ipopt", {"x": x, "f": ca.sumsqr(x - 1), "g": x[0] + x[1]},
    ...               {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"})
    >>> res, stats = call_buffered(s, x0=[0.0, 0.0], lbg=0.0, ubg=0.0)
    >>> np.round(res["x"], 8).tolist(), round(res["f"], 8), stats["success"]
    ([0.0, 0.0], 2.0, True)
    """
    args = {}
    for i in range(solver.n_in()):
        v = np.zeros(solver.nnz_in(i))
        name = solver.name_in(i)
        v[:] = np.ravel(given[name]) if name in given else solver.default_in(i)
        args[name] = v
    res = fast_call(solver, args, want_stats=True)
    stats = res.pop("_stats")
    res["f"] = float(res["f"][0])
    return res, dict(stats)


@contextlib.contextmanager
def quiet(enabled: bool = True):
    """Silence output written by C code (IPOPT, SUNDIALS' error handler, CasADi's evaluation
    warnings when an integration fails inside a line search), at the file-descriptor level and
    through Python's ``sys.stdout``/``sys.stderr`` (see :func:`daekit._cio.c_output`).

    Errors still arrive as Python exceptions; ``enabled=False`` (``verbose=True``) lets
    everything through.
    """
    with c_output(enabled):
        yield
