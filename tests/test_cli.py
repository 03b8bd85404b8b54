"""The command line: the documented workflow on a hand-made floor plan, and error paths."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sonarmap.cli import main
from sonarmap.io.rosmap import OccupancyMap, read_map
from sonarmap.metrics import score


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        main(args)
        code = 0
    except SystemExit as e:
        code = int(e.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def floor_plan(tmp_path: Path) -> Path:
    """A 5 m x 4 m room drawn as a map_server image, a rig and a loop trajectory."""
    h = 0.05
    rows, cols = int(4 / h), int(5 / h)
    px = np.full((rows, cols), 254, dtype=np.uint8)
    px[:3, :] = px[-3:, :] = 0
    px[:, :3] = px[:, -3:] = 0
    px[30:50, 40:44] = 0  # a pillar
    Image.fromarray(px).save(tmp_path / "plan.png")
    (tmp_path / "plan.yaml").write_text(
        "image: plan.png\nresolution: 0.05\norigin: [-1.0, -1.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    (tmp_path / "rig.yaml").write_text(
        "sensor: hc-sr04\nsonars:\n"
        + "".join(
            f"  - {{name: s{k}, x: 0.1, y: 0.0, yaw_deg: {a}}}\n"
            for k, a in enumerate(range(-90, 91, 30))
        )
        + "  - {name: back, x: -0.1, y: 0.0, yaw_deg: 180}\n"
    )
    t = np.linspace(0, 60, 601)
    a = 2 * math.pi * t / 60
    lines = ["t,x,y,theta"] + [
        f"{ti:.2f},{1.5 + 1.6 * math.cos(ai):.4f},{1.0 + 1.2 * math.sin(ai):.4f},"
        f"{ai + math.pi / 2:.4f}"
        for ti, ai in zip(t, a, strict=True)
    ]
    (tmp_path / "traj.csv").write_text("\n".join(lines) + "\n")
    return tmp_path


def test_workflow_on_outside_floor_plan(
    floor_plan: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = floor_plan
    code, _, err = run(
        [
            "simulate",
            "--map",
            str(d / "plan.yaml"),
            "--rig",
            str(d / "rig.yaml"),
            "--trajectory",
            str(d / "traj.csv"),
            "--seed",
            "1",
            "-o",
            str(d / "readings.csv"),
        ],
        capsys,
    )
    assert code == 0, err
    code, _, err = run(
        [
            "map",
            str(d / "readings.csv"),
            "--rig",
            str(d / "rig.yaml"),
            "--method",
            "inverse",
            "--like",
            str(d / "plan.yaml"),
            "-o",
            str(d / "inv"),
        ],
        capsys,
    )
    assert code == 0, err
    m = read_map(d / "inv.yaml")
    truth = read_map(d / "plan.yaml")
    assert m.grid == truth.grid
    s = score(truth, m)
    # Better than the maps that cost nothing: every cell occupied, or every cell free.
    full = score(truth, OccupancyMap(truth.grid, np.ones(truth.grid.shape, np.float32)))
    assert s.f1_all > full.f1_all
    assert s.precision > 0.6
    assert s.accuracy > 0.8
    occ_npy = np.load(d / "inv.npy")
    assert occ_npy.shape == truth.grid.shape
    assert occ_npy.dtype == np.float32
    code, _, err = run(
        [
            "show",
            str(d / "inv.yaml"),
            "--truth",
            str(d / "plan.yaml"),
            "--readings",
            str(d / "readings.csv"),
            "-o",
            str(d / "inv.png"),
        ],
        capsys,
    )
    assert code == 0, err
    with Image.open(d / "inv.png") as im:
        assert im.size[0] > 100
    code, _, err = run(
        [
            "map",
            str(d / "readings.csv"),
            "--rig",
            str(d / "rig.yaml"),
            "--method",
            "counting",
            "--resolution",
            "0.1",
            "--bounds",
            "-1",
            "-1",
            "4",
            "3",
            "-o",
            str(d / "cnt"),
        ],
        capsys,
    )
    assert code == 0, err
    assert read_map(d / "cnt.yaml").grid.shape == (40, 50)


def test_scenario_takes_a_rig_preset_by_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "h"
    code, _, err = run(
        ["scenario", "hall", "-o", str(out), "--param", "rig=hcsr04-six", "--param", "rate=2"],
        capsys,
    )
    assert code == 0, err
    assert "hc-sr04" in (out / "rig.yaml").read_text()


def test_scenario_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(
        [
            "scenario",
            "passages",
            "-o",
            str(tmp_path / "p"),
            "--seed",
            "2",
            "--param",
            "widths=0.3,0.5",
            "--p-rand",
            "0.05",
        ],
        capsys,
    )
    assert code == 0, err
    for name in (
        "truth.yaml",
        "truth.pgm",
        "geometry.yaml",
        "geometry.pgm",
        "rig.yaml",
        "trajectory.csv",
        "readings.csv",
        "annotations.yaml",
    ):
        assert (tmp_path / "p" / name).is_file()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (
            [
                "map",
                "{d}/readings.csv",
                "--rig",
                "{d}/rig.yaml",
                "--method",
                "magic",
                "--like",
                "{d}/plan.yaml",
                "-o",
                "{d}/x",
            ],
            "Invalid value for '--method'",
        ),
        (
            [
                "map",
                "{d}/readings.csv",
                "--rig",
                "{d}/rig.yaml",
                "--like",
                "{d}/plan.yaml",
                "--param",
                "p_occ=3",
                "-o",
                "{d}/x",
            ],
            r"parameter 'p_occ' must be in \(0.5, 1.0\)",
        ),
        (
            [
                "map",
                "{d}/readings.csv",
                "--rig",
                "{d}/rig.yaml",
                "--like",
                "{d}/plan.yaml",
                "--param",
                "p_occ",
                "-o",
                "{d}/x",
            ],
            "--param expects KEY=VALUE",
        ),
        (
            ["map", "{d}/readings.csv", "--rig", "{d}/rig.yaml", "-o", "{d}/x"],
            "give --like MAP.yaml or --resolution R",
        ),
        (
            [
                "map",
                "{d}/bad.csv",
                "--rig",
                "{d}/rig.yaml",
                "--like",
                "{d}/plan.yaml",
                "-o",
                "{d}/x",
            ],
            r"bad.csv:3, field 'range': range is negative",
        ),
        (
            [
                "map",
                "{d}/readings.csv",
                "--rig",
                "{d}/other_rig.yaml",
                "--like",
                "{d}/plan.yaml",
                "-o",
                "{d}/x",
            ],
            r"readings.csv:2, field 'sensor': unknown sensor 's0'",
        ),
        (
            [
                "simulate",
                "--map",
                "{d}/nope.yaml",
                "--rig",
                "{d}/rig.yaml",
                "--trajectory",
                "{d}/traj.csv",
                "-o",
                "{d}/x.csv",
            ],
            "nope.yaml: no such file, nor a built-in map",
        ),
        (
            [
                "simulate",
                "--map",
                "{d}/plan.yaml",
                "--rig",
                "{d}/rig.yaml",
                "--trajectory",
                "{d}/traj.csv",
                "--model",
                "thrun",
                "--p-hit",
                "0",
                "-o",
                "{d}/x.csv",
            ],
            r"p_hit must be in \(0, 1\]",
        ),
        (
            [
                "simulate",
                "--map",
                "{d}/plan.yaml",
                "--rig",
                "{d}/rig.yaml",
                "--trajectory",
                "{d}/traj.csv",
                "--p-hit",
                "0.5",
                "-o",
                "{d}/x.csv",
            ],
            r"p_hit belongs to Thrun's model \('thrun'\), not 'acoustic'",
        ),
        (
            [
                "simulate",
                "--map",
                "{d}/plan.yaml",
                "--rig",
                "{d}/rig.yaml",
                "--trajectory",
                "{d}/traj.csv",
                "--sonar-param",
                "specular_deg=0",
                "-o",
                "{d}/x.csv",
            ],
            r"acoustic model: specular_deg must be in \(0.0, 90.0\]",
        ),
        (
            ["scenario", "doorways", "-o", "{d}/x", "--param", "door_widths=wide"],
            "parameter 'door_widths' expects numbers",
        ),
        (
            ["scenario", "doorways", "-o", "{d}/x", "--param", "colour=3"],
            "unknown parameter 'colour' for scenario 'doorways'",
        ),
        (
            ["scenario", "hall", "-o", "{d}/x", "--param", "rig=ring17"],
            "scenario parameter 'rig' must be a rig preset",
        ),
        (
            ["map", "{d}", "--rig", "{d}/rig.yaml", "--resolution", "0.1", "-o", "{d}/m"],
            r"is a directory; expected a CSV file",
        ),
        (
            [
                "map",
                "{d}/readings.csv",
                "--rig",
                "{d}/rig.yaml",
                "--resolution",
                "0.1",
                "--bounds",
                "0,0,6",
                "-o",
                "{d}/m",
            ],
            r"--bounds takes 4 numbers \(comma- or space-separated\), got '0,0,6'",
        ),
        (
            [
                "stream",
                "{d}/readings.csv",
                "--rig",
                "{d}/rig.yaml",
                "--window",
                "last:0",
                "-o",
                "{d}/st",
            ],
            r"strategy 'last' needs a count >= 1, got 0",
        ),
        *[
            (
                [
                    "stream",
                    "{d}/readings.csv",
                    "--rig",
                    "{d}/rig.yaml",
                    "--method",
                    method,
                    "--param",
                    "specular_deg=30",
                    "-o",
                    "{d}/st",
                ],
                rf"streaming '{method}' cannot .*set specular_deg=0",
            )
            for method in ("inverse", "gradient")
        ],
        *[
            (
                [
                    "stream",
                    "{d}/readings.csv",
                    "--rig",
                    "{d}/rig.yaml",
                    "--method",
                    "gradient",
                    "--param",
                    f"{option}=0.1",
                    "-o",
                    "{d}/st",
                ],
                rf"streaming 'gradient' does not implement {option} .*set {option}=0",
            )
            for option in ("sparsity", "polish")
        ],
    ],
)
def test_errors_are_one_line_exit_2_no_output(
    floor_plan: Path, capsys: pytest.CaptureFixture[str], args: list[str], match: str
) -> None:
    d = floor_plan
    run(
        [
            "simulate",
            "--map",
            str(d / "plan.yaml"),
            "--rig",
            str(d / "rig.yaml"),
            "--trajectory",
            str(d / "traj.csv"),
            "-o",
            str(d / "readings.csv"),
        ],
        capsys,
    )
    lines = (d / "readings.csv").read_text().splitlines()
    fields = lines[2].split(",")
    fields[-1] = "-0.5"
    lines[2] = ",".join(fields)
    (d / "bad.csv").write_text("\n".join(lines) + "\n")
    (d / "other_rig.yaml").write_text(
        "sensor: hc-sr04\nsonars: [{name: z, x: 0, y: 0, yaw_deg: 0}]\n"
    )
    before = set(d.iterdir())
    code, _out, err = run([a.format(d=d) for a in args], capsys)
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert re.search(match, err), err
    assert set(d.iterdir()) == before  # nothing written, not even a temporary file


def test_help_and_version(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(["--version"], capsys)
    assert code == 0
    assert "sonarmap" in out
    for args in ([], ["-h"], ["map", "-h"]):
        code, out, err = run(args, capsys)
        assert (code, err) == (0, "")
        assert "Usage: sonarmap" in out
    for cmd in ("scenario", "simulate", "map", "show", "demo", "methods"):
        code, out, _ = run([cmd, "--help"], capsys)
        assert code == 0
        assert "Usage" in out


def test_map_tells_what_it_left_out(floor_plan: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Readings out of time order are put in place, a reading far off the grid is named,
    and bounds may be given with commas."""
    d = floor_plan
    args = ["simulate", "--map", f"{d}/plan.yaml", "--rig", f"{d}/rig.yaml"]
    run([*args, "--trajectory", f"{d}/traj.csv", "-o", f"{d}/r.csv"], capsys)
    lines = (d / "r.csv").read_text().splitlines()
    lines[10], lines[20] = lines[20], lines[10]
    lines.append(lines[-1].split(",")[0] + ",s0,1e9,0,0,1.0")
    (d / "r.csv").write_text("\n".join(lines) + "\n")
    code, out, err = run(
        [
            "map",
            f"{d}/r.csv",
            "--rig",
            f"{d}/rig.yaml",
            "--resolution",
            "0.1",
            "--bounds",
            "-1,-1,4,3",
            "-o",
            f"{d}/m",
        ],
        capsys,
    )
    assert code == 0, err
    # Line 11 now holds a reading 0.1 s ahead: the ones after it until then are late.
    assert re.search(
        r"put \d+ readings back in time order \(at most 0.1 s late; the first at "
        r"line 12\)",
        out,
    ), out
    assert "1 of " in out
    assert "outside the grid and add nothing to the map" in out
    m = read_map(d / "m.yaml")
    assert m.grid.shape == (40, 50)


def test_a_word_for_a_number_or_word_parameter(
    floor_plan: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``free_stop`` takes a number or ``beam``: the word reaches the mapper, which
    names a word it does not know."""
    d = floor_plan
    args = ["simulate", "--map", f"{d}/plan.yaml", "--rig", f"{d}/rig.yaml"]
    run([*args, "--trajectory", f"{d}/traj.csv", "-o", f"{d}/r.csv"], capsys)
    base = ["map", f"{d}/r.csv", "--rig", f"{d}/rig.yaml", "--method", "inverse"]
    base += ["--resolution", "0.1", "--bounds", "-1,-1,4,3"]
    code, _out, err = run([*base, "--param", "free_stop=beam", "-o", f"{d}/m"], capsys)
    assert code == 0, err
    code, _out, err = run([*base, "-o", f"{d}/n"], capsys)
    assert code == 0, err
    # The option took: the free regions stopped short change the map.
    assert not np.array_equal(read_map(d / "m.yaml").occupancy, read_map(d / "n.yaml").occupancy)
    code, _out, err = run([*base, "--param", "free_stop=wide", "-o", f"{d}/w"], capsys)
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "'free_stop' must be one of beam; got 'wide'" in err, err
    assert not (d / "w.yaml").exists()


def test_ctrl_c_is_exit_130_and_leaves_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import sonarmap.cli.mapping as mapping

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(mapping, "make_scenario", interrupted)
    code, _out, err = run(["scenario", "doorways", "-o", str(tmp_path / "sc")], capsys)
    assert code == 130
    assert err.strip() == "sonarmap: interrupted"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "args",
    [
        ["map", "{d}/readings.csv", "--rig", "{d}/rig.yaml", "--resolution", "0.1", "-o", "{o}"],
        ["show", "{d}/plan.yaml", "-o", "{o}.png"],
        ["scenario", "doorways", "-o", "{o}"],
        [
            "simulate",
            "--map",
            "{d}/plan.yaml",
            "--rig",
            "{d}/rig.yaml",
            "--trajectory",
            "{d}/traj.csv",
            "-o",
            "{o}.csv",
        ],
        ["stream", "{d}/readings.csv", "--rig", "{d}/rig.yaml", "--method", "inverse", "-o", "{o}"],
        ["demo", "-o", "{o}"],
    ],
)
def test_an_unwritable_output_is_one_line(
    floor_plan: Path, capsys: pytest.CaptureFixture[str], args: list[str]
) -> None:
    """An output under a plain file cannot be created, whoever runs the test (even root)."""
    d = floor_plan
    run(
        [
            "simulate",
            "--map",
            f"{d}/plan.yaml",
            "--rig",
            f"{d}/rig.yaml",
            "--trajectory",
            f"{d}/traj.csv",
            "-o",
            f"{d}/readings.csv",
        ],
        capsys,
    )
    (d / "blocker").write_text("a file, not a folder\n")
    before = set(d.rglob("*"))
    code, _out, err = run([a.format(d=d, o=d / "blocker" / "out") for a in args], capsys)
    assert code == 2, err
    assert err.strip().splitlines() == [
        f"sonarmap: error: {d / 'blocker' / 'out'}{'.png' if args[0] == 'show' else ''}"
        f"{'.csv' if args[0] == 'simulate' else ''}: cannot write: {d / 'blocker'} is a file, "
        "not a folder"
    ], err
    assert "Traceback" not in err
    assert set(d.rglob("*")) == before


def test_floor_plan_as_a_bare_image(floor_plan: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """simulate, map --like, compare and show take a bare image with --resolution."""
    d = floor_plan
    image = ["--resolution", "0.05", "--origin", "-1", "-1"]
    sim = ["simulate", "--rig", f"{d}/rig.yaml", "--trajectory", f"{d}/traj.csv"]
    code, _, err = run([*sim, "--map", f"{d}/plan.png", *image, "-o", f"{d}/r.csv"], capsys)
    assert code == 0, err
    run([*sim, "--map", f"{d}/plan.yaml", "-o", f"{d}/r2.csv"], capsys)
    assert (d / "r.csv").read_text() == (d / "r2.csv").read_text()  # the same plan
    mapping = ["map", f"{d}/r.csv", "--rig", f"{d}/rig.yaml", "--like", f"{d}/plan.png"]
    code, _, err = run([*mapping, *image, "-o", f"{d}/m"], capsys)
    assert code == 0, err
    assert read_map(d / "m.yaml").grid == read_map(d / "plan.yaml").grid
    code, _, err = run(
        ["compare", f"{d}/plan.png", f"{d}/m.yaml", *image, "--json", f"{d}/s.json"], capsys
    )
    assert code == 0, err
    assert json.loads((d / "s.json").read_text())[0]["f1_all"] > 0.3
    code, _, err = run(["show", f"{d}/plan.png", "-o", f"{d}/p.png"], capsys)
    assert code == 2
    assert "plan.png: a bare image needs --resolution" in err
