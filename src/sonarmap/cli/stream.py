"""``sonarmap stream``: replay a log through a streaming map (the user guide:
``docs/guides/streaming.md``)."""

from __future__ import annotations

import contextlib
import math
import sys
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from ..api import grid_for_log, stream_log
from ..errors import ConfigError
from ..files import atomic_folder, atomic_write_text, json_dumps, live_outputs
from ..io.record import MappingPublisher, make_recorder
from ..io.rosmap import OccupancyMap, write_map
from ..mappers import MAPPERS, parse_params
from ..plot import MapAnimation, save_map_picture
from ..readings import REORDER_WINDOW, Readings, TimeOrder
from ..rig import load_rig
from ..streaming import DEFAULT_STRATEGY, ReplayReport, StreamingMapper
from .common import (
    INTERRUPTED,
    ImageOrigin,
    LiveOption,
    LivePortOption,
    LiveRateOption,
    MethodPreset,
    ReorderWindow,
    StopOnInterrupt,
    check_grid_size,
    console,
    err_console,
    pairs,
    progress,
    read_plan,
    say_order,
    writable,
    wrote_folder,
)

#: Where --help points for more.
EPILOG = "Guide: docs/guides/streaming.md; the methods: docs/methods.md."

app = typer.Typer()


StreamMethod = Enum(  # type: ignore[misc]
    "StreamMethod", {n: n for n in sorted(MAPPERS) if MAPPERS[n].streamer is not None}, type=str
)


@app.command("stream", epilog=EPILOG)
def stream_cmd(
    readings: Annotated[Path, typer.Argument(help="Readings CSV t,sensor,x,y,theta,range.")],
    rig: Annotated[Path, typer.Option(help="Rig YAML or preset name.")],
    out: Annotated[
        Path,
        typer.Option("-o", "--out", callback=writable, help="Folder for the map and pictures."),
    ],
    method: Annotated[StreamMethod, typer.Option(help="Mapping method.")] = "gradient",  # type: ignore[assignment]
    window: Annotated[
        str | None,
        typer.Option(
            help="Readings in play: last:N, cell:N, pose:N[:XY_M[:DEG]][:median] or all "
            "(default: all for inverse, last:50 for em-thrun, last:1000 for the others)."
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
        int,
        typer.Option(
            help="Work per update: gradient steps, flip sweeps (stochastic) or M-step "
            "sweeps at most (em-thrun)."
        ),
    ] = 1,
    finish: Annotated[
        bool,
        typer.Option(
            "--finish/--no-finish",
            help="At the end of the log, bring the map to rest (gradient: 100 passes over "
            "the readings in play; Ctrl-C skips or cuts it short).",
        ),
    ] = True,
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
        float, typer.Option(help="--bag, --live: log seconds between map messages.", min=0.01)
    ] = 1.0,
    live: LiveOption = False,
    live_port: LivePortOption = 8765,
    live_rate: LiveRateOption = 1.0,
    origin: ImageOrigin = (0.0, 0.0),
) -> None:
    """Replay a log through a streaming map: latency, throughput, snapshots, animation.

    --like and --truth may be bare images: --resolution and --origin then place their
    pixels. Writes OUT/map.yaml (.pgm, .npy), OUT/snapshots/t*.png, the animation and
    OUT/stream.json with the figures printed.
    """
    _check_pace(speed, period, effort, snapshot_every)
    m = method.value
    params = parse_params(m, pairs(param, "--param"), preset=preset)
    r = load_rig(rig)
    if like is not None and bounds is not None:
        raise ConfigError("give either --like or --bounds, not both")
    if like is not None:
        grid = read_plan(like, resolution, origin).grid
    else:
        grid = grid_for_log(readings, r, resolution, bounds)
        check_grid_size(grid, "--resolution" if bounds is None else "--resolution/--bounds")
    t_map = read_plan(truth, resolution, origin) if truth is not None else None
    if t_map is not None and t_map.grid != grid:
        raise ConfigError(f"{truth}: the truth map's grid differs from the stream's; use --like")
    strategy = window if window is not None else DEFAULT_STRATEGY.get(m)
    if animation:
        MapAnimation.check_name(out / animation)
    draw_binary = (m == "gradient") if binary is None else binary
    order = TimeOrder(reorder_window)
    anim = MapAnimation(grid, m, binary=draw_binary) if animation else None
    stopping = StopOnInterrupt()
    report = ReplayReport()
    with (
        live_outputs(out / "snapshots") as shots,
        atomic_folder(out) as tmp,
        contextlib.ExitStack() as stack,
    ):
        recorder = stack.enter_context(
            make_recorder(
                tmp / "bag" if bag else None,
                live_port=live_port if live else None,
                # --realtime paces the replay itself, at --speed.
                live_rate=None if realtime else live_rate,
            )
        )
        rec = MappingPublisher(recorder, r) if recorder else None
        if recorder.url is not None:
            pace = f"{speed:g}x (--speed)" if realtime else f"{live_rate:g}x (--live-rate)"
            console.print(
                f"live: {recorder.url} (Foxglove: Open connection), {pace} real time",
                markup=False,
            )
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

        with progress(f"streaming ({m}, {strategy})") as cb, stopping:
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
                finish=finish,
            )
        say_order(order)
        if rec is not None and sm.last_batch is not None:
            rec.map(sm.result(), float(sm.last_batch.t[-1]))
        recorder.close()  # the bag complete before it moves into OUT
        write_map(sm.result(), tmp / "map")
        if anim is not None:
            # An animation of many frames takes tens of seconds to encode.
            with progress("writing") as cb:
                cb(0, 0, animation)
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
    if bag and rec is not None:
        console.print(f"bag/: {rec.n_messages} messages")
    console.print(wrote_folder(out), markup=False)
    if rep.interrupted:
        # A stop during the finish comes after the whole log: say which.
        when = "in the finish, " if rep.finish_time > 0 else ""
        err_console.print(
            f"interrupted {when}after {rep.data_duration:.1f} s of log: kept the map so far "
            f"in {out}"
        )
        # Not typer.Exit: main() would report the interruption a second time.
        sys.exit(INTERRUPTED)


#: The replay's pace, bounded so that a typo fails at once instead of running for days:
#: updates at most every millisecond of log, at least a hundredth of real time with
#: --realtime (a minute of log in under two hours), at most a thousand gradient steps or
#: flip sweeps per update.
MIN_PERIOD = 0.001
MIN_SPEED = 0.01
MAX_EFFORT = 1000


def _check_pace(speed: float, period: float, effort: int, snapshot_every: float) -> None:
    """--speed, --period, --effort and --snapshot-every in their ranges, before any work."""
    if not (period >= MIN_PERIOD):
        raise ConfigError(f"--period {period:g}: at least {MIN_PERIOD:g} s of log per update")
    if not (speed >= MIN_SPEED):
        raise ConfigError(f"--speed {speed:g}: at least {MIN_SPEED:g} log seconds a second")
    if not (1 <= effort <= MAX_EFFORT):
        raise ConfigError(f"--effort {effort}: must be in 1..{MAX_EFFORT}")
    if not (snapshot_every >= period):
        # A snapshot is taken after an update: a shorter interval cannot be kept.
        raise ConfigError(f"--snapshot-every {snapshot_every:g}: at least --period ({period:g} s)")


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
