"""Where the robots start: the thesis's start files, their checks, and starts spread
over the territory when none are given.

A start file (the thesis's format) holds the robot count, then ``X Y phi`` per robot:
X and Y in decimetres from the map's top-left corner (Y down), phi in radians. Runs
without one spread the robots over the reachable territory by farthest-point sampling
on path lengths (the first robot at a cell drawn with the seed, each next one at the
cell farthest by path from those already placed) and write the starts they used, in
the same format, so that the run can be repeated. Cars (:class:`CarStarts`) start only
where they can move and face along the street they stand in; a start file's car that
cannot move from its pose is refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError, InputError, quote
from ..files import read_text
from .paths import Wave
from .robots import arc, band_speed, close_pairs, wrap_angle
from .territory import Territory

__all__ = [
    "MAX_ROBOTS",
    "START_HEADINGS",
    "START_RUN",
    "CarStarts",
    "StartSource",
    "check_robot_count",
    "check_starts",
    "format_starts",
    "random_starts",
    "read_start_lines",
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

    Parameters
    ----------
    path : str or Path
        The start file.
    territory : Territory
        The map the file's decimetres are on.

    Returns
    -------
    ndarray (N, 3)
        World x and y (metres) and heading (radians) per robot.

    Raises
    ------
    InputError
        As :func:`read_start_lines`.
    """
    return read_start_lines(path, territory)[0]


def read_start_lines(path: str | Path, territory: Territory) -> tuple[F64, list[int]]:
    """A start file's starts (:func:`read_starts`) and the line each robot is on.

    Parameters
    ----------
    path : str or Path
        The start file.
    territory : Territory
        The map the file's decimetres are on.

    Returns
    -------
    starts : ndarray (N, 3)
        World x and y (metres) and heading (radians) per robot.
    lines : list of int
        The 1-based line of the file each robot's start is on (for messages:
        :class:`StartSource`).

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
    return starts_from_dm(rows, territory), [line for line, _ in body[1 : n + 1]]


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


@dataclass(frozen=True)
class StartSource:
    """Where given starts came from, for the messages refusing them.

    Without a path the starts are world poses (metres, radians) and a message says so;
    with one they came from that start file and a message gives the file, the robot's
    line and its pose in the file's units (decimetres from the top-left corner, Y down).

    Parameters
    ----------
    territory : Territory
        The map (for the file's units).
    path : Path, optional
        The start file; default None (starts given as world poses).
    lines : tuple of int
        The file's line of each robot (:func:`read_start_lines`); default none.
    """

    territory: Territory
    path: Path | None = None
    lines: tuple[int, ...] = ()

    def pose(self, starts: F64, i: int, heading: bool = True) -> str:
        """Robot i's pose as the user gave it.

        Parameters
        ----------
        starts : ndarray (N, 3)
            World (x, y, heading) per robot.
        i : int
            The robot (0-based).
        heading : bool
            Also the heading; default True.

        Returns
        -------
        str
            E.g. ``"robot 2 at (12.5, 3) m facing 0 rad"``, in decimetres for a file.
        """
        if self.path is None:
            x, y, h = (float(v) for v in starts[i])
            unit = "m"
        else:
            x, y, h = (float(v) for v in starts_to_dm(starts[i : i + 1], self.territory)[0])
            unit = "dm"
        facing = f" facing {h:g} rad" if heading else ""
        return f"robot {i + 1} at ({x:g}, {y:g}) {unit}{facing}"

    def error(self, message: str, i: int | None = None) -> InputError:
        """An :class:`~sonarmap.errors.InputError` naming the file and, for robot i, its
        line.

        Parameters
        ----------
        message : str
            What is wrong.
        i : int, optional
            The robot (0-based) it is about; default None (no line).

        Returns
        -------
        InputError
            To raise.
        """
        line = self.lines[i] if i is not None and i < len(self.lines) else None
        return InputError(message, path=self.path, line=line)


def check_starts(
    starts: F64,
    territory: Territory,
    passable: npt.NDArray[np.bool_],
    sep: float,
    source: StartSource | None = None,
) -> None:
    """Every start inside the map, on a passable cell and ``sep`` metres from the others.

    Parameters
    ----------
    starts : ndarray (N, 3)
        World (x, y, heading) per robot.
    territory : Territory
        The map.
    passable : ndarray of bool
        Cells a robot's centre may be on.
    sep : float
        Metres robots must start apart.
    source : StartSource, optional
        Where the starts came from (for the message); default: world poses.

    Raises
    ------
    InputError
        Naming the robot and where it is (and the file and line, from ``source``).
    """
    src = source if source is not None else StartSource(territory)
    if not np.isfinite(starts).all():
        raise src.error("every start must be finite numbers")
    r, c = territory.grid.world_to_cell(starts[:, 0], starts[:, 1])
    for i in range(len(starts)):
        where = src.pose(starts, i, heading=False)
        if not territory.grid.contains(r[i], c[i]):
            raise src.error(f"{where} is outside the map", i)
        if not territory.free[r[i], c[i]]:
            raise src.error(f"{where} is in an obstacle or unknown space, not on a free cell", i)
        if not passable[r[i], c[i]]:
            raise src.error(f"{where} is too near an obstacle for the robot's radius", i)
    near = close_pairs(starts[:, 0], starts[:, 1], sep)
    if near:
        a, b = near[0]
        raise src.error(f"robots {a + 1} and {b + 1} start closer than {sep:g} m", max(a, b))


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
    n: int,
    territory: Territory,
    passable: npt.NDArray[np.bool_],
    sep: float,
    seed: int,
    fits: Callable[[int, int], bool] | None = None,
) -> F64:
    """``n`` starts spread over ``passable`` by farthest-point sampling on path lengths.

    The first start is a passable cell drawn with ``seed``; each next one is the cell
    whose path to the nearest start so far is longest (cells less than ``sep`` metres
    from a start in a straight line never qualify). Headings face +x. Deterministic for
    a seed. With ``fits`` (row, column -> bool; default: every cell fits), a cell it
    turns down is skipped: the first start is drawn again, a next one is the farthest
    cell that fits.

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
    if fits is not None and not fits(int(first[0]), int(first[1])):
        # Drawn again from the same generator: deterministic for the seed.
        # The first that fits, not every one (each test costs milliseconds).
        good = next(
            (k for k in rng.permutation(len(cells)).tolist() if fits(*cells[k].tolist())), None
        )
        if good is None:
            raise InputError("no cell has room for a robot to move from")
        first = cells[good]
    chosen: list[tuple[int, int]] = [(int(first[0]), int(first[1]))]
    waver = Wave(passable.shape)
    nearest = waver(passable, chosen[0], res)[0].copy()
    cx, cy = territory.grid.all_centres()
    refused = np.zeros(passable.shape, dtype=bool)
    while len(chosen) < n:
        score = np.where(np.isfinite(nearest) & ~refused, nearest, -1.0)
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
        if fits is not None and not fits(*rc):
            refused[rc] = True
            continue
        chosen.append(rc)
        np.minimum(nearest, waver(passable, rc, res)[0], out=nearest)
    rows = np.array([r for r, _ in chosen])
    cols = np.array([c for _, c in chosen])
    x, y = territory.grid.cell_centres(rows, cols)
    return np.column_stack([x, y, np.zeros(n)]).astype(np.float64)


#: Headings a car's start is tried at (every 11.25 degrees, from +x anticlockwise).
START_HEADINGS = 32
#: Metres of a start heading's straight run looked at: the longest run wins.
START_RUN = 20.0


@dataclass(frozen=True)
class CarStarts:
    """Where a car can start: the headings it can move from, and the one it takes.

    A car at (x, y) facing ``h`` can move when some arc of one step's length (the speed
    rule's speed at the cell's clearance times ``dt``), of 9 curvatures from -1 to +1
    over ``turn_radius``, forward or in reverse, keeps its centre on ``passable``
    cells: otherwise neither the pursuit, a manoeuvre nor the escape can ever take it
    anywhere (a car facing across the tip of a street one passable cell wide). Its
    start heading (:meth:`heading`) is, of :data:`START_HEADINGS` headings it can move
    from, the one with the longest straight run forward on passable cells (up to
    :data:`START_RUN` metres; ties: the first from +x anticlockwise): along the street
    it stands in, towards its open end.

    Parameters
    ----------
    territory : Territory
        The map (its grid and clearance, metres).
    passable : ndarray of bool
        Cells a car's centre may be on.
    turn_radius : float
        The car's turning radius, metres.
    bands : tuple of (float, float)
        The speed rule (:data:`~sonarmap.patrol.robots.SPEED_BANDS`).
    dt : float
        Seconds a step lasts.
    """

    territory: Territory
    passable: npt.NDArray[np.bool_]
    turn_radius: float
    bands: tuple[tuple[float, float], ...]
    dt: float

    def step(self, x: float, y: float) -> float:
        """Metres a car at (x, y) drives in one step.

        Parameters
        ----------
        x, y : float
            World position, metres.

        Returns
        -------
        float
            The speed rule's speed at the cell's clearance (the slowest band off the
            map) times ``dt``.
        """
        g = self.territory.grid
        r, c = g.world_to_cell(x, y)
        if not g.contains(r, c):
            return band_speed(0.0, self.bands) * self.dt
        return band_speed(float(self.territory.clearance[int(r), int(c)]), self.bands) * self.dt

    def _clear(self, px: F64, py: F64) -> bool:
        g = self.territory.grid
        r, c = g.world_to_cell(px, py)
        return bool(g.contains(r, c).all()) and bool(self.passable[r, c].all())

    def moves(self, x: float, y: float, heading: float) -> bool:
        """Whether a car at (x, y) facing ``heading`` can move (class notes).

        Parameters
        ----------
        x, y : float
            World position, metres.
        heading : float
            Radians from +x, anticlockwise.

        Returns
        -------
        bool
            True when some arc of one step's length keeps the car's centre on passable
            cells.
        """
        s = self.step(x, y)
        kmax = 1.0 / self.turn_radius
        n = math.ceil(s / (self.territory.grid.resolution * 0.25)) + 1
        for length in (s, -s):
            for k in np.linspace(-kmax, kmax, 9).tolist():
                px, py, _ = arc(x, y, heading, length, k, n)
                if self._clear(px, py):
                    return True
        return False

    def run(self, x: float, y: float, heading: float) -> float:
        """Metres a car at (x, y) can drive straight on facing ``heading`` with its
        centre on passable cells.

        Parameters
        ----------
        x, y : float
            World position, metres.
        heading : float
            Radians from +x, anticlockwise.

        Returns
        -------
        float
            Up to :data:`START_RUN` metres, in quarter cells; 0 when (x, y) itself is
            not passable.
        """
        g = self.territory.grid
        u = np.arange(0.0, START_RUN + 1e-9, g.resolution * 0.25)
        r, c = g.world_to_cell(x + u * math.cos(heading), y + u * math.sin(heading))
        ok = g.contains(r, c)
        ok[ok] = self.passable[r[ok], c[ok]]
        bad = np.flatnonzero(~ok)
        if not len(bad):
            return float(u[-1])
        # Not u[-1] (what bad[0] - 1 would index) when the start itself is not passable.
        return float(u[bad[0] - 1]) if bad[0] > 0 else 0.0

    def heading(self, x: float, y: float) -> float | None:
        """The start heading at (x, y) (class notes).

        Parameters
        ----------
        x, y : float
            World position, metres.

        Returns
        -------
        float or None
            Radians in [-pi, pi); None when a car there cannot move at any heading.
        """
        best: tuple[float, float] | None = None
        for j in range(START_HEADINGS):
            h = wrap_angle(2.0 * math.pi * j / START_HEADINGS)
            if not self.moves(x, y, h):
                continue
            run = self.run(x, y, h)
            if best is None or run > best[0] + 1e-9:
                best = (run, h)
        return None if best is None else best[1]

    def fits(self, r: int, c: int) -> bool:
        """Whether a car can move from the centre of cell (r, c) at some heading.

        Parameters
        ----------
        r, c : int
            The cell's row and column.

        Returns
        -------
        bool
            True when :meth:`heading` finds one.
        """
        x, y = self.territory.grid.cell_centres(np.array([r]), np.array([c]))
        return self.heading(float(x[0]), float(y[0])) is not None

    def spread(self, n: int, sep: float, seed: int) -> F64:
        """:func:`spread_starts` over the cells a car can move from, each facing its
        start heading (class notes).

        Parameters
        ----------
        n : int
            Cars.
        sep : float
            Metres they start apart at least.
        seed : int
            The seed of the first start.

        Returns
        -------
        ndarray (n, 3)
            World x and y (metres) and heading (radians) per car.

        Raises
        ------
        InputError
            As :func:`spread_starts`.
        """
        starts = spread_starts(n, self.territory, self.passable, sep, seed, fits=self.fits)
        for row in starts:
            h = self.heading(float(row[0]), float(row[1]))
            assert h is not None  # spread_starts took only cells that fit
            row[2] = h
        return starts

    def check(self, starts: F64, source: StartSource | None = None) -> None:
        """Refuse starts a car cannot move from at the heading given.

        Parameters
        ----------
        starts : ndarray (N, 3)
            World (x, y, heading) per car.
        source : StartSource, optional
            Where the starts came from (for the message); default: world poses.

        Raises
        ------
        InputError
            Naming the robot, its pose and, when there is one, a heading it could move
            from (and the file and line, from ``source``).
        """
        src = source if source is not None else StartSource(self.territory)
        for i, (x, y, h) in enumerate(starts.tolist()):
            if self.moves(x, y, h):
                continue
            better = self.heading(x, y)
            hint = (
                f"; heading {better:.4g} rad would let it"
                if better is not None
                else "; no heading would: choose another place"
            )
            raise src.error(
                f"{src.pose(starts, i)}: a car can move neither forward nor in reverse from "
                f"there (turning radius {self.turn_radius:g} m){hint}",
                i,
            )
