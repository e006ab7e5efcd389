"""Direct collocation with Radau IIA (degree 1 to 5) on an index-1 DAE.

On each of ``N`` intervals of length ``h = T/N`` the state is a polynomial of degree ``d``
through the interval's start point and the ``d`` Radau points ``tau_1 < ... < tau_d = 1``; the
dynamics ``x' = ode`` and the algebraic equations ``0 = alg`` hold at the Radau points, where
the algebraic unknowns live. The last Radau point is the next interval's start (so states are
continuous without extra equations). The Lagrange term is integrated with the Radau weights
(exact for polynomials of degree ``2d - 2``). Radau IIA is stiffly accurate and of order
``2d - 1`` at the interval ends for index-1 DAEs.

Controls are piecewise constant (one value per interval) or piecewise polynomial (one value
per Radau point, degree ``d - 1`` on each interval). Extra decision variables at the initial
time: the algebraic unknowns ``z_0`` (with ``alg = 0``), where the invariants are imposed.
"""

from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from .derivatives import dm_triplet, point_hessian, point_jacobian
from .nlp import NLPBuilder
from .transcription import Transcription, finish, params_and_time

__all__ = ["radau_coefficients", "transcribe", "Transcription"]


def radau_coefficients(d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Radau IIA coefficients of degree ``d`` (cached; see :func:`_radau_coefficients`).

    >>> radau_coefficients(2)[0].round(4).tolist()
    [0.0, 0.3333, 1.0]
    """
    return tuple(np.array(v) for v in _radau_cached(int(d)))


@functools.lru_cache(maxsize=8)
def _radau_cached(d: int):
    return _radau_coefficients(d)


def _radau_coefficients(d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points ``tau = [0, tau_1..tau_d]``, derivative matrix ``C`` (``C[r, j]``: derivative of the
    ``r``-th Lagrange basis polynomial through ``tau`` at ``tau_j``), quadrature weights ``b``
    (Radau IIA, for ``tau_1..tau_d``) and ``e0`` (the degree ``d - 1`` interpolant through the
    Radau points evaluated at 0).

    >>> tau, C, b, e0 = radau_coefficients(1)
    >>> tau.tolist(), b.tolist()
    ([0.0, 1.0], [1.0])
    """
    tau = np.array([0.0] + list(ca.collocation_points(d, "radau")))
    C = np.zeros((d + 1, d + 1))
    for r in range(d + 1):
        poly = np.poly1d([1.0])
        for s in range(d + 1):
            if s != r:
                poly *= np.poly1d([1.0, -tau[s]]) / (tau[r] - tau[s])
        dp = np.polyder(poly)
        for j in range(d + 1):
            C[r, j] = dp(tau[j])
    b = np.zeros(d)
    e0 = np.zeros(d)
    for r in range(d):
        poly = np.poly1d([1.0])
        for s in range(d):
            if s != r:
                poly *= np.poly1d([1.0, -tau[s + 1]]) / (tau[r + 1] - tau[s + 1])
        ip = np.polyint(poly)
        b[r] = ip(1.0) - ip(0.0)
        e0[r] = poly(0.0)
    return tau, C, b, e0


#: Symbolic type of the collocation NLP. "MX": the model is one mapped call over all
#: collocation points and CasADi differentiates the map (the cost of building the NLP does not
#: grow with the number of intervals); "SX": the expression graph is expanded. Measured (CPU,
#: nlpsol construction / IPOPT run, MX against SX): planar swing N = 100 0.035 / 0.03 s against
#: 0.15 / 0.02 s; cart-pole 0.03 / 0.15 s against 0.09 / 0.12 s (32 iterations: an MX
#: evaluation is slower). ``solver_options={"expand": True}`` expands the MX NLP for IPOPT
#: (worth it when many iterations are expected).
SYMBOLIC = "MX"


def transcribe(prob, guess, T_guess: float | None = None, p_guess=None, kept=(),
               selectors=(), pins=()) -> Transcription:
    """Build the collocation NLP of ``prob`` (a :class:`~daekit.ocp.compiled.Problem`) with the
    boundary conditions ``kept`` (indices) as equalities (and the ``selectors`` and ``pins`` of
    :meth:`~daekit.ocp.compiled.Problem.add_boundary`); ``guess(t)`` gives ``(X, Z, W)`` at
    times ``t`` of a horizon ``T_guess``.

    Vectorized: the states at all ``N d + 1`` grid points are one symbolic matrix, the model is
    evaluated once over all collocation points (``Function.map``) and the collocation
    equations are ``d`` matrix expressions, so building the NLP costs no Python loop over the
    intervals."""
    a = prob.aug
    N, d = prob.intervals, prob.degree
    tau, C, b, e0 = radau_coefficients(d)
    nx, nz, nw = a.nx, a.nz, a.nw
    M = N * d
    S = ca.MX if SYMBOLIC == "MX" else ca.SX
    B = NLPBuilder(S)
    f = prob.model_fun()

    # parameters and final time
    Tg = prob.T_guess if T_guess is None else float(T_guess)
    P, T = params_and_time(prob, B, T_guess=Tg, p_guess=p_guess)
    h = T / N
    xlb, xub, zlb, zub, wlb, wub = prob.simple_bounds()
    an = [f"equation {n!r}" for n in prob.alg_names]
    fr = np.concatenate([[0.0], ((np.arange(N).reshape(-1, 1) + tau[1:]) / N).ravel()])
    gx, gz, gw = guess(fr * Tg)

    offs = {}

    def block(name, n, cols, lb, ub, g):
        v, offs[name] = B.var(name, n * cols, np.tile(lb, cols), np.tile(ub, cols),
                              np.asarray(g, float).reshape(n, cols).ravel("F"))
        return ca.reshape(v, n, cols)

    X = block("x", nx, M + 1, xlb, xub, gx)
    Z = block("z", nz, M + 1, zlb, zub, gz)
    if prob.control_mode == "constant":
        Wv = block("w", nw, N, wlb, wub, gw[:, 1:].reshape(nw, N, d).mean(axis=2))
        Wc = ca.repmat(Wv, d, 1).reshape((nw, M)) if nw else S(0, M)
        W0 = Wv[:, 0]
        ncoef = 1
    else:
        Wv = block("w", nw, M, wlb, wub, gw[:, 1:])
        Wc = Wv
        W0 = sum(float(e0[j]) * Wv[:, j] for j in range(d))
        ncoef = d
    tc = h * ca.DM((np.arange(N).reshape(-1, 1) + tau[1:]).ravel()).T  # collocation times
    Pm = ca.repmat(P, 1, M)
    structured = (STRUCTURED and S is ca.MX and prob.T_free is None and not prob.free_params
                  and not prob.solver_options.get("expand"))
    if structured:
        # the model's outputs at the collocation points as symbols Q, replaced by the mapped
        # model afterwards: the NLP is linear in Q, which gives its derivatives in closed form
        # (see _structured_derivatives)
        fq = _point_function(prob)
        nq = fq.size1_out(0)
        Q = ca.MX.sym("Q", nq, M)
        ode, alg, L = Q[:nx, :], Q[nx:nx + nz, :], Q[nx + nz:nx + nz + 1, :]
    else:
        ode, alg, L = f.map(M)(tc, X[:, 1:], Z[:, 1:], Wc, Pm)
    # t = 0: algebraic equations, invariants, path constraints
    alg0 = f(0.0, X[:, 0], Z[:, 0], W0, P)[1]
    B.con(alg0, 0.0, 0.0, "algebraic equations", 0.0, "alg", an)
    if a.inv.numel():
        inv0 = prob.inv_fun()(0.0, X[:, 0], Z[:, 0], W0, P)
        B.con(inv0, 0.0, 0.0, "invariants", 0.0, "invariant", list(a.inv_names))
    prob.add_path(B, 0.0, X[:, 0], Z[:, 0], W0, P, 0.0)
    # collocation: for each Radau point j, all intervals at once
    mapped = {}  # index in B.g -> ("dynamics", j) / ("alg",) / ("path",): rows linear in Q
    # the derivatives of the state polynomials at all collocation points: one product with
    # the constant (M + 1) x M matrix of the coefficients C (column i d + j - 1: interval i,
    # Radau point j)
    i_, r_, j_ = np.meshgrid(np.arange(N), np.arange(d + 1), np.arange(1, d + 1), indexing="ij")
    XP = ca.mtimes(X, dm_triplet(M + 1, M, (i_ * d + r_).ravel(), (i_ * d + j_ - 1).ravel(),
                                 C[r_, j_].ravel()))
    dyn_names = [f"dynamics on interval {k}" for k in range(N) for _ in range(nx)]
    for j in range(1, d + 1):
        n_g = len(B.g)
        B.con(ca.vec(XP[:, j - 1::d] - h * ode[:, j - 1::d]), 0.0, 0.0, "dynamics", None,
              "dynamics", dyn_names,
              times=np.repeat(fr[j::d], nx))
        if len(B.g) > n_g:
            mapped[n_g] = ("dynamics", j)
    n_g = len(B.g)
    B.con(ca.vec(alg), 0.0, 0.0, "algebraic equations", None, "alg", an * M,
          times=np.repeat(fr[1:], nz))
    if len(B.g) > n_g:
        mapped[n_g] = ("alg",)
    if prob.path_fun is not None:
        pth = Q[nx + nz + 1:, :] if structured else \
            prob.path_fun.map(M)(tc, X[:, 1:], Z[:, 1:], Wc, Pm)
        npth = prob.path_lb.size
        n_g = len(B.g)
        B.con(ca.vec(pth), np.tile(prob.path_lb, M), np.tile(prob.path_ub, M),
              "path constraints", None, "path", list(prob.path_labels) * M,
              times=np.repeat(fr[1:], npth))
        if len(B.g) > n_g:
            mapped[n_g] = ("path",)
    J = 0
    if prob.has_lagrange:
        J = h * sum(float(b[j - 1]) * ca.sum2(L[:, j - 1::d]) for j in range(1, d + 1))
    Wgrid = ca.horzcat(W0, Wc)
    tr = finish(prob, B, S(J), P, T, fr, X, Z, Wgrid, Wv, kept, selectors, pins,
                f"Radau IIA collocation, degree {d}", [k * d for k in range(N + 1)], ncoef)
    if structured:
        V = B.V()
        Qval = fq.map(M)(tc, X[:, 1:], Z[:, 1:], Wc, Pm)
        pts = _point_columns(offs, nx, nz, nw, N, d, prob.control_mode == "constant")
        G = B.G()
        G_real, J_real = ca.Function("nlp_q", [V, Q], [G, tr.J])(V, Qval)
        lin = _linear_parts(B.g, mapped, offs["x"], int(V.numel()), nx, nz, nq, N, d, C,
                            float(h), b)
        tr.derivatives = _structured_derivatives(prob, fq, V, Q, tr.J, G_real, J_real, tc, X,
                                                 Z, Wc, Pm, pts, lin)
        B.g = [G_real]
        tr.J = J_real
    return tr


#: Give IPOPT the constraint Jacobian and the Lagrangian Hessian of the collocation NLP in
#: closed form (fixed final time and parameters): the NLP is linear in the model's outputs
#: at the collocation points, so its derivatives are the per-point derivatives of the model
#: (small SX functions, mapped over the points) scattered into place, plus CasADi's AD of
#: the few rows at the ends. Measured (CPU, transcription + nlpsol + IPOPT, best of 5)
#: against CasADi's AD of the MX NLP: planar swing 0.049 -> 0.038 s, Betts 10.103 0.085 ->
#: 0.069 s, cart-pole 0.065 -> 0.047 s (nlpsol 0.02-0.03 -> 0.005 s; the Hessian evaluates
#: 4x faster, the Jacobian 2-3x); the same iterations and optima.
STRUCTURED = True


def _point_function(prob) -> ca.Function:
    """``(t, x, z, w, p) -> q = (ode, alg, lagrange, path)`` at one point."""
    a = prob.aug
    outs = list(prob.model_fun()(a.t, a.x, a.z, a.w, a.p))
    if prob.path_fun is not None:
        outs.append(prob.path_fun(a.t, a.x, a.z, a.w, a.p))
    # as columns: an empty output may be 1-by-0, which vertcat would count as a row
    outs = [ca.reshape(o, o.numel(), 1) for o in outs]
    return ca.Function("q", [a.t, a.x, a.z, a.w, a.p], [ca.vertcat(*outs)])


def _point_columns(offs, nx, nz, nw, N, d, constant) -> np.ndarray:
    """``(M, nx + nz + nw)``: the decision-vector index of each local unknown ``y = (x, z, w)``
    at each collocation point ``k`` (x and z at grid column ``k + 1``, w of its interval
    (constant controls) or of the point)."""
    M = N * d
    k = np.arange(M).reshape(-1, 1)
    cols = [offs["x"] + (k + 1) * nx + np.arange(nx), offs["z"] + (k + 1) * nz + np.arange(nz)]
    wc = k // d if constant else k
    cols.append(offs["w"] + wc * nw + np.arange(nw))
    return np.hstack([c.reshape(M, -1) for c in cols]).astype(int)


def _linear_parts(g_list, mapped, x_off, nV, nx, nz, nq, N, d, C, h, b) -> dict:
    """The rows of the collocation NLP that are linear in ``(V, Q)``, as constant matrices:
    ``dG/dV`` of the collocation sums, ``dG/dQ`` and ``dJ/dQ`` (the Radau weights of the
    integrand), and the other ("end") rows by their positions."""
    sizes = [int(g.numel()) for g in g_list]
    start = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    nG, M = int(start[-1]), N * d
    vr, vc, vv, qr, qc, qv = [], [], [], [], [], []
    end_rows = []
    i_, comp = np.meshgrid(np.arange(N), np.arange(nx), indexing="ij")
    for gi, n in enumerate(sizes):
        kind = mapped.get(gi)
        r0 = start[gi]
        if kind is None:
            end_rows.extend(range(r0, r0 + n))
        elif kind[0] == "dynamics":  # row i nx + c: sum_r C[r, j] X[c, i d + r] - h ode[c, k]
            j = kind[1]
            rows = (r0 + i_ * nx + comp).ravel()
            for r in range(d + 1):
                vr.append(rows)
                vc.append((x_off + (i_ * d + r) * nx + comp).ravel())
                vv.append(np.full(rows.size, float(C[r, j])))
            qr.append(rows)
            qc.append(((i_ * d + j - 1) * nq + comp).ravel())
            qv.append(np.full(rows.size, -h))
        else:  # alg (Q rows nx..) or path (Q rows nx + nz + 1..) at every point
            first = nx if kind[0] == "alg" else nx + nz + 1
            per = n // M
            k_, c_ = np.meshgrid(np.arange(M), np.arange(per), indexing="ij")
            qr.append((r0 + k_ * per + c_).ravel())
            qc.append((k_ * nq + first + c_).ravel())
            qv.append(np.ones(n))
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0, int)  # noqa: E731
    JVlin = dm_triplet(nG, nV, cat(vr), cat(vc), cat(vv))
    JQ = dm_triplet(nG, nq * M, cat(qr), cat(qc), cat(qv))
    k = np.arange(M)
    gJ = dm_triplet(nq * M, 1, k * nq + nx + nz, np.zeros(M, int), h * np.asarray(b)[k % d])
    return {"JV": JVlin, "JQ": JQ, "gJ": gJ, "end_rows": end_rows, "nG": nG,
            "ends": [g for gi, g in enumerate(g_list) if gi not in mapped]}


def _structured_derivatives(prob, fq, V, Q, J, G_real, J_real, tc, X, Z, Wc, Pm, pts,
                            lin) -> dict:
    """IPOPT's ``jac_g``, ``hess_lag`` and ``grad_f`` for the NLP ``G(V, Q), J(V, Q)`` (linear
    in ``Q``) with ``Q = fq`` mapped over the collocation points.

    ``dG/dV = dG/dV|_Q + dG/dQ dQ/dV``: constant collocation sums, the end rows by AD, and the
    per-point Jacobians of ``fq`` through the constant ``dG/dQ``. The Lagrangian Hessian is
    that of the end rows and the Mayer term (AD) plus the per-point Hessians of ``lq . fq``
    with the multipliers ``lq = dG/dQ^T lam_g + dJ/dQ lam_f``, scattered into place. The
    objective's gradient is ``dJ/dQ`` through the same per-point Jacobians plus the Mayer
    term's.
    """
    a = prob.aug
    M, ny = pts.shape
    nq = fq.size1_out(0)
    nV, nG = int(V.numel()), lin["nG"]
    y = ca.vertcat(a.x, a.z, a.w)
    q = fq(a.t, a.x, a.z, a.w, a.p)
    p_in = ca.MX.sym("p", 0)
    Qz = ca.DM.zeros(nq, M)
    end_rows = lin["end_rows"]
    ends = ca.vertcat(*lin["ends"]) if lin["ends"] else ca.MX(0, 1)
    args = (tc, X[:, 1:], Z[:, 1:], Wc, Pm)
    syms = [a.t, a.x, a.z, a.w, a.p]
    D = point_jacobian(q, y, syms, args, pts, nV)
    jac = lin["JV"] + ca.mtimes(lin["JQ"], D)
    # the end rows and the Mayer term touch a few entries of V: expanded to SX and
    # differentiated with respect to the entries they use, u = V[used], then placed (no MX
    # derivative graph over the whole decision vector; measured: the end rows' Jacobian and
    # Hessian 6.3 -> 2.4 ms to build on the planar swing, the SX expansion included)
    Vs = ca.SX.sym("V", nV)
    lam_fs, lam_es = ca.SX.sym("lam_f"), ca.SX.sym("lam_e", len(end_rows))
    ends_s, J_s = ca.Function("ends_q", [V, Q], [ends, J])(Vs, Qz)
    used = np.flatnonzero(ca.which_depends(ca.vertcat(ends_s, J_s), Vs, 1, False)).tolist()
    us, um = (Vs[used], V[used]) if used else (ca.SX(0, 1), ca.MX(0, 1))
    place = dm_triplet(len(used), nV, np.arange(len(used)), used, np.ones(len(used)))
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", nG)
    if end_rows:
        E = dm_triplet(nG, len(end_rows), end_rows, np.arange(len(end_rows)),
                        np.ones(len(end_rows)))
        jend = ca.Function("jac_ends", [us], [ca.jacobian(ends_s, us)])
        jac = jac + ca.mtimes(E, ca.mtimes(jend(um), place))
        lag_end = lam_fs * J_s + ca.dot(lam_es, ends_s)
    else:
        lag_end = lam_fs * J_s
    jac_g = ca.Function("nlp_jac_g", [V, p_in], [G_real, jac])
    # Hessian (used is increasing, so the placed upper triangle stays upper)
    hend = ca.Function("hess_ends", [us, lam_fs, lam_es],
                       [ca.triu(ca.hessian(lag_end, us)[0])])
    HV = ca.mtimes(place.T, ca.mtimes(
        hend(um, lam_f, lam_g[end_rows] if end_rows else ca.MX(0, 1)), place))
    lq = ca.mtimes(lin["JQ"].T, lam_g) + lam_f * lin["gJ"]
    Hp = point_hessian(q, y, syms, args, ca.reshape(lq, nq, M), pts, nV)
    H = HV if Hp is None else HV + Hp
    hess_lag = ca.Function("nlp_hess_l", [V, p_in, lam_f, lam_g], [ca.triu(H)])
    # the objective's gradient: the Radau weights through the per-point Jacobians, plus the
    # Mayer term's (J is linear in Q and separable, so its V part is that at Q = 0). Measured:
    # the objective and its gradient from the integrand alone (its own mapped function and
    # gradient) evaluate 0.04 ms faster per call pair but cost 1.2 ms (swing) / 0.6 ms
    # (cart-pole) more to build than IPOPT's 6-8 calls save
    gend = ca.Function("grad_ends", [us], [ca.gradient(J_s, us)])
    grad = ca.mtimes(D.T, lin["gJ"]) + ca.mtimes(place.T, gend(um))
    grad_f = ca.Function("nlp_grad_f", [V, p_in], [J_real, ca.densify(grad)])  # IPOPT: dense
    return {"jac_g": jac_g, "hess_lag": hess_lag, "grad_f": grad_f}
