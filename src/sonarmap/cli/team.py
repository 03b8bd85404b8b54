"""``sonarmap team``: each robot's long-term store and global map (a thin layer over
:mod:`sonarmap.team`)."""

from __future__ import annotations

import csv
import io
import math
from functools import partial
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from ..errors import ConfigError
from ..io._atomic import atomic_folder, atomic_write_text
from ..io._json import dumps as json_dumps
from ..io.rosmap import write_map
from ..team.animation import save_mission_animation
from ..team.globalmap import plot_pose_graph
from ..team.mission import MissionConfig, MissionResult, run_mission
from ..team.records import compose
from ..team.store import StoreParams
from ..team.world import load_world, make_world, patrol_route, read_route, save_world
from . import ImageOrigin, ImageResolution, _progress, _read_plan, _writable, console

team_app = typer.Typer(
    help="Team mapping: each robot's bounded store and global map (thesis 002, chapter 2).",
    no_args_is_help=True,
    context_settings={"help_option_names": ["-h", "--help"]},
)

MapOption = Annotated[
    Path, typer.Option("--map", help="Floor plan: map_server YAML, or an image with --resolution.")
]
OutOption = Annotated[
    Path, typer.Option("-o", "--out", callback=_writable, help="Folder for the results.")
]
SeedOption = Annotated[int, typer.Option("--seed", help="Seed of everything random.")]
DurationOption = Annotated[float, typer.Option("--duration", help="Mission length, seconds.")]

#: Summary figures averaged over the robots at the top level of summary.json.
MEAN_KEYS = (
    "association_precision",
    "association_recall",
    "ate_m",
    "ate_odometry_m",
    "map_f1",
    "map_f1_true_poses",
    "map_f1_odometry_poses",
    "alignment_error_m",
    "alignment_error_deg",
)


@team_app.command("world")
def world_cmd(
    out: OutOption,
    map_: MapOption,
    seed: SeedOption = 0,
    duration: DurationOption = 600.0,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
    texture_share: Annotated[
        float, typer.Option(help="Share of landmarks in repeated-texture groups.")
    ] = 0.2,
    change_share: Annotated[
        float, typer.Option(help="Share of landmarks that vanish (and as many that appear).")
    ] = 0.1,
) -> None:
    """Make a mission's world: landmarks with their changes, a patrol route, the truth."""
    plan = _read_plan(map_, resolution, origin)
    world = make_world(
        plan,
        seed=seed,
        duration=duration,
        texture_share=texture_share,
        change_share=change_share,
        plan_path=map_.resolve(),
    )
    route = patrol_route(plan, duration, seed=seed)
    save_world(world, route, out)
    console.print(f"{len(world)} landmarks, route of {len(route)} poses: {out}/world.yaml")


def _tick(update: Any, note: str, done: int, total: int) -> None:
    update(done, total, note)


def _check_bounds(pose_limit: int, region_limit: int) -> StoreParams:
    try:
        return StoreParams(pose_limit=pose_limit, region_limit=region_limit)
    except ConfigError as e:
        option = "--pose-limit" if str(e).startswith("store: pose_limit") else "--region-limit"
        raise ConfigError(f"{option}: {str(e).removeprefix('store: ')}") from None


def _summary(results: list[MissionResult]) -> dict[str, Any]:
    robots = [r.summary for r in results]
    out: dict[str, Any] = {"robots": robots}
    for key in MEAN_KEYS:
        vals = [float(r[key]) for r in robots if not math.isnan(float(r[key]))]
        out[key] = float(np.mean(vals)) if vals else float("nan")
    for key in ("store_bytes_peak", "store_bytes_final", "poses", "landmarks", "closures"):
        out[key] = int(sum(int(r[key]) for r in robots))
    return out


def _memory_csv(results: list[MissionResult]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["robot", "pose", "store_bytes"])
    for r in results:
        for i, b in enumerate(r.bytes_per_pose):
            w.writerow([r.summary["robot"], i, b])
    return buf.getvalue()


@team_app.command("run")
def run_cmd(
    out: OutOption,
    map_: MapOption,
    robots: Annotated[
        int, typer.Option("--robots", help="Robots, each with its own store (no exchange yet).")
    ] = 1,
    duration: DurationOption = 600.0,
    route: Annotated[
        Path | None, typer.Option("--route", help="Route CSV (t,x,y,theta) for robot 0.")
    ] = None,
    world_dir: Annotated[
        Path | None, typer.Option("--world", help="A folder made by 'team world'.")
    ] = None,
    pose_limit: Annotated[
        int, typer.Option("--pose-limit", help="M_pose: bytes a pose may take.")
    ] = StoreParams().pose_limit,
    region_limit: Annotated[
        int, typer.Option("--region-limit", help="M_r: bytes a region may take.")
    ] = StoreParams().region_limit,
    seed: SeedOption = 0,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
    animate: Annotated[
        bool,
        typer.Option(
            "--animate", help="Also write mission.gif: truth, odometry, kept poses, closures."
        ),
    ] = False,
) -> None:
    """One mission per robot: store, association, memory bounds, global map, scores."""
    if robots < 1:
        raise ConfigError(f"--robots must be >= 1, got {robots}")
    if not (math.isfinite(duration) and duration > 0):
        raise ConfigError(f"--duration must be > 0, got {duration}")
    if seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {seed}")
    store = _check_bounds(pose_limit, region_limit)
    plan = _read_plan(map_, resolution, origin)
    world = None
    routes: dict[int, Any] = {}
    if world_dir is not None:
        world, saved = load_world(world_dir)
        if saved is not None:
            routes[0] = saved
    if route is not None:
        routes[0] = read_route(route)
    config = MissionConfig(duration=duration, seed=seed, store=store)
    results = []
    with _progress("mission") as update:
        for robot in range(robots):
            results.append(
                run_mission(
                    plan,
                    config,
                    route=routes.get(robot),
                    world=world,
                    robot=robot,
                    progress=partial(_tick, update, f"robot {robot}"),
                    record=animate,
                )
            )
    with atomic_folder(out) as tmp:
        atomic_write_text(tmp / "summary.json", json_dumps(_summary(results)))
        atomic_write_text(tmp / "memory.csv", _memory_csv(results))
        for r in results:
            name = "map" if robots == 1 else f"map_robot{r.summary['robot']}"
            write_map(r.global_map, tmp / name)
            placed = {u: compose(r.alignment.transform, e) for u, e in r.graph.estimates.items()}
            plot_pose_graph(
                plan,
                placed,
                r.store.local.edges,
                r.store.closures,
                tmp / ("graph.png" if robots == 1 else f"graph_robot{r.summary['robot']}.png"),
                truth={u: t for u, t in r.truth.items() if u in placed},
                title=f"robot {r.summary['robot']}: ATE {r.summary['ate_m']:.2f} m "
                f"(odometry {r.summary['ate_odometry_m']:.2f} m)",
            )
            if animate:
                suffix = "" if robots == 1 else f"_robot{r.summary['robot']}"
                save_mission_animation(
                    r.frames,
                    plan,
                    r.alignment.transform,
                    tmp / f"mission{suffix}.gif",
                    title=f"robot {r.summary['robot']}",
                )
    s0 = _summary(results)
    console.print(
        f"precision {s0['association_precision']:.3f}, recall {s0['association_recall']:.3f}, "
        f"ATE {s0['ate_m']:.3f} m (odometry {s0['ate_odometry_m']:.3f} m), "
        f"map F1 {s0['map_f1']:.3f}, peak store {s0['store_bytes_peak']} B: {out}"
    )
