"""A mission as an animation: where the robot truly is, where odometry alone would put
it, the poses its store keeps at their current estimates, and the closures it holds.

Frames are taken by :func:`~sonarmap.team.mission.run_mission` (``record=True``), one
per pose made, in the robot's own frame; :func:`save_mission_animation` draws them over
the prior map through one transform (the final alignment), so the picture shows how the
estimate of every kept pose moves as closures arrive and compression removes poses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from matplotlib.animation import FFMpegWriter, PillowWriter

from ..errors import ConfigError
from ..io.rosmap import OccupancyMap
from ..plot import MapAnimation, _write_animation
from .records import compose

__all__ = ["Frame", "save_mission_animation"]

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Frame:
    """The mission just after one pose was made.

    Attributes
    ----------
    t : float
        Mission time, seconds.
    truth : ndarray (2,)
        The robot's true position (prior-map frame).
    odometry : ndarray (2,)
        Where odometry alone puts it (robot frame).
    estimates : ndarray (N, 2)
        The kept poses' current estimates (robot frame).
    closures : ndarray (M, 4)
        Each closure of the store as a segment x0, y0, x1, y1 (robot frame).
    store_bytes : int
        The store's encoded size.
    """

    t: float
    truth: F64
    odometry: F64
    estimates: F64
    closures: F64
    store_bytes: int


def _placed(transform: F64, xy: F64) -> F64:
    """Points of the robot frame in the prior map's frame."""
    if len(xy) == 0:
        return xy.reshape(0, 2)
    full = np.column_stack([xy, np.zeros(len(xy))])
    return compose(transform, full)[:, :2]


def save_mission_animation(
    frames: Sequence[Frame],
    prior: OccupancyMap,
    transform: npt.ArrayLike,
    path: str | Path,
    *,
    max_frames: int = 150,
    fps: int = 8,
    title: str = "",
) -> Path:
    """Write the frames as an animated GIF (or MP4 with ffmpeg).

    Parameters
    ----------
    frames : sequence of Frame
        As recorded by the mission; at most ``max_frames`` of them, evenly spaced and
        always the last, are drawn.
    prior : OccupancyMap
        The background.
    transform : array_like (3,)
        Robot frame to prior frame (the mission's alignment).
    path : str or Path
        ``.gif``, or ``.mp4`` when ffmpeg is installed.
    """
    p = Path(path)
    MapAnimation.check_name(p)
    if not frames:
        raise ConfigError("no frames to animate")
    if max_frames < 1:
        raise ConfigError(f"max_frames must be >= 1, got {max_frames}")
    a = np.asarray(transform, dtype=np.float64)
    pick = np.unique(np.linspace(0, len(frames) - 1, min(max_frames, len(frames))).round())
    chosen = pick.astype(int).tolist()
    truth = np.array([f.truth for f in frames])
    odo = _placed(a, np.array([f.odometry for f in frames]))
    writer: Any = PillowWriter(fps=fps) if p.suffix.lower() == ".gif" else FFMpegWriter(fps=fps)

    fig, ax = plt.subplots(figsize=(6.5, 6.5 * prior.grid.rows / max(prior.grid.cols, 1) + 0.6))
    occ = np.where(np.isnan(prior.occupancy), 0.25, prior.occupancy)
    ax.imshow(1.0 - occ, cmap="gray", vmin=0, vmax=1, extent=prior.grid.extent, origin="upper")
    (true_line,) = ax.plot([], [], color="green", lw=1, alpha=0.7, label="true path")
    (odo_line,) = ax.plot([], [], color="tab:red", lw=1, ls="--", label="odometry alone")
    (kept,) = ax.plot([], [], ".", color="#1f3d7a", ms=4, label="kept poses (estimates)")
    (robot,) = ax.plot([], [], "o", ms=8, mfc="none", mec="green", mew=1.5)
    links = ax.plot([], [], color="orange", lw=0.6, label="closures")[0]
    ax.set_xlim(prior.grid.extent[0], prior.grid.extent[1])
    ax.set_ylim(prior.grid.extent[2], prior.grid.extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=3, fontsize="small")
    fig.subplots_adjust(bottom=0.18)

    def show(k: int) -> list[Any]:
        i = chosen[k]
        f = frames[i]
        upto = i + 1
        true_line.set_data(truth[:upto, 0], truth[:upto, 1])
        odo_line.set_data(odo[:upto, 0], odo[:upto, 1])
        est = _placed(a, f.estimates)
        kept.set_data(est[:, 0], est[:, 1])
        robot.set_data([f.truth[0]], [f.truth[1]])
        p0, p1 = _placed(a, f.closures[:, :2]), _placed(a, f.closures[:, 2:])
        # A NaN after each segment breaks the one line into separate segments.
        gap = np.full(len(p0), np.nan)
        links.set_data(
            np.column_stack([p0[:, 0], p1[:, 0], gap]).ravel(),
            np.column_stack([p0[:, 1], p1[:, 1], gap]).ravel(),
        )
        ax.set_title(
            f"{title}  t = {f.t:.0f} s, {len(f.estimates)} poses kept, "
            f"{len(f.closures)} closures, {f.store_bytes / 1e3:.0f} kB".strip(),
            fontsize="small",
        )
        return [true_line, odo_line, kept, robot, links]

    return _write_animation(fig, show, len(chosen), p, writer)
