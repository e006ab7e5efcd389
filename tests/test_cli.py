"""The command line: analyze, reduce, simulate, tour (issue 2 item 6, issue 3 item 6, issue 4)."""

import json
import textwrap

import numpy as np
import pytest

from daekit.cli import main
from daekit.examples import exact

PENDULUM_FILE = textwrap.dedent('''
    import casadi as ca
    import daekit as dk

    def model():
        return dk.examples.pendulum3d()

    def planar():
        m = dk.Model("planar")
        x = m.state("x"); y = m.state("y"); T = m.algebraic("T")
        m.equation(m.der(x, 2) - x * T, name="newton_x")
        m.equation(m.der(y, 2) - (y * T - 9.81), name="newton_y")
        m.equation(x**2 + y**2 - 1, name="rod")
        return m

    def not_a_model():
        return 42
''')


@pytest.fixture
def model_file(tmp_path):
    f = tmp_path / "pend.py"
    f.write_text(PENDULUM_FILE)
    return f


def test_analyze_json(model_file, capsys):
    assert main(["analyze", f"{model_file}:planar", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["index"] == 3 and d["structural_index"] == 3 and d["dof"] == 2
    assert d["structurally_ok"] is True
    assert d["equation_offsets"] == {"newton_x": 0, "newton_y": 0, "rod": 2}
    assert d["variable_offsets"] == {"x": 2, "y": 2, "T": 0}


def test_analyze_default_function_and_text(model_file, capsys):
    assert main(["analyze", str(model_file)]) == 0
    out = capsys.readouterr().out
    assert "Differential index 3" in out and "Degrees of freedom: 4" in out


def test_analyze_builtin_example(capsys):
    assert main(["analyze", "gear_petzold", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["structurally_ok"] is False and d["index"] == 2 and d["dof"] == 0


def test_errors_are_reported_not_raised(model_file, tmp_path, capsys):
    assert main(["analyze", f"{model_file}:nope"]) == 2
    assert "has no function 'nope'" in capsys.readouterr().err
    assert main(["analyze", f"{model_file}:not_a_model"]) == 2
    assert "expected a daekit.Model" in capsys.readouterr().err
    assert main(["analyze", str(tmp_path / "missing.py")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_reduce_prints_invariants_and_selection(model_file, capsys):
    assert main(["reduce", f"{model_file}:planar"]) == 0
    out = capsys.readouterr().out
    assert "rod" in out and "d/dt rod" in out
    assert main(["reduce", f"{model_file}:planar", "--method", "dummy_derivatives"]) == 0
    out = capsys.readouterr().out
    assert "State selection" in out


def test_simulate_matches_exact_pendulum(model_file, tmp_path, capsys):
    out_json = tmp_path / "traj.json"
    out_png = tmp_path / "traj.png"
    fixed = json.dumps({"x": 1.0, "der(x)": 0.0})  # case B: theta0 = pi/2, released at rest
    guess = json.dumps({"y": 0.0, "der(y)": 0.0})
    assert main(["simulate", f"{model_file}:planar", "--t-end", "1", "--points", "11",
                 "--fixed", fixed, "--guess", guess, "--rtol", "1e-10", "--atol", "1e-10",
                 "--json", str(out_json), "--plot", str(out_png), "--quiet"]) == 0
    data = json.loads(out_json.read_text())
    ref = exact.pendulum_planar(np.array([1.0]), np.pi / 2, g=9.81, L=1.0)
    assert data["values"]["x"][-1] == pytest.approx(float(np.ravel(ref["x"])[0]), abs=1e-7)
    assert data["values"]["y"][-1] == pytest.approx(float(np.ravel(ref["y"])[0]), abs=1e-7)
    assert out_png.stat().st_size > 1000
    assert "max |invariant|" in capsys.readouterr().out


def test_simulate_bad_json(model_file, capsys):
    assert main(["simulate", f"{model_file}:planar", "--t-end", "1", "--fixed", "{x: 1"]) == 2
    assert "not valid JSON" in capsys.readouterr().err


def test_tour_short_run(tmp_path, capsys):
    """The tour's story holds even on a short run: drift without stabilization, none with the
    remedies; the figures are written."""
    from daekit.tour import run_tour

    rows = run_tour(out=tmp_path, t_end=5.0, quiet=True, ocp=False)  # default: no GIFs
    out = capsys.readouterr().out
    assert "Differential index 3" in out and "Figures written to" in out
    by = {(r.system, r.remedy.split(" (")[0]): r for r in rows}
    none = by["pendulum", "none"]
    assert none.max_c > 1e-8  # the index-1 form drifts at rtol = atol = 1e-6
    assert by["pendulum", "Baumgarte"].max_c < none.max_c
    assert by["pendulum", "GGL"].max_c < 1e-5 and by["delta robot", "GGL"].max_c < 1e-5
    for remedy in ("projection", "dummy derivatives", "RATTLE"):
        assert by["pendulum", remedy].max_c < 1e-9
        assert by["delta robot", remedy].max_c < 1e-9
    assert (tmp_path / "pendulum3d_drift.png").exists()
    assert (tmp_path / "delta_robot_drift.png").exists()
    assert (tmp_path / "pendulum3d_structure.png").exists()
    assert not list(tmp_path.glob("*.gif"))


def test_tour_ocp_section(tmp_path, capsys):
    """The tour's optimal control part: the crane's minimum time and the periodic pendulum,
    solved with the redundant periodicity conditions dropped, failing when all are imposed."""
    from daekit.tour import _ocp_section

    _ocp_section(tmp_path, progress=False)
    out = capsys.readouterr().out
    assert "success=True, minimum time T = 1.97" in out
    assert "dropped as implied by the others and the invariants: initial p[2]" in out
    assert "naive (all conditions imposed): success=False" in out
    assert (tmp_path / "crane_ocp.png").exists()
    assert (tmp_path / "pendulum3d_periodic_ocp.png").exists()


def test_simulate_with_input_expression_l2(tmp_path, capsys):
    """Lecture L2 driven by u = sin t: x2 = u, x1 = u', z = u'' (input derivatives from the
    expression)."""
    out_json = tmp_path / "l2.json"
    assert main(["simulate", "l2", "--t-end", "2", "--points", "5", "--input", "u=sin(t)",
                 "--json", str(out_json), "--quiet", "--rtol", "1e-10", "--atol", "1e-10"]) == 0
    data = json.loads(out_json.read_text())
    t = np.array(data["t"])
    assert np.allclose(data["values"]["x2"], np.sin(t), atol=1e-8)
    assert np.allclose(data["values"]["x1"], np.cos(t), atol=1e-8)
    assert np.allclose(data["values"]["z"], -np.sin(t), atol=1e-6)
    assert main(["simulate", "l2", "--t-end", "1", "--input", "u=sin(", "--quiet"]) == 2
    assert "cannot evaluate" in capsys.readouterr().err


def test_analyze_plot(tmp_path, capsys):
    png = tmp_path / "sigma.png"
    assert main(["analyze", "pendulum3d", "--plot", str(png)]) == 0
    assert png.stat().st_size > 5000


SCRIPT_FILE = textwrap.dedent('''
    import casadi as ca
    import daekit as dk

    m = dk.Model("planar")
    p = m.state("p", 2); v = m.state("v", 2); lam = m.algebraic("lam")
    m.equation(m.der(p) == v, name="kin")
    m.equation(m.der(v) == -lam * p - ca.vertcat(0, 9.81), name="newton")
    m.equation(ca.dot(p, p) == 1, name="rod")
''')


@pytest.mark.parametrize("tail, target", [
    ("", ""),                       # the one model the script builds at top level
    ("model = m\n", ""),            # a variable named model (not a function)
    ("other = 3\n", ":m"),          # a model named explicitly
    ("from daekit import LagrangianSystem, Model\n", ""),  # imported classes are no models
])
def test_a_script_that_builds_its_model_at_top_level(tmp_path, capsys, tail, target):
    f = tmp_path / "script.py"
    f.write_text(SCRIPT_FILE + tail)
    assert main(["analyze", f"{f}{target}", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["index"] == 3 and d["dof"] == 2


def test_a_script_with_two_models_asks_which(tmp_path, capsys):
    f = tmp_path / "two.py"
    f.write_text(SCRIPT_FILE + "m2 = dk.examples.pendulum3d()\n")
    assert main(["analyze", str(f)]) == 2
    assert "models: m, m2 (name one:" in capsys.readouterr().err


# ----------------------------------------------------------------------------------------------
# sweep: what can be checked is checked before the first sample runs
SWEEP = ["sweep", "pendulum_planar", "--param", "L=0.5:2.0:3", "--t-end", "0.5", "--points",
         "11", "--guess", '{"x": 0.5, "y": -0.5}', "--fixed", '{"der(x)": 0}', "--quiet",
         "--serial"]


@pytest.fixture
def no_sweep(forbid):
    """daekit.ensemble.ensemble fails the test: the sweep must not start."""
    forbid("daekit.ensemble", "ensemble")


@pytest.mark.parametrize("out, message", [
    ("s.txt", r"--out .*s\.txt: write a \.csv or a \.parquet file"),
    ("nodir/s.csv", r"--out .*nodir/s\.csv: the folder '.*nodir' does not exist"),
])
def test_sweep_checks_the_output_file_first(tmp_path, capsys, no_sweep, out, message):
    rc = main([*SWEEP, "--out", str(tmp_path / out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("daekit: error: --out") and "Traceback" not in err
    assert __import__("re").search(message, err)


def test_sweep_parquet_without_pyarrow_is_refused_first(tmp_path, capsys, no_sweep,
                                                        monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pyarrow", None)  # import pyarrow raises ImportError
    rc = main([*SWEEP, "--out", str(tmp_path / "s.parquet")])
    err = capsys.readouterr().err
    assert rc == 2 and "Parquet needs pandas and pyarrow" in err and "Traceback" not in err


def test_sweep_bad_scheduler_and_seed_are_daekit_errors(tmp_path, capsys, no_sweep):
    rc = main([*SWEEP[:-1], "--scheduler", "nonsense", "--out", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("daekit: error: --scheduler nonsense: cannot connect")
    rc = main([*SWEEP[:2], *SWEEP[4:], "--draw", "g=uniform:9:10", "--seed", "-1",
               "--out", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "seed must be a non-negative integer" in err


def test_sweep_upper_case_extension(tmp_path, capsys):
    out = tmp_path / "S.CSV"
    assert main([*SWEEP, "--out", str(out)]) == 0
    import pandas as pd

    df = pd.read_csv(out, index_col="sample")
    assert np.allclose(df["L"], [0.5, 1.25, 2.0]) and df["success"].all()
