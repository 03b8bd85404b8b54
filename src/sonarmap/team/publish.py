"""A team mapping run as ROS 2 messages, for a bag or a live viewer
(:mod:`sonarmap.io.record`).

:class:`TeamPublisher` observes a run: :func:`~.simulation.run_team`'s ``on_tick``
(:meth:`TeamPublisher.__call__`) or, for one robot alone, :func:`~.mission.run_mission`'s
``on_step`` (:meth:`TeamPublisher.robot_step`). Topics, stamped in mission seconds:

- ``/map`` (``nav_msgs/OccupancyGrid``, frame ``map``): the floor plan, trinary as
  ``map_server`` publishes a map (0 free, 100 occupied, -1 unknown); once, at time 0
  when the publisher is made;
- ``/tf`` (``tf2_msgs/TFMessage``): every tick, ``map -> robotK/base_link``, each
  robot's true pose (one message holding them all);
- ``/robotK/path`` (``nav_msgs/Path``): every ``path_every`` seconds (2), robot K's
  true trail over the last ``trail`` seconds (60);
- ``/robots`` (``visualization_msgs/MarkerArray``): every tick, a disc per robot;
- ``/network`` (the same type): every tick, the network's direct links;
- ``/robotK/map`` (``nav_msgs/OccupancyGrid``): every ``map_every`` seconds (10), robot
  K's global map: the local maps of every pose its store holds (its own and those
  received), fused at its pose graph's estimates on the plan's grid, trinary. The robot
  believes its frame is the plan's (it starts where it thinks), so the map is drawn
  as the robot holds it, before the alignment that scores it;
- ``/robotK/graph`` (``visualization_msgs/MarkerArray``): every ``map_every`` seconds,
  robot K's pose graph at its estimates: its kept poses (spheres), their odometry
  chain, its loop closures (lines) and the poses received from the others;
- ``/robotK/bytes_sent`` and ``/bytes_sent`` (``std_msgs/Float64``): every tick, the
  message bytes robot K, and the team, have sent so far (plot them).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError
from ..io.record import Recorder, trinary
from ..io.rosmap import OccupancyMap
from ..io.rosmsg import (
    CYLINDER,
    FLOAT,
    GRID,
    LINE_LIST,
    MARKERS,
    PATH,
    SPHERE_LIST,
    TF,
    Trails,
    float_message,
    grid_message,
    marker,
    markers_message,
    tf_message,
    transform,
)
from .globalmap import fuse_local_maps
from .mission import RobotAgent
from .simulation import TeamTick

__all__ = ["ROBOT_TOPICS", "TOPICS", "TeamPublisher", "global_map_now", "robot_frame"]

#: The team's topics, and their types; :data:`ROBOT_TOPICS` per robot (``/robotK/...``).
TOPICS = {"/map": GRID, "/tf": TF, "/robots": MARKERS, "/network": MARKERS, "/bytes_sent": FLOAT}
ROBOT_TOPICS = {"path": PATH, "map": GRID, "graph": MARKERS, "bytes_sent": FLOAT}

ROBOT_RGBA = (0.1, 0.4, 0.9, 0.9)
LINK_RGBA = (0.1, 0.8, 0.2, 0.9)
POSE_RGBA = (0.95, 0.6, 0.1, 0.9)
CHAIN_RGBA = (0.6, 0.6, 0.6, 0.8)
CLOSURE_RGBA = (0.9, 0.1, 0.1, 0.9)
RECEIVED_RGBA = (0.5, 0.2, 0.8, 0.7)
#: Diameter of a robot's disc on ``/robots``, metres (the team's robots have no size).
ROBOT_DIAMETER = 0.5


def robot_frame(k: int) -> str:
    """Robot ``k``'s frame in ``/tf``."""
    return f"robot{k}/base_link"


def global_map_now(agent: RobotAgent) -> OccupancyMap:
    """Robot ``agent``'s global map as it holds it now: every stored pose's local map at
    the last batch's estimates (the pose's own estimate for poses made since), on the
    plan's grid."""
    graph = agent.graph
    return fuse_local_maps(
        agent.all_poses(), None if graph is None else graph.estimates, agent.plan.grid
    )


class TeamPublisher:
    """A team run's topics (the module's) into a recorder.

    Parameters
    ----------
    recorder : Recorder
    plan : OccupancyMap
        The floor plan (``/map``).
    map_every : float
        Mission seconds between two ``/robotK/map`` and ``/robotK/graph`` (> 0); default
        10.
    path_every : float
        Mission seconds between two trail samples and ``/robotK/path`` (> 0); default 2.
    trail : float
        Seconds of trail on ``/robotK/path`` (> 0); default 60.
    """

    def __init__(
        self,
        recorder: Recorder,
        plan: OccupancyMap,
        *,
        map_every: float = 10.0,
        path_every: float = 2.0,
        trail: float = 60.0,
    ) -> None:
        for name, v in (("map_every", map_every), ("path_every", path_every), ("trail", trail)):
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be > 0 seconds, got {v}")
        self.recorder = recorder
        self.plan = plan
        self.map_every = map_every
        self.path_every = path_every
        self.trail = trail
        self.ticks = 0
        self._trails = Trails(0, trail)
        self._last: TeamTick | None = None
        # At once, before the run's set-up: a live viewer sees the floor from the start.
        recorder.declare(TOPICS)
        recorder.publish("/map", GRID, grid_message(plan.grid, 0.0, trinary(plan.classes())), 0.0)

    def robot_step(self, t: float, agent: RobotAgent) -> None:
        """``run_mission``'s ``on_step``: one robot alone, no network."""
        self(TeamTick(t, True, [agent], np.zeros((0, 2), dtype=np.int64), [0]))

    def __call__(self, tick: TeamTick) -> None:
        """Publish the team after one tick."""
        rec, t, agents = self.recorder, tick.t, tick.agents
        self._last = tick
        if self.ticks == 0:
            self._trails = Trails(len(agents), self.trail)
            rec.declare(
                {
                    f"/robot{a.robot}/{name}": msgtype
                    for a in agents
                    for name, msgtype in ROBOT_TOPICS.items()
                }
            )
        self.ticks += 1
        poses = np.array([a.route[max(a.k - 1, 0), 1:4] for a in agents], dtype=np.float64)
        tfs = [
            transform(t, "map", robot_frame(a.robot), *poses[k].tolist())
            for k, a in enumerate(agents)
        ]
        rec.publish("/tf", TF, tf_message(tfs), t)
        discs = [
            marker(t, "robots", CYLINDER, [], ident=k, scale=ROBOT_DIAMETER, height=0.2, at=(x, y))
            for k, (x, y) in enumerate(poses[:, :2].tolist())
        ]
        rec.publish("/robots", MARKERS, markers_message(t, discs), t)
        ends = [(*poses[i, :2], *poses[j, :2]) for i, j in np.asarray(tick.links).tolist()]
        links = [marker(t, "links", LINE_LIST, np.reshape(ends, (-1, 2)), rgba=LINK_RGBA)]
        rec.publish("/network", MARKERS, markers_message(t, links), t)
        for a, sent in zip(agents, tick.bytes_sent, strict=True):
            rec.publish(f"/robot{a.robot}/bytes_sent", FLOAT, float_message(sent), t)
        rec.publish("/bytes_sent", FLOAT, float_message(sum(tick.bytes_sent)), t)
        if rec.due("path", t, self.path_every):
            for k, a in enumerate(agents):
                path = self._trails.add(k, t, *(float(v) for v in poses[k]))
                rec.publish(f"/robot{a.robot}/path", PATH, path, t)
        if rec.due("map", t, self.map_every):
            self.maps(t, agents)

    def finish(self) -> None:
        """The robots' maps and graphs as the run left them (after the robots' last
        batch, which :func:`~.simulation.run_team` runs once the ticks are over)."""
        if self._last is not None:
            self.maps(self._last.t, self._last.agents)

    def maps(self, t: float, agents: Sequence[RobotAgent]) -> None:
        """Each robot's global map and pose graph now."""
        rec = self.recorder
        for a in agents:
            m = global_map_now(a)
            rec.publish(
                f"/robot{a.robot}/map", GRID, grid_message(m.grid, t, trinary(m.classes())), t
            )
            rec.publish(f"/robot{a.robot}/graph", MARKERS, _graph_markers(t, a), t)


def _xy(poses: Any, uids: Sequence[int]) -> npt.NDArray[np.float64]:
    return np.array([poses[u].estimate[:2] for u in uids], dtype=np.float64).reshape(-1, 2)


def _graph_markers(t: float, agent: RobotAgent) -> Any:
    """Robot ``agent``'s pose graph at its estimates."""
    store = agent.store
    own = store.local.poses
    held = agent.all_poses()
    chain = [
        (*own[e.a].estimate[:2], *own[e.b].estimate[:2])
        for e in store.local.edges
        if e.a in own and e.b in own
    ]
    closures = [
        (*held[c.a].estimate[:2], *held[c.b].estimate[:2])
        for c in store.closures
        if c.a in held and c.b in held
    ]
    received = [u for u in held if u not in own]
    parts = [
        marker(t, "poses", SPHERE_LIST, _xy(own, list(own)), scale=0.25, rgba=POSE_RGBA),
        marker(t, "odometry", LINE_LIST, np.reshape(chain, (-1, 2)), scale=0.05, rgba=CHAIN_RGBA),
        marker(
            t,
            "closures",
            LINE_LIST,
            np.reshape(closures, (-1, 2)),
            scale=0.08,
            rgba=CLOSURE_RGBA,
        ),
        marker(t, "received", SPHERE_LIST, _xy(held, received), scale=0.2, rgba=RECEIVED_RGBA),
    ]
    return markers_message(t, parts)
