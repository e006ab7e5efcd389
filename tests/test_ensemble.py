"""Ensembles and parameter sweeps (issue 13): local processes, Dask, failures, sampling, OCP
sweeps; the pickled system; and the entry points' one rule for Models (issue 15 item 1)."""

import pickle
import sys

import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline

import daekit as dk
from daekit.examples.exact import pendulum_planar, pendulum_planar_period

THETA0 = np.pi / 3  # released at rest from 60 degrees
LENGTHS = np.linspace(0.5, 2.0, 16)
T_GRID = np.linspace(0.0, 3.2, 641)  # the longest period (L = 2) is 3.05 s


@pytest.fixture(scope="module")
def planar():
    return dk.reduce_index(dk.examples.pendulum_planar())


@pytest.fixture(scope="module")
def dask_client():
    """One LocalCluster (2 worker processes) for the whole module."""
    import distributed  # the [dask] extra, part of the test extras: CI runs this path
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
    client = distributed.Client(cluster)
    yield client
    client.close()
    cluster.close()


def swing_samples():
    return [{"L": L, "x": L * np.sin(THETA0), "y": -L * np.cos(THETA0)} for L in LENGTHS]


def period(traj):
    """Twice the time between the two sign changes of x (at T/4 and 3T/4), each located on
    the cubic Hermite interpolant of x and der(x) between the grid points around it."""
    x, v, t = traj["x"], traj["der(x)"], traj.t
    crossings = []
    for k in np.where(np.diff(np.sign(x)) != 0)[0][:2]:
        s = CubicHermiteSpline(t[k:k + 2], x[k:k + 2], v[k:k + 2])
        crossings.append(float(s.roots(extrapolate=False)[0]))
    return {"period": 2.0 * (crossings[1] - crossings[0])}


def run(planar, executor, samples=None, **kw):
    return dk.ensemble(planar, T_GRID, samples or swing_samples(), executor=executor,
                       fixed={"der(x)": 0.0}, reduce=period, rtol=1e-11, atol=1e-11,
                       progress=False, **kw)


@pytest.fixture(scope="module")
def local(planar):
    return run(planar, None)


def exact_periods():
    return np.array([pendulum_planar_period(THETA0, g=9.81, L=L) for L in LENGTHS])


def test_sixteen_lengths_default_executor_exact_periods(local):
    assert local.stats["executor"] == "processes" and len(local) == 16 and local.failures == {}
    # the system travels once per worker process, not once per sample or task
    assert local.stats["system_transfers"] == local.stats["workers"] < local.stats["chunks"]
    got = np.array([row["period"] for row in local.summary()])
    assert np.abs(got - exact_periods()).max() < 1e-6
    # and the trajectories themselves against the exact (Jacobi elliptic) solution
    for i in (0, 15):
        ex = pendulum_planar(T_GRID, THETA0, g=9.81, L=LENGTHS[i])
        assert np.abs(local[i]["x"] - ex["x"]).max() < 1e-7
        assert np.abs(local[i]["y"] - ex["y"]).max() < 1e-7


def test_sixteen_lengths_on_dask_identical(planar, local, dask_client):
    ens = run(planar, dask_client)
    assert ens.stats["executor"].startswith("dask") and ens.failures == {}
    got = np.array([row["period"] for row in ens.summary()])
    assert np.abs(got - exact_periods()).max() < 1e-6
    for a, b in zip(local, ens, strict=True):  # bit for bit
        assert np.array_equal(a["x"], b["x"]) and np.array_equal(a.invariants, b.invariants)
    assert [r["period"] for r in ens.summary()] == [r["period"] for r in local.summary()]
    # the Client's concurrent.futures executor works too (the system shipped per chunk)
    ex = run(planar, dask_client.get_executor(), samples=swing_samples()[:4])
    assert [r["period"] for r in ex.summary()] == [r["period"] for r in local.summary()[:4]]


def blas_threads_here(traj):
    """A reduce run in the worker: how many threads its BLAS pool has."""
    from threadpoolctl import threadpool_info
    return {"blas": max((i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"),
                        default=1)}


def test_workers_run_one_blas_thread_and_this_process_gets_its_own_back(planar):
    """A started OpenBLAS thread spins 50-100 ms: forked workers must not start any (they run
    one BLAS thread), and this process gets its own setting back afterwards."""
    from threadpoolctl import threadpool_info, threadpool_limits

    def here():
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    with threadpool_limits(2, user_api="blas"):
        before = here()
        ens = dk.ensemble(planar, T_GRID[:50], swing_samples()[:4], fixed={"der(x)": 0.0},
                          reduce=blas_threads_here, progress=False)
        assert ens.failures == {} and ens.stats["executor"] == "processes"
        assert [row["blas"] for row in ens.summary()] == [1, 1, 1, 1]
        assert here() == before


def test_serial_and_thread_pool_identical(planar, local):
    from concurrent.futures import ThreadPoolExecutor

    some = swing_samples()[::5]
    ser = run(planar, "serial", samples=some)
    with ThreadPoolExecutor(2) as pool:
        thr = run(planar, pool, samples=some)
    for k, i in enumerate(range(0, 16, 5)):
        assert np.array_equal(ser[k]["x"], local[i]["x"])
        assert np.array_equal(thr[k]["x"], local[i]["x"])


def test_shipped_trajectories_compute_their_other_columns_here(planar):
    """Workers send the state arrays and a recipe (the system by reference); the columns that
    are not elements of x, z, u are computed here when read: all equal to a serial run's,
    bit for bit, and a shipped trajectory pickles as usual afterwards (every column)."""
    ser = run(planar, "serial", samples=swing_samples()[:2])
    local = run(planar, None, samples=swing_samples()[:2], chunksize=1)
    assert local.stats["executor"] == "processes"
    shipped = local[0]
    pending = set(shipped.values._pending)
    assert pending, "nothing was left to compute here"
    for name in ser[0].names:
        assert np.array_equal(shipped[name], ser[0][name]), name
    again = pickle.loads(pickle.dumps(local[1]))
    assert isinstance(again.values, dict) and set(again.names) == set(ser[1].names)
    assert np.array_equal(again["der(y)"], ser[1]["der(y)"])


def test_failing_sample_is_named_and_the_sweep_goes_on(planar):
    samples = swing_samples()[:3]
    samples.insert(1, {"L": 1.0, "x": 1.5})  # |x| > L: contradicts the rod
    ens = run(planar, None, samples=samples, chunksize=1)
    assert sorted(ens.failures) == [1] and ens[1] is None
    msg = ens.failures[1]
    assert msg.startswith("sample 1 (L = 1, x = 1.5)") and "rod" in msg and "x = 1.5" in msg
    rows = ens.summary()
    assert rows[1]["success"] is False and "rod" in rows[1]["error"]
    assert all(rows[i]["success"] for i in (0, 2, 3)) and ens.succeeded == [0, 2, 3]
    ex = [pendulum_planar_period(THETA0, L=s["L"]) for s in samples[0:1] + samples[2:]]
    assert np.allclose([rows[i]["period"] for i in (0, 2, 3)], ex, rtol=0, atol=1e-6)


def test_keep_summary_and_pandas(planar):
    samples = {"L": LENGTHS[:3], "x": LENGTHS[:3] * np.sin(THETA0),
               "y": -LENGTHS[:3] * np.cos(THETA0)}  # a dict of arrays
    ens = run(planar, "serial", samples=samples, keep="summary")
    with pytest.raises(dk.ModelError, match="keep='summary'"):
        ens[0]
    df = ens.to_pandas()
    assert list(df.index) == [0, 1, 2] and df["success"].all()
    assert {"L", "x", "y", "success", "error", "max_invariant", "max|rod|", "max|d/dt rod|",
            "wall_time", "steps", "period"} <= set(df.columns)
    assert np.allclose(df["period"], exact_periods()[:3], atol=1e-6)
    assert (df["max_invariant"] < 1e-7).all()


def test_summary_files(planar, tmp_path):
    ens = run(planar, "serial", samples=swing_samples()[:2])
    csv = ens.save_summary(tmp_path / "s.csv")
    pq = ens.save_summary(tmp_path / "s.parquet")
    import pandas as pd

    a, b = pd.read_csv(csv, index_col="sample"), pd.read_parquet(pq)
    assert np.array_equal(a["period"].to_numpy(), ens.to_pandas()["period"].to_numpy())
    assert np.array_equal(b["period"].to_numpy(), ens.to_pandas()["period"].to_numpy())
    with pytest.raises(dk.ModelError, match=".csv or a .parquet"):
        ens.save_summary(tmp_path / "s.txt")


def test_unknown_names_and_bad_arguments(planar):
    with pytest.raises(dk.ModelError, match=r"sample 1 sets 'Lx'.*parameter \(L, g\)"):
        dk.ensemble(planar, T_GRID, [{"L": 1.0}, {"Lx": 2.0}], executor="serial")
    with pytest.raises(dk.ModelError, match="equal lengths"):
        dk.ensemble(planar, T_GRID, {"L": [1, 2], "x": [0.1]}, executor="serial")
    with pytest.raises(dk.ModelError, match="keep must be"):
        dk.ensemble(planar, T_GRID, [{"L": 1.0}], keep="all")
    with pytest.raises(dk.ModelError, match="executor"):
        dk.ensemble(planar, T_GRID, [{"L": 1.0}], executor="threads")
    # options shared by every sample are checked once, before anything runs
    with pytest.raises(dk.ModelError, match="unknown stabilization 'projections'"):
        dk.ensemble(planar, T_GRID, [{"L": 1.0}], stabilization="projections")
    with pytest.raises(dk.ModelError, match="rtol must be a positive number"):
        dk.ensemble(planar, T_GRID, [{"L": 1.0}], rtol=-1.0)


def test_a_model_is_reduced_once_and_noted():
    m = dk.examples.pendulum_planar()
    ens = dk.ensemble(m, T_GRID[:101], [{"L": 1.0, "x": np.sin(THETA0), "y": -np.cos(THETA0)}],
                      executor="serial", fixed={"der(x)": 0.0}, rtol=1e-10, atol=1e-10)
    assert "reduced automatically" in ens.stats["notes"][0]
    ex = pendulum_planar(T_GRID[:101], THETA0)
    assert np.abs(ens[0]["x"] - ex["x"]).max() < 1e-7


def test_lambda_reduce_ships_to_processes(planar):
    ens = dk.ensemble(planar, T_GRID, swing_samples()[:2], fixed={"der(x)": 0.0},
                      reduce=lambda tr: {"x_end": tr["x"][-1]}, progress=False, rtol=1e-10,
                      atol=1e-10)
    assert ens.failures == {}
    for row in ens.summary():
        ex = pendulum_planar(T_GRID[-1:], THETA0, L=row["L"])
        assert abs(row["x_end"] - float(np.ravel(ex["x"])[0])) < 1e-7


def test_reduced_dae_pickles_and_simulates_exactly(planar):
    dk.initialize(planar, guess={"x": 0.5, "y": -0.5})  # leaves private caches on the system
    r2 = pickle.loads(pickle.dumps(planar))
    assert r2.x_names == planar.x_names and r2.invariant_names == planar.invariant_names
    init = dk.initialize(r2, fixed={"x": np.sin(THETA0), "der(x)": 0.0}, guess={"y": -0.5})
    tr = dk.simulate(r2, T_GRID[:201], init, rtol=1e-10, atol=1e-10)
    ex = pendulum_planar(T_GRID[:201], THETA0)
    assert np.abs(tr["x"] - ex["x"]).max() < 1e-7 and np.abs(tr["T"] - ex["T"]).max() < 1e-6
    import copy

    import casadi as ca

    c = copy.copy(planar)  # copies share the symbols (only pickling makes new ones)
    assert ca.is_equal(c.x, planar.x) and ca.is_equal(copy.deepcopy(planar).x, planar.x)
    traj2 = pickle.loads(pickle.dumps(tr))
    assert np.array_equal(traj2["x"], tr["x"]) and traj2.invariant_names == tr.invariant_names


def test_sample_reproducible_and_distributed():
    spec = {"L": ("uniform", 0.8, 1.2), "m": ("normal", 2.0, 0.1), "k": 3.0}
    a = dk.sample(spec, 2000, seed=7)
    assert a == dk.sample(spec, 2000, seed=7) and a != dk.sample(spec, 2000, seed=8)
    L = np.array([s["L"] for s in a])
    mass = np.array([s["m"] for s in a])
    assert L.min() >= 0.8 and L.max() <= 1.2 and abs(L.mean() - 1.0) < 0.01
    assert abs(mass.mean() - 2.0) < 0.01 and abs(mass.std() - 0.1) < 0.01
    assert all(s["k"] == 3.0 for s in a)
    # a name's stream does not depend on the others
    b = dk.sample({"L": ("uniform", 0.8, 1.2)}, 2000, seed=7)
    assert [s["L"] for s in b] == list(L)
    lhs = dk.sample({"u": ("uniform", 0, 1), "v": ("loguniform", 1e-3, 1)}, 50, seed=1,
                    method="lhs")
    assert sorted(int(s["u"] * 50) for s in lhs) == list(range(50))
    assert sorted(int((np.log10(s["v"]) + 3) / 3 * 50) for s in lhs) == list(range(50))
    for bad, match in [({"L": ("uniform", 2, 1)}, "lo < hi"), ({"L": ("gauss", 0, 1)}, "not a "
                       "distribution"), ({"L": ("normal", 0, -1)}, "standard deviation")]:
        with pytest.raises(dk.ModelError, match=match):
            dk.sample(bad, 3)


def test_monte_carlo_ensemble_from_sample(planar):
    """Uncertain rod length: every sampled period matches the exact one."""
    s = dk.sample({"L": ("uniform", 0.8, 1.2)}, 6, seed=3)
    for d in s:
        d.update(x=d["L"] * np.sin(THETA0), y=-d["L"] * np.cos(THETA0))
    ens = run(planar, "serial", samples=s)
    for row in ens.summary():
        assert abs(row["period"] - pendulum_planar_period(THETA0, L=row["L"])) < 1e-6


def test_ocp_sweep_warm_started():
    """Rest-to-rest transfer of a unit mass over distance d in 1 s: the minimum of int u^2 is
    12 d^2 (the cubic 3t^2 - 2t^3, exactly representable by the polynomial controls)."""
    m = dk.Model("cart")
    s = m.state("s")
    u = m.control("u")
    m.equation(m.der(s, 2) - u, name="newton")

    def problem(d):
        ocp = dk.OCP(m, t_final=1.0, intervals=10, controls="polynomial")
        ocp.minimize(integral=u**2)
        return ocp.initial({"s": 0, "der(s)": 0}).final({"s": d, "der(s)": 0})

    d = [0.5, 2.0, 1.0, 1.5, -3.0]
    ens = dk.ensemble_ocp(problem, {"d": d}, progress=False)
    rows = ens.summary()
    assert ens.failures == {}
    assert np.allclose([r["objective"] for r in rows], 12 * np.square(d), rtol=1e-8)
    order = ens.stats["order"]
    assert order[0] == 0 and sorted(order) == list(range(5))
    for i in order[1:]:  # every later solve started from its nearest solved neighbour
        j = rows[i]["warm_from"]
        assert j >= 0 and order.index(j) < order.index(i)
        before = [k for k in order[:order.index(i)]]
        assert abs(d[j] - d[i]) == min(abs(d[k] - d[i]) for k in before)
    assert ens[1].success and abs(ens[1]["s"][-1] - 2.0) < 1e-9
    with pytest.raises(dk.ModelError, match="factory"):
        dk.ensemble_ocp(42, [{"d": 1}])


def test_ocp_sweep_over_parameters_of_one_ocp():
    """mass * s'' = u, rest to rest over distance 1 in 1 s: min int u^2 = 12 mass^2."""
    m = dk.Model("cart")
    s = m.state("s")
    u = m.control("u")
    mass = m.parameter("mass", 1.0)
    m.equation(mass * m.der(s, 2) - u, name="newton")
    ocp = dk.OCP(m, t_final=1.0, intervals=10, controls="polynomial")
    ocp.minimize(integral=u**2)
    ocp.initial({"s": 0, "der(s)": 0}).final({"s": 1, "der(s)": 0})
    masses = [1.0, 3.0, 2.0]
    ens = dk.ensemble_ocp(ocp, {"mass": masses}, progress=False, keep="summary")
    rows = ens.summary()
    assert np.allclose([r["objective"] for r in rows], 12 * np.square(masses), rtol=1e-8)
    assert [r["warm_from"] for r in rows] == [-1, 2, 0]


def test_ensemble_plot_percentile_bands(local):
    import matplotlib

    matplotlib.use("Agg")
    fig = local.plot("x")
    ax = fig.axes[0]
    assert len(ax.collections) == 2  # the 5-95 % and 25-75 % bands
    assert len(ax.lines) == 16 + 1  # faint trajectories and the median
    med = ax.lines[-1].get_ydata()
    assert np.allclose(med, np.median(local.values("x"), axis=0))
    assert local.percentiles("x", (0, 100)).shape == (2, T_GRID.size)


def test_progress_only_on_a_terminal(planar, capsys):
    dk.ensemble(planar, T_GRID, swing_samples()[:2], executor="serial", fixed={"der(x)": 0.0},
                progress=True)
    err = capsys.readouterr().err
    assert err == ""  # stderr is not a terminal under pytest: nothing drawn


def test_progress_bar_draws_on_a_terminal(monkeypatch):
    from daekit.ensemble import _SampleProgress

    class Tty:
        text = ""

        def isatty(self):
            return True

        def write(self, s):
            Tty.text += s

        def flush(self):
            pass

    monkeypatch.setattr(sys, "stderr", Tty())
    bar = _SampleProgress(True, 4)
    bar.update(2, 1)
    bar.close()
    assert "2/4 samples, 1 failed" in Tty.text and Tty.text.endswith("\n")


def test_cli_sweep_csv(tmp_path, capsys):
    from daekit.cli import main

    out = tmp_path / "sweep.csv"
    rc = main(["sweep", "pendulum_planar", "--param", "L=0.5:2.0:4", "--t-end", "1",
               "--points", "51", "--guess", '{"x": 0.5, "y": -0.5}', "--fixed",
               '{"der(x)": 0}', "--out", str(out), "--quiet", "--serial"])
    assert rc == 0
    import pandas as pd

    df = pd.read_csv(out, index_col="sample")
    assert np.allclose(df["L"], np.linspace(0.5, 2.0, 4)) and df["success"].all()
    assert "swept 4 samples of L" in capsys.readouterr().out
    rc = main(["sweep", "pendulum_planar", "--param", "L=0.5:2.0", "--t-end", "1"])
    assert rc == 2 and "LO:HI:N" in capsys.readouterr().err
    # Monte Carlo from the shell: the same draws as dk.sample
    rc = main(["sweep", "pendulum_planar", "--draw", "L=uniform:0.8:1.2", "--n", "3",
               "--seed", "4", "--t-end", "0.5", "--points", "11", "--guess",
               '{"x": 0.5, "y": -0.5}', "--out", str(out), "--quiet", "--serial"])
    assert rc == 0
    df = pd.read_csv(out, index_col="sample")
    want = [d["L"] for d in dk.sample({"L": ("uniform", 0.8, 1.2)}, 3, seed=4)]
    assert df["L"].tolist() == want and df["success"].all()


def test_cli_sweep_on_a_scheduler(dask_client, tmp_path, capsys):
    from daekit.cli import main

    out = tmp_path / "sweep.parquet"
    rc = main(["sweep", "pendulum_planar", "--param", "L=1,2", "--param", "g=9.81,1.62",
               "--t-end", "1", "--points", "11", "--guess", '{"x": 0.5, "y": -0.5}',
               "--scheduler", dask_client.scheduler.address, "--out", str(out), "--quiet"])
    assert rc == 0
    import pandas as pd

    df = pd.read_parquet(out)
    assert len(df) == 4 and df["success"].all()
    assert sorted(zip(df["L"], df["g"])) == [(1.0, 1.62), (1.0, 9.81), (2.0, 1.62), (2.0, 9.81)]
    assert "dask" in capsys.readouterr().out



def test_input_expressions_travel_with_the_system():
    """Lecture L2 driven by u = a sin(t) (an SX expression of the model's time): x2 = u,
    x1 = u', z = u'' in every worker, the input's symbol shared with the shipped system."""
    import casadi as ca

    m = dk.examples.l2()
    t = np.linspace(0, 2, 21)
    ens = dk.ensemble(m, t, [{}, {}], inputs={"u": ca.sin(m.t)}, progress=False,
                      rtol=1e-10, atol=1e-10)
    assert ens.failures == {} and ens.stats["executor"] == "processes"
    for tr in ens:
        assert np.abs(tr["x2"] - np.sin(t)).max() < 1e-8
        assert np.abs(tr["x1"] - np.cos(t)).max() < 1e-8
        assert np.abs(tr["z"] + np.sin(t)).max() < 1e-6


def test_local_trajectories_come_through_shared_memory(planar):
    """Forked workers write each trajectory's arrays (x, z, the invariants, the parameters)
    into shared maps (one per chunk): exactly those bytes go that way, the output grid travels by
    reference, a few hundred bytes a trajectory as messages; the trajectories read here are
    bit for bit a serial run's in every column, and stay valid after the ensemble is gone."""
    import gc
    import multiprocessing

    if multiprocessing.get_start_method() != "fork":
        pytest.skip("shared memory needs forked workers")
    some = swing_samples()[:6]
    ser = run(planar, "serial", samples=some)
    loc = run(planar, None, samples=some)
    assert loc.stats["executor"] == "processes" and loc.failures == {}
    n, ninv = T_GRID.size, len(planar.invariant_names)
    per_traj = 8 * (n * (planar.nx + planar.nz + ninv) + int(planar.p.numel()))
    assert loc.stats["shared_bytes"] == len(some) * per_traj
    assert loc.stats["pipe_bytes"] < 1500 * len(some) < loc.stats["shared_bytes"] / 20
    first = loc[0]
    # the grid travels by reference, but each trajectory owns its times (as a serial run's
    # do): none shares memory with another, with the ensemble's grid, or with the caller's
    assert np.array_equal(first.t, T_GRID)
    assert not np.shares_memory(first.t, loc[1].t)
    assert not np.shares_memory(first.t, T_GRID) and not np.shares_memory(loc.t, T_GRID)
    del loc
    gc.collect()
    for name in ser[0].names:
        assert np.array_equal(first[name], ser[0][name]), name
    assert np.array_equal(first.invariants, ser[0].invariants)
    ex = pendulum_planar(T_GRID, THETA0, g=9.81, L=LENGTHS[0])  # and the exact solution
    assert np.abs(first["x"] - ex["x"]).max() < 1e-7 and np.abs(first["y"] - ex["y"]).max() < 1e-7


def test_what_does_not_fit_the_shared_map_takes_the_pipe(planar, monkeypatch):
    """A trajectory longer than its room in the map (events add rows) travels through the
    pipe as before: forced here by leaving no room at all; the results are the same."""
    ens_mod = sys.modules["daekit.ensemble"]
    monkeypatch.setattr(ens_mod, "_sample_bytes", lambda r, n: 64)
    some = swing_samples()[:3]
    loc = run(planar, None, samples=some)
    ser = run(planar, "serial", samples=some)
    assert loc.failures == {} and loc.stats["shared_bytes"] <= 3 * 64
    assert loc.stats["pipe_bytes"] > 8 * T_GRID.size * planar.nx * len(some)
    for a, b in zip(loc, ser, strict=True):
        assert np.array_equal(a["x"], b["x"]) and np.array_equal(a["der(y)"], b["der(y)"])
        assert np.array_equal(a.invariants, b.invariants)
    assert [r["period"] for r in loc.summary()] == [r["period"] for r in ser.summary()]


def test_callable_inputs_and_script_functions_travel_by_value(dask_client, tmp_path):
    """Inputs given as Python functions, and a reduce from a module the workers cannot import
    (as a function of the user's script is to a Dask worker), reach the workers by value:
    lecture L2 driven by u = sin(t) gives x2 = u = sin(t) on a thread pool and on Dask."""
    import importlib
    import os
    from concurrent.futures import ThreadPoolExecutor

    m = dk.examples.l2()
    t = np.linspace(0, 2, 21)
    inp = {"u": lambda t: np.sin(t), "der(u)": lambda t: np.cos(t),
           "der(u,2)": lambda t: -np.sin(t)}
    (tmp_path / "user_reduce_mod.py").write_text(
        "def first_x2(traj):\n    return {'x2_end': float(traj['x2'][-1])}\n")
    sys.path.insert(0, str(tmp_path))
    try:
        mod = importlib.import_module("user_reduce_mod")
    finally:
        sys.path.remove(str(tmp_path))
        os.remove(tmp_path / "user_reduce_mod.py")
        sys.modules.pop("user_reduce_mod", None)
    with ThreadPoolExecutor(2) as pool:
        for ex in (pool, dask_client):
            ens = dk.ensemble(m, t, [{}, {}], executor=ex, inputs=inp, reduce=mod.first_x2,
                              progress=False, rtol=1e-10, atol=1e-10)
            assert ens.failures == {}
            for tr, row in zip(ens, ens.summary(), strict=True):
                assert np.abs(tr["x2"] - np.sin(t)).max() < 1e-8
                assert abs(row["x2_end"] - np.sin(2.0)) < 1e-8


def test_a_sample_replaces_elements_of_the_shared_fixed_values():
    """A sample's "p[0]" replaces that element of a shared fixed "p" (and a sample's "p" a
    shared "p[0]"): the 3D pendulum (L = 1) started at p = (0, 0.6, -0.8) and at
    (0.6, 0, -0.8) is on the rod either way; p[0] = 0 with the shared p[1] = 0, p[2] = -0.8 is
    not, and that sample's failure names the rod."""
    r = dk.reduce_index(dk.examples.pendulum3d())
    t = np.linspace(0, 0.2, 5)
    ens = dk.ensemble(r, t, [{"p[0]": 0.0, "p[1]": 0.6}, {"p[0]": 0.6}, {"p[0]": 0.0}],
                      executor="serial", fixed={"p": [0.6, 0.0, -0.8], "v": [0, 0, 0]},
                      progress=False)
    assert sorted(ens.failures) == [2] and "rod" in ens.failures[2]
    assert np.allclose(ens[0]["p"][0], [0.0, 0.6, -0.8], atol=1e-12)
    assert np.allclose(ens[1]["p"][0], [0.6, 0.0, -0.8], atol=1e-12)
    ens = dk.ensemble(r, t, [{"p": [0.0, 0.0, -1.0]}], executor="serial",
                      fixed={"p[0]": 0.6, "v": [0, 1, 0]}, progress=False)
    assert ens.failures == {} and np.allclose(ens[0]["p"][0], [0, 0, -1], atol=1e-12)


def test_shared_mistakes_are_named_once_before_anything_runs(planar):
    with pytest.raises(dk.ModelError, match="fixed sets 'L', a parameter"):
        dk.ensemble(planar, T_GRID, [{"x": 0.5}], executor="serial", fixed={"L": 2.0})
    with pytest.raises(dk.ModelError, match="guess: .*'xx'"):
        dk.ensemble(planar, T_GRID, [{"x": 0.5}], executor="serial", guess={"xx": 1.0})
    with pytest.raises(dk.ModelError, match="params: .*'LL'"):
        dk.ensemble(planar, T_GRID, [{"x": 0.5}], executor="serial", params={"LL": 2.0})
    with pytest.raises(dk.ModelError, match="needs a system from .*dummy_derivatives"):
        dk.ensemble(planar, T_GRID, [{"x": 0.5}], executor="serial",
                    stabilization="dummy_derivatives")


def test_ocp_sweep_starts_every_sample_from_the_ocps_own_parameters():
    """Cart M s'' = u - c from rest to s = 1, der(s) = 0 in 1 s: u = M s'' + c, and
    int s'' dt = 0, so J = 12 M^2 + c^2; a sample setting M must leave neither the next
    sample (which sets only c: 12.25, not 48.25) nor the caller's OCP with it."""
    m = dk.Model("cart")
    s = m.state("s")
    u = m.control("u")
    M = m.parameter("M", 1.0)
    c = m.parameter("c", 0.0)
    m.equation(M * m.der(s, 2) - u + c, name="newton")
    ocp = dk.OCP(m, t_final=1.0, intervals=10, controls="polynomial")
    ocp.minimize(integral=u**2)
    ocp.initial({"s": 0, "der(s)": 0}).final({"s": 1.0, "der(s)": 0})
    ens = dk.ensemble_ocp(ocp, [{"M": 2.0}, {"c": 0.5}], warm_start=False, progress=False)
    assert [round(row["objective"], 6) for row in ens.summary()] == [48.0, 12.25]
    assert ocp.parameter_values() == {"M": 1.0, "c": 0.0}


def test_a_sample_replaces_a_shared_value_under_another_name_of_the_same_quantity():
    """In the reduced 3D pendulum der(p)[1] is v[1]: a sample's "der(p)[1]" (or "der(p,1)[1]",
    "der(p)") replaces the shared "v[1]" as a sample's "v[1]" does; at rest elsewhere the
    velocity v = (0, 0.5, 0) is tangent at p = (0.6, 0, -0.8) (p . v = 0)."""
    r = dk.reduce_index(dk.examples.pendulum3d())
    t = np.linspace(0, 0.1, 3)
    shared = {"p": [0.6, 0.0, -0.8], "v": [0.0, 0.0, 0.0]}
    for s in ({"der(p)[1]": 0.5}, {"der(p,1)[1]": 0.5}, {"v[1]": 0.5}, {"der(p)": [0, 0.5, 0]}):
        ens = dk.ensemble(r, t, [s], executor="serial", fixed=shared, progress=False)
        assert ens.failures == {}, (s, ens.failures)
        assert np.allclose(ens[0]["v"][0], [0.0, 0.5, 0.0], atol=1e-12)
    with pytest.raises(dk.ModelError, match=r"fixed sets 'v\[1\]' twice \(by 'v\[1\]' and 'v'\)"):
        dk.ensemble(r, t, [{"L": 1.0}], executor="serial",
                    fixed={"p": [0.6, 0, -0.8], "v[1]": 0.5, "v": [0, 0, 0]})


def test_shared_values_and_sample_values_are_checked_before_anything_runs(planar, forbid):
    forbid("daekit.ensemble", "_run_one")
    with pytest.raises(dk.ModelError, match=r"fixed: the value of 'der\(x\)' must be a number"):
        dk.ensemble(planar, T_GRID, [{"L": 1.0}], executor="serial", fixed={"der(x)": "abc"})
    with pytest.raises(dk.ModelError, match=r"'der\(x\)' has 1 element .* 2 values"):
        dk.ensemble(planar, T_GRID, [{"L": 1.0}], executor="serial", fixed={"der(x)": [0, 0]})
    with pytest.raises(dk.ModelError, match="a key of fixed is 0"):
        dk.ensemble(planar, T_GRID, [{"L": 1.0}], executor="serial", fixed={0: 0.0})
    with pytest.raises(dk.ModelError, match="sample 0 sets 'x' to nan, which is not finite"):
        dk.ensemble(planar, T_GRID, [{"x": np.nan}], executor="serial")
    with pytest.raises(dk.ModelError, match=r"^ensemble: stabilization='dummy_derivatives'"):
        dk.ensemble(planar, T_GRID, [{"x": 0.5}], executor="serial",
                    stabilization="dummy_derivatives")


def test_missing_cells_of_a_dataframe_are_names_that_row_does_not_set(planar):
    """pd.DataFrame([{"L": 2.0}, {"g": 4.0}]): row 0 sets L only (g stays 9.81), row 1 g only
    (L stays 1), as the list of those two dicts would."""
    pd = pytest.importorskip("pandas")
    df = pd.DataFrame([{"L": 2.0}, {"g": 4.0}])
    ens = dk.ensemble(planar, np.linspace(0, 0.2, 3), df, executor="serial",
                      guess={"x": 0.5, "y": -0.8}, fixed={"der(x)": 0.0}, progress=False)
    assert ens.failures == {}
    assert ens.samples == [{"L": 2.0}, {"g": 4.0}]
    assert (ens[0]["L"][0], ens[0]["g"][0]) == (2.0, 9.81)
    assert (ens[1]["L"][0], ens[1]["g"][0]) == (1.0, 4.0)
    for tr, L in zip(ens, (2.0, 1.0), strict=True):  # on the rod of its own length
        assert np.allclose(tr["x"] ** 2 + tr["y"] ** 2, L**2, rtol=1e-7)


def test_an_input_that_cannot_be_pickled_is_named():
    import threading
    from concurrent.futures import ThreadPoolExecutor

    lock = threading.Lock()

    def u(t, lock=lock):
        return np.sin(t)

    with ThreadPoolExecutor(1) as pool, pytest.raises(
            dk.ModelError, match=r"input 'u' cannot be pickled \(TypeError"):
        dk.ensemble(dk.examples.l2(), np.linspace(0, 1, 5), [{}], executor=pool,
                    inputs={"u": u, "der(u)": np.cos, "der(u,2)": lambda t: -np.sin(t)})
