"""The results of a sweep: trajectories with events put back on the output times, OCP
ensembles, failed samples, the summary files; and the samples checked before anything runs."""

import matplotlib
import numpy as np
import pytest

import daekit as dk
from daekit.examples.exact import pendulum_wall_impacts
from daekit.examples.impacts import pendulum_wall

matplotlib.use("Agg")

E = 0.8  # restitution of the wall
G = 9.81
LENGTHS = [1.0, 0.7, 1.3]
GRID = np.linspace(0.0, 2.0, 21)


@pytest.fixture(scope="module")
def wall():
    """The pendulum against a wall, released at rest from horizontal: each length has its
    own impact times, so each trajectory has its own rows (two at every impact)."""
    r = dk.reduce_index(pendulum_wall(E))
    return dk.ensemble(r, GRID, [{"L": L, "x": L, "y": 0.0} for L in LENGTHS],
                       executor="serial", fixed={"der(x)": 0.0}, progress=False,
                       rtol=1e-10, atol=1e-10)


@pytest.fixture(scope="module")
def falling():
    """A body falling from x = h, stopped by a terminal event at the floor x = 0 at the
    exact time sqrt(2 h / g)."""
    m = dk.Model("falling")
    x = m.state("x")
    g = m.parameter("g", G)
    m.equation(m.der(x, 2) + g, name="fall")
    m.event(x, name="floor", direction=-1, terminal=True)
    return dk.ensemble(dk.reduce_index(m), np.linspace(0.0, 1.0, 11), {"x": [1.0, 2.0]},
                       executor="serial", fixed={"der(x)": 0.0}, progress=False,
                       rtol=1e-10, atol=1e-10)


def test_events_add_rows_and_values_are_read_at_the_output_times(wall):
    assert not wall.failures
    for i, L in enumerate(LENGTHS):
        tr = wall[i]
        te = np.array([t for t, _ in tr.events])
        assert np.allclose(te, pendulum_wall_impacts(len(te), E, L=L), atol=1e-8)
        assert len(tr.t) == GRID.size + 2 * len(te)  # two rows at every jump
        # every output time is a row of the trajectory; values() takes the last such row
        rows = [np.flatnonzero(tr.t == t)[-1] for t in GRID]
        assert np.array_equal(wall.values("x")[i], tr["x"][rows])
    # against the exact solution: between impacts the energy is e^(2k) g L after k impacts
    vx, vy, y = (wall.values(n) for n in ("der(x)", "der(y)", "y"))
    assert vx.shape == (len(LENGTHS), GRID.size)
    energy = 0.5 * (vx**2 + vy**2) + G * (y + np.array(LENGTHS)[:, None])
    for i, L in enumerate(LENGTHS):
        k = np.searchsorted(pendulum_wall_impacts(10, E, L=L), GRID, side="right")
        assert np.max(np.abs(energy[i] - E ** (2 * k) * G * L)) < 1e-6
    p = wall.percentiles("x", (0, 100))
    assert p.shape == (2, GRID.size)
    assert np.allclose(p, [wall.values("x").min(axis=0), wall.values("x").max(axis=0)])
    fig = wall.plot("x")
    assert np.array_equal(fig.axes[0].lines[0].get_xdata(), GRID)
    assert np.allclose(fig.axes[0].lines[-1].get_ydata(), np.median(wall.values("x"), axis=0))


def test_terminal_event_gives_nan_after_the_stop(falling):
    assert not falling.failures
    t = falling.t
    V = falling.values("x")
    for i, h in enumerate([1.0, 2.0]):
        stop = np.sqrt(2 * h / G)
        assert abs(falling[i].t[-1] - stop) < 1e-8
        before = t <= stop
        assert np.allclose(V[i, before], h - G * t[before] ** 2 / 2, atol=1e-8)
        assert np.all(np.isnan(V[i, ~before]))
    p = falling.percentiles("x", (0, 100))
    assert p.shape == (2, t.size)
    both = t <= np.sqrt(2 / G)  # both falling: min is h = 1, max h = 2
    assert np.allclose(p[:, both], [1 - G * t[both] ** 2 / 2, 2 - G * t[both] ** 2 / 2])
    only = (t > np.sqrt(2 / G)) & (t <= np.sqrt(4 / G))  # only h = 2 still falls
    assert np.allclose(p[:, only], 2 - G * t[only] ** 2 / 2)
    assert np.all(np.isnan(p[:, t > np.sqrt(4 / G)]))
    fig = falling.plot("x")
    assert fig.axes[0].get_title() == "x: 2 of 2 samples"


class _Rows:
    """A stand-in trajectory with given rows (a jump at t = 0.5, a stop at 0.5 or 1)."""

    def __init__(self, t, x):
        self.t, self._x = np.array(t, float), np.array(x, float)

    def __getitem__(self, name):
        return self._x


def test_a_jump_at_an_output_time_gives_the_value_after_it():
    grid = np.array([0.0, 0.5, 1.0])
    res = [{"row": {}, "trajectory": _Rows([0.0, 0.5, 0.5, 1.0], [0.0, 1.0, 2.0, 3.0])},
           {"row": {}, "trajectory": _Rows([0.0, 0.25, 0.5, 0.5], [5.0, 6.0, 7.0, 8.0])}]
    ens = dk.Ensemble([{}, {}], res, grid, "trajectory", {})
    V = ens.values("x")
    assert np.array_equal(V[0], [0.0, 2.0, 3.0])
    assert np.array_equal(V[1, :2], [5.0, 8.0]) and np.isnan(V[1, 2])
    res.append({"row": {}, "trajectory": _Rows([0.0, 0.4, 1.0], [0.0, 1.0, 2.0])})
    with pytest.raises(dk.ModelError, match="do not share one time grid"):
        dk.Ensemble([{}] * 3, res, grid, "trajectory", {}).values("x")


def _cart():
    m = dk.Model("cart")
    s = m.state("s")
    u = m.control("u")
    m.equation(m.der(s, 2) - u, name="newton")
    return m, u


def test_ocp_ensemble_plots_on_the_solutions_grid():
    m, u = _cart()

    def problem(target, T=1.0):
        ocp = dk.OCP(m, t_final=T, intervals=10, controls="polynomial")
        ocp.minimize(integral=u**2)
        return ocp.initial({"s": 0, "der(s)": 0}).final({"s": target, "der(s)": 0})

    ens = dk.ensemble_ocp(problem, {"target": [1.0, 2.0]}, progress=False)
    assert not ens.failures
    t = ens[0].t
    assert np.array_equal(ens.grid, t)
    # the minimum-energy transfer in time 1: s = target (3 t^2 - 2 t^3), exact for cubics
    exact = np.outer([1.0, 2.0], 3 * t**2 - 2 * t**3)
    assert np.allclose(ens.values("s"), exact, atol=1e-8)
    fig = ens.plot("s")
    assert np.allclose(fig.axes[0].lines[-1].get_ydata(), exact.mean(axis=0), atol=1e-8)
    other = dk.ensemble_ocp(problem, [{"target": 1.0}, {"target": 1.0, "T": 2.0}],
                            progress=False)
    with pytest.raises(dk.ModelError, match="do not share one time grid.*ens\\[i\\].t"):
        other.plot("s")


def test_a_sample_whose_reduce_raises_is_none_and_left_out(wall):
    r = wall.system

    def reduce(traj):
        if traj["L"][0] > 1.2:
            raise ValueError("too long")
        return {"x_end": float(traj["x"][-1])}

    ens = dk.ensemble(r, GRID, [{"L": L, "x": L, "y": 0.0} for L in LENGTHS],
                      executor="serial", fixed={"der(x)": 0.0}, progress=False,
                      reduce=reduce, rtol=1e-10, atol=1e-10)
    assert sorted(ens.failures) == [2] and "too long" in ens.failures[2]
    assert ens[2] is None and ens[0] is not None and list(ens)[2] is None
    V = ens.values("x")
    assert np.all(np.isnan(V[2])) and np.array_equal(V[:2], wall.values("x")[:2])
    assert ens.plot("x").axes[0].get_title() == "x: 2 of 3 samples (1 failed)"


def test_plot_of_a_vector_on_given_axes():
    import matplotlib.pyplot as plt

    r = dk.reduce_index(dk.examples.pendulum3d())
    ens = dk.ensemble(r, np.linspace(0, 0.2, 11), [{"g": 9.81}, {"g": 5.0}], executor="serial",
                      fixed={"p": [0.6, 0.0, -0.8], "v": [0.0, 1.0, 0.0]}, progress=False)
    fig, ax = plt.subplots()
    with pytest.raises(dk.ModelError, match="'p' has 3 elements.*a sequence of 3 axes"):
        ens.plot("p", ax=ax)
    fig, axes = plt.subplots(3, 1)
    assert ens.plot("p", ax=axes) is fig
    assert np.allclose(axes[2].lines[-1].get_ydata(), np.median(ens.values("p")[:, :, 2], axis=0))
    plt.close("all")


def test_summary_files_upper_case_and_missing_vectors_null(tmp_path, monkeypatch):
    rows = [{"row": {"L": 1.0, "success": True, "error": "", "w": [1.0, 2.0]}},
            {"row": {"L": 2.0, "success": False, "error": "boom", "w": float("nan")},
             "error": "boom"}]
    ens = dk.Ensemble([{"L": 1.0}, {"L": 2.0}], rows, GRID, "summary", {})
    import pandas as pd

    pq = ens.save_summary(tmp_path / "S.PARQUET")
    back = pd.read_parquet(pq)
    assert list(back["w"][0]) == [1.0, 2.0] and back["w"][1] is None
    csv = ens.save_summary(tmp_path / "S.CSV")
    assert pd.read_csv(csv, index_col="sample")["L"].tolist() == [1.0, 2.0]
    with pytest.raises(dk.ModelError, match="the folder .*nodir.* does not exist"):
        ens.save_summary(tmp_path / "nodir" / "s.csv")
    with pytest.raises(dk.ModelError, match=".csv or a .parquet"):
        ens.save_summary(tmp_path / "s.txt")
    monkeypatch.setitem(__import__("sys").modules, "pyarrow", None)
    with pytest.raises(dk.ModelError, match="Parquet needs pandas and pyarrow"):
        dk.Ensemble.summary_format(tmp_path / "s.parquet")


# ----------------------------------------------------------------------------------------------
# the samples, checked before anything runs
@pytest.fixture(scope="module")
def pendulum3d():
    return dk.reduce_index(dk.examples.pendulum3d())


FIXED = {"p": [0.6, 0.0, -0.8], "v": [0.0, 1.0, 0.0]}


@pytest.fixture
def nothing_runs(forbid):
    """initialize fails the test: the checks must come before any sample runs."""
    forbid("daekit.initialize", "initialize")


@pytest.mark.parametrize("samples, message", [
    ([{"L": 1.0}, {"L": "abc"}], r"sample 1 sets 'L' to 'abc', which is not a number"),
    ([{0: 1.0}], r"a key of sample 0 is 0 \(of type int\); the keys are daekit names"),
    ([{"L": [[1.0], 1.5]}], r"sample 0 sets 'L' to \[\[1.0\], 1.5\], which is not a number"),
    ([{"p": [[0.6, 0.0, -0.8]]}], r"sample 0 sets 'p' to .*flat list of numbers"),
    ({"L": [1.0, "x"]}, r"samples\['L'\] is \[1.0, 'x'\], which is not one number"),
    ({"L": [[1.0], 1.5]}, r"samples\['L'\] is .*which is not one number"),
    ({1: [1.0, 2.0]}, r"a key of the dict of samples is 1"),
])
def test_bad_sample_values_are_named_before_anything_runs(pendulum3d, nothing_runs, samples,
                                                          message):
    with pytest.raises(dk.ModelError, match=message):
        dk.ensemble(pendulum3d, np.linspace(0, 0.1, 3), samples, executor="serial",
                    fixed=FIXED, progress=False)


def test_a_dataframe_of_samples_one_per_row(pendulum3d):
    import pandas as pd

    df = pd.DataFrame({"m": [1.0, 2.0]})
    ens = dk.ensemble(pendulum3d, np.linspace(0, 0.1, 3), df, executor="serial", fixed=FIXED,
                      progress=False)
    assert not ens.failures and ens.samples == [{"m": 1.0}, {"m": 2.0}]
    # m der(v) = -m g e3 - z p: the motion does not depend on the mass, z is proportional to it
    assert np.allclose(ens[1]["p"], ens[0]["p"], atol=1e-9)
    assert np.allclose(ens[1]["z"], 2 * ens[0]["z"], rtol=1e-6)
    with pytest.raises(dk.ModelError, match="a column of the DataFrame of samples is 0"):
        dk.ensemble(pendulum3d, np.linspace(0, 0.1, 3), pd.DataFrame({0: [1.0]}),
                    executor="serial", progress=False)


def test_inputs_and_unknown_names_as_sample_keys(pendulum3d, nothing_runs):
    t = np.linspace(0, 0.1, 3)
    with pytest.raises(dk.ModelError, match=r"sample 0 sets 'u\[0\]', an input of the model; "
                                            r"give inputs with inputs=\{\.\.\.\}"):
        dk.ensemble(pendulum3d, t, [{"u[0]": 1.0}], executor="serial", fixed=FIXED)
    with pytest.raises(dk.ModelError, match=r"sample 1 sets 'u', an input"):
        dk.ensemble(pendulum3d, t, [{"L": 1.0}, {"u": [0.0, 0.0, 1.0]}], executor="serial")
    with pytest.raises(dk.ModelError) as err:
        dk.ensemble(pendulum3d, t, [{"q": 1.0}], executor="serial", fixed=FIXED)
    msg = str(err.value)
    # the variables listed in full (no "..."), without the parameters and inputs
    assert msg.endswith("parameter (L, g, m) nor a variable of the model "
                        "(p, der(p), der(p,2), v, der(v), z)")
    with pytest.raises(dk.ModelError, match=r"^ensemble: fixed sets 'pp', which is neither"):
        dk.ensemble(pendulum3d, t, [{"L": 1.0}], executor="serial", fixed={"pp": 1.0})
    with pytest.raises(dk.ModelError, match=r"fixed sets 'u\[1\]', an input of the model"):
        dk.ensemble(pendulum3d, t, [{"L": 1.0}], executor="serial", fixed={"u[1]": 1.0})


def test_a_long_list_of_variables_is_cut_with_dots():
    m = dk.Model("many")
    for k in range(14):
        m.state(f"x{k}")
    for k in range(14):
        m.equation(m.der(m.variables[f"x{k}"].sym) + m.variables[f"x{k}"].sym, name=f"e{k}")
    r = dk.reduce_index(m)
    with pytest.raises(dk.ModelError, match=r"\(x0, der\(x0\), .*\.\.\.\)$"):
        dk.ensemble(r, [0.0, 1.0], [{"y": 1.0}], executor="serial")
