"""Error messages name the user's own things (issue: the first hour of a new user)."""

from __future__ import annotations

import pytest

import daekit as dk


def test_unknown_in_no_equation_is_named_without_an_empty_list():
    m = dk.Model("stray")
    x = m.state("x")
    m.algebraic("z")
    m.equation(m.der(x) + x, name="decay")
    with pytest.raises(dk.StructuralError) as err:
        dk.analyze(m)
    text = str(err.value)
    assert "'z' appear in no equation" in text
    assert "equations ," not in text and "1 equation," in text
    assert err.value.underdetermined_variables == ["z"]


def test_baumgarte_warns_not_on_a_model_without_a_rate_of_its_own():
    """A point mass sliding freely on a line (x'' = lam, y'' = lam, x + y = 0): the linearized
    dynamics have only zero eigenvalues, so no pole is 'too fast' for it."""
    import warnings

    import casadi as ca

    m = dk.Model("slider")
    q = m.state("q", 2)
    lam = m.algebraic("lam")
    m.equation(m.der(q, 2) - ca.vertcat(lam, lam), name="newton")
    m.equation(q[0] + q[1], name="line")
    r = dk.reduce_index(m)
    with warnings.catch_warnings():
        warnings.simplefilter("error", dk.BaumgarteStiffnessWarning)
        rb = dk.baumgarte(r, poles=(-50.0, -50.0))
    assert rb.stabilization == "baumgarte"


def test_unknown_idas_option_is_a_daekit_error_naming_it():
    r = dk.reduce_index(dk.examples.pendulum_planar())
    init = dk.initialize(r, fixed={"x": 0.6, "y": -0.8})
    with pytest.raises(dk.InputError, match=r"'max_num_stepz' is not an option.*'max_num_steps'"):
        dk.simulate(r, [0.0, 1.0], init, max_num_stepz=10)


def test_array_initial_state_off_the_manifold_is_refused_by_name():
    import numpy as np

    r = dk.reduce_index(dk.examples.pendulum_planar())  # x = (x, der(x), y, der(y))
    with pytest.raises(dk.InputError, match=r"consistency conditions \(rod = 0\.09"):
        dk.simulate(r, np.linspace(0, 1, 11), np.array([1.0, 0.0, 0.3, 0.0]))
    ok = dk.simulate(r, np.linspace(0, 1, 11), np.array([0.6, 0.0, -0.8, 0.0]))
    assert abs(ok["x"][-1] ** 2 + ok["y"][-1] ** 2 - 1) < 1e-6


def test_misspelt_keyword_in_an_ensemble_is_named_once_before_any_sample_runs():
    r = dk.reduce_index(dk.examples.pendulum_planar())
    with pytest.raises(dk.InputError, match=r"'stabilisation' is not an option"):
        dk.ensemble(r, [0.0, 1.0], [{"L": 1.0}], executor="serial", stabilisation="projection")


def test_a_file_that_is_not_a_trajectory_is_named(tmp_path):
    bad = tmp_path / "x.npz"
    bad.write_text("junk")
    with pytest.raises(dk.ModelError, match=r"x\.npz is not a daekit trajectory"):
        dk.load_trajectory(bad)


def test_a_conflict_names_only_the_condition_the_fixed_values_break():
    # issue 15's snippet: p = (0.6, -0.8) lies on the rod; v = (1, 0) breaks d/dt rod only
    r = dk.reduce_index(dk.examples.pendulum_planar())
    with pytest.raises(dk.InitializationError) as err:
        dk.initialize(r, fixed={"x": 0.6, "y": -0.8, "der(x)": 1.0, "der(y)": 0.0})
    text = str(err.value)
    assert "['d/dt rod']" in text and "d/dt rod = 1.2" in text  # 2 (x x' + y y') = 1.2
    assert "'rod'" not in text and "alg" not in text


def test_an_element_out_of_range_says_how_many_there_are():
    r = dk.reduce_index(dk.examples.pendulum3d())
    with pytest.raises(dk.InitializationError, match=r"'p\[5\]' is out of range: 'p' has 3 "
                                                     r"elements \(p\[0\] \.\. p\[2\]\)"):
        dk.initialize(r, fixed={"p[5]": 1.0})


def test_cli_json_to_stdout_and_numbers_checked_first(tmp_path, capsys):
    import json

    from daekit.cli import main

    assert main(["simulate", "l1", "--t-end", "0.5", "--json", "-"]) == 0
    out = capsys.readouterr()
    data = json.loads(out.out)  # stdout holds the JSON only; the tables went to stderr
    assert data["t"][-1] == pytest.approx(0.5) and "simulated" in out.err
    with pytest.raises(SystemExit, match="--t-end must be a positive number"):
        main(["simulate", "l1", "--t-end", "nan"])
    assert capsys.readouterr().out == ""


def test_rattle_says_that_tolerances_do_not_apply():
    import numpy as np

    sysm = dk.examples.lagrangian_pendulum3d()
    init = {"p": [1.0, 0.0, 0.0], "der(p)": [0.0, 0.0, 0.0]}
    with pytest.warns(UserWarning, match="rtol and atol do not apply; RATTLE takes fixed steps"):
        dk.simulate(sysm, np.linspace(0, 0.1, 3), init, method="rattle", rtol=1e-10)
