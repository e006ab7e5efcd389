"""``daekit tour``: the lecture's story on real models, with figures.

For the 3D pendulum and the delta robot (both index 3): analyze and explain, reduce to index 1
with the consistency conditions, find consistent initial values, then simulate 100 s with each
remedy against drift -- none, Baumgarte (poles -1, -1), projection, GGL, dummy derivatives,
RATTLE --
and print one table (max |c|, max |c'|, energy error, wall time, steps). Finally one optimal
control problem on an index-3 model (an overhead crane moved in minimum time). Figures go into
a folder that the tour names at the end.

Run it as ``daekit tour`` (or ``python -m daekit tour``); ``--quiet`` turns the progress off,
``--t-end`` shortens the runs, ``--out`` chooses the folder, ``--gifs`` adds the animations
(real time, 480 pixels: the swinging pendulum, the delta robot, and the drift of an
unstabilized pendulum next to a projected one at a loose tolerance).
"""

from __future__ import annotations

import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["run_tour", "RemedyResult"]

#: the drift tolerance of the tour's projection runs: the invariants held to 1e-10 on every
#: returned point (the integration restarts at the default, 100 atol; the points beyond
#: 1e-10 are projected), to show what the remedy can do; simulate's default is 100 atol
TOUR_DRIFT_TOL = 1e-10


@dataclass
class RemedyResult:
    """One row of the tour's table."""

    system: str
    remedy: str
    max_c: float
    max_dc: float
    energy_error: float
    wall_time: float
    steps: int
    trajectory: object = None
    energy: object = None  # energy along the trajectory (array)


def _save(fig, path: Path, dpi: int = 100) -> None:
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def _say(text: str = "") -> None:
    print(text, flush=True)


def _bar(enabled: bool, label: str):
    """A tiny progress indicator on stderr: one dot per finished run."""
    if enabled:
        sys.stderr.write(f"  {label} ...")
        sys.stderr.flush()

    def done(seconds: float) -> None:
        if enabled:
            sys.stderr.write(f" {seconds:.2f} s\n")
            sys.stderr.flush()

    return done


def _level_columns(traj, order: int) -> list[int]:
    """Invariants of one level: position (order 0, c) or velocity (order 1, c')."""
    from daekit.plot import invariant_order

    return [j for j, name in enumerate(traj.invariant_names) if invariant_order(name)[0] == order]


def _max_inv(traj, order: int) -> float:
    """Largest |invariant| among the position-level (order 0) or velocity-level (1) ones."""
    cols = _level_columns(traj, order)
    return float(np.max(np.abs(traj.invariants[:, cols]))) if cols else float("nan")


def _energy_pendulum(traj, m=1.0, g=9.81) -> np.ndarray:
    v = traj["der(p)"] if "der(p)" in traj else traj["v"]
    return 0.5 * m * np.sum(v**2, axis=1) + m * g * traj["p"][:, 2]


def _energy_delta(traj, system, u_hold) -> np.ndarray:
    """T + V minus the work potential of the constant holding torques."""
    q = np.hstack([traj["alpha"], traj["p"]])
    dq = np.hstack([traj["der(alpha)"], traj["der(p)"]])
    e = np.asarray(system.energy(q.T, dq.T, system.p_values)).ravel()
    return e - q[:, :3] @ np.asarray(u_hold)


def _rename(values: dict, names: dict) -> dict:
    """Rename the variables in a dict of values: ``{"v[1]": 2}`` with ``{"v": "der(p)"}`` gives
    ``{"der(p)[1]": 2}`` (the Lagrangian form names velocities as derivatives)."""
    out = {}
    for key, val in values.items():
        base, bracket, rest = key.partition("[")
        out[names.get(base, base) + bracket + rest] = val
    return out


def _remedies(system_name, model, lag, fixed, guess, t, energy, inputs, progress, dd_point,
              lag_names, dt=0.005):
    """Run each remedy on one system for the grid ``t``; return (reduced, init, table rows)."""
    import daekit as dk

    tol = {"rtol": 1e-6, "atol": 1e-6}
    r = dk.reduce_index(model)
    init = dk.initialize(r, fixed=fixed, guess=guess, inputs=inputs)
    rd = dk.reduce_index(model, method="dummy_derivatives", point=dd_point)
    rg = dk.ggl(r)
    rl = lag.index1()

    def start(red, names=None):
        return dk.initialize(red, fixed=_rename(fixed, names or {}),
                             guess=_rename(guess, names or {}), inputs=inputs)

    runs = [
        ("none", lambda: dk.simulate(r, t, init, inputs=inputs, **tol)),
        ("Baumgarte (-1, -1)", lambda: dk.simulate(r, t, init, inputs=inputs,
                                                   stabilization="baumgarte", **tol)),
        ("projection", lambda: dk.simulate(r, t, init, inputs=inputs,
                                           stabilization="projection",
                                           drift_tol=TOUR_DRIFT_TOL, **tol)),
        ("GGL (index 2)", lambda: dk.simulate(rg, t, start(rg), inputs=inputs, **tol)),
        ("dummy derivatives", lambda: dk.simulate(rd, t, start(rd), inputs=inputs,
                                                  stabilization="dummy_derivatives", **tol)),
        (f"RATTLE (h = {dt})", lambda: dk.simulate(rl, t, start(rl, lag_names), inputs=inputs,
                                                   method="rattle", dt=dt)),
    ]
    rows = []
    e0 = None
    for label, run in runs:
        done = _bar(progress, f"{system_name}: {label}")
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tr = run()
        wall = time.perf_counter() - t0
        done(wall)
        en = energy(tr)
        e0 = en[0] if e0 is None else e0
        rows.append(RemedyResult(system_name, label, _max_inv(tr, 0), _max_inv(tr, 1),
                                 float(np.max(np.abs(en - e0))), wall,
                                 int(tr.stats.get("steps", 0)), tr, en))
    return r, init, rows


def _analysis_section(title: str, model, figure: Path) -> None:
    """A section's heading, the model's analysis explained, and its structure figure."""
    import daekit as dk

    _say("=" * 78)
    _say(title)
    _say("=" * 78)
    a = dk.analyze(model)
    _say(a.explain())
    _save(a.plot_structure(), figure)


def _remedy_costs(rows: list[RemedyResult]) -> str:
    """What each remedy cost in this run, relative to no remedy on the same system (measured,
    wall times of one run on this machine)."""
    how = {
        "Baumgarte": "one IDAS run on modified equations (stiffer for fast poles)",
        "projection": f"drift_tol = {TOUR_DRIFT_TOL:g} here: one IDAS run, restarted "
                      "only where max |c| passed 100 atol (sparse Gauss-Newton there), the "
                      "recorded points beyond drift_tol projected afterwards (the default "
                      "drift_tol, 100 atol, leaves out that last step: about a microsecond a "
                      "point)",
        "GGL": "one IDAS run of an index-2 system (more unknowns, algebraic errors not "
               "controlled)",
        "dummy derivatives": "IDAS restarted at each re-selection of the states (when the "
                             "pivot degrades), one integrator per "
                             "selection, the explicitly given derivatives substituted, "
                             "IDAS's error test on the selected states only",
        "RATTLE": "a fixed-step symplectic method: cost set by h, not by a tolerance",
    }
    lines = ["What each remedy cost here (relative to no remedy on the same system):"]
    base = {r.system: r for r in rows if r.remedy == "none"}
    for r in rows:
        b = base.get(r.system)
        if b is None or r is b:
            continue
        key = r.remedy.split(" (")[0]
        st = r.trajectory.stats
        ev = ""
        if st.get("projections"):
            ev = f", {st['projections']} projections"
        elif st.get("selection_switches"):
            ev = f", {len(st['selection_switches'])} re-selections"
        ratio = r.wall_time / b.wall_time if b.wall_time > 0 else float("nan")
        steps = f"{r.steps / b.steps:.2g}x the steps, " if b.steps and r.steps else ""
        what = how.get(key) or how.get(key.capitalize()) or ""
        lines.append(f"  {r.system}, {r.remedy}: {ratio:.2g}x the time, {steps}"
                     f"max |c| {r.max_c:.1e} (none: {b.max_c:.1e}){ev}" + (f"; {what}" if what else ""))
    return "\n".join(lines)


def _table(rows: list[RemedyResult]) -> str:
    dc = "max |c'|"
    head = f"{'system':<12} {'remedy':<22} {'max |c|':>10} {dc:>10} {'energy err':>10} " \
           f"{'wall [s]':>9} {'steps':>8}"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r.system:<12} {r.remedy:<22} {r.max_c:10.2e} {r.max_dc:10.2e} "
                     f"{r.energy_error:10.2e} {r.wall_time:9.2f} {r.steps:8d}")
    return "\n".join(lines)


def _drift_figure(rows: list[RemedyResult], title: str, path: Path,
                  units: tuple[str, str, str] = ("model units", "model units / s", "J")) -> None:
    """Drift and energy error of each remedy over time, as running maxima (envelopes): the
    largest value so far, so that curves neither fill solid bands nor dive to the floor where a
    value happens to be exactly zero; one colour per remedy (:data:`daekit.plot.REMEDY_COLORS`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def envelope(ax, t, y, row):
        _running_max(ax, t, y, row.remedy)

    fig, axes = plt.subplots(3, 1, figsize=(10, 8.5), sharex=True)
    e0 = rows[0].energy[0]
    for row in rows:
        tr = row.trajectory
        envelope(axes[2], tr.t, row.energy - e0, row)
        for ax, order in zip(axes[:2], (0, 1)):
            cols = _level_columns(tr, order)
            if cols:
                envelope(ax, tr.t, np.max(np.abs(tr.invariants[:, cols]), axis=1), row)
    axes[0].set_ylabel(f"max |c| so far\n(position level) [{units[0]}]")
    axes[1].set_ylabel(f"max |c'| so far\n(velocity level) [{units[1]}]")
    axes[2].set_ylabel(f"max |E - E(0)| so far\n(energy) [{units[2]}]")
    axes[2].set_xlabel("t [s]")
    axes[0].set_title(title + "\n(running maxima: the largest value up to each time)", fontsize=11)
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    for ax in axes:
        ax.grid(True, which="major", alpha=0.3)
        ax.set_ylim(1e-17, 1e0)
    axes[2].set_ylim(1e-12, 1e0)
    fig.tight_layout()
    _save(fig, path, dpi=110)


def run_tour(out: str | Path = "daekit-tour", t_end: float = 100.0, quiet: bool = False,
             animations: bool | None = None, ocp: bool = True, gifs: bool = False
             ) -> list[RemedyResult]:
    """Run the tour; print the story and the table, write figures into ``out``.

    ``gifs=True`` also writes the GIF animations (10-20 s of CPU time more); ``animations`` is the
    older name of the same switch (when given, it wins). ``ocp=False`` skips the optimal
    control section. Returns the table rows (with their trajectories).

    >>> import tempfile
    >>> rows = run_tour(tempfile.mkdtemp(), t_end=0.5, quiet=True, ocp=False)  # doctest: +SKIP
    """
    if animations is not None:
        gifs = bool(animations)
    import daekit as dk
    from daekit.examples import mechanisms

    progress = not quiet
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t = np.linspace(0.0, t_end, int(round(20 * t_end)) + 1)
    rows: list[RemedyResult] = []

    # ------------------------------------------------------------------ 3D pendulum
    m = dk.examples.pendulum3d()
    _analysis_section("1. The 3D pendulum (lecture L3): p' = v, m v' = u - m g e3 - z p, "
                      "0 = (p.p - L^2)/2", m, out / "pendulum3d_structure.png")
    _say("")
    r = dk.reduce_index(m)
    _say(f"Reduced: {r}. Consistency conditions: {', '.join(r.invariant_names)}.")
    th = 1.0
    fixed = {"p[0]": float(np.sin(th)), "p[1]": 0.0, "v[0]": 0.0, "v[1]": 2.0}
    guess = {"p": [np.sin(th), 0.0, -np.cos(th)], "v": [0.0, 2.0, 0.0]}
    _say(f"Initial values: fixed {fixed}; daekit completes them consistently.")
    r, init, prow = _remedies("pendulum", m, mechanisms.lagrangian_pendulum3d(), fixed, guess, t,
                              _energy_pendulum, None, progress,
                              dd_point={"p": guess["p"], "v": guess["v"]},
                              lag_names={"v": "der(p)"})
    _say(f"  free (could have been fixed instead): {sorted(init.free)}")
    rows += prow
    _say("")
    _say(_table(prow))
    _drift_figure(prow, f"3D pendulum, {t_end:g} s, rtol = atol = 1e-6: constraint drift and energy",
                  out / "pendulum3d_drift.png", units=("m^2", "m^2/s", "J"))
    _positions_figure(next(row for row in prow if row.remedy == "projection"),
                      out / "pendulum3d_positions.png")

    # ------------------------------------------------------------------ ODE invariants
    rows += _invariant_section(out, t, progress)

    # ------------------------------------------------------------------ delta robot
    _say("")
    md = dk.examples.delta_robot()
    _analysis_section("2. The delta robot (lecture L4): three arms, a platform, three rods; index 3",
                      md, out / "delta_robot_structure.png")
    # The motors are off (u = 0): the robot swings about its hanging equilibrium, where the
    # arms' gravity torque balances the platform's weight (found from the home configuration).
    from scipy.optimize import brentq

    a0 = brentq(lambda a: dk.examples.delta_robot_home((a, a, a))["u"][0], 1.6, 2.2)
    home = dk.examples.delta_robot_home((a0, a0, a0))
    u_hold = np.zeros(3)
    inputs = {"u": [0.0, 0.0, 0.0]}
    _say(f"Motors off; hanging equilibrium at alpha = {a0:.4f} rad; started with arm speeds "
         "(1, -0.5, 0) rad/s.")
    fixed_d = {"alpha": [a0, a0, a0], "omega": [1.0, -0.5, 0.0]}
    guess_d = {"alpha": [a0, a0, a0], "p": [float(x) for x in home["p"]]}
    lag = mechanisms.lagrangian_delta_robot()
    drow = []
    try:
        _rd, _initd, drow = _remedies(
            "delta robot", md, lag, fixed_d, guess_d, t,
            lambda tr: _energy_delta(tr, lag, u_hold), inputs, progress,
            dd_point=guess_d,
            lag_names={"omega": "der(alpha)", "v": "der(p)"},
        )
    except dk.DaekitError as exc:  # keep the tour going; say what failed
        _say(f"  delta robot runs stopped: {exc}")
    rows += drow
    if drow:
        _say("")
        _say(_table(drow))
        _drift_figure(drow, f"Delta robot, {t_end:g} s, rtol = atol = 1e-6: constraint drift and energy",
                      out / "delta_robot_drift.png")

    # ------------------------------------------------------------------ events and impacts
    _events_section(out, progress)

    # ------------------------------------------------------------------ animations
    if gifs:
        _animations(out, r, init, prow, drow, t_end, progress)

    # ------------------------------------------------------------------ optimal control
    if ocp:
        _say("")
        _say("=" * 78)
        _say("3. Optimal control on index-3 models: a crane in minimum time; a periodic orbit")
        _say("=" * 78)
        _ocp_section(out, progress)

    _say("")
    _say("=" * 78)
    _say("Summary (each remedy, 100 s unless --t-end says otherwise)")
    _say("=" * 78)
    _say(_table(rows))
    _say("")
    _say("Reading the table: without stabilization the index-1 form drifts off the constraint "
         "(|c| grows with time); Baumgarte damps the drift to the level of the integration error; "
         "GGL keeps c and c' as equations (bounded at the solver's tolerance, in the fewest "
         f"steps); projection keeps them below drift_tol ({TOUR_DRIFT_TOL:g} here; by "
         "default 100 atol); dummy derivatives keep them at rounding level; "
         "RATTLE keeps them to rounding and the energy error bounded without drift.")
    _say("")
    _say(_remedy_costs(rows))
    _say(f"Figures written to {out.resolve()}:")
    for f in sorted(out.iterdir()):
        _say(f"  {f.name}")
    if not gifs:
        _say("Animations (GIF, real time; the drift of an unstabilized pendulum among them): "
             "daekit tour --gifs")
    return rows


def _invariant_section(out: Path, t: np.ndarray, progress: bool) -> list[RemedyResult]:
    """The lecture's last slide: an ODE with an invariant drifts like a DAE and takes the same
    remedies. A free rigid body with a unit quaternion (``m.invariant(q.q - 1)``), the same
    run length, each remedy; |q|^2 - 1 over time in a figure next to the pendulum's."""
    import daekit as dk
    from daekit.examples import invariants as inv

    _say("")
    _say("=" * 78)
    _say("1b. ODE invariants: a free rigid body with a unit quaternion, m.invariant(q.q - 1)")
    _say("=" * 78)
    m = inv.rigid_body()
    data = inv.RIGID_BODY_DATA
    fixed = {"q": list(data["q0"]), "w": list(data["w0"])}
    rows: list[RemedyResult] = []
    rates: list[float] = []
    runs = [("none", None, "differentiate"), ("Baumgarte (pole -1)", "baumgarte", "differentiate"),
            ("projection", "projection", "differentiate"),
            ("dummy derivatives", "dummy_derivatives", "dummy_derivatives")]
    for label, stab, method in runs:
        done = _bar(progress, f"rigid body, {label}")
        w0 = time.perf_counter()
        r = dk.reduce_index(m, method=method, point=fixed if method != "differentiate" else None)
        init = dk.initialize(r, fixed=fixed)  # q fixed in full: redundant with 'unit', accepted
        extra = {"drift_tol": TOUR_DRIFT_TOL} if stab == "projection" else {}
        tr = dk.simulate(r, t, init, stabilization=stab, rtol=1e-6, atol=1e-6, **extra)
        wall = time.perf_counter() - w0
        done(wall)
        energy = inv.rigid_body_energy(tr["w"], data["I"])
        rate_err = float(np.max(np.abs(tr["w"] - inv.rigid_body_rates(tr.t))))
        rows.append(RemedyResult("rigid body", label, float(np.max(np.abs(tr.invariant("unit")))),
                                 float("nan"), float(np.max(np.abs(energy - energy[0]))), wall,
                                 int(tr.stats.get("steps", 0)), tr, energy))
        rates.append(rate_err)
    _say(f"Reduced: {dk.reduce_index(m)}; declared invariant 'unit' = |q|^2 - 1, held at t = 0; "
         "DOF 6 of 7 states.")
    _say("")
    head = (f"{'system':<12} {'remedy':<22} {'max|q.q-1|':>10} {'rate err':>10} "
            f"{'energy err':>10} {'wall [s]':>9} {'steps':>8}")
    _say(head)
    _say("-" * len(head))
    for row, er in zip(rows, rates, strict=True):
        _say(f"{row.system:<12} {row.remedy:<22} {row.max_c:10.2e} {er:10.2e} "
             f"{row.energy_error:10.2e} {row.wall_time:9.2f} {row.steps:8d}")
    _say("(rate err: max |w - w_exact| against the closed form w = (cos t, sin t, 2); no "
         "velocity-level invariant here: |q|^2 = 1 is first order, so Baumgarte has one pole, "
         "c' = -c, and dummy derivatives make one component of q algebraic, re-selected as "
         "the components pass through zero.)")
    _invariant_figure(rows, out / "rigid_body_drift.png")
    return rows


def _running_max(ax, t, y, label) -> None:
    """The running maximum of ``|y|`` (the largest value up to each time) on a log axis, in
    the remedy's colour: curves neither fill solid bands nor dive where a value is 0."""
    from .plot import remedy_color

    env = np.maximum.accumulate(np.abs(np.asarray(y, dtype=float)))
    keep = env > 0
    ax.semilogy(t[keep], np.maximum(env[keep], 1e-17), label=label, lw=1.4,
                color=remedy_color(label))


def _invariant_figure(rows: list[RemedyResult], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for row in rows:
        tr = row.trajectory
        _running_max(axes[0], tr.t, tr.invariant("unit"), row.remedy)
        _running_max(axes[1], tr.t, row.energy - row.energy[0], row.remedy)
    axes[0].set_ylabel("max | |q|^2 - 1 | so far\n[dimensionless]")
    axes[1].set_ylabel("max |E - E(0)| so far\n[J]")
    axes[1].set_xlabel("t [s]")
    axes[0].set_title("Rigid body with a unit quaternion: drift of the declared invariant\n"
                      "(running maxima: the largest value up to each time)", fontsize=11)
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    for ax in axes:
        ax.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    _save(fig, path, dpi=110)


def _ocp_section(out: Path, progress: bool) -> None:
    from daekit.examples import ocp_examples

    done = _bar(progress, "crane OCP (IPOPT)")
    t0 = time.perf_counter()
    sol = ocp_examples.crane_ocp().solve()
    done(time.perf_counter() - t0)
    _say(sol.report)
    _say(f"  daekit: success={sol.success}, minimum time T = {sol.T:.4f} s (objective "
         f"{sol.objective:.4f} with the small force regularization)")
    ocp_examples.crane_figure(sol, str(out / "crane_ocp.png"))

    _say("")
    _say("Periodic orbit of the 3D pendulum with full periodicity p(T) = p(0), v(T) = v(0):")
    done = _bar(progress, "periodic pendulum OCP, redundant conditions dropped")
    t0 = time.perf_counter()
    sol = ocp_examples.pendulum3d_periodic_ocp().solve()
    done(time.perf_counter() - t0)
    dropped = sol.stats.get("boundary_dropped", [])
    _say(f"  daekit: success={sol.success} ({sol.stats.get('return_status')}), objective "
         f"{sol.objective:.6g}; dropped as implied by the others and the invariants: "
         f"{', '.join(dropped)}")
    done = _bar(progress, "periodic pendulum OCP, everything imposed (naive)")
    t0 = time.perf_counter()
    naive = ocp_examples.pendulum3d_periodic_ocp().solve(redundancy="keep")
    done(time.perf_counter() - t0)
    _say(f"  naive (all conditions imposed): success={naive.success} "
         f"({naive.stats.get('return_status')}): the redundant conditions make the constraint "
         "Jacobian rank deficient.")
    ocp_examples.pendulum3d_periodic_figure(sol, str(out / "pendulum3d_periodic_ocp.png"))


def _events_section(out: Path, progress: bool) -> None:
    """Impacts and stop conditions on index-3 models: the wall pendulum against its exact impact
    times, and the crane trolley hitting its end stop until a terminal event finds it at rest."""
    import matplotlib.pyplot as plt

    import daekit as dk
    from daekit.examples.exact import pendulum_wall_impacts

    _say("")
    _say("=" * 78)
    _say("2b. Events: a pendulum hitting a wall, a crane trolley at its end stop")
    _say("=" * 78)
    e = 0.8
    r = dk.reduce_index(dk.examples.pendulum_wall(e))
    init = dk.initialize(r, fixed={"x": 1.0, "y": 0.0, "der(x)": 0.0})
    done = _bar(progress, "wall pendulum")
    t0 = time.perf_counter()
    tr = dk.simulate(r, np.linspace(0.0, 6.0, 601), init, rtol=1e-10, atol=1e-10)
    done(time.perf_counter() - t0)
    te = np.array([t for t, _ in tr.events])
    ref = pendulum_wall_impacts(te.size, e)
    post = [int(np.nonzero(tr.t == t)[0][-1]) for t in te]
    _say(f"Planar pendulum (index 3) released from horizontal, wall at x = 0, restitution {e}: "
         f"{te.size} impacts in 6 s; largest error of the impact times against the exact ones "
         f"(elliptic integral K, energy x e^2 per impact): {np.max(np.abs(te - ref)):.1e} s; "
         f"after each reset |rod|, |d/dt rod| <= {np.max(np.abs(tr.invariants[post])):.1e} "
         "(the velocity jump re-projected onto G v = 0, positions untouched).")
    ls = dk.examples.crane_end_stop()
    rc = ls.index1()
    initc = dk.initialize(rc, fixed=dk.examples.CRANE_END_STOP_INIT)
    done = _bar(progress, "crane end stop")
    t0 = time.perf_counter()
    trc = dk.simulate(rc, np.linspace(0.0, 30.0, 1201), initc, rtol=1e-8, atol=1e-8)
    done(time.perf_counter() - t0)
    _say("Crane: the trolley is pushed for 0.5 s (an if_else on t: a switch the integrator "
         "stops at), hits the end stop at s = 0.5 (restitution 0.5; the mass-weighted "
         "projection passes the impulse through the cable to the load) and the terminal event "
         "'at_rest' ends the run when the swing's energy is below 1e-3:")
    for t_, n_ in trc.events:
        _say(f"  t = {t_:8.4f}  {n_}")
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    axes[0].plot(tr.t, tr["x"], label="x")
    axes[0].plot(tr.t, tr["der(x)"], label="der(x)")
    for t_ in ref:
        axes[0].axvline(t_, color="0.8", lw=0.8, zorder=0)
    axes[0].set_title(f"wall pendulum, e = {e}: exact impact times (grey)")
    axes[0].set_xlabel("t [s]")
    axes[0].legend()
    axes[1].plot(trc.t, trc["q[0]"], label="trolley s")
    axes[1].plot(trc.t, trc["q[1]"], label="load x")
    axes[1].axhline(0.5, color="k", lw=0.8, ls="--", label="end stop")
    axes[1].set_title("crane: end stop, then at rest (terminal)")
    axes[1].set_xlabel("t [s]")
    axes[1].legend()
    fig.tight_layout()
    _save(fig, out / "events.png")


def _positions_figure(row: RemedyResult, path: Path, window: float = 10.0) -> None:
    """The bob's coordinates of one run: the first and the last ``window`` seconds side by side
    (the whole run in one column when it is shorter than two windows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from daekit.plot import remedy_color

    tr = row.trajectory
    t, p = tr.t, tr["p"]
    t0, t1 = float(t[0]), float(t[-1])
    spans = [(t0, t1)] if t1 - t0 <= 2 * window else [(t0, t0 + window), (t1 - window, t1)]
    fig, axes = plt.subplots(3, len(spans), figsize=(5.2 * len(spans) + 1.0, 6.6), sharey="row",
                             squeeze=False)
    colour = remedy_color(row.remedy)
    for j, (a, b) in enumerate(spans):
        k = (t >= a - 1e-9) & (t <= b + 1e-9)
        for i, name in enumerate("xyz"):
            ax = axes[i, j]
            ax.plot(t[k], p[k, i], color=colour, lw=1.2)
            ax.set_xlim(a, b)
            ax.grid(True, alpha=0.3)
            if j == 0:
                ax.set_ylabel(f"{name} = p[{i}] [m]")
        axes[0, j].set_title(f"t in [{a:g}, {b:g}] s", fontsize=10)
        axes[-1, j].set_xlabel("t [s]")
    fig.suptitle(f"3D pendulum, bob position with {row.remedy} (rtol = atol = 1e-6): "
                 + (f"first and last {window:g} s of {t1 - t0:g} s"
                    if len(spans) == 2 else f"{t1 - t0:g} s"), fontsize=11)
    fig.tight_layout()
    _save(fig, path, dpi=100)


def _animations(out: Path, reduced, init, prow: list, drow: list, t_end: float,
                progress: bool) -> None:
    """The GIFs, in real time at 20 frames per second, 480 pixels: the pendulum and the delta
    robot (projection, the first 10 s), and the drift of the unstabilized pendulum next to a
    projected one at a loose tolerance."""
    import daekit as dk
    from daekit import animate
    from daekit.plot import remedy_color

    done = _bar(progress, "animations (GIF, real time)")
    t0 = time.perf_counter()
    span = min(t_end, 10.0)
    tr = next(row.trajectory for row in prow if row.remedy == "projection")
    k = tr.t <= span + 1e-9
    animate.animate_pendulum(tr.t[k], tr["p"][k], out / "pendulum3d.gif", fps=20, real_time=True,
                             title="3D pendulum, projection")
    if drow:
        trd = next(row.trajectory for row in drow if row.remedy == "projection")
        k = trd.t <= span + 1e-9
        dd = dk.examples.DELTA_ROBOT_DATA
        animate.animate_delta_robot(trd.t[k], trd["alpha"][k], trd["p"][k], dd["r"], dd["a"],
                                    dd["L"], out / "delta_robot.gif", fps=20, real_time=True,
                                    title="delta robot, projection")
    # Drift made visible: a loose tolerance and a long span, nothing scaled up. The drift of a
    # run is an accumulation of local errors (it wanders, and it changes with the smallest change
    # of the formulation), so the tolerance is the tightest of a few loose ones at which the
    # rod's length leaves L = 1 m by 10 % within the span (the loosest if none does); the title
    # says which.
    drift_span, fps = min(t_end, 30.0), 10
    t = np.linspace(0.0, drift_span, int(round(20 * drift_span)) + 1)  # shown at 10 fps
    candidates = (3e-4, 1e-3, 3e-3, 1e-2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for tol in candidates:
            free = dk.simulate(reduced, t, init, rtol=tol, atol=tol)["p"]
            if np.max(np.abs(np.linalg.norm(free, axis=1) - 1.0)) >= 0.1:
                break
        kept = dk.simulate(reduced, t, init, rtol=tol, atol=tol, stabilization="projection",
                           drift_tol=TOUR_DRIFT_TOL)["p"]
    runs = {"no stabilization": free, "projection": kept}
    animate.animate_drift(
        t, runs, 1.0, out / "pendulum3d_drift.gif", fps=fps, real_time=True,
        colors={lab: remedy_color(lab) for lab in runs}, pixels=480,
        title=f"3D pendulum, index-1 form at the loose tolerance rtol = atol = {tol:.0e} (the "
              f"tightest of {', '.join(f'{c:.0e}' for c in candidates)} with a visible drift),\n"
              f"{drift_span:g} s in real time, nothing exaggerated: without stabilization the "
              "rod's length drifts from L = 1 m; with projection it stays 1 m")
    done(time.perf_counter() - t0)
