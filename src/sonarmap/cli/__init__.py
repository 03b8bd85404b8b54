"""The ``sonarmap`` command line: a thin layer over the Python API.

Every library error becomes one line on stderr and exit code 2; outputs are written
atomically, so a failed command leaves no partial file.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import inspect
import io
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from enum import Enum
from pathlib import Path
from typing import Annotated, Any, Protocol

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from ..annotations import load_annotations
from ..api import build_map, grid_for_log, grid_for_readings, off_grid_note, stream_log
from ..errors import ConfigError, InputError, SonarmapError
from ..experiments import EXPERIMENTS, run_experiment
from ..files import (
    atomic_folder,
    atomic_write,
    atomic_write_text,
    check_writable,
    json_dumps,
    live_outputs,
)
from ..io.record import BagRecorder
from ..io.rosmap import IMAGE_SUFFIXES, OccupancyMap, read_map, write_map
from ..mappers import MAPPERS, parse_params, preset_params
from ..metrics import MapScore, score
from ..plot import MapAnimation, save_map_picture, save_side_by_side
from ..readings import (
    REORDER_WINDOW,
    Readings,
    TimeOrder,
    in_time_order,
    read_readings,
    read_trajectory,
    write_readings,
    write_readings_stream,
)
from ..rig import Rig, load_rig, save_rig
from ..scenarios import PAPER_NOISE, SCENARIOS, make_scenario
from ..simulate import MODEL_KINDS, PoseNoise, make_model, simulate
from ..streaming import DEFAULT_STRATEGY, ReplayReport, StreamingMapper
from ..sweep import load_sweep, run_sweep, summarise
from ..version import __version__

app = typer.Typer(
    name="sonarmap",
    help="Occupancy-grid mapping with wide-beam sonars.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _console(stderr: bool = False) -> Console:
    """A console whose messages stay on one line (soft wrap) and whose tables, in a log
    or a pipe (no terminal, no COLUMNS), get 120 columns instead of rich's 80."""
    stream = sys.stderr if stderr else sys.stdout
    piped = not stream.isatty() and "COLUMNS" not in os.environ
    return Console(stderr=stderr, soft_wrap=True, width=120 if piped else None)


err_console = _console(stderr=True)
console = _console()

ScenarioName = Enum("ScenarioName", {n.replace("-", "_"): n for n in SCENARIOS}, type=str)  # type: ignore[misc]
MethodName = Enum("MethodName", {n: n for n in sorted(MAPPERS)}, type=str)  # type: ignore[misc]


ImageResolution = Annotated[
    float | None,
    typer.Option(
        "--resolution",
        help="Metres per pixel of a map given as a bare image (.png, .pgm, ...), as the "
        "research's simulator took them (0.1).",
    ),
]
ImageOrigin = Annotated[
    tuple[float, float],
    typer.Option(
        "--origin", metavar="X Y", help="World position of a bare image's lower-left corner."
    ),
]


def _read_plan(path: Path, resolution: float | None, origin: tuple[float, float]) -> OccupancyMap:
    """A map from a map_server YAML, or from a bare image with its resolution."""
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return read_map(path, resolution=resolution, origin=origin)
    return read_map(path)


def _writable(out: Path) -> Path:
    """-o: refuse at once an output that cannot be written, before any work."""
    check_writable(out)
    return out


class _Update(Protocol):
    def __call__(self, done: int, total: int, note: str = "") -> None: ...


@contextmanager
def _progress(label: str) -> Iterator[_Update]:
    """A rich progress bar as a callback (``note`` is shown after the label); when
    stderr is not a terminal (a log, CI), a plain line every 10 % or 30 s instead."""
    if not err_console.is_terminal:
        yield _progress_lines(label)
        return
    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=True,
    )
    task = bar.add_task(label, total=None)

    def update(done: int, total: int, note: str = "") -> None:
        bar.update(task, completed=done, total=total, description=f"{label} {note}".strip())

    with bar:
        yield update


def _progress_lines(label: str) -> _Update:
    start = time.monotonic()
    last = {"t": start, "step": -1}

    def update(done: int, total: int, note: str = "") -> None:
        now = time.monotonic()
        step = int(10 * done / total) if total else -1
        if step > last["step"] or now - last["t"] >= 30.0:
            last["t"], last["step"] = now, step
            share = f"{done}/{total} ({100 * done / total:.0f} %)" if total else f"{done}"
            extra = f", {note}" if note else ""
            print(f"{label}: {share}, {now - start:.0f} s{extra}", file=sys.stderr, flush=True)

    return update


def _pairs(items: list[str] | None, option: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{option} expects KEY=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


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
            else:
                out[key] = float(value)
        except ValueError:
            raise ConfigError(
                f"parameter '{key}' expects "
                f"{'numbers separated by commas' if isinstance(default, tuple) else 'a number'}"
                f", got {value!r}"
            ) from None
    return out


ModelName = Enum("ModelName", {n: n for n in MODEL_KINDS}, type=str)  # type: ignore[misc]

_MODEL_HELP = (
    "Sonar model: 'acoustic' (rays through a 1 cm plan, a transducer's beam pattern, "
    "mirror-like walls; see sonarmap.acoustics) or 'thrun' (the research's model on the "
    "map's cells)."
)


@app.command("scenario")
def scenario_cmd(
    name: Annotated[ScenarioName, typer.Argument(help="Which scenario.")],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=_writable, help="Folder to write into.")
    ],
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
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
    params = _scenario_params(scen, _pairs(param, "--param"))
    params["model"] = make_model(
        model.value,
        p_rand=p_rand,
        p_hit=p_hit,
        sigma=sigma,
        base=PAPER_NOISE.get(scen),
        params=_pairs(sonar_param, "--sonar-param"),
    )
    with _progress(f"simulating {scen}") as cb:
        s = make_scenario(scen, **params, seed=seed, progress=cb)
    s.write(out)
    console.print(f"wrote scenario [bold]{scen}[/] ({len(s.readings)} readings) to {out}")


@app.command("simulate")
def simulate_cmd(
    map_: Annotated[
        Path,
        typer.Option(
            "--map",
            help="Floor plan: map_server YAML, or a bare image with --resolution; the finer, "
            "the truer the echoes.",
        ),
    ],
    rig: Annotated[Path, typer.Option(help="Rig YAML or preset name.")],
    trajectory: Annotated[Path, typer.Option(help="Trajectory CSV t,x,y,theta.")],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=_writable, help="Readings CSV to write.")
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
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    resolution: ImageResolution = None,
    origin: ImageOrigin = (0.0, 0.0),
) -> None:
    """Simulate sonar readings of a rig driven along a trajectory through a floor plan.

    With --model thrun, noise not given comes from the rig's sensor file (default none).
    """
    world = _read_plan(map_, resolution, origin)
    r = load_rig(rig)
    traj = read_trajectory(trajectory)
    sonar = make_model(
        model.value,
        p_rand=p_rand,
        p_hit=p_hit,
        sigma=sigma,
        base=r.sensor.noise,
        params=_pairs(sonar_param, "--sonar-param"),
    )
    with _progress("simulating") as cb:
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


MethodPreset = Annotated[
    str | None,
    typer.Option(
        "--preset",
        help="A named parameter set of the method (see 'sonarmap methods'), e.g. "
        "thesis002; --param overrides its values.",
    ),
]


ReorderWindow = Annotated[
    float,
    typer.Option(
        "--reorder-window",
        help="Seconds a reading may come after a later one and still be put back in "
        "time order; later ones are dropped and counted (0 drops every one out of order).",
        min=0.0,
    ),
]


def _say_order(order: TimeOrder) -> None:
    said = order.message(first_line=2)
    if said is not None:
        console.print(f"note: {said}")


@app.command("map")
def map_cmd(
    readings: Annotated[Path, typer.Argument(help="Readings CSV t,sensor,x,y,theta,range.")],
    rig: Annotated[Path, typer.Option(help="Rig YAML or preset name.")],
    out: Annotated[
        Path,
        typer.Option("-o", "--out", callback=_writable, help="Output stem: writes .yaml/.pgm/.npy"),
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
    params = parse_params(m, _pairs(param, "--param"), preset=preset)
    r = load_rig(rig)
    like_image = like is not None and like.suffix.lower() in IMAGE_SUFFIXES
    if like is not None and (bounds is not None or (resolution is not None and not like_image)):
        raise ConfigError("give either --like or --resolution/--bounds, not both")
    order = TimeOrder(reorder_window)
    data = read_readings(readings, names=r.names, order=order)
    _say_order(order)
    if like is not None:
        # A bare image as --like takes its pixel size from --resolution.
        grid = _read_plan(like, resolution, origin).grid
    elif resolution is not None:
        grid = grid_for_readings(data, r, resolution, bounds)
    else:
        raise ConfigError("give --like MAP.yaml or --resolution R")
    said = off_grid_note(data, r, grid)
    if said is not None:
        console.print(f"note: {said}")
    try:
        with _progress(f"mapping ({m})") as cb:
            result = build_map(data, r, grid, m, params, progress=cb)
    except InputError as err:
        raise InputError(err.reason, path=readings, field=err.field) from err
    paths = write_map(result, out)
    console.print(f"wrote {', '.join(str(p) for p in paths)}")


StreamMethod = Enum(  # type: ignore[misc]
    "StreamMethod", {n: n for n in sorted(MAPPERS) if MAPPERS[n].streamer is not None}, type=str
)


@app.command("stream")
def stream_cmd(
    readings: Annotated[Path, typer.Argument(help="Readings CSV t,sensor,x,y,theta,range.")],
    rig: Annotated[Path, typer.Option(help="Rig YAML or preset name.")],
    out: Annotated[
        Path,
        typer.Option("-o", "--out", callback=_writable, help="Folder for the map and pictures."),
    ],
    method: Annotated[StreamMethod, typer.Option(help="Mapping method.")] = "gradient",  # type: ignore[assignment]
    window: Annotated[
        str | None,
        typer.Option(
            help="Readings in play: last:N, cell:N, pose:N[:XY_M[:DEG]][:median] or all "
            "(default: all for inverse, last:1000 for the others)."
        ),
    ] = None,
    realtime: Annotated[
        bool,
        typer.Option(
            "--realtime/--fast",
            help="Replay at the recorded pace (spare time improves the map) or as fast "
            "as possible.",
        ),
    ] = False,
    speed: Annotated[float, typer.Option(help="--realtime: log seconds per wall second.")] = 1.0,
    period: Annotated[float, typer.Option(help="Log seconds per map update.")] = 0.25,
    effort: Annotated[
        int, typer.Option(help="Work per update: gradient steps, or flip sweeps (stochastic).")
    ] = 1,
    resolution: Annotated[float, typer.Option(help="Cell size, metres.")] = 0.05,
    bounds: Annotated[
        tuple[float, float, float, float] | None,
        typer.Option(
            metavar="XMIN YMIN XMAX YMAX",
            help="Metres, space- or comma-separated (default: a first pass over the log).",
        ),
    ] = None,
    like: Annotated[Path | None, typer.Option(help="Use the grid of this map YAML.")] = None,
    snapshot_every: Annotated[
        float, typer.Option(help="Log seconds between map snapshots (PNG + animation frame).")
    ] = 30.0,
    animation: Annotated[
        str, typer.Option(help="Animation file in OUT (.gif, or .mp4 with ffmpeg); '' for none.")
    ] = "stream.gif",
    truth: Annotated[Path | None, typer.Option(help="Truth map YAML to outline in red.")] = None,
    binary: Annotated[
        bool | None,
        typer.Option(
            "--binary/--no-binary",
            help="Draw snapshots binarised at 0.5 (default for gradient, whose streaming "
            "map is not pushed to 0 or 1).",
        ),
    ] = None,
    param: Annotated[
        list[str] | None, typer.Option("--param", help="Method parameter KEY=VALUE, repeatable.")
    ] = None,
    preset: MethodPreset = None,
    reorder_window: ReorderWindow = REORDER_WINDOW,
    bag: Annotated[
        bool,
        typer.Option(
            "--bag/--no-bag",
            help="Also record the run as a ROS 2 bag in MCAP storage (OUT/bag/): /map, "
            "/map_occupancy, /sonar/NAME ranges, /tf robot poses; open it in Foxglove or "
            "'ros2 bag play' it into RViz.",
        ),
    ] = False,
    bag_map_every: Annotated[
        float, typer.Option(help="--bag: log seconds between map messages.", min=0.01)
    ] = 1.0,
    origin: ImageOrigin = (0.0, 0.0),
) -> None:
    """Replay a log through a streaming map: latency, throughput, snapshots, animation.

    --like and --truth may be bare images: --resolution and --origin then place their
    pixels. Writes OUT/map.yaml (.pgm, .npy), OUT/snapshots/t*.png, the animation and
    OUT/stream.json with the figures printed.
    """
    m = method.value
    params = parse_params(m, _pairs(param, "--param"), preset=preset)
    r = load_rig(rig)
    if like is not None and bounds is not None:
        raise ConfigError("give either --like or --bounds, not both")
    grid = (
        _read_plan(like, resolution, origin).grid
        if like is not None
        else grid_for_log(readings, r, resolution, bounds)
    )
    t_map = _read_plan(truth, resolution, origin) if truth is not None else None
    if t_map is not None and t_map.grid != grid:
        raise ConfigError(f"{truth}: the truth map's grid differs from the stream's; use --like")
    strategy = window if window is not None else DEFAULT_STRATEGY.get(m)
    if animation:
        MapAnimation.check_name(out / animation)
    draw_binary = (m == "gradient") if binary is None else binary
    order = TimeOrder(reorder_window)
    anim = MapAnimation(grid, m, binary=draw_binary) if animation else None
    stopping = _StopOnInterrupt()
    report = ReplayReport()
    with (
        live_outputs(out / "snapshots") as shots,
        atomic_folder(out) as tmp,
        contextlib.ExitStack() as stack,
    ):
        rec = stack.enter_context(BagRecorder(tmp / "bag", r)) if bag else None
        next_map = -math.inf

        def record(batch: Readings, sm: StreamingMapper) -> None:
            nonlocal next_map
            if rec is None:
                return
            rec.readings(batch)
            t = float(batch.t[-1])
            if t >= next_map:
                rec.map(sm.result(), t)
                next_map = t + bag_map_every

        def snapshot(t: float, sm: StreamingMapper) -> None:
            occ = sm.occupancy_
            batch = sm.last_batch
            robot = (float(batch.x.mean()), float(batch.y.mean())) if batch else None
            # Straight into OUT/snapshots, so they can be watched while the log plays.
            shots.append(
                save_map_picture(
                    OccupancyMap(grid, occ),
                    out / "snapshots" / f"t{t:07.1f}.png",
                    truth=t_map,
                    readings=batch,
                    r_max=r.sensor.r_max,
                    robot=robot,
                    binary=draw_binary,
                    title=f"{m}, t = {t:.1f} s",
                )
            )
            if anim is not None:
                anim.add(t, occ, robot=robot)

        with _progress(f"streaming ({m}, {strategy})") as cb, stopping:
            total = _log_seconds(readings)

            def tick(t: float) -> None:
                cb(int(t * 10), int(total * 10), f"lag {report.lag:.1f} s" if realtime else "")

            sm, rep = stream_log(
                readings,
                r,
                grid,
                m,
                params,
                strategy=strategy,
                effort=effort,
                period=period,
                realtime=realtime,
                speed=speed,
                snapshot_every=snapshot_every,
                on_snapshot=snapshot,
                progress=tick,
                order=order,
                on_note=lambda said: err_console.print(f"warning: {said}"),
                stop=stopping.asked,
                report=report,
                on_update=record if rec is not None else None,
            )
        _say_order(order)
        if rec is not None and sm.last_batch is not None:
            rec.map(sm.result(), float(sm.last_batch.t[-1]))
        write_map(sm.result(), tmp / "map")
        if anim is not None:
            anim.save(tmp / animation)
        summary: dict[str, Any] = {
            "method": m,
            "strategy": sm.strategy.spec(),
            "mode": "realtime" if realtime else "fast",
            "period_s": period,
            "effort": effort,
            "params": params,
            "readings_reordered": order.reordered,
            "readings_dropped_late": order.dropped,
            **rep.summary(),
        }
        atomic_write_text(tmp / "stream.json", json_dumps(summary) + "\n")
    table = Table("figure", "value")
    for k, v in summary.items():
        table.add_row(k, str(v))
    console.print(table)
    bag_note = f", bag/ ({rec.n_messages} messages)" if rec is not None else ""
    console.print(
        f"wrote {out}/map.yaml, snapshots, {animation or 'no animation'}, stream.json{bag_note}"
    )
    if rep.interrupted:
        err_console.print(
            f"interrupted after {rep.data_duration:.1f} s of log: kept the map so far in {out}"
        )
        # Not typer.Exit: main() would report the interruption a second time.
        sys.exit(_INTERRUPTED)


class _StopOnInterrupt:
    """While active, the first Ctrl-C asks a long job to stop at its next step (so it
    can keep what it has); a second one interrupts at once."""

    def __init__(self) -> None:
        self._asked = False
        self._previous: Any = None

    def asked(self) -> bool:
        return self._asked

    def _handle(self, signum: int, frame: Any) -> None:
        if self._asked:
            raise KeyboardInterrupt
        self._asked = True
        err_console.print("stopping at the next update (Ctrl-C again to abort)")

    def __enter__(self) -> _StopOnInterrupt:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None


def _log_seconds(path: Path) -> float:
    """Time span of a readings CSV from its first and last data lines (for the progress
    bar only; a malformed file is reported by the reader)."""
    try:
        with open(path, "rb") as f:
            f.readline()
            first = f.readline().split(b",")[0]
            f.seek(0, 2)
            f.seek(max(0, f.tell() - 4096))
            last = f.read().splitlines()[-1].split(b",")[0]
        return max(float(last) - float(first), 1e-9)
    except (OSError, ValueError, IndexError):
        return 1.0


@app.command("show")
def show_cmd(
    map_: Annotated[Path, typer.Argument(help="Map YAML (or bare image) to draw.")],
    out: Annotated[Path, typer.Option("-o", "--out", callback=_writable, help="PNG to write.")],
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
    m = _read_plan(map_, resolution, origin)
    t = _read_plan(truth, resolution, origin) if truth is not None else None
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


@app.command("methods")
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


@app.command("demo")
def demo_cmd(
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=_writable, help="Folder for the results.")
    ] = Path("out"),
    seed: Annotated[int, typer.Option(help="Seed of the held-out corridor scene.")] = 1000,
) -> None:
    """Map a held-out corridor scene with every method: maps, a picture, a metrics table."""
    with _progress("simulating corridor") as cb:
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
        with _progress(f"mapping ({label})") as cb:
            maps[label] = build_map(s.readings, s.rig, s.truth.grid, name, params, progress=cb)
        write_map(maps[label], out / "maps" / label)
    picture = save_side_by_side(maps, out / "corridor.png", truth=s.truth)
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
        table.add_row(name, *(_figure(sc[k]) for k in shown))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(out / "metrics.csv", buf.getvalue())
    console.print(table)
    console.print(f"wrote {picture}, {out / 'metrics.csv'} and maps under {out / 'maps'}")


def _figure(v: object) -> str:
    """A table cell: floats to two decimals, NaN (not measured) as a dash."""
    if isinstance(v, float):
        return "-" if math.isnan(v) else f"{v:.2f}"
    return str(v)


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


@app.command("experiment")
def experiment_cmd(
    name: Annotated[ExperimentName, typer.Argument(help="Which experiment.")],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=_writable, help="Folder for figures and report.")
    ],
    quick: Annotated[bool, typer.Option(help="A small, fast version.")] = False,
    seed: Annotated[
        int | None,
        typer.Option(help="Seed of the first scene (default: the first held-out seed, 1000)."),
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
    params = _scenario_params(family, _pairs(param, "--param"))
    if name.value != "real" and (log is not None or rig is not None):
        raise ConfigError("--log and --rig belong to the 'real' experiment")
    sonar = make_model(model.value, base=PAPER_NOISE.get(family)) if model is not None else None
    with _progress(f"experiment {name.value}") as cb:
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
    console.print(f"wrote {report} and the figures and metrics beside it")


@app.command("compare")
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
    t = _read_plan(truth, resolution, origin)
    ann = annotations if annotations is not None else truth.parent / "annotations.yaml"
    passages, obstacles = load_annotations(ann) if ann.is_file() else ((), ())
    if annotations is not None and not ann.is_file():
        raise InputError("no such file", path=ann)
    rows = []
    for path in maps:
        m = _read_plan(path, resolution, origin)
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
        table.add_row(path.stem, *(_figure(r[k]) for k in shown))
    console.print(table)
    if json_out is not None:
        atomic_write_text(json_out, json_dumps(rows))
        console.print(f"wrote {json_out}")


@app.command("sweep")
def sweep_cmd(
    config: Annotated[Path, typer.Argument(help="Sweep file (YAML).")],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=_writable, help="Folder for the results.")
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
    cfg = load_sweep(config)
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    n = len(cfg.tasks())
    with _progress(f"sweep ({n} maps)") as cb:
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
    console.print(f"wrote {out / 'results.parquet'}, results.csv and best.csv")


def _log_kind(log: Path) -> str:
    if log.is_dir() or log.suffix in (".bag", ".db3", ".mcap"):
        return "rosbag"
    return "udacity" if log.name.startswith("measurement") else "carmen"


@app.command("convert")
def convert_cmd(
    log: Annotated[
        Path,
        typer.Argument(
            help="CARMEN log (.log, .log.gz), ROS bag (.bag, or a ROS 2 bag folder) or "
            "udacity measurement.txt."
        ),
    ],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=_writable, help="Readings CSV to write.")
    ],
    fmt: Annotated[str, typer.Option("--format", help="auto, carmen, rosbag or udacity.")] = "auto",
    source: Annotated[
        str,
        typer.Option(
            help="CARMEN messages to convert: auto, FLASER, RLASER, ROBOTLASER1 or SONAR."
        ),
    ] = "auto",
    max_range: Annotated[
        float, typer.Option(help="CARMEN: ranges at or above this (m) are no return.")
    ] = 80.0,
    topic: Annotated[
        list[str] | None,
        typer.Option(
            "--topic", help="ROS: a sensor_msgs/Range topic to convert (repeatable; default all)."
        ),
    ] = None,
    odom_topic: Annotated[
        str | None,
        typer.Option(
            help="ROS: the nav_msgs/Odometry topic for poses (default: the first; else /tf)."
        ),
    ] = None,
    base_frame: Annotated[str, typer.Option(help="ROS: the robot's base frame.")] = "base_link",
    poses: Annotated[
        Path | None,
        typer.Option(help="udacity: the poses file (default: poses.txt beside the log)."),
    ] = None,
    rig: Annotated[
        Path | None,
        typer.Option(
            help="udacity: rig of the sonars (default: the assumed udacity-8 mounting); ROS: "
            "mountings of sensor frames tf_static lacks."
        ),
    ] = None,
    units: Annotated[str, typer.Option(help="udacity: length unit, mm, cm or m.")] = "mm",
    rig_out: Annotated[
        Path | None, typer.Option(help="Where to write the rig (default: OUT with .rig.yaml).")
    ] = None,
) -> None:
    """Convert a recorded log into a readings CSV and the rig that describes its sensors."""

    from ..io.carmen import ConvertSummary, iter_carmen_readings
    from ..io.rosbag import BagSummary, read_bag
    from ..io.udacity import read_udacity

    if fmt not in ("auto", "carmen", "rosbag", "udacity"):
        raise ConfigError(f"--format must be auto, carmen, rosbag or udacity, got {fmt!r}")
    kind = _log_kind(log) if fmt == "auto" else fmt
    rig_path = (
        rig_out
        if rig_out is not None
        else out.with_name(out.name.removesuffix(".gz").removesuffix(".csv") + ".rig.yaml")
    )
    given = load_rig(rig) if rig is not None else None
    t0 = time.perf_counter()
    if kind == "udacity":
        readings, used = read_udacity(
            log, poses or log.with_name("poses.txt"), rig=given, units=units
        )
        write_readings(readings, out)
        save_rig(used, rig_path)
        console.print(f"wrote {len(readings)} readings to {out} and the rig to {rig_path}")
        return
    if kind == "rosbag":
        bag = log.parent if log.suffix in (".db3", ".mcap") else log
        s = BagSummary()
        readings, used = read_bag(
            bag, topics=topic, odom_topic=odom_topic, base_frame=base_frame, rig=given, summary=s
        )
        write_readings(readings, out)
        save_rig(used, rig_path)
        read = ", ".join(f"{k} {v}" for k, v in sorted(s.topics.items()))
        skipped = ", ".join(f"{k} {v}" for k, v in sorted(s.skipped.items()) if v) or "none"
        console.print(
            f"read {read}; poses from {s.pose_source}; skipped: {skipped}; wrote "
            f"{len(readings)} readings to {out} and the rig to {rig_path}"
        )
        return
    summary = ConvertSummary()
    rigs: list[Rig] = []
    order = TimeOrder()
    with _progress("converting") as cb:

        def chunks() -> Iterator[Readings]:
            for part, rg in iter_carmen_readings(
                log,
                source=source,
                max_range=max_range,
                summary=summary,
                progress=lambda n: cb(n, 0),
            ):
                if not rigs:
                    rigs.append(rg)
                yield part

        n = write_readings_stream(in_time_order(chunks(), order), out)
    save_rig(rigs[0], rig_path)
    dt = time.perf_counter() - t0
    counts = ", ".join(f"{k} {v}" for k, v in sorted(summary.counts.items()))
    skipped = ", ".join(f"{k} {v}" for k, v in sorted(summary.skipped.items())) or "none"
    console.print(
        f"read {summary.lines} lines ({counts}; skipped: {skipped}) in {dt:.1f} s, "
        f"{summary.lines / dt:.0f} lines/s; wrote {n} readings to {out} and the "
        f"rig to {rig_path}"
    )
    if order.first is not None:
        console.print(f"note: {order.message()}; the CSV is written in time order")


@app.callback(invoke_without_command=True)
def _root(
    version: Annotated[bool, typer.Option("--version", help="Print the version.")] = False,
) -> None:
    if version:
        console.print(f"sonarmap {__version__}")
        raise typer.Exit()


def _fail(message: str) -> None:
    err_console.print(f"sonarmap: error: {message}", markup=False, highlight=False, soft_wrap=True)
    sys.exit(2)


#: Exit code of a command stopped by Ctrl-C (128 + SIGINT, as shells report it).
_INTERRUPTED = 130

#: Options taking several numbers, which may also be given as one comma-separated word.
_LIST_OPTIONS = {"--bounds": 4}


def _split_lists(args: list[str]) -> list[str]:
    """``--bounds 0,0,6,6`` (or ``--bounds=0,0,6,6``) as ``--bounds 0 0 6 6``."""
    out: list[str] = []
    i = 0
    while i < len(args):
        a = args[i]
        name, eq, value = a.partition("=")
        if name in _LIST_OPTIONS and (eq or (i + 1 < len(args) and "," in args[i + 1])):
            if not eq:
                i += 1
                value = args[i]
            values = [v.strip() for v in value.split(",")]
            if len(values) != _LIST_OPTIONS[name]:
                raise ConfigError(
                    f"{name} takes {_LIST_OPTIONS[name]} numbers (comma- or space-separated), "
                    f"got {value!r}"
                )
            out.append(name)
            out.extend(values)
        else:
            out.append(a)
        i += 1
    return out


def main(argv: list[str] | None = None) -> None:
    """Console entry point: every error becomes one line on stderr and exit code 2."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:
        # Help for a bare command, as for --help (not a usage error).
        args = ["--help"]
    try:
        rv = app(args=_split_lists(args), prog_name="sonarmap", standalone_mode=False)
    except SonarmapError as err:
        _fail(str(err))
    except typer.Abort:
        _fail("aborted")
    except Exception as err:
        # Usage errors of the command-line parser (typer vendors click, whose exception
        # classes are private): they carry format_message() and a context.
        fmt = getattr(err, "format_message", None)
        if fmt is None:
            raise
        ctx = getattr(err, "ctx", None)
        where = f"{ctx.command_path}: " if ctx is not None else ""
        _fail(where + " ".join(str(fmt()).split()))
    if rv == _INTERRUPTED:
        # Typer turns Ctrl-C into this exit code. Outputs are written atomically, so an
        # interrupted command leaves none behind.
        err_console.print("sonarmap: interrupted", markup=False, highlight=False)
    if isinstance(rv, int) and rv != 0:
        sys.exit(rv)


# Command groups in modules of their own; they use the helpers above.
from .patrol import patrol_app  # noqa: E402

app.add_typer(patrol_app, name="patrol")

from .team import team_app  # noqa: E402

app.add_typer(team_app, name="team")


if __name__ == "__main__":  # pragma: no cover
    main()
