"""Bad input and absurd sizes on the command line: one line naming the option or the
file, exit code 2, nothing written, and within seconds (issues 36 and 38)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sonarmap.builtins import builtin_plan
from sonarmap.cli import MESSAGE_LIMIT, bounded, main
from sonarmap.errors import ConfigError, InputError, quote
from sonarmap.io.rosmap import read_map
from sonarmap.parallel import check_workers, process_limit
from sonarmap.patrol import PatrolConfig
from sonarmap.patrol.starts import check_robot_count
from sonarmap.team.config import MAX_ROBOTS, MissionConfig, check_team_size, team_size_problem
from sonarmap.team.world import patrol_route

#: Seconds a refused command may take at most, the interpreter's start included.
QUICK = 60
#: ``team node``'s required options.
NODE = ["--id", "0", "--listen", "tcp://127.0.0.1:1"]


def refused(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``sonarmap ARGS`` in process; assert exit code 2 and one line; the line."""
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("sonarmap: error: ")
    return lines[0]


def refused_subprocess(args: list[str], tmp_path: Path) -> str:
    """Run ``sonarmap ARGS`` as a process with a deadline (a hang fails the test, it does
    not stall the suite); assert exit code 2 and one line; the line."""
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "sonarmap", *args],
        capture_output=True,
        text=True,
        timeout=QUICK,
        cwd=tmp_path,
        env=env,
        check=False,
    )
    assert done.returncode == 2, done.stderr[-2000:]
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr[-2000:]
    return lines[0]


@pytest.fixture
def plan(tmp_path: Path) -> Path:
    """A 6 m x 6 m room at 0.1 m: plan.yaml, plan.png."""
    px = np.full((60, 60), 254, dtype=np.uint8)
    px[:2, :] = px[-2:, :] = px[:, :2] = px[:, -2:] = 0
    Image.fromarray(px).save(tmp_path / "plan.png")
    (tmp_path / "plan.yaml").write_text(
        "image: plan.png\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return tmp_path / "plan.yaml"


# --- Map files ---------------------------------------------------------------------------


def test_a_damaged_npy_header_is_one_line(
    plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = plan.with_suffix(".npy")
    np.save(good, np.zeros((60, 60), dtype=np.float32))
    raw = bytearray(good.read_bytes())
    # The header's dict cut open: numpy's parser fails with tokenize.TokenError.
    start = raw.index(b"{")
    raw[start : start + 10] = b"{'descr': "
    raw[start + 10 : start + 40] = b"(" * 30
    good.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=r"plan\.npy: cannot read occupancy array"):
        read_map(plan)
    line = refused(
        ["patrol", "run", "--map", str(plan), "--robots", "1", "-o", str(tmp_path / "out")],
        capsys,
    )
    assert "plan.npy: cannot read occupancy array" in line
    assert len(line) < 300
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("array", "match"),
    [
        (np.zeros((30, 60), dtype=np.float32), r"array of shape \(30, 60\) beside an image"),
        (np.zeros((60, 60), dtype=np.int64), r"expected a float occupancy array, got int64"),
        (np.full((60, 60), 2.0), r"occupancy must be in \[0, 1\] or NaN, got 2\.0"),
    ],
)
def test_an_npy_of_the_wrong_shape_or_kind_is_one_line(
    plan: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    array: np.ndarray,
    match: str,
) -> None:
    np.save(plan.with_suffix(".npy"), array)
    with pytest.raises(InputError, match=match):
        read_map(plan)
    line = refused(
        ["patrol", "run", "--map", str(plan), "--robots", "1", "-o", str(tmp_path / "out")],
        capsys,
    )
    assert "plan.npy: " in line
    assert not (tmp_path / "out").exists()


# --- Messages of bounded length ------------------------------------------------------------


def test_quote_cuts_a_long_value() -> None:
    assert quote("abc") == "'abc'"
    long = quote("1" * 1_000_000)
    assert long.startswith("'111")
    assert long.endswith("... (1000000 characters)")
    assert len(long) < 120


def test_a_huge_field_is_quoted_short(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "rig.yaml").write_text(
        "sensor: hc-sr04\nsonars: [{name: s0, x: 0.1, y: 0, yaw_deg: 0}]\n"
    )
    (tmp_path / "readings.csv").write_text(
        "t,sensor,x,y,theta,range\n0,s0,1,1,0,0.5\n0.1,s0,1,1,0," + "1" * 1_000_000 + "x\n"
    )
    line = refused(
        [
            "map",
            str(tmp_path / "readings.csv"),
            "--rig",
            str(tmp_path / "rig.yaml"),
            "--resolution",
            "0.1",
            "-o",
            str(tmp_path / "m"),
        ],
        capsys,
    )
    assert "readings.csv:3, field 'range': not a finite number" in line
    assert len(line) < 300
    assert not list(tmp_path.glob("m*"))


# --- NaN and infinity ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "match"),
    [
        # NaN is PatrolConfig's "unset" sentinel: given by a user it must not mean the default.
        (["patrol", "run", "--map", "open-field", "--robots", "1", "--cell", "nan"], "--cell nan"),
        (["patrol", "run", "--map", "open-field", "--min-separation", "nan"], "--min-separation"),
        (["patrol", "run", "--map", "open-field", "--r-obst", "nan"], "--r-obst nan"),
        (["patrol", "run", "--map", "open-field", "--duration", "inf"], "--duration inf"),
        (["patrol", "run", "--map", "open-field", "--origin", "0", "nan"], "--origin nan"),
        (["team", "run", "--map", "office", "--duration", "nan"], "--duration nan"),
        (["team", "run", "--map", "office", "--link-range", "-inf"], "--link-range -inf"),
        (
            [
                "team",
                "node",
                "--map",
                "office",
                "--id",
                "0",
                "--listen",
                "tcp://127.0.0.1:1",
                "--settle",
                "inf",
            ],
            "--settle inf",
        ),
        (["team", "world", "--map", "office", "--texture-share", "nan"], "--texture-share nan"),
    ],
)
def test_nan_and_inf_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], match: str
) -> None:
    line = refused([*args, "-o", str(tmp_path / "out")], capsys)
    assert f"{match}" in line
    assert "expected a finite number" in line
    assert not (tmp_path / "out").exists()


# --- Team sizes and times ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--robots", "100000"], r"--robots 100000: at most 64 robots in a team"),
        (["--robots", "100000", "--transport", "zmq"], r"--robots 100000: at most 64 robots"),
        (["--duration", "1e12"], r"--duration 1e\+12: at most 86400 s \(a day\)"),
    ],
)
def test_team_run_refuses_absurd_sizes_at_once(tmp_path: Path, args: list[str], match: str) -> None:
    out = tmp_path / "out"
    line = refused_subprocess(["team", "run", "--map", "office", *args, "-o", str(out)], tmp_path)
    assert re.search(match, line), line
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        # Each a process: refused before any is started.
        (
            ["run", "--robots", str(process_limit() + 1), "--transport", "zmq"],
            r"--robots \d+: at most \d+ (node processes on this machine|robots in a team)",
        ),
        (["run", "--robots", "0"], r"--robots 0: expected an int >= 1"),
        (["run", "--tour", "--patrol"], r"--tour draws every robot's route: drop --patrol"),
        (["run", "--animate", "--transport", "zmq"], r"--transport zmq: .*--animate"),
        (["world", "--duration", "1e12"], r"--duration 1e\+12: at most 86400 s"),
        (["world", "--change-share", "2"], r"--change-share 2: must be in \[0, 1\]"),
        (["run", "--seed", "-1"], r"'--seed'"),
        (["node", *NODE, "--duration", "1e9"], r"--duration 1e\+09: at most 86400 s"),
        (["node", *NODE, "--settle", "-1"], r"--settle -1: must be >= 0 seconds"),
        (["node", *NODE, "--wait-timeout", "1e9"], r"--wait-timeout 1e\+09: at most 86400 s"),
        (["node", *NODE, "--quiet", "0"], r"--quiet 0: must be > 0 seconds"),
        (["node", *NODE, "--preset", "fast"], r"--preset must be one of classic, lean"),
        (
            ["node", *NODE, "--exchange", "anchor_every=1"],
            r"anchor_share needs anchor_every > 1 .*\(under the default --preset lean; "
            r"--preset classic for the thesis's\)$",
        ),
        (
            ["node", *NODE, "--preset", "lean", "--exchange", "hold=5", "--no-fold"],
            r"--preset lean sets --exchange hold=5, --fold: drop them or drop --preset",
        ),
        (
            ["node", *NODE, "--peers", ",".join(f"tcp://127.0.0.1:{5000 + i}" for i in range(70))],
            r"--peers: a team of 71 robots; at most 64",
        ),
    ],
)
def test_team_options_are_checked_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], match: str
) -> None:
    out = tmp_path / "out"
    line = refused(["team", args[0], "--map", "office", *args[1:], "-o", str(out)], capsys)
    assert re.search(match, line), line
    assert not out.exists()


def test_the_team_library_refuses_absurd_sizes() -> None:
    with pytest.raises(ConfigError, match=r"^robots 100000: at most 64 robots in a team$") as e:
        check_team_size(100_000)
    assert e.value.field == "robots"
    over = team_size_problem(process_limit() + 1, processes=True)
    assert over is not None
    assert re.search(r"node processes on this machine|at most 64 robots", over)
    assert process_limit() <= MAX_ROBOTS
    assert team_size_problem(3, processes=True) is None  # the smallest machine runs 8
    with pytest.raises(ConfigError, match=r"^duration 1e\+12 s: at most 86400 s") as e:
        MissionConfig(duration=1e12)
    assert e.value.field == "duration"
    with pytest.raises(ConfigError, match=r"duration 1e\+12 s: at most 86400 s"):
        patrol_route(builtin_plan("office"), 1e12)


# --- Patrol --------------------------------------------------------------------------------


def test_patrol_run_refuses_a_huge_team_at_once(tmp_path: Path) -> None:
    out = tmp_path / "out"
    line = refused_subprocess(
        ["patrol", "run", "--map", "open-field", "--robots", "100000", "-o", str(out)], tmp_path
    )
    assert line == "sonarmap: error: --robots 100000: at most 64 robots"
    assert not out.exists()


def _patrol_files(d: Path, plan: Path) -> None:
    (d / "many.txt").write_text("100\n" + "10 10 0\n" * 100)
    (d / "short.txt").write_text("3\n10 10 0\n30 30 0\n")
    (d / "nan.txt").write_text("1\n10 nan 0\n")
    (d / "far.txt").write_text("1\n10 1e9 0\n")
    (d / "huge.txt").write_text("1\n" + "1" * 1_000_000 + " 1 0\n")
    (d / "poly_nan.txt").write_text("0 0\n5 0\nnan 5\n")
    (d / "poly_two.txt").write_text("0 0\n5 0\n")
    (d / "poly_three.txt").write_text("0 0 0\n5 0\n5 5\n")
    (d / "wall.txt").write_text("1\n1 1 0\n")
    (d / "sem_nan.txt").write_text("0 0;10 0;nan 10\n")
    (d / "setup.json").write_text('{"max_model_time": 1e15, "robot_number": 1}')
    (d / "settings.yaml").write_text("robots: 1\nstart_fog: .nan\n")
    # Thresholds under which no pixel is free: nothing to patrol.
    (d / "dark.yaml").write_text(plan.read_text().replace("free_thresh: 0.196", "free_thresh: 0.0"))


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--robots", "1", "--duration", "1e12"], r"--duration: duration 1e\+12 s is .* at most"),
        (["--robots", "1", "--sectors", "100000000"], r"--sectors: sectors must be in 1\.\.360"),
        (["--robots", "1", "--dilation", "1000000"], r"--dilation: dilation must be in 0\.\.20"),
        (
            ["--robots", "1", "--cell", "100"],
            r"--cell 100: too coarse for .*plan\.yaml, a map 6 m across",
        ),
        (["--robots", "0"], r"--robots 0: robots must be >= 1"),
        (["--starts", "many.txt"], r"many\.txt:1: robot count must be in 1\.\.64, got 100"),
        (["--starts", "short.txt"], r"short\.txt: the file says 3 robots but lists 2"),
        (["--starts", "nan.txt"], r"nan\.txt:2: expected finite numbers"),
        (["--starts", "far.txt"], r"far\.txt:2: start \(10, 1e\+09\) dm is outside the map"),
        (["--starts", "huge.txt"], r"huge\.txt:2: expected finite numbers, got '1111.*\.\.\."),
        (["--starts", "wall.txt"], r"wall\.txt:2: robot 1 at \(1, 1\) dm is in an obstacle"),
        (
            ["--robots", "1", "--crowding", "semaphores", "--semaphores", "sem_nan.txt"],
            r"sem_nan\.txt:1: expected finite numbers",
        ),
        (["--config", "setup.json"], r"setup\.json, field 'max_model_time': 1e\+15 steps"),
        (["--config", "settings.yaml"], r"--start-fog nan \(from the settings file\)"),
        (["--robots", "1", "--territory", "poly_nan.txt"], r"poly_nan\.txt:3: expected finite"),
        (["--robots", "1", "--territory", "poly_two.txt"], r"poly_two\.txt:1: a polygon needs"),
        (["--robots", "1", "--territory", "poly_three.txt"], r"poly_three\.txt:1: expected 'x y'"),
    ],
)
def test_bad_patrol_sizes_and_files_are_one_line(
    plan: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    args: list[str],
    match: str,
) -> None:
    _patrol_files(tmp_path, plan)
    here = [str(tmp_path / a) if a.endswith((".txt", ".json", ".yaml")) else a for a in args]
    out = tmp_path / "out"
    line = refused(["patrol", "run", "--map", str(plan), *here, "-o", str(out)], capsys)
    assert re.search(match, line), line
    assert len(line) < 400
    assert not out.exists()


def test_a_map_with_no_free_place_names_its_file(
    plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _patrol_files(tmp_path, plan)
    out = tmp_path / "out"
    line = refused(
        ["patrol", "run", "--map", str(tmp_path / "dark.yaml"), "--robots", "1", "-o", str(out)],
        capsys,
    )
    assert re.search(r"dark\.yaml: the map has no free cell .*thresholds", line), line
    assert not out.exists()


def test_the_patrol_library_refuses_absurd_sizes() -> None:
    with pytest.raises(ConfigError, match=r"^sectors must be in 1\.\.360, got 100000000$") as e:
        PatrolConfig(sectors=100_000_000)
    assert e.value.field == "sectors"
    with pytest.raises(ConfigError, match=r"^dilation must be in 0\.\.20 cells") as e:
        PatrolConfig(dilation=10**6)
    assert e.value.field == "dilation"
    with pytest.raises(ConfigError, match=r"at most 10,000,000 steps") as e:
        PatrolConfig(duration=1e12)
    assert e.value.field == "duration"
    with pytest.raises(ConfigError, match=r"^robots 100000: at most 64 robots$") as e:
        check_robot_count(100_000)
    assert e.value.field == "robots"
    # NaN stays the library's explicit "unset": the command line refuses it (above).
    assert PatrolConfig(cell=float("nan"), radius=0.5).cell == 0.25


# --- Mapping, streaming, simulating and the process pools -----------------------------------


@pytest.fixture
def log(tmp_path: Path) -> Path:
    """A rig and a readings CSV of a few seconds in a 4 m square: rig.yaml, readings.csv."""
    (tmp_path / "rig.yaml").write_text(
        "sensor: hc-sr04\nsonars: [{name: s0, x: 0.1, y: 0, yaw_deg: 0}]\n"
    )
    rows = [f"{0.1 * k:.1f},s0,{1 + 0.02 * k:.2f},2,0,1.5" for k in range(50)]
    (tmp_path / "readings.csv").write_text("t,sensor,x,y,theta,range\n" + "\n".join(rows) + "\n")
    (tmp_path / "traj.csv").write_text("t,x,y,theta\n0,1,1,0\n1,2,1,0\n")
    return tmp_path


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["map", "{d}/readings.csv", "--resolution", "0.0001"], r"--resolution: a grid of \d+ x"),
        (
            ["map", "{d}/readings.csv", "--resolution", "0.1", "--bounds", "0,0,2000,2000"],
            r"--resolution/--bounds: a grid of 20000 x 20000 cells at 0.1 m; at most 1e\+08",
        ),
        # Beyond what a Grid holds at all: the grid's own message.
        (["map", "{d}/readings.csv", "--resolution", "1e-9"], r"cells is too large"),
        (["stream", "{d}/readings.csv", "--resolution", "0.0001"], r"--resolution: a grid of"),
        (["stream", "{d}/readings.csv", "--effort", "1000000000"], r"--effort 1000000000: must"),
        (["stream", "{d}/readings.csv", "--snapshot-every", "1e-9"], r"--snapshot-every 1e-09"),
        (["stream", "{d}/readings.csv", "--period", "1e-9"], r"--period 1e-09: at least 0.001"),
        (["stream", "{d}/readings.csv", "--speed", "1e-9"], r"--speed 1e-09: at least 0.01"),
        (["stream", "{d}/readings.csv", "--period", "nan"], r"--period nan: expected a finite"),
    ],
)
def test_map_and_stream_sizes_are_checked_before_any_work(
    log: Path, capsys: pytest.CaptureFixture[str], args: list[str], match: str
) -> None:
    out = log / "out"
    cmd = [a.format(d=log) for a in args]
    line = refused([*cmd, "--rig", str(log / "rig.yaml"), "-o", str(out)], capsys)
    assert re.search(match, line), line
    assert not list(log.glob("out*"))


def test_simulate_refuses_a_negative_seed(log: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (log / "plan.yaml").write_text("image: plan.png\nresolution: 0.1\norigin: [0, 0, 0]\n")
    Image.fromarray(np.full((40, 40), 254, dtype=np.uint8)).save(log / "plan.png")
    out = log / "sim.csv"
    line = refused(
        ["simulate", "--map", str(log / "plan.yaml"), "--rig", str(log / "rig.yaml"),
         "--trajectory", str(log / "traj.csv"), "--seed", "-1", "-o", str(out)],
        capsys,
    )  # fmt: skip
    assert "'--seed'" in line
    assert not out.exists()


def test_process_pools_are_bounded(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError, match=r"^workers 100000: at most \d+ worker processes") as e:
        check_workers(100_000)
    assert e.value.field == "workers"
    check_workers(None)
    check_workers(process_limit())
    out = tmp_path / "out"
    line = refused(
        ["patrol", "experiment", "forces", "--workers", "100000", "-o", str(out)], capsys
    )
    assert re.search(r"--workers: workers 100000: at most \d+ worker processes", line), line
    assert not out.exists()


def test_every_error_line_is_bounded(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert bounded("a\nb   c") == "a b c"
    assert bounded("x" * 1000).endswith("...")
    assert len(bounded("x" * 1000)) < 250
    assert len(bounded("word " * 1000)) <= MESSAGE_LIMIT + 3
    # A value quoted whole by a check deep down (the network's kind) still makes a short line.
    out = tmp_path / "out"
    line = refused(
        ["team", "run", "--map", "office", "--network", "x" * 100_000, "-o", str(out)], capsys
    )
    assert "--network" in line
    assert len(line) < 400
    assert not out.exists()
