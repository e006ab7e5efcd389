"""The result of :meth:`daekit.ocp.OCP.solve`: :class:`OCPSolution`, built in one place
(:func:`build_solution`) from a transcription's decision vector."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import OCPError
from ..numerics import DenseFunction
from .consistency import BoundaryAnalysis
from .nlp import quiet

__all__ = ["OCPSolution", "build_solution"]

STATUS_OK = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}


def build_solution(prob, tr, V, f, success, status, stats, kept, boundary, report, infeas,
                   bc_residuals) -> OCPSolution:
    """The one place an :class:`OCPSolution` is made: the grid values of ``V`` (a decision
    vector of the transcription ``tr`` of ``prob``), the outcome, the boundary analysis, the
    report and the residuals of all the boundary conditions at the solution."""
    sol = OCPSolution._from_grid(prob, tr, V, f, success, status, stats, kept)
    sol.boundary = boundary
    sol.report, sol.infeasibilities = report, infeas
    sol._bc_residuals = bc_residuals
    return sol


class OCPSolution:
    """The solution of an :class:`OCP`: the same interface as a simulation Trajectory.

    Attributes
    ----------
    success : bool
        IPOPT converged (``Solve_Succeeded`` or ``Solved_To_Acceptable_Level``).
    status : str
        IPOPT's return status, or ``"Contradictory_Boundary_Conditions"`` when IPOPT was not
        run because the conditions are proven contradictory (see
        :attr:`BoundaryAnalysis.conflict` and :attr:`BoundaryAnalysis.proven`).
    objective : float
    t : numpy.ndarray
        Time grid: ``0`` and every collocation point (shooting: the interval boundaries).
    T : float
        Final time.
    invariants : numpy.ndarray (len(t), number of invariants)
        The invariants along the solution (small: they are imposed at ``t = 0`` only).
    invariant_names : list of str
    parameters : dict
        Parameter values used (free ones at their optimum).
    stats : dict
        IPOPT's statistics (``iter_count``, ``return_status``, ``iterations``: the history of
        objective and infeasibilities, ``t_wall_nlp_*``: time per function) and daekit's:
        ``objective``, ``method``, ``transcription``, ``intervals``, ``guess`` (where the
        initial guess came from), ``t_build``, ``t_solve``, ``t_total``, ``n_variables``,
        ``n_constraints``, ``max_constraint_violation``, ``max_bound_violation``,
        ``max_invariant_t0``, ``max_invariant`` (on the grid), ``n_boundary_conditions``,
        ``boundary_rank``, ``boundary_dropped``, ``boundary_selectors`` (dropped conditions
        that select a branch: checked at the solution), ``boundary_pins`` (the values imposed
        at an isolated degenerate end point), and ``resolved`` (only after a second solve
        that imposed violated dropped conditions: ``first_objective``, ``first_status``,
        ``first_iter_count``, ``forced``).
    method : str
        ``"collocation"`` or ``"shooting"``.
    report : str
        What was done: reduction, transcription, boundary conditions kept and dropped (and why),
        solver outcome, and on failure the constraints at fault.
    infeasibilities : list of (label, violation, time)
        Largest constraint violations at the returned point (empty on success).

    ``sol["p"]`` gives any original variable or element by name, ``(len(t),)`` for one element,
    ``(len(t), k)`` for a vector. Controls are read left-continuously: the value at a grid time
    is that of the interval ending there (at ``t = 0``, the first interval's).
    :meth:`simulate` gives a finer :class:`daekit.Trajectory` by integrating with the optimal
    controls; :attr:`controls` the decision controls on the grid.
    """

    def __init__(self) -> None:
        self.success = False
        self.status = ""
        self.objective = float("nan")
        self.t = np.zeros(0)
        self.T = float("nan")
        self.invariants = np.zeros((0, 0))
        self.invariant_names: list[str] = []
        self.parameters: dict[str, float] = {}
        self.stats: dict = {}
        self.report = ""
        self.infeasibilities: list = []
        self.boundary: BoundaryAnalysis | None = None
        self.method = ""
        self._bc_residuals: tuple[np.ndarray, float] = (np.zeros(0), 1.0)
        self._lam: tuple[np.ndarray, np.ndarray] | None = None  # IPOPT's multipliers

    @classmethod
    def _from_grid(cls, prob, tr, V, f, success, status, stats, kept) -> OCPSolution:
        s = cls()
        a = prob.aug
        fr, X, Z, W, T, P = (np.asarray(v) for v in tr.grid(V))
        s.T = float(np.asarray(T).ravel()[0])
        s.t = np.asarray(fr).ravel() * s.T
        s._X, s._Z, s._W, s._P = X, Z, W, np.asarray(P).ravel()
        s._aug = a
        s._V = V
        s._key = prob.structure_key(kept)
        s.success, s.status, s.objective, s.stats = success, status, f, stats
        s.parameters = dict(zip(a.p_names, s._P.tolist(), strict=True))
        s.invariant_names = list(a.inv_names)
        if a.inv.numel():
            s.invariants = s._eval(a.inv)
        else:
            s.invariants = np.zeros((s.t.size, 0))
        s.method = prob.method
        s._N = prob.intervals
        s._ncoef = tr.ncoef
        s._node_index = list(tr.node_index) if tr.node_index is not None else None
        s._Wint = None
        if tr.controls is not None:
            s._Wint = np.asarray(tr.controls(V)).reshape(a.nw, prob.intervals * tr.ncoef)
        s._integrator_options = dict(prob.integrator_options)
        if s.invariants.size:
            stats["max_invariant_t0"] = float(np.max(np.abs(s.invariants[0])))
            stats["max_invariant"] = float(np.max(np.abs(s.invariants)))
        return s

    def _eval(self, expr: ca.SX) -> np.ndarray:
        a = self._aug
        fn = DenseFunction(ca.Function("ev", [a.t, a.x, a.z, a.w, a.p], [expr]))
        return fn(self.t.reshape(1, -1), self._X, self._Z, self._W, self._P.reshape(-1, 1)).T

    def __getitem__(self, name: str) -> np.ndarray:
        els, vector = self._aug.select(name, f"solution[{name!r}]")
        val = self._eval(ca.vertcat(*[self._aug.names[e] for e in els]))
        return val if vector else val[:, 0]

    def simulate(self, points_per_interval: int = 10, rtol: float | None = None,
                 atol: float | None = None):
        """Finer output: integrate each interval with IDAS from the solution's state at its
        start, with the optimal controls, and return a :class:`daekit.Trajectory`.

        The time grid has ``points_per_interval`` equally spaced points on each interval (and
        ``t = 0``); values by the original model's names, the invariants, and in ``stats``
        ``"node_mismatch"``: the largest difference between an interval's integrated end state
        and the solution's state there (zero up to the integrator's tolerance for shooting;
        for collocation, an a posteriori estimate of its discretization error).

        >>> import daekit as dk
        >>> m = dk.Model("cart"); s = m.state("s"); u = m.control("u")
        >>> _ = m.equation(m.der(s, 2) - u, name="newton")
        >>> ocp = dk.OCP(m, t_final=1.0, intervals=4, method="shooting")
        >>> _ = ocp.minimize(integral=u**2).initial({"s": 0, "der(s)": 0}).final({"s": 1})
        >>> fine = ocp.solve().simulate(points_per_interval=5)
        >>> fine.t.size, round(float(fine["s"][-1]), 8), fine.stats["node_mismatch"] < 1e-8
        (21, 1.0, True)
        """
        from ..simulate import Trajectory
        from .collocation import radau_coefficients
        from .shooting import DEFAULT_INTEGRATOR_OPTIONS, interval_integrator

        if self._Wint is None or self._node_index is None:
            raise OCPError("this solution has no interval data to simulate from")
        n = int(points_per_interval)
        if n < 1:
            raise OCPError(f"simulate(points_per_interval={points_per_interval!r}): need >= 1")
        a, N, nc = self._aug, self._N, self._ncoef
        opts = {**DEFAULT_INTEGRATOR_OPTIONS, **self._integrator_options}
        if rtol is not None:
            opts["reltol"] = float(rtol)
        if atol is not None:
            opts["abstol"] = float(atol)
        svals = np.linspace(0.0, 1.0, n + 1)[1:]
        F = interval_integrator(a, None, tout=svals, ncoef=nc, options=opts, name="dense")
        h = self.T / N
        idx = self._node_index
        X0, Z0 = self._X[:, idx[:N]], self._Z[:, idx[:N]]
        Wc = self._Wint.reshape(a.nw, N, nc).transpose(2, 0, 1).reshape(a.nw * nc, N)
        P = np.vstack([Wc, np.repeat(self._P.reshape(-1, 1), N, axis=1),
                       h * np.arange(N).reshape(1, -1), np.full((1, N), h)])
        try:
            with quiet():
                res = F.map(N)(x0=X0, z0=Z0, p=P)
        except RuntimeError as exc:
            raise OCPError(
                "simulating the solution failed: "
                f"{str(exc).strip().splitlines()[-1]} (try rtol/atol)"
            ) from None
        xf = np.asarray(res["xf"]).reshape(a.nx, N * n)
        zf = np.asarray(res["zf"]).reshape(a.nz, N * n)
        if nc == 1:
            basis = np.ones((n, 1))
        else:
            tau = radau_coefficients(nc)[0][1:]
            basis = np.array([[np.prod([(sv - tau[q]) / (tau[r] - tau[q])
                                        for q in range(nc) if q != r]) for r in range(nc)]
                              for sv in svals])
        Wd = np.einsum("jr,wkr->wkj", basis, self._Wint.reshape(a.nw, N, nc)).reshape(a.nw, N * n)
        t = np.concatenate([[0.0], (np.arange(N).reshape(-1, 1) + svals).ravel() * h])
        X = np.hstack([self._X[:, :1], xf])
        Z = np.hstack([self._Z[:, :1], zf])
        W = np.hstack([self._W[:, :1], Wd])
        ends = xf[:, n - 1::n]
        mismatch = float(np.max(np.abs(ends - self._X[:, idx[1:]]), initial=0.0))
        names = list(a.names)
        fn = ca.Function("ev", [a.t, a.x, a.z, a.w, a.p],
                         [ca.vertcat(*[ca.SX(a.names[k]) for k in names]), a.inv])
        m = t.size
        vals, inv = fn.map(m)(t.reshape(1, -1), X, Z, W, np.repeat(self._P.reshape(-1, 1), m, 1))
        vals, inv = np.asarray(vals), np.asarray(inv)
        return Trajectory(
            t, {k: vals[i] for i, k in enumerate(names)}, inv.T if inv.size else None,
            self.invariant_names,
            {"method": f"IDAS re-simulation of the {self.method} solution, interval by interval",
             "node_mismatch": mismatch, "points_per_interval": n},
        )

    @property
    def controls(self) -> dict[str, np.ndarray]:
        """The decision controls on the grid by name."""
        return {n: self._W[i, :].copy() for i, n in enumerate(self._aug.w_names)}

    def __repr__(self) -> str:
        return (f"OCPSolution(success={self.success}, status={self.status!r}, "
                f"objective={self.objective:.10g}, T={self.T:.6g}, {self.t.size} time points)")
