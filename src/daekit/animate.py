"""Animations of planar and spatial mechanisms, saved as GIF (matplotlib + Pillow).

Three drawings, each fed with plain arrays of positions over time, so they work with any
simulation (daekit's, or your own):

- :func:`animate_pendulum`: a rod from the pivot (the origin) to the bob, planar ``(N, 2)``
  or spatial ``(N, 3)`` positions, with a fading trail of the bob.
- :func:`animate_chain`: a planar chain of point masses hanging from the origin, positions
  ``(N, 2K)`` (``x1, y1, x2, y2, ...``) or ``(N, K, 2)``.
- :func:`animate_delta_robot`: the delta robot of lecture L4. Arm ``k`` turns about a horizontal
  axis at distance ``r`` from the vertical axis, at azimuth ``gamma_k = (0, 2pi/3, 4pi/3)``;
  its elbow is ``p_k = R_z(gamma_k) [r + a cos alpha_k, 0, -a sin alpha_k]``; rods of length
  ``L`` join the elbows to the platform point ``p``.

:func:`animate` dispatches on ``mechanism`` and reads the arrays off a trajectory by name
(``traj["p"]``, ``traj["alpha"]``, ``traj["q"]``) or takes them from a dict.

- :func:`animate_drift`: several runs of the same pendulum side by side, above a strip chart
  of their rod lengths ``|p - pivot|`` over time: constraint drift made visible (the rod of an
  unstabilized index-1 run stretches or shrinks, a stabilized one keeps its length).

At most ``max_frames`` frames (150 by default) are drawn, evenly spread over the time grid;
the GIF plays at ``fps`` frames per second. With ``real_time=True`` the frames are the grid
points nearest to ``t0, t0 + 1/fps, ...`` instead, so the GIF plays in real time (GIF delays are
whole hundredths of a second: 20, 25 or 50 fps are exact). Frames are ``pixels`` square (480 by
default). Only the moving parts are redrawn per frame (blitting), so a 480-pixel frame costs a
few milliseconds. A file name ending in ``.png`` saves one still frame (``frame``, default the
middle one) instead: handy to check a drawing.

Example
-------
>>> import numpy as np, os, tempfile
>>> from daekit.animate import animate_pendulum
>>> t = np.linspace(0, 2, 41)
>>> th = 0.5 * np.cos(3.1 * t)
>>> p = np.column_stack([np.sin(th), -np.cos(th)])
>>> out = animate_pendulum(t, p, os.path.join(tempfile.mkdtemp(), "pend.gif"), max_frames=10)
>>> out.n_frames
10
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .errors import DaekitError, ModelError

__all__ = [
    "AnimationResult",
    "animate",
    "animate_pendulum",
    "animate_chain",
    "animate_delta_robot",
    "animate_drift",
    "delta_robot_points",
]

GAMMA = (0.0, 2.0 * math.pi / 3.0, 4.0 * math.pi / 3.0)


@dataclass
class AnimationResult:
    """What an ``animate_*`` call wrote: ``path``, ``n_frames`` and the ``frames`` (indices
    into the time grid)."""

    path: Path
    n_frames: int
    frames: np.ndarray

    def __fspath__(self) -> str:
        return str(self.path)


# ------------------------------------------------------------------------------------- helpers


def _check_arrays(t: Any, arrays: dict[str, tuple[Any, tuple]]) -> tuple[np.ndarray, dict]:
    """Validate ``t`` (N,) and each array's shape (None = any) against N; return floats."""
    tt = np.asarray(t, dtype=float).ravel()
    if tt.size < 1 or not np.all(np.isfinite(tt)):
        raise ModelError("animate: t must be a non-empty array of finite times")
    out = {}
    for name, (arr, tail) in arrays.items():
        a = np.asarray(arr, dtype=float)
        if a.ndim == 1 and len(tail) == 1:
            a = a.reshape(-1, 1) if tail[0] in (None, 1) else a
        if a.shape[0] != tt.size:
            raise ModelError(
                f"animate: {name} has {a.shape[0]} rows but there are {tt.size} time points; "
                "give one row per time point"
            )
        if len(tail) + 1 != a.ndim or any(s is not None and s != d for s, d in
                                          zip(tail, a.shape[1:], strict=False)):
            want = ", ".join("any" if s is None else str(s) for s in tail)
            raise ModelError(
                f"animate: {name} has shape {a.shape}; expected (N, {want}) with N = {tt.size}"
            )
        if not np.all(np.isfinite(a)):
            k = int(np.argmax(~np.isfinite(a).reshape(a.shape[0], -1).all(axis=1)))
            raise ModelError(
                f"animate: {name} is not finite at t = {tt[k]:g} (row {k}); animate only the "
                "part of the trajectory before the failure"
            )
        out[name] = a
    return tt, out


def _frames(n: int, max_frames: int, t: np.ndarray | None = None, fps: float | None = None
            ) -> np.ndarray:
    """Indices of the frames: ``max_frames`` evenly spread, or (``t`` and ``fps`` given) the
    grid points nearest to the times ``t0, t0 + 1/fps, ...`` (the GIF then plays in real time;
    ``max_frames`` is not applied)."""
    if max_frames < 1:
        raise ModelError(f"animate: max_frames must be at least 1, got {max_frames}")
    if t is not None and fps is not None:
        if not fps > 0:
            raise ModelError(f"animate: fps must be positive, got {fps}")
        if n > 1 and np.any(np.diff(t) < 0):
            raise ModelError("animate: real_time needs increasing times t")
        want = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * fps + 1e-9)) + 1) / fps
        idx = np.clip(np.searchsorted(t, want), 1, max(n - 1, 1)) if n > 1 else np.zeros(1, int)
        if n > 1:
            idx = np.where(np.abs(t[idx - 1] - want) <= np.abs(t[idx] - want), idx - 1, idx)
        return np.unique(idx.astype(int))
    k = min(n, int(max_frames))
    return np.unique(np.round(np.linspace(0, n - 1, k)).astype(int))


def _figure(three_d: bool, pixels: int = 480):
    """A ``pixels`` x ``pixels`` figure (80 dpi) with one Axes, on its own Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if pixels < 16:
        raise ModelError(f"animate: pixels must be at least 16, got {pixels}")
    fig = Figure(figsize=(pixels / 80.0, pixels / 80.0), dpi=80)
    FigureCanvasAgg(fig)
    if three_d:
        fig.subplots_adjust(left=0.0, right=0.94, bottom=0.04, top=0.96)
    ax = fig.add_subplot(projection="3d") if three_d else fig.add_subplot()
    return fig, ax


def _limits(points: np.ndarray, pad: float = 0.1) -> tuple[np.ndarray, float]:
    """Centre and half-width of a cube (or square) holding all ``points`` (rows)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = 0.5 * float(np.max(hi - lo))
    half = half * (1 + pad) if half > 0 else 1.0
    return centre, half


def _set_limits(ax, centre: np.ndarray, half: float, three_d: bool, unit: str = "m") -> None:
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    if three_d:
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_box_aspect((1, 1, 1))
        from matplotlib.ticker import MaxNLocator

        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(5))
        ax.set_xlabel(f"x [{unit}]")
        ax.set_ylabel(f"y [{unit}]")
        ax.set_zlabel(f"z [{unit}]")
    else:
        ax.set_aspect("equal")
        ax.set_xlabel(f"x [{unit}]")
        ax.set_ylabel(f"y [{unit}]")
        ax.grid(True, alpha=0.3)


def _set_line(line, pts: np.ndarray, three_d: bool) -> None:
    line.set_data(pts[:, 0], pts[:, 1])
    if three_d:
        line.set_3d_properties(pts[:, 2])


def _past(frames: np.ndarray, k: int, trail: int) -> np.ndarray:
    """The grid indices of the trail ending at ``k`` (``k`` included): every grid point from the
    frame ``trail`` frames back up to ``k`` (so that the trail is smooth between frames)."""
    prior = frames[frames < k][-trail:] if trail > 0 else frames[:0]
    start = int(prior[0]) if prior.size else int(k)
    return np.arange(start, int(k) + 1)


def _floor_shadow(ax, z: float):
    """A grey line on the floor plane ``z`` (for the 3D trails: depth is easier to read)."""
    line, = ax.plot([], [], [], "-", color="0.6", lw=1, alpha=0.8)

    def put(pts: np.ndarray) -> None:
        flat = pts.copy()
        flat[:, 2] = z
        _set_line(line, flat, True)

    return line, put


def _write(fig, update, frames: np.ndarray, filename: Any, fps: float, frame: int | None):
    """Draw the frames and write a GIF (or one PNG still).

    ``update(k)`` moves the artists to time index ``k`` and returns every artist it changes.
    The static part of the figure (axes, panes, grid, fixed lines) is drawn once; each frame
    only redraws the changing artists over it (blitting on the Agg canvas), and Pillow writes
    the frames with one shared palette: about 5 ms a frame at 480 x 480 instead of ~100 ms
    for a full redraw and an own palette per frame.
    """
    path = Path(filename)
    if path.parent and not path.parent.exists():
        raise DaekitError(f"animate: the folder {str(path.parent)!r} does not exist; create it")
    suffix = path.suffix.lower()
    if suffix not in (".png", ".gif"):
        raise DaekitError(
            f"animate: cannot write {path.name!r}: give a file name ending in .gif (the "
            "animation) or .png (one still frame)"
        )
    if not fps > 0:
        raise ModelError(f"animate: fps must be positive, got {fps}")
    if suffix == ".png":
        k = int(frames[len(frames) // 2]) if frame is None else int(frame)
        update(k)
        fig.savefig(path)
        return AnimationResult(path, 1, np.array([k]))
    from PIL import Image

    canvas = fig.canvas
    moving = [a for a in update(int(frames[0])) if a is not None]
    for a in moving:
        a.set_animated(True)
    canvas.draw()  # everything but the moving artists
    background = canvas.copy_from_bbox(fig.bbox)
    rgb = []
    for k in frames:
        canvas.restore_region(background)
        update(int(k))
        for a in moving:
            (a.axes or fig).draw_artist(a)
        rgb.append(np.asarray(canvas.buffer_rgba())[:, :, :3].copy())
    # one palette for all frames, taken from the first, middle and last frame together
    sample = np.vstack([rgb[0], rgb[len(rgb) // 2], rgb[-1]])
    palette = Image.fromarray(sample).quantize(colors=255, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(a).quantize(palette=palette, dither=Image.Dither.NONE) for a in rgb]
    # GIF delays are in hundredths of a second: 20 or 25 fps are exact, others are rounded
    images[0].save(path, save_all=True, append_images=images[1:],
                   duration=max(int(round(1000.0 / fps)), 10), loop=0)
    return AnimationResult(path, len(frames), frames)


# ------------------------------------------------------------------------------------ pendulum


def animate_pendulum(
    t: Any,
    p: Any,
    filename: Any = "pendulum.gif",
    *,
    pivot: Any = None,
    fps: float = 20,
    max_frames: int = 150,
    trail: int = 30,
    frame: int | None = None,
    title: str = "pendulum",
    pixels: int = 480,
    real_time: bool = False,
    unit: str = "m",
) -> AnimationResult:
    """Animate a pendulum: a rod from ``pivot`` (default the origin) to the bob at ``p``.

    ``p`` is ``(N, 2)`` (planar, ``y`` up) or ``(N, 3)`` (spatial, ``z`` up). ``trail`` frames
    of the bob's past path are drawn. Returns an :class:`AnimationResult`.
    """
    p = np.asarray(p, dtype=float)
    tt, arr = _check_arrays(t, {"p": (p, (None,))})
    p = arr["p"]
    dim = p.shape[1]
    if dim not in (2, 3):
        raise ModelError(f"animate_pendulum: p must have 2 or 3 columns, got {dim}")
    piv = np.zeros(dim) if pivot is None else np.asarray(pivot, dtype=float).ravel()
    three_d = dim == 3
    frames = _frames(tt.size, max_frames, tt if real_time else None, fps)
    fig, ax = _figure(three_d, pixels)
    centre, half = _limits(np.vstack([p, piv[None, :]]))
    _set_limits(ax, centre, half, three_d, unit)
    rod, = ax.plot([], [], *([[]] if three_d else []), "-", color="0.2", lw=2)
    bob, = ax.plot([], [], *([[]] if three_d else []), "o", color="tab:red", ms=10)
    path, = ax.plot([], [], *([[]] if three_d else []), "-", color="tab:blue", lw=1, alpha=0.6)
    ax.plot(*[[v] for v in piv], "s", color="k", ms=5)
    if three_d:
        floor = centre[2] - half
        shadow_line, shadow = _floor_shadow(ax, floor)
        drop, = ax.plot([], [], [], ":", color="0.5", lw=1)
    head = ax.set_title(title)

    def update(k: int):
        _set_line(rod, np.vstack([piv, p[k]]), three_d)
        _set_line(bob, p[k : k + 1], three_d)
        past = _past(frames, k, trail)
        _set_line(path, p[past], three_d)
        if three_d:
            shadow(p[past])
            _set_line(drop, np.array([p[k], [p[k, 0], p[k, 1], floor]]), True)
        head.set_text(f"{title}, t = {tt[k]:.2f} s")
        return (rod, bob, path, head) + ((shadow_line, drop) if three_d else ())

    return _write(fig, update, frames, filename, fps, frame)


# --------------------------------------------------------------------------------------- chain


def animate_chain(
    t: Any,
    xy: Any,
    filename: Any = "chain.gif",
    *,
    pivot: Any = (0.0, 0.0),
    fps: float = 20,
    max_frames: int = 150,
    trail: int = 20,
    frame: int | None = None,
    title: str = "chain",
    pixels: int = 480,
    real_time: bool = False,
    unit: str = "m",
) -> AnimationResult:
    """Animate a planar chain of point masses hanging from ``pivot``.

    ``xy``: ``(N, 2K)`` with columns ``x1, y1, x2, y2, ...`` (the coordinates ``q`` of
    :func:`daekit.examples.mechanisms.lagrangian_planar_chain`) or ``(N, K, 2)``. The last
    mass leaves a trail. Returns an :class:`AnimationResult`.
    """
    a = np.asarray(xy, dtype=float)
    if a.ndim == 2:
        if a.shape[1] % 2:
            raise ModelError(
                f"animate_chain: xy has {a.shape[1]} columns; give x1, y1, x2, y2, ... (an even "
                "number) or an (N, K, 2) array"
            )
        a = a.reshape(a.shape[0], -1, 2)
    tt, arr = _check_arrays(t, {"xy": (a, (None, 2))})
    a = arr["xy"]
    piv = np.asarray(pivot, dtype=float).ravel()
    frames = _frames(tt.size, max_frames, tt if real_time else None, fps)
    fig, ax = _figure(False, pixels)
    centre, half = _limits(np.vstack([a.reshape(-1, 2), piv[None, :]]))
    _set_limits(ax, centre, half, False, unit)
    links, = ax.plot([], [], "-", color="0.2", lw=2)
    masses, = ax.plot([], [], "o", color="tab:red", ms=7)
    path, = ax.plot([], [], "-", color="tab:blue", lw=1, alpha=0.6)
    ax.plot([piv[0]], [piv[1]], "s", color="k", ms=5)
    head = ax.set_title(title)

    def update(k: int):
        pts = np.vstack([piv[None, :], a[k]])
        _set_line(links, pts, False)
        _set_line(masses, a[k], False)
        past = _past(frames, k, trail)
        _set_line(path, a[past, -1, :], False)
        head.set_text(f"{title}, t = {tt[k]:.2f} s")
        return links, masses, path, head

    return _write(fig, update, frames, filename, fps, frame)


# --------------------------------------------------------------------------------- delta robot


def delta_robot_points(alpha: Any, r: float, a: float) -> tuple[np.ndarray, np.ndarray]:
    """Motor axes (shoulders) and elbows of the delta robot for arm angles ``alpha``.

    Returns ``(shoulders, elbows)``, each ``(..., 3, 3)``: ``shoulders[k] = R_z(gamma_k) [r, 0, 0]``
    and ``elbows[k] = R_z(gamma_k) [r + a cos alpha_k, 0, -a sin alpha_k]``.

    >>> s, e = delta_robot_points([0.0, 0.0, 0.0], r=0.2, a=0.3)
    >>> np.round(e[0], 3).tolist()
    [0.5, 0.0, -0.0]
    """
    al = np.asarray(alpha, dtype=float)
    cg = np.cos(GAMMA)
    sg = np.sin(GAMMA)
    radial = r + a * np.cos(al)
    elbows = np.stack([radial * cg, radial * sg, -a * np.sin(al)], axis=-1)
    shoulders = np.stack([r * cg, r * sg, np.zeros(3)], axis=-1)
    shoulders = np.broadcast_to(shoulders, elbows.shape).copy()
    return shoulders, elbows


def animate_delta_robot(
    t: Any,
    alpha: Any,
    p: Any,
    r: float = 0.2,
    a: float = 0.3,
    L: float = 0.6,
    filename: Any = "delta_robot.gif",
    *,
    fps: float = 20,
    max_frames: int = 150,
    trail: int = 30,
    frame: int | None = None,
    check_tol: float | None = 1e-3,
    title: str = "delta robot",
    pixels: int = 480,
    real_time: bool = False,
    unit: str = "m",
) -> AnimationResult:
    """Animate the delta robot: base, three upper arms (angles ``alpha``, ``(N, 3)``), rods of
    length ``L`` and the platform point ``p`` (``(N, 3)``, ``z`` up).

    The geometry is that of lecture L4 (see the module docstring) with base radius ``r`` and
    arm length ``a``. Unless ``check_tol`` is None, the rod lengths ``|p - p_k|`` are checked
    against ``L`` (a mismatch above ``check_tol`` means the data do not belong to this geometry
    and raises :class:`~daekit.errors.ModelError`). Returns an :class:`AnimationResult`.
    """
    tt, arr = _check_arrays(t, {"alpha": (alpha, (3,)), "p": (p, (3,))})
    al, pp = arr["alpha"], arr["p"]
    sh, el = delta_robot_points(al, r, a)  # (N, 3, 3)
    if check_tol is not None:
        lengths = np.linalg.norm(pp[:, None, :] - el, axis=2)
        err = np.abs(lengths - L)
        if err.max() > check_tol:
            k, j = np.unravel_index(int(np.argmax(err)), err.shape)
            raise ModelError(
                f"animate_delta_robot: rod {j} has length {lengths[k, j]:.4g} at t = {tt[k]:g}, "
                f"not L = {L:g}: check r, a, L (they must be the model's) and the order of "
                "alpha and p (or pass check_tol=None)"
            )
    frames = _frames(tt.size, max_frames, tt if real_time else None, fps)
    fig, ax = _figure(True, pixels)
    centre, half = _limits(np.vstack([sh.reshape(-1, 3), el.reshape(-1, 3), pp]), pad=0.15)
    _set_limits(ax, centre, half, True, unit)
    base = np.vstack([sh[0], sh[0, :1]])
    ax.plot(base[:, 0], base[:, 1], base[:, 2], "-", color="0.4", lw=3)
    ax.plot(sh[0, :, 0], sh[0, :, 1], sh[0, :, 2], "s", color="k", ms=6)
    colours = ("tab:red", "tab:green", "tab:blue")
    arms = [ax.plot([], [], [], "-", color=colours[k], lw=4)[0] for k in range(3)]
    rods = [ax.plot([], [], [], "-", color=colours[k], lw=1.5)[0] for k in range(3)]
    elb, = ax.plot([], [], [], "o", color="0.2", ms=5)
    plat, = ax.plot([], [], [], "o", color="tab:orange", ms=9)
    path, = ax.plot([], [], [], "-", color="tab:orange", lw=1, alpha=0.6)
    floor = centre[2] - half
    shadow_line, shadow = _floor_shadow(ax, floor)
    drop, = ax.plot([], [], [], ":", color="0.5", lw=1)
    head = ax.set_title(title)

    def update(k: int):
        for j in range(3):
            _set_line(arms[j], np.vstack([sh[k, j], el[k, j]]), True)
            _set_line(rods[j], np.vstack([el[k, j], pp[k]]), True)
        _set_line(elb, el[k], True)
        _set_line(plat, pp[k : k + 1], True)
        past = _past(frames, k, trail)
        _set_line(path, pp[past], True)
        shadow(pp[past])
        _set_line(drop, np.array([pp[k], [pp[k, 0], pp[k, 1], floor]]), True)
        head.set_text(f"{title}, t = {tt[k]:.2f} s")
        return (*arms, *rods, elb, plat, path, shadow_line, drop, head)

    return _write(fig, update, frames, filename, fps, frame)


# ------------------------------------------------------------------------------------- drift


def animate_drift(
    t: Any,
    runs: dict[str, Any],
    length: float,
    filename: Any = "drift.gif",
    *,
    pivot: Any = None,
    colors: dict[str, str] | None = None,
    fps: float = 20,
    max_frames: int = 150,
    real_time: bool = False,
    trail: int = 30,
    frame: int | None = None,
    title: str = "constraint drift",
    pixels: int = 480,
    unit: str = "m",
) -> AnimationResult:
    """Animate runs of one pendulum side by side, above their rod lengths over time.

    ``runs`` maps a label (e.g. ``"no stabilization"``, ``"projection"``) to bob positions
    ``(N, 3)`` or ``(N, 2)`` on the common time grid ``t``. Each run gets a panel with the rod,
    the bob and its trail, all panels on the same scale; a dashed circle (planar) or the
    sphere's equator and meridian (spatial) of radius ``length`` about ``pivot`` shows where the
    bob belongs. Below, the rod length ``|p - pivot|`` of each run is drawn up to the current
    time against the true ``length``. ``colors`` maps labels to matplotlib colours. The panels
    are ``pixels`` high; the figure is about ``pixels`` times the number of runs wide.

    >>> import numpy as np, os, tempfile
    >>> t = np.linspace(0, 2, 41)
    >>> ok = np.column_stack([np.sin(t), np.zeros_like(t), -np.cos(t)])
    >>> out = animate_drift(t, {"drifts": (1 + 0.1 * t[:, None]) * ok, "kept": ok}, 1.0,
    ...                     os.path.join(tempfile.mkdtemp(), "drift.gif"), max_frames=5)
    >>> out.n_frames
    5
    """
    if not isinstance(runs, dict) or not runs:
        raise ModelError("animate_drift: runs must be a non-empty dict {label: positions}")
    if len(runs) > 4:
        raise ModelError(f"animate_drift: at most 4 runs side by side, got {len(runs)}")
    if not (np.isfinite(length) and length > 0):
        raise ModelError(f"animate_drift: length must be positive, got {length}")
    tt, arr = _check_arrays(t, {str(k): (v, (None,)) for k, v in runs.items()})
    labels = list(arr)
    dims = {arr[k].shape[1] for k in labels}
    if len(dims) != 1 or not dims <= {2, 3}:
        raise ModelError(
            "animate_drift: every run needs positions with the same number of columns, 2 or 3; "
            f"got {', '.join(f'{k}: {arr[k].shape[1]}' for k in labels)}"
        )
    dim = dims.pop()
    three_d = dim == 3
    piv = np.zeros(dim) if pivot is None else np.asarray(pivot, dtype=float).ravel()
    frames = _frames(tt.size, max_frames, tt if real_time else None, fps)
    default = ("tab:red", "tab:green", "tab:blue", "tab:purple")
    col = {k: (colors or {}).get(k, default[i]) for i, k in enumerate(labels)}

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if pixels < 16:
        raise ModelError(f"animate_drift: pixels must be at least 16, got {pixels}")
    n = len(labels)
    h_in = pixels / 80.0
    fig = Figure(figsize=(max(h_in * n, h_in * 1.4), h_in * 1.4), dpi=80)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, n, height_ratios=(3.2, 1.0), hspace=0.12, wspace=0.05,
                            left=0.07, right=0.97, top=0.88, bottom=0.08)
    allp = np.vstack([arr[k] for k in labels] + [piv[None, :]])
    centre, half = _limits(allp, pad=0.08)
    ang = np.linspace(0, 2 * np.pi, 121)
    moving = []
    parts = []
    for i, k in enumerate(labels):
        ax = fig.add_subplot(grid[0, i], projection="3d" if three_d else None)
        _set_limits(ax, centre, half, three_d, unit)
        if three_d:
            ax.view_init(elev=12, azim=-60)
            ring = np.column_stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)])
            for pts in (ring, ring[:, [0, 2, 1]], ring[:, [2, 0, 1]]):
                q = piv + length * pts
                ax.plot(q[:, 0], q[:, 1], q[:, 2], "--", color="0.65", lw=0.8)
        else:
            ax.plot(piv[0] + length * np.cos(ang), piv[1] + length * np.sin(ang), "--",
                    color="0.65", lw=0.8)
        extra = [[]] if three_d else []
        rod, = ax.plot([], [], *extra, "-", color="0.2", lw=2)
        bob, = ax.plot([], [], *extra, "o", color=col[k], ms=9)
        path, = ax.plot([], [], *extra, "-", color=col[k], lw=1, alpha=0.6)
        ax.plot(*[[v] for v in piv], "s", color="k", ms=5)
        label = ax.set_title(k, color=col[k], fontsize=11)
        parts.append((rod, bob, path, arr[k], label, k))
    strip = fig.add_subplot(grid[1, :])
    lengths = {k: np.linalg.norm(arr[k] - piv, axis=1) for k in labels}
    lo = min(float(v.min()) for v in lengths.values())
    hi = max(float(v.max()) for v in lengths.values())
    pad = 0.05 * max(hi - lo, 0.02 * length)
    strip.set_xlim(tt[0], tt[-1] if tt[-1] > tt[0] else tt[0] + 1)
    strip.set_ylim(min(lo, length) - pad, max(hi, length) + pad)
    strip.axhline(length, color="0.5", ls="--", lw=0.8)
    strip.set_xlabel("t [s]")
    strip.set_ylabel(f"rod length [{unit}]")
    strip.grid(True, alpha=0.3)
    curves = {k: strip.plot([], [], "-", color=col[k], lw=1.5, label=k)[0] for k in labels}
    strip.legend(loc="lower left", fontsize=8, ncol=n, framealpha=0.9)
    fig.suptitle(title, fontsize=11)
    clock = strip.text(1.0, 1.03, "", ha="right", va="bottom", transform=strip.transAxes,
                       fontsize=10)
    moving = [a for part in parts for a in part[:3] + part[4:5]] + list(curves.values())
    moving.append(clock)

    def update(k: int):
        past = _past(frames, k, trail)
        for rod, bob, path, p, label, lab in parts:
            _set_line(rod, np.vstack([piv, p[k]]), three_d)
            _set_line(bob, p[k : k + 1], three_d)
            _set_line(path, p[past], three_d)
            label.set_text(f"{lab}: rod {lengths[lab][k]:.3f} {unit}")
        for lab, line in curves.items():
            line.set_data(tt[: k + 1], lengths[lab][: k + 1])
        clock.set_text(f"t = {tt[k]:.1f} s")
        return moving

    return _write(fig, update, frames, filename, fps, frame)


# ------------------------------------------------------------------------------------ dispatch


def _get(src: Any, names: tuple[str, ...], what: str) -> np.ndarray:
    for nm in names:
        try:
            if isinstance(src, dict):
                if nm in src:
                    return np.asarray(src[nm], dtype=float)
                continue
            return np.asarray(src[nm], dtype=float)
        except (KeyError, ValueError, IndexError):
            continue
    raise ModelError(
        f"animate: cannot find {what} in the trajectory (tried {', '.join(map(repr, names))}); "
        "pass the arrays yourself, e.g. animate({'t': t, 'p': positions}, ...)"
    )


def animate(
    traj_or_arrays: Any,
    mechanism: str = "pendulum",
    filename: Any = None,
    fps: float = 20,
    **kw: Any,
) -> AnimationResult:
    """Animate a trajectory of a pendulum, planar chain or delta robot as a GIF.

    ``traj_or_arrays`` is a :class:`~daekit.simulate.Trajectory` (or anything with ``t`` and
    ``[name]`` access) or a dict of arrays with ``"t"``. Arrays are read by name:

    - ``"pendulum"``: bob positions ``"p"`` (``(N, 2)`` or ``(N, 3)``), else ``"q"``, else
      ``"x"`` and ``"y"``;
    - ``"chain"``: ``"q"`` (``x1, y1, x2, y2, ...``), else ``"xy"``;
    - ``"delta_robot"``: arm angles ``"alpha"`` and platform ``"p"``; ``r``, ``a``, ``L`` as
      keyword arguments (default the data of :func:`daekit.examples.delta_robot`: 0.2, 0.3,
      0.6).

    Other keyword arguments go to :func:`animate_pendulum`, :func:`animate_chain` or
    :func:`animate_delta_robot`. ``filename`` defaults to ``"<mechanism>.gif"``.
    """
    src = traj_or_arrays
    if isinstance(src, dict):
        if "t" not in src:
            raise ModelError("animate: the dict of arrays needs the time points under 't'")
        t = np.asarray(src["t"], dtype=float)
    elif hasattr(src, "t"):
        t = np.asarray(src.t, dtype=float)
    else:
        raise ModelError(
            f"animate: give a trajectory or a dict of arrays with 't', got {type(src).__name__}"
        )
    filename = filename or f"{mechanism}.gif"
    if mechanism == "pendulum":
        try:
            p = _get(src, ("p", "q"), "the bob position")
        except ModelError:
            p = np.column_stack([_get(src, ("x",), "x"), _get(src, ("y",), "y")])
        return animate_pendulum(t, p, filename, fps=fps, **kw)
    if mechanism == "chain":
        return animate_chain(t, _get(src, ("q", "xy"), "the mass positions"), filename,
                             fps=fps, **kw)
    if mechanism == "delta_robot":
        alpha = _get(src, ("alpha",), "the arm angles")
        p = _get(src, ("p",), "the platform position")
        geo = {k: kw.pop(k) for k in ("r", "a", "L") if k in kw}
        return animate_delta_robot(t, alpha, p, filename=filename, fps=fps, **geo, **kw)
    raise ModelError(
        f"animate: unknown mechanism {mechanism!r}; use 'pendulum', 'chain' or 'delta_robot'"
    )
