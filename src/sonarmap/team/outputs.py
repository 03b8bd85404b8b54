"""The files a mission or a team's run writes: ``summary.json``, ``memory.csv`` (the store's
bytes after each pose), each robot's global map (map_server YAML + PGM + float ``.npy``)
and pose-graph picture, the central bound's map, the team's picture and, on request,
animations (``mission.gif`` per robot; ``team.gif``, and ``team.mp4`` where ffmpeg is
installed).

Everything is written into a temporary folder renamed into place at the end, so a failed
run leaves no half-written output.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..files import atomic_folder, atomic_write_text, json_dumps
from ..io.rosmap import OccupancyMap, write_map
from .mission import MissionResult
from .records import compose
from .simulation import TeamResult
from .summary import mission_figures

__all__ = ["memory_csv", "run_inputs", "write_missions", "write_prior", "write_run", "write_team"]

#: ``note(text)``: told each phase as it starts (a progress line).
Note = Callable[[str], None]


def memory_csv(results: Sequence[MissionResult]) -> str:
    """``robot,pose,store_bytes,local_bytes,local_bytes_bound``: each robot's whole store
    and its local layer after each pose it made, beside the local layer's configured
    bound (``local_bytes_bound`` of its summary). ``local_bytes`` is empty where the
    result has no such figure (a robot restored from a checkpoint keeps only the
    whole store's)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["robot", "pose", "store_bytes", "local_bytes", "local_bytes_bound"])
    for r in results:
        bound = r.summary["local_bytes_bound"]
        local = r.local_bytes_per_pose
        for i, b in enumerate(r.bytes_per_pose):
            w.writerow([r.summary["robot"], i, b, local[i] if i < len(local) else "", bound])
    return buf.getvalue()


def _write_robot(
    tmp: Path, plan: OccupancyMap, r: MissionResult, suffix: str, animate: bool
) -> None:
    """One robot's map, graph picture and (``animate``) animation, named with ``suffix``."""
    from .animation import save_mission_animation
    from .globalmap import plot_pose_graph

    robot = r.summary["robot"]
    write_map(r.global_map, tmp / f"map{suffix}")
    placed = {u: compose(r.alignment.transform, e) for u, e in r.graph.estimates.items()}
    plot_pose_graph(
        plan,
        placed,
        r.store.local.edges,
        r.store.closures,
        tmp / f"graph{suffix}.png",
        truth={u: t for u, t in r.truth.items() if u in placed},
        title=f"robot {robot}: ATE {r.summary['ate_m']:.2f} m "
        f"(odometry {r.summary['ate_odometry_m']:.2f} m)",
    )
    if animate:
        save_mission_animation(
            r.frames,
            plan,
            r.alignment.transform,
            tmp / f"mission{suffix}.gif",
            title=f"robot {robot}",
        )


def _files(folder: Path, tmp: Path) -> list[Path]:
    return sorted(folder / p.relative_to(tmp) for p in tmp.rglob("*") if p.is_file())


def write_missions(
    out: Path,
    plan: OccupancyMap,
    results: Sequence[MissionResult],
    *,
    animate: bool = False,
    note: Note | None = None,
    extra: Mapping[str, Any] | None = None,
) -> tuple[dict[str, Any], list[Path]]:
    """Write single missions' outputs into the folder ``out``: ``summary.json``
    (:func:`~.summary.mission_figures`, with the keys of ``extra`` added at its top
    level), ``memory.csv``, and per robot ``map.*``, ``graph.png`` (``mission.gif`` with
    ``animate``); with several robots, each name takes the suffix ``_robotK``. Returns
    the summary and the files written."""
    summary = mission_figures([r.summary for r in results])
    summary.update(extra or {})
    with atomic_folder(out) as tmp:
        atomic_write_text(tmp / "summary.json", json_dumps(summary))
        atomic_write_text(tmp / "memory.csv", memory_csv(results))
        for r in results:
            if note is not None:
                note(f"writing robot {r.summary['robot']}")
            suffix = "" if len(results) == 1 else f"_robot{r.summary['robot']}"
            _write_robot(tmp, plan, r, suffix, animate)
        files = _files(out, tmp)
    return summary, files


def write_team(
    out: Path,
    plan: OccupancyMap,
    team: TeamResult,
    *,
    animate: bool = False,
    note: Note | None = None,
) -> list[Path]:
    """Write a team's outputs into the folder ``out``: ``summary.json`` (the team's
    summary), ``memory.csv``, per robot ``map_robotK.*`` and ``graph_robotK.png``, the
    central bound's ``map_central.*``, ``team.png``; with ``animate`` each robot's
    ``mission_robotK.gif`` and ``team.gif`` (and ``team.mp4`` where ffmpeg is
    installed). Returns the files written."""
    from .animation import mp4_available, save_team_animation
    from .globalmap import plot_team

    with atomic_folder(out) as tmp:
        atomic_write_text(tmp / "summary.json", json_dumps(team.summary))
        atomic_write_text(tmp / "memory.csv", memory_csv(team.robots))
        for r in team.robots:
            if note is not None:
                note(f"writing robot {r.summary['robot']}")
            _write_robot(tmp, plan, r, f"_robot{r.summary['robot']}", animate)
        if team.central is not None:
            write_map(team.central.global_map, tmp / "map_central")
        graphs = []
        for r in team.robots:
            own = {u: e for u, e in r.graph.estimates.items() if u in r.store.local.poses}
            placed = {u: compose(r.alignment.transform, e) for u, e in own.items()}
            graphs.append((f"robot {r.summary['robot']}", placed, r.store.local.edges))
        plot_team(
            plan,
            graphs,
            tmp / "team.png",
            title=f"{len(team.robots)} robots, {team.summary['network']['kind']} network, "
            f"{team.summary['exchange']['mode']} exchange: team F1 "
            f"{team.summary['map_f1_team']:.3f}",
        )
        if animate and team.team_frames:
            kind = team.summary["network"]["kind"]
            names = ["team.gif", "team.mp4"] if mp4_available() else ["team.gif"]
            for name in names:
                if note is not None:
                    note(f"writing {name}")
                save_team_animation(
                    plan,
                    team.team_frames,
                    tmp / name,
                    title=f"{len(team.robots)} robots, {kind} network",
                )
        files = _files(out, tmp)
    return files


def write_run(
    out: Path,
    plan: OccupancyMap,
    result: MissionResult | TeamResult,
    *,
    prior: OccupancyMap | None = None,
    prior_record: Mapping[str, Any] | None = None,
    territory_record: Mapping[str, Any] | None = None,
    preset: str | None = None,
    animate: bool = False,
) -> dict[str, Any]:
    """Write what ``team run`` writes of one robot's mission or a team's into the
    folder ``out``: :func:`write_missions` or :func:`write_team`, their summary adding
    what it records of the prior and the territory, and the prior the robots were given.

    Parameters
    ----------
    out : Path
        The folder.
    plan : OccupancyMap
        The truth the robots were scored on.
    result : MissionResult or TeamResult
        One robot's mission (:func:`~.mission.run_mission`) or a team's
        (:func:`~.simulation.run_team`).
    prior : OccupancyMap, optional
        The robots' prior map (:func:`~.prior.make_prior`), written as ``prior.*``
        beside the maps; None (the plan itself): nothing.
    prior_record, territory_record : mapping, optional
        What the summary records of the prior and of the territory (as ``prior`` and
        ``territory``; nothing when None).
    preset : str or None
        A team's exchange and store preset (:mod:`.presets`; None for none), recorded
        in its summary as ``preset``; a single mission records none.
    animate : bool
        Write the animations too. Default False.

    Returns
    -------
    dict
        The summary written.
    """
    extra = run_inputs(prior_record, territory_record)
    if isinstance(result, TeamResult):
        result.summary.update(extra)
        result.summary["preset"] = preset
        write_team(out, plan, result, animate=animate)
        summary = result.summary
    else:
        summary, _ = write_missions(out, plan, [result], animate=animate, extra=extra or None)
    # After the run's own files: a failed write leaves no prior behind.
    write_prior(out, prior)
    return summary


def run_inputs(
    prior_record: Mapping[str, Any] | None, territory_record: Mapping[str, Any] | None
) -> dict[str, Any]:
    """What a run's summary records of its inputs: ``prior`` and ``territory``, each
    only when given (not None), in that order.

    Parameters
    ----------
    prior_record, territory_record : mapping or None
        What :func:`~.prior.make_prior` and :func:`~.inputs.run_territory` record.

    Returns
    -------
    dict
        The summary's entries (empty when both are None).
    """
    records = {"prior": prior_record, "territory": territory_record}
    return {k: v for k, v in records.items() if v is not None}


def write_prior(folder: Path, prior: OccupancyMap | None) -> None:
    """Write the prior the robots were given as ``prior.*`` in ``folder``, beside the
    truth they were scored on; nothing when ``prior`` is None (the plan itself)."""
    if prior is not None:
        write_map(prior, folder / "prior")
