"""A mission as an animation: where the robot truly is, where odometry alone would put
it, the poses its store keeps at their current estimates, and the closures it holds.

Frames are taken by :func:`~sonarmap.team.mission.run_mission` (``record=True``), one
per pose made, in the robot's own frame; :func:`save_mission_animation` draws them over
the prior map through one transform (the final alignment), so the picture shows how the
estimate of every kept pose moves as closures arrive and compression removes poses.

A team's mission has its own animation: :func:`~sonarmap.team.simulation.run_team`
(``record=True``) samples a :class:`TeamFrame` at a regular cadence of mission time,
and :func:`save_team_animation` draws every robot's true position with a short trail,
the network's links of the moment, and how much of the others' poses each robot holds.
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
from matplotlib.lines import Line2D

from ..errors import ConfigError
from ..io.rosmap import OccupancyMap
from ..plot import MapAnimation
from ..plot import write_animation as _write_animation
from .records import compose

__all__ = ["Frame", "TeamFrame", "mp4_available", "save_mission_animation", "save_team_animation"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


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


@dataclass(frozen=True)
class TeamFrame:
    """A team's mission at one sampled tick: plain numbers, a few hundred bytes.

    Attributes
    ----------
    t : float
        Mission time, seconds.
    driving : bool
        Whether the robots still drive their routes (False in the quiet phase, when
        they stand still and only exchange).
    positions : ndarray (N, 2)
        Each robot's true position (prior-map frame), by robot id.
    links : ndarray of int (K, 2)
        The network's direct links at that moment, pairs (i, j) with i < j.
    held : ndarray of int (N,)
        Of the poses the other robots keep as their own at that moment, how many each
        robot holds (in any layer of its store).
    others : ndarray of int (N,)
        How many poses the other robots keep as their own at that moment.
    bytes_sent : int
        Message bodies the team has sent so far.
    """

    t: float
    driving: bool
    positions: F64
    links: I64
    held: I64
    others: I64
    bytes_sent: int


def mp4_available() -> bool:
    """Whether an ``.mp4`` animation can be written here (ffmpeg is installed)."""
    return bool(FFMpegWriter.isAvailable())


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


def _amount(n: int) -> str:
    """Bytes for a reader: B, kB or MB."""
    if n < 1000:
        return f"{n} B"
    if n < 1_000_000:
        return f"{n / 1e3:.1f} kB"
    return f"{n / 1e6:.2f} MB"


def _segments(points: F64, pairs: I64) -> tuple[F64, F64]:
    """x and y of one line drawing each pair's segment, NaN between segments."""
    if len(pairs) == 0:
        return np.empty(0), np.empty(0)
    a, b = points[pairs[:, 0]], points[pairs[:, 1]]
    # A NaN after each segment breaks the one line into separate segments.
    gap = np.full(len(pairs), np.nan)
    return (
        np.column_stack([a[:, 0], b[:, 0], gap]).ravel(),
        np.column_stack([a[:, 1], b[:, 1], gap]).ravel(),
    )


def save_team_animation(
    plan: OccupancyMap,
    frames: Sequence[TeamFrame],
    path: str | Path,
    *,
    trail: float = 20.0,
    fps: int = 8,
    title: str = "",
) -> Path:
    """Write a team's frames as an animated GIF (or MP4 with ffmpeg).

    Over the floor plan, each robot is a marker of its own colour (those of
    :func:`~sonarmap.team.globalmap.plot_team`) with its last ``trail`` seconds of path;
    the network's links of the moment are lines between them. Beside the map, a bar per
    robot shows the share of the other robots' own poses it holds, with the counts
    (held / the others have). The title gives the mission time, whether the robots
    drive or the network settles (the quiet phase), and the bytes the team has sent.

    Parameters
    ----------
    plan : OccupancyMap
        The background (the prior map).
    frames : sequence of TeamFrame
        As recorded by :func:`~sonarmap.team.simulation.run_team`, in time order, all
        of one team; every one is drawn.
    path : str or Path
        ``.gif``, or ``.mp4`` when ffmpeg is installed.
    trail : float
        Seconds of path drawn behind each robot (>= 0).
    fps : int
        Frames a second of the animation.
    title : str
        Put before the mission time, e.g. ``"3 robots, limited network"``.

    Returns
    -------
    Path
    """
    p = Path(path)
    MapAnimation.check_name(p)
    if not frames:
        raise ConfigError("no frames to animate")
    if not (np.isfinite(trail) and trail >= 0):
        raise ConfigError(f"trail must be >= 0 seconds, got {trail}")
    n = len(frames[0].positions)
    if any(len(f.positions) != n for f in frames):
        raise ConfigError("frames of teams of different sizes")
    times = np.array([f.t for f in frames])
    where = np.array([f.positions for f in frames]).reshape(len(frames), n, 2)
    writer: Any = PillowWriter(fps=fps) if p.suffix.lower() == ".gif" else FFMpegWriter(fps=fps)

    rows, cols = plan.grid.shape
    side = 6.0 * rows / max(cols, 1)
    fig, (ax, bars) = plt.subplots(
        1, 2, figsize=(9.0, side + 1.0), gridspec_kw={"width_ratios": [3.0, 1.0]}
    )
    occ = np.where(np.isnan(plan.occupancy), 0.25, plan.occupancy)
    ax.imshow(1.0 - occ, cmap="gray", vmin=0, vmax=1, extent=plan.grid.extent, origin="upper")
    colours = [plt.get_cmap("tab10")(i % 10) for i in range(n)]
    (links,) = ax.plot([], [], color="gold", lw=2.0, alpha=0.9, zorder=2)
    trails = [ax.plot([], [], color=c, lw=1.2, alpha=0.7, zorder=3)[0] for c in colours]
    markers = [
        ax.plot([], [], "o", ms=9, color=c, mec="black", mew=0.8, zorder=4)[0] for c in colours
    ]
    names = [
        ax.annotate(
            str(i), (0.0, 0.0), xytext=(6, 6), textcoords="offset points", fontsize=8, zorder=5
        )
        for i in range(n)
    ]
    ax.set_xlim(plan.grid.extent[0], plan.grid.extent[1])
    ax.set_ylim(plan.grid.extent[2], plan.grid.extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    handles: list[Any] = [
        Line2D([], [], ls="", marker="o", color=c, mec="black", label=f"robot {i}")
        for i, c in enumerate(colours)
    ]
    handles.append(Line2D([], [], color="gold", lw=2.0, label="network link"))
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.1),
        ncol=min(4, len(handles)),
        fontsize="small",
        frameon=False,
    )

    rects = bars.barh(np.arange(n), np.zeros(n), color=colours, height=0.6)
    counts = [
        bars.text(
            0.5,
            i,
            "",
            ha="center",
            va="center",
            fontsize="small",
            bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none", "pad": 1},
        )
        for i in range(n)
    ]
    bars.set_xlim(0.0, 1.0)
    bars.set_xticks([0.0, 0.5, 1.0], ["0", "0.5", "1"], fontsize="small")
    bars.set_ylim(n - 0.5, -0.5)
    bars.set_yticks(np.arange(n), [f"robot {i}" for i in range(n)], fontsize="small")
    bars.set_xlabel("share held", fontsize="small")
    bars.set_title("the others' poses held", fontsize="small")
    # Bars as tall as the map would be bands for a small team: keep them slim.
    bars.set_box_aspect(min(0.35 * n + 0.2, side / 2.0))
    head = fig.suptitle("", fontsize="medium")
    fig.subplots_adjust(left=0.08, right=0.97, bottom=0.2, wspace=0.35)

    def show(k: int) -> list[Any]:
        f = frames[k]
        lx, ly = _segments(f.positions, f.links)
        links.set_data(lx, ly)
        start = int(np.searchsorted(times, f.t - trail, side="left"))
        for i in range(n):
            path_i = where[start : k + 1, i]
            trails[i].set_data(path_i[:, 0], path_i[:, 1])
            x, y = float(f.positions[i, 0]), float(f.positions[i, 1])
            markers[i].set_data([x], [y])
            names[i].xy = (x, y)
            held, others = int(f.held[i]), int(f.others[i])
            rects[i].set_width(held / others if others else 0.0)
            counts[i].set_text(f"{held} / {others}")
        phase = "driving" if f.driving else "quiet phase"
        moment = (
            f"t = {f.t:.0f} s ({phase}), {len(f.links)} link{'' if len(f.links) == 1 else 's'}, "
            f"team sent {_amount(f.bytes_sent)}"
        )
        head.set_text(f"{title}: {moment}" if title else moment)
        return [links, *trails, *markers, *names, *rects, *counts, head]

    return _write_animation(fig, show, len(frames), p, writer)
