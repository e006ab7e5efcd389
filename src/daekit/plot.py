"""Static figures of trajectories (matplotlib): variables over time and the lecture's drift plot.

``traj.plot()`` and ``traj.plot_invariants()`` delegate here. Both return the matplotlib
``Figure`` (nothing is shown; call ``fig.savefig(...)`` or ``plt.show()``).

Example
-------
>>> import numpy as np, matplotlib
>>> matplotlib.use("Agg")
>>> from daekit.simulate import Trajectory
>>> from daekit.plot import plot_invariants
>>> t = np.linspace(0, 1, 5)
>>> tr = Trajectory(t, {"x": t}, np.c_[1e-9 * t, 1e-8 * t], ["rod", "d/dt rod"])
>>> len(plot_invariants(tr).axes)
2
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["plot_trajectory", "plot_invariants", "plot_overview", "plot_structure",
           "invariant_order", "REMEDY_COLORS", "remedy_color", "Plane", "best_plane",
           "plot_in_plane", "STRUCTURE_LEGEND"]

_ORDER_RE = re.compile(r"^d(\d*)/dt(\d*)\s+(.*)$")

#: One colour per remedy against drift, the same in every figure and animation of daekit
#: (the tour's drift figures, its positions figure and its drift animation).
REMEDY_COLORS: dict[str, str] = {
    "none": "tab:red",
    "Baumgarte": "tab:orange",
    "projection": "tab:blue",
    "GGL": "tab:purple",
    "dummy derivatives": "tab:green",
    "RATTLE": "tab:brown",
}

_REMEDY_ALIASES = {
    "no stabilization": "none", "unstabilized": "none", "baumgarte": "Baumgarte",
    "ggl": "GGL", "dummy_derivatives": "dummy derivatives", "rattle": "RATTLE",
}


def remedy_color(label: str | None) -> str:
    """The colour of a remedy in :data:`REMEDY_COLORS`, from a table label or a
    ``stabilization`` name: ``"Baumgarte (-1, -1)"``, ``"baumgarte"``, ``"RATTLE (h = 0.005)"``,
    ``None`` (no stabilization). Unknown labels get black.

    >>> remedy_color("Baumgarte (-1, -1)"), remedy_color("dummy_derivatives"), remedy_color(None)
    ('tab:orange', 'tab:green', 'tab:red')
    """
    if label is None:
        return REMEDY_COLORS["none"]
    key = str(label).split(" (")[0].strip()
    key = _REMEDY_ALIASES.get(key, _REMEDY_ALIASES.get(key.lower(), key))
    return REMEDY_COLORS.get(key, "k")


def invariant_order(name: str) -> tuple[int, str]:
    """``"rod"`` -> ``(0, "rod")``, ``"d/dt rod"`` -> ``(1, "rod")``, ``"d2/dt2 rod"`` -> 2."""
    m = _ORDER_RE.match(name.strip())
    if not m:
        return 0, name
    k = int(m.group(1) or 1)
    return k, m.group(3)


def _figure(ax, nrows: int = 1, height: float = 3.0):
    import matplotlib.pyplot as plt

    if ax is not None:
        axes = list(np.atleast_1d(ax).ravel())
        return axes[0].figure, axes
    fig, axs = plt.subplots(nrows, 1, figsize=(7, height * nrows), sharex=True, squeeze=False)
    return fig, list(axs[:, 0])


def plot_trajectory(traj, names: Iterable[str] | str | None = None, ax=None):
    """Plot variables of a :class:`~daekit.simulate.Trajectory` over time, one panel per name.

    Parameters
    ----------
    traj : Trajectory
    names : str or list of str, optional
        Original names (``"p"``, ``"p[0]"``, ``"der(p)"``, ``"z"``); by default the variables
        without derivatives in their name (the positions), at most six.
    ax : matplotlib Axes or array of Axes, optional
        Where to draw; all names go to one Axes when a single Axes is given.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if isinstance(names, str):
        names = [names]
    if names is None:
        names = [n for n in traj.names if not n.startswith("der(")][:6] or traj.names[:6]
    names = list(names)
    single = ax is not None and np.ndim(ax) == 0
    fig, axes = _figure(ax if not single else [ax], 1 if single else max(len(names), 1), 2.2)
    for k, name in enumerate(names):
        a = axes[0] if single else axes[k]
        vals = traj[name]
        if vals.ndim == 1:
            a.plot(traj.t, vals, label=name)
        else:
            for j in range(vals.shape[1]):
                a.plot(traj.t, vals[:, j], label=f"{name}[{j}]")
        if not single:
            a.set_ylabel(name)
        if vals.ndim > 1 or single:
            a.legend(loc="best", fontsize="small")
        a.grid(True, alpha=0.3)
    axes[-1 if not single else 0].set_xlabel("t")
    fig.tight_layout()
    return fig


def plot_overview(traj, exclude: Iterable[str] = (), floor: float = 1e-17):
    """Every variable of ``traj`` (its own panel each, derivatives and the names in
    ``exclude``, e.g. the parameters, left out), then the invariants ``|c|`` on a log scale,
    one panel per derivative level. What ``daekit simulate --plot`` draws.

    >>> import numpy as np, matplotlib
    >>> matplotlib.use("Agg")
    >>> from daekit.simulate import Trajectory
    >>> t = np.linspace(0, 1, 5)
    >>> tr = Trajectory(t, {"x": t, "y": -t, "der(x)": 1 + 0 * t, "L": 1 + 0 * t},
    ...                 np.c_[1e-9 * t, 1e-8 * t], ["rod", "d/dt rod"])
    >>> [a.get_ylabel() for a in plot_overview(tr, exclude=["L"]).axes]
    ['x', 'y', '|c|', "|c'|"]
    """
    import matplotlib.pyplot as plt

    skip = set(exclude)
    names = [n for n in traj.names if not n.startswith("der(") and n not in skip]
    levels: dict[int, list[int]] = {}
    for j, n in enumerate(traj.invariant_names):
        levels.setdefault(invariant_order(n)[0], []).append(j)
    order = sorted(levels)
    rows = max(len(names) + len(order), 1)
    fig, axs = plt.subplots(rows, 1, figsize=(7.5, 1.9 * rows + 0.5), sharex=True, squeeze=False)
    axes = list(axs[:, 0])
    for a, name in zip(axes, names, strict=False):
        vals = traj[name]
        if vals.ndim == 1:
            a.plot(traj.t, vals, lw=1.2)
        else:
            for j in range(vals.shape[1]):
                a.plot(traj.t, vals[:, j], lw=1.2, label=f"{name}[{j}]")
            a.legend(loc="upper right", fontsize="small", ncol=min(vals.shape[1], 4))
        a.set_ylabel(name)
        a.grid(True, alpha=0.3)
    title = {0: "|c|", 1: "|c'|", 2: "|c''|"}
    for a, lvl in zip(axes[len(names):], order, strict=False):
        for j in levels[lvl]:
            a.semilogy(traj.t, np.maximum(np.abs(traj.invariants[:, j]), floor), lw=1.0,
                       label=traj.invariant_names[j])
        a.set_ylabel(title.get(lvl, f"|c^({lvl})|"))
        a.grid(True, which="both", alpha=0.3)
        if len(levels[lvl]) <= 8:
            a.legend(loc="upper right", fontsize="small")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    return fig


def plot_invariants(traj, axes=None, floor: float = 1e-17):
    """The lecture's drift figure: ``|c|`` (position level) and ``|c'|`` (velocity level), and
    higher levels if present, over time on logarithmic scales, one panel per derivative level.

    Invariants named ``"rod"``, ``"d/dt rod"``, ``"d2/dt2 rod"`` go to levels 0, 1, 2. Values
    below ``floor`` are drawn at ``floor`` (exact zeros have no logarithm).

    Returns
    -------
    matplotlib.figure.Figure
    """
    levels: dict[int, list[int]] = {}
    for j, n in enumerate(traj.invariant_names):
        levels.setdefault(invariant_order(n)[0], []).append(j)
    if not levels:
        fig, axs = _figure(axes, 1)
        axs[0].text(0.5, 0.5, "no invariants", ha="center", va="center",
                    transform=axs[0].transAxes)
        return fig
    order = sorted(levels)
    fig, axs = _figure(axes, len(order))
    title = {0: "|c|", 1: "|c'|", 2: "|c''|"}
    for a, lvl in zip(axs, order, strict=False):
        for j in levels[lvl]:
            vals = np.maximum(np.abs(traj.invariants[:, j]), floor)
            a.semilogy(traj.t, vals, label=traj.invariant_names[j])
        a.set_ylabel(title.get(lvl, f"|c^({lvl})|"))
        a.grid(True, which="both", alpha=0.3)
        if len(levels[lvl]) <= 8:
            a.legend(loc="best", fontsize="small")
    axs[-1].set_xlabel("t")
    stab = traj.stats.get("stabilization") if traj.stats else None
    axs[0].set_title(f"constraint drift ({stab or 'no stabilization'})")
    fig.tight_layout()
    return fig


@dataclass
class Plane:
    """The plane a 3D path lies in (:func:`best_plane`): ``project(points)`` gives in-plane
    coordinates along ``basis`` (2 x 3, orthonormal) from ``origin``; ``normal``; ``labels`` of
    the two in-plane axes; ``out_of_plane`` the largest distance of a point from the plane;
    ``name`` e.g. ``"y = 0"`` for a coordinate plane.

    >>> pl = best_plane([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    >>> pl.name, pl.project([[2.0, 3.0, 0.0]]).tolist()
    ('z = 0', [[2.0, 3.0]])
    """

    origin: np.ndarray
    basis: np.ndarray
    normal: np.ndarray
    labels: tuple[str, str]
    out_of_plane: float
    name: str

    def project(self, points: ArrayLike) -> np.ndarray:
        """In-plane coordinates ``(N, 2)`` of points ``(N, 3)``."""
        return (np.asarray(points, dtype=float) - self.origin) @ self.basis.T


def best_plane(points: ArrayLike, names: tuple[str, str, str] = ("x", "y", "z"),
               snap: float = 1e-6) -> Plane:
    """The least-squares plane through 3D ``points`` (rows), from their singular value
    decomposition. When its normal is within ``snap`` (radians, about) of a coordinate axis,
    the plane is that coordinate plane and the in-plane coordinates are the other two
    coordinates themselves (``names``), so that the axes of a plot read ``x`` and ``z``.

    >>> import numpy as np
    >>> a = np.linspace(-0.5, 0.5, 9)
    >>> pl = best_plane(np.column_stack([np.sin(a), 0 * a, -np.cos(a)]))
    >>> pl.name, pl.labels, bool(pl.out_of_plane < 1e-15)
    ('y = 0', ('x', 'z'), True)
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    centre = p.mean(axis=0)
    _, sv, vt = np.linalg.svd(p - centre, full_matrices=True)
    normal = vt[2]
    k = int(np.argmax(np.abs(normal)))
    if abs(abs(normal[k]) - 1.0) < snap:
        keep = [j for j in range(3) if j != k]
        basis = np.eye(3)[keep]
        normal = np.eye(3)[k]
        level = float(np.mean(p[:, k]))
        level = 0.0 if abs(level) < 1e-12 * max(1.0, float(np.abs(p).max())) else level
        dist = float(np.max(np.abs(p[:, k] - level))) if p.size else 0.0
        return Plane(np.zeros(3), basis, normal, (names[keep[0]], names[keep[1]]), dist,
                     f"{names[k]} = {level:.4g}")
    basis = vt[:2]
    dist = float(np.max(np.abs((p - centre) @ normal))) if p.size else 0.0

    def along(v):
        return "along (" + ", ".join(f"{c:.2f}" for c in v) + ")"

    return Plane(centre, basis, normal, (along(basis[0]), along(basis[1])), dist,
                 "normal (" + ", ".join(f"{c:.2f}" for c in normal) + ")")


def plot_in_plane(points: ArrayLike, ax: Any = None, unit: str = "m",
                  names: tuple[str, str, str] = ("x", "y", "z"), **line_kw: Any) -> tuple[Any, Plane]:
    """Draw a 3D path in the plane it lies in (:func:`best_plane`), with equal scales.

    Returns ``(figure, plane)``; project other points with ``plane.project``.

    >>> import numpy as np, matplotlib
    >>> matplotlib.use("Agg")
    >>> a = np.linspace(-0.5, 0.5, 9)
    >>> fig, pl = plot_in_plane(np.column_stack([np.sin(a), 0 * a, -np.cos(a)]))
    >>> fig.axes[0].get_xlabel(), fig.axes[0].get_ylabel()
    ('x [m]', 'z [m]')
    """
    import matplotlib.pyplot as plt

    plane = best_plane(points, names)
    if ax is None:
        fig, ax = plt.subplots(figsize=(4.5, 4.5))
    else:
        fig = ax.figure
    q = plane.project(points)
    ax.plot(q[:, 0], q[:, 1], **line_kw)
    ax.set_xlabel(f"{plane.labels[0]} [{unit}]")
    ax.set_ylabel(f"{plane.labels[1]} [{unit}]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    return fig, plane


#: The one line under :func:`plot_structure`'s figure that says what ``c``, ``d`` and the
#: transversal are.
STRUCTURE_LEGEND = (
    "c = times the equation is differentiated;  d = highest derivative of the unknown;  "
    "transversal (boxed) = one cell per row and column, largest sum"
)


def plot_structure(analysis, ax=None, max_size: int = 60):
    """Draw the Sigma matrix of an :class:`~daekit.analysis.Analysis`.

    Each cell shows the highest derivative order of an unknown (column) in an equation (row);
    the highest-value transversal is boxed; the equation offsets ``c`` (how often each equation
    is differentiated) stand on the right, the variable offsets ``d`` (the highest derivative
    needed) on top; cells on the system Jacobian (``sigma_ij = d_j - c_i``) are shaded. Systems
    with more than ``max_size`` equations are drawn as a sparsity pattern without labels.

    >>> import matplotlib; matplotlib.use("Agg")
    >>> import daekit as dk
    >>> fig = dk.analyze(dk.examples.l3()).plot_structure()
    >>> fig.axes[0].get_title()[:12]
    'Sigma matrix'
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    eqs = list(analysis.equation_offsets)
    vars_ = list(analysis.variable_offsets)
    ri = {e: i for i, e in enumerate(eqs)}
    cj = {v: j for j, v in enumerate(vars_)}
    n = len(eqs)
    own = ax is None
    if own:
        size = min(0.45 * n + 2.5, 12.0)
        fig, ax = plt.subplots(figsize=(max(size + 1.5, 8.0), size + 0.3))
    else:
        fig = ax.figure
    c = analysis.equation_offsets
    d = analysis.variable_offsets
    if n > max_size:
        rows = [ri[e] for e, _, _ in analysis.sigma]
        cols = [cj[v] for _, v, _ in analysis.sigma]
        ax.scatter(cols, rows, s=max(0.5, 200.0 / n), marker="s", color="0.2")
        ax.set_xlim(-0.5, n - 0.5)
        ax.set_ylim(n - 0.5, -0.5)
        ax.set_title(f"Sigma matrix of {analysis.model_name!r}: {n} equations")
        return fig
    matched = set(analysis.transversal.items())
    for e, v, k in analysis.sigma:
        i, j = ri[e], cj[v]
        on_jac = k == d[v] - c[e]
        ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, color="#cfe3f5" if on_jac else "#f2f2f2"))
        ax.text(j, i, str(k), ha="center", va="center", fontsize=9,
                weight="bold" if (e, v) in matched else "normal")
        if (e, v) in matched:
            ax.add_patch(Rectangle((j - 0.42, i - 0.42), 0.84, 0.84, fill=False, lw=1.5,
                                   color="#c0392b"))
    ax.set_xlim(-0.5, n - 0.5)
    ax.set_ylim(n - 0.5, -0.5)
    ax.set_xticks(range(n))
    ax.set_xticklabels([f"{v}\nd={d[v]}" for v in vars_], rotation=90, fontsize=8)
    ax.xaxis.tick_top()
    ax.set_yticks(range(n))
    ax.set_yticklabels(eqs, fontsize=8)
    sec = ax.secondary_yaxis("right")
    sec.set_yticks(range(n))
    sec.set_yticklabels([f"c={c[e]}" for e in eqs], fontsize=8)
    ax.set_title(f"Sigma matrix of {analysis.model_name!r}: index {analysis.index}, "
                 f"DOF {analysis.dof}\n(cell: highest derivative of the unknown in the equation; "
                 "shaded: on the system Jacobian, cell = d - c)", fontsize=10, pad=12)
    ax.set_aspect("equal")
    if own:
        legend = fig.text(0.5, 0.012, STRUCTURE_LEGEND, ha="center", va="bottom", fontsize=8)
        try:  # shrink the one line until it fits the figure's width
            width = legend.get_window_extent(fig.canvas.get_renderer()).width
            room = 0.97 * fig.get_figwidth() * fig.dpi
            if width > room:
                legend.set_fontsize(8 * room / width)
        except (AttributeError, RuntimeError):  # a backend without a renderer: keep 8 pt
            pass
        fig.tight_layout(rect=(0, 0.035, 1, 1))
    else:
        fig.tight_layout()
    return fig
