"""The central upper bound of a team's map (issue 15, ``map_f1_central``): one map from
all robots' data with no memory or bandwidth limits.

Built as a central server holding every robot's raw data would build it, with the
robots' own algorithms:

- **Every pose every robot made**, as made: landmarks observed again from the
  simulation's record of the observation (:func:`~.world.observe` with the robot's seed
  at the pose's true place and time, which is how the robot made them: the same
  values, without the stamps and reliabilities the robots' stores changed since) and
  the pose's local sonar map; none compressed, deleted or merged. Its initial estimate
  is the robot's dead reckoning (its believed start and odometry).
- **Odometry edges** between each robot's successive poses, from its odometry with the
  covariance and hard bound the robots use.
- **Association** of each pose, in mission time order, with every earlier pose of any
  robot (:func:`~.association.associate`, the mission's parameters), the hard odometry
  bound (top speed x elapsed time) against the same robot's poses and none against
  another's. The robots' tighter gate needs their running drift estimate, which belongs
  to their bounded stores; a central graph has GNC to reject what the gate would have.
- **One graph** over all of it (gtsam GNC, robot 0's first pose the anchor), fused and
  aligned to the prior map and scored as each robot's map is
  (:meth:`~.mission.RobotAgent.finish`).

Nothing here uses the true poses but to observe the landmarks exactly as the robots
did and to score, so the bound measures the data and the algorithms, not the truth.
The alternative of rerunning the team with unbounded stores over an ideal network
would still map each pose from one robot's point of view, with its gate and its
batches, and would cost a second team run; a single graph over every pose is the
upper bound the issue names.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from ..io.rosmap import OccupancyMap
from ..metrics import score
from .association import Prior, associate
from .calibration import HEADING_BIAS_PRIOR
from .globalmap import (
    Alignment,
    GraphResult,
    fuse_local_maps,
    grid_around,
    optimise_graph,
)
from .mission import RobotAgent
from .quantise import check_quantisation, quantise_pose
from .records import ClosureEdge, OdometryEdge, Pose, compose, invert
from .scoring import closure_correct, rigid_ate
from .world import ODOMETRY_MODEL, observe, odometry_covariance

__all__ = ["CentralResult", "central_map", "raw_poses"]

F64 = npt.NDArray[np.float64]


@dataclass
class CentralResult:
    """The central map and what it measured.

    Attributes
    ----------
    summary : dict
        ``map_f1`` (wall F1 of the aligned map against the plan), ``poses``,
        ``odometry_edges``, ``closures`` found, ``closures_correct``,
        ``closures_rejected_by_graph``, ``ate_m`` (all poses, after a rigid fit),
        ``alignment_score_m`` and ``wall_seconds``.
    global_map : OccupancyMap
        On the plan's grid, placed by the alignment found.
    graph : GraphResult
    alignment : Alignment
    poses : dict of int to Pose
    """

    summary: dict[str, Any]
    global_map: OccupancyMap
    graph: GraphResult
    alignment: Alignment
    poses: dict[int, Pose]


def raw_poses(agent: RobotAgent) -> list[Pose]:
    """The poses ``agent`` made, as made, at its dead-reckoned estimates."""
    out = []
    for uid in agent.truth:  # the poses made (not merged), in the order made
        made = agent.made[uid]
        landmarks = observe(agent.world, agent.truth[uid], made.time, seed=agent.seed)
        out.append(
            replace(
                made, estimate=np.asarray(agent.odo_poses[uid], dtype=np.float64).copy()
            ).with_landmarks(landmarks)
        )
    return out


def _odometry_edges(agent: RobotAgent, poses: Sequence[Pose]) -> list[OdometryEdge]:
    """Edges between successive poses, as the robot makes them from its odometry."""
    t = agent.route[:, 0]
    odo, cfg = agent.odo, agent.cfg
    out = []
    for a, b in itertools.pairwise(poses):
        ka = int(np.searchsorted(t, a.time))
        kb = int(np.searchsorted(t, b.time))
        step = compose(invert(odo[ka, 1:4]), odo[kb, 1:4])
        cov = odometry_covariance(odo, ka, kb, ODOMETRY_MODEL, bias_sd=HEADING_BIAS_PRIOR)
        out.append(
            OdometryEdge(
                a.uid,
                b.uid,
                (float(step[0]), float(step[1]), float(step[2])),
                tuple(float(v) for v in cov.ravel()),
                cfg.max_speed * (b.time - a.time) + 0.05,
            )
        )
    return out


def central_map(
    agents: Sequence[RobotAgent],
    *,
    seed: int | None = None,
    descriptor_bits: int = 8,
    ternary_maps: bool = False,
) -> CentralResult:
    """The central upper bound over the data of ``agents`` (after their missions).

    Parameters
    ----------
    agents : sequence of RobotAgent
        The team's robots, their routes processed; robot ``agents[0]``'s first pose
        anchors the graph, and its mission settings (association, resolution, the
        prior map and the plan the map is scored on) are used.
    seed : int, optional
        The alignment's seed; default the first robot's mission seed.
    descriptor_bits, ternary_maps : int, bool
        Build the bound from every pose quantised as it would travel
        (:func:`~.quantise.quantise_pose`): what the quantisation alone costs the map.
        Default exact.

    Returns
    -------
    CentralResult
    """
    if not agents:
        raise ValueError("central_map needs at least one robot")
    wall0 = time.perf_counter()
    lead = agents[0]
    cfg, plan = lead.cfg, lead.plan
    check_quantisation(descriptor_bits, ternary_maps)
    by_robot = [
        [quantise_pose(p, descriptor_bits, ternary_maps) for p in raw_poses(a)] for a in agents
    ]
    poses = {p.uid: p for ps in by_robot for p in ps}
    edges = [e for a, ps in zip(agents, by_robot, strict=True) for e in _odometry_edges(a, ps)]
    truth = {u: t for a in agents for u, t in a.truth.items()}
    order = sorted(poses.values(), key=lambda p: (p.time, p.robot, p.uid))

    closures: list[ClosureEdge] = []
    stored: list[Pose] = []
    for pose in order:
        if stored:
            priors = {
                p.uid: Prior((0.0, 0.0, 0.0), cfg.max_speed * (pose.time - p.time) + 0.05)
                for p in stored
                if p.robot == pose.robot
            }
            found, _ = associate(pose, stored, priors, cfg.association)
            closures.extend(found)
        stored.append(pose)

    anchor = by_robot[0][0].uid if by_robot[0] else None
    graph = optimise_graph(poses, edges, closures, anchor=anchor)
    built = fuse_local_maps(
        poses,
        graph.estimates,
        grid_around(graph.estimates, cfg.local_size / 2, cfg.map_resolution, margin=1.0),
    )
    # Robot 0's frame (its first pose anchors the graph), with its belief of its start.
    alignment = lead.align(built, seed=seed)
    a = np.asarray(alignment.transform, dtype=np.float64)
    in_prior = {u: compose(a, e) for u, e in graph.estimates.items()}
    global_map = fuse_local_maps(poses, in_prior, plan.grid)
    uids = sorted(graph.estimates)
    est = np.array([graph.estimates[u][:2] for u in uids]).reshape(-1, 2)
    tru = np.array([truth[u][:2] for u in uids]).reshape(-1, 2)
    correct = sum(
        closure_correct(c, truth[c.a], truth[c.b], cfg.correct_xy, cfg.correct_theta)
        for c in closures
    )
    summary: dict[str, Any] = {
        "map_f1": score(plan, global_map).f1_all,
        "poses": len(poses),
        "odometry_edges": len(edges),
        "closures": len(closures),
        "closures_correct": int(correct),
        "closures_rejected_by_graph": len(graph.inconsistent),
        "ate_m": rigid_ate(est, tru),
        "alignment_score_m": float(alignment.score),
        "wall_seconds": time.perf_counter() - wall0,
    }
    return CentralResult(summary, global_map, graph, alignment, poses)
