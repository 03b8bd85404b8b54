"""A patrol run as ROS 2 messages, for a bag or a live viewer (:mod:`sonarmap.io.record`).

:class:`PatrolPublisher` is :func:`~sonarmap.patrol.simulation.run_patrol`'s
``on_step`` observer: after every step it turns the robots and the fog into messages
and gives them to a :class:`~sonarmap.io.record.Recorder`. Topics, all in frame
``map`` and stamped in simulated seconds:

- ``/map`` (``nav_msgs/OccupancyGrid``): the territory on the run's cells, trinary as
  ``map_server`` publishes a map (0 free, 100 obstacle, -1 unknown); once, at time 0
  when the publisher is made (a live viewer gets it again every few seconds,
  :class:`~sonarmap.io.live.LiveSink`);
- ``/fog`` (the same type): every ``fog_every`` simulated seconds (5), each watched
  cell's time since last seen scaled to 0-100, 100 the worst place now (the MTB);
  -1 on the cells not watched;
- ``/tf`` (``tf2_msgs/TFMessage``): every step, ``map -> robotK/base_link`` for every
  robot (one message holding them all);
- ``/robotK/path`` (``nav_msgs/Path``): every ``path_every`` seconds (2), robot K's
  trail over the last ``trail`` seconds (60), sampled at that rate;
- ``/robots`` (``visualization_msgs/MarkerArray``): every step, each robot's disc;
- ``/network`` (the same type): every step, the direct links of the network (every
  pair with ``full``; within the link range and in line of sight with ``limited``);
- ``/crowding`` (the same type): the crowding areas: the semaphores' cells, once at time
  0, or
  with ``crowding="obstacles"`` every step the artificial obstacles' discs around the
  robots;
- ``/mtb`` and ``/mean_tb`` (``std_msgs/Float64``): every step, the worst and the mean
  time since last seen, seconds (plot them).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..io.record import Recorder
from ..io.rosmsg import (
    CUBE_LIST,
    CYLINDER,
    FLOAT,
    GRID,
    LINE_LIST,
    MARKERS,
    PATH,
    TF,
    Trails,
    float_message,
    grid_message,
    marker,
    markers_message,
    tf_message,
    transform,
)
from .fog import Fog
from .network import direct_links
from .robots import Team
from .simulation import PatrolConfig
from .territory import Territory

__all__ = ["TOPICS", "PatrolPublisher", "fog_levels", "robot_frame", "territory_levels"]

#: The topics of every run, and their types (``/robotK/path`` besides).
TOPICS = {
    "/map": GRID,
    "/fog": GRID,
    "/tf": TF,
    "/robots": MARKERS,
    "/network": MARKERS,
    "/crowding": MARKERS,
    "/mtb": FLOAT,
    "/mean_tb": FLOAT,
}

#: Colours (r, g, b, a) of the markers.
ROBOT_RGBA = (0.1, 0.4, 0.9, 0.9)
LINK_RGBA = (0.1, 0.8, 0.2, 0.9)
CROWDING_RGBA = (0.95, 0.55, 0.1, 0.35)


def robot_frame(k: int) -> str:
    """Robot ``k``'s frame in ``/tf``."""
    return f"robot{k}/base_link"


def territory_levels(territory: Territory) -> npt.NDArray[np.int8]:
    """The territory as a trinary map: 0 free, -1 unknown, 100 otherwise."""
    out = np.where(territory.free, 0, 100).astype(np.int8)
    if territory.unknown is not None:
        out[territory.unknown & ~territory.free] = -1
    return out


def fog_levels(fog: Fog) -> npt.NDArray[np.int8]:
    """Each watched cell's time since last seen as 0-100, 100 the worst now (the MTB);
    -1 on the cells not watched."""
    tb = fog.tb
    worst = max(fog.mtb(), 1e-9)
    scaled = np.round(np.clip(tb / worst, 0.0, 1.0) * 100.0)
    out: npt.NDArray[np.int8] = np.where(fog.watched, scaled, -1).astype(np.int8)
    return out


class PatrolPublisher:
    """``run_patrol``'s ``on_step``: a patrol run's topics (the module's) into a
    recorder.

    Parameters
    ----------
    recorder : Recorder
    territory : Territory
        The territory patrolled.
    config : PatrolConfig
        The run's settings (network, link range, crowding, robot radius).
    semaphores : list of ndarray of bool, optional
        The semaphores' cells, drawn on ``/crowding``.
    fog_every : float
        Simulated seconds between two ``/fog`` grids (> 0); default 5.
    path_every : float
        Simulated seconds between two trail samples and ``/robotK/path`` messages
        (> 0); default 2.
    trail : float
        Seconds of trail on ``/robotK/path`` (> 0); default 60.
    """

    def __init__(
        self,
        recorder: Recorder,
        territory: Territory,
        config: PatrolConfig,
        *,
        semaphores: list[npt.NDArray[np.bool_]] | None = None,
        fog_every: float = 5.0,
        path_every: float = 2.0,
        trail: float = 60.0,
    ) -> None:
        for name, v in (("fog_every", fog_every), ("path_every", path_every), ("trail", trail)):
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be > 0 seconds, got {v}")
        self.recorder = recorder
        self.territory = territory
        self.config = config
        self.semaphores = semaphores or []
        self.fog_every = fog_every
        self.path_every = path_every
        self.trail = trail
        self.steps = 0
        self._trails = Trails(0, trail)
        # At once, before the run's set-up: a live viewer sees the territory from the start.
        recorder.declare(TOPICS)
        g = territory.grid
        recorder.publish("/map", GRID, grid_message(g, 0.0, territory_levels(territory)), 0.0)
        if self.semaphores:
            recorder.publish("/crowding", MARKERS, markers_message(0.0, self._semaphores(0.0)), 0.0)

    def __call__(self, t: float, team: Team, fog: Fog) -> None:
        """Publish the run after the step that ended at time ``t``."""
        rec = self.recorder
        g = self.territory.grid
        if self.steps == 0:
            self._trails = Trails(len(team), self.trail)
            rec.declare({f"/robot{k}/path": PATH for k in range(len(team))})
        self.steps += 1
        x, y, heading = team.x, team.y, team.heading
        tfs = [
            transform(t, "map", robot_frame(k), x[k], y[k], heading[k]) for k in range(len(team))
        ]
        rec.publish("/tf", TF, tf_message(tfs), t)
        radius = self.config.radius
        discs = [
            marker(t, "robots", CYLINDER, [], ident=k, scale=2 * radius, height=0.2, at=(xk, yk))
            for k, (xk, yk) in enumerate(zip(x.tolist(), y.tolist(), strict=True))
        ]
        rec.publish("/robots", MARKERS, markers_message(t, discs), t)
        pairs = direct_links(
            self.config.network, x, y, clear=self.territory.free, grid=g, r_max=self.config.r_max
        )
        ends = [(x[i], y[i], x[j], y[j]) for i, j in pairs]
        links = [marker(t, "links", LINE_LIST, np.reshape(ends, (-1, 2)), rgba=LINK_RGBA)]
        rec.publish("/network", MARKERS, markers_message(t, links), t)
        if self.config.crowding == "obstacles" and len(team) > 1:
            r_obst = self.config.r_obst
            around = [
                marker(
                    t,
                    "obstacles",
                    CYLINDER,
                    [],
                    ident=k,
                    scale=2 * r_obst,
                    height=0.05,
                    at=(xk, yk),
                    rgba=CROWDING_RGBA,
                )
                for k, (xk, yk) in enumerate(zip(x.tolist(), y.tolist(), strict=True))
            ]
            rec.publish("/crowding", MARKERS, markers_message(t, around), t)
        rec.publish("/mtb", FLOAT, float_message(fog.mtb()), t)
        rec.publish("/mean_tb", FLOAT, float_message(fog.mean_tb()), t)
        if rec.due("fog", t, self.fog_every):
            rec.publish("/fog", GRID, grid_message(g, t, fog_levels(fog)), t)
        if rec.due("path", t, self.path_every):
            for k in range(len(team)):
                path = self._trails.add(k, t, float(x[k]), float(y[k]), float(heading[k]))
                rec.publish(f"/robot{k}/path", PATH, path, t)

    def _semaphores(self, t: float) -> list[object]:
        g = self.territory.grid
        out: list[object] = []
        for k, cells in enumerate(self.semaphores):
            cx, cy = g.cell_centres(*np.nonzero(cells))
            pts = np.column_stack([cx, cy])
            out.append(
                marker(
                    t,
                    "semaphores",
                    CUBE_LIST,
                    pts,
                    ident=k,
                    scale=g.resolution,
                    height=0.02,
                    rgba=CROWDING_RGBA,
                )
            )
        return out
