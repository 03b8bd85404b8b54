"""What a mission or a team's run reports: the rows of ``summary.json``, built once for the
simulated team (:func:`~.simulation.run_team`), the ZeroMQ team
(:func:`~.launcher.run_zmq_team`), single missions and every caller (the CLI, the
benchmarks, an API user).

A robot's row is its mission's scores (:meth:`~.mission.RobotAgent.finish`) with its
exchange counters; a team's summary adds the team's figures (duplicates, convergence,
bytes per robot-minute and their share of the naive baseline's, the team map's F1) and,
at the top level, the robots' mean scores and summed store figures
(:func:`mission_figures`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np

__all__ = [
    "MEAN_KEYS",
    "SUM_KEYS",
    "mission_figures",
    "naive_share_note",
    "robot_row",
    "team_figures",
]

#: Scores averaged over the robots at the top level of a summary (NaNs left out).
MEAN_KEYS = (
    "association_precision",
    "association_recall",
    "ate_m",
    "ate_odometry_m",
    "map_f1",
    "map_f1_true_poses",
    "map_f1_odometry_poses",
    "map_f1_held_true_poses",
    "alignment_error_m",
    "alignment_error_deg",
)
#: Store figures summed over the robots at the top level of a summary.
SUM_KEYS = ("store_bytes_peak", "store_bytes_final", "poses", "landmarks", "closures")


class _Stats(Protocol):
    bytes_sent: int
    bytes_received: int
    messages_sent: int
    messages_received: int
    closures_sent: int
    closures_received: int
    closures_added: int
    closures_duplicate: int
    closures_unheld: int
    closures_withheld: int

    @property
    def bytes_by_kind(self) -> Mapping[str, int]: ...


class _Agent(Protocol):
    @property
    def received_closures(self) -> int: ...

    @property
    def received_correct(self) -> int: ...

    @property
    def store(self) -> Any: ...


def _number(v: Any) -> float:
    """A score as a float; None (a NaN that went through JSON) as NaN."""
    return math.nan if v is None else float(v)


def robot_row(
    mission: Mapping[str, Any],
    agent: _Agent,
    stats: _Stats,
    links: tuple[int, int] | None = None,
) -> dict[str, Any]:
    """One robot's row of a team's summary.

    Parameters
    ----------
    mission : mapping
        The robot's mission summary (:attr:`~.mission.MissionResult.summary`).
    agent : RobotAgent
        The robot after its mission: its store's layers and its received closures.
    stats : ExchangeStats
        Its exchanger's counters.
    links : (int, int), optional
        Direct links the robot made and lost (the simulated network's counts).
    """
    store = agent.store
    row = dict(mission)
    row.update(
        {
            "bytes_sent": stats.bytes_sent,
            "bytes_by_kind": dict(sorted(stats.bytes_by_kind.items())),
            "bytes_received": stats.bytes_received,
            "messages": stats.messages_sent,
            "messages_received": stats.messages_received,
            "poses_local": len(store.local.poses),
            "poses_received": sum(len(x.poses) for x in store.received.values()),
            "received_closures": agent.received_closures,
            "received_closures_correct": agent.received_correct,
            "peer_closures": {
                "sent": stats.closures_sent,
                "received": stats.closures_received,
                "added": stats.closures_added,
                "duplicate": stats.closures_duplicate,
                "unheld": stats.closures_unheld,
                "withheld": stats.closures_withheld,
            },
        }
    )
    if links is not None:
        row["links_made"], row["links_broken"] = int(links[0]), int(links[1])
    return row


def mission_figures(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The robots' rows and, over them, the mean of each of :data:`MEAN_KEYS` (NaN where
    no robot has one) and the sum of each of :data:`SUM_KEYS`."""
    out: dict[str, Any] = {"robots": [dict(r) for r in rows]}
    for key in MEAN_KEYS:
        vals = [v for v in (_number(r[key]) for r in rows) if not math.isnan(v)]
        out[key] = float(np.mean(vals)) if vals else float("nan")
    for key in SUM_KEYS:
        out[key] = int(sum(int(r[key]) for r in rows))
    return out


def team_figures(
    rows: Sequence[Mapping[str, Any]],
    *,
    held: Sequence[set[int]],
    duplicates: int,
    route_seconds: float,
    sent_in_mission: int,
    naive_bytes: float | None,
    converged: bool,
    convergence_s: float,
    settle_seconds: float,
    settled: bool,
) -> dict[str, Any]:
    """The team's figures over its robots' rows.

    Parameters
    ----------
    rows : sequence of mapping
        The robots' rows (:func:`robot_row`), by robot id.
    held : sequence of set of int
        The pose UIDs each robot held once the network was quiet.
    duplicates : int
        Poses held twice, summed over the robots.
    route_seconds : float
        Seconds the routes lasted: the minutes of the per-minute figures.
    sent_in_mission : int
        Bytes the robots sent while they drove.
    naive_bytes : float, optional
        Bytes the naive baseline would have sent on the same mission (all robots); None
        when unknown.
    converged : bool
        Whether the exchange converged (the network went quiet, and on a full network
        every robot held every pose).
    convergence_s, settle_seconds : float
        Seconds from the routes' end to the last change, and of the quiet phase.
    settled : bool
        Whether the network went quiet within the settle time.
    """
    robots = len(rows)
    minutes = max(route_seconds, 1e-9) / 60.0
    f1 = [v for v in (_number(r["map_f1"]) for r in rows) if not math.isnan(v)]
    sent_all = sum(int(r["bytes_sent"]) for r in rows) / robots / minutes
    naive = sent_all if naive_bytes is None else naive_bytes / robots / minutes
    return {
        "robots": [dict(r) for r in rows],
        "robots_n": robots,
        "duplicate_poses": duplicates,
        "identical_maps": all(h == held[0] for h in held),
        "convergence_s": convergence_s if converged else None,
        "bytes_per_robot_minute": sent_in_mission / robots / minutes,
        # The quiet phase's bytes too, still per minute of mission: the maps are scored
        # after it, so a protocol that defers its sending must pay for it here.
        "bytes_per_robot_minute_all": sent_all,
        "naive_bytes_per_robot_minute": naive,
        "share_of_naive": sent_all / naive if naive > 0 else None,
        "map_f1_team": float(np.mean(f1)) if f1 else math.nan,
        "settle_seconds": settle_seconds,
        "settled": settled,
    }


def naive_share_note(summary: Mapping[str, Any]) -> str:
    """The bytes a team sent as a share of the naive baseline's, as a note for a line
    of text: ``" (12.3 % of the naive baseline's, quiet phase included)"``.

    Parameters
    ----------
    summary : mapping
        A team's summary (:func:`team_figures`, with its ``exchange``).

    Returns
    -------
    str
        The note with its leading space; empty for the naive baseline itself or a
        summary without the share.
    """
    share = summary.get("share_of_naive")
    if share is None or summary["exchange"]["mode"] == "naive":
        return ""
    return f" ({100 * share:.1f} % of the naive baseline's, quiet phase included)"
