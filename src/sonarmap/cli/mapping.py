"""Mapping commands of ``sonarmap``: scenes, simulation, maps, scores, experiments,
sweeps (the user guide: ``docs/guides/mapping.md``)."""

from __future__ import annotations

import csv
import dataclasses
import inspect
import io
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from ..annotations import load_annotations
from ..api import build_map, grid_for_readings, off_grid_note
from ..errors import ConfigError, InputError, quote
from ..experiments import EXPERIMENTS, run_experiment
from ..files import atomic_write, atomic_write_text, json_dumps
from ..io.rosmap import IMAGE_SUFFIXES, write_map
from ..mappers import MAPPERS, parse_params, preset_params
from ..metrics import MapScore, score
from ..parallel import check_workers
from ..plot import save_map_picture, save_side_by_side
from ..readings import REORDER_WINDOW, TimeOrder, read_readings, read_trajectory, write_readings
from ..rig import load_rig
from ..scenarios import PAPER_NOISE, SCENARIOS, make_scenario
from ..simulate import MODEL_KINDS, PoseNoise, make_model, simulate
from ..streaming import DEFAULT_STRATEGY
from ..sweep import load_sweep, run_sweep, summarise
from .common import (
    ImageOrigin,
    ImageResolution,
    MethodPreset,
    ReorderWindow,
    check_grid_size,
    check_inside_plan,
    console,
    figure,
    named_check,
    pairs,
    progress,
    read_plan,
    resolve_map,
    say_order,
    writable,
    wrote,
    wrote_folder,
)

#: Where --help points for more.
EPILOG = "Guide: docs/guides/mapping.md; the methods: docs/methods.md."

app = typer.Typer(help="Mapping commands.")


ScenarioName = Enum("ScenarioName", {n.replace("-", "_"): n for n in SCENARIOS}, type=str)  # type: ignore[misc]
MethodName = Enum("MethodName", {n: n for n in sorted(MAPPERS)}, type=str)  # type: ignore[misc]


def _scenario_params(name: str, pairs: dict[str, str]) -> dict[str, Any]:
    sig = inspect.signature(SCENARIOS[name]).parameters
    valid = [p for p in sig if p not in ("model", "seed", "progress")]
    out: dict[str, Any] = {}
    for key, value in pairs.items():
        if key not in valid:
            raise ConfigError(
                f"unknown parameter '{key}' for scenario '{name}'; valid: {', '.join(valid)}"
            )
        default = sig[key].default
        try:
            if isinstance(default, tuple | list):
                out[key] = tuple(float(v) for v in value.split(","))
            elif isinstance(default, int) and not isinstance(default, bool):
                out[key] = int(value)
            elif isinstance(default, str):  # a name (a rig preset): the scenario checks it
                out[key] = value
            else:
                out[key] = float(value)
        except ValueError:
            raise ConfigError(
                f"parameter '{key}' expects "
                f"{'numbers separated by commas' if isinstance(default, tuple) else 'a number'}"
                f", got {quote(value)}"
            ) from None
    return out


ModelName = Enum("ModelName", {n: n for n in MODEL_KINDS}, type=str)  # type: ignore[misc]

_MODEL_HELP = (
    "Sonar model: 'acoustic' (rays through a 1 cm plan, a transducer's beam pattern, "
    "mirror-like walls; see sonarmap.acoustics) or 'thrun' (the research's model on the "
    "map's cells)."
)


@app.command("scenario", epilog=EPILOG)
def scenario_cmd(
    name: Annotated[ScenarioName, typer.Argument(help="Which scenario.")],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder to write into.")
    ],
    seed: Annotated[int, typer.Option(min=0, help="Seed of everything random.")] = 0,
    param: Annotated[
        list[str] | None,
        typer.Option(
            "--param", help="Scenario parameter KEY=VALUE (lists comma-separated), repeatable."
        ),
    ] = None,
    model: Annotated[ModelName, typer.Option(help=_MODEL_HELP)] = "acoustic",  # type: ignore[assignment]
    p_rand: Annotated[float | None, typer.Option(help="Spurious-reading probability.")] = None,
    p_hit: Annotated[
        float | None, typer.Option(help="thrun: reflection probability per cell.")
    ] = None,
    sigma: Annotated[float | None, typer.Option(help="Range noise, metres.")] = None,
    sonar_param: Annotated[
        list[str] | None,
        typer.Option("--sonar-param", help="acoustic: model parameter KEY=VALUE, repeatable."),
    ] = None,
) -> None:
    """Write a built-in scenario: truth map, geometry, rig, trajectory, readings, annotations.

    With --model thrun and no noise given, the noise the research used for the scene.
    """
    scen = name.value
    params = _scenario_params(scen, pairs(param, "--param"))
    params["model"] = make_model(
        model.value,
        p_rand=p_rand,
        p_hit=p_hit,
        sigma=sigma,
        base=PAPER_NOISE.get(scen),
        params=pairs(sonar_param, "--sonar-param"),
    )
    with progress(f"simulating {scen}") as cb:
        s = make_scenario(scen, **params, seed=seed, progress=cb)
    s.write(out)
    console.print(f"scenario [bold]{scen}[/]: {len(s.readings)} readings")
    console.print(wrote_folder(out), markup=False)


@app.command("simulate", epilog=EPILOG)
def simulate_cmd(
    map_: Annotated[
        Path,
        typer.Option(
            "--map",
            help="Floor plan: map_server YAML, or a bare image with --resolution; the finer, "
            "the truer the echoes; or a built-in map by name (office, building:SEED, open-field, "
            "fig3-2, fig3-4, fig3-10).",
        ),
    ],
    rig: Annotated[Path, typer.Option(help="Rig YAML or preset name.")],
    trajectory: Annotated[Path, typer.Option(help="Trajectory CSV t,x,y,theta.")],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Readings CSV to write.")
    ],
    model: Annotated[ModelName, typer.Option(help=_MODEL_HELP)] = "acoustic",  # type: ignore[assignment]
    p_rand: Annotated[
        float | None, typer.Option(help="Spurious-reading probability [0, 1].")
    ] = None,
    p_hit: Annotated[
        float | None, typer.Option(help="thrun: reflection probability (0, 1].")
    ] = None,
    sigma: Annotated[float | None, typer.Option(help="Range noise sigma, metres.")] = None,
    sonar_param: Annotated[
        list[str] | None,
        typer.Option("--sonar-param", help="acoustic: model parameter KEY=VALUE, repeatable."),
    ] = None,
    pose_sigma_xy: Annotated[float, typer.Option(help="Recorded-pose noise, metres.")] = 0.0,
    pose_sigma_theta: Annotated[float, typer.Option(help="Recorded-heading noise, rad.")] = 0.0,
    seed: Annotated[int, typer.Option(min=0, help="Seed of everything random.")] = 0,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
) -> None:
    """Simulate sonar readings of a rig driven along a trajectory through a floor plan.

    With --model thrun, noise not given comes from the rig's sensor file (default none).
    """
    world = resolve_map(map_, resolution, origin)
    r = load_rig(rig)
    traj = read_trajectory(trajectory)
    check_inside_plan(traj.t, traj.x, traj.y, world.grid, trajectory)
    sonar = make_model(
        model.value,
        p_rand=p_rand,
        p_hit=p_hit,
        sigma=sigma,
        base=r.sensor.noise,
        params=pairs(sonar_param, "--sonar-param"),
    )
    with progress("simulating") as cb:
        readings = simulate(
            world,
            r,
            traj,
            model=sonar,
            pose_noise=PoseNoise(pose_sigma_xy, pose_sigma_theta),
            seed=seed,
            progress=cb,
        )
    write_readings(readings, out)
    console.print(f"wrote {len(readings)} readings to {out}")


@app.command("map", epilog=EPILOG)
def map_cmd(
    readings: Annotated[Path, typer.Argument(help="Readings CSV t,sensor,x,y,theta,range.")],
    rig: Annotated[Path, typer.Option(help="Rig YAML or preset name.")],
    out: Annotated[
        Path,
        typer.Option("-o", "--out", callback=writable, help="Output stem: writes .yaml/.pgm/.npy"),
    ],
    method: Annotated[MethodName, typer.Option(help="Mapping method.")] = "inverse",  # type: ignore[assignment]
    like: Annotated[Path | None, typer.Option(help="Use the grid of this map YAML.")] = None,
    resolution: Annotated[float | None, typer.Option(help="Cell size, metres.")] = None,
    bounds: Annotated[
        tuple[float, float, float, float] | None,
        typer.Option(
            metavar="XMIN YMIN XMAX YMAX",
            help="Metres, space- or comma-separated (default: around the data).",
        ),
    ] = None,
    param: Annotated[
        list[str] | None, typer.Option("--param", help="Method parameter KEY=VALUE, repeatable.")
    ] = None,
    preset: MethodPreset = None,
    reorder_window: ReorderWindow = REORDER_WINDOW,
    origin: ImageOrigin = (0.0, 0.0),
) -> None:
    """Build an occupancy map from readings; writes OUT.yaml, OUT.pgm and OUT.npy.

    --like may be a bare image: --resolution and --origin then place its pixels.
    """
    m = method.value
    params = parse_params(m, pairs(param, "--param"), preset=preset)
    r = load_rig(rig)
    like_image = like is not None and like.suffix.lower() in IMAGE_SUFFIXES
    if like is not None and (bounds is not None or (resolution is not None and not like_image)):
        raise ConfigError("give either --like or --resolution/--bounds, not both")
    order = TimeOrder(reorder_window)
    data = read_readings(readings, names=r.names, order=order)
    say_order(order)
    if like is not None:
        # A bare image as --like takes its pixel size from --resolution.
        grid = read_plan(like, resolution, origin).grid
    elif resolution is not None:
        grid = grid_for_readings(data, r, resolution, bounds)
        check_grid_size(grid, "--resolution" if bounds is None else "--resolution/--bounds")
    else:
        raise ConfigError("give --like MAP.yaml or --resolution R")
    said = off_grid_note(data, r, grid)
    if said is not None:
        console.print(f"note: {said}")
    try:
        with progress(f"mapping ({m})") as cb:
            result = build_map(data, r, grid, m, params, progress=cb)
    except InputError as err:
        raise InputError(err.reason, path=readings, field=err.field) from err
    paths = write_map(result, out)
    console.print(f"wrote {', '.join(str(p) for p in paths)}")


@app.command("show", epilog=EPILOG)
def show_cmd(
    map_: Annotated[
        Path, typer.Argument(help="Map YAML, a bare image, or a built-in map by name, to draw.")
    ],
    out: Annotated[Path, typer.Option("-o", "--out", callback=writable, help="PNG to write.")],
    readings: Annotated[Path | None, typer.Option(help="Readings CSV to overlay.")] = None,
    truth: Annotated[Path | None, typer.Option(help="Truth map YAML to outline in red.")] = None,
    rig: Annotated[
        Path | None,
        typer.Option(help="Rig of the readings: its r_max tells echoes from no-echo readings."),
    ] = None,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
) -> None:
    """Draw a map as a PNG, optionally with the truth outlined and readings overlaid."""
    m = resolve_map(map_, resolution, origin)
    t = read_plan(truth, resolution, origin) if truth is not None else None
    r = load_rig(rig) if rig is not None else None
    rd = None
    if readings is not None:
        rd = read_readings(readings, names=r.names if r is not None else None)
    save_map_picture(
        m,
        out,
        truth=t,
        readings=rd,
        title=map_.stem,
        r_max=r.sensor.r_max if r is not None else None,
    )
    console.print(f"wrote {out}")


@app.command("methods", epilog=EPILOG)
def methods_cmd() -> None:
    """List mapping methods, their parameters with defaults, and their presets (--preset)."""
    table = Table("method", "streams", "parameters (defaults)", "presets (--preset)")
    for name in sorted(MAPPERS):
        cls = MAPPERS[name]
        streams = DEFAULT_STRATEGY.get(name, "yes") if cls.streamer is not None else "-"
        presets = "; ".join(
            f"{p}: " + ", ".join(f"{k}={v!r}" for k, v in values.items())
            for p, values in cls.presets.items()
        )
        table.add_row(
            name,
            streams,
            ", ".join(f"{k}={v!r}" for k, v in cls.param_defaults().items()),
            presets or "-",
        )
    console.print(table)


@app.command("demo", epilog=EPILOG)
def demo_cmd(
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder for the results.")
    ] = Path("out"),
    seed: Annotated[int, typer.Option(min=0, help="Seed of the held-out corridor scene.")] = 1000,
) -> None:
    """Map a held-out corridor scene with every method: maps, a picture, a metrics table."""
    with progress("simulating corridor") as cb:
        s = make_scenario("corridor", seed=seed, progress=cb)
    s.write(out / "corridor")
    # Every registered method at its defaults, after the presets it shows in the demo
    # (the inverse's "traditional": the research's baseline), so the labels are those
    # `map --method NAME --preset PRESET` reproduces.
    runs: list[tuple[str, str, dict[str, Any]]] = []
    for name in sorted(MAPPERS, key=lambda n: (n != "inverse", n)):
        runs += [(f"{name}-{p}", name, preset_params(name, p)) for p in MAPPERS[name].demo_presets]
        runs.append((name, name, {}))
    maps = {}
    for label, name, params in runs:
        with progress(f"mapping ({label})") as cb:
            maps[label] = build_map(s.readings, s.rig, s.truth.grid, name, params, progress=cb)
        write_map(maps[label], out / "maps" / label)
    save_side_by_side(maps, out / "corridor.png", truth=s.truth)
    fields = ["method", *(f.name for f in dataclasses.fields(MapScore))]
    # The terminal shows the main columns; metrics.csv has them all.
    shown = {
        "f1_all": "wall F1",
        "passages_open": "open",
        "passages_detected": "detected",
        "false_openings": "false open.",
        "passage_f1": "passage F1",
        "width_error": "width err",
    }
    table = Table(title=f"corridor seed {seed}: maps against the truth ({len(s.passages)} doors)")
    table.add_column("method", no_wrap=True)
    for head in shown.values():
        table.add_column(head, justify="right", no_wrap=True)
    rows = []
    for name, m in maps.items():
        sc = score(s.truth, m, s.passages).as_dict()
        rows.append({"method": name, **sc})
        table.add_row(name, *(figure(sc[k]) for k in shown))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(out / "metrics.csv", buf.getvalue())
    console.print(table)
    console.print(wrote_folder(out), markup=False)


ExperimentName = Enum("ExperimentName", {n.replace("-", "_"): n for n in EXPERIMENTS}, type=str)  # type: ignore[misc]


#: The research's scene of each experiment (--paper), whose parameters --param sets.
EXPERIMENT_SCENE = {
    "doorways": "doorways",
    "passages": "passages",
    "room-turn": "room-turn",
    "noise": "doorways",
    "real": "doorways",
    "boxes": "boxes",
}
#: The held-out scene family each experiment runs on by default.
HELD_OUT_SCENE = {"doorways": "corridor", "passages": "gaps", "noise": "corridor"}


@app.command("experiment", epilog=EPILOG)
def experiment_cmd(
    name: Annotated[ExperimentName, typer.Argument(help="Which experiment.")],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder for figures and report.")
    ],
    quick: Annotated[bool, typer.Option(help="A small, fast version.")] = False,
    seed: Annotated[
        int | None,
        typer.Option(
            min=0, help="Seed of the first scene (default: the first held-out seed, 1000)."
        ),
    ] = None,
    seeds: Annotated[
        int | None, typer.Option(help="How many scenes (default: the experiment's own).")
    ] = None,
    paper: Annotated[
        bool,
        typer.Option(
            help="The research's own scene read with Thrun's model (a reproduction), "
            "instead of held-out scenes read by the acoustic sonar."
        ),
    ] = False,
    model: Annotated[
        ModelName | None, typer.Option(help="Sonar model of the simulated readings.")
    ] = None,
    scene: Annotated[
        Path | None,
        typer.Option(
            help="A scene folder of your own: truth.yaml, rig.yaml, trajectory.csv and/or "
            "readings.csv, geometry.yaml, annotations.yaml."
        ),
    ] = None,
    param: Annotated[
        list[str] | None,
        typer.Option("--param", help="Parameter of the built-in scene, KEY=VALUE, repeatable."),
    ] = None,
    log: Annotated[
        Path | None, typer.Option(help="real: a CARMEN log or a udacity measurement.txt.")
    ] = None,
    rig: Annotated[
        Path | None,
        typer.Option(help="real: the sonar rig (default: a 16-sonar ring for laser logs)."),
    ] = None,
    resolution: Annotated[
        float | None,
        typer.Option(
            help="real: cell size, metres (0.1). --scene whose truth is a bare image "
            "(truth.png): its metres per pixel."
        ),
    ] = None,
    origin: ImageOrigin = (0.0, 0.0),
) -> None:
    """Run one of the research's experiments: figures, metrics (CSV, JSON), report.html."""
    if scene is not None and param:
        raise ConfigError("give either a scene folder or scene parameters, not both")
    family = EXPERIMENT_SCENE[name.value]
    if not paper and name.value in HELD_OUT_SCENE:
        family = HELD_OUT_SCENE[name.value]
    params = _scenario_params(family, pairs(param, "--param"))
    if name.value != "real" and (log is not None or rig is not None):
        raise ConfigError("--log and --rig belong to the 'real' experiment")
    sonar = make_model(model.value, base=PAPER_NOISE.get(family)) if model is not None else None
    with progress(f"experiment {name.value}") as cb:
        report = run_experiment(
            name.value,
            out,
            quick=quick,
            seed=seed,
            seeds=seeds,
            paper=paper,
            model=sonar,
            progress=cb,
            scene=scene,
            scene_params=params,
            log=log,
            rig=rig,
            resolution=resolution if resolution is not None else 0.1,
            truth_resolution=resolution,
            truth_origin=origin,
        )
    console.print(f"report: {report}", markup=False)
    console.print(wrote_folder(out), markup=False)


@app.command("compare", epilog=EPILOG)
def compare_cmd(
    truth: Annotated[Path, typer.Argument(help="Truth map YAML.")],
    maps: Annotated[list[Path], typer.Argument(help="Map YAML files to score.")],
    annotations: Annotated[
        Path | None,
        typer.Option(
            help="Passages and small obstacles (default: annotations.yaml beside the truth)."
        ),
    ] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Also write JSON here.")] = None,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
) -> None:
    """Score maps against a truth map on the same grid (YAML, or bare images)."""
    t = read_plan(truth, resolution, origin)
    ann = annotations if annotations is not None else truth.parent / "annotations.yaml"
    passages, obstacles = load_annotations(ann) if ann.is_file() else ((), ())
    if annotations is not None and not ann.is_file():
        raise InputError("no such file", path=ann)
    rows = []
    for path in maps:
        m = read_plan(path, resolution, origin)
        try:
            sc = score(t, m, passages, obstacles)
        except InputError as err:
            raise InputError(err.reason, path=path) from err
        rows.append({"map": str(path), **sc.as_dict()})
    # The terminal shows the main columns; --json has them all.
    shown = {
        "f1_all": "wall F1",
        "passages_open": "open",
        "passages_detected": "detected",
        "width_error": "width err",
        "false_openings": "false open.",
        "passage_f1": "passage F1",
        "size_error": "size err",
    }
    # The truth's path goes on a line of its own: a table title would wrap it mid-path.
    console.print(f"against {truth}", soft_wrap=True, markup=False, highlight=False)
    table = Table(title=f"{len(passages)} passages, {len(obstacles)} small obstacles")
    table.add_column("map", no_wrap=True)
    for head in shown.values():
        table.add_column(head, justify="right")
    for path, r in zip(maps, rows, strict=True):
        table.add_row(path.stem, *(figure(r[k]) for k in shown))
    console.print(table)
    if json_out is not None:
        atomic_write_text(json_out, json_dumps(rows))
        console.print(f"wrote {json_out}")


@app.command("sweep", epilog=EPILOG)
def sweep_cmd(
    config: Annotated[Path, typer.Argument(help="Sweep file (YAML).")],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Folder for the results.")
    ],
    scheduler: Annotated[
        str | None,
        typer.Option(help="Address of a running Dask scheduler (default: start a LocalCluster)."),
    ] = None,
    workers: Annotated[
        int | None, typer.Option(help="Worker processes of the LocalCluster (default: the cores).")
    ] = None,
) -> None:
    """Run a parameter sweep on Dask: results.parquet, results.csv, best.csv."""
    named_check("--workers", check_workers, workers)
    cfg = load_sweep(config)
    n = len(cfg.tasks())
    with progress(f"sweep ({n} maps)") as cb:
        df = run_sweep(cfg, scheduler=scheduler, workers=workers, progress=cb)
    best = summarise(df, cfg.metrics)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "results.parquet", lambda tmp: df.to_parquet(tmp, index=False))
    atomic_write_text(out / "results.csv", df.to_csv(index=False))
    atomic_write_text(out / "best.csv", best.to_csv(index=False))
    table = Table(
        title=f"best parameters over {len(cfg.scenarios)} scenario(s) x {len(cfg.seeds)} seed(s)"
    )
    for col in ("method", "metric", "best value", "best parameters"):
        table.add_column(col, no_wrap=col != "best parameters")
    for r in best.itertuples():
        table.add_row(
            str(r.method), f"{r.metric} ({r.goal})", f"{r.best_value:.3f}", str(r.best_params)
        )
    console.print(table)
    console.print(wrote(out, ["results.parquet", "results.csv", "best.csv"]), markup=False)
