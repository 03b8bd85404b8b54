"""What a mission's world offers on a map: its landmarks, its route and its regions,
measured against the territory a robot can reach.

A mission only closes loops where the route passes a place again and sees landmarks it
saw there before; its regions only name rooms if they are cut where the rooms meet. On
the project's own buildings every wall faces the inside and every free cell is
reachable; on a real map (thin or speckled walls, the outside drawn free, unknown
cells) neither holds. :func:`survey` measures, for one world and one route:

- **landmarks**: how many lie on wall faces that face the reachable territory
  (:func:`~sonarmap.team.world.facing_cells`: free cells within the robot's radius
  plus 0.5 m of where its centre can get to, never across a wall), per metre of such
  face; the share of that face with a landmark within ``near`` metres;
  the share of landmarks on speckle (occupied specks smaller than ``speckle_area``),
  facing free space the robot cannot reach (the outside, closed pockets) or facing no
  free cell at all (unknown, inside an obstacle); the share the route ever sees;
- **route**: the share of its poses on the territory where the robot's centre may be;
  the share of the territory within ``cover`` metres of it; its *revisits*: moments
  (on a 1 s grid) where the robot is within ``place`` metres of where it was at least
  ``gap`` seconds before, heading within ``view`` degrees of its heading then (the
  stereo camera sees 90 degrees: a place passed the other way shows other landmarks),
  counted as episodes of consecutive such moments, with the time since that earlier
  pass;
- **regions**: their count and areas, the share of their area outside the territory,
  and their *cuts* (the boundaries between two regions): a cut lies at a door when
  the free space along it is nowhere wider than ``door_width`` plus two cells (twice
  the largest clearance of its cells).

The territory is :func:`~sonarmap.patrol.reach.reach`'s: what a robot of ``radius``
reaches from the route's first pose, unknown cells never free. Straight-line distances
(no line of sight) for ``cover`` and ``place``. :func:`draw_survey` pictures it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from matplotlib.lines import Line2D
from scipy import ndimage
from scipy.spatial import cKDTree

from ..errors import ConfigError
from ..files import atomic_write
from ..io.rosmap import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from ..patrol.reach import Reach, reach
from ..patrol.territory import Territory
from .regions import clearance
from .world import World, facing_cells, observe, speckle_mask, wall_faces

__all__ = ["KINDS", "Survey", "draw_survey", "landmark_kinds", "survey"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Mask = npt.NDArray[np.bool_]

#: What a landmark's face looks onto: the reachable territory, nothing but a speck,
#: free space the robot cannot reach, or no free cell (unknown, inside an obstacle).
KINDS = ("reachable", "speckle", "unreachable", "unknown")

_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True, eq=False)
class Survey:
    """A world's landmarks, route and regions measured on its map (module notes).

    Attributes
    ----------
    figures : dict
        JSON-ready numbers, keys prefixed ``landmarks_``, ``route_``, ``regions_``.
    kinds : ndarray (n,) int64
        Each landmark's index into :data:`KINDS`.
    revisit : ndarray (T,) bool
        Route steps that revisit a place.
    reach : Reach
        The territory measured against.
    cut_cells : ndarray of bool
        Free cells on a cut between two regions.
    door_cells : ndarray of bool
        Those of the cuts that lie at a door.
    """

    figures: dict[str, Any]
    kinds: I64
    revisit: Mask
    reach: Reach
    cut_cells: Mask
    door_cells: Mask
    params: dict[str, float] = field(default_factory=dict)


def _probe(plan: OccupancyMap, x: F64, y: F64) -> tuple[npt.NDArray[np.intp], ...]:
    """Rows and columns (k, 4) of the cells a quarter cell to each side of points that
    lie on cell sides, clipped to the map, with whether each is on the map."""
    g = plan.grid
    e = 0.25 * g.resolution
    dx = np.array([e, -e, 0.0, 0.0])
    dy = np.array([0.0, 0.0, e, -e])
    r, c = g.world_to_cell(x[:, None] + dx, y[:, None] + dy)
    on = g.contains(r, c)
    return (
        np.clip(r, 0, g.rows - 1).astype(np.intp),
        np.clip(c, 0, g.cols - 1).astype(np.intp),
        np.asarray(on, dtype=np.intp),
    )


def landmark_kinds(plan: OccupancyMap, xy: F64, facing: Mask, speckle: Mask) -> I64:
    """Each landmark's index into :data:`KINDS`, from the cells beside its point.

    A landmark sits on the side of an occupied cell. It is ``speckle`` when the only
    occupied cells beside it are specks (``speckle``), else ``reachable`` when a free
    cell beside it is ``facing`` (:func:`~sonarmap.team.world.facing_cells`: free
    space the robot sees the wall from), else ``unreachable`` when some free cell is beside
    it, else ``unknown``.
    """
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    r, c, on = _probe(plan, p[:, 0], p[:, 1])
    on_b = on.astype(bool)
    cls = plan.classes()[r, c]
    occ = on_b & (cls == OCCUPIED)
    speck = occ & speckle[r, c]
    free = on_b & (cls == FREE)
    seen = free & facing[r, c]
    kind = np.full(len(p), KINDS.index("unknown"), dtype=np.int64)
    kind[free.any(axis=1)] = KINDS.index("unreachable")
    kind[seen.any(axis=1)] = KINDS.index("reachable")
    kind[speck.any(axis=1) & ~(occ & ~speck).any(axis=1)] = KINDS.index("speckle")
    return kind


def _landmark_figures(
    plan: OccupancyMap,
    world: World,
    route: F64,
    facing: Mask,
    speckle: Mask,
    kinds: I64,
    near: float,
    every: float,
) -> dict[str, Any]:
    g = plan.grid
    h = g.resolution
    starts, dirs, normals = wall_faces(plan)
    centre = starts + 0.5 * h * dirs
    fr, fc = g.world_to_cell(*(centre + 0.5 * h * normals).T)
    orr, occ_c = g.world_to_cell(*(centre - 0.5 * h * normals).T)
    faces_useful = facing[fr, fc] & ~speckle[orr, occ_c]
    initial = world.born == 0
    good = (kinds == KINDS.index("reachable")) & initial
    useful_m = float(faces_useful.sum()) * h
    if good.any() and faces_useful.any():
        d, _ = cKDTree(world.points[good, :2]).query(centre[faces_useful], k=1)
        within = float(np.mean(d <= near))
    else:
        within = 0.0
    n0 = int(initial.sum())
    out: dict[str, Any] = {
        "landmarks": len(world),
        "landmarks_face_m": round(float(len(starts)) * h, 2),
        "landmarks_useful_face_m": round(useful_m, 2),
        "landmarks_per_m": round(int(good.sum()) / useful_m, 4) if useful_m else 0.0,
        f"landmarks_face_within_{near:g}m": round(within, 4),
    }
    for i, k in enumerate(KINDS):
        out[f"landmarks_{k}_share"] = round(float(np.mean(kinds[initial] == i)) if n0 else 0.0, 4)
    # What the camera ever sees from the route, sampled every `every` seconds.
    seen: set[int] = set()
    t = route[:, 0]
    picks = np.unique(np.searchsorted(t, np.arange(t[0], t[-1] + 1e-9, every)))
    for k in picks[picks < len(route)]:
        seen.update(observe(world, route[k, 1:4], float(t[k])).ids.tolist())
    out["landmarks_seen_share"] = round(len(seen) / len(world), 4) if len(world) else 0.0
    return out


def _revisits(route: F64, gap: float, place: float, view: float) -> tuple[Mask, list[float]]:
    """Route steps that revisit a place, and each episode's time since the earlier pass."""
    t = route[:, 0]
    grid = np.unique(np.searchsorted(t, np.arange(t[0], t[-1] + 1e-9, 1.0)))
    grid = grid[grid < len(route)]
    pts = route[grid, 1:3]
    th = route[grid, 3]
    tg = t[grid]
    hit = np.zeros(len(grid), dtype=bool)
    since = np.full(len(grid), np.nan)
    tree = cKDTree(pts)
    for j, nb in enumerate(tree.query_ball_point(pts, place)):
        idx = np.asarray(nb, dtype=np.intp)
        idx = idx[tg[idx] <= tg[j] - gap]
        if len(idx) == 0:
            continue
        dth = np.abs(np.remainder(th[idx] - th[j] + np.pi, 2 * np.pi) - np.pi)
        idx = idx[dth <= math.radians(view)]
        if len(idx):
            hit[j] = True
            since[j] = tg[j] - float(tg[idx].max())
    starts = np.flatnonzero(hit & ~np.concatenate([[False], hit[:-1]]))
    mask = np.zeros(len(route), dtype=bool)
    # Each 1 s sample stands for the route steps up to the next sample.
    bounds = np.append(grid, len(route))
    for i in np.flatnonzero(hit).tolist():
        mask[bounds[i] : bounds[i + 1]] = True
    return mask, [float(since[j]) for j in starts]


def _route_figures(
    plan: OccupancyMap,
    route: F64,
    terr: Reach,
    cover: float,
    revisit: Mask,
    episodes: list[float],
) -> dict[str, Any]:
    g = plan.grid
    r, c = g.world_to_cell(route[:, 1], route[:, 2])
    on = g.contains(r, c)
    rr, cc = np.clip(r, 0, g.rows - 1), np.clip(c, 0, g.cols - 1)
    on_passable = on & terr.passable[rr, cc]
    on_free = on & (plan.classes()[rr, cc] == FREE)
    visited = np.zeros(g.shape, dtype=bool)
    visited[rr[on], cc[on]] = True
    near = ndimage.distance_transform_edt(~visited) * g.resolution <= cover
    watched = terr.watched
    steps = np.hypot(*np.diff(route[:, 1:3], axis=0).T)
    return {
        "route_seconds": round(float(route[-1, 0] - route[0, 0]), 1),
        "route_length_m": round(float(steps.sum()), 1),
        "route_on_territory_share": round(float(on_passable.mean()), 4),
        "route_on_free_share": round(float(on_free.mean()), 4),
        "route_territory_m2": round(float(watched.sum()) * g.resolution**2, 1),
        f"route_covered_{cover:g}m_share": round(
            float((near & watched).sum()) / max(1, int(watched.sum())), 4
        ),
        "route_revisits": len(episodes),
        "route_revisit_time_share": round(float(revisit.mean()), 4),
        "route_revisit_since_median_s": round(float(np.median(episodes)), 1) if episodes else None,
    }


def _cuts(labels: npt.NDArray[np.int32], free: Mask, h: float, door: float) -> tuple[Any, ...]:
    """Cells on each cut between two regions, and which cuts lie at a door."""
    clear = clearance(free, h)
    cells: dict[tuple[int, int], list[npt.NDArray[np.intp]]] = {}
    rows, cols = labels.shape
    for dr, dc in ((0, 1), (1, 0)):
        a = labels[: rows - dr, : cols - dc]
        b = labels[dr:, dc:]
        touch = (a >= 0) & (b >= 0) & (a != b)
        ia = np.flatnonzero(touch)
        ra, ca = np.unravel_index(ia, touch.shape)
        for k in range(len(ia)):
            key = (int(min(a.flat[ia[k]], b.flat[ia[k]])), int(max(a.flat[ia[k]], b.flat[ia[k]])))
            cells.setdefault(key, []).append(np.array([[ra[k], ca[k]], [ra[k] + dr, ca[k] + dc]]))
    cut = np.zeros(labels.shape, dtype=bool)
    at_door = np.zeros(labels.shape, dtype=bool)
    widths = []
    for pieces in cells.values():
        pc = np.concatenate(pieces)
        cut[pc[:, 0], pc[:, 1]] = True
        width = 2.0 * float(clear[pc[:, 0], pc[:, 1]].max())
        widths.append(width)
        if width <= door + 2 * h:
            at_door[pc[:, 0], pc[:, 1]] = True
    return cut, at_door, np.array(widths)


def _region_figures(
    labels: npt.NDArray[np.int32], plan: OccupancyMap, terr: Reach, route: F64, door: float
) -> tuple[dict[str, Any], Mask, Mask]:
    h = plan.grid.resolution
    free = labels >= 0
    k = int(labels.max()) + 1
    area = np.bincount(labels[free], minlength=k) * h * h
    inside = np.bincount(labels[free & terr.watched], minlength=k) * h * h
    cut, at_door, widths = _cuts(labels, free, h, door)
    r, c = plan.grid.world_to_cell(route[:, 1], route[:, 2])
    on = plan.grid.contains(r, c)
    used = np.unique(labels[r[on], c[on]])
    out = {
        "regions": k,
        "regions_area_min_m2": round(float(area.min()), 1) if k else None,
        "regions_area_median_m2": round(float(np.median(area)), 1) if k else None,
        "regions_area_max_m2": round(float(area.max()), 1) if k else None,
        "regions_unreachable": int(np.sum(inside == 0)),
        "regions_area_outside_share": round(1.0 - float(inside.sum() / max(area.sum(), 1e-12)), 4),
        "regions_on_route": int(np.sum(used >= 0)),
        "regions_cuts": len(widths),
        "regions_cuts_at_doors": int(np.sum(widths <= door + 2 * h)),
        "regions_cut_width_median_m": round(float(np.median(widths)), 2) if len(widths) else None,
    }
    return out, cut, at_door


def survey(
    plan: OccupancyMap,
    world: World,
    route: npt.ArrayLike,
    labels: npt.NDArray[np.int32],
    *,
    radius: float = 0.3,
    near: float = 1.0,
    speckle_area: float = 0.01,
    every: float = 5.0,
    cover: float = 2.0,
    gap: float = 60.0,
    place: float = 1.0,
    view: float = 45.0,
    door_width: float = 1.2,
) -> Survey:
    """Measure a world, its route and its regions on ``plan`` (module notes).

    Parameters
    ----------
    plan : OccupancyMap
        The map the world was made on.
    world : World
        Its landmarks.
    route : array_like (T, 4)
        ``t, x, y, theta``, the true route.
    labels : ndarray of int32
        The regions (:func:`~sonarmap.team.regions.cut_regions`), -1 outside them, on
        ``plan``'s grid.
    radius : float
        The robot's radius, metres (0.3, as the routes).
    near : float
        Metres from a wall face to its nearest landmark that count as covered (1).
    speckle_area : float
        Occupied pieces under this many m^2 are specks (0.01).
    every : float
        Seconds between the route poses the camera is asked what it sees (5).
    cover : float
        Metres from the route that count as covered territory (2).
    gap, place, view : float
        A revisit: within ``place`` metres (1) and ``view`` degrees (45) of a pose at
        least ``gap`` seconds (60) earlier.
    door_width : float
        Widest opening a cut may span to lie at a door, metres (1.2, as the regions).

    Raises
    ------
    ConfigError
        A route that is not (T, 4) with T >= 2, or labels not on the plan's grid.
    """
    r = np.asarray(route, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 4 or len(r) < 2:
        raise ConfigError(f"a route is an array (T, 4) of t, x, y, theta, T >= 2; got {r.shape}")
    if labels.shape != plan.grid.shape:
        raise ConfigError(f"regions of shape {labels.shape} on a map of {plan.grid.shape}")
    territory = Territory.from_map(plan)
    # The territory is what the robot reaches from where it starts; a route starting
    # nowhere passable is measured against the largest reachable piece instead.
    r0, c0 = (int(v) for v in plan.grid.world_to_cell(r[0, 1], r[0, 2]))
    inside = plan.grid.contains(r0, c0) and bool(territory.passable(radius)[r0, c0])
    start = np.array([[r0, c0]], dtype=np.intp) if inside else None
    terr = reach(territory, radius, starts=start)
    speckle = speckle_mask(plan, speckle_area)
    facing = facing_cells(plan, radius, starts=start)
    kinds = landmark_kinds(plan, world.points[:, :2], facing, speckle)
    revisit, episodes = _revisits(r, gap, place, view)
    figures = _landmark_figures(plan, world, r, facing, speckle, kinds, near, every)
    figures.update(_route_figures(plan, r, terr, cover, revisit, episodes))
    regions, cut, at_door = _region_figures(labels, plan, terr, r, door_width)
    figures.update(regions)
    params = {"radius": radius, "near": near, "speckle_area": speckle_area, "cover": cover}
    params.update({"gap": gap, "place": place, "view": view, "door_width": door_width})
    return Survey(figures, kinds, revisit, terr, cut, at_door, params)


_KIND_COLOURS = ("tab:green", "magenta", "red", "orange")


def draw_survey(
    plan: OccupancyMap,
    world: World,
    route: npt.ArrayLike,
    s: Survey,
    path: str | Path,
    *,
    title: str = "",
    long_side: float = 9.0,
) -> Path:
    """A PNG of the survey: the map (territory white, free space outside it pale red,
    unknown pale blue), the region cuts (blue at a door, orange elsewhere), the
    landmarks by kind, the route (grey) and its revisits (black)."""
    r = np.asarray(route, dtype=np.float64)
    g = plan.grid
    cls = plan.classes()
    img = np.ones((*g.shape, 3))
    img[cls == UNKNOWN] = (0.80, 0.86, 0.93)
    img[(cls == FREE) & ~s.reach.watched] = (1.0, 0.85, 0.85)
    img[s.cut_cells & ~s.door_cells] = (1.0, 0.6, 0.0)
    img[s.door_cells] = (0.1, 0.3, 1.0)
    img[cls == OCCUPIED] = (0.0, 0.0, 0.0)
    # Only the part of the map that is not unknown (a SLAM map's grey margin is wide).
    rows, cols = np.nonzero(cls != UNKNOWN)
    if len(rows) == 0:
        rows, cols = np.array([0, g.rows - 1]), np.array([0, g.cols - 1])
    xs, ys = g.cell_centres(np.array([rows.max(), rows.min()]), np.array([cols.min(), cols.max()]))
    pad = 0.5 + g.resolution
    xlim, ylim = (xs[0] - pad, xs[1] + pad), (ys[0] - pad, ys[1] + pad)
    w, hgt = xlim[1] - xlim[0], ylim[1] - ylim[0]
    scale = long_side / max(w, hgt)
    fig, ax = plt.subplots(figsize=(max(3.0, w * scale), max(3.0, hgt * scale) + 0.8))
    ax.imshow(img, extent=g.extent, interpolation="nearest", origin="upper")
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.plot(r[:, 1], r[:, 2], "-", lw=0.4, color="0.5")
    rv = r[s.revisit]
    ax.plot(rv[:, 1], rv[:, 2], ".", ms=1.0, color="black")
    for i, colour in enumerate(_KIND_COLOURS):
        p = world.points[s.kinds == i]
        ax.plot(p[:, 0], p[:, 1], ".", ms=1.5, color=colour)
    handles = [
        Line2D([], [], ls="", marker=".", color=c, label=k)
        for k, c in zip(KINDS, _KIND_COLOURS, strict=True)
    ]
    handles += [
        Line2D([], [], color="0.5", label="route"),
        Line2D([], [], ls="", marker=".", color="black", label="revisits"),
        Line2D([], [], color=(0.1, 0.3, 1.0), label="cut at a door"),
        Line2D([], [], color=(1.0, 0.6, 0.0), label="other cut"),
    ]
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.08),
        ncol=4,
        fontsize="x-small",
        frameon=False,
    )
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title, fontsize="small")
    p = Path(path)
    atomic_write(p, lambda tmp: fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png"))
    plt.close(fig)
    return p
