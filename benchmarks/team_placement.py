"""Where a team's robots place the poses they hold: what the team map loses against the
central bound, split into the store, the graph and the alignment.

Four robots (``--robots``) patrol a map as ``sonarmap team run --map MAP --robots 4
--patrol`` drives them (the default lean exchange, a full network, the central bound),
and after the mission each robot's final global map is built again from its store,
once per start of its pose graph (``--starts``):

- ``odometry``: what the robot does (odometry chained from its oldest pose and from
  each received layer's oldest at its source's estimate);
- ``estimates``: every pose at its stored estimate (a received pose in its source's
  frame);
- ``placed``: our poses at ours, each received layer's moved into our frame by
  :func:`sonarmap.team.globalmap.layer_frames`.

and, with ``--levers``, once per lever a multi-robot SLAM system would pull to place
the received poses better (the graph started from odometry, as the robot's):

- ``sent-shape``: each received layer held as a shape at the estimates its source sent
  (:func:`shape_edges`: an edge from the layer's oldest pose to each other one at their
  estimates' relative pose, :data:`SHAPE_SIGMA`, which the graph takes as odometry, a
  known inlier): what a receiver can do today, at no byte;
- ``fresh-shape``: the same shape at the source's estimates at the mission's end
  (sending the source's optimised layer with its adverts, with ideal delivery: every
  estimate arrives, fresh, with no loss and no delay; no byte counted);
- ``source-closures``: the source's closures between two poses the receiver holds, one
  of them the source's, added to the receiver's graph unless it joins a pair of poses
  already joined, in either direction (:func:`source_closures`; the duplicates dropped
  are printed): exchanging them with ideal delivery, every one arriving with no loss
  and no delay, the bytes counted apart;
- ``source-revisits``: the same, only closures between poses made more than 30 s apart
  (the source's revisits, not its closures to the pose just before).

For the two closure levers it also prints what sending the added closures would cost:
each closure as its record's msgpack encoding (:func:`sonarmap.team.records.encode`, the
form an answer carries odometry edges in), without its feature matches, which the
receiver's graph does not use; uncompressed (the exchange compresses each message's
body in one zstd frame, and how closures would be batched into messages is not built).
It prints them per robot and minute and as points of the naive baseline's bytes added
to the run's share.

For each robot and start (or lever) it prints the map's F1 with the alignment the robot finds,
the F1 of the same map placed by the best rigid fit of the estimates to the truth (no
alignment error left), and the RMS position error after that one fit of the robot's own
poses and of its received poses (``ate_own``, ``ate_received``). Beside them, from the
mission: the robot's map F1, the held poses' map at their true poses (the store's
bound) and the correct closures its graph batches dropped during the mission.

Usage::

    python -m benchmarks.team_placement --map MAP [--robots 4] [--duration 600]
        [--seed 0] [--starts odometry estimates placed]
        [--levers sent-shape fresh-shape source-closures source-revisits] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
from collections.abc import Collection, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from sonarmap.cli.common import resolve_map
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.metrics import score
from sonarmap.team.association import estimate_planar
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.globalmap import (
    fuse_local_maps,
    grid_around,
    layer_frames,
    optimise_graph,
)
from sonarmap.team.mission import MissionConfig, RobotAgent
from sonarmap.team.network import NetworkParams
from sonarmap.team.patrolling import patrol_routes
from sonarmap.team.presets import DEFAULT_PRESET, PRESETS
from sonarmap.team.records import ClosureEdge, OdometryEdge, Pose, compose, encode, invert
from sonarmap.team.simulation import run_team
from sonarmap.team.store import StoreParams
from sonarmap.team.world import make_world

F64 = npt.NDArray[np.float64]
STARTS = ("odometry", "estimates", "placed")
LEVERS = ("sent-shape", "fresh-shape", "source-closures", "source-revisits")
#: The shape's standard deviations (m, m, rad) for the two shape levers.
SHAPE_SIGMA = (0.2, 0.2, 0.05)
#: Closures between poses made at most this far apart (s) are not revisits.
REVISIT_S = 30.0


def _graph_poses(agent: RobotAgent, start: str) -> tuple[dict[int, Pose], list[Any], int]:
    """Every pose the robot holds (estimates set for ``start``), every layer's odometry
    edges and the anchor (our oldest pose)."""
    store = agent.store
    poses = dict(store.local.poses)
    edges = list(store.local.edges)
    for source in sorted(store.received):
        poses.update(store.received[source].poses)
        edges.extend(store.received[source].edges)
    anchor = min(store.local.poses.values(), key=lambda p: (p.time, p.uid)).uid
    if start == "placed":
        frames = layer_frames(
            {u: p.estimate for u, p in store.local.poses.items()},
            {s: {u: p.estimate for u, p in ly.poses.items()} for s, ly in store.received.items()},
            store.closures,
        )
        for source, frame in frames.items():
            for uid, p in store.received[source].poses.items():
                poses[uid] = replace(p, estimate=compose(frame, p.estimate))
    return poses, edges, anchor


def closure_wire_bytes(c: ClosureEdge) -> int:
    """Bytes of one closure sent as its record (:func:`~sonarmap.team.records.encode`)
    without its feature matches, uncompressed."""
    return len(encode(replace(c, matches=())))


def shape_edges(
    layer: Mapping[int, Pose], sigma: tuple[float, float, float] = SHAPE_SIGMA
) -> list[OdometryEdge]:
    """Edges that hold ``layer`` at the shape of its poses' estimates (one frame, its
    source's): from its oldest pose (smallest time, then UID) to each other one, the
    transform their estimates' relative pose and the covariance diag(``sigma``^2)
    (m, m, rad). :func:`~sonarmap.team.globalmap.optimise_graph` takes them as odometry
    edges: known inliers. A layer of fewer than two poses gives none."""
    if len(layer) < 2:
        return []
    root = min(layer.values(), key=lambda p: (p.time, p.uid))
    to_root = invert(root.estimate)
    cov = tuple(np.diag(np.square(np.asarray(sigma, dtype=np.float64))).ravel().tolist())
    edges = []
    for uid in sorted(layer):
        if uid == root.uid:
            continue
        t = compose(to_root, layer[uid].estimate)
        # A shape, not a motion: no distance or turn bound applies.
        edges.append(OdometryEdge(root.uid, uid, (t[0], t[1], t[2]), cov, math.inf))
    return edges


def source_closures(
    held: Sequence[ClosureEdge],
    poses: Mapping[int, Pose],
    layers: Mapping[int, Collection[int]],
    sources: Mapping[int, Sequence[ClosureEdge]],
    *,
    min_gap: float = 0.0,
) -> tuple[list[ClosureEdge], int, int]:
    """The sources' closures a receiver would add to the ``held`` ones, and how many were
    dropped as duplicates.

    Parameters
    ----------
    held : sequence of ClosureEdge
        The receiver's closures.
    poses : mapping of UID to Pose
        Every pose the receiver holds.
    layers : mapping of robot number to collection of UID
        The UIDs of each source's poses the receiver holds.
    sources : mapping of robot number to sequence of ClosureEdge
        Each source's closures.
    min_gap : float
        Only closures between poses made more than this apart (s); default 0, all.

    Returns
    -------
    added : list of ClosureEdge
        A source's closures between two held poses, one of them that source's, the
        first of each pair of poses (in either direction) not in ``held``.
    duplicates : int
        Closures that passed the other tests but join a pair of poses already joined.
    reversed_only : int
        Those of ``duplicates`` whose pair was joined only the other way round (``b`` to
        ``a``).
    """
    seen = {frozenset((c.a, c.b)) for c in held}
    directed = {(c.a, c.b) for c in held}
    added: list[ClosureEdge] = []
    duplicates = reversed_only = 0
    for source in sorted(sources):
        mine = layers.get(source, ())
        for c in sources[source]:
            if c.a not in poses or c.b not in poses:
                continue
            if c.a not in mine and c.b not in mine:
                continue
            if min_gap > 0 and abs(poses[c.a].time - poses[c.b].time) <= min_gap:
                continue
            pair = frozenset((c.a, c.b))
            if pair in seen:
                duplicates += 1
                reversed_only += (c.a, c.b) not in directed
                continue
            added.append(c)
            seen.add(pair)
            directed.add((c.a, c.b))
    return added, duplicates, reversed_only


def _lever(
    agent: RobotAgent, team: Mapping[int, RobotAgent], poses: dict[int, Pose], lever: str
) -> tuple[list[ClosureEdge], list[OdometryEdge], int, int]:
    """The closures and the extra edges of the graph for ``lever`` (``poses`` is changed
    in place for ``fresh-shape``), and the counts of :func:`source_closures`
    (``duplicates``, ``reversed_only``)."""
    store = agent.store
    closures = list(store.closures)
    dropped = reversed_only = 0
    if lever in ("sent-shape", "fresh-shape"):
        if lever == "fresh-shape":
            for source, layer in store.received.items():
                now = team[source].store.local.poses
                for uid in layer.poses:
                    if uid in now:
                        poses[uid] = replace(poses[uid], estimate=now[uid].estimate.copy())
        shape: list[OdometryEdge] = []
        for source in sorted(store.received):
            shape.extend(shape_edges({u: poses[u] for u in store.received[source].poses}))
        return closures, shape, 0, 0
    if lever in ("source-closures", "source-revisits"):
        added, dropped, reversed_only = source_closures(
            closures,
            poses,
            {s: store.received[s].poses.keys() for s in store.received},
            {s: team[s].store.closures for s in store.received},
            min_gap=REVISIT_S if lever == "source-revisits" else 0.0,
        )
        closures.extend(added)
    return closures, [], dropped, reversed_only


def placement(
    agent: RobotAgent,
    truth: dict[int, F64],
    plan: OccupancyMap,
    start: str,
    *,
    lever: str | None = None,
    team: Mapping[int, RobotAgent] | None = None,
) -> dict[str, Any]:
    """The robot's final map rebuilt from its store with the graph started at ``start``
    (and, given ``lever``, one of :data:`LEVERS` pulled, from the stores of ``team``,
    every robot by its number): F1 (found alignment and rigid fit to the truth) and the
    placement errors.

    Raises
    ------
    ValueError
        ``lever`` given without ``team``, or not one of :data:`LEVERS`.
    """
    if lever is not None and (team is None or lever not in LEVERS):
        raise ValueError(f"lever {lever!r}: one of {', '.join(LEVERS)}, with the team")
    cfg, store = agent.cfg, agent.store
    poses, edges, anchor = _graph_poses(agent, start)
    closures: list[ClosureEdge] = list(store.closures)
    extra: list[OdometryEdge] = []
    duplicates = reversed_only = 0
    if lever is not None and team is not None:
        closures, extra, duplicates, reversed_only = _lever(agent, team, poses, lever)
    added = closures[len(store.closures) :]
    graph = optimise_graph(
        poses,
        edges + extra,
        closures,
        anchor=anchor,
        initial="odometry" if start == "odometry" else "estimates",
    )
    est = graph.estimates
    grid = grid_around(est, cfg.local_size / 2, cfg.map_resolution, margin=1.0)
    built = fuse_local_maps(poses, est, grid)
    found = np.asarray(agent.align(built).transform)
    f1 = score(
        plan, fuse_local_maps(poses, {u: compose(found, e) for u, e in est.items()}, plan.grid)
    )
    uids = [u for u in est if u in truth]
    e_xy = np.array([est[u][:2] for u in uids])
    t_xy = np.array([truth[u][:2] for u in uids])
    fit = estimate_planar(t_xy, e_xy)
    rigid = {u: compose(fit, e) for u, e in est.items()}
    f1_rigid = score(plan, fuse_local_maps(poses, rigid, plan.grid))
    err = np.array([np.hypot(*(rigid[u][:2] - truth[u][:2])) for u in uids])
    own = np.array([u in store.local.poses for u in uids])
    return {
        "robot": agent.robot,
        "start": start if lever is None else lever,
        "map_f1": f1.f1_all,
        "map_f1_rigid_to_truth": f1_rigid.f1_all,
        "ate_own_m": float(np.sqrt(np.mean(err[own] ** 2))) if own.any() else None,
        "ate_received_m": float(np.sqrt(np.mean(err[~own] ** 2))) if (~own).any() else None,
        "closures": len(closures),
        "closures_added": len(added),
        "closures_added_bytes": sum(closure_wire_bytes(c) for c in added),
        "closures_duplicate_dropped": duplicates,
        "closures_duplicate_reversed": reversed_only,
        "closures_rejected": len(graph.inconsistent),
    }


def _m(v: float | None) -> str:
    """Metres for the console; a robot with no such poses (one robot receives none)."""
    return "n/a" if v is None else f"{v:.3f} m"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", required=True, help="A map_server YAML or a built-in name.")
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--starts", nargs="+", choices=STARTS, default=list(STARTS))
    parser.add_argument("--levers", nargs="*", choices=LEVERS, default=[])
    parser.add_argument("--json", help="Also write the rows to this JSON file.")
    args = parser.parse_args(argv)
    plan = resolve_map(Path(args.map))
    exchange, store = PRESETS[DEFAULT_PRESET].apply(ExchangeParams(), StoreParams())
    cfg = MissionConfig(duration=args.duration, seed=args.seed, store=store)
    routes, _ = patrol_routes(plan, args.robots, args.duration, seed=args.seed)
    team = run_team(
        plan,
        cfg,
        args.robots,
        network=NetworkParams(kind="full"),
        exchange=exchange,
        seed=args.seed,
        world=make_world(plan, seed=args.seed, duration=args.duration),
        routes=list(routes),
        central=True,
    )
    s = team.summary
    central = s["central"]
    print(
        f"team F1 {s['map_f1_team']:.3f}, central {s['map_f1_central']:.3f} "
        f"(gap {s['map_f1_team'] - s['map_f1_central']:+.3f}, central ATE "
        f"{central['ate_m']:.3f} m), {100 * s['share_of_naive']:.1f} % of naive's bytes, "
        f"{s['duplicate_poses']} duplicates, identical pose sets {s['identical_maps']}"
    )
    for r in s["robots"]:
        graph = r["association_stages"]["graph"]
        print(
            f"robot {r['robot']}: map F1 {r['map_f1']:.3f}, held poses at truth "
            f"{r['map_f1_held_true_poses']:.3f}, ATE (own) {r['ate_m']:.3f} m, alignment "
            f"{r['alignment_error_m']:.2f} m off; the mission's graph batches dropped "
            f"{graph['removed_true']} correct closures of {graph['in']}"
        )
    truth: dict[int, F64] = {}
    for agent in team.agents:
        truth.update(agent.truth)
    by_robot = {agent.robot: agent for agent in team.agents}
    rows = []
    runs = [(start, None) for start in args.starts] + [("odometry", v) for v in args.levers]
    for start, lever in runs:
        for agent in team.agents:
            row = placement(agent, truth, plan, start, lever=lever, team=by_robot)
            rows.append(row)
            print(
                f"{row['start']:15s} robot {row['robot']}: F1 {row['map_f1']:.3f}, rigid to "
                f"truth {row['map_f1_rigid_to_truth']:.3f}, ATE own {_m(row['ate_own_m'])}, "
                f"received {_m(row['ate_received_m'])}, closures {row['closures']}"
            )
        name = start if lever is None else lever
        mine = [r for r in rows if r["start"] == name]
        print(f"{name:15s} mean F1 {np.mean([r['map_f1'] for r in mine]):.4f}")
        added = sum(r["closures_added_bytes"] for r in mine)
        if added:
            # Every robot receives what the others send: the bytes a robot sends, on
            # the mean, are the bytes the team received over the team's size.
            per_min = added / len(mine) / (args.duration / 60.0)
            points = 100 * per_min / s["naive_bytes_per_robot_minute"]
            print(
                f"{name:15s} {sum(r['closures_added'] for r in mine)} closures added "
                f"({sum(r['closures_duplicate_dropped'] for r in mine)} duplicates dropped, "
                f"{sum(r['closures_duplicate_reversed'] for r in mine)} of them joined only "
                "the other way round), "
                f"{added} B: {per_min:.0f} B per robot-minute, +{points:.2f} points of "
                f"naive's bytes ({100 * s['share_of_naive']:.1f} % -> "
                f"{100 * s['share_of_naive'] + points:.1f} %)"
            )
    if args.json:
        keys = ("map_f1_team", "map_f1_central", "share_of_naive", "duplicate_poses")
        team_row = {k: s[k] for k in (*keys, "identical_maps")}
        Path(args.json).write_text(json.dumps({"team": team_row, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
