"""Declared invariants (:meth:`daekit.Model.invariant`) in a reduced DAE.

An ODE whose state space holds more dimensions than the physics it represents has
invariants: a unit quaternion's ``|q|^2 - 1``, a lifted state's ``w - x^2``. They are not
equations of the model (the model is square without them) but, like the consistency
conditions the index reduction finds, they hold along exact solutions once they hold at the
start, and numerical solutions drift off them. The user declares them with ``m.invariant``;
here they join the found ones:

- :func:`attach_declared` maps them into the reduced system's symbols, appends them to
  ``r.invariants`` / ``r.invariant_names`` (so ``initialize`` holds them at ``t0``, projection
  projects onto them, trajectories and OCPs carry them) and *checks the claim*
  (:func:`check_declared`): the time derivative of each along the dynamics must vanish where
  all invariants and the algebraic equations hold; otherwise a :class:`ModelError` names it.
- :func:`baumgarte_declared` -- Baumgarte on a first-order invariant ``c(t, x)``:
  ``x' = f + G^T mu`` with ``G = dc/dx`` and a new algebraic ``mu`` fixed by
  ``c' + a c = 0`` (``c' = c_t + G x'``), one pole at ``-a``. Along exact solutions
  ``mu = 0``.
- :func:`declared_dummy` -- dummy derivatives: a declared invariant is a constraint whose
  dummy-derivative reformulation drops one state per invariant, chosen by QR with column
  pivoting of ``G`` at the selection point (the largest pivot: for ``|q|^2 = 1`` the largest
  ``|q_j|``). That state becomes algebraic, its ODE row is dropped and ``c = 0`` takes its
  place among the algebraic equations, so the invariant holds by construction (to the
  Newton tolerance). The choice is valid where the chosen pivot stays away from zero: ``G``
  joins Pryce's system Jacobian as one more diagonal block of ``r.selection_jacobian``
  / ``r.selection_blocks``, so :func:`daekit.reduction.selection_condition` watches
  it and the dummy-derivative simulation re-selects when it degrades (a quaternion component
  passing through zero).

Example
-------
>>> import casadi as ca, daekit as dk
>>> m = dk.Model("rotation")
>>> x = m.state("x", 2)
>>> _ = m.equation(m.der(x) - ca.vertcat(-x[1], x[0]), name="rotate")
>>> _ = m.invariant(ca.dot(x, x) - 1, name="circle")
>>> r = dk.reduce_index(m)
>>> r.invariant_names, r.declared_invariants
(['circle'], ['circle'])
>>> rd = dk.reduce_index(m, method="dummy_derivatives", point={"x": [0.1, 1.0]})
>>> rd.x_names, rd.state_selection["dummies"]
(['x[0]'], ['x[1]'])
"""

from __future__ import annotations

from collections.abc import Mapping

import casadi as ca
import numpy as np
import scipy
import scipy.sparse as sp

from ..errors import ModelError, ReductionError
from ..model import expand_name
from ..reduced import ReducedDAE

__all__ = ["attach_declared", "check_declared", "declared_names", "baumgarte_declared",
           "declared_dummy", "even_declared"]

#: relative size of the derivative of a declared invariant, against the size of its terms,
#: above which it is not an invariant
CHECK_RTOL = 1e-8
_DENSE = 400  # up to this many unknowns, manifold points by dense least squares


def _col(e: ca.SX) -> ca.SX:
    """``e`` as a column; an empty expression of any shape (a ``1x0`` ``alg``) as ``0x1``."""
    return ca.vec(e) if e.numel() else ca.SX(0, 1)


def declared_names(model) -> list[str]:
    """Element names of a model's declared invariants (``"unit"``, ``"lift[0]"``, ...).

    >>> import daekit as dk
    >>> declared_names(dk.Model("empty"))
    []
    """
    return [e.element(i) for e in getattr(model, "declared_invariants", []) for i in range(e.size)]


def _declared_in(r: ReducedDAE, model) -> ca.SX:
    """The declared invariants as expressions of ``r``'s symbols (through ``r.variables``)."""
    exprs = ca.vertcat(*[e.expr for e in model.declared_invariants])
    syms = ca.symvar(exprs)
    th = model.t.element_hash()
    src, dst = [], []
    for s in syms:
        if s.element_hash() == th:
            continue
        hit = model.lookup(s)
        inv = next(e.name for e in model.declared_invariants if ca.depends_on(e.expr, s))
        if hit is None:  # pragma: no cover - Model.invariant checks the symbols
            raise ModelError(f"model {model.name!r}, invariant {inv!r}: unknown symbol {s}")
        var, i, order = hit
        nm = var.element(i, order)
        if nm not in r.variables:
            raise ModelError(
                f"model {model.name!r}, invariant {inv!r} uses {nm!r}, which the reduced "
                "system does not have (a derivative above the order the equations use); "
                "write the invariant in terms of the states"
            )
        src.append(s)
        dst.append(ca.SX(r.variables[nm]))
    if not src:
        return exprs
    return ca.substitute([exprs], [ca.vertcat(*src)], [ca.vertcat(*dst)])[0]


def attach_declared(r: ReducedDAE, model, check: bool = True, seed: int = 0) -> ReducedDAE:
    """Append ``model``'s declared invariants to ``r`` (in place; returns ``r``).

    ``r.invariants`` / ``r.invariant_names`` get them after the found ones;
    ``r.declared_invariants`` lists their names; for ``r.chains`` (what
    Baumgarte stabilizes) each becomes a chain of length one marked ``"declared"``. With
    ``check`` the claim is verified (:func:`check_declared`).

    >>> import casadi as ca, daekit as dk
    >>> m = dk.Model("lift"); x = m.state("x"); w = m.state("w")
    >>> _ = m.equation(m.der(x) + x, name="decay")
    >>> _ = m.equation(m.der(w) + 2 * w, name="square")   # w = x^2 decays twice as fast
    >>> _ = m.invariant(w - x**2, name="lifted")
    >>> r = dk.reduce_index(m)
    >>> r.invariant_names, r.chains[-1]["declared"]
    (['lifted'], True)
    """
    names = declared_names(model)
    if not names:
        return r
    c = _declared_in(r, model)
    n_found = len(r.invariant_names)
    r.invariants = ca.vertcat(_col(r.invariants), c)
    r.invariant_names = list(r.invariant_names) + names
    r.declared_invariants = list(names)
    if r.method != "dummy_derivatives":
        chains = list(r.chains)
        chains += [{"equation": nm, "row": None, "invariants": [n_found + k], "alg": None,
                    "declared": True} for k, nm in enumerate(names)]
        r.chains = chains
    if check:
        check_declared(r, n_found, seed=seed, model_name=getattr(model, "name", "model"))
    return r


# ---------------------------------------------------------------------------- the check
def _manifold_point(hfun, n: int, rng, dense: bool, attempts: int = 6):
    """A point ``w`` with ``h(w) = 0`` (Gauss--Newton, minimum-norm steps), or None."""
    for a in range(attempts):
        w = rng.uniform(0.2, 1.2, n) if a % 2 == 0 else rng.standard_normal(n)
        for _ in range(60):
            hv, J = hfun(w)
            hv = np.asarray(hv, dtype=float).ravel()
            if not np.all(np.isfinite(hv)):
                break
            if np.max(np.abs(hv), initial=0.0) <= 1e-13 * (1.0 + np.max(np.abs(w))):
                return w
            if dense:
                Jd = np.asarray(ca.DM(J).full(), dtype=float)
                if not np.all(np.isfinite(Jd)):
                    break
                d = np.linalg.lstsq(Jd, -hv, rcond=1e-12)[0]
            else:
                Js = _to_csc(ca.DM(J))
                if not np.all(np.isfinite(Js.data)):
                    break
                d = sp.linalg.lsmr(Js, -hv, atol=1e-15, btol=1e-15, maxiter=10 * n)[0]
            w = w + d
            if not np.all(np.isfinite(w)):
                break
    return None


def _to_csc(M: ca.DM) -> sp.csc_matrix:
    colind, row = M.sparsity().get_ccs()
    return sp.csc_matrix((np.asarray(M.nonzeros(), dtype=float), row, colind), shape=M.shape)


def check_declared(r: ReducedDAE, n_found: int, seed: int = 0, points: int = 3,
                   model_name: str = "model") -> None:
    """Check that the invariants of ``r`` from position ``n_found`` on are invariants.

    At ``points`` random points on the manifold where the algebraic equations and *all*
    invariants hold (random time, inputs and input rates, default parameters; found by
    Gauss--Newton with minimum-norm steps), the time derivative along the dynamics,
    ``c' = c_t + c_x x' + c_u u' + c_z z'`` (``z'`` from differentiating ``alg = 0``), must be
    below :data:`CHECK_RTOL` times the size of its terms. Raises :class:`ModelError` naming
    the first declared invariant that fails, with the residual; also when a declared
    invariant is implied by the others (it would count a degree of freedom twice) or when no
    point satisfies them all.

    >>> import casadi as ca, daekit as dk
    >>> m = dk.Model("rotation"); x = m.state("x", 2)
    >>> _ = m.equation(m.der(x) - ca.vertcat(-x[1], x[0]), name="rotate")
    >>> _ = m.invariant(x[0] - 1, name="wrong")
    >>> dk.reduce_index(m)
    Traceback (most recent call last):
    ...
    daekit.errors.ModelError: model 'rotation': 'wrong' is not an invariant: ...
    """
    names = r.invariant_names[n_found:]
    k = len(names)
    if k == 0:
        return
    c = r.invariants[n_found:]
    t, x, z, u, p = r.t, r.x, r.z, r.u, r.p
    ud = ca.SX.sym("udot", r.nu)
    w = ca.vertcat(x, z)
    H = ca.vertcat(_col(r.alg), _col(r.invariants))
    n = r.nx + r.nz
    dense = n <= _DENSE
    tt, uu = ca.SX.sym("tt"), ca.SX.sym("uu", r.nu)
    Hs = ca.substitute([H], [t, u, p], [tt, uu, ca.DM(r.p_values)])[0]
    hsym = ca.Function("h", [w, tt, uu], [Hs, ca.jacobian(Hs, w)])
    cx, ct, cu, cz = (ca.jacobian(c, v) for v in (x, t, u, z))
    cdot = ct + ca.mtimes(cx, r.ode) + ca.mtimes(cu, ud)
    size = ca.fabs(ct) + ca.mtimes(ca.fabs(cx), ca.fabs(r.ode)) + ca.mtimes(ca.fabs(cu), ca.fabs(ud))
    outs = [ca.densify(cdot), ca.densify(size)]
    uses_z = cz.nnz() > 0 and r.nz > 0
    if uses_z:
        alg = _col(r.alg)
        gz = ca.jacobian(alg, z)
        rhs = ca.jacobian(alg, t) + ca.jtimes(alg, x, r.ode) + ca.jtimes(alg, u, ud)
        outs += [cz, gz, ca.densify(rhs)]
    dfun = ca.Function("cdot", [t, x, z, u, p, ud], outs)
    rng = np.random.default_rng(seed + 101)
    checked = 0
    for _ in range(points * 3):
        t0 = float(rng.uniform(0.1, 1.0))
        u0, ud0 = rng.uniform(0.2, 1.2, r.nu), rng.uniform(0.2, 1.2, r.nu)
        wv = _manifold_point(lambda wv, t0=t0, u0=u0: hsym(wv, t0, u0), n, rng, dense)
        if wv is None:
            continue
        res = dfun(t0, wv[: r.nx], wv[r.nx:], u0, r.p_values, ud0)
        d = np.asarray(res[0], dtype=float).ravel()
        s = np.asarray(res[1], dtype=float).ravel()
        if uses_z:
            Cz, Gz = _to_csc(ca.DM(res[2])), _to_csc(ca.DM(res[3]))
            rh = np.asarray(res[4], dtype=float).ravel()
            try:
                zd = -sp.linalg.splu(Gz).solve(rh)
            except RuntimeError:
                continue
            d = d + Cz @ zd
            s = s + abs(Cz) @ np.abs(zd)
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(s))):
            continue
        bad = np.nonzero(np.abs(d) > CHECK_RTOL * np.maximum(s, 1e-300))[0]
        bad = [i for i in bad if abs(d[i]) > 1e-14]
        if bad:
            i = bad[0]
            expr = "" if uses_z or ca.depends_on(cdot[i], z) else _short_expr(cdot[i])
            raise ModelError(
                f"model {model_name!r}: {names[i]!r} is not an invariant: its time derivative "
                f"along the dynamics{expr} does not vanish where the invariants hold; at a "
                f"random point on that manifold it is {d[i]:.3g} (its terms are of size "
                f"{s[i]:.3g}). An invariant holds along every solution that starts on it; "
                "correct the expression or remove the m.invariant declaration."
            )
        if checked == 0 and dense:
            _check_independent(hsym, wv, t0, u0, r, n_found, names, model_name)
        checked += 1
        if checked == points:
            return
    if checked == 0:
        raise ModelError(
            f"model {model_name!r}: no point was found where the declared invariants "
            f"{names} hold together with the model's equations and consistency conditions; "
            "check that they can hold at all (each is 'expr = 0')"
        )


def _short_expr(e: ca.SX, limit: int = 160) -> str:
    s = str(e)
    return f" ({s})" if len(s) <= limit else ""


def _check_independent(hsym, wv, t0, u0, r, n_found, names, model_name) -> None:
    """A declared invariant implied by the algebraic equations and the invariants before it
    constrains nothing new: a ModelError naming it (it would remove a degree of freedom
    twice)."""
    from ..analysis import numeric_rank

    J = np.asarray(ca.DM(hsym(wv, t0, u0)[1]).full(), dtype=float)
    first = r.nz + n_found
    rank, _ = numeric_rank(J[:first]) if first else (0, 1.0)
    for i, nm in enumerate(names):
        new, _ = numeric_rank(J[: first + i + 1])
        if new == rank:
            raise ModelError(
                f"model {model_name!r}: the declared invariant {nm!r} is implied by the "
                "model's equations and the invariants before it (its gradient is a "
                "combination of theirs); it adds nothing: remove the m.invariant declaration"
            )
        rank = new


# ---------------------------------------------------------------------------- Baumgarte
def baumgarte_declared(r: ReducedDAE, out: ReducedDAE, chains: list[dict],
                       coefficients: list[float]) -> None:
    """Baumgarte on declared (first-order) invariants, in place on the copy ``out`` of ``r``.

    For the invariants ``c`` of the ``chains`` (``c' + a c = 0`` with ``a`` from
    ``coefficients``): ``G = dc/dx``, new algebraic unknowns ``mu`` (named ``"mu(unit)"``),
    ``x' = f + G^T mu`` and the algebraic equations ``c_t + G (f + G^T mu) + a c = 0``
    (index 1 where ``G G^T`` is nonsingular). ``c`` must not depend on the algebraic
    unknowns or the inputs (a ReductionError names it otherwise).
    """
    if not chains:
        return
    idx = [ch["invariants"][0] for ch in chains]
    names = [ch["equation"] for ch in chains]
    C = ca.vertcat(*[r.invariants[i] for i in idx])
    for v, what in ((r.z, "algebraic unknowns"), (r.u, "inputs")):
        if v.numel():
            rows, _ = ca.jacobian_sparsity(C, v).get_triplet()
            if rows:
                raise ReductionError(
                    f"baumgarte: the declared invariant {names[int(rows[0])]!r} depends on the "
                    f"{what} of the reduced system; Baumgarte stabilization of a declared "
                    "invariant needs it in terms of the states (and time and parameters); use "
                    "stabilization='projection' for it"
                )
    G = ca.jacobian(C, r.x)
    mu = ca.vertcat(*[ca.SX.sym(f"mu({nm})") for nm in names])
    ode = out.ode + ca.mtimes(G.T, mu)
    a = ca.DM(coefficients)
    alg_new = ca.jacobian(C, r.t) + ca.mtimes(G, ode) + a * C
    out.ode = ode
    out.alg = ca.vertcat(_col(out.alg), alg_new)
    out.z = ca.vertcat(out.z, mu)
    out.z_names = list(out.z_names) + [f"mu({nm})" for nm in names]
    alg_names = list(out.alg_labels)
    out.alg_names = alg_names + [f"d/dt {nm} + {float(ai):g} {nm}"
                                         for nm, ai in zip(names, coefficients, strict=True)]


# ---------------------------------------------------------------------------- dummies
def _point_values(r: ReducedDAE, point: Mapping | None, seed: int) -> tuple:
    """``(t, x, z, u)`` for ``r`` from values by original name (random where not given)."""
    rng = np.random.default_rng(seed + 7)
    vals: dict[str, float] = {}
    t = 0.0
    keys = list(r.x_names) + list(r.z_names) + list(r.u_names)
    for name, value in (point or {}).items():
        if name == "t":
            t = float(value)
            continue
        try:
            els = expand_name(name, keys, "the reduced system")
        except ModelError:
            continue  # a name the system does not use (e.g. an eliminated derivative)
        arr = np.atleast_1d(np.asarray(value, dtype=float)).ravel()
        if arr.size == 1:
            arr = np.repeat(arr, len(els))
        if arr.size != len(els):
            raise ReductionError(
                f"point[{name!r}] has {arr.size} values, but {name!r} has {len(els)} element(s)"
            )
        vals.update(zip(els, arr.tolist(), strict=True))

    def vec(names):
        return np.array([vals.get(nm, float(rng.uniform(0.2, 1.2))) for nm in names])

    return t, vec(r.x_names), vec(r.z_names), vec(r.u_names)


def declared_dummy(r: ReducedDAE, n_found: int, point: Mapping | None = None,
                   seed: int = 0) -> ReducedDAE:
    """Dummy-derivative reformulation of the declared invariants ``r.invariants[n_found:]``.

    ``G = dc/dx`` at ``point`` (values by original name; random where missing); QR with
    column pivoting picks one state per invariant (the largest pivot); those states become
    algebraic unknowns, their ODE rows are dropped, and the invariants join the algebraic
    equations. ``r.state_selection`` records the choice as a stage ``"declared"``;
    ``r.declared_selection`` holds ``G`` (``"expression"``, in ``r``'s symbols), the
    chosen columns and the candidate names.
    """
    names = list(r.invariant_names[n_found:])
    if not names:
        return r
    c = r.invariants[n_found:]
    k = len(names)
    Gsym = ca.jacobian(c, r.x)
    cand = list(r.x_names)
    gfun = ca.Function("G", [r.t, r.x, r.z, r.u, r.p], [Gsym])
    t0, x0, z0, u0 = _point_values(r, point, seed)
    G = np.asarray(ca.DM(gfun(t0, x0, z0, u0, r.p_values)).full(), dtype=float)
    if not np.all(np.isfinite(G)) or k > r.nx:
        raise ReductionError(
            f"dummy derivatives: the declared invariants {names} cannot be solved for states at "
            "the selection point; give another point (point={...})"
        )
    if k == 1:
        cols = np.array([int(np.argmax(np.abs(G[0])))])
    else:
        _, _, piv = scipy.linalg.qr(G, mode="economic", pivoting=True)
        cols = np.sort(piv[:k])
    sub = G[:, cols]
    smin = np.linalg.svd(sub, compute_uv=False)[-1] if sub.size else 0.0
    if not smin > 1e-12 * max(np.linalg.norm(G), 1e-300):
        raise ReductionError(
            f"dummy derivatives: the declared invariants {names} do not determine any states at "
            "the selection point (their gradients vanish or are dependent there); give "
            "another point (point={...})"
        )
    cond = float(np.linalg.norm(G, 2) / smin)
    keep = [i for i in range(r.nx) if i not in set(cols.tolist())]
    xs = r.x
    r.x = xs[keep] if keep else ca.SX(0, 1)
    r.z = ca.vertcat(r.z, xs[cols.tolist()])
    r.ode = r.ode[keep] if keep else ca.SX(0, 1)
    r.alg = ca.vertcat(_col(r.alg), c)
    dummies = [cand[i] for i in cols]
    r.x_names = [cand[i] for i in keep]
    r.z_names = list(r.z_names) + dummies
    r.alg_names = list(r.alg_names) + names
    sel = r.state_selection if r.state_selection is not None else {
        "dummies": [], "stages": [], "condition": 1.0}
    sel["states"] = list(r.x_names)
    sel["dummies"] = list(sel.get("dummies", [])) + dummies
    sel["stages"] = list(sel.get("stages", [])) + [{
        "stage": "declared", "equations": names, "candidates": cand, "dummies": dummies,
        "condition": cond, "blocks": 1}]
    sel["condition"] = max(float(sel.get("condition", 1.0)), cond)
    r.state_selection = sel
    r.declared_selection = {"expression": Gsym, "cols": cols, "candidates": cand}
    return r


def even_declared(r: ReducedDAE, seed: int = 0) -> dict[str, list[str]]:
    """Declared invariants unchanged when all the states they involve change sign together
    (``|q|^2 - 1`` under ``q -> -q``): ``{invariant: [state names]}``. Conditions that fix all
    those states then fix a sign that the invariant leaves open (for a quaternion: which of
    the two representations of the same rotation, hence which way round it turns).

    >>> import daekit as dk
    >>> even_declared(dk.reduce_index(dk.examples.rigid_body()))
    {'unit': ['q[0]', 'q[1]', 'q[2]', 'q[3]']}
    """
    names = r.declared_invariants
    if not names:
        return {}
    n0 = len(r.invariant_names) - len(names)
    rng = np.random.default_rng(seed + 3)
    out: dict[str, list[str]] = {}
    for k, nm in enumerate(names):
        c = r.invariants[n0 + k]
        if ca.depends_on(c, r.z) if r.nz else False:
            continue
        _, cols = ca.jacobian_sparsity(c, r.x).get_triplet()
        cols = sorted(set(int(j) for j in cols))
        if not cols:
            continue
        flip = np.ones(r.nx)
        flip[cols] = -1.0
        f = ca.Function("c", [r.t, r.x, r.u, r.p], [c])
        even = True
        for _ in range(2):
            t, x, u = float(rng.uniform()), rng.uniform(0.2, 1.2, r.nx), rng.uniform(size=r.nu)
            a = float(f(t, x, u, r.p_values))
            b = float(f(t, flip * x, u, r.p_values))
            if not abs(a - b) <= 1e-12 * max(1.0, abs(a)):
                even = False
                break
        if even:
            out[nm] = [r.x_names[j] for j in cols]
    return out
