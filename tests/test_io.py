"""ROS map_server maps: round trip, conventions, a hand-made map, bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sonarmap.errors import InputError, OutputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import FREE, OCCUPIED, UNKNOWN, OccupancyMap, read_map, write_map


def test_round_trip(tmp_path: Path) -> None:
    grid = Grid(0.05, (-1.5, 2.25), (4, 5))
    occ = np.array(
        [[0, 1, np.nan, 0.5, 0.9], [0.1, 0.2, 0.3, 0.66, 1], [0, 0, 0, 0, 0], [1, 1, 1, 1, 1]],
        dtype=np.float32,
    )
    yaml_p, pgm_p, npy_p = write_map(OccupancyMap(grid, occ), tmp_path / "m")
    # With the .npy beside it, the exact occupancy comes back.
    exact = read_map(yaml_p)
    np.testing.assert_array_equal(exact.occupancy, occ)
    back = read_map(yaml_p, use_npy=False)
    assert back.grid == grid
    np.testing.assert_array_equal(np.load(npy_p), occ)
    px = np.asarray(Image.open(pgm_p))
    assert px.dtype == np.uint8
    assert px.shape == (4, 5)
    assert px[0, 0] == 254
    assert px[0, 1] == 0
    assert px[0, 2] == 205
    assert px[0, 3] == 205
    # From the image alone, with map_server's rules, the map's classes come back.
    assert back.classes().tolist() == OccupancyMap(grid, occ).classes().tolist()
    assert back.classes()[1].tolist() == [0, 0, 0, 1, 1]


def test_hand_made_map_with_known_origin(tmp_path: Path) -> None:
    # 3 rows x 4 columns; a single obstacle pixel at image row 0 (top), column 3.
    px = np.full((3, 4), 254, dtype=np.uint8)
    px[0, 3] = 0
    px[2, 0] = 205
    Image.fromarray(px).save(tmp_path / "hand.png")
    (tmp_path / "hand.yaml").write_text(
        "image: hand.png\nresolution: 0.5\norigin: [10.0, -2.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    m = read_map(tmp_path / "hand.yaml")
    assert m.grid.shape == (3, 4)
    # Lower-left pixel (row 2, col 0) has its lower-left corner at the origin.
    cx, cy = m.grid.cell_centres(2, 0)
    assert (float(cx), float(cy)) == (10.25, -1.75)
    # The obstacle (top row, last column) is the cell containing world (11.9, -0.6).
    r, c = m.grid.world_to_cell(11.9, -0.6)
    assert (int(r), int(c)) == (0, 3)
    assert m.occupancy[0, 3] == 1.0
    assert np.isnan(m.occupancy[2, 0])
    assert m.occupancy[1, 1] == 0.0


def test_negate_scale_raw_and_colour(tmp_path: Path) -> None:
    px = np.array([[0, 100, 255]], dtype=np.uint8)
    Image.fromarray(px).save(tmp_path / "p.pgm")
    base = "image: p.pgm\nresolution: 1.0\norigin: [0, 0, 0]\n"
    (tmp_path / "neg.yaml").write_text(base + "negate: 1\n")
    np.testing.assert_array_equal(
        read_map(tmp_path / "neg.yaml").occupancy, np.array([[0.0, np.nan, 1.0]], dtype=np.float32)
    )
    (tmp_path / "scale.yaml").write_text(base + "mode: scale\n")
    p = (255 - 100) / 255
    np.testing.assert_allclose(
        read_map(tmp_path / "scale.yaml").occupancy,
        [[1.0, (p - 0.196) / (0.65 - 0.196), 0.0]],
        rtol=1e-6,
    )
    (tmp_path / "raw.yaml").write_text(base + "mode: raw\n")
    np.testing.assert_array_equal(
        read_map(tmp_path / "raw.yaml").occupancy, np.array([[0.0, 1.0, np.nan]], dtype=np.float32)
    )
    rgb = np.zeros((1, 2, 3), dtype=np.uint8)
    rgb[0, 1] = 255
    Image.fromarray(rgb).save(tmp_path / "c.png")
    (tmp_path / "c.yaml").write_text("image: c.png\nresolution: 1.0\norigin: [0, 0, 0]\n")
    np.testing.assert_array_equal(read_map(tmp_path / "c.yaml").occupancy, [[1.0, 0.0]])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("image: m.pgm\nresolution: [\n", r"not valid YAML \(.* at line 3\)"),
        ("image: m.pgm\norigin: [0, 0, 0]\n", "field 'resolution': missing key"),
        ("image: m.pgm\nresolution: -1\norigin: [0, 0, 0]\n", "field 'resolution': must be > 0"),
        ("image: m.pgm\nresolution: 0.1\norigin: [0]\n", "field 'origin': expected"),
        ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0.5]\n", "rotated maps"),
        ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nmode: fancy\n", "unknown mode"),
        ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nfree_thresh: 0.9\n", "thresholds"),
        ("image: gone.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n", "map image not found"),
        ("- just\n- a list\n", "expected a YAML mapping"),
    ],
)
def test_bad_map_files(tmp_path: Path, text: str, match: str) -> None:
    Image.fromarray(np.zeros((2, 2), dtype=np.uint8)).save(tmp_path / "m.pgm")
    (tmp_path / "bad.yaml").write_text(text)
    with pytest.raises(InputError, match=match):
        read_map(tmp_path / "bad.yaml")


def test_wrong_image_mode_and_garbage(tmp_path: Path) -> None:
    Image.fromarray(np.zeros((2, 2), dtype=np.float32)).save(tmp_path / "w.tif")
    (tmp_path / "w.yaml").write_text("image: w.tif\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match="unsupported image mode 'F'"):
        read_map(tmp_path / "w.yaml")
    (tmp_path / "g.pgm").write_bytes(b"P5 garbage")
    (tmp_path / "g.yaml").write_text("image: g.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match="cannot read image"):
        read_map(tmp_path / "g.yaml")


def test_failed_write_leaves_nothing(tmp_path: Path) -> None:
    grid = Grid(1.0, (0, 0), (1, 2))
    (tmp_path / "x.pgm").mkdir()  # the image's place is taken: the write fails
    with pytest.raises(OutputError, match=r"x.pgm: is a directory"):
        write_map(OccupancyMap(grid, np.zeros((1, 2), np.float32)), tmp_path / "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.pgm"]
    assert list((tmp_path / "x.pgm").iterdir()) == []
    with pytest.raises(InputError, match="occupancy values must lie in"):
        OccupancyMap(grid, np.array([[0.0, 2.0]], np.float32))


def test_bare_image_maps(tmp_path: Path) -> None:
    """A floor plan given as a bare image, as the research's simulator took them: dark
    occupied, light free, mid-grey unknown, at the resolution and origin given."""
    px = np.full((30, 40), 254, dtype=np.uint8)
    px[0, :] = 0
    px[5:8, 10:12] = 205
    Image.fromarray(px).save(tmp_path / "plan.png")
    m = read_map(tmp_path / "plan.png", resolution=0.1, origin=(-1.0, 2.0))
    assert m.grid.shape == (30, 40)
    assert m.grid.resolution == 0.1
    assert m.grid.origin == (-1.0, 2.0)
    cls = m.classes()
    assert (cls[0] == OCCUPIED).all()
    assert (cls[5:8, 10:12] == UNKNOWN).all()
    assert (cls[10:, :] == FREE).all()
    with pytest.raises(InputError, match=r"plan.png: a bare image needs --resolution"):
        read_map(tmp_path / "plan.png")
    with pytest.raises(InputError, match="resolution must be > 0"):
        read_map(tmp_path / "plan.png", resolution=0.0)
    write_map(m, tmp_path / "plan")
    with pytest.raises(InputError, match="a resolution is given only with a bare image"):
        read_map(tmp_path / "plan.yaml", resolution=0.1)


def test_a_failed_atomic_folder_leaves_no_folder_it_made(tmp_path: Path) -> None:
    from sonarmap.files import atomic_folder

    kept = tmp_path / "kept"
    kept.mkdir()

    def fail(out: Path) -> None:
        with atomic_folder(out) as tmp:
            (tmp / "half.txt").write_text("half")
            raise RuntimeError("the job failed")

    for out in (tmp_path / "new" / "deeper" / "run", kept / "run"):
        with pytest.raises(RuntimeError):
            fail(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"]
    assert list(kept.iterdir()) == []
    with atomic_folder(tmp_path / "new" / "run") as tmp:
        (tmp / "whole.txt").write_text("whole")
    assert (tmp_path / "new" / "run" / "whole.txt").read_text() == "whole"
    assert [p.name for p in (tmp_path / "new").iterdir()] == ["run"]
