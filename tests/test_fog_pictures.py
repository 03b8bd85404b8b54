"""Patrol pictures a reader can tell apart: fog, obstacles, unknown and outside cells,
robots, the key and the colour bar; the animation's frame size."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image

from sonarmap.grid import Grid
from sonarmap.plot import FogAnimation, FogPicture, save_fog_picture

# A 240 m x 160 m map at 1 m cells (the size of fig3-10), with a block of each class.
GRID = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(160, 240))
TOP = 300.0


def _scene() -> dict[str, Any]:
    rows, cols = GRID.shape
    free = np.ones((rows, cols), dtype=bool)
    free[20:60, 20:60] = False  # obstacle: x 20-60 m, y 100-140 m
    unknown = np.zeros_like(free)
    unknown[100:140, 20:60] = True  # x 20-60 m, y 20-60 m
    free[unknown] = False
    outside = np.zeros_like(free)
    outside[20:60, 120:160] = True  # x 120-160 m, y 100-140 m
    _, cc = np.indices((rows, cols))
    tb = 250.0 * cc / cols
    tb[100:150, 200:240] = TOP  # the longest unseen: x 200-240 m, y 10-60 m
    tb[20:60, 60:100] = 0.0  # just seen: x 60-100 m, y 100-140 m
    robots = np.array([[80.0, 80.0, 0.5], [10.0, 10.0, -2.0]])
    return {"free": free, "unknown": unknown, "outside": outside, "tb": tb, "robots": robots}


def _picture(grid: Grid = GRID, **masks: Any) -> FogPicture:
    s = _scene() if grid is GRID else {}
    free = s.get("free", np.ones(grid.shape, dtype=bool))
    pic = FogPicture(
        grid,
        free,
        top=TOP,
        radius=0.3,
        title="test",
        outside=masks.get("outside", s.get("outside")),
        unknown=masks.get("unknown", s.get("unknown")),
        never_seen=True,
    )
    tb = s.get("tb", np.full(grid.shape, 100.0))
    pic.update(tb, s.get("robots", np.array([[1.0, 1.0, 0.0]])), t=12.0)
    pic.fig.canvas.draw()
    return pic


def _rgb_at(pic: FogPicture, x: float, y: float) -> npt.NDArray[np.float64]:
    """The drawn colour (0-255) at world (x, y)."""
    canvas: Any = pic.fig.canvas  # Agg's, which has a pixel buffer
    buf = np.asarray(canvas.buffer_rgba())
    px, py = pic.ax.transData.transform((x, y))
    return buf[round(buf.shape[0] - py), round(px), :3].astype(np.float64)


def _distance(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> float:
    return float(np.linalg.norm(a - b))


def test_classes_and_fog_are_told_apart() -> None:
    pic = _picture()
    try:
        obstacle = _rgb_at(pic, 40.0, 120.0)
        unknown = _rgb_at(pic, 40.0, 40.0)
        outside = _rgb_at(pic, 141.0, 119.0)  # between hatch lines or on one: both pale
        unseen = _rgb_at(pic, 220.0, 35.0)
        seen = _rgb_at(pic, 80.0, 130.0)
    finally:
        plt.close(pic.fig)
    assert _distance(obstacle, np.zeros(3)) < 10  # obstacles are black
    # The longest unseen fog stays far from obstacle black (it was 0.8 grey before).
    assert _distance(unseen, obstacle) > 100
    for name, colour in {"unknown": unknown, "outside": outside}.items():
        for other, ref in {"obstacle": obstacle, "unseen": unseen, "seen": seen}.items():
            assert _distance(colour, ref) > 40, f"{name} too close to {other}"
    assert _distance(unknown, outside) > 40
    assert _distance(seen, unseen) > 150


def test_robot_drawn_in_a_colour_of_its_own() -> None:
    pic = _picture()
    try:
        robot = _rgb_at(pic, 80.0, 80.0)
        around = _rgb_at(pic, 80.0, 95.0)
        disc = pic.robots[0][0]
    finally:
        plt.close(pic.fig)
    assert _distance(robot, around) > 80
    # A 0.3 m robot on a 240 m map is drawn larger than to scale, so that it shows.
    assert disc.get_radius() >= 0.005 * 240


@pytest.mark.parametrize("shape", [(160, 240), (400, 60), (30, 30)])
def test_key_clear_of_the_axis_label(shape: tuple[int, int]) -> None:
    grid = Grid(resolution=1.0, origin=(0.0, 0.0), shape=shape)
    pic = _picture(grid)
    try:
        canvas: Any = pic.fig.canvas
        renderer = canvas.get_renderer()
        key = pic.legend.get_window_extent(renderer)
        label = pic.ax.xaxis.label.get_window_extent(renderer)
        ticks = pic.ax.xaxis.get_tightbbox(renderer)
    finally:
        plt.close(pic.fig)
    assert not key.overlaps(label)
    assert ticks is not None
    assert not key.overlaps(ticks)
    assert key.y1 <= label.y0  # below the label


def test_colour_bar_in_seconds_with_round_ticks() -> None:
    pic = _picture()
    try:
        ticks = list(pic.bar.get_ticks())
        label = pic.bar.ax.get_ylabel()
    finally:
        plt.close(pic.fig)
    assert len(ticks) >= 3
    assert ticks[0] == 0.0
    assert ticks[-1] == TOP
    assert ticks == sorted(ticks)
    assert label == "time since last seen [s]"


def test_save_fog_picture_old_and_new_calls(tmp_path: Path) -> None:
    s = _scene()
    old = save_fog_picture(GRID, s["free"], s["tb"], s["robots"], tmp_path / "old.png")
    never = np.zeros_like(s["free"])
    never[120:150, 200:240] = True
    new = save_fog_picture(
        GRID,
        s["free"],
        s["tb"],
        s["robots"],
        tmp_path / "new.png",
        radius=0.3,
        title="t",
        outside=s["outside"],
        unknown=s["unknown"],
        never_seen=never,
    )
    for p in (old, new):
        with Image.open(p) as im:
            assert im.format == "PNG"
            assert im.size[0] >= 800


def test_gif_frames_sized_by_the_map(tmp_path: Path) -> None:
    s = _scene()
    anim = FogAnimation(
        GRID, s["free"], radius=0.3, outside=s["outside"], unknown=s["unknown"], title="t"
    )
    never = np.ones_like(s["free"])
    for k in range(3):
        never[:, : 80 * (k + 1)] = False
        anim.add(10.0 * k, s["tb"] * (k + 1) / 3, s["robots"] + k, never_seen=never)
    out = anim.save(tmp_path / "patrol.gif")
    with Image.open(out) as gif:
        assert getattr(gif, "n_frames", 1) == 3
        width, height = gif.size
    assert width >= 800  # a 240 m map was drawn 480 px wide
    assert 0.5 < height / width < 0.85  # the map's 2:3, with the key and title
    tall = FogAnimation(Grid(0.05, (0.0, 0.0), (600, 200)), np.ones((600, 200), dtype=bool))
    tall.add(1.0, np.zeros((600, 200)), np.array([[5.0, 15.0, 0.0]]))
    with Image.open(tall.save(tmp_path / "tall.gif")) as gif:
        width, height = gif.size
    assert height >= 800
    assert width < height
