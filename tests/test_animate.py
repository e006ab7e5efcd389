"""Animations: GIFs are written, have the expected frame count, and draw the right geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from daekit.animate import (
    animate,
    animate_chain,
    animate_delta_robot,
    animate_pendulum,
    delta_robot_points,
)
from daekit.errors import DaekitError, ModelError

R, A, L = 0.2, 0.3, 0.6


def delta_platform(alpha: np.ndarray) -> np.ndarray:
    """Platform position with every rod of length L (Newton from below the elbows)."""
    _, el = delta_robot_points(alpha, R, A)
    p = np.array([el[:, 0].mean(), el[:, 1].mean(), el[:, 2].min() - L])
    for _ in range(50):
        e = p - el
        p = p - np.linalg.solve(2 * e, np.sum(e * e, axis=1) - L**2)
    return p


def test_delta_robot_geometry_of_lecture_l4():
    # p_k = R_z(gamma_k) [r + a cos alpha_k, 0, -a sin alpha_k], gamma = (0, 2pi/3, 4pi/3)
    sh, el = delta_robot_points([0.0, math.pi / 2, 0.3], R, A)
    assert np.allclose(el[0], [R + A, 0, 0])
    g = 2 * math.pi / 3
    assert np.allclose(el[1], [R * math.cos(g), R * math.sin(g), -A])
    g = 4 * math.pi / 3
    rad = R + A * math.cos(0.3)
    assert np.allclose(el[2], [rad * math.cos(g), rad * math.sin(g), -A * math.sin(0.3)])
    assert np.allclose(np.linalg.norm(sh[:, :2], axis=1), R) and np.all(sh[:, 2] == 0)
    # the arms have length a
    assert np.allclose(np.linalg.norm(el - sh, axis=1), A)


def test_pendulum_gif_planar_and_3d(tmp_path):
    t = np.linspace(0.0, 2.0, 41)
    th = 0.5 * np.cos(3.1 * t)
    p2 = np.column_stack([np.sin(th), -np.cos(th)])
    out = animate_pendulum(t, p2, tmp_path / "p2.gif", max_frames=8)
    with Image.open(out.path) as im:
        assert im.n_frames == 8 == out.n_frames
        assert im.size[0] > 100
    p3 = np.column_stack([np.sin(th) * np.cos(t), np.sin(th) * np.sin(t), -np.cos(th)])
    out = animate({"t": t, "p": p3}, "pendulum", tmp_path / "p3.gif", max_frames=5)
    with Image.open(out.path) as im:
        assert im.n_frames == 5
    # fewer samples than max_frames: one frame per sample
    out = animate_pendulum(t[:4], p2[:4], tmp_path / "short.gif")
    with Image.open(out.path) as im:
        assert im.n_frames == 4


def test_chain_gif_and_still(tmp_path):
    t = np.linspace(0.0, 1.0, 21)
    K = 3
    ang = -math.pi / 2 + 0.4 * np.sin(4 * t)[:, None] * np.arange(1, K + 1)
    links = np.stack([np.cos(ang), np.sin(ang)], axis=2)  # (N, K, 2) unit links
    xy = np.cumsum(links, axis=1).reshape(len(t), -1)  # x1, y1, x2, y2, ...
    out = animate({"t": t, "q": xy}, "chain", tmp_path / "chain.gif", max_frames=6)
    with Image.open(out.path) as im:
        assert im.n_frames == 6
    still = animate_chain(t, xy, tmp_path / "chain.png", frame=10)
    with Image.open(still.path) as im:
        assert im.format == "PNG"
        rgb = np.asarray(im.convert("RGB"), dtype=int)
    # the masses are drawn in red: some strongly red pixels exist
    red = (rgb[..., 0] > 180) & (rgb[..., 1] < 90) & (rgb[..., 2] < 90)
    assert red.sum() > 50


def test_delta_robot_gif_from_a_trajectory(tmp_path):
    from daekit.simulate.trajectory import Trajectory

    t = np.linspace(0.0, 1.0, 30)
    alpha = np.column_stack([0.3 + 0.3 * np.sin(2 * t), 0.3 + 0.2 * t, 0.3 - 0.1 * t])
    p = np.array([delta_platform(a) for a in alpha])
    vals = {f"alpha[{i}]": alpha[:, i] for i in range(3)}
    vals.update({f"p[{i}]": p[:, i] for i in range(3)})
    traj = Trajectory(t, vals)
    out = animate(traj, "delta_robot", tmp_path / "delta.gif", r=R, a=A, L=L, max_frames=7)
    with Image.open(out.path) as im:
        assert im.n_frames == 7
    # a rod length that does not match L is caught
    with pytest.raises(ModelError, match="rod"):
        animate_delta_robot(t, alpha, p, R, A, 0.5, tmp_path / "bad.gif")


def test_bad_input(tmp_path):
    t = np.linspace(0.0, 1.0, 5)
    with pytest.raises(ModelError, match="rows"):
        animate_pendulum(t, np.zeros((4, 2)), tmp_path / "x.gif")
    with pytest.raises(ModelError, match="2 or 3"):
        animate_pendulum(t, np.zeros((5, 4)), tmp_path / "x.gif")
    with pytest.raises(ModelError, match="not finite"):
        animate_pendulum(t, np.full((5, 2), np.nan), tmp_path / "x.gif")
    with pytest.raises(DaekitError, match=".gif"):
        animate_pendulum(t, np.zeros((5, 2)), tmp_path / "x.mp4")
    with pytest.raises(ModelError, match="unknown mechanism"):
        animate({"t": t, "p": np.zeros((5, 2))}, "crane", tmp_path / "x.gif")
    with pytest.raises(ModelError, match="alpha"):
        animate({"t": t, "p": np.zeros((5, 3))}, "delta_robot", tmp_path / "x.gif")
