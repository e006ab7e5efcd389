"""Simulation: exact and published solutions, drift control, inputs, errors, Trajectory."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import daekit as dk
from daekit.errors import DaekitError, SimulationError
from daekit.initialize import initialize
from daekit.inputs import InputError
from daekit.reduced import ReducedDAE
from daekit.reduction import reduce_index
from daekit.simulate import Trajectory, simulate

# reference-problems.md section 2, case B (theta0 = pi/2, g = 9.81, L = 1)
X10, Y10 = 0.27508746257611686005, -0.96141920509912506427
X1, Y1 = -0.98629175113187531936, -0.16501085312554116875


def _released_horizontal(r):
    return initialize(r, guess={"x": 1.0, "y": 0.0}, fixed={"der(x)": 0.0, "der(y)": 0.0})


@pytest.fixture(scope="module")
def planar():
    return reduce_index(dk.examples.pendulum_planar())


def test_pendulum_case_b_exact(planar):
    traj = simulate(planar, np.linspace(0, 10, 11), _released_horizontal(planar),
                    rtol=1e-10, atol=1e-10)
    assert abs(traj["x"][1] - X1) < 1e-8 and abs(traj["y"][1] - Y1) < 1e-8
    assert abs(traj["x"][-1] - X10) < 1e-7
    assert abs(traj["y"][-1] - Y10) < 1e-7
    assert traj.stats["steps"] > 0 and traj.stats["residual_evaluations"] > 0


@pytest.fixture(scope="module")
def drift(planar):
    t = np.linspace(0, 100, 1001)
    out = {}
    for stab in (None, "baumgarte", "projection"):
        tr = simulate(planar, t, _released_horizontal(planar), rtol=1e-6, atol=1e-6,
                      stabilization=stab, poles=(-1, -1))
        out[stab] = np.max(np.abs(tr.invariant("rod")))
        if stab == "projection":
            out["projection_tol"] = tr.stats["drift_tol"]
            out["projection_all"] = np.max(np.abs(tr.invariants))
    rdd = reduce_index(dk.examples.pendulum_planar(), method="dummy_derivatives",
                       point={"x": 1.0, "y": 0.0})
    tr = simulate(rdd, t, _released_horizontal(rdd), rtol=1e-6, atol=1e-6,
                  stabilization="dummy_derivatives")
    out["dummy_derivatives"] = np.max(np.abs(tr.invariant("rod")))
    out["dd_traj"] = tr
    return out


def test_drift_baumgarte_ten_times_below_none(drift):
    assert drift[None] > 1e-5  # the index-1 form does drift at this tolerance
    assert drift["baumgarte"] * 10 <= drift[None]


def test_drift_projection_and_dummy_derivatives(drift):
    # projection by drift tolerance (issue 8): every invariant within drift_tol (default
    # 100 atol), far below the plain form's drift; no restart at every output point any more
    assert drift["projection_all"] < drift["projection_tol"]
    assert drift["projection"] * 20 <= drift[None]
    assert drift["dummy_derivatives"] < 1e-9
    tr = drift["dd_traj"]
    assert tr.t[-1] == 100.0  # swung through x = 0 and y = 0 many times without failing
    assert len(tr.stats["selection_switches"]) > 10
    assert np.max(np.abs(tr["x"] ** 2 + tr["y"] ** 2 - 1)) < 1e-9


def test_chemakzo_published():
    r = reduce_index(dk.examples.chemakzo())
    ks = 115.83
    init = initialize(r, fixed={"y": [0.444, 0.00123, 0, 0.007, 0]},
                      guess={"y6": ks * 0.444 * 0.007})
    assert init["y6"] == pytest.approx(ks * 0.444 * 0.007, rel=1e-14)
    traj = simulate(r, [0.0, 180.0], init, rtol=1e-10, atol=1e-10)
    ref = np.array([0.1150794920661702, 0.1203831471567715e-2, 0.1611562887407974,
                    0.3656156421249283e-3, 0.1708010885264404e-1, 0.4873531310307455e-2])
    got = np.r_[traj["y"][-1], traj["y6"][-1]]
    _check_published(got, ref)


def test_transistor_published():
    r = reduce_index(dk.examples.transistor_amplifier())
    init = initialize(r, fixed={"y": [0, 3, 3, 6, 3, 3, 6, 0]})  # consistent: 3 implied
    assert len(init.redundant) == 3
    traj = simulate(r, [0.0, 0.2], init, rtol=1e-10, atol=1e-10)
    ref = np.array([-0.5562145012262709e-2, 0.3006522471903042e1, 0.2849958788608128e1,
                    0.2926422536206241e1, 0.2704617865010554e1, 0.2761837778393145e1,
                    0.4770927631616772e1, 0.1236995868091548e1])
    _check_published(traj["y"][-1], ref)


def _check_published(got, ref):
    small = np.abs(ref) < 1e-6
    assert np.all(np.abs(got - ref)[small] < 1e-9)
    rel = np.abs(got - ref)[~small] / np.abs(ref[~small])
    assert np.all(rel < 1e-6), rel


def test_e1_brenan():
    r = reduce_index(dk.examples.e1())
    t = np.linspace(0, 5, 51)
    init = initialize(r, fixed={"y1": 1.0, "y2": 0.0})
    traj = simulate(r, t, init, rtol=1e-10, atol=1e-10)
    assert np.max(np.abs(traj["y1"] - (np.exp(-t) + t * np.sin(t)))) < 1e-6
    assert np.max(np.abs(traj["y2"] - np.sin(t))) < 1e-6


def test_e2_jay():
    r = reduce_index(dk.examples.e2())
    t = np.linspace(0, 1, 11)
    init = initialize(r, fixed={"y1": 1.0}, guess={"y2": 1.0, "w": 1.0})
    traj = simulate(r, t, init, rtol=1e-10, atol=1e-10)
    assert np.max(np.abs(traj["y1"] - np.exp(t))) < 1e-6
    assert np.max(np.abs(traj["y2"] - np.exp(-2 * t))) < 1e-6
    assert np.max(np.abs(traj["w"] - np.exp(2 * t))) < 1e-6


def test_e3_arevalo():
    # index 3 with a fast-growing frequency (2t): the drift of the plain index-1 form costs
    # accuracy (velocities off by ~3e-6 at 1e-10); projection keeps every component within 1e-6
    r = reduce_index(dk.examples.e3())
    t = np.linspace(1, 5, 41)
    s, c = np.sin(1.0), np.cos(1.0)
    init = initialize(r, fixed={"x": s, "u": 2 * c}, guess={"y": c, "v": -2 * s})
    traj = simulate(r, t, init, rtol=1e-10, atol=1e-10, stabilization="projection")
    exact = {"x": np.sin(t**2), "y": np.cos(t**2), "u": 2 * t * np.cos(t**2),
             "v": -2 * t * np.sin(t**2), "l": -4 * t**2}
    for name, val in exact.items():
        assert np.max(np.abs(traj[name] - val)) < 1e-6, name


# ------------------------------------------------------------------ inputs


def _l2():
    m = dk.Model("L2")
    x1, x2 = m.state("x1"), m.state("x2")
    z = m.algebraic("z")
    u = m.control("u")
    m.equation(m.der(x1) - z, name="a")
    m.equation(m.der(x2) - x1, name="b")
    m.equation(x2 - u, name="c")
    return m


def test_input_derivatives_from_expressions():
    m = _l2()
    r = reduce_index(m)
    assert "der(u)" in r.u_names
    t = np.linspace(0, 3, 31)
    inputs = {"u": ca.sin(m.t)}
    init = initialize(r, guess={"x1": 1.0, "x2": 0.0}, inputs=inputs)
    traj = simulate(r, t, init, inputs=inputs, rtol=1e-10, atol=1e-10)
    assert np.max(np.abs(traj["x2"] - np.sin(t))) < 1e-7
    assert np.max(np.abs(traj["x1"] - np.cos(t))) < 1e-7
    assert np.max(np.abs(traj["z"] - (-np.sin(t)))) < 1e-6


def test_callable_where_derivative_needed_is_an_error():
    r = reduce_index(_l2())
    with pytest.raises(InputError, match="der\\(u\\)"):
        simulate(r, [0, 1], np.zeros(r.nx), inputs={"u": np.sin})


def test_callable_input_matches_expression():
    from test_initialize import hand_pendulum3d

    r = hand_pendulum3d()
    init = initialize(r, fixed={"p": [0.0, 0.6, -0.8], "v": [1.0, 0.0, 0.0]})
    t = np.linspace(0, 2, 21)
    tr1 = simulate(r, t, init, inputs={"u": lambda s: [0.0, 0.0, np.sin(s)]})
    tr2 = simulate(r, t, init, inputs={"u": ca.vertcat(0, 0, ca.sin(r.t))})
    assert np.max(np.abs(tr1["p"] - tr2["p"])) < 1e-6
    assert tr1["p"].shape == (21, 3) and tr1["u[2]"][5] == pytest.approx(np.sin(t[5]))


def test_nan_input_is_named():
    from test_initialize import hand_pendulum3d

    r = hand_pendulum3d()
    init = initialize(r, fixed={"p": [0.0, 0.0, -1.0], "v": [0.0, 0.0, 0.0]})
    with pytest.raises(InputError, match="'u'"):
        simulate(r, np.linspace(0, 1, 11), init,
                 inputs={"u": lambda s: [0.0, 0.0, np.nan if s > 0.5 else 0.0]})
    with pytest.raises(InputError, match="'u\\[2\\]'"):
        simulate(r, np.linspace(0, 1, 11), init, inputs={"u[2]": ca.log(r.t - 0.5)})


# ------------------------------------------------------------------ failures


def _losing_rank():
    """x' = 1, 0 = z^2 + x^2 - 1: d alg/dz = 2z vanishes at t = 1, no solution after."""
    t, x, z = ca.SX.sym("t"), ca.SX.sym("x"), ca.SX.sym("z")
    return ReducedDAE(t, x, z, ca.SX(0, 1), ca.SX(0, 1), ca.SX(1), z**2 + x**2 - 1, ca.SX(0, 1),
                      [], ["x"], ["z"], [], [], np.zeros(0), {"x": x, "z": z})


def test_integrator_failure_carries_partial_trajectory():
    r = _losing_rank()
    init = initialize(r, fixed={"x": 0.0}, guess={"z": 1.0})
    with pytest.raises(SimulationError) as exc:
        simulate(r, np.linspace(0, 2, 21), init)
    err = exc.value
    assert 0.9 <= err.t <= 1.1
    part = err.trajectory
    assert isinstance(part, Trajectory) and 5 < len(part) <= 11
    assert np.allclose(part["z"], np.sqrt(1 - part.t**2), atol=1e-6)
    assert "t = " in str(err)


def test_bad_arguments():
    r = _losing_rank()
    with pytest.raises(DaekitError, match="increasing"):
        simulate(r, [0, 1, 0.5], [0.0])
    with pytest.raises(DaekitError, match="stabilization"):
        simulate(r, [0, 0.5], [0.0], stabilization="magic")
    with pytest.raises(DaekitError, match="dummy_derivatives"):
        simulate(r, [0, 0.5], [0.0], stabilization="dummy_derivatives")


# ------------------------------------------------------------------ Trajectory and figures


def test_trajectory_access_and_figures(tmp_path, capsys, monkeypatch):
    import sys

    import matplotlib

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)  # bar: TTY only

    matplotlib.use("Agg")
    from test_initialize import hand_pendulum3d

    r = hand_pendulum3d()
    init = initialize(r, fixed={"p": [0.0, 0.6, -0.8], "v": [1.0, 0.0, 0.0]})
    traj = simulate(r, np.linspace(0, 1, 11), init, progress=True)
    assert "100%" in capsys.readouterr().err
    assert traj["p"].shape == (11, 3) and traj["p[1]"].shape == (11,)
    assert traj["der(p)"].shape == (11, 3) and traj["z"].shape == (11,)
    assert traj.invariants.shape == (11, 2) and traj.invariant_names == ["rod", "d/dt rod"]
    assert np.max(np.abs(traj.invariants)) < 1e-6
    P, V = traj["p"], traj["v"]
    assert np.allclose(traj.invariant("rod"), 0.5 * (np.sum(P * P, axis=1) - 1), atol=1e-15)
    assert np.allclose(traj.invariant("d/dt rod"), np.sum(P * V, axis=1), atol=1e-15)
    assert np.allclose(traj["der(p)"], V)
    with pytest.raises(KeyError):
        traj["q"]
    fig = traj.plot(["p", "z"])
    assert len(fig.axes) == 2
    fig2 = traj.plot_invariants()
    assert len(fig2.axes) == 2 and fig2.axes[0].get_yscale() == "log"
    fig2.savefig(tmp_path / "drift.png")
    try:
        import pandas  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="pandas"):
            traj.to_pandas()
    else:
        assert traj.to_pandas().shape[0] == 11


def test_bad_init_type_is_a_daekit_error():
    import daekit as dk

    r = dk.reduce_index(dk.examples.pendulum3d())
    with pytest.raises(dk.DaekitError, match="init must be InitialValues"):
        dk.simulate(r, [0.0, 1.0], "hello")


def test_integrator_cache_distinguishes_inputs_that_print_alike():
    """Constants differing in the 7th digit print alike; each must get its own integrator."""
    import daekit as dk

    m = dk.Model("drive")
    x = m.state("x")
    u = m.control("u")
    m.equation(m.der(x) - u, name="d")
    r = dk.reduce_index(m)
    init = dk.initialize(r, fixed={"x": 0.0})
    for a in (1.2345671, 1.2345674):
        tr = dk.simulate(r, np.linspace(0, 10, 3), init, inputs={"u": a + 0 * r.t})
        assert tr["x"][-1] == pytest.approx(10 * a, rel=1e-12)


def test_progress_does_not_change_the_result(capsys, monkeypatch):
    """Case B at 1e-10 with the progress bar: still one IDAS run, still within 1e-7."""
    import sys

    import daekit as dk

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)  # bar: TTY only
    from daekit.examples import exact

    r = dk.reduce_index(dk.examples.pendulum_planar())
    init = dk.initialize(r, fixed={"x": 1.0, "der(x)": 0.0}, guess={"y": 0.0, "der(y)": 0.0})
    t = np.linspace(0, 10, 1001)
    tr = dk.simulate(r, t, init, rtol=1e-10, atol=1e-10, progress=True)
    ref = exact.pendulum_planar(np.array([10.0]), np.pi / 2, g=9.81, L=1.0)
    assert abs(tr["x"][-1] - float(np.ravel(ref["x"])[0])) < 1e-7
    assert "100%" in capsys.readouterr().err


def test_systems_without_states_gear_petzold_and_l2_dummy():
    """F1 (reduced: no states) and L2 by dummy derivatives: solved at each output time."""
    import casadi as ca

    import daekit as dk

    t = np.linspace(0, 2, 9)
    r = dk.reduce_index(dk.examples.gear_petzold())
    assert r.nx == 0
    tr = dk.simulate(r, t, dk.initialize(r))
    assert np.allclose(tr["y"], np.sin(t), atol=1e-12)  # y = sin t, z = 0
    assert np.allclose(tr["z"], 0.0, atol=1e-12)
    rd = dk.reduce_index(dk.examples.l2(), method="dummy_derivatives")
    assert rd.nx == 0
    u = {"u": ca.sin(rd.t)}
    tr = dk.simulate(rd, t, dk.initialize(rd, inputs=u), inputs=u)
    assert np.allclose(tr["x1"], np.cos(t), atol=1e-10)  # x1 = u'
    assert np.allclose(tr["z"], -np.sin(t), atol=1e-10)  # z = u''


def test_initial_values_for_another_start_or_parameters_are_refused():
    import casadi as ca

    import daekit as dk

    r = dk.reduce_index(dk.examples.l2())
    u = {"u": ca.sin(r.t)}
    init = dk.initialize(r, inputs=u)  # at t0 = 0: x2 = sin 0
    with pytest.raises(dk.DaekitError, match=r"computed at t0 = 0 while the grid starts at t = 1"):
        dk.simulate(r, np.linspace(1, 3, 5), init, inputs=u)
    rp = dk.reduce_index(dk.examples.pendulum3d())
    init = dk.initialize(rp, fixed={"p": [0.6, 0, -0.8], "v": [0, 1, 0]})
    with pytest.raises(dk.DaekitError, match=r"other parameter values.*'rod'"):
        dk.simulate(rp, np.linspace(0, 1, 5), init, params={"L": 2.0})


def test_failure_time_is_where_idas_stopped_not_the_interval_start():
    """z^2 + x^2 = 1 with x = t loses its solution at t = 1: on the coarse grid [0, 2] the
    error must say t = 1 (read from SUNDIALS' own report), not t = 0."""
    import daekit as dk

    m = dk.Model("fold")
    x = m.state("x")
    z = m.algebraic("z")
    m.equation(m.der(x) - 1, name="clock")
    m.equation(z**2 + x**2 - 1, name="circle")
    r = dk.reduce_index(m)
    init = dk.initialize(r, fixed={"x": 0.0}, guess={"z": 1.0})
    with pytest.raises(dk.SimulationError) as err:
        dk.simulate(r, [0.0, 2.0], init)
    assert err.value.t == pytest.approx(1.0, abs=1e-3)
    assert err.value.trajectory.t[-1] == 0.0


def test_ggl_initialized_on_the_index1_system_and_accurate_at_tight_tolerance():
    """GGL (index 2): initialize gives the index-1 system's multiplier and mu = 0; IDAS at
    rtol = atol = 1e-10 reaches case B's exact x(10), y(10) (reference-problems section 2)."""
    import daekit as dk
    from daekit.examples import exact

    r = dk.reduce_index(dk.examples.pendulum_planar())
    g = dk.ggl(r)
    fixed = {"x": 1.0, "der(x)": 0.0}
    guess = {"y": 0.0, "der(y)": 0.0}
    i1, ig = dk.initialize(r, fixed=fixed, guess=guess), dk.initialize(g, fixed=fixed, guess=guess)
    assert ig["T"] == pytest.approx(i1["T"], abs=1e-12)
    assert ig.z0[-1] == 0.0 and g.z_names[-1].startswith("mu(")
    tr = dk.simulate(g, np.linspace(0, 10, 101), ig, rtol=1e-10, atol=1e-10)
    ref = exact.pendulum_planar(np.array([10.0]), np.pi / 2, g=9.81, L=1.0)
    assert abs(tr["x"][-1] - float(np.ravel(ref["x"])[0])) < 1e-7
    assert abs(tr["y"][-1] - float(np.ravel(ref["y"])[0])) < 1e-7
    # from another angle too (it used to fail with IDA_CONV_FAIL at t ~ 5e-9)
    i2 = dk.initialize(g, fixed={"x": float(np.sin(0.6)), "der(x)": 0.0},
                       guess={"y": -0.8, "der(y)": 0.0})
    tr = dk.simulate(g, np.linspace(0, 10, 101), i2, rtol=1e-10, atol=1e-10)
    assert max(tr.max_invariant().values()) < 1e-8


def test_dummy_derivative_system_always_reselects():
    """A dummy-derivative system simulated without naming the stabilization: the selection
    (x dummy, from horizontal) becomes singular at the bottom; the run must re-select, not
    cross onto a wrong solution (it ended at x = 0.786 instead of the exact 0.942 at t = 5)."""
    from daekit.examples import exact

    rd = dk.reduce_index(dk.examples.pendulum_planar(), method="dummy_derivatives")
    iv = dk.initialize(rd, 0.0, fixed={"x": 1.0, "y": 0.0, "der(x)": 0.0})
    t = np.linspace(0.0, 5.0, 201)
    ref = exact.pendulum_planar(t, np.pi / 2)
    for stab in (None, "dummy_derivatives"):
        tr = dk.simulate(rd, t, iv, rtol=1e-8, atol=1e-8, stabilization=stab)
        assert np.max(np.abs(tr["x"] - ref["x"])) < 1e-4, stab


def test_statistics_are_those_of_the_run():
    """Every statistic counts the run it is reported with: a second identical call (the same
    reused integrator) reports the same numbers (the Jacobian evaluations used to be CasADi's
    lifetime count of the reused integrator's Jacobian calls, growing call after call), and
    the plain run's counts satisfy IDAS's own relations."""
    r = reduce_index(dk.examples.pendulum_planar())
    iv = dk.initialize(r, fixed={"x": 1.0, "der(x)": 0.0}, guess={"y": 0.0, "der(y)": 0.0})
    t = np.linspace(0.0, 5.0, 11)
    keys = ("steps", "residual_evaluations", "jacobian_evaluations", "error_test_failures",
            "newton_failures")
    runs = [dk.simulate(r, t, iv, rtol=1e-8, atol=1e-8).stats for _ in range(3)]
    assert all({k: s[k] for k in keys} == {k: runs[0][k] for k in keys} for s in runs)
    st = runs[0]
    assert 0 < st["jacobian_evaluations"] < st["steps"] < st["residual_evaluations"]


def test_options_with_one_value_per_unknown_are_checked_against_the_system():
    """``abstolv`` of the wrong length used to abort the process (CasADi does not check it and
    SUNDIALS wrote past the vector: "free(): invalid next size", found on the 3D pendulum's
    dummy-derivative system); now a daekit error names the option, the unknowns in order and
    the lengths. With the right length it runs and matches the scalar ``atol`` run; dummy
    derivatives, whose unknowns change at each re-selection, refuse such options."""
    r = reduce_index(dk.examples.pendulum_planar())
    iv = dk.initialize(r, fixed={"x": 1.0, "der(x)": 0.0}, guess={"y": 0.0, "der(y)": 0.0})
    t = np.linspace(0.0, 1.0, 5)
    n = r.nx + r.nz
    same = dk.simulate(r, t, iv, rtol=1e-8, atol=1e-8, abstolv=[1e-8] * n)
    ref = dk.simulate(r, t, iv, rtol=1e-8, atol=1e-8)
    assert same.stats["steps"] == ref.stats["steps"]
    assert np.array_equal(same["x"], ref["x"])
    with pytest.raises(InputError, match=r"abstolv needs one value per unknown.*'T'.*\(5\); got 3"):
        dk.simulate(r, t, iv, abstolv=[1e-8] * 3)
    with pytest.raises(InputError, match="init_xdot needs one value per unknown"):
        dk.simulate(r, t, iv, init_xdot=[0.0] * n)
    # the right number of values in the wrong shape (CasADi's own error named no option)
    with pytest.raises(InputError, match=r"abstolv needs one value.*an array of shape \(5, 2\)"):
        dk.simulate(r, t, iv, abstolv=np.full((n, 2), 1e-8))
    rd = reduce_index(dk.examples.pendulum_planar(), method="dummy_derivatives")
    ivd = dk.initialize(rd, 0.0, fixed={"x": 1.0, "y": 0.0, "der(x)": 0.0})
    with pytest.raises(InputError, match="dummy derivatives change the unknowns"):
        dk.simulate(rd, t, ivd, abstolv=[1e-8] * (rd.nx + rd.nz))
