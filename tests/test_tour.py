"""The tour's figures and animations (issue 15 items 5 and 7): GIFs only on request, in real time
and at least 480 pixels; the figures' helpers (the plane of an orbit, remedy colours, the Sigma
legend, real-time frame selection, the drift animation)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from daekit.animate import animate_drift, animate_pendulum
from daekit.cli import main
from daekit.errors import ModelError
from daekit.plot import REMEDY_COLORS, STRUCTURE_LEGEND, best_plane, remedy_color


def _gif(path):
    im = Image.open(path)
    durations = []
    for k in range(im.n_frames):
        im.seek(k)
        durations.append(im.info["duration"])
    return im.size, im.n_frames, durations


def test_tour_cli_gifs_only_on_request(monkeypatch):
    """``daekit tour`` asks for no GIFs; ``--gifs`` does; ``--no-animations`` wins."""
    import daekit.tour

    seen = []
    monkeypatch.setattr(daekit.tour, "run_tour", lambda **kw: seen.append(kw["gifs"]))
    assert main(["tour", "--quiet"]) == 0
    assert main(["tour", "--quiet", "--gifs"]) == 0
    assert main(["tour", "--quiet", "--gifs", "--no-animations"]) == 0
    assert seen == [False, True, False]


def test_tour_gifs_real_time_and_large(tmp_path, capsys):
    """``run_tour(gifs=True)`` writes three GIFs that play in real time (one frame per 1/20 s,
    or 1/10 s for the drift, of simulated time, each shown that long) at >= 480 pixels; the
    table header reads max |c'|. (The default tour writing no GIF: tests/test_cli.py.)"""
    from daekit.tour import run_tour

    t_end = 1.0
    run_tour(out=tmp_path, t_end=t_end, quiet=True, ocp=False, gifs=True)
    out = capsys.readouterr().out
    assert "max |c'|" in out and "max |c`|" not in out
    names = sorted(p.name for p in tmp_path.glob("*.gif"))
    assert names == ["delta_robot.gif", "pendulum3d.gif", "pendulum3d_drift.gif"]
    for name, fps in (("pendulum3d.gif", 20), ("delta_robot.gif", 20),
                      ("pendulum3d_drift.gif", 10)):
        size, n, durations = _gif(tmp_path / name)
        assert min(size) >= 480, name
        assert n == round(fps * t_end) + 1, name
        assert set(durations) == {round(1000 / fps)}, name


def test_real_time_frames_pick_the_grid_points_at_one_over_fps(tmp_path):
    t = np.linspace(0.0, 3.0, 301)  # 100 points per second
    p = np.column_stack([np.sin(t), -np.cos(t)])
    res = animate_pendulum(t, p, tmp_path / "a.gif", fps=20, max_frames=10, real_time=True)
    assert res.n_frames == 61  # max_frames does not apply in real time
    assert np.allclose(t[res.frames], np.arange(61) / 20.0)
    # an uneven grid: the nearest points to 0, 0.1, 0.2, 0.3
    tu = np.array([0.0, 0.04, 0.11, 0.2, 0.26, 0.33])
    res = animate_pendulum(tu, p[:6], tmp_path / "b.gif", fps=10, real_time=True)
    assert res.frames.tolist() == [0, 2, 3, 5]


def test_best_plane_of_a_tilted_circle_and_of_a_swing():
    # a circle of radius 2 in the plane with normal n through c: the fitted normal is +-n and
    # every point lies in it; the in-plane coordinates keep distances (radius 2 about c)
    n = np.array([1.0, 2.0, 2.0]) / 3.0
    a = np.cross(n, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    s = np.linspace(0, 2 * math.pi, 40, endpoint=False)
    c = np.array([0.5, -1.0, 3.0])
    pts = c + 2 * (np.outer(np.cos(s), a) + np.outer(np.sin(s), b))
    pl = best_plane(pts)
    assert abs(abs(pl.normal @ n) - 1) < 1e-12 and pl.out_of_plane < 1e-12
    q = pl.project(pts) - pl.project(c[None, :])
    assert np.allclose(np.hypot(q[:, 0], q[:, 1]), 2.0)
    # a planar swing in y = 0.3: the coordinate plane, in-plane axes x and z themselves
    th = np.linspace(-0.5, 0.5, 11)
    sw = np.column_stack([np.sin(th), np.full_like(th, 0.3), -np.cos(th)])
    pl = best_plane(sw)
    assert pl.name == "y = 0.3" and pl.labels == ("x", "z")
    assert np.allclose(pl.project(sw), sw[:, [0, 2]])


def test_remedy_colours_are_one_per_remedy_and_found_from_table_labels():
    assert len(set(REMEDY_COLORS.values())) == len(REMEDY_COLORS)
    labels = ["none", "Baumgarte (-1, -1)", "projection", "GGL (index 2)", "dummy derivatives",
              "RATTLE (h = 0.005)"]
    assert [remedy_color(x) for x in labels] == list(REMEDY_COLORS.values())
    assert remedy_color("dummy_derivatives") == REMEDY_COLORS["dummy derivatives"]
    assert remedy_color(None) == remedy_color("no stabilization") == REMEDY_COLORS["none"]


def test_sigma_figure_explains_c_d_and_the_transversal_in_one_line():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import daekit as dk

    fig = dk.analyze(dk.examples.pendulum3d()).plot_structure()
    texts = [t.get_text() for t in fig.texts]
    plt.close(fig)
    assert STRUCTURE_LEGEND in texts and "\n" not in STRUCTURE_LEGEND
    assert "c = " in STRUCTURE_LEGEND and "d = " in STRUCTURE_LEGEND
    assert "transversal" in STRUCTURE_LEGEND


def test_drift_animation_rod_lengths_and_bad_input(tmp_path):
    t = np.linspace(0, 1, 11)
    ok = np.column_stack([np.sin(t), np.zeros_like(t), -np.cos(t)])
    res = animate_drift(t, {"drifts": 1.2 * ok, "kept": ok}, 1.0, tmp_path / "d.png", frame=10)
    assert res.n_frames == 1 and (tmp_path / "d.png").stat().st_size > 5000
    with pytest.raises(ModelError, match="same number of columns"):
        animate_drift(t, {"a": ok, "b": ok[:, :2]}, 1.0, tmp_path / "d.gif")
    with pytest.raises(ModelError, match="length must be positive"):
        animate_drift(t, {"a": ok}, -1.0, tmp_path / "d.gif")
    with pytest.raises(ModelError, match="kept has 5 rows"):
        animate_drift(t, {"kept": ok[:5]}, 1.0, tmp_path / "d.gif")


def test_counts_in_messages_have_the_right_number():
    """Lecture L1 (shared/reference-problems.md: x - x' + 1 = 0, x' z + 2 = 0) has one state and
    one degree of freedom: the explanation says "1 initial value", the reduced form "1 state";
    the 3D pendulum L3 has 4; L6 (one rod) has 1 invariant."""
    import daekit as dk
    from daekit.wording import count

    text = dk.analyze(dk.examples.l1()).explain()
    assert "Degrees of freedom: 1 initial value can" in text and "1 initial values" not in text
    assert "1 state," in repr(dk.reduce_index(dk.examples.l1()))
    assert "Degrees of freedom: 4 initial values can" in dk.analyze(dk.examples.l3()).explain()
    assert "1 invariant)" in repr(dk.reduce_index(dk.examples.l6()))
    assert [count(k, "iteration") for k in (0, 1, 2)] == ["0 iterations", "1 iteration",
                                                         "2 iterations"]
