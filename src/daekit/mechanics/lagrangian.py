"""Lagrangian mechanics: from kinetic and potential energy, constraints and forces to DAEs.

A mechanical system with generalized coordinates ``q`` (n), velocities ``q'``, kinetic energy
``T(q, q')``, potential ``V(q)``, holonomic constraints ``c(q) = 0`` (m) and generalized forces
``Q(t, q, q', u)`` moves by the Euler--Lagrange equations with multipliers ``z``::

    d/dt dT/dq' - dT/dq + dV/dq + G(q)^T z = Q,     c(q) = 0,     G = dc/dq.

This is an index-3 DAE. :class:`LagrangianSystem` builds it as a :class:`daekit.Model`
(:meth:`LagrangianSystem.model`, second-order form in ``q``), and writes its index-1 form
directly (:meth:`LagrangianSystem.index1`, a :class:`daekit.reduced.ReducedDAE`), the form of
lecture L3: with ``M = d^2T/dq'^2`` and ``a = q''``::

    [M  G^T] [a]   [Q - M' q' + grad_q (T - V)]
    [G  0  ] [z] = [-(G q')_q q'              ]

together with the invariants ``c = 0`` and ``dc/dt = G q' = 0``. Everything is built from
gradients and directional derivatives (``casadi.jtimes``): ``M' q'`` and the constraint
curvature ``(G q')_q q'`` are never formed from full symbolic Hessians.

Example
-------
>>> import casadi as ca
>>> from daekit.mechanics import LagrangianSystem
>>> x = ca.SX.sym("x", 2); dx = ca.SX.sym("dx", 2); g = ca.SX.sym("g")
>>> pend = LagrangianSystem({"q": x}, dx, T=0.5 * ca.dot(dx, dx), V=g * x[1],
...                         constraints={"rod": 0.5 * (ca.dot(x, x) - 1)},
...                         parameters={"g": (g, 9.81)}, name="pendulum")
>>> r = pend.index1()
>>> r.x_names, r.z_names
(['q[0]', 'q[1]', 'der(q)[0]', 'der(q)[1]'], ['der(q,2)[0]', 'der(q,2)[1]', 'z'])
>>> r.invariant_names
['rod', 'd/dt rod']
"""

from __future__ import annotations

from collections.abc import Mapping

import casadi as ca
import numpy as np
import scipy.sparse as sp

from ..errors import ModelError
from ..model import Model, element_name
from ..reduced import ReducedDAE
from ..wording import count

__all__ = ["LagrangianSystem", "lagrangian"]


# ---------------------------------------------------------------------------------- helpers
def _to_sx(value, what: str) -> ca.SX:
    if isinstance(value, ca.MX):
        raise ModelError(f"{what}: MX expressions are not supported; build it from SX symbols")
    try:
        sx = value if isinstance(value, ca.SX) else ca.SX(value)
    except Exception as exc:  # noqa: BLE001 - turned into a daekit error
        raise ModelError(
            f"{what}: cannot convert {type(value).__name__} to CasADi SX ({exc})"
        ) from None
    return ca.vec(ca.densify(sx))


def _groups(value, default: str, what: str) -> list[tuple[str, ca.SX]]:
    """``SX`` -> ``[(default, SX)]``; ``{name: SX}`` -> list of pairs; ``None`` -> ``[]``."""
    if value is None:
        return []
    items = list(value.items()) if isinstance(value, Mapping) else [(default, value)]
    out = []
    for name, expr in items:
        if not isinstance(name, str):
            raise ModelError(f"{what}: names must be strings, got {name!r}")
        sx = _to_sx(expr, f"{what} {name!r}")
        if sx.numel() == 0:
            raise ModelError(f"{what} {name!r} is empty")
        out.append((name, sx))
    return out


def _element_names(groups: list[tuple[str, int]], order: int = 0) -> list[str]:
    return [element_name(n, s, i, order) for n, s in groups for i in range(s)]


def _symbols(sx: ca.SX, what: str) -> None:
    for i in range(sx.numel()):
        if not sx[i].is_symbolic():
            raise ModelError(
                f"{what}: element {i} is the expression {sx[i]}, not a symbol; pass symbols made "
                "with casadi.SX.sym"
            )


def _to_scipy(dm: ca.DM) -> sp.csc_matrix:
    r, c = dm.sparsity().get_triplet()
    return sp.csc_matrix(
        (np.asarray(dm.nonzeros(), dtype=float), (np.asarray(r, int), np.asarray(c, int))),
        shape=dm.shape,
    )


class LagrangianSystem:
    """A constrained mechanical system given by its energies, constraints and forces.

    Parameters
    ----------
    coordinates : casadi.SX or dict of str to casadi.SX
        The generalized coordinates ``q`` (symbols). A dict names groups of them
        (``{"alpha": alpha, "p": p}``); a bare SX is named ``"q"``. The names become the model's
        state names, so ``"p[0]"``, ``"der(p)"``, ``"der(p,2)"`` work everywhere.
    velocities : casadi.SX or dict of str to casadi.SX
        Symbols standing for ``q'`` in ``T`` and ``forces``, as many as coordinates (a dict with
        the same keys, or one SX in the order of the coordinates).
    T : casadi.SX
        Kinetic energy ``T(q, q')``, at most quadratic in ``q'`` with a positive definite
        mass matrix ``M = d^2T/dq'^2`` (``T = 1/2 q'^T M(q) q' + b(q)^T q' + T0(q)``).
    V : casadi.SX, optional
        Potential energy ``V(q)``.
    constraints : casadi.SX or dict of str to casadi.SX, optional
        Holonomic constraints ``c(q) = 0``; a dict names them (``{"rod": ...}``), a bare SX is
        named ``"c"``. They may depend on ``q`` and parameters only.
    forces : casadi.SX, optional
        Generalized forces ``Q(t, q, q', u)`` (n), e.g. motor torques, friction.
    inputs : casadi.SX or dict of str to casadi.SX, optional
        Input symbols ``u`` used in ``forces`` (a bare SX is named ``"u"``).
    parameters : dict of str to (casadi.SX, value), optional
        Named constants: symbol and default value.
    t : casadi.SX, optional
        The time symbol, if ``forces`` depend on time.
    multipliers : str
        Name of the multiplier vector ``z`` (one per constraint element).
    name : str
        Name of the model.
    equation_name : str
        Name of the Euler--Lagrange equations in the model.
    check : bool
        Check at two random configurations (parameters at their defaults) that the mass
        matrix is positive definite and the constraint Jacobian has full row rank (default).

    Sign conventions: the constraint force on the coordinates is ``-G^T z``, so for the
    pendulum with ``c = (p.p - L^2)/2``, ``z`` is the rod tension divided by ``L``.

    What it gives
    -------------
    - :meth:`model`: the index-3 :class:`daekit.Model`, second-order form. States: the
      coordinate groups (their ``der(., 2)`` appear); algebraic: ``multipliers``; controls:
      ``inputs``; parameters. Equations: ``equation_name`` (n),
      ``M q'' + M' q' - grad_q T + grad_q V + G^T z - Q = 0``, and one per constraint group.
    - :meth:`index1`: the index-1 form as a :class:`~daekit.reduced.ReducedDAE` (``method =
      "lagrangian"``): states ``x = (q, q')`` (names ``"q[i]"``, ``"der(q)[i]"``), algebraic
      unknowns ``(q'', z)`` (``"der(q,2)[i]"``, ``"z[j]"``), semi-explicit
      ``x' = (q', q'')``, ``0 = [Euler--Lagrange residual; G q'' + (G q')_q q']``, invariants
      ``[c; G q']`` named ``"rod"``/``"d/dt rod"`` (or ``"c[0]"``/``"d/dt c[0]"``).
      ``q''`` stays an algebraic unknown (rather than being eliminated by solving the linear
      system symbolically), which keeps the expressions sparse; ``d alg / d(q'', z)`` is the
      KKT matrix ``[M G^T; G 0]``. ``r.lagrangian`` is this object;
      ``r.chains`` and ``r.alg_names`` are filled as by
      :func:`daekit.reduce_index`, so :func:`daekit.baumgarte`, :func:`daekit.ggl` and
      ``daekit.simulate(..., stabilization="baumgarte")`` work on the result.
    - For RATTLE and other structure-exploiting integrators, CasADi Functions (the symbolic
      arguments are named; ``p`` is the parameter vector in declaration order, ``u`` the inputs):

      ========================  ===========================  =============================
      attribute                 inputs                       output
      ========================  ===========================  =============================
      ``mass_matrix``           ``q, p``                     ``M`` (n x n, sparse)
      ``momentum``              ``q, dq, p``                 ``dT/dq'``
      ``kinetic_energy``        ``q, dq, p``                 ``T``
      ``potential_energy``      ``q, p``                     ``V``
      ``energy``                ``q, dq, p``                 ``T + V``
      ``potential_gradient``    ``q, p``                     ``grad_q V``
      ``velocity_terms``        ``q, dq, p``                 ``M' q' - grad_q T``
      ``generalized_force``     ``t, q, dq, u, p``           ``Q``
      ``constraint``            ``q, p``                     ``c``
      ``constraint_jacobian``   ``q, p``                     ``G = dc/dq`` (m x n, sparse)
      ``constraint_velocity``   ``q, dq, p``                 ``G q'`` (the hidden constraint)
      ``constraint_curvature``  ``q, dq, p``                 ``(G q')_q q'``
      ``kkt_matrix``            ``q, p``                     ``[M G^T; G 0]`` (sparse)
      ``acceleration``          ``t, q, dq, u, p``           ``q''`` and ``z`` (sparse QR)
      ========================  ===========================  =============================

      So ``M q'' + velocity_terms + potential_gradient + G^T z = generalized_force``.
    - Flags: ``is_conservative`` (``Q`` is identically zero: no forces, no inputs, so
      ``T + V`` is conserved); ``has_constant_mass_matrix`` (``M`` does not depend on ``q``);
      ``is_separable`` (conservative, constant ``M`` and ``T = 1/2 q'^T M q'`` exactly, so the
      Hamiltonian is ``p^T M^-1 p / 2 + V(q)``: the case of the explicit RATTLE scheme).

    Bad input raises :class:`daekit.errors.ModelError` naming the culprit: sizes that do not
    match, a symbol that is neither coordinate, velocity, input, parameter nor time, a
    constraint that depends on velocities or inputs, ``T`` not quadratic in ``q'``, a mass
    matrix that is not positive definite (checked at random points; at a given point with
    :meth:`check_configuration`), redundant constraints.

    Example
    -------
    >>> import casadi as ca
    >>> p = ca.SX.sym("p", 3); v = ca.SX.sym("v", 3); u = ca.SX.sym("u", 3)
    >>> sys3 = LagrangianSystem({"p": p}, v, T=0.5 * ca.dot(v, v), V=9.81 * p[2],
    ...                         constraints={"rod": 0.5 * (ca.dot(p, p) - 1)}, forces=u,
    ...                         inputs=u, name="pendulum3d")
    >>> sys3.is_conservative, sys3.has_constant_mass_matrix
    (False, True)
    >>> import daekit.structure as st
    >>> inc = sys3.model().incidence()
    >>> st.sigma_method(inc.n_equations, inc.rows, inc.cols, inc.vals).index
    3
    """

    def __init__(
        self,
        coordinates,
        velocities,
        T,
        V=0,
        constraints=None,
        forces=None,
        inputs=None,
        parameters: Mapping[str, tuple] | None = None,
        t: ca.SX | None = None,
        multipliers: str = "z",
        name: str = "mechanism",
        equation_name: str = "motion",
        check: bool = True,
    ) -> None:
        self.name = name
        self.multiplier_name = multipliers
        self.equation_name = equation_name
        where = f"mechanical system {name!r}"
        # ---- coordinates and velocities
        qgroups = _groups(coordinates, "q", f"{where}: coordinates")
        if not qgroups:
            raise ModelError(f"{where}: give at least one generalized coordinate")
        for gname, sx in qgroups:
            _symbols(sx, f"{where}: coordinates {gname!r}")
        self.coordinate_groups = [(g, int(s.numel())) for g, s in qgroups]
        q = ca.vertcat(*[s for _, s in qgroups])
        n = int(q.numel())
        if isinstance(velocities, Mapping):
            missing = [g for g, _ in qgroups if g not in velocities]
            extra = [k for k in velocities if k not in dict(qgroups)]
            if missing or extra:
                raise ModelError(
                    f"{where}: velocities must have the keys of the coordinates "
                    f"{[g for g, _ in qgroups]}; missing {missing}, unexpected {extra}"
                )
            parts = []
            for g, size in self.coordinate_groups:
                vg = _to_sx(velocities[g], f"{where}: velocities {g!r}")
                if vg.numel() != size:
                    raise ModelError(
                        f"{where}: velocities {g!r} have {vg.numel()} elements, the coordinates "
                        f"{g!r} have {size}; give one velocity symbol per coordinate"
                    )
                parts.append(vg)
            dq = ca.vertcat(*parts)
        else:
            dq = _to_sx(velocities, f"{where}: velocities")
        if dq.numel() != n:
            raise ModelError(
                f"{where}: {count(dq.numel(), 'velocity')} for {count(n, 'coordinate')}; give one "
                "velocity symbol per coordinate"
            )
        _symbols(dq, f"{where}: velocities")
        qnames = _element_names(self.coordinate_groups)
        dqnames = _element_names(self.coordinate_groups, 1)
        self.n = n
        # ---- inputs, parameters, time
        ugroups = _groups(inputs, "u", f"{where}: inputs")
        for gname, sx in ugroups:
            _symbols(sx, f"{where}: inputs {gname!r}")
        self.input_groups = [(g, int(s.numel())) for g, s in ugroups]
        u = ca.vertcat(*[s for _, s in ugroups]) if ugroups else ca.SX(0, 1)
        self.parameter_groups: list[tuple[str, int, np.ndarray]] = []
        psyms = []
        for pname, spec in (parameters or {}).items():
            if not (isinstance(spec, tuple) and len(spec) == 2):
                raise ModelError(
                    f"{where}: parameter {pname!r} must be given as (symbol, value), got {spec!r}"
                )
            sym = _to_sx(spec[0], f"{where}: parameter {pname!r}")
            _symbols(sym, f"{where}: parameter {pname!r}")
            val = np.atleast_1d(np.asarray(spec[1], dtype=float)).ravel()
            if val.size != sym.numel():
                raise ModelError(
                    f"{where}: parameter {pname!r} has {count(sym.numel(), 'symbol')} but "
                    f"{count(val.size, 'value')}"
                )
            self.parameter_groups.append((pname, int(sym.numel()), val))
            psyms.append(sym)
        p = ca.vertcat(*psyms) if psyms else ca.SX(0, 1)
        if t is not None:
            t = _to_sx(t, f"{where}: t")
            if t.numel() != 1 or not t.is_symbolic():
                raise ModelError(f"{where}: t must be one scalar SX symbol")
        # ---- all symbols distinct
        seen: dict[int, str] = {}
        for label, vec, names in (
            ("coordinate", q, qnames),
            ("velocity", dq, dqnames),
            ("input", u, _element_names(self.input_groups)),
            ("parameter", p, _element_names([(g, s) for g, s, _ in self.parameter_groups])),
            ("time", t if t is not None else ca.SX(0, 1), ["t"]),
        ):
            for i in range(vec.numel()):
                h = vec[i].element_hash()
                if h in seen:
                    raise ModelError(
                        f"{where}: the symbol {vec[i].name()!r} is used both as {seen[h]} and as "
                        f"{label} {names[i]!r}; each needs its own symbol"
                    )
                seen[h] = f"{label} {names[i]!r}"
        # ---- energies, constraints, forces
        T = _to_sx(T, f"{where}: kinetic energy T")
        V = _to_sx(V, f"{where}: potential energy V")
        for label, e in (("kinetic energy T", T), ("potential energy V", V)):
            if e.numel() != 1:
                raise ModelError(f"{where}: the {label} must be a scalar, got {e.numel()} elements")
        cgroups = _groups(constraints, "c", f"{where}: constraints")
        self.constraint_groups = [(g, int(s.numel())) for g, s in cgroups]
        c = ca.vertcat(*[s for _, s in cgroups]) if cgroups else ca.SX(0, 1)
        self.m = int(c.numel())
        cnames = [g if s == 1 else f"{g}[{i}]" for g, s in self.constraint_groups for i in range(s)]
        if self.m > n:
            raise ModelError(
                f"{where}: {count(self.m, 'constraint')} for {count(n, 'coordinate')}; at most n independent "
                "holonomic constraints are possible, remove redundant ones"
            )
        Q = _to_sx(forces, f"{where}: forces") if forces is not None else ca.SX.zeros(n, 1)
        if Q.numel() != n:
            raise ModelError(
                f"{where}: the generalized forces have {Q.numel()} elements for {n} coordinates "
                f"({', '.join(qnames[:6])}{', ...' if n > 6 else ''}); give one per coordinate"
            )
        # ---- which symbols each expression may use
        h_q = {q[i].element_hash(): f"coordinate {qnames[i]!r}" for i in range(n)}
        h_dq = {dq[i].element_hash(): f"velocity {dqnames[i]!r}" for i in range(n)}
        h_u = {u[i].element_hash(): "input" for i in range(u.numel())}
        h_p = {p[i].element_hash(): "parameter" for i in range(p.numel())}
        h_t = {t.element_hash(): "time"} if t is not None else {}

        def allowed(expr: ca.SX, label: str, ok: dict[int, str], hint: str) -> None:
            for s in ca.symvar(expr):
                h = s.element_hash()
                if h in ok:
                    continue
                kind = seen.get(h)
                if kind is None:
                    raise ModelError(
                        f"{where}: the {label} uses the symbol {s.name()!r}, which is neither a "
                        "coordinate, velocity, input, parameter nor time; declare it (e.g. in "
                        "parameters={...})"
                    )
                raise ModelError(f"{where}: the {label} depends on the {kind}; {hint}")

        allowed(T, "kinetic energy T", {**h_q, **h_dq, **h_p}, "T = T(q, q') only")
        allowed(
            V, "potential energy V", {**h_q, **h_p}, "V = V(q) only; put other effects into forces"
        )
        for i in range(self.m):
            allowed(
                c[i],
                f"constraint {cnames[i]!r}",
                {**h_q, **h_p},
                "only holonomic constraints c(q) = 0 are supported; a constraint on velocities "
                "(nonholonomic) or on inputs/time must be written as a daekit.Model directly",
            )
        allowed(Q, "generalized force", {**h_q, **h_dq, **h_u, **h_p, **h_t}, "")
        self._qnames, self._dqnames, self._cnames = qnames, dqnames, cnames

        # ---- derived quantities (in the user's symbols)
        mom = ca.gradient(T, dq)
        M = ca.jacobian(mom, dq)
        if ca.depends_on(M, dq):
            bad = [i for i in range(n) if ca.depends_on(M[:, i], dq)]
            raise ModelError(
                f"{where}: the kinetic energy T is not quadratic in the velocities: "
                f"d^2T/dq'^2 depends on the velocities (column of {dqnames[bad[0]]!r}); "
                "write T = 1/2 q'^T M(q) q' (+ terms linear in q')"
            )
        self._u_sym = (q, dq, u, p, t)
        self._expr = {"T": T, "V": V, "c": c, "Q": Q, "mom": mom, "M": M}
        self.p_values = (
            np.concatenate([v for _, _, v in self.parameter_groups])
            if self.parameter_groups
            else np.zeros(0)
        )
        self._model: Model | None = None
        self._functions()
        if check:
            self._check_random()

    # ------------------------------------------------------------------ sizes and names
    @property
    def coordinate_names(self) -> list[str]:
        """Element names of ``q`` (``"p[0]"``, ...)."""
        return list(self._qnames)

    @property
    def velocity_names(self) -> list[str]:
        """Element names of ``q'`` (``"der(p)[0]"``, ...)."""
        return list(self._dqnames)

    @property
    def constraint_names(self) -> list[str]:
        """Element names of ``c`` (``"rod"``, ``"c[0]"``, ...)."""
        return list(self._cnames)

    @property
    def n_constraints(self) -> int:
        return self.m

    @property
    def n_inputs(self) -> int:
        return int(self._u_sym[2].numel())

    # ------------------------------------------------------------------ model
    def model(self) -> Model:
        """The index-3 :class:`daekit.Model` (built once, then cached).

        Second-order form: the coordinate groups are states whose second derivatives appear;
        equations ``equation_name`` (the Euler--Lagrange equations, n) and one equation per
        constraint group.
        """
        if self._model is None:
            self._build_model()
        return self._model

    def _build_model(self) -> None:
        q0, dq0, u0, p0, t0 = self._u_sym
        mdl = Model(self.name)
        qs = [mdl.state(g, s) for g, s in self.coordinate_groups]
        zsym = mdl.algebraic(self.multiplier_name, self.m) if self.m else ca.SX(0, 1)
        us = [mdl.control(g, s) for g, s in self.input_groups]
        ps = [mdl.parameter(g, v) for g, _, v in self.parameter_groups]
        q = ca.vertcat(*qs)
        dq = ca.vertcat(*[mdl.der(x) for x in qs])
        a = ca.vertcat(*[mdl.der(x, 2) for x in qs])
        u = ca.vertcat(*us) if us else ca.SX(0, 1)
        p = ca.vertcat(*ps) if ps else ca.SX(0, 1)
        old = [q0, dq0, u0, p0] + ([t0] if t0 is not None else [])
        new = [q, dq, u, p] + ([mdl.t] if t0 is not None else [])
        e = self._expr
        T, V, c, Q = ca.substitute([e["T"], e["V"], e["c"], e["Q"]], old, new)
        mom = ca.gradient(T, dq)
        vel_terms = ca.jtimes(mom, q, dq) - ca.gradient(T, q)  # M' q' - grad_q T
        gradV = ca.gradient(V, q)
        gtz = ca.jtimes(c, q, zsym, True) if self.m else ca.SX.zeros(self.n, 1)
        motion = ca.jtimes(mom, dq, a) + vel_terms + gradV + gtz - Q
        mdl.equation(motion, name=self.equation_name)
        k = 0
        for g, s in self.constraint_groups:
            mdl.equation(c[k : k + s], name=g)
            k += s
        cdot = ca.jtimes(c, q, dq) if self.m else ca.SX(0, 1)
        curv = ca.jtimes(cdot, q, dq) if self.m else ca.SX(0, 1)
        cddot = ca.jtimes(c, q, a) + curv if self.m else ca.SX(0, 1)
        mdl.mechanics = self  # the mass matrix for impacts (daekit.simulate.reset)
        self._model = mdl
        self._msym = {"q": q, "dq": dq, "a": a, "z": zsym, "u": u, "p": p, "t": mdl.t}
        self._mexpr = {"motion": motion, "c": c, "cdot": cdot, "cddot": cddot, "T": T, "V": V}

    # ------------------------------------------------------------------ index-1 form
    def index1(self) -> ReducedDAE:
        """The index-1 form ``[M G^T; G 0] [q''; z] = [...]`` as a :class:`ReducedDAE`.

        States ``x = (q, q')``, algebraic unknowns ``(q'', z)``, ``x' = (q', q'')``,
        ``0 = [Euler--Lagrange residual; c'']``, invariants ``[c; c']``. The symbols are the
        model's own (``r.model`` is :meth:`model`), so names map one to one.

        >>> from daekit.examples.mechanisms import lagrangian_pendulum3d
        >>> r = lagrangian_pendulum3d().index1()
        >>> r.nx, r.nz, r.invariant_names
        (6, 4, ['rod', 'd/dt rod'])
        """
        mdl = self.model()
        s, e = self._msym, self._mexpr
        x = ca.vertcat(s["q"], s["dq"])
        z = ca.vertcat(s["a"], s["z"])
        x_names = self._qnames + self._dqnames
        a_names = _element_names(self.coordinate_groups, 2)
        mult_names = [element_name(self.multiplier_name, self.m, j) for j in range(self.m)]
        z_names = a_names + mult_names
        variables = {nm: x[i] for i, nm in enumerate(x_names)}
        variables.update({nm: z[i] for i, nm in enumerate(z_names)})
        # invariant chains as reduce_index gives them (what baumgarte and ggl read): constraint
        # element j is the model's equation element n + j, its invariants c_j (row j) and
        # dc_j/dt (row m + j), its top equation c_j'' the algebraic row n + j
        n, m = self.n, self.m
        chains = [
            {"equation": nm, "row": n + j, "invariants": [j, m + j], "alg": n + j}
            for j, nm in enumerate(self._cnames)
        ]
        alg_names = [element_name(self.equation_name, n, i) for i in range(n)] + [
            f"d2/dt2 {nm}" for nm in self._cnames
        ]
        return ReducedDAE(
            t=s["t"],
            x=x,
            z=z,
            u=s["u"],
            p=s["p"],
            ode=ca.vertcat(s["dq"], s["a"]),
            alg=ca.vertcat(e["motion"], e["cddot"]),
            invariants=ca.vertcat(e["c"], e["cdot"]),
            invariant_names=self._cnames + [f"d/dt {nm}" for nm in self._cnames],
            x_names=x_names,
            z_names=z_names,
            u_names=_element_names(self.input_groups),
            p_names=_element_names([(g, k) for g, k, _ in self.parameter_groups]),
            p_values=self.p_values.copy(),
            variables=variables,
            input_derivatives=[],
            control_names=[g for g, _ in self.input_groups],
            state_selection=None,
            method="lagrangian",
            model=mdl,
            lagrangian=self, chains=chains, alg_names=alg_names,
        )

    # ------------------------------------------------------------------ functions
    def _functions(self) -> None:
        q, dq, u, p, t = self._u_sym
        tt = t if t is not None else ca.SX.sym("t")
        e = self._expr
        T, V, c, Q, mom, M = e["T"], e["V"], e["c"], e["Q"], e["mom"], e["M"]
        gradV = ca.gradient(V, q)
        vel = ca.jtimes(mom, q, dq) - ca.gradient(T, q)
        G = ca.jacobian(c, q) if self.m else ca.SX(0, self.n)
        cdot = ca.jtimes(c, q, dq) if self.m else ca.SX(0, 1)
        curv = ca.jtimes(cdot, q, dq) if self.m else ca.SX(0, 1)
        qp = ["q", "p"]
        qdp = ["q", "dq", "p"]
        F = ca.Function
        self.mass_matrix = F("mass_matrix", [q, p], [M], qp, ["M"])
        self.momentum = F("momentum", [q, dq, p], [mom], qdp, ["momentum"])
        self.kinetic_energy = F("kinetic_energy", [q, dq, p], [T], qdp, ["T"])
        self.potential_energy = F("potential_energy", [q, p], [V], qp, ["V"])
        self.energy = F("energy", [q, dq, p], [T + V], qdp, ["E"])
        self.potential_gradient = F("potential_gradient", [q, p], [gradV], qp, ["gradV"])
        self.velocity_terms = F("velocity_terms", [q, dq, p], [vel], qdp, ["h"])
        self.generalized_force = F(
            "generalized_force", [tt, q, dq, u, p], [Q], ["t", "q", "dq", "u", "p"], ["Q"]
        )
        self.constraint = F("constraint", [q, p], [c], qp, ["c"])
        self.constraint_jacobian = F("constraint_jacobian", [q, p], [G], qp, ["G"])
        self.constraint_velocity = F("constraint_velocity", [q, dq, p], [cdot], qdp, ["cdot"])
        self.constraint_curvature = F("constraint_curvature", [q, dq, p], [curv], qdp, ["curv"])
        # KKT solve for the accelerations and multipliers: a sparse QR inside a CasADi Function
        K = ca.blockcat([[M, G.T], [G, ca.SX(self.m, self.m)]])
        rhs = ca.vertcat(Q - vel - gradV, -curv)
        kf = F("kkt", [q, p], [K])
        rf = F("kkt_rhs", [tt, q, dq, u, p], [rhs])
        mt, mq, mdq = ca.MX.sym("t"), ca.MX.sym("q", self.n), ca.MX.sym("dq", self.n)
        mu, mp = ca.MX.sym("u", u.numel()), ca.MX.sym("p", p.numel())
        sol = ca.solve(kf(mq, mp), rf(mt, mq, mdq, mu, mp), "qr")
        self.acceleration = F(
            "acceleration", [mt, mq, mdq, mu, mp], [sol[: self.n], sol[self.n :]],
            ["t", "q", "dq", "u", "p"], ["ddq", "z"],
        )
        self.kkt_matrix = F("kkt_matrix", [q, p], [K], qp, ["K"])
        # flags
        self.is_conservative = bool(Q.nnz() == 0 or Q.is_zero())
        self.has_constant_mass_matrix = not ca.depends_on(M, q)
        if self.is_conservative and self.has_constant_mass_matrix:
            zero = ca.DM.zeros(self.n, 1)
            rest = F("rest", [q, dq, p], [ca.substitute(ca.vertcat(T, mom), dq, zero)])
            rng = np.random.default_rng(1)
            pure = True
            for _ in range(3):
                val = np.asarray(rest(rng.standard_normal(self.n), 0, self.p_values)).ravel()
                if np.max(np.abs(val)) > 1e-12:
                    pure = False
            self.is_separable = pure
        else:
            self.is_separable = False

    # ------------------------------------------------------------------ checks
    def _check_random(self) -> None:
        rng = np.random.default_rng(20240611)
        for _ in range(2):
            q = rng.uniform(-1.0, 1.0, self.n)
            self._check_at(q, self.p_values, where="at a random point")

    def _check_at(self, q, pvals, where: str) -> float:
        label = f"mechanical system {self.name!r}"
        M = _to_scipy(ca.DM(self.mass_matrix(q, pvals)))
        d = M.diagonal()
        qn = self._qnames
        if not np.all(np.isfinite(M.data)):
            raise ModelError(
                f"{label}: the mass matrix is not finite {where} (q = {np.round(q, 4).tolist()}); "
                "if the coordinates have a restricted range, pass check=False and check a valid "
                "configuration with check_configuration(q)"
            )
        for i in range(self.n):
            if not d[i] > 0:
                raise ModelError(
                    f"{label}: the mass matrix M = d^2T/dq'^2 is not positive definite {where} "
                    f"(q = {np.round(q, 4).tolist()}): its diagonal entry for {qn[i]!r} is "
                    f"{d[i]:g}; T must depend on the velocity {self._dqnames[i]!r} with a "
                    "positive coefficient (every coordinate needs inertia)"
                )
        try:
            lu = sp.linalg.splu(M.tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                           options={"SymmetricMode": True})
            piv = lu.U.diagonal()
        except RuntimeError:
            piv = np.zeros(self.n)
        bad = np.nonzero(~(piv > 1e-14 * max(1.0, float(np.max(np.abs(d))))))[0]
        if bad.size:
            raise ModelError(
                f"{label}: the mass matrix M = d^2T/dq'^2 is not positive definite {where} "
                f"(q = {np.round(q, 4).tolist()}); the trouble starts at coordinate "
                f"{qn[int(bad[0])]!r}; check the kinetic energy T"
            )
        if not self.m:
            return 1.0
        G = np.asarray(ca.DM(self.constraint_jacobian(q, pvals)).full()) if self.m <= 400 else None
        if G is not None:
            sv = np.linalg.svd(G, compute_uv=False)
            if sv[-1] <= 1e-10 * max(1.0, sv[0]):
                # which constraint is redundant: the first row dependent on the previous ones
                for k in range(1, self.m + 1):
                    if np.linalg.matrix_rank(G[:k], tol=1e-10 * max(1.0, sv[0])) < k:
                        break
                raise ModelError(
                    f"{label}: the constraint Jacobian G = dc/dq loses rank {where} "
                    f"(q = {np.round(q, 4).tolist()}): constraint {self._cnames[k - 1]!r} is "
                    "redundant with the ones before it (or the mechanism is singular there); "
                    "remove redundant constraints"
                )
        K = _to_scipy(ca.DM(self.kkt_matrix(q, pvals)))
        try:
            lu = sp.linalg.splu(K.tocsc())
        except RuntimeError:
            raise ModelError(
                f"{label}: the index-1 matrix [M G^T; G 0] is singular {where} "
                f"(q = {np.round(q, 4).tolist()}); the constraints are redundant or the "
                "mechanism is at a singular configuration"
            ) from None
        piv = np.abs(lu.U.diagonal())
        return float(piv.max() / piv.min())

    def check_configuration(self, q, params=None) -> float:
        """Check that the index-1 form is solvable at the configuration ``q``.

        Raises :class:`ModelError` when the mass matrix is not positive definite there (naming
        the coordinate where it fails) or the constraint Jacobian loses rank (naming the
        redundant constraint). Returns a rough conditioning figure of ``[M G^T; G 0]`` (ratio of
        the largest and smallest LU pivots).

        >>> from daekit.examples.mechanisms import lagrangian_pendulum3d
        >>> lagrangian_pendulum3d().check_configuration([1.0, 0.0, 0.0]) < 10
        True
        """
        q = np.asarray(q, dtype=float).ravel()
        if q.size != self.n:
            raise ModelError(
                f"mechanical system {self.name!r}: check_configuration needs {self.n} coordinate "
                f"values ({', '.join(self._qnames)}), got {q.size}"
            )
        pv = self.p_values if params is None else np.asarray(params, dtype=float).ravel()
        if pv.size != self.p_values.size:
            raise ModelError(
                f"mechanical system {self.name!r}: {count(self.p_values.size, 'parameter value')} "
                f"needed, got {pv.size}"
            )
        return self._check_at(q, pv, where="at the given configuration")

    def __repr__(self) -> str:
        return (
            f"LagrangianSystem({self.name!r}: {count(self.n, 'coordinate')}, "
            f"{count(self.m, 'constraint')}, {count(self.n_inputs, 'input')})"
        )


def lagrangian(coordinates, velocities, T, V=0, **kwargs) -> LagrangianSystem:
    """Shorthand for :class:`LagrangianSystem` (same arguments).

    >>> import casadi as ca
    >>> x = ca.SX.sym("x"); dx = ca.SX.sym("dx")
    >>> osc = lagrangian({"x": x}, dx, T=0.5 * dx**2, V=0.5 * x**2)
    >>> osc.is_separable, osc.index1().alg
    (True, SX((der(x,2)+x)))
    """
    return LagrangianSystem(coordinates, velocities, T, V, **kwargs)
