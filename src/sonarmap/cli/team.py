"""``sonarmap team``: each robot's long-term store and global map (a thin layer over
:mod:`sonarmap.team`)."""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import numpy.typing as npt
import typer

from ..errors import ConfigError, InputError, quote
from ..files import atomic_folder
from ..io.record import make_recorder
from ..io.rosmap import OccupancyMap
from ..team.config import MAX_DURATION, MAX_ROBOTS, team_size_problem
from ..team.exchange import ExchangeParams
from ..team.inputs import (
    RunTerritory,
    check_world_territory,
    draw_world,
    mission_routes,
    run_territory,
)
from ..team.mission import MissionConfig, run_mission
from ..team.network import NetworkParams
from ..team.outputs import write_run
from ..team.patrolling import patrol_routes
from ..team.presets import (
    DEFAULT_PRESET,
    PRESETS,
    PresetClashError,
    TeamPreset,
    check_preset,
    default_mode,
    team_settings,
)
from ..team.prior import ERROR_KEYS, check_prior_inside, make_prior
from ..team.publish import TeamPublisher
from ..team.simulation import run_team
from ..team.store import StoreParams
from ..team.summary import naive_share_note
from ..team.territory import (
    MissionTerritory,
    check_route_inside,
    territory_option,
)
from ..team.world import (
    load_world,
    make_world,
    patrol_route,
    read_route,
    save_world,
)
from .common import (
    BagOption,
    ImageOrigin,
    ImageResolution,
    LiveOption,
    LivePortOption,
    LiveRateOption,
    Opt,
    check_inside_plan,
    config_from_options,
    config_options,
    console,
    given,
    progress,
    resolve_map,
    writable,
    wrote,
    wrote_folder,
)

#: Where --help points for more.
EPILOG = "Guide: docs/guides/team.md; the protocols: docs/team.md."

app = team_app = typer.Typer(
    help="Team mapping: each robot's bounded store and global map (thesis 002, chapter 2).",
    epilog=EPILOG,
    no_args_is_help=True,
    context_settings={"help_option_names": ["-h", "--help"]},
)

MapOption = Annotated[
    Path,
    typer.Option(
        "--map",
        help="Floor plan: map_server YAML, an image with --resolution, or a built-in map "
        "by name: office, building:SEED (a random building), or a patrol territory "
        "(open-field, fig3-2, fig3-4, fig3-10).",
    ),
]
OutOption = Annotated[
    Path, typer.Option("-o", "--out", callback=writable, help="Folder for the results.")
]
SeedOption = Annotated[int, typer.Option("--seed", min=0, help="Seed of everything random.")]
DurationOption = Annotated[
    float,
    typer.Option(
        "--duration", help=f"Mission length, simulated seconds (at most {MAX_DURATION:g}: a day)."
    ),
]
TourOption = Annotated[
    bool,
    typer.Option(
        "--tour",
        help="Drive one tour of the reachable territory lap after lap (at most a third of "
        "the mission per lap) instead of random waypoints, so places are passed again.",
    ),
]
TerritoryOption = Annotated[
    Path | None,
    typer.Option(
        "--territory",
        help="Map only inside this mask, as 'patrol run --territory': a map_server YAML "
        "(its free cells) or a polygon file ('x y' metres a line, a blank line between "
        "polygons); 'none': the whole map. Routes, starts and landmarks stay in the "
        "largest area a robot fits in inside it. Default: on a drawn plan whose outside "
        "is free (no unknown cells, a free margin all round, one building) the building's "
        "footprint, its walls bridged across openings up to 1.5 m, so the outside is left "
        "out (unless --route is given; with --world, the mask 'team world' made it in); "
        "elsewhere the whole map. A --route must keep to a given mask's area (refused "
        "otherwise); --world is refused with a mask. The store's regions are cut inside the "
        "territory too.",
    ),
]
NodeTerritoryOption = Annotated[
    Path | None,
    typer.Option(
        "--territory",
        help="Map only inside this mask, as 'team run --territory': a map_server YAML "
        "(its free cells) or a polygon file; 'none': the whole map. The node's landmarks "
        "(and routes, without --routes) stay in the largest area a robot fits in inside "
        "it. Default: as 'team run' (the building's footprint on a drawn plan whose "
        "outside is free, elsewhere the whole map), with --routes too, since the launcher "
        "hands its nodes routes drawn inside that same default; give 'none' to map the "
        "whole plan along routes of your own.",
    ),
]


def _territory(path: Path | None, plan: OccupancyMap) -> MissionTerritory | None:
    """``--territory`` (:func:`~sonarmap.team.territory.territory_option`), the default
    told in one line when it applies."""
    mask = territory_option(path, plan)
    if path is None and mask is not None:
        _say_footprint(mask)
    return mask


def _say_footprint(mask: MissionTerritory) -> None:
    r = mask.record
    console.print(
        f"territory: {r['why']}; left out its free outside, "
        f"{r['left_out_free_area_m2']:,.1f} m^2 (the building's footprint; "
        "--territory none keeps the whole map)",
        markup=False,
    )


def _run_territory(
    territory: Path | None, plan: OccupancyMap, route: Path | None, world_dir: Path | None
) -> RunTerritory:
    """``team run``'s territory (:func:`~sonarmap.team.inputs.run_territory`), the
    default or the --world's told in one line."""
    chosen = run_territory(territory, plan, route_given=route is not None, world=world_dir)
    if chosen.how == "default" and chosen.mask is not None:
        _say_footprint(chosen.mask)
    if chosen.how == "world" and chosen.record is not None:
        r = chosen.record
        console.print(
            f"territory: the --world's, made inside {r['world_territory_from'] or 'a mask'} "
            f"({r['file']})",
            markup=False,
        )
    return chosen


@team_app.command("world", epilog=EPILOG)
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
    tour: TourOption = False,
    territory: TerritoryOption = None,
) -> None:
    """Make a mission's world: landmarks with their changes, a patrol route, the truth."""
    _check_duration(duration)
    for name, share in (("--texture-share", texture_share), ("--change-share", change_share)):
        if not (0.0 <= share <= 1.0):
            raise ConfigError(f"{name} {share:g}: must be in [0, 1]")
    plan = resolve_map(map_, resolution, origin)
    mask = _territory(territory, plan)
    region = None if mask is None else mask.region
    world = make_world(
        plan,
        seed=seed,
        duration=duration,
        texture_share=texture_share,
        change_share=change_share,
        plan_path=map_.resolve() if map_.exists() else None,
        region=region,
    )
    route = patrol_route(
        plan, duration, seed=seed, style="tour" if tour else "waypoints", region=region
    )
    source = None
    if mask is not None:
        source = mask.record["file"] or str(mask.record.get("default", "footprint"))
    save_world(world, route, out, region=region, territory=source)
    console.print(f"{len(world)} landmarks, route of {len(route)} poses")
    console.print(wrote_folder(out), markup=False)


def _check_duration(duration: float) -> None:
    """--duration: > 0 and at most a day, refused before any work (a route is drawn for
    the whole mission at once)."""
    if not (math.isfinite(duration) and duration > 0):
        raise ConfigError(f"--duration must be > 0, got {duration}")
    if duration > MAX_DURATION:
        raise ConfigError(f"--duration {duration:g}: at most {MAX_DURATION:g} s (a day)")


def _check_robots(robots: int, *, processes: bool = False) -> None:
    """--robots: a team the machine can run (:func:`~sonarmap.team.config.team_size_problem`)."""
    problem = team_size_problem(robots, processes=processes)
    if problem is not None:
        raise ConfigError(f"--robots {robots}: {problem}")


def _check_seconds(name: str, value: float | None, least: float | None) -> None:
    """A node's time option: >= ``least`` (None: > 0) and at most a day (more would only
    keep a node waiting for ever); None (not given) passes."""
    if value is None:
        return
    low = value >= least if least is not None else value > 0
    if not low:
        bound = f">= {least:g}" if least is not None else "> 0"
        raise ConfigError(f"{name} {value:g}: must be {bound} seconds")
    if value > MAX_DURATION:
        raise ConfigError(f"{name} {value:g}: at most {MAX_DURATION:g} s (a day)")


def _tick(update: Any, note: str, done: int, total: int) -> None:
    update(done, total, note)


def _phase(update: Any, name: str) -> None:
    """A phase after the routes: its own line, with no share of ticks to show."""
    update(0, 0, name)


#: Transports of ``--transport``.
TRANSPORTS = ("sim", "zmq")


#: Options that set :class:`~sonarmap.team.network.NetworkParams`.
NETWORK_OPTIONS = (
    Opt("kind", "Links: full, limited (--link-range and line of sight) or none.", flag="--network"),
    Opt("bandwidth", "Bytes/s of each link (default: unlimited).", kind=float),
    Opt("loss", "Probability a message is lost on one hop (0..1)."),
    Opt(
        "r_max",
        "limited network: metres a link reaches with line of sight.",
        flag="--link-range",
        aliases=("--range", "--r-max"),
    ),
)
#: Options that set :class:`~sonarmap.team.exchange.ExchangeParams`.
EXCHANGE_OPTIONS = (
    Opt(
        "mode",
        "Protocol: good, limited, or naive (every new pose to everyone). "
        "Default: good on a full network, limited otherwise.",
        flag="--exchange",
        unset_as=None,
        kind=str,
    ),
    Opt(
        "cap_bytes",
        "Bytes of poses one limited-protocol answer carries at most (the thesis's T).",
        flag="--cap",
    ),
    Opt("budget", "Bytes/s of answers each robot lets its requests bring in (0: no budget)."),
    Opt(
        "anchor_every",
        "Landmarks travel only with every K-th pose a robot made and with "
        "merged poses (1: every pose whole, as the thesis stores it).",
        flag="--anchors",
        metavar="K",
    ),
    Opt(
        "loop_anchors",
        "With --anchors K: also send whole every pose that closed a loop "
        "with an older anchor or met another robot's pose, so that receivers can close it "
        "too.",
    ),
    Opt(
        "anchor_share",
        "With --anchors K: also send a pose whole while the robot has sent "
        "less than S times what the naive baseline would have (0: off).",
        metavar="S",
    ),
    Opt("hold", "Seconds a robot keeps a new pose to itself before offering it."),
    Opt("descriptor_bits", "Bits each landmark descriptor byte keeps as it travels (8: exact)."),
    Opt(
        "ternary_maps",
        "Local maps travel as free / occupied / unknown, each class at its "
        "mean log-odds in that map.",
    ),
    Opt(
        "send_closures",
        "Answers carry the answerer's loop closures that touch the poses sent "
        "(compact, checked on receipt; the thesis keeps closures private; "
        "--no-send-closures: the thesis's private closure store).",
        off="--no-send-closures",
    ),
)
#: Options that set :class:`~sonarmap.team.store.StoreParams`.
STORE_OPTIONS = (
    Opt("pose_limit", "Bytes one pose may take in the store (the thesis's M_pose)."),
    Opt(
        "region_limit",
        "Bytes one region of the store may take at least (the thesis's M_r); a larger "
        "region may take --region-density bytes per m^2 of its area.",
    ),
    Opt(
        "region_density",
        "Bytes per m^2 of a region's area that it may take when that is more than "
        "--region-limit (0: every region --region-limit, the thesis's).",
    ),
    Opt(
        "store_limit",
        "Bytes the robot's own layer may take, every region together; past it the store "
        "thins its poses across regions (0: only the regions' bound).",
    ),
    Opt(
        "fold",
        "A pose that compression deletes leaves its local map to its nearest odometry "
        "neighbour that no other robot holds yet (--no-fold: the thesis's deletion).",
        off="--no-fold",
    ),
    Opt(
        "merge_on_closure",
        "Merge two own poses as soon as a loop closure with >= N "
        "inliers joins them, so that the loop travels in the exchanged layer (0: only "
        "under region compression).",
        metavar="N",
    ),
)


def _team_options(
    ctx: typer.Context, robots: int
) -> tuple[NetworkParams, ExchangeParams, StoreParams, str | None]:
    """The network, exchange and store of ``team run``'s options, and the preset applied
    (None: none). A preset named by ``--preset`` (or ``--lean``) refuses the options it
    sets; the default preset of a team (:data:`~sonarmap.team.presets.DEFAULT_PRESET`)
    yields to them. A single robot and the naive baseline get no preset by default."""
    net = config_from_options(NetworkParams, ctx.params, NETWORK_OPTIONS)
    if "r_max" in given(ctx, NETWORK_OPTIONS) and net.kind != "limited":
        raise ConfigError(f"--link-range is the limited network's; --network is {net.kind}")

    protocol = partial(default_mode, network=net.kind)
    chosen: str | None = ctx.params.get("preset")
    flag = None if chosen is None else f"--preset {chosen}"
    check_preset(chosen)
    if ctx.params.get("lean"):
        if chosen not in (None, "lean"):
            raise ConfigError(f"--lean is --preset lean: drop it or {flag}")
        chosen, flag = "lean", "--lean"
    # Given at all, even at its default value, an option would be silently overridden.
    opts = given(ctx, (*EXCHANGE_OPTIONS, *STORE_OPTIONS))
    if chosen is not None:
        preset = PRESETS[chosen]
        clash = preset.conflicts(opts)
        if clash:
            names = [opts[f] for f in clash]
            raise ConfigError(
                f"{flag} sets {', '.join(opts_of(preset.sets()))}: drop {', '.join(names)} "
                f"or drop {flag}"
            )
    params: dict[str, Any] = dict(ctx.params)
    fixed: dict[str, dict[str, Any]] = {"exchange": {}, "store": {}}
    mode = next(ctx.params.get(o.param) for o in EXCHANGE_OPTIONS if o.field == "mode")
    default = chosen is None and robots > 1 and protocol(mode) != "naive"
    if default:
        # The default preset's values stand in for the defaults of the options not given.
        chosen, flag = DEFAULT_PRESET, f"under the default --preset {DEFAULT_PRESET}"
        params, fixed = _under_preset(PRESETS[chosen], params, set(opts))
    try:
        exchange = config_from_options(
            ExchangeParams,
            params,
            EXCHANGE_OPTIONS,
            convert={"mode": protocol},
            fixed=fixed["exchange"],
        )
        if exchange.loop_anchors and exchange.anchor_every == 1:
            raise ConfigError("--loop-anchors chooses among poses sent bare: give --anchors K > 1")
        store = config_from_options(StoreParams, params, STORE_OPTIONS, fixed=fixed["store"])
    except ConfigError as err:
        if default:
            raise ConfigError(f"{err} ({flag}; --preset classic for the thesis's)") from None
        raise
    if chosen is not None and not default:
        try:
            exchange, store = PRESETS[chosen].apply(exchange, store)
        except ConfigError as err:
            raise ConfigError(f"{flag}: {err}") from None
    return net, exchange, store, chosen


def _under_preset(
    preset: TeamPreset, params: dict[str, Any], given_fields: set[str]
) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """``ctx.params`` with the preset's value for every option it sets that was not
    given, and the preset's values of fields no option sets (``fixed`` of
    :func:`config_from_options`, by ``"exchange"`` and ``"store"``)."""
    out = dict(params)
    fixed: dict[str, dict[str, Any]] = {"exchange": {}, "store": {}}
    values = preset.values(given_fields)
    for kind, opts in (("exchange", EXCHANGE_OPTIONS), ("store", STORE_OPTIONS)):
        by_field = {o.field: o for o in opts}
        for f, v in values[kind].items():
            if f in by_field:
                out[by_field[f].param] = v
            else:
                fixed[kind][f] = v
    return out, fixed


def _node_settings(
    ctx: typer.Context, chosen: str | None, items: list[str]
) -> tuple[ExchangeParams, StoreParams, str | None]:
    """``team node``'s exchange and store from its ``--exchange`` items, store options
    and ``--preset`` (:func:`~sonarmap.team.presets.team_settings`), and the preset
    applied; a clash names the options."""
    from ..team.node import parse_exchange

    check_preset(chosen)
    store_given = given(ctx, STORE_OPTIONS)
    names = {item.partition("=")[0].strip(): f"--exchange {item}" for item in items}
    names.update(store_given)
    exchange = parse_exchange(items)
    store = config_from_options(StoreParams, ctx.params, STORE_OPTIONS)
    try:
        return team_settings(chosen, exchange, store, list(names))
    except PresetClashError as err:
        raise ConfigError(
            f"--preset {chosen} sets {', '.join(names[f] for f in err.fields)}: drop "
            f"{'it' if len(err.fields) == 1 else 'them'} or drop --preset"
        ) from None
    except ConfigError as err:
        if chosen is None:
            # As team run words it: the default preset's values met the ones given.
            raise ConfigError(
                f"{err} (under the default --preset {DEFAULT_PRESET}; --preset classic for "
                "the thesis's)"
            ) from None
        raise ConfigError(f"--preset {chosen}: {err}") from None


PcmOption = Annotated[
    bool,
    typer.Option(
        "--pcm/--no-pcm",
        help="Pairwise consistency: before each graph batch keep, for each pair of robots' "
        "layers, the largest set of closures whose loops with the odometry agree (chi-square "
        "99 %), reject the rest.",
    ),
]


def _mission_config(
    duration: float, seed: int, store: StoreParams, pcm: bool = False
) -> MissionConfig:
    """The mission's config; a store bound too small for one pose names its option."""
    try:
        return MissionConfig(duration=duration, seed=seed, store=store, pcm=pcm)
    except ConfigError as err:
        names = {o.field: o.name for o in STORE_OPTIONS}
        if err.field in names:
            raise ConfigError(f"{names[err.field]}: {err.reason}", field=err.field) from None
        raise


def opts_of(fields: tuple[str, ...]) -> list[str]:
    """The options of ``fields`` that have one, in the tables' order."""
    names = {o.field: o.name for o in (*EXCHANGE_OPTIONS, *STORE_OPTIONS)}
    return [names[f] for f in fields if f in names]


def _drawn(
    plan: OccupancyMap,
    map_: Path,
    duration: float,
    seed: int,
    routes: dict[int, Any],
    robots: int,
    region: npt.NDArray[np.bool_] | None = None,
    territory: Path | None = None,
) -> tuple[Any, dict[int, Any]]:
    """:func:`~sonarmap.team.inputs.draw_world`, a plan with no wall for a landmark or no
    territory for a route failing in one line naming --map (and --territory)."""
    try:
        return draw_world(plan, duration, seed=seed, robots=robots, region=region, routes=routes)
    except (InputError, ConfigError) as err:
        # The reason itself says when the mask is what left no room.
        within = "" if territory is None else f", --territory {territory}"
        if territory is None and region is not None:
            within = (
                ", inside the building's footprint (the default; --territory none: the whole map)"
            )
        raise ConfigError(f"--map {map_}{within}: {err.reason}") from None


@team_app.command("run", epilog=EPILOG)
@config_options(
    (NetworkParams, NETWORK_OPTIONS),
    (ExchangeParams, EXCHANGE_OPTIONS),
    (StoreParams, STORE_OPTIONS),
)
def run_cmd(
    ctx: typer.Context,
    out: OutOption,
    map_: MapOption,
    robots: Annotated[
        int,
        typer.Option(
            "--robots",
            help="Robots, each with its own store; two or more exchange their poses.",
        ),
    ] = 1,
    duration: DurationOption = 600.0,
    route: Annotated[
        Path | None, typer.Option("--route", help="Route CSV (t,x,y,theta) for robot 0.")
    ] = None,
    world_dir: Annotated[
        Path | None, typer.Option("--world", help="A folder made by 'team world'.")
    ] = None,
    seed: SeedOption = 0,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
    animate: Annotated[
        bool,
        typer.Option(
            "--animate",
            help="Also write mission.gif: truth, odometry, kept poses, closures; with two "
            "or more robots team.gif too: positions, links, poses held from the others.",
        ),
    ] = False,
    preset: Annotated[
        str | None,
        typer.Option(
            "--preset",
            help="Exchange and store settings by name: lean (the measured lean exchange: "
            "--anchors 12 --anchor-share 0.15 --hold 30 --descriptor-bits 3 --ternary-maps "
            "--fold --merge-on-closure 8, adverts every 10 s, whole every 60 s) or classic "
            "(the thesis's: every pose whole and exact). Default: lean for a team exchanging "
            "by a protocol, the options given winning over it; none for one robot or the "
            "naive baseline. A preset named here refuses the options it sets.",
        ),
    ] = None,
    lean: Annotated[
        bool,
        typer.Option("--lean", help="The same as --preset lean."),
    ] = False,
    transport: Annotated[
        str, typer.Option("--transport", help="sim (simulated network) or zmq (processes).")
    ] = "sim",
    patrol: Annotated[
        bool,
        typer.Option("--patrol", help="Drive the robots by the potential-field patroller."),
    ] = False,
    tour: TourOption = False,
    territory: TerritoryOption = None,
    pcm: PcmOption = False,
    bag: BagOption = False,
    live: LiveOption = False,
    live_port: LivePortOption = 8765,
    live_rate: LiveRateOption = 1.0,
    map_every: Annotated[
        float,
        typer.Option(
            "--map-every",
            help="--bag, --live: mission seconds between two of each robot's global maps "
            "and pose graphs (poses go every tick).",
        ),
    ] = 10.0,
    prior_path: Annotated[
        Path | None,
        typer.Option(
            "--prior",
            help="The robots' prior map (map_server YAML), which their regions and "
            "alignment use; --map stays the truth they drive, sense and are scored on. "
            "Default: --map itself.",
        ),
    ] = None,
    prior_error: Annotated[
        str | None,
        typer.Option(
            "--prior-error",
            metavar="SPEC",
            help="Make the prior (--prior, else --map) imprecise: comma-separated "
            f"KEY=VALUE, KEY one of {', '.join(ERROR_KEYS)} (doorways closed, doorways "
            "opened, furniture left out: counts; scale: the plan drawn 1+S times too "
            "large, e.g. 0.03; seed: which ones, default --seed).",
        ),
    ] = None,
) -> None:
    """One mission per robot: store, association, memory bounds, global map, scores.

    Two or more robots run as a team exchanging their poses over the simulated network;
    summary.json then adds the exchange's figures per robot and the team's, with the
    central upper bound map_f1_central (one map built from every robot's poses). With
    --transport zmq the team runs as local processes. The protocols and the figures are
    explained in docs/team.md."""
    if transport not in TRANSPORTS:
        raise ConfigError(
            f"--transport must be one of {', '.join(TRANSPORTS)}, got {quote(transport)}"
        )
    # Refused, not attempted: with zmq each robot is a process of its own.
    _check_robots(robots, processes=transport == "zmq")
    _check_duration(duration)
    net, protocol, store, preset_used = _team_options(ctx, robots)
    if patrol and route is not None:
        raise ConfigError("--patrol drives every robot: drop --route")
    if tour and (patrol or route is not None or world_dir is not None):
        raise ConfigError("--tour draws every robot's route: drop --patrol, --route and --world")
    if transport == "zmq" and (world_dir is not None or animate or bag or live):
        raise ConfigError(
            "--transport zmq: each node draws its own world and writes its own outputs; "
            "--world, --animate, --bag and --live are --transport sim's"
        )
    if not (math.isfinite(map_every) and map_every > 0):
        raise ConfigError(f"--map-every must be > 0 seconds, got {map_every}")
    check_world_territory(territory, world_dir)
    plan = resolve_map(map_, resolution, origin)
    chosen = _run_territory(territory, plan, route, world_dir)
    mask, territory_desc, region = chosen.mask, chosen.record, chosen.region
    prior, prior_desc = make_prior(
        plan, prior_path, prior_error, seed=seed, resolution=resolution, origin=origin
    )
    check_prior_inside(
        plan,
        prior,
        region,
        f"--prior-error {prior_error}" if prior_error is not None else f"--prior {prior_path}",
    )
    world = None
    routes: dict[int, Any] = {}
    if world_dir is not None:
        world, saved = load_world(world_dir)
        if saved is not None:
            routes[0] = saved
    if route is not None:
        routes[0] = read_route(route)
        check_inside_plan(routes[0][:, 0], routes[0][:, 1], routes[0][:, 2], plan.grid, route)
        if mask is not None:
            check_route_inside(
                plan, mask, routes[0], where=f"--route {route}", inside=f"--territory {territory}"
            )
    config = _mission_config(duration, seed, store, pcm)
    if tour:
        routes = mission_routes(
            plan, duration, seed=seed, robots=robots, style="tour", region=region
        )
    if patrol:
        # The patrol replaces any route, a saved world's included.
        patrolled, _ = patrol_routes(plan, robots, duration, seed=seed, region=region)
        routes = dict(enumerate(patrolled))
    if transport == "sim" and world is None:
        world, routes = _drawn(plan, map_, duration, seed, routes, robots, region, territory)
    if transport == "zmq":
        # Imported here: the node module pulls in the process machinery only zmq needs.
        from ..team.launcher import run_zmq_team_into

        # The ZeroMQ team: one process per robot (sonarmap.team.node), its own outputs.
        with progress("team") as update:
            tick = partial(_tick, update, f"{robots} nodes")
            s = run_zmq_team_into(
                out,
                plan,
                config,
                robots,
                network=net,
                exchange=protocol,
                seed=seed,
                progress=tick,
                preset=preset_used,
                routes=[routes.get(i) for i in range(robots)],
                prior=prior,
                prior_record=prior_desc,
                # The nodes work the default footprint out as this command did; none
                # when it did not apply (a --route of the user's, say).
                territory=chosen.node_value(),
                territory_record=territory_desc,
            )
        console.print(
            f"{robots} nodes: {s['bytes_per_robot_minute']:.0f} B per robot-minute"
            f"{naive_share_note(s)}, "
            f"{s['duplicate_poses']} duplicate poses, identical maps {s['identical_maps']}: {out}"
        )
        return
    # Everything, the bag included, goes into OUT at once at the end (or nothing).
    with atomic_folder(out) as tmp:
        with make_recorder(
            tmp / "bag" if bag else None,
            live_port=live_port if live else None,
            live_rate=live_rate,
        ) as rec:
            publisher = TeamPublisher(rec, plan, map_every=map_every) if rec else None
            if rec.url is not None:
                console.print(
                    f"live: {rec.url} (Foxglove: Open connection), {live_rate:g}x real time",
                    markup=False,
                )
            if robots > 1:
                team_args: dict[str, Any] = {
                    "network": net,
                    "exchange": protocol,
                    "seed": seed,
                    "world": world,
                    "routes": [routes.get(i) for i in range(robots)],
                    "central": True,
                    "record": animate,
                    "on_tick": publisher,
                    "prior": prior,
                    "territory": region,
                }
                with progress("team") as update:
                    team_args["progress"] = partial(_tick, update, f"{robots} robots")
                    team_args["phase"] = partial(_phase, update)
                    team = run_team(plan, config, robots, **team_args)
            else:
                with progress("mission") as update:
                    result = run_mission(
                        plan,
                        config,
                        prior=prior,
                        route=routes.get(0),
                        world=world,
                        robot=0,
                        progress=partial(_tick, update, "robot 0"),
                        record=animate,
                        on_step=None if publisher is None else publisher.robot_step,
                        territory=region,
                    )
            if publisher is not None:
                publisher.finish()
        written: dict[str, Any] = {
            "prior": prior,
            "prior_record": prior_desc,
            "territory_record": territory_desc,
            "preset": preset_used,
            "animate": animate,
        }
        if robots > 1:
            with progress("writing") as update:
                update(0, 0, "maps, pictures" + (" and animations" if animate else ""))
                write_run(tmp, plan, team, **written)
        else:
            s0 = write_run(tmp, plan, result, **written)
    if robots > 1:
        s = team.summary
        convergence = s["convergence_s"]
        console.print(
            f"team F1 {s['map_f1_team']:.3f} (central {s['map_f1_central']:.3f}), "
            f"{s['bytes_per_robot_minute']:.0f} B per robot-minute{naive_share_note(s)}, "
            f"{s['duplicate_poses']} duplicate poses, identical maps {s['identical_maps']}, "
            f"converged {'never' if convergence is None else f'{convergence:.1f} s'}"
        )
    else:
        console.print(
            f"precision {s0['association_precision']:.3f}, "
            f"recall {s0['association_recall']:.3f}, "
            f"ATE {s0['ate_m']:.3f} m (odometry {s0['ate_odometry_m']:.3f} m), "
            f"map F1 {s0['map_f1']:.3f}, peak store {s0['store_bytes_peak']} B"
        )
    console.print(wrote_folder(out), markup=False)


@team_app.command("node", epilog=EPILOG)
@config_options((StoreParams, STORE_OPTIONS))
def node_cmd(
    ctx: typer.Context,
    out: OutOption,
    map_: MapOption,
    robot: Annotated[int, typer.Option("--id", help="This robot's id, in 0..N-1.")],
    listen: Annotated[str, typer.Option("--listen", help="tcp://HOST:PORT this node listens on.")],
    peers: Annotated[
        str,
        typer.Option(
            "--peers",
            help="The other robots' listen addresses, comma-separated: ID=ADDRESS each, "
            "or bare addresses for the ids 0..N-1 other than --id, in order.",
        ),
    ] = "",
    duration: DurationOption = 600.0,
    seed: SeedOption = 0,
    state: Annotated[
        Path | None,
        typer.Option("--state", help="Checkpoint folder; a node started on one resumes."),
    ] = None,
    exchange: Annotated[
        list[str] | None,
        typer.Option("--exchange", help="An exchange setting KEY=VALUE (repeatable)."),
    ] = None,
    preset: Annotated[
        str | None,
        typer.Option(
            "--preset",
            help="Exchange and store settings by name, as in 'team run': lean or classic. "
            "Default: lean, the --exchange settings and store options given winning over "
            "it (none with --exchange mode=naive). A preset named here refuses the "
            "settings it sets.",
        ),
    ] = None,
    lookahead: Annotated[
        float, typer.Option("--lookahead", help="Seconds of route whose regions come first.")
    ] = 30.0,
    quiet: Annotated[
        float | None, typer.Option("--quiet", help="Seconds without change that end it.")
    ] = None,
    settle: Annotated[
        float, typer.Option("--settle", help="Seconds of exchange at most after the routes.")
    ] = 120.0,
    wait_timeout: Annotated[
        float, typer.Option("--wait-timeout", help="Wall seconds to wait for a silent peer.")
    ] = 300.0,
    checkpoint_every: Annotated[
        float, typer.Option("--checkpoint-every", help="Wall seconds between checkpoints.")
    ] = 5.0,
    routes_dir: Annotated[
        Path | None,
        typer.Option(
            "--routes", help="Folder of every robot's route, robotK.npy (t, x, y, theta)."
        ),
    ] = None,
    max_queue: Annotated[
        float,
        typer.Option(
            "--max-queue",
            help="MiB of frames kept per peer: sent and not yet acknowledged (past it the "
            "node fails naming the peer), and received ahead of the one awaited.",
        ),
    ] = 64.0,
    key_file: Annotated[
        Path | None,
        typer.Option(
            "--key",
            help="The team key ('team key'): connections encrypted, and only robots "
            "holding it admitted, each known by its key.",
        ),
    ] = None,
    insecure: Annotated[
        bool,
        typer.Option(
            "--insecure",
            help="Without --key, listen on an address other than loopback all the same "
            "(anyone reaching it could pose as a robot).",
        ),
    ] = False,
    prior_path: Annotated[
        Path | None,
        typer.Option(
            "--prior",
            help="The robot's prior map (map_server YAML), as 'team run --prior': its "
            "regions and global frame; scored against --map all the same. Default: --map.",
        ),
    ] = None,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
    pcm: PcmOption = False,
    territory: NodeTerritoryOption = None,
) -> None:
    """One robot of a team over ZeroMQ (TCP), on the team's lock-step clock: the same
    results as 'team run' on a full network; killed and started again on its --state
    folder, it resumes."""
    from ..team.keys import read_team_key
    from ..team.node import (
        MIB,
        LockstepParams,
        load_routes,
        parse_peers,
        run_node,
    )

    _check_duration(duration)
    for name, value, least in (
        ("--lookahead", lookahead, 0.0),
        ("--settle", settle, 0.0),
        ("--quiet", quiet, None),
        ("--wait-timeout", wait_timeout, None),
        ("--checkpoint-every", checkpoint_every, None),
    ):
        _check_seconds(name, value, least)
    if not (math.isfinite(max_queue) and max_queue > 0):
        raise ConfigError(f"--max-queue must be > 0 MiB, got {max_queue}")
    timing = LockstepParams(
        wait_timeout=wait_timeout, checkpoint_every=checkpoint_every, max_queue=max_queue * MIB
    )
    ex, store, preset_used = _node_settings(ctx, preset, exchange or [])
    peer_map = parse_peers(peers, robot)
    if len(peer_map) + 1 > MAX_ROBOTS:
        raise ConfigError(
            f"--peers: a team of {len(peer_map) + 1} robots; at most {MAX_ROBOTS} robots in a team"
        )
    fixed_routes = None if routes_dir is None else load_routes(routes_dir, len(peer_map) + 1)
    key = None if key_file is None else read_team_key(key_file)
    plan = resolve_map(map_, resolution, origin)
    mask = _territory(territory, plan)
    region = None if mask is None else mask.region
    prior, _ = make_prior(plan, prior_path, seed=seed, resolution=resolution, origin=origin)
    check_prior_inside(plan, prior, region, f"--prior {prior_path}")
    config = _mission_config(duration, seed, store, pcm)
    with progress(f"robot {robot}") as update:
        s = run_node(
            plan,
            config,
            robot,
            listen,
            peer_map,
            out=out,
            exchange=ex,
            state_dir=state,
            lookahead=lookahead,
            quiet=quiet,
            settle=settle,
            timing=timing,
            progress=partial(_tick, update, "ticks"),
            routes=fixed_routes,
            key=key,
            insecure=insecure,
            prior=prior,
            region=region,
        )
    console.print(
        f"robot {robot}: {s['row']['poses_local']} own poses, {len(s['held'])} held, "
        f"{s['ticks']} ticks, {s['restarts']} restarts, preset {preset_used or 'none'}"
    )
    console.print(wrote_folder(out), markup=False)


@team_app.command("key", epilog=EPILOG)
def key_cmd(
    out: Annotated[Path, typer.Option("-o", "--out", help="The key file to write (mode 0600).")],
    robots: Annotated[
        int, typer.Option("--robots", help="Robots the key admits: ids 0..N-1.")
    ] = 16,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing key file.")] = False,
) -> None:
    """A team key for 'team node --key': a CURVE key pair per robot id, in one file
    every robot of the team gets (keep it secret: whoever holds it can join the team)."""
    from ..team.keys import make_team_key

    if out.exists() and not force:
        raise ConfigError(
            f"-o: {out} exists; give --force to replace it (the team's nodes "
            "then need the new file)"
        )
    make_team_key(robots).write(out)
    console.print(f"team key for robots 0..{robots - 1}", markup=False)
    console.print(wrote(out.parent, [out.name]), markup=False)
