"""``sonarmap patrol``: a team keeps a territory watched (a thin layer over
:mod:`sonarmap.patrol`)."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from ..errors import ConfigError, InputError
from ..io._atomic import atomic_folder, atomic_write_text
from ..io._json import dumps as json_dumps
from ..patrol import Fog, PatrolConfig, Territory, parse_force, read_starts, run_patrol
from ..patrol.config import read_run_file
from ..patrol.experiments import run_experiment
from ..patrol.maps import write_builtin_maps
from ..patrol.robots import Team, parse_speed_bands
from ..patrol.semaphores import read_semaphores
from ..plot import FogAnimation, save_fog_picture
from .common import ImageOrigin, ImageResolution, console, progress, read_plan, writable

#: setup.json keys with no option of their own.
SETUP_ONLY = ("steps", "output_file", "log_period_steps")


def _load_settings(ctx: typer.Context, path: Path | None) -> Path | None:
    """--config (eager): the file's values become the command's defaults, so options
    given on the command line win; each value is converted by its option's own type."""
    if path is None:
        return None
    params = {("map" if q.name == "map_" else q.name): q for q in ctx.command.params if q.name}
    names = set(params) - {"config_file", "out", "ctx"}
    defaults: dict[str, Any] = {}
    setup: dict[str, Any] = {}
    for key, value in read_run_file(path, names | set(SETUP_ONLY)).items():
        if key in SETUP_ONLY:
            setup[key] = value
            continue
        param = params[key]
        try:
            defaults[str(param.name)] = param.process_value(ctx, value)
        except Exception as err:  # click's BadParameter (private in typer's vendored click)
            fmt = getattr(err, "format_message", None)
            raise InputError(str(fmt() if fmt else err), path=path, field=key) from None
    if "steps" in setup:
        try:
            steps = int(setup["steps"])
        except (TypeError, ValueError):
            raise InputError(
                f"expected a number of steps, got {setup['steps']!r}",
                path=path,
                field="max_model_time",
            ) from None
        defaults.setdefault("duration", steps * PatrolConfig().dt)
    ctx.default_map = {**(ctx.default_map or {}), **defaults}
    ctx.meta["patrol_setup"] = setup
    return path


app = patrol_app = typer.Typer(
    help="Team patrolling with potential fields (thesis 002, chapter 3).",
    no_args_is_help=True,
    context_settings={"help_option_names": ["-h", "--help"]},
)


@patrol_app.command("run")
def run_cmd(
    ctx: typer.Context,
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder for the results.")
    ],
    map_: Annotated[
        Path | None,
        typer.Option(
            "--map", help="Territory: map_server YAML, or a bare image with --resolution."
        ),
    ] = None,
    robots: Annotated[
        int | None, typer.Option(help="Robots (random starts, seeded) unless --starts.")
    ] = None,
    starts: Annotated[
        Path | None,
        typer.Option(help="Start file: the count, then 'X Y phi' per robot (dm from top-left)."),
    ] = None,
    policy: Annotated[
        str,
        typer.Option(help="potential (the thesis's), random, reactive, gravity or cycle."),
    ] = "potential",
    model: Annotated[
        str,
        typer.Option(
            help="holonomic (4.4 m/s or standing, turns at once) or car (turning radius, "
            "speed by the nearest obstacle, dead-end escape)."
        ),
    ] = "holonomic",
    motion: Annotated[
        str,
        typer.Option(
            help="Holonomic robots: straight (a full step along the chosen direction, the "
            "thesis's) or path (a step along the shortest path to the strongest pull that "
            "way; for doors narrower than a step)."
        ),
    ] = "straight",
    force: Annotated[str, typer.Option(help="Force law f1..f5 x g1..g5.")] = "f3g4",
    force_a: Annotated[float, typer.Option(help="a of the f family.")] = 40.0,
    force_b: Annotated[float, typer.Option(help="b of the g family, decimetres.")] = 65.0,
    direction: Annotated[str, typer.Option(help="mode or vector.")] = "mode",
    sectors: Annotated[int, typer.Option(help="mode: direction sectors.")] = 8,
    paths: Annotated[
        str,
        typer.Option(
            help="wave (follows crowding's map edits), straight (open space), regions "
            "(offline rectangles and doors) or marching (fast marching, Euclidean lengths)."
        ),
    ] = "wave",
    network: Annotated[
        str, typer.Option(help="full, limited (--r-max and line of sight) or none.")
    ] = "full",
    r_max: Annotated[float, typer.Option(help="limited network: link range, metres.")] = 70.0,
    dilation: Annotated[int, typer.Option(help="Fog dilation wing, cells.")] = 0,
    crowding: Annotated[
        str,
        typer.Option(help="none, obstacles (artificial obstacles around robots) or semaphores."),
    ] = "none",
    semaphores: Annotated[
        Path | None,
        typer.Option(help="Semaphore file: one polygon a line, 'x y;x y;...' in dm."),
    ] = None,
    r_obst: Annotated[
        float | None,
        typer.Option(help="Artificial obstacles' radius, metres (default 3 x --radius)."),
    ] = None,
    refine: Annotated[
        bool,
        typer.Option(
            "--refine/--no-refine",
            help="Direction refinement: head for the least obstacle-crowded point near a "
            "goal 2.5 m ahead.",
        ),
    ] = False,
    weaken: Annotated[
        bool,
        typer.Option(
            "--weaken/--no-weaken",
            help="Direction weakening: sectors scaled by min(1, r / 5.5 m), r the nearest "
            "obstacle in the sector (mode only).",
        ),
    ] = False,
    weaken_r0: Annotated[float, typer.Option(help="Weakening's R0, metres.")] = 5.5,
    refine_window: Annotated[
        float, typer.Option(help="Refinement's l: half the penalty window, metres.")
    ] = 10.0,
    refine_goal: Annotated[
        float, typer.Option(help="Refinement's R_G: the goal's distance, metres.")
    ] = 2.5,
    refine_side: Annotated[
        float, typer.Option(help="Refinement's r: side of the search square, metres.")
    ] = 2.0,
    radius: Annotated[float, typer.Option(help="Robot radius, metres.")] = 1.0,
    min_separation: Annotated[
        float | None,
        typer.Option(help="Least distance between robots' centres, m (default 2 x --radius)."),
    ] = None,
    p_random: Annotated[
        float, typer.Option(help="Chance per step that a blocked robot moves at random.")
    ] = 0.1,
    dt: Annotated[float, typer.Option(help="Step, seconds.")] = 0.5,
    start_fog: Annotated[float, typer.Option(help="TB of every place at the start, s.")] = 0.0,
    speed: Annotated[float, typer.Option(help="Holonomic robots' speed, m/s.")] = 4.4,
    turn_radius: Annotated[float, typer.Option(help="Cars' minimum turning radius, metres.")] = 3.5,
    speed_bands: Annotated[
        str,
        typer.Option(
            help="Cars' speed rule: 'D:KMH,...', KMH below D metres from the nearest "
            "obstacle, in order; the last D may be inf.",
        ),
    ] = "2:3,5:6,7.5:9,inf:15",
    vision: Annotated[float, typer.Option(help="Vision radius, metres.")] = 10.0,
    line_of_sight: Annotated[
        bool,
        typer.Option(
            "--line-of-sight/--disc",
            help="Vision blocked by obstacles, or a plain disc (the thesis's).",
        ),
    ] = False,
    duration: Annotated[float, typer.Option(help="Simulated seconds.")] = 3600.0,
    warmup: Annotated[
        float | None, typer.Option(help="Seconds left out of the mean MTB (default a fifth).")
    ] = None,
    cell: Annotated[
        float | None,
        typer.Option(
            help="Cell of the fog and paths, metres (default 0.5, or --radius / 2 if less)."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    animate: Annotated[
        bool, typer.Option("--animate", help="Also write OUT/patrol.gif (200 frames at most).")
    ] = False,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
    config_file: Annotated[
        Path | None,
        typer.Option(
            "--config",
            is_eager=True,
            callback=_load_settings,
            help="Settings from the thesis's setup.json or a patrol.yaml of option names; "
            "options given on the command line win.",
        ),
    ] = None,
) -> None:
    """Patrol a territory; writes metrics.csv, summary.json, fog.png (and patrol.gif)."""
    extra: dict[str, Any] = ctx.meta.get("patrol_setup", {})
    if map_ is None:
        raise ConfigError("give the territory: --map, or 'map' in --config")
    config = PatrolConfig(
        policy=policy,
        model=model,
        motion=motion,
        turn_radius=turn_radius,
        speed_bands=parse_speed_bands(speed_bands),
        force=parse_force(force, force_a, force_b),
        direction=direction,
        sectors=sectors,
        paths=paths,
        network=network,
        r_max=r_max,
        dilation=dilation,
        crowding=crowding,
        r_obst=math.nan if r_obst is None else r_obst,
        refine=refine,
        weaken=weaken,
        weaken_r0=weaken_r0,
        refine_window=refine_window,
        refine_goal=refine_goal,
        refine_side=refine_side,
        radius=radius,
        min_separation=math.nan if min_separation is None else min_separation,
        p_random=p_random,
        dt=dt,
        start_fog=start_fog,
        speed=speed,
        vision=vision,
        line_of_sight=line_of_sight,
        duration=duration,
        warmup=warmup,
        cell=math.nan if cell is None else cell,
    )
    territory = Territory.from_map(read_plan(map_, resolution, origin), cell=config.cell)
    start = read_starts(starts, territory) if starts is not None else None
    if robots is not None and robots < 1:
        raise ConfigError(f"robots must be >= 1, got {robots}")
    if start is not None and robots is not None:
        if robots > len(start):
            raise ConfigError(f"{robots} robots asked for, the start file has {len(start)}")
        start = start[:robots]  # robot_number: the first N of the start file
    areas = read_semaphores(semaphores, territory.grid) if semaphores is not None else None
    anim = FogAnimation(territory.grid, territory.free, radius=radius) if animate else None
    every = max(1, round(config.duration / config.dt) // 200)
    frame = {"k": 0}

    def keep(t: float, team: Team, fog: Fog) -> None:
        frame["k"] += 1
        if anim is not None and frame["k"] % every == 0:
            anim.add(t, fog.tb, np.column_stack([team.x, team.y, team.heading]))

    with progress("patrolling") as cb, atomic_folder(out) as tmp:
        res = run_patrol(
            territory,
            config,
            starts=start,
            robots=robots,
            seed=seed,
            progress=cb,
            on_step=keep if anim is not None else None,
            semaphores=areas,
        )
        if anim is not None:
            anim.title = f"{policy}, {res.summary()['robots']} robots"
            anim.save(tmp / "patrol.gif")
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["step", "t", "mtb", "mean_tb", "dvt"])
        for k in range(len(res.t)):
            w.writerow(
                [
                    k + 1,
                    f"{res.t[k]:g}",
                    f"{res.mtb[k]:g}",
                    f"{res.mean_tb[k]:.4g}",
                    f"{res.dvt[k]:.4g}",
                ]
            )
        atomic_write_text(tmp / "metrics.csv", buf.getvalue())
        if "output_file" in extra:
            # The thesis's batch output: 'step MTB DVT' every log_period_steps steps.
            period = max(1, int(extra.get("log_period_steps", 1)))
            rows = [
                f"{k + 1} {res.mtb[k]:g} {res.dvt[k]:.4g}"
                for k in range(len(res.t))
                if (k + 1) % period == 0
            ]
            atomic_write_text(tmp / Path(str(extra["output_file"])).name, "\n".join(rows) + "\n")
        summary: dict[str, Any] = {
            **res.summary(),
            "map": str(map_),
            "cell_m": territory.grid.resolution,  # the cell used (whole map pixels)
            "seed": seed,
            "params": config.as_dict(),
        }
        atomic_write_text(tmp / "summary.json", json_dumps(summary) + "\n")
        save_fog_picture(
            territory.grid,
            territory.free,
            res.final_tb,
            res.positions,
            tmp / "fog.png",
            radius=radius,
            title=f"{res.summary()['robots']} robots, t = {res.t[-1]:.0f} s",
        )
    console.print(
        f"mean MTB {summary['mean_mtb']:.1f} s (after {config.warmup_s:g} s), worst idleness "
        f"{summary['worst_idleness']:.0f} s, {summary['steps']} steps in "
        f"{summary['wall_seconds']:.1f} s; wrote {out}/metrics.csv, summary.json, fog.png"
    )


@patrol_app.command("maps")
def maps_cmd(
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder for the maps.")
    ],
) -> None:
    """Write the built-in territories (map_server YAML + PGM at 0.1 m), their start files
    and semaphore files."""
    with atomic_folder(out) as tmp:
        written = write_builtin_maps(tmp)
    console.print(f"wrote {len(written)} files to {out}: {', '.join(p.name for p in written)}")


@patrol_app.command("experiment")
def experiment_cmd(
    name: Annotated[
        str,
        typer.Argument(
            help="forces, paths, direction, car, refine, weaken, crowding, dilation, network "
            "or baselines."
        ),
    ],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder for the results.")
    ],
    quick: Annotated[
        bool,
        typer.Option("--quick", help="One seed, 300 s runs on 1 m cells: a smoke run."),
    ] = False,
    seeds: Annotated[int | None, typer.Option(help="Seeds per setting (default 3).")] = None,
    duration: Annotated[
        float | None, typer.Option(help="Simulated seconds per run (default 3600).")
    ] = None,
    cell: Annotated[
        float | None, typer.Option(help="Cell of the fog and paths, metres (default 0.5).")
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(help="Address of a running Dask scheduler; default a LocalCluster."),
    ] = None,
    workers: Annotated[
        int | None, typer.Option(help="LocalCluster worker processes (default: the cores).")
    ] = None,
) -> None:
    """Rerun one of the thesis's chapter-3 experiments on the built-in maps: runs.csv,
    table.csv, claims.json, figures and report.html in OUT."""
    with progress(f"patrol experiment {name}") as cb:
        report = run_experiment(
            name,
            out,
            quick=quick,
            seeds=seeds,
            duration=duration,
            cell=cell,
            scheduler=scheduler,
            workers=workers,
            progress=cb,
        )
    claims = json.loads((out / "claims.json").read_text())
    for c in claims:
        console.print(
            f"{c['verdict']}: {c['claim']}: {c['measured']} (thesis: {c['thesis']})", markup=False
        )
    console.print(f"wrote {report}")
