"""The first hour of a new user (issue 15, items 1, 3, 4 and the CLI parts of 6): entry points
accept what people pass, terminal output and files that fit, results people can keep."""

import json
import textwrap

import matplotlib
import numpy as np
import pytest

import daekit as dk
from daekit.cli import main
from daekit.examples.exact import pendulum_planar

matplotlib.use("Agg")
TH = np.pi / 3


# ---------------------------------------------------------------- 1. accept what people pass
def test_simulate_and_initialize_accept_an_unreduced_model():
    m = dk.examples.pendulum_planar()
    init = dk.initialize(m, fixed={"x": np.sin(TH), "der(x)": 0.0}, guess={"y": -0.5})
    assert "reduced automatically" in init.notes[0]
    t = np.linspace(0, 2, 201)
    traj = dk.simulate(m, t, init, rtol=1e-10, atol=1e-10)
    assert "reduced automatically" in traj.stats["reduced"]
    ex = pendulum_planar(t, TH)
    assert np.abs(traj["x"] - ex["x"]).max() < 1e-7 and np.abs(traj["T"] - ex["T"]).max() < 1e-6
    # the same model object is reduced once: initialize and simulate share the reduction
    from daekit.reduction import as_reduced

    r1 = as_reduced(m, "a")
    assert r1 is as_reduced(m, "b")
    m.parameter("extra", 1.0)  # a changed model is reduced again
    r2 = as_reduced(m, "c")
    assert r2 is not r1 and "extra" in r2.p_names and "extra" not in r1.p_names


def test_lagrangian_system_accepted_everywhere():
    ls = dk.examples.lagrangian_pendulum3d()
    assert dk.analyze(ls).index == 3
    r = dk.reduce_index(ls)
    assert r.invariant_names == ["rod", "d/dt rod"]
    # released at rest from 60 degrees in the x-z plane: the planar pendulum's exact motion
    fixed = {"p": [np.sin(TH), 0.0, -np.cos(TH)], "der(p)": [0.0, 0.0, 0.0]}
    t = np.linspace(0, 1, 101)
    ex = pendulum_planar(t, TH)
    traj = dk.simulate(ls, t, dk.initialize(ls, fixed=fixed), rtol=1e-10, atol=1e-10)
    assert np.abs(traj["p[0]"] - ex["x"]).max() < 1e-7
    assert "index1() form" in traj.stats["reduced"]
    rat = dk.simulate(ls, t, fixed, method="rattle", dt=1e-3)
    assert np.abs(rat["p[0]"] - ex["x"]).max() < 1e-4  # RATTLE is of order 2


def test_stabilizers_format_and_ocp_accept_models_too():
    m = dk.examples.pendulum_planar()
    rb = dk.baumgarte(m, poles=(-5.0, -5.0))
    assert rb.stabilization == "baumgarte" and "reduced automatically" in rb.info["notes"][0]
    t = np.linspace(0, 1, 101)
    init = dk.initialize(rb, fixed={"x": np.sin(TH), "der(x)": 0.0}, guess={"y": -0.5})
    tr = dk.simulate(rb, t, init, rtol=1e-10, atol=1e-10)
    assert np.abs(tr["x"] - pendulum_planar(t, TH)["x"]).max() < 1e-7
    assert dk.ggl(m).index == 2
    assert dk.format_reduced(m).startswith("pendulum_planar reduced by differentiate")
    ocp = dk.OCP(dk.examples.lagrangian_pendulum3d(), t_final=1.0, intervals=5)
    assert ocp is not None


def test_rattle_on_a_model_says_what_it_needs():
    m = dk.examples.pendulum_planar()
    with pytest.raises(dk.ModelError, match=r"method='rattle'\) needs a mechanical system.*"
                       r"LagrangianSystem"):
        dk.simulate(m, np.linspace(0, 1, 11), {}, method="rattle")


def test_other_objects_get_a_clear_error():
    with pytest.raises(dk.ModelError, match="simulate needs a daekit.ReducedDAE"):
        dk.simulate(42, np.linspace(0, 1, 3), {})


# ---------------------------------------------------------------- 4. results people can keep
def test_free_is_an_ordered_list_of_the_free_values_only():
    r = dk.reduce_index(dk.examples.pendulum3d())
    init = dk.initialize(r, guess={"p": [0.6, 0, -0.8]}, fixed={"v[1]": 1.0, "p[0]": 0.6})
    assert init.dof == 4 and init.fixed == ["v[1]", "p[0]"]
    assert "p[0]" not in init.free and "v[1]" not in init.free and len(init.free) == 2
    assert init.free == [n for n in r.x_names if n in init.free]  # state order
    assert set(init.free) | {"p[0]", "v[1]"} == set(init.dof_names)
    # fixing the reported free values too pins the state: the solution does not move
    more = dk.initialize(r, guess={"p": [0.6, 0, -0.8]},
                         fixed={"v[1]": 1.0, "p[0]": 0.6, **{n: init[n] for n in init.free}})
    assert more.free == [] and np.allclose(more.x0, init.x0, atol=1e-12)


@pytest.mark.parametrize("ext", ["npz", "parquet"])
def test_trajectory_save_load_lossless(tmp_path, ext):
    ls = dk.examples.lagrangian_pendulum3d()
    fixed = {"p": [np.sin(TH), 0.0, -np.cos(TH)], "der(p)": [0.0, 0.3, 0.0]}
    traj = dk.simulate(ls, np.linspace(0, 0.5, 51), fixed, method="rattle", dt=1e-2)
    traj.events = [(0.25, "wall"), (0.4, "rest")]  # extra data comes back as it was
    path = traj.save(tmp_path / f"run.{ext}")
    back = dk.load_trajectory(path)
    assert np.array_equal(back.t, traj.t) and list(back.values) == list(traj.values)
    for k in traj.values:
        assert np.array_equal(back.values[k], traj.values[k])
    assert np.array_equal(back.invariants, traj.invariants)
    assert back.invariant_names == traj.invariant_names
    assert back.events == traj.events
    assert set(back.stats) == set(traj.stats)
    for k, v in traj.stats.items():
        if isinstance(v, np.ndarray):
            assert np.array_equal(back.stats[k], v) and back.stats[k].dtype == v.dtype
        else:
            assert back.stats[k] == v or (v != v and back.stats[k] != back.stats[k])
    if ext == "parquet":
        import pandas as pd

        df = pd.read_parquet(path)  # any Parquet reader sees the plain table
        assert list(df.columns[:2]) == ["t", list(traj.values)[0]]
        assert np.array_equal(df["invariant:rod"].to_numpy(), traj.invariant("rod"))


def test_load_trajectory_errors(tmp_path):
    with pytest.raises(dk.ModelError, match="no such file"):
        dk.load_trajectory(tmp_path / "none.npz")
    tr = dk.Trajectory(np.arange(3.0), {"x": np.arange(3.0)})
    with pytest.raises(dk.ModelError, match=".parquet .pyarrow. or a .npz"):
        tr.save(tmp_path / "x.txt")
    np.savez(tmp_path / "other.npz", a=np.zeros(2), meta=np.array('{"format": "other"}'))
    with pytest.raises(dk.ModelError, match="not a daekit trajectory"):
        dk.load_trajectory(tmp_path / "other.npz")


# ---------------------------------------------------------------- 6. bad input, named
def test_initialize_rejects_nan_time_and_names_parameters():
    r = dk.reduce_index(dk.examples.pendulum_planar())
    with pytest.raises(dk.InitializationError, match="t0 must be a finite number"):
        dk.initialize(r, t0=float("nan"))
    with pytest.raises(dk.InitializationError, match=r"L is a parameter.*use params=\{'L': 2\}"):
        dk.initialize(r, fixed={"L": 2})


BAD_FILES = {
    "syntax.py": "import daekit as dk\ndef model(:\n    return 1\n",
    "raises.py": textwrap.dedent("""\
        import daekit as dk

        def model():
            m = dk.Model("broken")
            return m.stat("x")
        """),
    "import_fails.py": "import daekit as dk\nraise RuntimeError('no licence server')\n",
}


@pytest.mark.parametrize("name, expect", [
    ("syntax.py", r"syntax\.py, line 2: syntax error"),
    ("raises.py", r"raises\.py, line 5: model\(\) raised AttributeError: .*stat"),
    ("import_fails.py", r"import_fails\.py, line 2: running the file raised RuntimeError: "
                        "no licence server"),
])
def test_cli_user_file_errors_without_traceback(tmp_path, capsys, name, expect):
    f = tmp_path / name
    f.write_text(BAD_FILES[name])
    assert main(["analyze", str(f)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    import re

    assert re.search(expect, err), err


# ---------------------------------------------------------------- 3. terminal output and files
def test_cli_simulate_prints_initial_values_and_free(tmp_path, capsys):
    out_json = tmp_path / "t.json"
    assert main(["simulate", "pendulum_planar", "--t-end", "1", "--points", "11",
                 "--fixed", '{"x": 0.8660254037844386, "der(x)": 0}', "--guess", '{"y": -0.5}',
                 "--rtol", "1e-10", "--atol", "1e-10", "--json", str(out_json), "--quiet"]) == 0
    out = capsys.readouterr().out
    head = out.split("simulated")[0]
    assert "initial values at t = 0" in head
    lines = {ln.split("=")[0].strip(): ln for ln in head.splitlines()[1:] if "=" in ln}
    assert lines["x"].rstrip().endswith("fixed") and lines["der(x)"].rstrip().endswith("fixed")
    assert lines["y"].rstrip().endswith("determined")
    assert float(lines["y"].split("=")[1].split()[0]) == pytest.approx(-0.5, abs=1e-12)
    data = json.loads(out_json.read_text())
    assert data["parameters"] == {"g": 9.81, "L": 1.0}
    assert "L" not in data["values"] and "g" not in data["values"]
    ex = pendulum_planar(np.array(data["t"]), TH)
    assert np.abs(np.array(data["values"]["x"]) - ex["x"]).max() < 1e-7
    assert "parameters: g = 9.81, L = 1" in out


def test_cli_simulate_without_fixed_says_so(capsys):
    assert main(["simulate", "pendulum_planar", "--t-end", "0.5", "--points", "6",
                 "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "no --fixed/--guess given" in out and "free" in out


def test_overview_plot_variables_then_invariants_never_parameters():
    from daekit.plot import plot_overview

    r = dk.reduce_index(dk.examples.planar_chain(4))
    t = np.linspace(0, 0.2, 21)
    traj = dk.simulate(r, t, dk.initialize(r, guess={"q": [1, 0, 2, 0, 3, 0, 4, 0]}))
    fig = plot_overview(traj, exclude=r.p_names)
    labels = [a.get_ylabel() for a in fig.axes]
    variables = [n for n in traj.names if not n.startswith("der(") and n not in r.p_names]
    assert labels[:len(variables)] == variables
    assert labels[len(variables):] == ["|c|", "|c'|"]
    assert not set(r.p_names) & set(labels)
    assert fig.axes[-1].get_yscale() == "log"


def test_cli_analyze_json_has_conditions_inputs_explanation(capsys):
    assert main(["analyze", "l2", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["input_derivatives"] == {"u": 2}
    assert d["consistency_conditions"] and "Differential index" in d["explanation"]
    assert main(["analyze", "pendulum_planar", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["consistency_conditions"] == ["rod", "d/dt rod"] and d["index"] == 3


def test_cli_reduce_json(capsys):
    assert main(["reduce", "pendulum_planar", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["states"] == ["x", "der(x)", "y", "der(y)"]
    assert d["invariant_names"] == ["rod", "d/dt rod"] and d["parameters"]["L"] == 1.0
    assert d["ode"]["x"] == "der(x)"
    assert main(["reduce", "pendulum_planar", "--json", "--method", "dummy_derivatives"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["method"] == "dummy_derivatives" and "state_selection" in d
