"""Benchmark: what ``import daekit`` costs against ``import casadi, numpy, scipy.sparse``.

Each side is imported in a fresh interpreter with ``python -X importtime``; the cost of a run
is the sum of the cumulative times of its top-level imports (what the interpreter spent
importing, without its own start-up). Both sides alternate, ``REPEAT`` times, and the median
of each is reported with their ratio (issue 16's target: at most 1.3x). Bytecode is written
and used as in a normal installation (``PYTHONDONTWRITEBYTECODE`` is removed for the
children; one warm-up run compiles daekit's modules first).

The table also lists the largest top-level imports of ``import daekit`` and says whether
matplotlib, the examples or SciPy's linear algebra were loaded (they must not be).

Run: ``python benchmarks/import_time.py``
"""

from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys

REPEAT = 7
DEFERRED = ("matplotlib", "daekit.examples", "scipy.linalg", "scipy.sparse.linalg",
            "scipy.sparse.csgraph", "pandas", "dask")
LINE = re.compile(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)")


def import_cost(code: str) -> tuple[float, dict[str, float], list[str]]:
    """(total seconds of the top-level imports, {module: cumulative seconds} of every import,
    the modules of ``DEFERRED`` that were loaded) of running ``code`` in a fresh interpreter."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    probe = code + f"; import sys; print([m for m in {DEFERRED!r} if m in sys.modules])"
    out = subprocess.run([sys.executable, "-X", "importtime", "-c", probe], capture_output=True,
                         text=True, env=env, check=True)
    total, every = 0.0, {}
    for line in out.stderr.splitlines():
        m = LINE.match(line)
        if m:
            every[m.group(4)] = int(m.group(2)) * 1e-6
            if len(m.group(3)) == 1:  # a top-level import
                total += int(m.group(2)) * 1e-6
    loaded = eval(out.stdout.strip().splitlines()[-1])  # noqa: S307 - our own printed list
    return total, every, loaded


def main() -> None:
    import_cost("import daekit")  # warm-up: writes daekit's bytecode
    ours, base = [], []
    for _ in range(REPEAT):
        ours.append(import_cost("import daekit")[0])
        base.append(import_cost("import casadi, numpy, scipy.sparse")[0])
    t_ours, t_base = statistics.median(ours), statistics.median(base)
    _, every, loaded = import_cost("import daekit")
    print(f"median of {REPEAT} fresh interpreters each")
    print(f"{'import':38s} {'ms':>8s}")
    print(f"{'casadi, numpy, scipy.sparse':38s} {1e3 * t_base:8.1f}")
    print(f"{'daekit':38s} {1e3 * t_ours:8.1f}")
    print(f"ratio daekit / (casadi, numpy, scipy.sparse): {t_ours / t_base:.2f} (target <= 1.3)")
    print(f"deferred modules loaded by 'import daekit': {loaded or 'none'}")
    own = sorted(((v, k) for k, v in every.items() if k.startswith("daekit.")), reverse=True)
    print("largest daekit modules (cumulative ms):",
          ", ".join(f"{k} {1e3 * v:.1f}" for v, k in own[:6]))


if __name__ == "__main__":
    main()
