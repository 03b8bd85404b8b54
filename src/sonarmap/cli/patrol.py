"""``sonarmap patrol``: a team keeps a territory watched (a thin layer over
:mod:`sonarmap.patrol`)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from ..errors import ConfigError, InputError, quote
from ..files import atomic_folder
from ..patrol import Fog, PatrolConfig
from ..patrol.config import read_run_file
from ..patrol.robots import Team
from ..patrol.simulation import MAX_STEPS
from ..patrol.starts import MAX_ROBOTS
from .common import (
    BagOption,
    ImageOrigin,
    ImageResolution,
    LiveOption,
    LivePortOption,
    LiveRateOption,
    Opt,
    config_from_options,
    config_options,
    console,
    named_check,
    progress,
    resolve_map,
    writable,
    wrote,
    wrote_folder,
)

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
        except (TypeError, ValueError, OverflowError):
            raise InputError(
                f"expected a number of steps, got {quote(setup['steps'])}",
                path=path,
                field="max_model_time",
            ) from None
        if not (1 <= steps <= MAX_STEPS):
            raise InputError(
                f"{steps:g} steps; must be in 1..{MAX_STEPS:,}", path=path, field="max_model_time"
            )
        defaults.setdefault("duration", steps * PatrolConfig().dt)
    ctx.default_map = {**(ctx.default_map or {}), **defaults}
    ctx.meta["patrol_setup"] = setup
    return path


#: Where --help points for more.
EPILOG = "Guide: docs/guides/patrolling.md; the model: docs/patrol.md."

app = patrol_app = typer.Typer(
    help="Team patrolling with potential fields (thesis 002, chapter 3).",
    epilog=EPILOG,
    no_args_is_help=True,
    context_settings={"help_option_names": ["-h", "--help"]},
)


#: The options of ``patrol run`` that set :class:`~sonarmap.patrol.PatrolConfig`'s
#: fields, in ``--help``'s order (types and defaults from the dataclass).
PATROL_OPTIONS = (
    Opt(
        "policy",
        "How a robot picks its way: potential (the thesis's potential field), "
        "random, reactive, gravity, cycle, or cr / hcr / sebs (conscientious and heuristic "
        "conscientious reactive agents, the state exchange Bayesian strategy, on the patrol "
        "graph).",
    ),
    Opt(
        "model",
        "holonomic (4.4 m/s or standing, turns at once) or car (turning radius, "
        "speed by the nearest obstacle, dead-end escape).",
    ),
    Opt(
        "motion",
        "Holonomic robots: straight (a full step along the chosen direction, the "
        "thesis's) or path (a step along the shortest path to the strongest pull that way; "
        "for doors narrower than a step).",
    ),
    Opt(
        "force",
        "The force law: f1..f5 (how the pull of a place grows with the time it "
        "has gone unseen) times g1..g5 (how it falls with distance), e.g. f3g4; see "
        "docs/patrol.md.",
        kind=str,
        default="f3g4",
        metavar="fNgM",
    ),
    Opt(
        "direction",
        "How the pulls become a heading: mode (the strongest of --sectors "
        "sectors) or vector (their sum).",
    ),
    Opt("sectors", "mode: number of direction sectors around a robot."),
    Opt(
        "paths",
        "Path lengths: wave (follows crowding's map edits), straight (open space), "
        "regions (offline rectangles and doors) or marching (fast marching, Euclidean).",
    ),
    Opt("network", "Who hears whom: full, limited (--link-range and line of sight) or none."),
    Opt(
        "r_max",
        "limited network: the link range, metres.",
        flag="--link-range",
        aliases=("--r-max", "--range"),
    ),
    Opt(
        "reach",
        "The places watched: reachable (what a robot of --radius can get to from the "
        "starts; free space it cannot reach is reported, not counted) or free (every "
        "free cell, the thesis's reading).",
        flag="--territory-mode",
    ),
    Opt("dilation", "Fog dilation: cells by which each unseen area grows every step."),
    Opt(
        "crowding",
        "none, obstacles (artificial obstacles around robots) or semaphores (--semaphores).",
    ),
    Opt(
        "traffic",
        "When moves would collide: thesis (both robots stop) or give-way (the later "
        "robot stops first and, blocked, plans around the earlier robots near it for 5 s); "
        "auto: give-way with the path motion.",
    ),
    Opt(
        "keep_goal",
        "Path motion: keep the place a robot goes for until it is seen, or choose "
        "again every step.",
        off="--choose-every-step",
    ),
    Opt(
        "min_hold",
        "Path motion: keep the place a robot goes for at least this many seconds, even "
        "once seen (fewer choices, each a wave over the places that could change it).",
    ),
    Opt(
        "choice_cell",
        "Path motion: choose each new place on blocks about this many metres wide, then "
        "run the fine wave only as far as it (0: choose on the map's own cells).",
    ),
    Opt(
        "claim",
        "Path motion, full network: while a robot chooses, the places within this many "
        "metres of a place another robot goes for pull as if just seen (0: off).",
    ),
    Opt(
        "r_obst", "Artificial obstacles' radius, metres (default 3 x --radius).", unset_as=math.nan
    ),
    Opt(
        "refine",
        "Direction refinement: head for the least obstacle-crowded point near a goal 2.5 m ahead.",
        off="--no-refine",
    ),
    Opt(
        "weaken",
        "Direction weakening: sectors scaled by min(1, r / 5.5 m), r the nearest "
        "obstacle in the sector (mode only).",
        off="--no-weaken",
    ),
    Opt("weaken_r0", "Weakening's distance at which a sector keeps its whole pull, metres."),
    Opt("refine_window", "Refinement: half the width of the penalty window, metres."),
    Opt("refine_goal", "Refinement: the goal's distance ahead, metres."),
    Opt("refine_side", "Refinement: side of the square searched around the goal, metres."),
    Opt("radius", "Robot radius, metres."),
    Opt(
        "min_separation",
        "Least distance between robots' centres, metres (default 2 x --radius).",
        unset_as=math.nan,
    ),
    Opt("p_random", "Chance per step that a blocked robot moves at random (0..1)."),
    Opt("dt", "Simulation step, seconds."),
    Opt("start_fog", "Time since last seen of every place at the start, seconds."),
    Opt("speed", "Holonomic robots' speed, m/s."),
    Opt("turn_radius", "Cars' minimum turning radius, metres."),
    Opt(
        "car_planner",
        "Cars: track (pure pursuit along the wave's path, hybrid-A* manoeuvres out of "
        "dead ends) or thesis (turn towards the chosen direction, reversing escape).",
    ),
    Opt("lookahead", "Tracking cars: the pure-pursuit point's distance along the path, metres."),
    Opt(
        "forward_wave",
        "Tracking cars: paths leave forwards (cells up to 4 m behind the car closed on "
        "its wave) unless the way ahead is a dead end (a flood fill over up to half the "
        "map a step). "
        "Default: on for tracking cars on the potential field's wave paths, else off.",
        off="--no-forward-wave",
        unset_as=None,
    ),
    Opt(
        "forward_stale",
        "Tracking cars with --forward-wave: on a step when the worst time since seen "
        "exceeds this many times the mean over the places seen at least once, the wave "
        "runs in every direction; 0: never. Never-seen places count in the worst (time "
        "since the start) but not the mean, given-up ones too; tested on the fog of the "
        "step before. Default: 10 for tracking cars on the potential field's wave paths "
        "with --forward-wave, else 0.",
        unset_as=math.nan,
    ),
    Opt(
        "give_up",
        "Tracking cars: reversing manoeuvres on the way to a never-seen place after which "
        "the cars stop going for it (and the never-seen places within 2 m); 0: never.",
    ),
    Opt(
        "turn_penalty",
        "Tracking cars: the lead in log pull a place whose path leaves behind the car "
        "(over 100 deg off its heading) needs over the places ahead; 0: none. Default: 10 "
        "for tracking cars on the potential field's wave paths, else 0.",
        unset_as=math.nan,
    ),
    Opt(
        "turn_time",
        "Tracking cars: seconds a turn-round costs; places seen less than this long ago "
        "behind a car (over 100 deg off its heading) do not pull on it; 0: they do. "
        "Default: 30 for tracking cars on the potential field's wave paths, else 0.",
        unset_as=math.nan,
    ),
    Opt(
        "out_of_sight",
        "Tracking cars: only places out of sight (not seen this step) pull on a car; "
        "--every-place-pulls: every watched place does (the thesis's). Default: the "
        "former for tracking cars on the potential field's wave paths, else the latter.",
        off="--every-place-pulls",
        unset_as=None,
    ),
    Opt(
        "round_block",
        "Tracking cars: metres of extra path a car accepts to drive on round the block "
        "rather than turn round for a path behind it; 0: the shortest path. Default: 60 "
        "for tracking cars on the potential field's wave paths, else 0.",
        unset_as=math.nan,
    ),
    Opt(
        "one_way",
        "Tracking cars: one-way streets, every street narrower than the turning circle "
        "but dead-end stubs driven one way only, derived from the map. Default: one-way "
        "for two or more tracking cars on the potential field's wave paths, else two-way.",
        off="--two-way",
        unset_as=None,
    ),
    Opt(
        "one_way_orient",
        "Tracking cars on one-way streets: how the streets' directions are chosen: dfs "
        "(any that keeps every place reachable) or short (one with shorter detours).",
        flag="--one-way-orient",
    ),
    Opt(
        "stub_sight",
        "Tracking cars: a place in a dead-end stub seen from the junction it opens on "
        "(within the vision less 1 m of it) is looked at from there, not driven to; "
        "--enter-stubs: the route runs to the place.",
        off="--enter-stubs",
    ),
    Opt(
        "stub_delay",
        "Tracking cars seeing a disc: seconds later than it was that a place in a "
        "dead-end stub a car must drive into to see pulls as if seen (at most --duration); "
        "0: it pulls as any place.",
        kind=float,
    ),
    Opt(
        "speed_bands",
        "Cars' speed rule: 'D:KMH,...', KMH below D metres from the "
        "nearest obstacle, in order; the last D may be inf.",
        kind=str,
        default="2:3,5:6,7.5:9,inf:15",
        metavar="D:KMH,...",
    ),
    Opt("vision", "Vision radius, metres."),
    Opt(
        "line_of_sight",
        "Vision blocked by obstacles, or a plain disc (the thesis's).",
        off="--disc",
    ),
    Opt("duration", "Mission length, simulated seconds."),
    Opt(
        "warmup",
        "Seconds at the start left out of the mean MTB (the mean of the worst "
        "time since last seen; default a fifth of --duration).",
        kind=float,
    ),
    Opt(
        "cell",
        "Cell of the fog and paths, metres (default 0.5, or --radius / 2 if less).",
        unset_as=math.nan,
    ),
)


@patrol_app.command("run", epilog=EPILOG)
@config_options((PatrolConfig, PATROL_OPTIONS))
def run_cmd(
    ctx: typer.Context,
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder for the results.")
    ],
    map_: Annotated[
        Path | None,
        typer.Option(
            "--map",
            help="Territory: map_server YAML, a bare image with --resolution, or a built-in "
            "map by name: open-field, fig3-2, fig3-4, fig3-10 (see 'patrol maps').",
        ),
    ] = None,
    robots: Annotated[
        int | None,
        typer.Option(help=f"Robots (random starts, seeded) unless --starts; at most {MAX_ROBOTS}."),
    ] = None,
    starts: Annotated[
        Path | None,
        typer.Option(help="Start file: the count, then 'X Y phi' per robot (dm from top-left)."),
    ] = None,
    force_a: Annotated[
        float, typer.Option(help="The f family's constant a (how fast the pull grows).")
    ] = 40.0,
    force_b: Annotated[
        float, typer.Option(help="The g family's constant b (how far the pull reaches), dm.")
    ] = 65.0,
    semaphores: Annotated[
        Path | None,
        typer.Option(help="Semaphore file: one polygon a line, 'x y;x y;...' in dm."),
    ] = None,
    territory_file: Annotated[
        Path | None,
        typer.Option(
            "--territory",
            help="Patrol only inside this mask: a map_server YAML (its free cells) or a "
            "polygon file ('x y' metres a line, a blank line between polygons).",
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of everything random.")] = 0,
    animate: Annotated[
        bool, typer.Option("--animate", help="Also write OUT/patrol.gif (200 frames at most).")
    ] = False,
    graph: Annotated[
        bool,
        typer.Option(
            "--graph/--no-graph",
            help="patrolling_sim's metrics on the patrol graph (idleness per vertex, "
            "visits, cycles, interference): summary.json's 'graph', idleness.csv, "
            "vertices.csv, idleness.png.",
        ),
    ] = True,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
    bag: BagOption = False,
    live: LiveOption = False,
    live_port: LivePortOption = 8765,
    live_rate: LiveRateOption = 1.0,
    fog_every: Annotated[
        float,
        typer.Option(
            help="--bag, --live: simulated seconds between two /fog grids (poses go every step).",
        ),
    ] = 5.0,
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
    """Patrol a territory; writes metrics.csv, summary.json, fog.png, starts.txt, the patrol
    graph's idleness.csv, vertices.csv and idleness.png (and patrol.gif).

    The model, the force laws and the metrics (MTB: the worst time since a place was
    last seen; DVT: time spent escaping dead ends) are explained in docs/patrol.md."""
    from ..io.record import make_recorder
    from ..patrol import parse_force, run_patrol
    from ..patrol.publish import PatrolPublisher
    from ..patrol.region import read_region
    from ..patrol.robots import parse_speed_bands
    from ..patrol.semaphores import read_semaphores
    from ..patrol.starts import StartSource, read_start_lines

    extra: dict[str, Any] = ctx.meta.get("patrol_setup", {})
    if map_ is None:
        raise ConfigError("give the territory: --map, or 'map' in --config")
    if robots is not None and robots < 1:
        raise ConfigError(f"--robots {robots}: robots must be >= 1")
    if robots is not None and robots > MAX_ROBOTS:
        # Refused before any work: placing each robot alone runs a wave over the map.
        raise ConfigError(f"--robots {robots}: at most {MAX_ROBOTS} robots")
    config = config_from_options(
        PatrolConfig,
        ctx.params,
        PATROL_OPTIONS,
        convert={
            "force": lambda name: parse_force(name, force_a, force_b),
            "speed_bands": parse_speed_bands,
        },
    )
    territory = _territory(map_, resolve_map(map_, resolution, origin), config)
    _check_reach(config, territory.grid)
    region = read_region(territory_file, territory.grid) if territory_file else None
    start, source = None, None
    if starts is not None:
        start, lines = read_start_lines(starts, territory)
        if robots is not None:
            if robots > len(start):
                raise ConfigError(f"{robots} robots asked for, the start file has {len(start)}")
            start = start[:robots]  # robot_number: the first N of the start file
        # The run checks the starts it uses (a robot beyond --robots is not one) and
        # names the file and line of one it refuses.
        source = StartSource(territory, starts, tuple(lines[: len(start)]))
    areas = read_semaphores(semaphores, territory.grid) if semaphores is not None else None
    anim: Any = None
    every = max(1, round(config.duration / config.dt) // 200)
    frame = {"k": 0}

    def keep(t: float, team: Team, fog: Fog) -> None:
        nonlocal anim
        if anim is None:
            from ..plot import FogAnimation

            # Made at the first step, once the run has settled what it watches.
            anim = FogAnimation(
                territory.grid,
                territory.free,
                radius=config.radius,
                outside=territory.free & ~fog.watched,
                unknown=territory.unknown,
            )
        frame["k"] += 1
        if frame["k"] % every == 0:
            robots_now = np.column_stack([team.x, team.y, team.heading])
            anim.add(t, fog.tb, robots_now, never_seen=fog.never_seen())

    batch = None
    if "output_file" in extra:
        batch = (str(extra["output_file"]), int(extra.get("log_period_steps", 1)))
    # Everything, the bag included, goes into OUT at once at the end (or nothing).
    with atomic_folder(out) as tmp:
        with make_recorder(
            tmp / "bag" if bag else None,
            live_port=live_port if live else None,
            live_rate=live_rate,
        ) as rec:
            observers = [keep] if animate else []
            if rec:
                observers.append(
                    PatrolPublisher(rec, territory, config, semaphores=areas, fog_every=fog_every)
                )
            said = {"live": not live}

            def step(t: float, team: Team, fog: Fog) -> None:
                # Said at the first step, once the run has accepted its starts: a refused
                # start file is then the run's only line.
                if not said["live"]:
                    said["live"] = True
                    console.print(
                        f"live: {rec.url} (Foxglove: Open connection), {live_rate:g}x real time",
                        markup=False,
                    )
                for observe in observers:
                    observe(t, team, fog)

            with progress("patrolling") as cb:
                res = run_patrol(
                    territory,
                    config,
                    starts=start,
                    robots=robots,
                    seed=seed,
                    progress=cb,
                    on_step=step if observers else None,
                    semaphores=areas,
                    region=region,
                    graph=graph,
                    start_source=source,
                )
        with progress("writing") as cb:
            cb(0, 0, "patrol.gif" if anim is not None else "")
            written = res.write(
                tmp, territory, seed=seed, source=str(map_), batch=batch, animation=anim
            )
    names = [p.name for p in written] + (["bag/"] if bag else [])
    s = res.summary()
    if res.reach is not None:
        console.print(res.reach.describe(), markup=False)
    if s["never_seen"] > 0:
        console.print(
            f"[yellow]warning:[/] {100 * s['never_seen']:.1f} % of the territory was never "
            f"seen in {config.duration:g} s: the mean MTB says only that the run was too "
            "short or the team too small"
        )
    console.print(
        f"mean MTB {s['mean_mtb']:.1f} s (after {config.warmup_s:g} s), worst idleness "
        f"{s['worst_idleness']:.0f} s, {s['steps']} steps in {s['wall_seconds']:.1f} s"
    )
    if "graph" in s:
        m = s["graph"]
        console.print(
            f"patrol graph: {m['graph_vertices']} vertices, average idleness "
            f"{m['avg_idleness']:.1f} s (median {m['median_idleness']:.1f}, worst "
            f"{m['worst_idleness_visits']:.0f}), {m['complete_cycles']} complete cycles, "
            f"{m['interference_events']} interference events"
        )
    console.print(wrote(out, names))


def _check_reach(config: PatrolConfig, grid: Any) -> None:
    """The library's check (:meth:`PatrolConfig.check_reach`), made before the run with
    the option's name beside the field's (the value may come from --config)."""
    try:
        config.check_reach(grid)
    except ConfigError as err:
        option = "--" + str(err.field).replace("_", "-")
        raise ConfigError(f"{option} / {err.reason}") from None


def _territory(path: Path, m: Any, config: PatrolConfig) -> Any:
    """The map's territory on the run's cells; a map with no free cell (thresholds or
    mode that make none) or cells coarser than the map is one error naming the file."""
    from ..patrol import Territory

    g = m.grid
    short = min(g.rows, g.cols) * g.resolution
    if config.cell > short / 4:
        raise ConfigError(
            f"--cell {config.cell:g}: too coarse for {path}, a map {short:g} m across "
            f"(at most {short / 4:g} m)",
            field="cell",
        )
    try:
        return Territory.from_map(m, cell=config.cell)
    except InputError as err:
        if err.path is not None:
            raise
        raise InputError(
            f"{err.reason} (check the YAML's mode and thresholds)", path=path
        ) from None


@patrol_app.command("maps", epilog=EPILOG)
def maps_cmd(
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder for the maps.")
    ],
) -> None:
    """Write the built-in territories (map_server YAML + PGM at 0.1 m), their start files
    and semaphore files."""
    from ..patrol.maps import write_builtin_maps

    with atomic_folder(out) as tmp:
        written = write_builtin_maps(tmp)
    console.print(wrote(out, [p.name for p in written]), markup=False)


@patrol_app.command("experiment", epilog=EPILOG)
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
    map_: Annotated[
        Path | None,
        typer.Option(
            "--map",
            help="baselines only: run on this map (map_server YAML) instead of the built-in "
            "ones, one run at a time, with indoor robots (defaults: --radius 0.3 --speed 1 "
            "--vision 5, 0.1 m cells, 1800 s, 2 seeds).",
        ),
    ] = None,
    radius: Annotated[
        float | None, typer.Option(help="With --map: robot radius, metres (0.3).")
    ] = None,
    speed: Annotated[float | None, typer.Option(help="With --map: speed, m/s (1).")] = None,
    vision: Annotated[
        float | None, typer.Option(help="With --map: vision radius, metres (5).")
    ] = None,
    robots: Annotated[
        str | None, typer.Option(help="With --map: team sizes, comma-separated (1,2,4).")
    ] = None,
    policies: Annotated[
        str | None,
        typer.Option(
            help="With --map: policies, comma-separated (potential,random,reactive,cycle,"
            "cr,hcr,sebs)."
        ),
    ] = None,
) -> None:
    """Rerun one of the thesis's chapter-3 experiments on the built-in maps: runs.csv,
    table.csv, claims.json, figures and report.html in OUT. With --map FILE, the
    baselines experiment runs the policies side by side on a real map instead (runs.csv,
    runs.json, table.csv, claims.json, mtb.png, report.html)."""
    from ..parallel import check_workers
    from ..patrol.experiments import run_experiment

    named_check("--workers", check_workers, workers)
    if map_ is not None:
        if name != "baselines":
            raise ConfigError(f"--map runs only the baselines experiment, not {name!r}")
        _baselines_on_map(
            map_, out, quick, seeds, duration, cell, radius, speed, vision, robots, policies
        )
        return
    given: dict[str, object] = {"--radius": radius, "--speed": speed, "--vision": vision}
    given |= {"--robots": robots, "--policies": policies}
    extra = [k for k, v in given.items() if v is not None]
    if extra:
        raise ConfigError(f"{', '.join(extra)} only with --map")

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
    console.print(f"report: {report}", markup=False)
    console.print(wrote_folder(out), markup=False)


def _numbers(option: str, text: str) -> list[int]:
    """``1,2,4`` as [1, 2, 4]; anything else one error naming ``option``."""
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{option} takes whole numbers, comma-separated, got {text!r}") from None


def _baselines_on_map(
    map_: Path,
    out: Path,
    quick: bool,
    seeds: int | None,
    duration: float | None,
    cell: float | None,
    radius: float | None,
    speed: float | None,
    vision: float | None,
    robots: str | None,
    policies: str | None,
) -> None:
    """``patrol experiment baselines --map``: the policies side by side on one map
    (:mod:`sonarmap.patrol.baselines`), a table and the claims printed."""
    from ..patrol.baselines import (
        BASELINE_POLICIES,
        INDOOR,
        baseline_claims,
        baseline_table,
        run_baselines,
        table_lines,
        write_baselines,
    )

    n_seeds = seeds if seeds is not None else (1 if quick else 2)
    if n_seeds < 1:
        raise ConfigError(f"seeds must be >= 1, got {n_seeds}")
    sizes = _numbers("--robots", robots) if robots is not None else [1, 2, 4]
    names = (
        [p.strip() for p in policies.split(",") if p.strip()]
        if policies is not None
        else list(BASELINE_POLICIES)
    )
    base: dict[str, Any] = {
        "radius": INDOOR["radius"] if radius is None else radius,
        "speed": INDOOR["speed"] if speed is None else speed,
        "vision": INDOOR["vision"] if vision is None else vision,
        "cell": INDOOR["cell"] if cell is None else cell,
        "duration": duration if duration is not None else (300.0 if quick else 1800.0),
    }
    config = PatrolConfig(**base)
    territory = _territory(map_, resolve_map(map_), config)
    settings = {"map": str(map_), **base, "robots": sizes, "seeds": n_seeds, "policies": names}

    def show(row: dict[str, Any]) -> None:
        console.print(
            f"{row['policy']}, {row['robots']} robots, seed {row['seed']}: mean MTB "
            f"{row['mean_mtb']:.1f} s, graph idleness {row['graph_avg_idleness']:.1f} s "
            f"(worst {row['graph_worst_idleness']:.1f} s), blocked {row['blocked']:.3f}, "
            f"never seen {row['never_seen']:.3f}, {row['x_real']:.1f}x real",
            markup=False,
        )

    with progress(f"patrol experiment baselines on {map_.stem}") as cb:
        rows = run_baselines(
            territory,
            base,
            policies=names,
            robots=sizes,
            seeds=list(range(n_seeds)),
            map_name=map_.stem,
            progress=cb,
            on_row=show,
        )
    with atomic_folder(out) as tmp:
        write_baselines(tmp, rows, settings)
    table = baseline_table(rows)
    for line in table_lines(table):
        console.print(line, markup=False)
    for c in baseline_claims(table):
        console.print(f"{c['verdict']}: {c['claim']}: {c['measured']}", markup=False)
    console.print(wrote_folder(out), markup=False)
