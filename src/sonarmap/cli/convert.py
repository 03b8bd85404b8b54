"""``sonarmap convert``: a recorded log into a readings CSV and its rig (the user guide:
``docs/guides/real-data.md``)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer

from ..errors import ConfigError
from ..readings import Readings, TimeOrder, in_time_order, write_readings, write_readings_stream
from ..rig import Rig, load_rig, save_rig
from .common import console, progress, writable

#: Where --help points for more.
EPILOG = "Guide: docs/guides/real-data.md; formats: docs/formats/logs.md."

app = typer.Typer()


def _log_kind(log: Path) -> str:
    if log.is_dir() or log.suffix in (".bag", ".db3", ".mcap"):
        return "rosbag"
    return "udacity" if log.name.startswith("measurement") else "carmen"


@app.command("convert", epilog=EPILOG)
def convert_cmd(
    log: Annotated[
        Path,
        typer.Argument(
            help="CARMEN log (.log, .log.gz), ROS bag (.bag, or a ROS 2 bag folder) or "
            "udacity measurement.txt."
        ),
    ],
    out: Annotated[
        Path, typer.Option("-o", "--out", callback=writable, help="Readings CSV to write.")
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
    with progress("converting") as cb:

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
