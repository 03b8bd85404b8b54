"""Readings and trajectory CSV: round trip, chunks, every kind of bad line."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from sonarmap.errors import InputError
from sonarmap.readings import (
    Readings,
    TimeOrder,
    in_time_order,
    iter_readings,
    read_readings,
    read_trajectory,
    write_readings,
)

GOOD = (
    "t,sensor,x,y,theta,range\n"
    "0.0,a,0.0,0.0,0.0,1.5\n"
    "0.1,b,0.1,0.0,1.57,2.0\n"
    "0.2,a,0.2,0.0,0.0,inf\n"
)


def write(tmp_path: Path, text: str, name: str = "r.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_read_and_round_trip(tmp_path: Path) -> None:
    r = read_readings(write(tmp_path, GOOD), names=["a", "b"])
    assert len(r) == 3
    assert r.names == ("a", "b")
    assert r.sensor.tolist() == [0, 1, 0]
    assert np.isinf(r.range[2])
    write_readings(r, tmp_path / "out.csv.gz")
    back = read_readings(tmp_path / "out.csv.gz", names=["a", "b"])
    np.testing.assert_allclose(back.range[:2], r.range[:2])
    assert back.sensor.tolist() == r.sensor.tolist()


def test_chunks_give_the_same_result(tmp_path: Path) -> None:
    rows = ["t,sensor,x,y,theta,range"] + [
        f"{i * 0.1},s{i % 3},{i},0,0,{1 + i % 5}" for i in range(50)
    ]
    p = write(tmp_path, "\n".join(rows) + "\n")
    parts = list(iter_readings(p, chunk_size=7))
    # Chunks are handed on as soon as no later reading can come before them (2 s).
    assert len(parts) > 1
    assert sum(len(x) for x in parts) == 50
    whole = read_readings(p)
    joined = Readings.concat(parts)
    np.testing.assert_array_equal(whole.range, joined.range)
    assert [whole.names[i] for i in whole.sensor] == [joined.names[i] for i in joined.sensor]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (GOOD.replace("1.5\n", "nan\n"), r"r.csv:2, field 'range': not a finite number"),
        (GOOD.replace("2.0\n", "-2.0\n"), r"r.csv:3, field 'range': range is negative"),
        (GOOD.replace("0.1,b,0.1", "0.1,b,abc"), r"r.csv:3, field 'x': not a finite number"),
        (GOOD.replace("b,0.1,0.0,1.57", "c,0.1,0.0,1.57"), r"r.csv:3, field 'sensor': unknown"),
        (GOOD.replace("theta,range", "heading,range"), r"r.csv:1: missing column\(s\) theta"),
        (GOOD + "0.3,a,0.0,0.0\n", r"r.csv:5, field 'theta': missing value"),
        (GOOD + "0.3,a,0,0,0,1,9\n", r"r.csv:5: expected 6 fields, saw 7"),
        (GOOD + "\n0.4,a,0,0,0,-1\n", r"r.csv:6, field 'range': range is negative"),
        ("", "file is empty"),
        ("t,sensor,x,y,theta,range\n", "no readings"),
    ],
)
def test_bad_readings(tmp_path: Path, text: str, match: str) -> None:
    with pytest.raises(InputError, match=match):
        read_readings(write(tmp_path, text), names=["a", "b"])


def test_truncated_gzip(tmp_path: Path) -> None:
    data = gzip.compress((GOOD * 200).encode())
    p = tmp_path / "r.csv.gz"
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"r\.csv\.gz: cannot read file"):
        read_readings(p)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"nope\.csv: no such file"):
        read_readings(tmp_path / "nope.csv")


def test_trajectory(tmp_path: Path) -> None:
    p = write(tmp_path, "t,x,y,theta\n0,0,0,0\n1,1,0,0.5\n", "traj.csv")
    traj = read_trajectory(p)
    assert len(traj) == 2
    assert traj.theta[1] == 0.5
    with pytest.raises(InputError, match="trajectory is empty"):
        read_trajectory(write(tmp_path, "t,x,y,theta\n", "e.csv"))
    with pytest.raises(InputError, match=r"b.csv:3, field 'y': not a finite number \('inf'\)"):
        read_trajectory(write(tmp_path, "t,x,y,theta\n0,0,0,0\n1,0,inf,0\n", "b.csv"))


def test_strict_order_names_the_line(tmp_path: Path) -> None:
    text = GOOD.replace("0.2,a", "0.05,a")
    with pytest.raises(InputError, match=r"r.csv:4, field 't': time goes backwards"):
        read_readings(write(tmp_path, text), names=["a", "b"], order=TimeOrder(None))


def _shuffled_log(tmp_path: Path) -> tuple[Path, list[float]]:
    """Readings every 0.1 s with some swapped by 0.2 s (like CARMEN scans that arrive
    late) and one reading 4.6 s late; the range column holds each row's line."""
    times = [round(0.1 * i, 3) for i in range(60)]
    for i in (5, 17, 18, 40):
        times[i], times[i + 2] = times[i + 2], times[i]
    times.insert(50, 0.3)  # 4.6 s behind the reading before it
    rows = ["t,sensor,x,y,theta,range"] + [
        f"{t},a,0,0,0,{line}" for line, t in enumerate(times, start=2)
    ]
    return write(tmp_path, "\n".join(rows) + "\n"), times


@pytest.mark.parametrize("chunk_size", [1, 3, 7, 1000])
def test_out_of_order_readings_are_put_in_place(tmp_path: Path, chunk_size: int) -> None:
    path, times = _shuffled_log(tmp_path)
    order = TimeOrder(1.0)
    r = read_readings(path, chunk_size=chunk_size, order=order)
    assert np.all(np.diff(r.t) >= 0)
    # Everything but the 4.6 s straggler (line 52) survives, each reading with its row.
    assert len(r) == len(times) - 1
    assert 52 not in r.range.tolist()
    assert sorted(r.range.tolist()) == [x for x in range(2, len(times) + 2) if x != 52]
    assert (order.reordered, order.dropped) == (6, 1)
    assert order.max_lag == pytest.approx(4.6)
    said = order.message(first_line=2)
    assert said is not None
    assert "put 6 readings back" in said
    assert "dropped 1 readings more than 1 s late" in said
    assert "line 8" in said  # the first reading behind a later one: t=0.6 after 0.7


def test_zero_window_drops_every_late_reading(tmp_path: Path) -> None:
    path, times = _shuffled_log(tmp_path)
    order = TimeOrder(0.0)
    r = read_readings(path, chunk_size=5, order=order)
    assert np.all(np.diff(r.t) >= 0)
    assert (order.reordered, order.dropped) == (0, 7)
    assert len(r) == len(times) - 7


def test_in_order_streams_pass_unchanged() -> None:
    t = np.repeat(np.arange(20) * 0.05, 3)  # ties keep their order
    r = Readings(t, np.zeros(len(t), np.int32), t, t, t, np.arange(len(t), dtype=float), ("s",))
    order = TimeOrder()
    out = Readings.concat(
        list(in_time_order((r.take(slice(i, i + 4)) for i in range(0, 60, 4)), order))
    )
    np.testing.assert_array_equal(out.range, r.range)
    assert order.message() is None
