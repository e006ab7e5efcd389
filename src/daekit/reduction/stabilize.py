"""Stabilizations of a reduced DAE against drift of its invariants.

After :func:`~daekit.reduction.reduce_index` (method ``"differentiate"``), each equation ``F_i``
with offset ``c_i > 0`` gives an invariant chain ``c = F_i, c' = F_i', ..., c^(m-1)`` and the
algebraic equation ``c^(m) = 0`` (``m = c_i``). Integrating ``c^(m) = 0`` lets rounding and
truncation errors grow like ``t^(m-1)`` in ``c``.

- :func:`baumgarte` replaces ``c^(m) = 0`` by ``c^(m) + a_(m-1) c^(m-1) + ... + a_0 c = 0``
  whose characteristic polynomial has the given poles, so drift decays like ``exp(pole t)``
  (Baumgarte 1972; Ascher, Chin & Reich 1994 for choosing the poles: a few times faster than
  the model's own dynamics, not more, or the system turns stiff).
- :func:`ggl` (Gear, Gupta & Leimkuhler 1985) for mechanical systems: the position
  constraints ``0 = c(q)`` and the velocity constraints ``0 = c'`` are both imposed, with a new
  multiplier ``mu`` in ``q' = v + G(q)^T mu`` (``G = dc/dq``); along exact solutions ``mu = 0``.
  The result is index 2 (Hessenberg form): integrate it with the algebraic variables excluded
  from the error test (IDAS option ``suppress_algebraic``) and consistent initial values.
"""

from __future__ import annotations

import copy
import warnings

import casadi as ca
import numpy as np

from ..errors import ReductionError
from ..reduced import ReducedDAE
from .accept import as_reduced
from .invariants import baumgarte_declared

__all__ = ["BaumgarteStiffnessWarning", "baumgarte", "ggl", "time_scale"]


class BaumgarteStiffnessWarning(UserWarning):
    """Baumgarte poles far faster than the model's own dynamics: the system becomes stiff."""


def _poles(poles) -> np.ndarray:
    """The poles as a 1-D complex array; a ReductionError saying what is expected otherwise."""
    if isinstance(poles, (str, bytes)):
        arr = None
    else:
        try:
            arr = np.asarray(poles, dtype=complex)
        except (TypeError, ValueError):
            arr = None
    if arr is None or arr.ndim > 1:
        raise ReductionError(
            f"baumgarte: poles must be a number or a sequence of numbers (one per "
            f"derivative level of the longest invariant chain, e.g. poles=(-1.0, -1.0)), "
            f"got {poles!r}"
        )
    return np.atleast_1d(arr)


def _chain_coefficients(poles, m: int) -> np.ndarray:
    """``[a_0, ..., a_(m-1)]`` of ``prod (s - pole)`` over the first ``m`` poles (the last pole
    repeated if fewer are given)."""
    ps = list(_poles(poles))
    if not ps:
        raise ReductionError("baumgarte: give at least one pole, e.g. poles=(-1.0, -1.0)")
    if not all(np.isfinite(p) for p in ps):
        raise ReductionError(f"baumgarte: the poles must be finite numbers, got {list(poles)}")
    unstable = [f"{p.real:g}" if p.imag == 0 else f"{p:g}" for p in ps if p.real >= 0]
    if unstable:
        raise ReductionError(
            f"baumgarte: the poles {', '.join(unstable)} have real part >= 0, so the constraint dynamics "
            "c'' + a1 c' + a0 c = 0 would not decay (drift would grow); give poles with negative "
            "real parts, e.g. poles=(-1.0, -1.0)"
        )
    ps = (ps + [ps[-1]] * m)[:m]
    coef = np.poly(ps)  # [1, a_(m-1), ..., a_0]
    if np.max(np.abs(coef.imag)) > 1e-12 * max(1.0, np.max(np.abs(coef.real))):
        raise ReductionError(
            f"baumgarte: the poles {ps} give complex coefficients; give complex poles in "
            "conjugate pairs"
        )
    return coef.real[::-1][:m]


def time_scale(r: ReducedDAE, x=None, z=None, u=None, seed: int = 0) -> float | None:
    """The model's fastest rate ``max |eig(A)|`` of the linearized index-1 ODE at a point.

    ``A = ode_x - ode_z (alg_z)^-1 alg_x`` at ``(x, z)`` (random when not given). ``None`` for
    systems with more than 300 states (too costly to check densely) or where the evaluation
    fails.
    """
    if r.nx == 0 or r.nx > 300:
        return None
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.2, 1.2, r.nx) if x is None else np.asarray(x, float)
    z = rng.uniform(0.2, 1.2, r.nz) if z is None else np.asarray(z, float)
    u = np.zeros(r.nu) if u is None else np.asarray(u, float)
    f = ca.Function(
        "lin",
        [r.t, r.x, r.z, r.u, r.p],
        [ca.jacobian(r.ode, r.x), ca.jacobian(r.ode, r.z), ca.jacobian(r.alg, r.x),
         ca.jacobian(r.alg, r.z)],
    )
    fx, fz, gx, gz = (np.asarray(ca.DM(a).full()) for a in f(0.0, x, z, u, r.p_values))
    try:
        A = fx - fz @ np.linalg.solve(gz, gx) if r.nz else fx
        ev = np.linalg.eigvals(A)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(ev)):
        return None
    return float(np.max(np.abs(ev)))


def baumgarte(
    r: ReducedDAE,
    poles=(-1.0, -1.0),
    x=None,
    z=None,
    warn_ratio: float = 100.0,
) -> ReducedDAE:
    """Baumgarte stabilization: each invariant chain gets ``c^(m) + ... + a_0 c = 0``.

    Parameters
    ----------
    r : ReducedDAE
        From ``reduce_index(model)`` (method ``"differentiate"``) or
        :meth:`daekit.mechanics.LagrangianSystem.index1`.
    poles : sequence of float (complex in conjugate pairs)
        Roots of ``s^m + a_(m-1) s^(m-1) + ... + a_0`` (negative: drift decays). A chain of
        length ``m`` uses the first ``m`` poles (the last one repeated when fewer are given):
        ``(-1, -1)`` gives ``c'' + 2 c' + c = 0`` for a position constraint and
        ``c' + c = 0`` for a velocity-level one.
    x, z : array, optional
        A (consistent) point for the time-scale check; random when not given.
    warn_ratio : float
        Warn (:class:`BaumgarteStiffnessWarning`) when the fastest pole is more than this many
        times faster than the model's fastest rate :func:`time_scale`.

    Returns
    -------
    ReducedDAE
        A copy with the modified ``alg`` (still index 1: the invariants do not involve ``z``),
        ``stabilization="baumgarte"`` and ``info["baumgarte"]`` (poles, coefficients per chain).

    Example
    -------
    >>> import daekit as dk
    >>> from daekit.reduction import reduce_index
    >>> rb = baumgarte(reduce_index(dk.examples.pendulum_planar()), poles=(-1.0, -1.0))
    >>> rb.info["baumgarte"]["coefficients"]["rod"]
    [1.0, 2.0]
    """
    r = as_reduced(r, "baumgarte")  # a Model or LagrangianSystem: reduced (the one rule)
    if r.method == "dummy_derivatives":
        raise ReductionError(
            "baumgarte: a dummy-derivative system keeps every invariant among its algebraic "
            "equations, so nothing drifts and there is nothing to stabilize; use "
            "reduce_index(model) (method='differentiate') for Baumgarte stabilization"
        )
    chains = r.chains
    if chains is None:
        raise ReductionError(
            "baumgarte: this ReducedDAE carries no invariant chains (r.chains); make it "
            "with daekit.reduce_index(model)"
        )
    _chain_coefficients(poles, 1)  # validate the poles even without chains
    inv_rows, alg_rows, vals, coeffs = [], [], [], {}
    declared, declared_a = [], []
    for ch in chains:
        m = len(ch["invariants"])
        a = _chain_coefficients(poles, m)
        coeffs[ch["equation"]] = a.tolist()
        if ch.get("declared"):  # m.invariant(...): c' + a0 c = 0 through a multiplier
            declared.append(ch)
            declared_a.append(float(a[0]))
            continue
        for k, idx in enumerate(ch["invariants"]):
            alg_rows.append(ch["alg"])
            inv_rows.append(idx)
            vals.append(float(a[k]))
    out = copy.copy(r)
    out.info = dict(r.info)
    if vals:
        W = ca.DM(ca.Sparsity.triplet(r.nz, len(r.invariant_names), alg_rows, inv_rows), vals)
        out.alg = r.alg + ca.mtimes(W, r.invariants)
    baumgarte_declared(r, out, declared, declared_a)
    fastest = float(np.max(np.abs(_poles(poles))))
    rate = time_scale(r, x, z)
    # a model with no rate of its own (all eigenvalues zero, e.g. a free mass on a constraint)
    # gives no time scale to compare the poles with: no warning then
    if rate is not None and rate > 1e-9 and fastest > warn_ratio * rate:
        warnings.warn(
            f"baumgarte: the fastest pole ({fastest:g}) is more than {warn_ratio:g} times faster "
            f"than the model's own fastest rate (about {rate:.3g}); the stabilized system is "
            "stiff and an explicit or low-accuracy integrator will struggle. Choose poles a few "
            "times faster than the model's dynamics (Ascher, Chin & Reich 1994).",
            BaumgarteStiffnessWarning,
            stacklevel=2,
        )
    out.stabilization = "baumgarte"
    out.info["baumgarte"] = {"poles": list(np.atleast_1d(poles)), "coefficients": coeffs,
                             "model_rate": rate}
    return out


def ggl(r: ReducedDAE) -> ReducedDAE:
    """Gear--Gupta--Leimkuhler stabilized form of a mechanical system (index 2).

    For every invariant chain of length 2 (a position constraint ``c(q) = 0`` with its velocity
    constraint ``c' = G(q) q' = 0``): the algebraic equation ``c'' = 0`` is replaced by the
    velocity constraint ``c' = 0``, the position constraint ``c = 0`` is added, and the ODE of
    the positions ``q`` (the states ``c`` depends on) becomes ``q' = v + G(q)^T mu`` with a new
    algebraic variable ``mu`` per constraint (named ``"mu(rod)"``). Both constraints then hold
    along numerical solutions; ``mu`` is zero along exact ones. Other chains are kept as they
    are (see ``r.chains``).

    The result is index 2 in Hessenberg form: integrate it with ``suppress_algebraic`` (IDAS)
    from consistent initial values.

    >>> import daekit as dk
    >>> from daekit.reduction import reduce_index
    >>> rg = ggl(reduce_index(dk.examples.pendulum_planar()))
    >>> rg.z_names[-1], rg.index
    ('mu(rod)', 2)
    """
    r = as_reduced(r, "ggl")  # a Model or LagrangianSystem: reduced (the one rule)
    chains = r.chains
    pos = [ch for ch in chains if len(ch["invariants"]) == 2]
    if r.method not in ("differentiate", "lagrangian") or not pos:
        raise ReductionError(
            "ggl: needs a ReducedDAE from reduce_index(model) (method='differentiate') or "
            "LagrangianSystem.index1() with position constraints (equations differentiated "
            "twice); this one has none"
        )
    C = ca.vertcat(*[r.invariants[ch["invariants"][0]] for ch in pos])
    C1 = ca.vertcat(*[r.invariants[ch["invariants"][1]] for ch in pos])
    _, cols = ca.jacobian_sparsity(C, r.x).get_triplet()
    q_idx = sorted(set(cols))
    G = ca.jacobian(C, r.x[q_idx])
    mu = ca.vertcat(*[ca.SX.sym(f"mu({ch['equation']})") for ch in pos])
    ode = ca.SX(r.ode)
    ode[q_idx] = ode[q_idx] + ca.mtimes(G.T, mu)
    alg = ca.SX(r.alg)
    alg[[ch["alg"] for ch in pos]] = C1
    alg = ca.vertcat(alg, C)
    out = copy.copy(r)
    out.ode = ode
    out.alg = alg
    out.z = ca.vertcat(r.z, mu)
    out.z_names = list(r.z_names) + [f"mu({ch['equation']})" for ch in pos]
    out.stabilization = "ggl"
    out.info = dict(r.info)
    names = list(r.alg_labels)
    for ch in pos:
        names[ch["alg"]] = "d/dt " + ch["equation"]
    out.alg_names = names + [ch["equation"] for ch in pos]
    out.chains = [ch for ch in chains if len(ch["invariants"]) != 2]
    out.index = 2
    out.info["ggl_positions"] = [r.x_names[i] for i in q_idx]
    # the index-1 system it came from: consistent initial values are found there (with the
    # hidden constraint c'' = 0 that fixes the multipliers z), and mu = 0
    out.origin = r
    return out
