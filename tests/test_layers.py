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


def test_import_daekit_defers_scipy_linear_algebra():
    """SciPy loads ``scipy.linalg``, ``scipy.sparse.linalg`` and ``scipy.sparse.csgraph``
    (about 70 ms together) on first attribute access; daekit reaches them only as
    ``scipy.linalg.*`` / ``sp.linalg.*`` / ``sp.csgraph.*`` inside functions, so that
    ``import daekit`` costs little more than CasADi, NumPy and ``scipy.sparse``."""
    code = (
        "import sys, daekit\n"
        "print(sorted(m for m in ('scipy.linalg', 'scipy.sparse.linalg', 'scipy.sparse.csgraph')"
        " if m in sys.modules))\n"
        "m = daekit.Model('m'); x = m.state('x'); m.equation(m.der(x) + x)\n"
        "daekit.analyze(m)\n"
        "print('scipy.sparse.csgraph' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["[]", "True"]


def _module_graph():
    """daekit's import graph from the source (``ast``; imports inside functions included):
    ``{module: {imported daekit module}}`` and the ``(module, target, name)`` of every
    ``from target import _name`` across modules."""
    import ast
    from pathlib import Path

    import daekit

    root = Path(daekit.__file__).parent
    mods = {}
    for f in root.rglob("*.py"):
        parts = list(f.relative_to(root.parent).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        mods[".".join(parts[:-1] if is_pkg else parts)] = (f, is_pkg)
    edges: dict[str, set[str]] = {m: set() for m in mods}
    private = []
    for name, (f, is_pkg) in mods.items():
        base = name.split(".") if is_pkg else name.split(".")[:-1]
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    target = ".".join(base[: len(base) - node.level + 1]
                                      + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if not target.startswith("daekit"):
                    continue
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    to = sub if sub in mods else target
                    edges[name].add(to)
                    if to == target and alias.name.startswith("_") and not alias.name.startswith("__"):
                        private.append((name, target, alias.name))
            elif isinstance(node, ast.Import):
                edges[name].update(a.name for a in node.names if a.name.startswith("daekit."))
    return mods, edges, private


def test_no_import_cycle_and_no_private_names_across_modules():
    mods, edges, private = _module_graph()

    def ancestors(m):
        p = m.split(".")
        return {".".join(p[:i]) for i in range(1, len(p))}

    # a package's __init__ importing its own submodules is not a cycle; a submodule importing
    # its package's __init__ is the usual relative import of a sibling
    graph = {m: {t for t in edges[m] if t in mods and t != m and t not in ancestors(m)}
             for m in mods}
    state: dict[str, int] = {}
    cycles = []

    def visit(v, path):
        state[v] = 1
        for w in sorted(graph[v]):
            if state.get(w) == 1:
                cycles.append(path[path.index(w):] + [w])
            elif w not in state:
                visit(w, path + [w])
        state[v] = 2

    for v in sorted(graph):
        if v not in state:
            visit(v, [v])
    assert cycles == [], f"import cycles: {cycles}"
    assert private == [], f"private names imported across modules: {private}"


def test_casadi_buffers_are_bound_in_numerics_only():
    """One place per concern: a CasADi Function's raw buffers (``Function.buffer()``) are
    bound only by ``numerics`` (``fast_call``, ``FastFunction``); every other module calls
    those (found by the AST: any ``.buffer()`` call)."""
    import ast
    from pathlib import Path

    import daekit

    root = Path(daekit.__file__).parent
    found = []
    for f in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr == "buffer"):
                found.append(f"{f.relative_to(root)}:{node.lineno}")
    assert found and all(x.startswith("numerics.py:") for x in found), found
