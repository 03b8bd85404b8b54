"""Inputs a new user brings: map_server maps, CSV logs, CARMEN logs and rigs written by
hand or by other tools. The odd but valid ones are read as their owners meant; the bad
ones stop with one line naming the place, exit code 2 and nothing written."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from sonarmap.cli import main
from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.io.carmen import read_carmen
from sonarmap.io.rosmap import MAX_PIXELS, OccupancyMap, read_map
from sonarmap.patrol.starts import read_starts
from sonarmap.patrol.territory import Territory
from sonarmap.readings import read_readings, read_trajectory
from sonarmap.rig import load_rig

HEADER = "t,sensor,x,y,theta,range"
ROWS = ["0.0,a,1.0,1.0,0.0,1.5", "0.1,b,1.1,1.0,1.57,2.0", "0.2,a,1.2,1.0,0.0,0.8"]


def refused(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``sonarmap ARGS`` in process; assert exit code 2 and one line; the line."""
    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("sonarmap: error: ")
    return lines[0]


# --- CSV readings ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text",
    [
        # Comment lines before the header and between readings, blank lines anywhere.
        "# logged by hand\n# rig: rig.yaml\n"
        + HEADER
        + "\n"
        + ROWS[0]
        + "\n# a note\n"
        + "\n".join(ROWS[1:])
        + "\n",
        HEADER + "\n" + "\n".join(ROWS) + "\n\n\n",
        HEADER + "\n" + ROWS[0] + "\n\n" + "\n".join(ROWS[1:]) + "\n",
        # Spaces after the commas, in the header too (a spreadsheet's export).
        ", ".join(HEADER.split(",")) + "\n" + "\n".join(", ".join(r.split(",")) for r in ROWS),
        # A byte-order mark and Windows line ends.
        "\ufeff" + "\r\n".join([HEADER, *ROWS]) + "\r\n",
        # Comments with commas, indented ones, lines of spaces or a tab (review).
        "# note, with, many, commas, here, and, more, fields\n"
        + HEADER
        + "\n"
        + ROWS[0]
        + "\n# a, b, c, d, e, f, g, h\n   \n\t\n   # note, a, b\n"
        + "\n".join(ROWS[1:])
        + "\n",
        # The same with CR line ends only.
        "# a, b, c, d, e, f, g\r"
        + HEADER
        + "\r"
        + ROWS[0]
        + "\r  # x, y\r \t\r"
        + "\r".join(ROWS[1:])
        + "\r",
    ],
    ids=["comments", "trailing-blank", "blank-between", "spaces", "bom-crlf", "commas", "cr"],
)
def test_odd_but_valid_readings_csvs_read_as_the_plain_one(tmp_path: Path, text: str) -> None:
    plain = tmp_path / "plain.csv"
    plain.write_text("\n".join([HEADER, *ROWS]) + "\n")
    odd = tmp_path / "odd.csv"
    odd.write_bytes(text.encode())
    a, b = read_readings(plain, names=["a", "b"]), read_readings(odd, names=["a", "b"])
    for field in ("t", "x", "y", "theta", "range", "sensor"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


def test_errors_after_comment_and_blank_lines_name_the_files_own_line(tmp_path: Path) -> None:
    p = tmp_path / "r.csv"
    p.write_text("# one\n\n" + HEADER + "\n" + ROWS[0] + "\n# two\n\n0.1,a,1,1,0,-3\n")
    with pytest.raises(InputError, match=r"r.csv:7, field 'range': range is negative"):
        read_readings(p, names=["a", "b"])
    p.write_text("# one\n" + HEADER + "\n\n" + ROWS[0] + "\n0.1,c,1,1,0,1\n")
    with pytest.raises(InputError, match=r"r.csv:5, field 'sensor': unknown sensor 'c'"):
        read_readings(p, names=["a", "b"])
    p.write_text(HEADER + "\n" + ROWS[0] + "\n# a, b, c, d, e, f, g\n  \n0.1,a,1,1\n")
    with pytest.raises(InputError, match=r"r.csv:5, field 'theta': missing value"):
        read_readings(p, names=["a", "b"])


@pytest.mark.parametrize("suffix", [".log", ".txt", ".gz", ".bz2", ".xz"])
def test_comments_before_the_header_are_skipped_whatever_the_suffix(
    tmp_path: Path, suffix: str
) -> None:
    """They were skipped only for .csv, .txt, .gz and no suffix (review)."""
    import bz2
    import gzip
    import lzma
    from collections.abc import Callable

    text = ("# a, b, c, d, e, f, g, h\n  # b\n" + HEADER + "\n" + "\n".join(ROWS) + "\n").encode()
    pack: dict[str, Callable[[bytes], bytes]] = {
        ".gz": gzip.compress,
        ".bz2": bz2.compress,
        ".xz": lzma.compress,
    }
    p = tmp_path / f"r{suffix}"
    p.write_bytes(pack.get(suffix, bytes)(text))
    assert len(read_readings(p, names=["a", "b"])) == 3


def test_a_trajectory_with_comments_and_blank_lines_reads(tmp_path: Path) -> None:
    p = tmp_path / "traj.csv"
    p.write_text("# from the odometry\nt,x,y,theta\n0,1,2,0\n\n# stop\n1,1.5,2,0\n\n")
    traj = read_trajectory(p)
    assert traj.t.tolist() == [0.0, 1.0]
    assert traj.x.tolist() == [1.0, 1.5]


def test_a_pose_far_out_is_one_line_not_an_overflow(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A pose of 1e308 m made the grid's width infinite: OverflowError, exit 1."""
    csv = tmp_path / "r.csv"
    csv.write_text("\n".join([HEADER, ROWS[0], "0.1,a,1e308,1.0,0.0,1.5"]) + "\n")
    rig = tmp_path / "rig.yaml"
    rig.write_text(
        "sensor: maxsonar-ez1\nsonars:\n  - {name: a, x: 0, y: 0, yaw_deg: 0}\n"
        "  - {name: b, x: 0, y: 0, yaw_deg: 90}\n"
    )
    line = refused(
        ["map", str(csv), "--rig", str(rig), "--resolution", "0.1", "-o", str(tmp_path / "m")],
        capsys,
    )
    assert "the readings reach x 1 to 1e+308" in line
    assert not list(tmp_path.glob("m.*"))


@pytest.mark.parametrize(
    "bounds", [(0.0, 0.0, math.inf, 1.0), (-1e308, 0.0, 1e308, 1.0), (0.0, 0.0, 1e12, 1.0)]
)
def test_grid_bounds_beyond_the_cell_limit_are_a_config_error(
    bounds: tuple[float, float, float, float],
) -> None:
    with pytest.raises(ConfigError, match="limit 2\\*\\*31 cells"):
        Grid.from_bounds(*bounds, 0.1)


# --- map_server maps ---------------------------------------------------------------------


def _image(tmp_path: Path) -> np.ndarray:
    px = np.full((20, 30), 254, dtype=np.uint8)
    px[:2, :] = px[-2:, :] = px[:, :2] = px[:, -2:] = 0
    px[5:8, 20:25] = 205
    Image.fromarray(px).save(tmp_path / "plan.pgm")
    return px


def test_numbers_in_exponent_form_are_numbers(tmp_path: Path) -> None:
    """YAML 1.1 reads ``5e-2`` and ``1.0e-1`` as strings; map_server reads numbers."""
    _image(tmp_path)
    p = tmp_path / "m.yaml"
    p.write_text("image: plan.pgm\nresolution: 5e-2\norigin: [-1.0e1, 2E0, 0]\n")
    m = read_map(p)
    assert m.grid.resolution == 0.05
    assert m.grid.origin == (-10.0, 2.0)


def test_a_rig_number_in_exponent_form_is_a_number(tmp_path: Path) -> None:
    p = tmp_path / "rig.yaml"
    p.write_text(
        "sensor:\n  beam: {cone: {aperture_deg: 3e1}}\n  r_min: 1.5e-1\n  r_max: 6.0e0\n"
        "  range_resolution: 2.54e-2\nsonars:\n  - {name: a, x: 1e-1, y: 0, yaw_deg: 0}\n"
    )
    rig = load_rig(p)
    assert rig.sensor.r_min == 0.15
    assert rig.mounts[0].x == 0.1


def test_yaml_1_1_strings_that_look_like_numbers_stay_strings_where_a_string_is_wanted(
    tmp_path: Path,
) -> None:
    """The previous release wrote a sonar named 1e5 unquoted (yaml.safe_dump); a
    YAML 1.2 loader read it back as the number 100000.0 and refused the rig."""
    from sonarmap.files import read_yaml

    p = tmp_path / "rig.yaml"
    p.write_text("sensor: maxsonar-ez1\nsonars:\n  - {name: 1e5, x: 2e-1, y: 0, yaw_deg: 0}\n")
    rig = load_rig(p)
    assert rig.names == ("1e5",)
    assert rig.mounts[0].x == 0.2
    (tmp_path / "t.yaml").write_text("image: 1e3\nroute: 2e5\nn: 1_000e2\nm: +1e5\n")
    assert read_yaml(tmp_path / "t.yaml") == {
        "image": "1e3",
        "route": "2e5",
        "n": "1_000e2",
        "m": "+1e5",
    }


def test_a_quoted_number_where_a_number_is_wanted_reads_as_map_server_reads_it(
    tmp_path: Path,
) -> None:
    _image(tmp_path)
    p = tmp_path / "m.yaml"
    p.write_text('image: plan.pgm\nresolution: "0.1"\norigin: ["-1e1", 0, 0]\n')
    m = read_map(p)
    assert m.grid.resolution == 0.1
    assert m.grid.origin == (-10.0, 0.0)
    for bad in ('"0x10"', '"1_0"', '"ten"', "yes", '"1:30"'):
        p.write_text(f"image: plan.pgm\nresolution: {bad}\norigin: [0, 0, 0]\n")
        with pytest.raises(InputError, match="field 'resolution': expected a number"):
            read_map(p)


def test_a_maps_extent_is_checked_from_the_image_header_before_decoding(tmp_path: Path) -> None:
    """The extent was checked after the pixels were decoded: a damaged or huge image
    was read (or failed) first."""
    (tmp_path / "cut.pgm").write_bytes(b"P5\n100 100\n255\n" + bytes(10))  # pixels cut short
    p = tmp_path / "m.yaml"
    p.write_text("image: cut.pgm\nresolution: 1e6\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match=r"field 'resolution': .* 1e\+08 m across"):
        read_map(p)


def test_raw_mode_rounds_a_16_bit_pixel_as_nav2_does(tmp_path: Path) -> None:
    from sonarmap.checks import MAX_MAP_CELLS

    assert MAX_PIXELS == MAX_MAP_CELLS
    px = np.full((4, 4), 50 * 257 + 200, dtype=np.uint16)  # 50.78 on the 8-bit scale
    Image.fromarray(px).save(tmp_path / "raw.png")
    p = tmp_path / "m.yaml"
    p.write_text("image: raw.png\nresolution: 0.1\norigin: [0, 0, 0]\nmode: raw\n")
    assert np.allclose(read_map(p, use_npy=False).occupancy, 0.51)


def test_a_map_whose_resolution_makes_it_astronomical_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """resolution 1e300 overflowed in team run's world making (OverflowError, exit 1)."""
    _image(tmp_path)
    p = tmp_path / "m.yaml"
    p.write_text("image: plan.pgm\nresolution: 1e300\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match=r"field 'resolution': .* 3e\+301 m across"):
        read_map(p)
    p.write_text("image: plan.pgm\nresolution: 0.1\norigin: [1e9, 0, 0]\n")
    with pytest.raises(InputError, match=r"field 'origin': origin \(1e\+09, 0\)"):
        read_map(p)
    out = tmp_path / "team"
    line = refused(["team", "run", "--map", str(p), "--duration", "5", "-o", str(out)], capsys)
    assert "field 'origin'" in line
    assert not out.exists()


def test_a_huge_declared_image_is_refused_from_its_header(tmp_path: Path) -> None:
    """A 10 001 x 10 000 header with no pixels: refused before any decoding."""
    (tmp_path / "big.pgm").write_bytes(b"P5\n10001 10000\n255\n")
    p = tmp_path / "m.yaml"
    p.write_text("image: big.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    assert MAX_PIXELS < 10001 * 10000
    with pytest.raises(InputError, match=r"big.pgm: image of 10001 x 10000 pixels; at most"):
        read_map(p)


def test_an_unsupported_image_mode_is_said_once(tmp_path: Path) -> None:
    """The mode's message was wrapped in 'cannot read image (InputError: ...)', the path
    twice."""
    px = _image(tmp_path).astype(np.float32)
    Image.fromarray(px).save(tmp_path / "float.tif")
    p = tmp_path / "m.yaml"
    p.write_text("image: float.tif\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError) as e:
        read_map(p)
    assert str(e.value).count("float.tif") == 1
    assert "unsupported image mode" in str(e.value)
    assert "cannot read image" not in str(e.value)


def test_an_image_path_that_is_a_folder_says_so(tmp_path: Path) -> None:
    (tmp_path / "plan dir").mkdir()
    p = tmp_path / "m.yaml"
    p.write_text("image: plan dir\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match="plan dir: map image is a folder"):
        read_map(p)


def test_a_rotated_map_is_refused_naming_its_yaw(tmp_path: Path) -> None:
    _image(tmp_path)
    p = tmp_path / "m.yaml"
    p.write_text("image: plan.pgm\nresolution: 0.1\norigin: [0, 0, 0.3]\n")
    with pytest.raises(InputError, match=r"field 'origin': rotated maps \(origin yaw 0.3 rad"):
        read_map(p)


@pytest.mark.parametrize(
    "variant", ["ascii", "alpha", "negate", "spaces", "absolute", "png16", "pgm16", "pgm1000"]
)
def test_map_server_variants_read_as_the_plain_map(tmp_path: Path, variant: str) -> None:
    px = _image(tmp_path)
    (tmp_path / "plain.yaml").write_text("image: plan.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    image = "plan.pgm"
    negate = 0
    if variant == "ascii":
        body = "\n".join(" ".join(str(v) for v in row) for row in px)
        (tmp_path / "a.pgm").write_text(
            f"P2\n# by hand\n{px.shape[1]} {px.shape[0]}\n255\n{body}\n"
        )
        image = "a.pgm"
    elif variant == "alpha":
        rgba = np.dstack([px, px, px, np.full_like(px, 255)])
        Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
        image = "a.png"
    elif variant == "negate":
        Image.fromarray(255 - px).save(tmp_path / "a.pgm")
        image, negate = "a.pgm", 1
    elif variant == "spaces":
        (tmp_path / "my maps").mkdir()
        Image.fromarray(px).save(tmp_path / "my maps" / "floor 2.pgm")
        image = "my maps/floor 2.pgm"
    elif variant == "png16":
        # Refused before, read by Nav2's map_server: 16-bit grey on its own scale.
        Image.fromarray(px.astype(np.uint16) * 257).save(tmp_path / "a.png")
        image = "a.png"
    elif variant.startswith("pgm"):
        top = 65535 if variant == "pgm16" else 1000
        deep = np.rint(px.astype(np.float64) * top / 255).astype(">u2")
        head = f"P5\n{px.shape[1]} {px.shape[0]}\n{top}\n".encode()
        (tmp_path / "a.pgm").write_bytes(head + deep.tobytes())
        image = "a.pgm"
    else:
        image = str(tmp_path / "plan.pgm")
    (tmp_path / "odd.yaml").write_text(
        f"image: {image}\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: {negate}\n"
        "mode: trinary\nmap_name: floor\n"
    )
    a, b = read_map(tmp_path / "plain.yaml"), read_map(tmp_path / "odd.yaml")
    np.testing.assert_array_equal(a.classes(), b.classes())


# --- CARMEN ------------------------------------------------------------------------------


def _sonar(cone: float, t: float) -> str:
    return f"SONAR {cone} 2 1.0 2.0 0.1 0.1 0.5 0.1 -0.1 -0.5 1.0 0.5 0.0 0 0 {t} h {t}"


@pytest.mark.parametrize("cone", [0.0, -0.26, 7.0])
def test_a_sonar_cone_angle_out_of_range_is_refused_not_clamped(
    tmp_path: Path, cone: float
) -> None:
    """The cone became 0.05 or 179 degrees without a word."""
    p = tmp_path / "log.log"
    p.write_text(_sonar(cone, 1.0) + "\n")
    with pytest.raises(InputError, match=r"log.log:1: SONAR cone angle must be in \(0, pi\)"):
        read_carmen(p)


def test_a_sonar_cone_that_changes_is_refused(tmp_path: Path) -> None:
    """The rig kept the first message's cone and the second's was dropped silently."""
    p = tmp_path / "log.log"
    p.write_text(_sonar(0.26, 1.0) + "\n" + _sonar(0.5, 1.1) + "\n")
    with pytest.raises(InputError, match=r"log.log:2: SONAR cone angle 0.5 rad, the first"):
        read_carmen(p)
    p.write_text(_sonar(0.26, 1.0) + "\n" + _sonar(0.26, 1.1) + "\n")
    readings, _ = read_carmen(p)
    assert len(readings) == 4


def test_a_laser_whose_angular_step_is_rounded_differently_is_read(tmp_path: Path) -> None:
    """The cone check, meant for SONAR messages, refused a ROBOTLASER1 log whose
    resolution field was written 0.7854 in one message and 0.785398 in the next (a
    laser's "cone" is its angular step, not a beam's opening)."""

    def robotlaser(res: str, t: float) -> str:
        return (
            f"ROBOTLASER1 0 -1.5708 3.1416 {res} 50.0 0.01 0 5 1 2 3 2 1 "
            f"1.1 2.0 0.5 1.0 2.0 0.5 0.0 0.0 0.5 0.5 0.0 {t} host {t}"
        )

    p = tmp_path / "log.log"
    p.write_text(robotlaser("0.7854", 1.0) + "\n" + robotlaser("0.785398", 2.0) + "\n")
    readings, _ = read_carmen(p)
    assert len(readings) == 10


# --- rigs --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("sonar", "match"),
    [
        ("{name: '', x: 0, y: 0, yaw_deg: 0}", r"sonars\[0\].name: '' is empty"),
        ("{name: ' left', x: 0, y: 0, yaw_deg: 0}", r"sonars\[0\].name: ' left'"),
        ("{name: null, x: 0, y: 0, yaw_deg: 0}", r"sonars\[0\].name: expected a name"),
        ("{name: a, x: 0, y: 0, yaw_deg: 999}", r"sonars\[0\].yaw_deg: must be within"),
        ("{name: a, x: 0, y: 0, yaw_deg: -400}", r"sonars\[0\].yaw_deg: must be within"),
    ],
)
def test_bad_sonar_names_and_angles_are_refused(tmp_path: Path, sonar: str, match: str) -> None:
    p = tmp_path / "rig.yaml"
    p.write_text(f"sensor: maxsonar-ez1\nsonars:\n  - {sonar}\n")
    with pytest.raises(InputError, match=match):
        load_rig(p)


def test_a_numeric_sonar_name_and_a_full_turn_are_kept(tmp_path: Path) -> None:
    p = tmp_path / "rig.yaml"
    p.write_text("sensor: maxsonar-ez1\nsonars:\n  - {name: 7, x: 0, y: 0, yaw_deg: -360}\n")
    rig = load_rig(p)
    assert rig.names == ("7",)
    assert rig.mounts[0].yaw_deg == -360.0


# --- patrol start files ------------------------------------------------------------------


def test_a_start_file_listing_more_robots_than_its_count_is_refused(tmp_path: Path) -> None:
    """'1' then two starts ran one robot and dropped the other without a word."""
    g = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(300, 400))
    territory = Territory.from_map(OccupancyMap(g, np.zeros(g.shape, np.float32)))
    p = tmp_path / "s.txt"
    p.write_text("1\n100 50 0\n# the second robot\n200 250 1.57\n")
    with pytest.raises(InputError, match=r"s.txt:4: the file says 1 robots but lists 2"):
        read_starts(p, territory)
    p.write_text("# two robots\n2\n100 50 0\n\n200 250 1.57\n")
    assert read_starts(p, territory).shape == (2, 3)


def test_an_empty_semaphore_file_is_named_not_called_missing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It was 'crowding semaphores needs a semaphore file (--semaphores)', given one."""
    plan = tmp_path / "plan.yaml"
    px = np.full((300, 400), 254, dtype=np.uint8)
    px[:3, :] = px[-3:, :] = px[:, :3] = px[:, -3:] = 0
    Image.fromarray(px).save(tmp_path / "plan.pgm")
    plan.write_text("image: plan.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    sem = tmp_path / "sem.txt"
    sem.write_text("# none yet\n\n")
    out = tmp_path / "run"
    args = ["patrol", "run", "--map", str(plan), "--robots", "2", "--duration", "1"]
    args += ["--crowding", "semaphores", "--semaphores", str(sem), "-o", str(out)]
    line = refused(args, capsys)
    assert line.endswith("sem.txt: the semaphore file holds no polygon")
    assert not out.exists()


# --- peers -------------------------------------------------------------------------------


def test_a_nest_too_deep_is_named_in_the_rejection() -> None:
    """msgpack's StackError has no text: the log line read 'not msgpack: ' and nothing."""
    from sonarmap.team.records import UnpackError, unpack_strict

    with pytest.raises(UnpackError, match="not msgpack: StackError"):
        unpack_strict(b"\x91" * 100_000 + b"\xc0", max_bin=9, max_str=9, max_array=9, max_map=9)


def test_a_sonar_named_like_a_number_survives_a_round_trip(tmp_path: Path) -> None:
    """With numbers in exponent form read as numbers, a name "2e1" written bare would
    come back the number 20.0; the writer quotes it."""
    from sonarmap.rig import save_rig

    p = tmp_path / "rig.yaml"
    p.write_text("sensor: maxsonar-ez1\nsonars:\n  - {name: '2e1', x: 0, y: 0, yaw_deg: 0}\n")
    save_rig(load_rig(p), tmp_path / "again.yaml")
    assert load_rig(tmp_path / "again.yaml").names == ("2e1",)


def test_a_choice_cell_wider_than_the_map_is_one_block_not_a_memory_error() -> None:
    """--choice-cell 1e9 padded the map to 2e9 x 2e9 cells: ArrayMemoryError, exit 1."""
    from sonarmap.patrol.coarse import any_in_blocks

    mask = np.zeros((3, 4), dtype=bool)
    mask[2, 1] = True
    assert any_in_blocks(mask, 2 * 10**9).tolist() == [[True]]
    assert any_in_blocks(mask, 4).tolist() == [[True]]
    assert any_in_blocks(~np.ones((3, 4), dtype=bool), 10**9).tolist() == [[False]]


def _room(tmp_path: Path) -> Path:
    """A 30 m x 30 m walled room at 0.5 m: room.yaml."""
    px = np.full((60, 60), 254, dtype=np.uint8)
    px[:2, :] = px[-2:, :] = px[:, :2] = px[:, -2:] = 0
    Image.fromarray(px).save(tmp_path / "room.pgm")
    (tmp_path / "room.yaml").write_text("image: room.pgm\nresolution: 0.5\norigin: [0, 0, 0]\n")
    return tmp_path / "room.yaml"


@pytest.mark.parametrize(
    "option",
    [
        ["--refine", "--refine-window", "1e9"],
        ["--refine", "--refine-side", "1e9"],
        ["--weaken", "--weaken-r0", "1e9"],
        ["--crowding", "obstacles", "--r-obst", "1e9"],
        ["--choice-cell", "1e9"],
    ],
)
def test_a_patrol_distance_past_the_map_is_refused_before_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: list[str]
) -> None:
    """Each allocated arrays of 1e9 m in cells (ArrayMemoryError, ValueError: exit 1) or,
    --refine-side, searched for minutes."""
    out = tmp_path / "run"
    args = ["patrol", "run", "--map", str(_room(tmp_path)), "--robots", "2"]
    line = refused([*args, "--duration", "1", *option, "-o", str(out)], capsys)
    name = option[-2][2:].replace("-", "_")
    assert f"{option[-2]} / {name} 1e+09 m: at most the map's diagonal, 42.4 m" in line
    assert not out.exists()


def test_a_patrol_distance_past_the_map_is_refused_by_the_library_for_every_caller(
    tmp_path: Path,
) -> None:
    """Experiment files build PatrolConfig directly: r_obst 1e9 there ran out of memory,
    the check being only in the command line."""
    from sonarmap.io.rosmap import read_map
    from sonarmap.patrol.simulation import PatrolConfig, run_patrol

    territory = Territory.from_map(read_map(_room(tmp_path)), cell=0.5)
    for name in ("r_obst", "choice_cell", "refine_window"):
        far: dict[str, Any] = {name: 1e9}
        config = PatrolConfig(duration=1.0, **far)
        with pytest.raises(ConfigError, match=f"{name} 1e\\+09 m: at most") as err:
            run_patrol(territory, config, robots=1, seed=0)
        assert err.value.field == name


def test_a_low_bandwidth_runs_and_max_message_is_checked_first() -> None:
    """A floor on the bandwidth (10^6 periods for the largest message) refused
    plausible links (210 B/s at period 0.1 s, factor 0.05), and was computed before
    max_message was checked (a TypeError for max_message="x")."""
    from sonarmap.team.network import NetworkParams, SimNetwork

    with pytest.raises(ConfigError, match="'max_message' must be an int"):
        NetworkParams(bandwidth=1.0, max_message="x")  # type: ignore[arg-type]
    p = NetworkParams(bandwidth=210.0, bandwidth_period=0.1, bandwidth_min_factor=0.05)
    assert p.bandwidth == 210.0
    # --bandwidth 1e-9 (a slip for 1e9): a constant rate is paid in closed form, so a
    # message due in 10^15 s costs nothing to schedule; it does not arrive in the mission.
    net = SimNetwork(NetworkParams(bandwidth=1e-9), 2)
    assert net.send(0.0, 0, 1, b"x" * 1_000_000)
    assert net.deliver(1e6) == []


def test_simulating_from_outside_the_plan_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A pose 5 m left of a 30 m room gave readings of its outer wall, written as data."""
    traj = tmp_path / "traj.csv"
    traj.write_text("# a route\nt,x,y,theta\n0,5,5,0\n0.1,-5,5,0\n")
    out = tmp_path / "r.csv"
    args = ["simulate", "--map", str(_room(tmp_path)), "--rig", "paper-real"]
    line = refused([*args, "--trajectory", str(traj), "--model", "thrun", "-o", str(out)], capsys)
    assert line.endswith(
        "traj.csv: pose 2 (t = 0.1 s) at (-5, 5) m is outside the plan, x 0..30 m, y 0..30 m"
    )
    assert not out.exists()
    traj.write_text("t,x,y,theta\n0,5,5,0\n0.1,6,5,0\n")
    main([*args, "--trajectory", str(traj), "--model", "thrun", "-o", str(out)])
    assert out.exists()


def test_a_team_route_outside_the_plan_is_refused_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A route 40 m left of the plan ended 'built map has no occupied cell: nothing to
    align', one at x = 1e308 'bounds must satisfy xmin < xmax': neither named the route."""
    route = tmp_path / "route.csv"
    out = tmp_path / "team"
    args = ["team", "run", "--map", str(_room(tmp_path)), "--duration", "5", "-o", str(out)]
    for x, shown in (("-40", "-40"), ("1e308", "1e+308")):
        route.write_text(f"t,x,y,theta\n0,5,5,0\n10,{x},5,0\n")
        line = refused([*args, "--route", str(route)], capsys)
        where = f"route.csv: pose 2 (t = 10 s) at ({shown}, 5) m is outside the plan"
        assert line.endswith(f"{where}, x 0..30 m, y 0..30 m")
        assert not out.exists()
