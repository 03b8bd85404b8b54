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

from .errors import ConfigError
from .grid import Grid
from .io._atomic import atomic_outputs, atomic_write
from .io.rosmap import OCCUPIED, UNKNOWN, OccupancyMap, classify
from .readings import Readings

__all__ = ["MapAnimation", "draw_map", "save_map_picture", "save_side_by_side"]

_UNKNOWN_RGBA = (0.80, 0.86, 0.93, 1.0)


def _classes_as_values(occupancy: npt.NDArray[np.float32]) -> npt.NDArray[np.float64]:
    """1 occupied, 0 free, NaN unknown: the classes every score uses, for drawing."""
    cls = classify(occupancy)
    return np.where(cls == UNKNOWN, np.nan, cls.astype(np.float64))


def draw_map(
    ax: Any,
    m: OccupancyMap,
    *,
    truth: OccupancyMap | None = None,
    readings: Readings | None = None,
    r_max: float | None = None,
    binary: bool = False,
    title: str | None = None,
) -> None:
    """Draw a map on a matplotlib axes: white free, black occupied, pale blue unknown.

    With ``truth``, true obstacles are outlined in red; with ``readings``, sensor positions
    are dots and echoes (ranges below ``r_max``) small crosses.
    """
    occ = m.occupancy.astype(np.float64)
    if binary:
        occ = _classes_as_values(m.occupancy)
    cmap = plt.get_cmap("gray_r").with_extremes(bad=_UNKNOWN_RGBA)
    ax.imshow(
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
        ax.contour(xc, yc, t, levels=[0.5], colors="red", linewidths=0.6)
    if readings is not None and len(readings):
        ax.plot(readings.x, readings.y, ".", ms=1.5, color="tab:blue")
        rng = readings.range
        hit = rng < (np.inf if r_max is None else r_max)
        ex = readings.x[hit] + rng[hit] * np.cos(readings.theta[hit])
        ey = readings.y[hit] + rng[hit] * np.sin(readings.theta[hit])
        ax.plot(ex, ey, "x", ms=2, mew=0.5, color="tab:orange")
    xmin, xmax, ymin, ymax = m.grid.extent
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)


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
) -> Path:
    """Maps side by side (a second row with their classes) with the truth first, to a PNG."""
    panels = ([(truth_label, truth)] if truth is not None else []) + list(maps.items())
    rows = 2 if binary_row else 1
    fig, axes = plt.subplots(
        rows, len(panels), figsize=(3.2 * len(panels), 3.4 * rows), squeeze=False
    )
    for j, (name, m) in enumerate(panels):
        draw_map(axes[0, j], m, truth=None if name == truth_label else truth, title=name)
        if binary_row:
            draw_map(axes[1, j], m, binary=True, title=f"{name} (binarised)")
    fig.tight_layout()
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

    def add(self, t: float, occupancy: npt.NDArray[np.float32]) -> None:
        """Keep the map at log time ``t`` (seconds), as its classes if asked."""
        occ = np.asarray(occupancy, dtype=np.float64).reshape(self.grid.shape)
        if self.binary:
            occ = _classes_as_values(np.asarray(occ, dtype=np.float32))
        code = np.where(np.isnan(occ), 255, np.round(np.clip(occ, 0, 1) * 250)).astype(np.uint8)
        self.frames.append((t, code))

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

        def show(i: int) -> list[Any]:
            t, code = self.frames[i]
            im.set_data(image(code))
            ax.set_title(f"{self.title}  t = {t:.0f} s".strip())
            return [im]

        anim = FuncAnimation(fig, show, frames=len(self.frames), blit=False)
        try:
            with atomic_outputs(p, keep_suffix=True) as (tmp,):
                anim.save(tmp, writer=writer, dpi=80)
        finally:
            plt.close(fig)
        return p
