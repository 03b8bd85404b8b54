"""Where the robots start: the thesis's start files, their checks, and starts spread
over the territory when none are given.

A start file (the thesis's format) holds the robot count, then ``X Y phi`` per robot:
X and Y in decimetres from the map's top-left corner (Y down), phi in radians. Runs
without one spread the robots over the reachable territory by farthest-point sampling
on path lengths (the first robot at a cell drawn with the seed, each next one at the
cell farthest by path from those already placed) and write the starts they used, in
the same format, so that the run can be repeated.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError, InputError, quote
from ..files import read_text
from .paths import Wave
from .robots import close_pairs
from .territory import Territory

__all__ = [
    "MAX_ROBOTS",
    "check_robot_count",
    "check_starts",
    "format_starts",
    "random_starts",
    "read_starts",
    "spread_starts",
    "starts_from_dm",
    "starts_to_dm",
]

F64 = npt.NDArray[np.float64]

#: Robots in one patrol at most. Every step checks each pair of robots for collisions
#: and placing each spread start runs a wave over the whole map; the thesis's teams have
#: a handful of robots.
MAX_ROBOTS = 64


def check_robot_count(n: int) -> None:
    """Refuse a team of ``n`` robots unless 1 <= n <= :data:`MAX_ROBOTS`.

    Raises
    ------
    ConfigError
        With ``field="robots"``.
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ConfigError(f"robots must be an int >= 1, got {quote(n)}", field="robots")
    if n > MAX_ROBOTS:
        raise ConfigError(f"robots {n}: at most {MAX_ROBOTS} robots", field="robots")


def read_starts(path: str | Path, territory: Territory) -> F64:
    """A start file: world (x, y, heading) per robot (module notes for the format).

    Raises
    ------
    InputError
        Naming the file and line: unreadable, a count that is not a whole number in
        1..:data:`MAX_ROBOTS`, fewer or more lines than the count, a line that is not three
        finite numbers, a start outside the map.
    """
    p = Path(path)
    lines = [ln.strip() for ln in read_text(p, "start file").splitlines()]
    body = [(k + 1, ln) for k, ln in enumerate(lines) if ln and not ln.startswith("#")]
    if not body:
        raise InputError("start file is empty; expected the robot count", path=p)
    line, head = body[0]
    try:
        n = int(head)
    except ValueError:
        raise InputError(
            f"expected the robot count, got {quote(head)}", path=p, line=line
        ) from None
    if not (1 <= n <= MAX_ROBOTS):
        raise InputError(f"robot count must be in 1..{MAX_ROBOTS}, got {n}", path=p, line=line)
    if len(body) - 1 < n:
        raise InputError(f"the file says {n} robots but lists {len(body) - 1}", path=p)
    if len(body) - 1 > n:
        # A count left behind when starts were added would drop robots without a word.
        raise InputError(
            f"the file says {n} robots but lists {len(body) - 1}", path=p, line=body[n + 1][0]
        )
    rows = []
    for line, text in body[1 : n + 1]:
        parts = text.split()
        try:
            xd, yd, phi = (float(v) for v in parts)
        except ValueError:
            raise InputError(f"expected 'X Y phi', got {quote(text)}", path=p, line=line) from None
        if not all(math.isfinite(v) for v in (xd, yd, phi)):
            raise InputError(f"expected finite numbers, got {quote(text)}", path=p, line=line)
        g = territory.grid
        width, height = 10.0 * g.cols * g.resolution, 10.0 * g.rows * g.resolution
        if not (0.0 <= xd <= width and 0.0 <= yd <= height):
            raise InputError(
                f"start ({xd:g}, {yd:g}) dm is outside the map, 0..{width:g} x 0..{height:g} dm",
                path=p,
                line=line,
            )
        rows.append((xd, yd, phi))
    return starts_from_dm(rows, territory)


def starts_from_dm(rows: Sequence[tuple[float, float, float]], territory: Territory) -> F64:
    """World (x, y, heading) of starts given as ``X Y phi``, X and Y in decimetres from
    the map's top-left corner (Y down), phi in radians."""
    g = territory.grid
    top = g.origin[1] + g.rows * g.resolution
    out = [(g.origin[0] + xd / 10.0, top - yd / 10.0, phi) for xd, yd, phi in rows]
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def starts_to_dm(starts: F64, territory: Territory) -> F64:
    """The inverse of :func:`starts_from_dm`: (X dm, Y dm down, phi) per robot."""
    g = territory.grid
    top = g.origin[1] + g.rows * g.resolution
    xd = (starts[:, 0] - g.origin[0]) * 10.0
    yd = (top - starts[:, 1]) * 10.0
    return np.column_stack([xd, yd, starts[:, 2]])


def format_starts(starts: F64, territory: Territory) -> str:
    """A start file's text for world starts (readable by :func:`read_starts`)."""
    dm = starts_to_dm(starts, territory)
    lines = [str(len(dm))] + [f"{x:.6g} {y:.6g} {phi:.6g}" for x, y, phi in dm.tolist()]
    return "\n".join(lines) + "\n"


def check_starts(
    starts: F64, territory: Territory, passable: npt.NDArray[np.bool_], sep: float
) -> None:
    """Every start inside the map, on a passable cell and ``sep`` metres from the others.

    Raises
    ------
    InputError
        Naming the robot and where it is.
    """
    if not np.isfinite(starts).all():
        raise InputError("every start must be finite numbers")
    r, c = territory.grid.world_to_cell(starts[:, 0], starts[:, 1])
    for i in range(len(starts)):
        where = f"robot {i + 1} at ({starts[i, 0]:g}, {starts[i, 1]:g}) m"
        if not territory.grid.contains(r[i], c[i]):
            raise InputError(f"{where} is outside the map")
        if not territory.free[r[i], c[i]]:
            raise InputError(f"{where} is in an obstacle or unknown space, not on a free cell")
        if not passable[r[i], c[i]]:
            raise InputError(f"{where} is too near an obstacle for the robot's radius")
    near = close_pairs(starts[:, 0], starts[:, 1], sep)
    if near:
        a, b = near[0]
        raise InputError(f"robots {a + 1} and {b + 1} start closer than {sep:g} m")


def random_starts(
    n: int, territory: Territory, passable: npt.NDArray[np.bool_], sep: float, seed: int
) -> F64:
    """``n`` starts drawn on passable cells, at least ``sep`` apart, facing +x."""
    check_robot_count(n)
    rng = np.random.default_rng(seed)
    cells = np.argwhere(passable)
    out: list[tuple[float, float, float]] = []
    for k in rng.permutation(len(cells)):
        x, y = territory.grid.cell_centres(cells[k, :1], cells[k, 1:])
        if all(math.hypot(x[0] - a, y[0] - b) >= sep for a, b, _ in out):
            out.append((float(x[0]), float(y[0]), 0.0))
            if len(out) == n:
                return np.array(out)
    raise InputError(f"room for only {len(out)} robots {sep:g} m apart on this map, not {n}")


def spread_starts(
    n: int, territory: Territory, passable: npt.NDArray[np.bool_], sep: float, seed: int
) -> F64:
    """``n`` starts spread over ``passable`` by farthest-point sampling on path lengths.

    The first start is a passable cell drawn with ``seed``; each next one is the cell
    whose path to the nearest start so far is longest (cells less than ``sep`` metres
    from a start in a straight line never qualify). Headings face +x. Deterministic for
    a seed.

    Raises
    ------
    InputError
        When fewer than ``n`` robots fit ``sep`` apart on one connected piece.
    """
    check_robot_count(n)
    res = territory.grid.resolution
    cells = np.argwhere(passable)
    if not len(cells):
        raise InputError("no cell has room for a robot")
    rng = np.random.default_rng(seed)
    first = cells[int(rng.integers(len(cells)))]
    chosen: list[tuple[int, int]] = [(int(first[0]), int(first[1]))]
    waver = Wave(passable.shape)
    nearest = waver(passable, chosen[0], res)[0].copy()
    cx, cy = territory.grid.all_centres()
    while len(chosen) < n:
        score = np.where(np.isfinite(nearest), nearest, -1.0)
        for r, c in chosen:
            too_near = np.hypot(cx - cx[r, c], cy - cy[r, c]) < sep
            score[too_near] = -1.0
        k = int(np.argmax(score))
        if score.flat[k] < 0:
            raise InputError(
                f"room for only {len(chosen)} robots {sep:g} m apart on the reachable "
                f"territory, not {n}"
            )
        rc = (k // passable.shape[1], k % passable.shape[1])
        chosen.append(rc)
        np.minimum(nearest, waver(passable, rc, res)[0], out=nearest)
    rows = np.array([r for r, _ in chosen])
    cols = np.array([c for _, c in chosen])
    x, y = territory.grid.cell_centres(rows, cols)
    return np.column_stack([x, y, np.zeros(n)]).astype(np.float64)
