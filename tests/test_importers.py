"""CARMEN and udacity importers, on logs written here and on the shared real logs."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pytest

from conftest import SHARED_DATA
from sonarmap.cli import main
from sonarmap.errors import InputError
from sonarmap.io.carmen import ConvertSummary, read_carmen
from sonarmap.io.udacity import read_udacity
from sonarmap.readings import TimeOrder, read_readings
from sonarmap.rig import load_rig

TRAILER = "12.5 host 12.6"


def flaser(n: int, r: float, x: float, y: float, th: float, t: float = 1.0) -> str:
    ranges = " ".join([str(r)] * n)
    return f"FLASER {n} {ranges} {x} {y} {th} {x} {y} {th} {t} host {t}"


def robotlaser(ranges: list[float], remissions: bool) -> str:
    rem = " 2 0.1 0.2" if remissions else ""
    rs = " ".join(map(str, ranges))
    return (
        f"ROBOTLASER1 0 -1.5708 3.1416 0.7854 50.0 0.01 0 {len(ranges)} {rs}{rem} "
        f"1.1 2.0 0.5 1.0 2.0 0.5 0.0 0.0 0.5 0.5 0.0 {TRAILER}"
    )


def sonar(ranges: list[float]) -> str:
    n = len(ranges)
    offs = " ".join(f"0.1 {0.05 * i} {0.5 * i}" for i in range(n))
    return f"SONAR 0.5236 {n} {' '.join(map(str, ranges))} {offs} 3.0 4.0 1.0 0.1 0.0 {TRAILER}"


def write(tmp_path: Path, lines: list[str], name: str = "log.log") -> Path:
    p = tmp_path / name
    text = "\n".join(lines) + "\n"
    if name.endswith(".gz"):
        p.write_bytes(gzip.compress(text.encode()))
    else:
        p.write_text(text)
    return p


def test_flaser_beams_poses_and_no_return(tmp_path: Path) -> None:
    log = write(
        tmp_path,
        [
            "# CARMEN Logfile",
            "PARAM robot_width 0.5 host 0",
            "ODOM 1 2 0.3 0 0 0 1.0 host 1.0",
            flaser(5, 2.0, 1.0, 2.0, 0.5),
            "NEFF 1 2 3",
            flaser(5, 81.9, 1.5, 2.0, 0.5, t=2.0),
        ],
        "a.log.gz",
    )
    s = ConvertSummary()
    r, rig = read_carmen(log, summary=s)
    assert len(r) == 10
    assert s.counts == {"FLASER": 2, "ODOM": 1}
    assert s.skipped == {"PARAM": 1, "NEFF": 1}
    assert rig.names[0] == "flaser_000"
    yaws = [m.yaw_deg for m in rig.mounts]
    assert yaws[0] == pytest.approx(-90.0)
    assert yaws[-1] == pytest.approx(90.0)
    assert r.theta[2] == pytest.approx(0.5)  # the middle beam looks along the heading
    assert np.all(r.range[5:] == rig.sensor.r_max)  # no return: no echo
    assert rig.sensor.r_max == 80.0


def test_rlaser_robotlaser_sonar(tmp_path: Path) -> None:
    log = write(
        tmp_path,
        [
            flaser(3, 1.0, 0, 0, 0),
            "RLASER 3 1 1 1 0 0 0 0 0 0 1.0 h 1.0",
            robotlaser([1.0, 2.0, 3.0, 4.0, 5.0], remissions=False),
            robotlaser([1.0, 2.0, 3.0, 4.0, 5.0], remissions=True),
            sonar([1.0, 2.0, 3.0]),
        ],
    )
    r, rig = read_carmen(log, source="RLASER")
    assert rig.mounts[0].yaw_deg == pytest.approx(90.0)
    r, rig = read_carmen(log, source="ROBOTLASER1")
    assert len(r) == 10
    # The laser sits 0.1 m from the robot along world x; the robot heads 0.5 rad, so in
    # the robot frame the offset is rotated by -0.5.
    assert rig.mounts[0].x == pytest.approx(0.1 * math.cos(0.5))
    assert rig.mounts[0].y == pytest.approx(-0.1 * math.sin(0.5))
    assert r.x[0] == pytest.approx(1.1)
    assert r.theta[0] == pytest.approx(0.5 - 1.5708)
    r, rig = read_carmen(log)  # auto prefers sonar
    assert rig.names == ("sonar_000", "sonar_001", "sonar_002")
    assert math.degrees(0.5236) == pytest.approx(
        rig.sensor.to_dict()["beam"]["cone"]["aperture_deg"], rel=1e-6
    )
    c, s = math.cos(1.0), math.sin(1.0)
    assert r.x[1] == pytest.approx(3.0 + 0.1 * c - 0.05 * s)
    assert r.theta[2] == pytest.approx(2.0)


@pytest.mark.parametrize(
    ("lines", "match"),
    [
        (["FLASER 3 1 2 x 0 0 0 0 0 0 1 h 1"], r"log.log:1: range: not a number \('x'\)"),
        ([flaser(3, 1, 0, 0, 0), "ODOM 1 2"], r"log.log:2: ODOM message is truncated"),
        ([flaser(3, 1, 0, 0, 0), "FLASER 5 1 2"], r"log.log:2: FLASER message is truncated"),
        (["SONAR 0.5 2 1 2 0 0 0 3 4 5 h 1"], r"log.log:1: SONAR message has 13 fields"),
        (["FLASER -3 1 h"], r"log.log:1: number of readings is negative"),
        ([flaser(3, 1, 0, 0, 0), flaser(4, 1, 0, 0, 0)], r"log.log:2: FLASER message has 4 beams"),
        (["FLASER 2 -1 1 0 0 0 0 0 0 1 h 1"], r"log.log:1: negative range"),
        (["PARAM a b c"], r"no range messages"),
    ],
)
def test_bad_logs(tmp_path: Path, lines: list[str], match: str) -> None:
    with pytest.raises(InputError, match=match):
        read_carmen(write(tmp_path, lines))


def test_truncated_gzip_and_unknown_source(tmp_path: Path) -> None:
    data = gzip.compress(("\n".join([flaser(180, 2.0, 0, 0, 0)] * 400) + "\n").encode())
    p = tmp_path / "cut.log.gz"
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut.log.gz: compressed file is truncated"):
        read_carmen(p, source="FLASER")
    with pytest.raises(InputError, match="unknown source 'LIDAR'"):
        read_carmen(p, source="LIDAR")


def test_convert_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write(
        tmp_path,
        [flaser(5, 2.0, 1.0, 2.0, 0.5), "NEFF 1", flaser(5, 3.0, 1.5, 2.0, 0.5, t=2.0)],
        "run.log.gz",
    )
    main(["convert", str(log), "-o", str(tmp_path / "run.csv")])
    out = capsys.readouterr().out
    assert "FLASER 2" in out
    assert "skipped: NEFF 1" in out
    rig = load_rig(tmp_path / "run.rig.yaml")
    r = read_readings(tmp_path / "run.csv", names=rig.names)
    assert len(r) == 10
    bad = write(tmp_path, [flaser(5, 2.0, 1.0, 2.0, 0.5), "FLASER 5 1 2"], "bad.log")
    with pytest.raises(SystemExit) as e:
        main(["convert", str(bad), "-o", str(tmp_path / "bad.csv")])
    assert e.value.code == 2
    assert "bad.log:2: FLASER message is truncated" in capsys.readouterr().err
    assert not (tmp_path / "bad.csv").exists()
    assert not (tmp_path / "bad.rig.yaml").exists()


@pytest.mark.parametrize("prefix", [b"", flaser(3, 1, 0, 0, 0).encode() + b"\n"])
def test_binary_garbage_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], prefix: bytes
) -> None:
    log = tmp_path / "garbage.log"
    log.write_bytes(prefix + bytes(range(128, 256)) * 40)
    with pytest.raises(SystemExit) as e:
        main(["convert", str(log), "-o", str(tmp_path / "g.csv")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "garbage.log: not a text log" in err
    assert len(err.strip().splitlines()) == 1
    assert sorted(q.name for q in tmp_path.iterdir()) == ["garbage.log"]


def test_convert_writes_time_order(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The third scan was logged 0.5 s late, as four of the Intel log's are.
    scans = [flaser(2, 2.0, 0.1 * k, 0, 0, t=1.0 + k) for k in range(5)]
    scans[2], scans[3] = scans[3], scans[2].replace(" 3.0 host 3.0", " 3.5 host 3.5")
    log = write(tmp_path, scans, "late.log")
    main(["convert", str(log), "-o", str(tmp_path / "late.csv")])
    out = capsys.readouterr().out
    assert "put 2 readings back in time order (at most 0.5 s late; the first at reading 6" in out
    r = read_readings(tmp_path / "late.csv", order=TimeOrder(None))  # strictly in order
    assert r.t.tolist() == [1, 1, 2, 2, 3.5, 3.5, 4, 4, 5, 5]


def test_udacity(tmp_path: Path) -> None:
    (tmp_path / "measurement.txt").write_text(
        "1000 5110 5110 2320 2360 5110 5110 2160 1190\n1214 100 200 300 400 500 600 700 800\n"
    )
    (tmp_path / "poses.txt").write_text("1000 0 0 0\n1214 1000 -500 900\n")
    r, rig = read_udacity(tmp_path / "measurement.txt", tmp_path / "poses.txt")
    assert len(r) == 16
    assert r.range[0] == rig.sensor.r_max  # 5110: no echo
    assert r.range[2] == pytest.approx(2.32)
    assert r.t[8] == pytest.approx(0.214)
    assert r.x[8] == pytest.approx(1.0)
    assert r.theta[8] == pytest.approx(math.radians(90 - 90))  # heading 90, sonar at -90
    (tmp_path / "poses.txt").write_text("1000 0 0 0\n1215 1000 -500 900\n")
    with pytest.raises(InputError, match=r"poses.txt:2: timestamp 1215 does not match"):
        read_udacity(tmp_path / "measurement.txt", tmp_path / "poses.txt")
    with pytest.raises(InputError, match="unknown units 'inch'"):
        read_udacity(tmp_path / "measurement.txt", tmp_path / "poses.txt", units="inch")
    (tmp_path / "measurement.txt").write_text("1000 5110 5110\n")
    with pytest.raises(InputError, match=r"measurement.txt:1: expected 9 fields"):
        read_udacity(tmp_path / "measurement.txt", tmp_path / "poses.txt")


CARMEN = SHARED_DATA / "carmen"
UDACITY = SHARED_DATA / "udacity-sonar"


@pytest.mark.skipif(
    not (CARMEN / "intel-corrected.log.gz").is_file(),
    reason="shared data (../shared/data/carmen) not present",
)
def test_real_intel_log() -> None:
    s = ConvertSummary()
    r, rig = read_carmen(CARMEN / "intel-corrected.log.gz", summary=s)
    assert s.counts["FLASER"] == 910
    assert len(rig.mounts) == 180
    assert len(r) == 910 * 180
    assert 0.0 < np.mean(r.range >= rig.sensor.r_max) < 0.1


@pytest.mark.skipif(
    not (UDACITY / "measurement.txt").is_file(),
    reason="shared data (../shared/data/udacity-sonar) not present",
)
def test_real_udacity_log() -> None:
    r, rig = read_udacity(UDACITY / "measurement.txt", UDACITY / "poses.txt")
    assert len(r) == 413 * 8
    assert np.mean(r.range >= rig.sensor.r_max) == pytest.approx(1 / 3, abs=0.05)


def laser_log(tmp_path: Path) -> Path:
    """A FLASER log of a 6 m x 4 m room, simulated with a 181-beam laser."""
    from sonarmap.grid import Grid
    from sonarmap.io.rosmap import OccupancyMap
    from sonarmap.readings import Trajectory
    from sonarmap.rig import Mount, Rig
    from sonarmap.sensors import Noise, Region, SensorModel
    from sonarmap.simulate import simulate

    grid = Grid(0.05, (0.0, 0.0), (80, 120))
    occ = np.zeros(grid.shape, np.float32)
    occ[:2, :] = occ[-2:, :] = 1
    occ[:, :2] = occ[:, -2:] = 1
    occ[30:50, 60:62] = 1  # a short wall in the middle
    truth = OccupancyMap(grid, occ)
    beam = SensorModel("laser", Region.cone(0.5, 20.0), 0.0, 20.0, 0.01)
    rig = Rig(beam, tuple(Mount(f"b{i}", 0, 0, -90 + i) for i in range(181)))
    n = 60
    t = np.arange(n, dtype=np.float64) * 0.2
    traj = Trajectory(t, 1.0 + 4.0 * t / t[-1], np.full(n, 2.0), np.zeros(n))
    r = simulate(truth, rig, traj, model=Noise(0, 1, 0), seed=0)
    lines = []
    for k in range(n):
        ranges = " ".join(f"{v:.3f}" for v in r.range[k * 181 : (k + 1) * 181])
        x, y = traj.x[k], traj.y[k]
        lines.append(f"FLASER 181 {ranges} {x} {y} 0.0 {x} {y} 0.0 {t[k]} h {t[k]}")
    return write(tmp_path, lines, "room.log.gz")


def test_virtual_sonar_and_real_experiment(tmp_path: Path) -> None:
    from sonarmap.experiments import run_experiment
    from sonarmap.virtual import default_ring, virtual_sonar

    laser, laser_rig = read_carmen(laser_log(tmp_path))
    sonar, kept = virtual_sonar(laser, laser_rig, default_ring())
    # The laser covers -90..90 degrees: the ring's sonars within 75 degrees of the front.
    assert kept.names == ("s00", "s01", "s02", "s03", "s13", "s14", "s15")
    # A sonar looking along the heading reads the nearest wall point in its 30-degree cone.
    front = sonar.range[sonar.sensor == 0]
    assert 0.1 < front.min() < front.max() <= kept.sensor.r_max
    report = run_experiment("real", tmp_path / "exp", log=tmp_path / "room.log.gz", resolution=0.1)
    rows = {
        r["method"]: r
        for r in __import__("json").loads((tmp_path / "exp" / "metrics.json").read_text())
    }
    assert set(rows) >= {"inverse", "gradient", "stochastic", "em"}
    assert rows["em"]["f1"] > 0.4
    assert "laser reference" in report.read_text()


@pytest.mark.skipif(
    not (CARMEN / "intel-corrected.log.gz").is_file(),
    reason="shared data (../shared/data/carmen) not present",
)
def test_real_experiment_on_intel(tmp_path: Path) -> None:
    from sonarmap.experiments import run_experiment

    run_experiment("real", tmp_path, quick=True, log=CARMEN / "intel-corrected.log.gz")
    import json

    from sonarmap.experiments import METHODS

    rows = json.loads((tmp_path / "metrics.json").read_text())
    assert [r["method"] for r in rows] == [m.label for m in METHODS]
    assert all(r["f1"] > 0.2 for r in rows)


@pytest.mark.skipif(
    not (UDACITY / "measurement.txt").is_file(),
    reason="shared data (../shared/data/udacity-sonar) not present",
)
def test_real_experiment_on_udacity(tmp_path: Path) -> None:
    from sonarmap.experiments import run_experiment

    run_experiment("real", tmp_path, log=UDACITY / "measurement.txt")
    import json

    agree = json.loads((tmp_path / "agreement.json").read_text())
    assert all(0.5 < r["inverse"] <= 1.0 for r in agree)
