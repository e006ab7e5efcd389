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

At most ``max_frames`` frames (150 by default) are drawn, evenly spread over the time grid;
the GIF plays at ``fps`` frames per second. A file name ending in ``.png`` saves one still
frame (``frame``, default the middle one) instead: handy to check a drawing.

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


def _frames(n: int, max_frames: int) -> np.ndarray:
    if max_frames < 1:
        raise ModelError(f"animate: max_frames must be at least 1, got {max_frames}")
    k = min(n, int(max_frames))
    return np.unique(np.round(np.linspace(0, n - 1, k)).astype(int))


def _figure(three_d: bool, size: float = 4.0):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size, size), dpi=80)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d") if three_d else fig.add_subplot()
    return fig, ax


def _limits(points: np.ndarray, pad: float = 0.1) -> tuple[np.ndarray, float]:
    """Centre and half-width of a cube (or square) holding all ``points`` (rows)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = 0.5 * float(np.max(hi - lo))
    half = half * (1 + pad) if half > 0 else 1.0
    return centre, half


def _set_limits(ax, centre: np.ndarray, half: float, three_d: bool) -> None:
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    if three_d:
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
    else:
        ax.set_aspect("equal")
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.grid(True, alpha=0.3)


def _set_line(line, pts: np.ndarray, three_d: bool) -> None:
    line.set_data(pts[:, 0], pts[:, 1])
    if three_d:
        line.set_3d_properties(pts[:, 2])


def _past(frames: np.ndarray, k: int, trail: int) -> np.ndarray:
    """The frame indices of the trail ending at ``k`` (``k`` included)."""
    prior = frames[frames < k][-trail:] if trail > 0 else frames[:0]
    return np.append(prior, k).astype(int)


def _floor_shadow(ax, z: float):
    """A grey line on the floor plane ``z`` (for the 3D trails: depth is easier to read)."""
    line, = ax.plot([], [], [], "-", color="0.6", lw=1, alpha=0.8)

    def put(pts: np.ndarray) -> None:
        flat = pts.copy()
        flat[:, 2] = z
        _set_line(line, flat, True)

    return line, put


def _write(fig, update, frames: np.ndarray, filename: Any, fps: float, frame: int | None):
    path = Path(filename)
    if path.parent and not path.parent.exists():
        raise DaekitError(f"animate: the folder {str(path.parent)!r} does not exist; create it")
    if path.suffix.lower() == ".png":
        k = int(frames[len(frames) // 2]) if frame is None else int(frame)
        update(k)
        fig.savefig(path)
        return AnimationResult(path, 1, np.array([k]))
    if path.suffix.lower() != ".gif":
        raise DaekitError(
            f"animate: cannot write {path.name!r}: give a file name ending in .gif (the "
            "animation) or .png (one still frame)"
        )
    from matplotlib.animation import FuncAnimation, PillowWriter

    anim = FuncAnimation(fig, update, frames=[int(k) for k in frames], blit=False,
                         repeat=False, cache_frame_data=False)
    anim.save(str(path), writer=PillowWriter(fps=fps))
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
    frames = _frames(tt.size, max_frames)
    fig, ax = _figure(three_d)
    centre, half = _limits(np.vstack([p, piv[None, :]]))
    _set_limits(ax, centre, half, three_d)
    rod, = ax.plot([], [], *([[]] if three_d else []), "-", color="0.2", lw=2)
    bob, = ax.plot([], [], *([[]] if three_d else []), "o", color="tab:red", ms=10)
    path, = ax.plot([], [], *([[]] if three_d else []), "-", color="tab:blue", lw=1, alpha=0.6)
    ax.plot(*[[v] for v in piv], "s", color="k", ms=5)
    if three_d:
        floor = centre[2] - half
        _, shadow = _floor_shadow(ax, floor)
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
        head.set_text(f"{title}, t = {tt[k]:.2f}")
        return rod, bob, path

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
    frames = _frames(tt.size, max_frames)
    fig, ax = _figure(False)
    centre, half = _limits(np.vstack([a.reshape(-1, 2), piv[None, :]]))
    _set_limits(ax, centre, half, False)
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
        head.set_text(f"{title}, t = {tt[k]:.2f}")
        return links, masses, path

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
    frames = _frames(tt.size, max_frames)
    fig, ax = _figure(True)
    centre, half = _limits(np.vstack([sh.reshape(-1, 3), el.reshape(-1, 3), pp]), pad=0.15)
    _set_limits(ax, centre, half, True)
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
    _, shadow = _floor_shadow(ax, floor)
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
        head.set_text(f"{title}, t = {tt[k]:.2f}")
        return (*arms, *rods, elb, plat, path)

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
