"""The package's layering: what ``import daekit`` costs, and what may import what."""

from __future__ import annotations

import subprocess
import sys


def test_import_daekit_loads_neither_matplotlib_nor_the_examples():
    code = (
        "import sys, daekit\n"
        "print('matplotlib' in sys.modules, 'daekit.examples' in sys.modules)\n"
        "daekit.examples.pendulum_planar()\n"
        "print('daekit.examples' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False", "True"]
