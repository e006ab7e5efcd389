"""The README's and the guide's code runs as written."""

import re
from pathlib import Path

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
ROOT = Path(__file__).resolve().parents[1]


def python_blocks(path: Path) -> str:
    return "\n".join(re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S))


def run(doc: str) -> dict:
    code = python_blocks(ROOT / doc)
    assert code.strip(), f"{doc} has no python blocks"
    namespace: dict = {}
    exec(compile(code, doc, "exec"), namespace)  # noqa: S102 - our own documentation
    import matplotlib.pyplot as plt

    plt.close("all")
    return namespace


def test_readme_runs_and_says_true_things():
    ns = run("README.md")
    assert (ns["a"].index, ns["a"].dof) == (3, 4)  # "a.index == 3, a.dof == 4"
    r = ns["r"]
    assert r.x_names == ["p[0]", "p[1]", "p[2]", "v[0]", "v[1]", "v[2]"]  # x = (p, v)
    assert r.invariant_names == ["rod", "d/dt rod"]
    p = ns["traj"]["p"]
    # projection: on the rod within drift_tol (100 atol = 1e-6; the rod is |p|^2 / 2 - 1 / 2)
    assert ns["traj"].stats["drift_tol"] == 1e-6
    assert np.max(np.abs(np.sum(p * p, axis=1) - 1.0)) < 2e-6


def test_guide_runs_and_says_true_things():
    ns = run("docs/guide.md")
    a = ns["a"]
    assert (a.index, a.dof, a.structurally_ok) == (3, 4, True)
    assert a.equation_offsets["rod"] == 2
    assert ns["init"]["p"][0] == 0.6
    sol = ns["sol"]
    assert sol.success and sol.objective == pytest.approx(15.4575, abs=1e-3)
    assert sol["p"].shape == (91, 3)
