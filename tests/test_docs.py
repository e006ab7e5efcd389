"""The README's and the guide's code runs as written."""

import re
from pathlib import Path

import matplotlib
import pytest

matplotlib.use("Agg")
ROOT = Path(__file__).resolve().parents[1]


def python_blocks(path: Path) -> str:
    return "\n".join(re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S))


@pytest.mark.parametrize("doc", ["README.md", "docs/guide.md"])
def test_code_blocks_run(doc):
    code = python_blocks(ROOT / doc)
    assert code.strip(), f"{doc} has no python blocks"
    namespace: dict = {}
    exec(compile(code, doc, "exec"), namespace)  # noqa: S102 - our own documentation
    import matplotlib.pyplot as plt

    plt.close("all")
