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
from matplotlib.patches import Patch

from .errors import ConfigError
from .files import atomic_outputs, atomic_write
from .grid import Grid
from .io.rosmap import OCCUPIED, UNKNOWN, OccupancyMap, classify
from .readings import Readings

__all__ = [
    "FogAnimation",
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


def save_fog_picture(
    grid: Grid,
    free: npt.NDArray[np.bool_],
    tb: npt.NDArray[np.float64],
    robots: npt.NDArray[np.float64],
    path: str | Path,
    *,
    radius: float = 1.0,
    title: str = "",
) -> Path:
    """A patrol as the thesis's simulator drew it: obstacles black, fog from white (just
    seen) to dark grey (longest unseen), robots as circles with a heading segment.

    ``robots`` holds (x, y, heading) per robot; ``tb`` the time since each cell was seen.
    """
    from matplotlib.patches import Circle

    fig, ax = plt.subplots(figsize=(7, 7 * grid.rows / max(grid.cols, 1) + 0.8))
    top = float(tb[free].max()) if free.any() else 0.0
    shade = np.where(free, tb / top if top > 0 else 0.0, np.nan)
    cmap = plt.get_cmap("Greys").with_extremes(bad="black")
    im = ax.imshow(
        np.ma.masked_invalid(shade * 0.8),
        cmap=cmap,
        vmin=0.0,
        vmax=1.0,
        extent=grid.extent,
        interpolation="nearest",
        origin="upper",
    )
    for x, y, th in robots:
        ax.add_patch(Circle((x, y), radius, fill=False, color="tab:red", lw=1.5))
        ax.plot([x, x + radius * np.cos(th)], [y, y + radius * np.sin(th)], color="tab:red")
    ax.set_xlim(grid.extent[0], grid.extent[1])
    ax.set_ylim(grid.extent[2], grid.extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    bar = fig.colorbar(im, ax=ax, shrink=0.7, ticks=[0, 0.8])
    bar.ax.set_yticklabels(["just seen", f"{top:.0f} s unseen"])
    ax.legend(
        handles=[
            Patch(facecolor="black", label="obstacle"),
            Line2D([], [], ls="", marker="o", mfc="none", mec="tab:red", label="robot"),
        ],
        loc="upper center",
        bbox_to_anchor=(0.5, -0.1),
        ncol=2,
        fontsize="small",
        frameon=False,
    )
    return _save(fig, path)


class FogAnimation:
    """Frames of a patrol (the fog as one byte per cell, the robots' poses), saved as an
    animated GIF (or MP4 with ffmpeg)."""

    def __init__(
        self, grid: Grid, free: npt.NDArray[np.bool_], *, radius: float = 1.0, title: str = ""
    ) -> None:
        self.grid = grid
        self.free = free
        self.radius = radius
        self.title = title
        self.frames: list[tuple[float, npt.NDArray[np.uint8], npt.NDArray[np.float64]]] = []

    def add(self, t: float, tb: npt.NDArray[np.float64], robots: npt.NDArray[np.float64]) -> None:
        """Keep the fog at time ``t`` (shaded against its own maximum) and the robots'
        (x, y, heading)."""
        top = float(tb[self.free].max()) if self.free.any() else 0.0
        shade = np.where(self.free, tb / top if top > 0 else 0.0, 1.25)
        self.frames.append((t, np.round(shade * 200).astype(np.uint8), robots.copy()))

    def save(self, path: str | Path, *, fps: int = 8) -> Path:
        p = Path(path)
        MapAnimation.check_name(p)
        if not self.frames:
            raise ConfigError("no frames to animate")
        writer: Any = PillowWriter(fps=fps) if p.suffix.lower() == ".gif" else FFMpegWriter(fps=fps)
        fig, ax = plt.subplots(figsize=(6, 6 * self.grid.rows / max(self.grid.cols, 1) + 0.6))
        im = ax.imshow(
            self.frames[0][1],
            cmap="Greys",
            vmin=0,
            vmax=250,
            extent=self.grid.extent,
            interpolation="nearest",
        )
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        n = len(self.frames[0][2])
        rings = ax.plot(*([[], []] * n), color="tab:red", lw=1.2)
        theta = np.linspace(0, 2 * np.pi, 24)

        def show(i: int) -> list[Any]:
            t, code, robots = self.frames[i]
            im.set_data(code)
            for line, (x, y, th) in zip(rings, robots, strict=True):
                xs = np.concatenate(
                    [x + self.radius * np.cos(theta), [x, x + 2 * self.radius * np.cos(th)]]
                )
                ys = np.concatenate(
                    [y + self.radius * np.sin(theta), [y, y + 2 * self.radius * np.sin(th)]]
                )
                line.set_data(xs, ys)
            ax.set_title(f"{self.title}  t = {t:.0f} s".strip())
            return [im, *rings]

        return write_animation(fig, show, len(self.frames), p, writer)


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
