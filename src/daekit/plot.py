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

import numpy as np

__all__ = ["plot_trajectory", "plot_invariants", "plot_overview", "plot_structure", "invariant_order"]

_ORDER_RE = re.compile(r"^d(\d*)/dt(\d*)\s+(.*)$")


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
    if ax is None:
        size = min(0.45 * n + 2.5, 12.0)
        fig, ax = plt.subplots(figsize=(size + 1.5, size))
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
                 f"DOF {analysis.dof}\n(boxed: transversal; shaded: system Jacobian)",
                 fontsize=10, pad=12)
    ax.set_aspect("equal")
    fig.tight_layout()
    return fig
