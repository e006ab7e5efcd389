"""``simulate()``: validate the arguments once and dispatch to a simulation path.

Paths: plain IDAS and Baumgarte (:mod:`daekit.simulate.idas`), projection by drift tolerance
(:class:`daekit.simulate.projection.DriftMonitor`) and dummy derivatives
(:mod:`daekit.simulate.dummy`), all on the event-driven driver
(:mod:`daekit.simulate.driver`); RATTLE (:mod:`daekit.simulate.rattle`); systems without
states (Newton at each output time).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence

import casadi as ca
import numpy as np

from ..inputs import InputError, resolve_params
from ..reduced import ReducedDAE
from ..reduction.accept import as_reduced
from ..wording import count
from .driver import Driver
from .idas import run_algebraic, run_idas
from .projection import DriftMonitor, Projector, default_drift_tol
from .system import EVENT_KEYWORDS, check_idas_options, check_sized_options, signal_for, system_for
from .trajectory import Trajectory

__all__ = ["simulate", "STABILIZATIONS", "check_stabilization"]

STABILIZATIONS = (None, "baumgarte", "projection", "dummy_derivatives")


class NothingToStabilizeWarning(UserWarning):
    """A drift remedy was asked for on a system without invariants: it runs plain."""


def check_grid(t) -> np.ndarray:
    """The output grid as a float array; an InputError unless finite, increasing, >= 2 points.

    >>> check_grid([0, 1, 2]).tolist()
    [0.0, 1.0, 2.0]
    """
    try:
        tg = np.asarray(t, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError("simulate: t must be an array of output times") from None
    if tg.size < 2:
        raise InputError(
            "simulate: t must hold at least two output times, e.g. np.linspace(0, 10, 1001)"
        )
    # strictly increasing (a NaN fails the comparison) with finite ends: all finite
    if not (np.isfinite(tg[0]) and np.isfinite(tg[-1]) and (tg[1:] > tg[:-1]).all()):
        raise InputError("simulate: the output times t must be finite and strictly increasing")
    return tg


def initial_state(r, init, t0, inputs, params, sig, pv, system,
                  off_manifold_ok: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Consistent ``(x0, z0)`` from ``init`` (InitialValues, a dict of guesses, or an array).

    An array that violates the consistency conditions is refused (an index-1 system started
    there drifts from the start, silently) unless ``off_manifold_ok`` (Baumgarte: its poles
    pull such a start back to the manifold, which is what one may want to watch)."""
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
        other_p = ip.size == np.size(pv) and not (ip == pv).all() and not np.allclose(
            ip, pv, rtol=1e-12, atol=0.0)
        u0 = sig.value(t0)
        xn = init.x_names
        if xn is r.x_names or list(xn) == list(r.x_names):
            x0 = np.asarray(init.x0, dtype=float)
        else:
            try:
                x0 = np.array([init.values[n] for n in r.x_names], dtype=float)
            except KeyError as exc:
                raise InputError(
                    f"simulate: the initial values do not contain the state {exc.args[0]!r} of "
                    "this system; call dk.initialize on this system"
                ) from None
        zn = init.z_names
        if zn is r.z_names or list(zn) == list(r.z_names):
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
        if not off_manifold_ok:
            _check_array_start(r, t0, x0, z0, sig.value(t0), pv)
        return x0, z0
    if arr.size == r.nx + r.nz:
        if not off_manifold_ok:
            _check_array_start(r, t0, arr[: r.nx], arr[r.nx:], sig.value(t0), pv)
        return arr[: r.nx], arr[r.nx:]
    raise InputError(
        f"simulate: init must be InitialValues (dk.initialize), a dict of guesses, or an array "
        f"of the {count(r.nx, 'state')}; got {count(arr.size, 'number')}"
    )


def _stabilization(stabilization):
    """The stabilization asked for, checked (``"none"`` is None)."""
    if isinstance(stabilization, str) and stabilization.lower() == "none":
        return None
    if stabilization not in STABILIZATIONS:
        raise InputError(
            f"simulate: unknown stabilization {stabilization!r}; use None, 'baumgarte', "
            "'projection' or 'dummy_derivatives'"
        )
    return stabilization


def check_stabilization(r, stabilization):
    """The stabilization a run of ``r`` takes: ``stabilization`` checked (``"none"`` is
    None), dummy derivatives where ``r`` was reduced by them and none was asked for (without
    the re-selection monitor a run would cross a singular pivot onto a wrong solution), and
    a dummy-derivative run refused on a system reduced otherwise. Raises InputError.

    >>> import daekit as dk
    >>> r = dk.reduce_index(dk.examples.pendulum_planar(), method="dummy_derivatives")
    >>> check_stabilization(r, "none")
    'dummy_derivatives'
    """
    stabilization = _stabilization(stabilization)
    method = getattr(r, "method", "")
    if stabilization is None and method == "dummy_derivatives":
        stabilization = "dummy_derivatives"
    if stabilization == "dummy_derivatives" and method != "dummy_derivatives":
        raise InputError(
            "simulate: stabilization='dummy_derivatives' needs a system from "
            "dk.reduce_index(model, method='dummy_derivatives'); this one was made by "
            f"{method or '?'!r}"
        )
    return stabilization


def _check_array_start(r, t0, x0, z0, u0, pv, rtol: float = 1e-6) -> None:
    """An initial state given as an array must satisfy the consistency conditions: an index-1
    system started off them integrates a different (drifting) solution without a word."""
    if not r.invariants.numel():
        return
    inv = np.asarray(ca.Function("inv0", [r.t, r.x, r.z, r.u, r.p], [r.invariants])(
        t0, x0, z0, u0, pv), dtype=float).ravel()
    scale = 1.0 + np.max(np.abs(x0), initial=0.0)
    bad = np.nonzero(~(np.abs(inv) <= rtol * scale))[0]
    if bad.size:
        shown = ", ".join(f"{r.invariant_names[i]} = {inv[i]:.3g}" for i in bad[:5])
        raise InputError(
            f"simulate: the initial state given as an array violates the consistency "
            f"conditions ({shown}); an index-1 system started there drifts from the start. "
            "Make it consistent with dk.initialize(r, guess=..., fixed=...) and pass the result"
        )


def _project_recorded(proj: Projector, part, res, pv, tol: float, every: bool) -> int:
    """Project the recorded rows of one driver part (all with ``every``, else those whose
    largest ``|invariant|`` exceeds ``tol``); returns how many rows were projected."""
    sy = part[0]
    T, X, Z = res.arrays(part)
    if not T.size:
        return 0
    U = sy.sig.values(T)
    if every:
        res.set_rows(part, *proj.project_rows(T, X, Z, U, pv))
        return int(T.size)
    drift = np.max(np.abs(sy.evaluator.invariants(T, X, Z, U, pv)), axis=1, initial=0.0)
    rows = np.nonzero(drift > tol)[0]
    if rows.size:
        X, Z = X.copy(), Z.copy()
        X[rows], Z[rows] = proj.project_rows(T[rows], X[rows], Z[rows], U[rows], pv)
        res.set_rows(part, X, Z)
    return int(rows.size)


def simulate(
    r,
    t,
    init,
    inputs: Mapping | None = None,
    params: Mapping | None = None,
    stabilization: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    method: str = "idas",
    progress: bool = False,
    poles=(-1.0, -1.0),
    drift_tol: float | None = None,
    monitors: Sequence = (),
    project_output: bool | None = None,
    events: bool = True,
    **options,
) -> Trajectory:
    """Simulate a reduced (index-1) DAE and return its :class:`Trajectory`.

    Parameters
    ----------
    r : ReducedDAE
        From :func:`daekit.reduce_index` (or by hand). A Model or a LagrangianSystem is reduced
        automatically (:func:`daekit.reduction.as_reduced`; ``traj.stats["reduced"]`` says how).
    t : array
        Output times, strictly increasing; ``t[0]`` is the initial time. They are where results
        are read: IDAS interpolates them, and they never restart the integration nor limit its
        steps (the result does not depend on how many there are).
    init : InitialValues, dict or array
        Consistent initial values from :func:`daekit.initialize` (a dict is taken as guesses for
        it; an array as the state vector ``x0``, ``z0`` then solved from ``alg = 0``). An array
        must satisfy the consistency conditions (to 1e-6 relative), except with
        ``stabilization="baumgarte"``, whose poles pull an inconsistent start back.
    inputs : dict, optional
        ``{control name: f}`` with ``f`` a Python callable of ``t`` or a CasADi SX expression of
        time (``r.t`` or the model's ``m.t``). Input derivatives the reduction needs are
        differentiated automatically from expressions; for callables give them explicitly
        (``{"u": f, "der(u)": df}``). Controls not given are zero.
    params : dict, optional
        Parameter values overriding the defaults (``{"L": 2.0}``).
    stabilization : None, "baumgarte", "projection" or "dummy_derivatives"
        Drift control. ``"baumgarte"`` integrates ``daekit.baumgarte(r, poles)``;
        ``"projection"`` integrates in one IDAS run until ``max |invariant|`` exceeds
        ``drift_tol`` and then projects (sparse Gauss--Newton, in IDAS's error-weight metric)
        onto ``{alg = 0, invariants = 0}`` and restarts (``stats["projections"]``); returned
        rows beyond ``drift_tol`` are projected too (``project_output``);
        ``"dummy_derivatives"`` needs ``r`` from ``reduce_index(model,
        method="dummy_derivatives")`` and re-selects the states when the selection's pivot
        degrades (``stats["selection_switches"]``); such an ``r`` is always simulated this
        way (None means it too: a fixed selection is valid only while its pivot is regular).
    rtol, atol : float
        IDAS tolerances (default 1e-8 each). RATTLE takes fixed steps ``dt`` and no
        tolerances: given with ``method="rattle"`` they warn and are not used.
    method : "idas" or "rattle"
        ``"rattle"`` dispatches to :func:`daekit.simulate.rattle.simulate_rattle`.
    progress : bool
        A progress bar on stderr, drawn only when stderr is a terminal.
    poles : pair of float
        Baumgarte poles.
    drift_tol : float, optional
        For ``"projection"``: the largest ``|invariant|`` tolerated on the returned values;
        default :func:`daekit.simulate.projection.default_drift_tol` ``= 100 atol``. The
        integration is projected (and restarted) when its drift exceeds
        ``max(drift_tol, 100 atol)`` (``stats["restart_drift_tol"]``), and the returned rows
        whose drift still exceeds ``drift_tol`` are projected (read-only,
        ``stats["rows_projected"]``): IDAS re-creates drift of order ``atol`` within a few
        steps of each restart, so a tolerance below ``100 atol`` is met on the rows rather
        than by restarting every few steps (with ``project_output=False`` the integration
        itself is held to ``drift_tol``, at the price of many restarts).
    project_output : bool, optional
        For ``"projection"``: ``True`` projects every returned row onto the manifold, so the
        values satisfy the invariants to rounding (about 1 microsecond per row on the 3D
        pendulum: as much as the integration itself at 2001 points); the default (None)
        projects only the rows whose drift exceeds ``drift_tol``; ``False`` none (the
        integration restarts at ``drift_tol`` itself). ``stats["max_drift_integrated"]`` is
        the largest drift the integration itself had at its check points.
    monitors : sequence of daekit.simulate.driver.Monitor
        Further monitors on the driver (user events; see :mod:`daekit.simulate.driver`).
    events : bool
        Honour the model's events (:meth:`daekit.Model.event`) and stop at the switches of its
        equations (``if_else``, ``fabs``, ...); see :mod:`daekit.simulate.events`, whose
        keywords ``event_spacing``, ``zeno_count``, ``zeno_window`` and ``max_events`` may be
        given here. ``False`` integrates the equations as they are.
    **options
        Passed to the CasADi IDAS integrator (e.g. ``max_num_steps``). For an index-2 system
        (``dk.ggl(r)``) and for ``stabilization="dummy_derivatives"``
        ``suppress_algebraic=True`` is the default (IDAS's error test on the selected states
        only: the dummies follow from them through the kept constraints; measured at least as
        accurate as plain IDAS at the same tolerance and 1.2-6x faster than with the dummies in
        the test, which is more accurate still on some problems: see
        :func:`daekit.simulate.dummy.simulate_dummy`); pass ``suppress_algebraic=False`` to
        include them.

    Raises
    ------
    SimulationError
        When IDAS fails: ``.t`` is the time, ``.trajectory`` the solution so far.
    daekit.inputs.InputError
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
    if method == "rattle" and (rtol is not None or atol is not None):
        warnings.warn(
            "simulate(method='rattle'): rtol and atol do not apply; RATTLE takes fixed steps "
            "dt (give dt=...; its error is O(dt^2))", UserWarning, stacklevel=2)
    rtol = 1e-8 if rtol is None else rtol
    atol = 1e-8 if atol is None else atol
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
        if events and getattr(getattr(r, "model", None), "events", None):
            from .events import simulate_rattle_events

            traj = simulate_rattle_events(r, t, init, inputs=inputs, params=params,
                                          progress=progress, **options)
            if notes:
                traj.stats["reduced"] = notes[0]
            return traj
        traj = simulate_rattle(
            r, t, init, inputs=inputs, params=params, progress=progress,
            **options,
        )
        if notes:
            traj.stats["reduced"] = notes[0]
        return traj
    if method != "idas":
        raise InputError(f"simulate: unknown method {method!r}; use 'idas' or 'rattle'")
    check_idas_options(options)  # a misspelt keyword is named before anything runs
    event_keys = EVENT_KEYWORDS
    if events and not monitors:
        from .events import has_events, simulate_events

        if has_events(r):
            stabilization = _stabilization(stabilization)
            check_grid(t)
            traj = simulate_events(r, t, init, inputs=inputs, params=params,
                                   stabilization=stabilization, rtol=rtol, atol=atol,
                                   poles=poles, progress=progress, drift_tol=drift_tol,
                                   project_output=project_output, run=simulate, **options)
            if notes:
                traj.stats["reduced"] = notes[0]
            return traj
    options = {k: v for k, v in options.items() if k not in event_keys}
    stabilization = check_stabilization(r, stabilization)
    for name, tol in (("rtol", rtol), ("atol", atol)):
        if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
            raise InputError(f"simulate: {name} must be a positive number, got {tol!r}")
    if drift_tol is not None and not (isinstance(drift_tol, (int, float))
                                      and math.isfinite(drift_tol) and drift_tol > 0):
        raise InputError(f"simulate: drift_tol must be a positive number, got {drift_tol!r}")
    tg = check_grid(t)
    if stabilization in ("baumgarte", "projection") and not r.invariants.numel():
        warnings.warn(
            f"simulate: stabilization={stabilization!r} has nothing to act on (this system has "
            "no invariants); simulating without it", NothingToStabilizeWarning, stacklevel=2)
        stabilization = None

    r_int = r
    if stabilization == "baumgarte":
        from ..reduction import baumgarte

        # made once per system and poles, kept on it (so is its integrator)
        cache = r.derived("simulate.baumgarte", lambda r: {})
        key = repr(poles)
        if key not in cache:
            cache[key] = baumgarte(r, poles=poles)
        r_int = cache[key]
    if r_int.index >= 2 and "suppress_algebraic" not in options:
        # an index-2 form (GGL): its algebraic unknowns are not controlled by the BDF error
        # test (the index-2 variables' errors do not converge at the order of the method),
        # else IDAS takes tiny steps (Brenan, Campbell, Petzold 1996, sec. 5.4)
        options = {**options, "suppress_algebraic": True}
    if options:
        check_sized_options(r_int, options, reselects=stabilization == "dummy_derivatives")
    pv = resolve_params(r_int, params)
    sig = signal_for(r_int, inputs)
    U = sig.values(tg)  # NaN check on the grid (names the input)
    system = system_for(r_int, sig, rtol, atol, options)
    x0, z0 = initial_state(r_int, init, float(tg[0]), inputs, params, sig, pv, system,
                           off_manifold_ok=stabilization == "baumgarte")
    if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(z0))):
        raise InputError("simulate: the initial values contain NaN or infinity")

    extra: dict = {}
    if r_int.nx == 0:
        # nothing to integrate (e.g. Gear-Petzold, or L2 by dummy derivatives): the solution
        # is alg(t, z, u(t)) = 0 at each output time, solved by Newton from the previous point
        traj = run_algebraic(system, tg, z0, U, pv)
    elif stabilization == "dummy_derivatives":
        from .dummy import simulate_dummy

        traj = simulate_dummy(r_int, tg, x0, z0, inputs, pv, rtol, atol, options, progress)
    elif stabilization == "projection":
        proj = r_int.derived("simulate.projector", Projector)  # built once per system
        proj.stats = {"projections": 0, "projection_iterations": 0}
        proj.set_tolerances(rtol, atol)
        tol = default_drift_tol(rtol, atol) if drift_tol is None else float(drift_tol)
        # below the default (100 atol) IDAS's own local errors re-create the drift within a
        # few steps of every restart: restarting that often sends BDF back to order 1 each
        # time (195 s for 100 s of a rigid body at drift_tol = 1e-10, and less accurate). The
        # integration is then restarted at the default level, and drift_tol is met on the
        # returned rows by projecting the rows that exceed it (read-only)
        restart_tol = tol if project_output is False else max(tol, default_drift_tol(rtol, atol))
        inv0 = system.evaluator.invariants(tg[:1], x0[None, :], z0[None, :], U[:1], pv)
        if np.max(np.abs(inv0), initial=0.0) > tol:
            x0, z0, _ = proj(tg[0], x0, z0, U[0], pv)
        mon = DriftMonitor(proj, restart_tol)
        res = Driver(system, tg, x0, z0, pv, [mon, *monitors], progress=progress,
                     label="projection").run()
        nproj = proj.stats["projections"]
        rows_projected = 0
        if project_output is not False:
            # the recorded rows onto the manifold (read-only: the integration is not
            # touched): every row with project_output=True, else those whose drift exceeds
            # drift_tol (the monitor looks at its check points only, and restarts at
            # max(drift_tol, 100 atol)), so every returned row is within drift_tol
            for part in res.parts:
                rows_projected += _project_recorded(proj, part, res, pv, tol,
                                                    every=project_output is True)
        traj = res.trajectory()
        traj = res.trajectory()
        extra = {"projections": nproj, "drift_tol": tol, "restart_drift_tol": restart_tol,
                 "output_projected": rows_projected > 0, "rows_projected": rows_projected,
                 "max_projection_correction": mon.max_correction,
                 "max_drift_integrated": mon.max_drift}
    else:
        traj = run_idas(system, tg, x0, z0, pv, list(monitors), progress, "simulate")
    traj.stats.update(extra)
    traj.stats.setdefault("projections", 0)
    traj.stats["wall_time"] = time.perf_counter() - wall0
    traj.stats["stabilization"] = stabilization
    if notes:
        traj.stats["reduced"] = notes[0]
    return traj
