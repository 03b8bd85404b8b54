"""Pictures of maps: one map with optional truth and readings, or several side by side."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from matplotlib.animation import FFMpegWriter, FuncAnimation, PillowWriter
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch

from .errors import ConfigError
from .files import atomic_outputs, atomic_write
from .grid import Grid
from .io.rosmap import OCCUPIED, UNKNOWN, OccupancyMap, classify
from .readings import Readings

__all__ = [
    "FogAnimation",
    "FogPicture",
    "MapAnimation",
    "draw_map",
    "save_fog_picture",
    "save_force_tables",
    "save_map_picture",
    "save_patrol_series",
    "save_side_by_side",
    "write_animation",
]

_UNKNOWN_RGBA = (0.80, 0.86, 0.93, 1.0)


def _classes_as_values(occupancy: npt.NDArray[np.float32]) -> npt.NDArray[np.float64]:
    """1 occupied, 0 free, NaN unknown: the classes every score uses, for drawing."""
    cls = classify(occupancy)
    return np.where(cls == UNKNOWN, np.nan, cls.astype(np.float64))


def _class_handles() -> list[Any]:
    return [
        Patch(facecolor="black", label="occupied (> 0.5)"),
        Patch(facecolor="white", edgecolor="0.5", label="free (< 0.5)"),
        Patch(facecolor=_UNKNOWN_RGBA, label="unknown (no evidence, or 0.5)"),
    ]


def _overlay_handles(*, truth: bool, readings: bool, robot: bool) -> list[Any]:
    out: list[Any] = []
    if truth:
        out.append(Line2D([], [], color="red", lw=1, label="true walls"))
    if readings:
        out.append(Line2D([], [], ls="", marker=".", color="tab:blue", label="sonar positions"))
        out.append(Line2D([], [], ls="", marker="x", color="tab:orange", label="echoes"))
    if robot:
        out.append(
            Line2D([], [], ls="", marker="o", mfc="none", mec="tab:green", mew=1.5, label="robot")
        )
    return out


def draw_map(
    ax: Any,
    m: OccupancyMap,
    *,
    truth: OccupancyMap | None = None,
    readings: Readings | None = None,
    r_max: float | None = None,
    binary: bool = False,
    title: str | None = None,
    robot: tuple[float, float] | None = None,
    legend: bool = True,
) -> Any:
    """Draw a map on a matplotlib axes: grey levels from white (free) to black
    (occupied), pale blue unknown; with ``binary``, the three classes every score uses.

    With ``truth``, true obstacles are outlined in red; with ``readings``, sensor
    positions are dots and echoes (ranges below ``r_max``) small crosses; ``robot`` is
    marked with a green ring. ``legend`` adds a key below the map and, for grey levels,
    a colour bar. Returns the image (for a colour bar drawn elsewhere).
    """
    occ = m.occupancy.astype(np.float64)
    # Even odds are unknown in every score; drawn so in the grey levels too.
    occ[occ == 0.5] = np.nan
    if binary:
        occ = _classes_as_values(m.occupancy)
    cmap = plt.get_cmap("gray_r").with_extremes(bad=_UNKNOWN_RGBA)
    im = ax.imshow(
        np.ma.masked_invalid(occ),
        cmap=cmap,
        vmin=0.0,
        vmax=1.0,
        extent=m.grid.extent,
        interpolation="nearest",
        origin="upper",
    )
    if truth is not None:
        t = (truth.classes() == OCCUPIED).astype(float)
        # Sample positions are the cell centres; the 0.5 level then runs along cell edges.
        xc, yc = truth.grid.all_centres()
        ax.contour(xc, yc, t, levels=[0.5], colors="red", linewidths=0.5, alpha=0.7)
    has_readings = readings is not None and len(readings) > 0
    if readings is not None and has_readings:
        ax.plot(readings.x, readings.y, ".", ms=1.5, color="tab:blue")
        rng = readings.range
        hit = rng < (np.inf if r_max is None else r_max)
        ex = readings.x[hit] + rng[hit] * np.cos(readings.theta[hit])
        ey = readings.y[hit] + rng[hit] * np.sin(readings.theta[hit])
        ax.plot(ex, ey, "x", ms=2, mew=0.5, color="tab:orange")
    if robot is not None:
        ax.plot(*robot, "o", ms=9, mfc="none", mec="tab:green", mew=1.5)
    xmin, xmax, ymin, ymax = m.grid.extent
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    if legend:
        _add_key(
            ax,
            im,
            binary=binary,
            extra=_overlay_handles(
                truth=truth is not None, readings=has_readings, robot=robot is not None
            ),
        )
    return im


def _add_key(ax: Any, im: Any, *, binary: bool, extra: list[Any]) -> None:
    """A key below the map: the classes, or a colour bar for grey levels, and ``extra``."""
    if binary:
        handles = _class_handles() + extra
    else:
        ax.figure.colorbar(im, ax=ax, shrink=0.7, label="occupancy (0 free, 1 occupied)")
        handles = [_class_handles()[2], *extra]
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.12),
        ncol=min(3, len(handles)),
        fontsize="small",
        frameon=False,
    )


def _save(fig: Any, path: str | Path) -> Path:
    p = Path(path)
    atomic_write(p, lambda tmp: fig.savefig(tmp, dpi=150, bbox_inches="tight", format="png"))
    plt.close(fig)
    return p


def save_map_picture(m: OccupancyMap, path: str | Path, **kwargs: Any) -> Path:
    """Draw one map (see :func:`draw_map`) to a PNG file."""
    fig, ax = plt.subplots(figsize=(6, 6))
    draw_map(ax, m, **kwargs)
    return _save(fig, path)


def save_side_by_side(
    maps: Mapping[str, OccupancyMap],
    path: str | Path,
    *,
    truth: OccupancyMap | None = None,
    binary_row: bool = True,
    truth_label: str = "truth",
    outline: bool = True,
    columns: int = 4,
) -> Path:
    """Maps side by side with the truth first, to a PNG, at most ``columns`` a row; with
    ``binary_row`` each map's classes (what the scores see) are drawn below it.

    ``outline`` draws the truth's obstacles in red over every map (leave it off where
    the truth is dense, like a laser reference, and would hide the maps).
    """
    panels = ([(truth_label, truth)] if truth is not None else []) + list(maps.items())
    cols = max(1, min(columns, len(panels)))
    bands = -(-len(panels) // cols)
    per = 2 if binary_row else 1
    fig, axes = plt.subplots(
        bands * per,
        cols,
        figsize=(3.6 * cols, 3.4 * bands * per + 0.8),
        squeeze=False,
        layout="constrained",
    )
    im = None
    for k, (name, m) in enumerate(panels):
        b, j = divmod(k, cols)
        over = truth if outline and name != truth_label else None
        im = draw_map(axes[b * per, j], m, truth=over, title=name, legend=False)
        if binary_row:
            draw_map(axes[b * per + 1, j], m, binary=True, title=f"{name}: classes", legend=False)
    for k in range(len(panels), bands * cols):
        b, j = divmod(k, cols)
        for r in range(per):
            axes[b * per + r, j].set_axis_off()
    if im is not None:
        fig.colorbar(im, ax=axes, shrink=0.5, label="occupancy (0 free, 1 occupied)")
    handles = _class_handles() + _overlay_handles(
        truth=truth is not None and outline, readings=False, robot=False
    )
    fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), frameon=False)
    return _save(fig, path)


class MapAnimation:
    """Frames of a map being built, saved as an animated GIF (or MP4 with ffmpeg).

    Each frame is kept as one byte per cell (occupancy in 250 levels, 255 unknown), so a
    frame of a 400 x 400 map costs 160 kB.
    """

    def __init__(self, grid: Grid, title: str = "", *, binary: bool = False) -> None:
        self.grid = grid
        self.title = title
        self.binary = binary
        self.frames: list[tuple[float, npt.NDArray[np.uint8]]] = []
        self.robots: list[tuple[float, float] | None] = []

    def add(
        self,
        t: float,
        occupancy: npt.NDArray[np.float32],
        robot: tuple[float, float] | None = None,
    ) -> None:
        """Keep the map at log time ``t`` (seconds), as its classes if asked, and where
        the robot is."""
        occ = np.array(occupancy, dtype=np.float64).reshape(self.grid.shape)
        occ[occ == 0.5] = np.nan
        if self.binary:
            occ = _classes_as_values(np.asarray(occ, dtype=np.float32))
        code = np.where(np.isnan(occ), 255, np.round(np.clip(occ, 0, 1) * 250)).astype(np.uint8)
        self.frames.append((t, code))
        self.robots.append(robot)

    @staticmethod
    def check_name(path: str | Path) -> None:
        """Refuse a file name whose format cannot be written here."""
        p = Path(path)
        suffix = p.suffix.lower()
        if suffix == ".mp4" and not FFMpegWriter.isAvailable():
            raise ConfigError(f"{p}: writing .mp4 needs ffmpeg; use a .gif name")
        if suffix not in (".gif", ".mp4"):
            raise ConfigError(f"{p}: animation must be a .gif or .mp4 file")

    def save(self, path: str | Path, *, fps: int = 4) -> Path:
        """Write the animation; the format follows the suffix (``.gif``, or ``.mp4``
        when ffmpeg is installed)."""
        p = Path(path)
        self.check_name(p)
        writer: Any = PillowWriter(fps=fps) if p.suffix.lower() == ".gif" else FFMpegWriter(fps=fps)
        if not self.frames:
            raise ConfigError("no frames to animate")
        cmap = plt.get_cmap("gray_r").with_extremes(bad=_UNKNOWN_RGBA)
        fig, ax = plt.subplots(figsize=(6, 6))

        def image(code: npt.NDArray[np.uint8]) -> Any:
            return np.ma.masked_equal(code, 255).astype(np.float64) / 250.0

        im = ax.imshow(
            image(self.frames[0][1]),
            cmap=cmap,
            vmin=0.0,
            vmax=1.0,
            extent=self.grid.extent,
            interpolation="nearest",
        )
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        (marker,) = ax.plot([], [], "o", ms=9, mfc="none", mec="tab:green", mew=1.5)
        robots = any(r is not None for r in self.robots)
        _add_key(
            ax,
            im,
            binary=self.binary,
            extra=_overlay_handles(truth=False, readings=False, robot=robots),
        )
        fig.subplots_adjust(bottom=0.2)

        def show(i: int) -> list[Any]:
            t, code = self.frames[i]
            im.set_data(image(code))
            robot = self.robots[i]
            marker.set_data([robot[0]] if robot else [], [robot[1]] if robot else [])
            ax.set_title(f"{self.title}  t = {t:.0f} s".strip())
            return [im, marker]

        return write_animation(fig, show, len(self.frames), p, writer)


def write_animation(fig: Any, show: Any, frames: int, path: Path, writer: Any) -> Path:
    """Render an animation of a figure to a file atomically, then close the figure.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure ``show`` draws on; closed when done, written or not.
    show : callable
        ``show(i)`` draws frame ``i`` (matplotlib's FuncAnimation protocol).
    frames : int
        How many frames, 0 to ``frames - 1``.
    path : Path
        The output; its suffix chooses the format with ``writer``.
    writer : matplotlib.animation.MovieWriter
        The writer (e.g. FFMpegWriter for .mp4, PillowWriter for .gif); frames are
        rendered at 80 dpi.

    Returns
    -------
    Path
        ``path``.
    """
    anim = FuncAnimation(fig, show, frames=frames, blit=False)
    try:
        with atomic_outputs(path, keep_suffix=True) as (tmp,):
            anim.save(tmp, writer=writer, dpi=80)
    finally:
        plt.close(fig)
    return path


# The fog's colours: obstacles black, and nothing else near black, so that the longest
# unseen places never read as walls. Magma (reversed, pale yellow to purple) is ordered
# in lightness and made for colour-blind readers; cut at 0.28 its dark end keeps a
# lightness of about 25 (of 100) and stays purple.
_FOG_CMAP = matplotlib.colors.ListedColormap(
    plt.get_cmap("magma")(np.linspace(1.0, 0.28, 256)), name="fog"
).with_extremes(bad=(0.0, 0.0, 0.0, 0.0))
_OBSTACLE_RGBA = (0.0, 0.0, 0.0, 1.0)
# A neutral grey: the fog's colours are all warm and saturated, the robots blue.
_MAP_UNKNOWN_RGBA = (0.56, 0.56, 0.56, 1.0)
_OUTSIDE_RGBA = (0.84, 0.89, 0.93, 1.0)
_OUTSIDE_HATCH_RGBA = (0.45, 0.55, 0.65, 1.0)
_NEVER_HATCH_RGBA = (1.0, 1.0, 1.0, 1.0)
# Okabe-Ito blue: absent from the fog map, dark enough to show on the just-seen yellow
# that surrounds every robot.
_ROBOT_RGB = "#0072B2"


def _seconds_ticks(top: float) -> tuple[list[float], list[str]]:
    """Round ticks from 0 for a colour bar in seconds, and ``top`` itself (the bar's end)."""
    locator = matplotlib.ticker.MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10])
    # A round tick nearer the end than 12 % of the bar would collide with the end's label.
    ticks = [float(v) for v in locator.tick_values(0.0, top) if 0.0 <= v < 0.88 * top]
    ticks.append(top)
    labels = [f"{v:g}" for v in ticks[:-1]]
    labels.append(f"{top:.0f}" if top >= 10 else f"{top:.2g}")
    return ticks, labels


def _mask(
    mask: npt.NDArray[np.bool_] | None, shape: tuple[int, int], name: str
) -> npt.NDArray[np.bool_]:
    if mask is None:
        return np.zeros(shape, dtype=bool)
    out = np.asarray(mask, dtype=bool)
    if out.shape != shape:
        raise ConfigError(f"{name} mask has shape {out.shape}, the grid {shape}")
    return out


def _blocks(mask: npt.NDArray[np.bool_], k: int) -> npt.NDArray[np.bool_]:
    """Whether any cell of each k x k block is in ``mask`` (edge blocks may be partial)."""
    if k == 1:
        return mask
    return _blocks_max(mask.astype(np.float64), k) > 0


def _blocks_max(values: npt.NDArray[np.float64], k: int) -> npt.NDArray[np.float64]:
    """The largest value of each k x k block (edge blocks may be partial)."""
    if k == 1:
        return values
    rows, cols = -(-values.shape[0] // k), -(-values.shape[1] // k)
    padded = np.full((rows * k, cols * k), -np.inf)
    padded[: values.shape[0], : values.shape[1]] = values
    # k * k strided maxima: several times faster than a max over a reshaped view.
    out = padded[::k, ::k].copy()
    for i in range(k):
        for j in range(k):
            np.maximum(out, padded[i::k, j::k], out=out)
    return out


def _figure_inches(grid: Grid, long_side: float) -> tuple[float, float]:
    """A figure whose long side is ``long_side`` inches and whose map keeps its aspect,
    with room for the labels, the title, the colour bar and the key below."""
    xmin, xmax, ymin, ymax = grid.extent
    aspect = (ymax - ymin) / (xmax - xmin)
    # Inches around the map: y label and colour bar across; title, x label, key down.
    across, down = 2.6, 1.9
    if aspect <= 1.0:
        width = long_side
        height = (width - across) * aspect + down
    else:
        height = long_side
        width = (height - down) / aspect + across
    return max(width, 6.0), max(height, 4.0)


class FogPicture:
    """A figure of a patrol: the time since each place was last seen, the map's other
    classes, the robots and a key; what :func:`save_fog_picture` writes and each frame
    of :class:`FogAnimation`.

    The fog's colours run from pale yellow (just seen) through orange and red to purple
    (``top`` seconds and more); obstacles are black, cells the map marks unknown flat
    grey, cells outside the patrolled territory pale blue-grey with hatching, places
    never seen cross-hatched white over the darkest fog colour, and robots blue discs
    (their radius, or at least 0.6 % of the map's long side) with a segment along the
    heading. The key sits below the x-axis label, the colour bar to the right.

    Parameters
    ----------
    grid : Grid
    free : ndarray of bool, shape grid.shape
        The free cells (the fog is drawn on those not ``outside`` nor ``unknown``).
        Cells neither free, unknown nor outside are drawn as obstacles.
    top : float
        Seconds at the colour bar's end; longer times take its colour. Values <= 0
        (nothing unseen yet) draw a bar of 1 s.
    radius : float
        The robots' radius in metres.
    title : str
    outside : ndarray of bool, optional
        Free cells that are not part of the patrolled territory (unreachable, or left
        out by the user). None: none.
    unknown : ndarray of bool, optional
        Cells the map marks unknown. None: none.
    never_seen : bool
        Whether the key lists "never seen" (the cells are given to :meth:`update`).
    long_side : float
        The figure's long side in inches.
    dpi : float
        The figure's dots per inch (a saved PNG may choose its own).

    Attributes
    ----------
    fig : matplotlib.figure.Figure
    ax : matplotlib.axes.Axes
        The map's axes (world metres).
    bar : matplotlib.colorbar.Colorbar
    legend : matplotlib.legend.Legend
        The key, a figure legend below the axes.
    """

    def __init__(
        self,
        grid: Grid,
        free: npt.NDArray[np.bool_],
        *,
        top: float,
        radius: float = 1.0,
        title: str = "",
        outside: npt.NDArray[np.bool_] | None = None,
        unknown: npt.NDArray[np.bool_] | None = None,
        never_seen: bool = False,
        long_side: float = 8.0,
        dpi: float = 100.0,
    ) -> None:
        shape = (grid.rows, grid.cols)
        self.grid = grid
        free = _mask(free, shape, "free")
        out = _mask(outside, shape, "outside")
        unk = _mask(unknown, shape, "unknown") & ~out
        self.fogged = free & ~out & ~unk
        self.top = float(top) if top > 0 else 1.0
        self.title = title
        width, height = _figure_inches(grid, long_side)
        self.fig = plt.figure(figsize=(width, height), dpi=dpi, layout="constrained")
        self.ax = self.fig.add_subplot()
        ax = self.ax
        xmin, xmax, ymin, ymax = grid.extent
        # No picture shows more than about 1000 samples along the map: larger grids are
        # drawn in blocks of k x k cells, resampled once here rather than by every frame.
        self.k = k = max(1, max(shape) // 1000)
        obstacle = _blocks(~free & ~unk & ~out, k)
        unk_b = _blocks(unk, k) & ~obstacle
        out_b = _blocks(out, k) & ~obstacle & ~unk_b
        self.fogged_blocks = _blocks(self.fogged, k) & ~obstacle & ~unk_b & ~out_b
        rows, cols = obstacle.shape
        step = k * grid.resolution
        self.extent = (xmin, xmin + cols * step, ymax - rows * step, ymax)
        # Contour samples at block centres, with the picture's edges added so that
        # hatching reaches them.
        self._xs = np.concatenate([[xmin], xmin + (np.arange(cols) + 0.5) * step, [xmax]])
        # Row 0 is the top of the map: y falls down the rows.
        self._ys = np.concatenate([[ymax], ymax - (np.arange(rows) + 0.5) * step, [ymin]])
        classes = np.zeros((rows, cols, 4))
        classes[obstacle] = _OBSTACLE_RGBA
        classes[unk_b] = _MAP_UNKNOWN_RGBA
        classes[out_b] = _OUTSIDE_RGBA
        ax.imshow(classes, extent=self.extent, interpolation="nearest", origin="upper")
        self.image = ax.imshow(
            np.ma.masked_array(np.zeros((rows, cols)), mask=True),
            cmap=_FOG_CMAP,
            vmin=0.0,
            vmax=self.top,
            extent=self.extent,
            interpolation="nearest",
            origin="upper",
        )
        if out_b.any():
            self._hatch(out_b, "///", _OUTSIDE_HATCH_RGBA)
        self._never: Any = None
        self.long = max(xmax - xmin, ymax - ymin)
        self.disc = max(float(radius), 0.006 * self.long)
        self.robots: list[tuple[Any, Any]] = []
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        self.bar = self.fig.colorbar(self.image, ax=ax, shrink=0.85, aspect=25, pad=0.02)
        self.bar.set_label("time since last seen [s]")
        ticks, labels = _seconds_ticks(self.top)
        self.bar.set_ticks(ticks, labels=labels)
        handles: list[Any] = [Patch(facecolor=_OBSTACLE_RGBA, edgecolor="0.4", label="obstacle")]
        if unk_b.any():
            handles.append(Patch(facecolor=_MAP_UNKNOWN_RGBA, label="unknown (map)"))
        if out_b.any():
            handles.append(
                Patch(
                    facecolor=_OUTSIDE_RGBA,
                    hatch="///",
                    edgecolor=_OUTSIDE_HATCH_RGBA,
                    label="outside territory",
                )
            )
        if never_seen:
            handles.append(
                Patch(
                    facecolor=_FOG_CMAP(1.0),
                    hatch="xx",
                    edgecolor=_NEVER_HATCH_RGBA,
                    label="never seen",
                )
            )
        handles.append(
            Line2D(
                [],
                [],
                ls="-",
                lw=1.8,
                color=_ROBOT_RGB,
                marker="o",
                ms=9,
                mfc=_ROBOT_RGB,
                mec="black",
                mew=0.8,
                label="robot (to scale), heading",
            )
        )
        ncol = len(handles) if width >= 9.5 else min(3, len(handles))
        self.legend = self.fig.legend(
            handles=handles, loc="outside lower center", ncol=ncol, frameon=False
        )

    def _hatch(self, blocks: npt.NDArray[np.bool_], hatch: str, colour: Any) -> Any:
        """Hatch the blocks of a mask: a filled contour at 0.5 of the mask runs along
        block edges; the mask is padded so that the hatching reaches the map's edge."""
        padded = np.pad(blocks.astype(np.float64), 1, mode="edge")
        cs = self.ax.contourf(
            self._xs, self._ys, padded, levels=[0.5, 1.5], colors="none", hatches=[hatch]
        )
        cs.set_edgecolor("none")
        cs.set_hatchcolor(colour)
        cs.set_hatch_linewidth(1.0)
        return cs

    def update(
        self,
        tb: npt.NDArray[np.float64],
        robots: npt.NDArray[np.float64],
        *,
        never_seen: npt.NDArray[np.bool_] | None = None,
        t: float | None = None,
    ) -> None:
        """Draw a moment of the patrol.

        Parameters
        ----------
        tb : ndarray of float, shape grid.shape
            Seconds since each cell was last seen (read on the fogged cells only).
        robots : ndarray of float, shape (n, 3) or (n, 2)
            Each robot's world x, y in metres and heading in radians (no heading
            segment without the third column).
        never_seen : ndarray of bool, optional
            Cells not seen since the start, drawn cross-hatched in the darkest fog
            colour whatever their time.
        t : float, optional
            The time in seconds, added to the title.
        """
        shape = (self.grid.rows, self.grid.cols)
        never = _blocks(_mask(never_seen, shape, "never_seen") & self.fogged, self.k)
        never &= self.fogged_blocks
        values = np.where(self.fogged, np.asarray(tb, dtype=np.float64), -np.inf)
        # A block shows its longest time: the picture errs towards the unseen.
        shown = np.where(never, self.top, _blocks_max(values, self.k))
        self.image.set_data(np.ma.masked_where(~self.fogged_blocks, shown))
        if self._never is not None:
            self._never.remove()
            self._never = None
        if never.any():
            self._never = self._hatch(never, "xx", _NEVER_HATCH_RGBA)
        pose = np.asarray(robots, dtype=np.float64).reshape(-1, robots.shape[-1])
        while len(self.robots) < len(pose):
            disc = Circle(
                (0.0, 0.0), self.disc, facecolor=_ROBOT_RGB, edgecolor="black", lw=0.8, zorder=4
            )
            self.ax.add_patch(disc)
            (tick,) = self.ax.plot(
                [], [], color=_ROBOT_RGB, lw=1.8, solid_capstyle="round", zorder=3
            )
            self.robots.append((disc, tick))
        for k, (disc, tick) in enumerate(self.robots):
            here = k < len(pose)
            disc.set_visible(here)
            tick.set_visible(here)
            if not here:
                continue
            x, y = pose[k, 0], pose[k, 1]
            disc.set_center((x, y))
            if pose.shape[1] >= 3:
                reach = 2.5 * self.disc
                th = pose[k, 2]
                tick.set_data([x, x + reach * np.cos(th)], [y, y + reach * np.sin(th)])
            else:
                tick.set_data([], [])
        when = f"t = {t:.0f} s" if t is not None else ""
        self.ax.set_title("  ".join(s for s in (self.title, when) if s))

    def moving(self) -> list[Any]:
        """The artists :meth:`update` changes: the fog, the never-seen hatching, the
        robots and the title."""
        out: list[Any] = [self.image]
        if self._never is not None:
            out.append(self._never)
        for disc, tick in self.robots:
            out += [tick, disc]
        out.append(self.ax.title)
        return out

    def freeze(self) -> None:
        """Lay the figure out once and keep that layout (frames of an animation then
        stay put and draw faster)."""
        self.fig.canvas.draw()
        self.fig.set_layout_engine("none")


def save_fog_picture(
    grid: Grid,
    free: npt.NDArray[np.bool_],
    tb: npt.NDArray[np.float64],
    robots: npt.NDArray[np.float64],
    path: str | Path,
    *,
    radius: float = 1.0,
    title: str = "",
    outside: npt.NDArray[np.bool_] | None = None,
    unknown: npt.NDArray[np.bool_] | None = None,
    never_seen: npt.NDArray[np.bool_] | None = None,
    top: float | None = None,
) -> Path:
    """Write a PNG of a patrol's fog (see :class:`FogPicture` for the colours).

    Parameters
    ----------
    grid : Grid
    free : ndarray of bool, shape grid.shape
        The free cells; the fog is drawn on those neither ``outside`` nor ``unknown``.
    tb : ndarray of float, shape grid.shape
        Seconds since each cell was last seen.
    robots : ndarray of float, shape (n, 3)
        Each robot's world x, y (metres) and heading (radians); with shape (n, 2)
        the robots are drawn without a heading.
    path : str or Path
        The PNG, written atomically.
    radius : float
        The robots' radius in metres (drawn to scale, at least 0.6 % of the map's long
        side so that small robots on large maps still show).
    title : str
    outside : ndarray of bool, optional
        Free cells that are not part of the patrolled territory (unreachable, or
        excluded by the user): pale blue-grey, hatched, no fog. Default: none.
    unknown : ndarray of bool, optional
        Cells the map marks unknown: flat grey, no fog. Default: none.
    never_seen : ndarray of bool, optional
        Cells not seen since the start: cross-hatched white over the darkest fog
        colour, with a key entry. Default: none marked.
    top : float, optional
        Seconds at the colour bar's end. Default: the longest time on the fogged cells.

    Returns
    -------
    Path
        ``path``.
    """
    shape = (grid.rows, grid.cols)
    fogged = (
        _mask(free, shape, "free")
        & ~_mask(outside, shape, "outside")
        & ~_mask(unknown, shape, "unknown")
    )
    if top is None:
        top = float(np.max(tb[fogged])) if fogged.any() else 0.0
    never = never_seen is not None and bool(np.any(np.asarray(never_seen) & fogged))
    pic = FogPicture(
        grid,
        free,
        top=top,
        radius=radius,
        title=title,
        outside=outside,
        unknown=unknown,
        never_seen=never,
    )
    pic.update(tb, robots, never_seen=never_seen)
    return _save(pic.fig, path)


class FogAnimation:
    """Frames of a patrol, saved as an animated GIF (or MP4 with ffmpeg) drawn as
    :class:`FogPicture` draws, on one colour scale for the whole animation.

    Each frame keeps the fog as one byte per cell (against the frame's own longest
    time, rescaled when saved), the never-seen cells as one bit per cell, and the
    robots' poses.

    Parameters
    ----------
    grid : Grid
    free : ndarray of bool, shape grid.shape
        The free cells (see :class:`FogPicture`).
    radius : float
        The robots' radius in metres.
    title : str
        Shown before each frame's time.
    outside, unknown : ndarray of bool, optional
        As for :func:`save_fog_picture`; fixed for the whole animation.
    top : float, optional
        Seconds at the colour bar's end. Default: the longest time over all frames.
    long_side : float
        The frames' long side in inches; rendered at 80 dpi, the default 12 gives
        960 pixels whatever the map's size, its aspect kept.
    """

    def __init__(
        self,
        grid: Grid,
        free: npt.NDArray[np.bool_],
        *,
        radius: float = 1.0,
        title: str = "",
        outside: npt.NDArray[np.bool_] | None = None,
        unknown: npt.NDArray[np.bool_] | None = None,
        top: float | None = None,
        long_side: float = 12.0,
    ) -> None:
        shape = (grid.rows, grid.cols)
        self.grid = grid
        self.free = _mask(free, shape, "free")
        self.outside = None if outside is None else _mask(outside, shape, "outside")
        self.unknown = None if unknown is None else _mask(unknown, shape, "unknown")
        self.fogged = (
            self.free & ~_mask(outside, shape, "outside") & ~_mask(unknown, shape, "unknown")
        )
        self.radius = radius
        self.title = title
        self.top = top
        self.long_side = long_side
        self.frames: list[
            tuple[float, float, npt.NDArray[np.uint8], npt.NDArray[np.uint8] | None, Any]
        ] = []

    def add(
        self,
        t: float,
        tb: npt.NDArray[np.float64],
        robots: npt.NDArray[np.float64],
        *,
        never_seen: npt.NDArray[np.bool_] | None = None,
    ) -> None:
        """Keep a frame.

        Parameters
        ----------
        t : float
            The time in seconds.
        tb : ndarray of float, shape grid.shape
            Seconds since each cell was last seen.
        robots : ndarray of float, shape (n, 3)
            Each robot's world x, y (metres) and heading (radians).
        never_seen : ndarray of bool, optional
            Cells not seen since the start.
        """
        top = float(np.max(tb[self.fogged])) if self.fogged.any() else 0.0
        scale = 250.0 / top if top > 0 else 0.0
        code = np.round(np.clip(np.asarray(tb) * scale, 0, 250)).astype(np.uint8)
        bits = None if never_seen is None else np.packbits(np.asarray(never_seen, dtype=bool))
        self.frames.append((t, top, code, bits, np.array(robots, dtype=np.float64)))

    def save(self, path: str | Path, *, fps: int = 8) -> Path:
        """Write the animation; the format follows the suffix (``.gif``, or ``.mp4``
        when ffmpeg is installed). Returns ``path``."""
        p = Path(path)
        MapAnimation.check_name(p)
        if not self.frames:
            raise ConfigError("no frames to animate")
        writer: Any = PillowWriter(fps=fps) if p.suffix.lower() == ".gif" else FFMpegWriter(fps=fps)
        top = self.top if self.top is not None else max(f[1] for f in self.frames)
        cells = self.grid.rows * self.grid.cols
        shape = (self.grid.rows, self.grid.cols)

        def never(bits: npt.NDArray[np.uint8] | None) -> npt.NDArray[np.bool_] | None:
            if bits is None:
                return None
            return np.unpackbits(bits, count=cells).reshape(shape).astype(bool)

        any_never = False
        for frame in self.frames:
            seen = never(frame[3])
            any_never = any_never or (seen is not None and bool(np.any(seen & self.fogged)))
        pic = FogPicture(
            self.grid,
            self.free,
            top=top,
            radius=self.radius,
            title=self.title,
            outside=self.outside,
            unknown=self.unknown,
            never_seen=any_never,
            long_side=self.long_side,
            dpi=80,
        )

        def show(i: int) -> list[Any]:
            t, frame_top, code, bits, robots = self.frames[i]
            tb = code.astype(np.float64) * (frame_top / 250.0)
            pic.update(tb, robots, never_seen=never(bits), t=t)
            return pic.moving()

        show(0)
        pic.freeze()
        if p.suffix.lower() != ".gif":
            return write_animation(pic.fig, show, len(self.frames), p, writer)
        try:
            with atomic_outputs(p, keep_suffix=True) as (tmp,):
                _write_gif(pic.fig, show, len(self.frames), tmp, fps=fps)
        finally:
            plt.close(pic.fig)
        return p


def _write_gif(fig: Any, show: Any, frames: int, path: Path, *, fps: int) -> None:
    """Write frames of a figure as a GIF, redrawing only what moves.

    ``show(i)`` draws frame ``i`` and returns the artists that change; the rest is
    drawn once and restored for every frame. Each frame is reduced to a palette of
    its own as it is made, so that memory holds one byte a pixel a frame.
    """
    from PIL import Image

    canvas = fig.canvas
    for artist in show(0):
        artist.set_animated(True)
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    images = []
    for i in range(frames):
        canvas.restore_region(background)
        for artist in show(i):
            fig.draw_artist(artist)
        rgb = np.asarray(canvas.buffer_rgba())[..., :3]
        images.append(
            Image.fromarray(rgb).quantize(
                255, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE
            )
        )
    images[0].save(
        path,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=round(1000 / fps),
        loop=0,
    )


def save_force_tables(
    tables: Mapping[str, npt.NDArray[np.float64]],
    rows: list[str],
    cols: list[str],
    path: str | Path,
) -> Path:
    """Tables of mean MTB (seconds) as heat maps side by side, one shared log colour
    scale, each cell labelled with its value."""
    finite = np.concatenate([t[np.isfinite(t)] for t in tables.values()])
    lo, hi = (float(finite.min()), float(finite.max())) if len(finite) else (1.0, 10.0)
    norm = matplotlib.colors.LogNorm(vmin=max(lo, 1e-3), vmax=max(hi, lo * 1.01))
    n = len(tables)
    ncols = min(n, 2)
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.6 * ncols, 4.0 * nrows), squeeze=False)
    im = None
    for ax, (title, t) in zip(axes.ravel(), tables.items(), strict=False):
        im = ax.imshow(t, cmap="viridis_r", norm=norm)
        ax.set_xticks(range(len(cols)), cols)
        ax.set_yticks(range(len(rows)), rows)
        ax.set_title(title)
        for (i, j), v in np.ndenumerate(t):
            ax.text(
                j,
                i,
                "-" if not np.isfinite(v) else f"{v:.0f}",
                ha="center",
                va="center",
                fontsize=8,
                color="white" if np.isfinite(v) and norm(v) > 0.55 else "black",
            )
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    if im is not None:
        fig.colorbar(im, ax=axes.ravel().tolist(), label="mean MTB [s]", shrink=0.8)
    return _save(fig, path)


def save_patrol_series(table: Any, path: str | Path) -> Path:
    """Mean MTB against the number of robots, a line per variant and a panel per map;
    a second row of DVT panels when any run has a DVT (cars). ``table`` is a pandas
    frame with columns map, variant, robots, mean_mtb, mtb_sd and dvt."""
    maps = list(dict.fromkeys(table["map"]))
    with_dvt = bool((table["dvt"] > 0).any())
    nrows = 2 if with_dvt else 1
    fig, axes = plt.subplots(
        nrows, len(maps), figsize=(5.2 * len(maps), 3.6 * nrows), squeeze=False
    )
    for k, m in enumerate(maps):
        sub = table[table["map"] == m]
        for variant in dict.fromkeys(sub["variant"]):
            v = sub[sub["variant"] == variant].sort_values("robots")
            sd = v["mtb_sd"].fillna(0.0)
            axes[0, k].errorbar(
                v["robots"], v["mean_mtb"], yerr=sd, marker="o", capsize=3, label=str(variant)
            )
            if with_dvt:
                axes[1, k].plot(v["robots"], v["dvt"], marker="o", label=str(variant))
        for ax in axes[:, k]:
            ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        axes[0, k].set_title(str(m))
        axes[0, k].set_ylabel("mean MTB [s]")
        axes[0, k].set_xlabel("robots")
        axes[0, k].legend(fontsize=7)
        if with_dvt:
            axes[1, k].set_ylabel("DVT [%]")
            axes[1, k].set_xlabel("robots")
    fig.tight_layout()
    return _save(fig, path)


def save_memory_series(
    series: Mapping[str, npt.ArrayLike],
    path: str | Path,
    *,
    interval: float,
    bound: float | None = None,
    ylabel: str = "local layer [MB]",
) -> Path:
    """Bytes after each pose, a line per robot, with the configured bound as a dashed
    line: the picture of memory that stops growing.

    Parameters
    ----------
    series : mapping of str to array of int
        Bytes after each pose made, by robot label.
    path : str or Path
    interval : float
        Seconds between poses (the x axis is mission time).
    bound : float, optional
        The configured bound of what ``series`` measures, bytes.
    ylabel : str
    """
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for label, values in series.items():
        v = np.asarray(values, dtype=np.float64)
        ax.plot(np.arange(1, len(v) + 1) * interval, v / 1e6, lw=1.0, label=label)
    if bound is not None:
        ax.axhline(bound / 1e6, color="black", ls="--", lw=1.0, label="bound")
    ax.set_xlabel("mission time [s]")
    ax.set_ylabel(ylabel)
    ax.set_ylim(bottom=0.0)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def save_idleness_plot(
    series: Mapping[str, npt.ArrayLike],
    path: str | Path,
    *,
    title: str = "",
) -> Path:
    """The idleness of a patrol graph's vertices over time: the mean and the max over
    the vertices, seconds against seconds.

    Parameters
    ----------
    series : mapping of str to array of float
        ``t``, ``mean`` and ``max`` of equal length, as
        :meth:`sonarmap.patrol.monitor.Monitor.idleness_series` gives them.
    path : str or Path
        The picture written (PNG by its suffix).
    title : str
    """
    t = np.asarray(series["t"], dtype=np.float64)
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    ax.plot(t, np.asarray(series["max"], dtype=np.float64), lw=1.0, label="max over vertices")
    ax.plot(t, np.asarray(series["mean"], dtype=np.float64), lw=1.0, label="mean over vertices")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("idleness [s]")
    ax.set_ylim(bottom=0.0)
    if title:
        ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)
