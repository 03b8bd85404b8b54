"""The prior map cut into regions: rooms and corridors, identically on every robot.

Thesis 002 (chapter 2) asks for non-overlapping regions of the prior map, cut before
the mission by every robot alike, so that a pose's region names a part of the map before
the robots' own maps are aligned. It says nothing of how to cut; this module chooses
rooms and corridors, split where the free space narrows (doors):

1. The clearance of every free cell (distance to the nearest cell that is not free, or
   to the map's edge) by a distance transform.
2. Seeds: the connected pieces of the cells whose clearance exceeds half ``door_width``
   by a margin of one cell. An opening at most ``door_width`` wide has no such cell, so
   it separates the seeds of the spaces it joins; a room or a corridor wider than that
   keeps a core. A free component with no core (all of it narrower) is its own seed.
3. Growth: every free cell joins the seed nearest along 8-connected paths through free
   cells (a multi-source Dijkstra), so the boundary between two rooms falls in their
   door, where both are equally far. (``scipy.ndimage.watershed_ift`` on the inverted
   clearance was tried: its min-max path cost ties for every cell nearer a wall than the
   door's half width, and one room then leaks around the other's walls.)
4. A region larger than ``max_area`` (a big open hall with no narrow place) is cut into
   tiles of equal size on its bounding box, each at most ``max_area``.
5. Regions smaller than ``min_area`` (slivers, closets, pieces of tiles) merge into
   their largest neighbour, the smallest first; one with no neighbour (a closed pocket)
   into the region of the nearest free cell of another region.

Labels are numbered 0..K-1 in row-major order of each region's first cell; every step
is deterministic, so the same map gives the same cut on every robot.
"""

from __future__ import annotations

import heapq
import math

import numba as nb
import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..errors import ConfigError
from ..grid import Grid
from ..io.rosmap import FREE, OccupancyMap
from ..patrol.reach import reach
from ..patrol.territory import Territory

__all__ = [
    "clearance",
    "cut_regions",
    "mission_regions",
    "region_adjacency",
    "region_of",
    "region_sizes",
]

I32 = npt.NDArray[np.int32]
Mask = npt.NDArray[np.bool_]

_EIGHT = np.ones((3, 3), dtype=bool)


def _check_positive(**values: float) -> None:
    for name, v in values.items():
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"region parameter '{name}' must be > 0, got {v}")


def clearance(free: Mask, resolution: float) -> npt.NDArray[np.float64]:
    """Metres from each free cell's centre to the edge of the nearest cell that is not
    free (the map's edge counts as an obstacle); 0 outside the free space."""
    padded = np.pad(free, 1, constant_values=False)
    dist = np.asarray(ndimage.distance_transform_edt(padded))[1:-1, 1:-1] * resolution
    return np.where(free, dist - 0.5 * resolution, 0.0)


def _seeds(free: Mask, resolution: float, door_width: float) -> I32:
    """Seed labels 1..S (0 elsewhere): cores wider than a door, plus free components
    with no core."""
    core = free & (clearance(free, resolution) > 0.5 * door_width + resolution)
    seeds, n = ndimage.label(core, structure=_EIGHT)
    comps, m = ndimage.label(free, structure=_EIGHT)
    has_core = np.zeros(m + 1, dtype=bool)
    has_core[comps[core]] = True
    bare = ~has_core[comps] & free
    extra, _ = ndimage.label(bare, structure=_EIGHT)
    seeds = np.where(bare, extra + n, seeds)
    return np.asarray(seeds, dtype=np.int32)


@nb.njit(cache=True)
def _grow_kernel(
    free: npt.NDArray[np.bool_], label: npt.NDArray[np.int32], width: int
) -> npt.NDArray[np.int32]:
    # Multi-source Dijkstra on the padded flat grid; equal lengths go to the lower
    # label, so the result does not depend on the order cells are taken in.
    n = free.size
    dist = np.full(n, np.inf)
    out = label.copy()
    heap = [(0.0, np.int32(0), 0)]
    heap.pop()
    for u in range(n):
        if out[u] > 0:
            dist[u] = 0.0
            heap.append((0.0, out[u], u))
    heapq.heapify(heap)
    steps = np.array(
        [1, -1, width, -width, width + 1, width - 1, -width + 1, -width - 1], dtype=np.int64
    )
    diag = math.sqrt(2.0)
    while len(heap) > 0:
        d, lab, u = heapq.heappop(heap)
        if d > dist[u] or lab != out[u]:
            continue
        for j in range(8):
            v = u + steps[j]
            if not free[v]:
                continue
            nd = d + (1.0 if j < 4 else diag)
            if nd < dist[v] - 1e-9 or (abs(nd - dist[v]) <= 1e-9 and lab < out[v]):
                dist[v] = nd
                out[v] = lab
                heapq.heappush(heap, (nd, lab, v))
    return out


def _grow(free: Mask, seeds: I32) -> I32:
    """Every free cell labelled with its geodesically nearest seed."""
    pf = np.pad(free, 1, constant_values=False)
    pl = np.pad(seeds, 1, constant_values=0).astype(np.int32)
    out = _grow_kernel(pf.ravel(), pl.ravel(), pf.shape[1])
    return np.asarray(out.reshape(pf.shape)[1:-1, 1:-1], dtype=np.int32)


def _split_components(labels: I32) -> I32:
    """Each connected piece of each label its own label 1..K (0 stays 0)."""
    out = np.zeros_like(labels)
    nxt = 0
    for lab, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        pieces, k = ndimage.label(labels[box] == lab, structure=_EIGHT)
        sub = out[box]
        sub[pieces > 0] = pieces[pieces > 0] + nxt
        nxt += k
    return out


def _tile(labels: I32, resolution: float, max_area: float) -> I32:
    """Regions larger than ``max_area`` cut into equal tiles of their bounding box."""
    side = math.sqrt(max_area) / resolution
    out = labels.copy()
    nxt = int(labels.max())
    areas = np.bincount(labels.ravel())
    boxes = ndimage.find_objects(labels)
    for lab, box in enumerate(boxes, start=1):
        if box is None or areas[lab] * resolution**2 <= max_area:
            continue
        h = box[0].stop - box[0].start
        w = box[1].stop - box[1].start
        nr, nc = math.ceil(h / side), math.ceil(w / side)
        rr, cc = np.indices((h, w))
        tile = (rr * nr // h) * nc + cc * nc // w
        mine = labels[box] == lab
        pieces, k = ndimage.label(mine, structure=_EIGHT)
        # A tile's cells of this region may fall apart (an obstacle inside the tile):
        # one region per connected piece of (tile, piece).
        key = np.where(mine, tile * (k + 1) + pieces, -1)
        _, inv = np.unique(key[mine], return_inverse=True)
        sub = out[box]
        sub[mine] = inv.reshape(-1) + nxt + 1
        nxt += int(inv.max()) + 1
    return out


def _adjacency(labels: I32) -> dict[tuple[int, int], int]:
    """Pairs (a < b) of labels > 0 that touch (8-neighbours), with a count of contacts."""
    pairs: list[npt.NDArray[np.int64]] = []
    h, w = labels.shape
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        ca = slice(max(0, -dc), w - max(0, dc))
        cb = slice(max(0, dc), w - max(0, -dc))
        a = labels[: h - dr, ca]
        b = labels[dr:, cb]
        touch = (a > 0) & (b > 0) & (a != b)
        lo = np.minimum(a[touch], b[touch]).astype(np.int64)
        hi = np.maximum(a[touch], b[touch]).astype(np.int64)
        pairs.append(np.stack([lo, hi], axis=1))
    allp = np.concatenate(pairs)
    uniq, counts = np.unique(allp, axis=0, return_counts=True)
    return {(int(p[0]), int(p[1])): int(c) for p, c in zip(uniq, counts, strict=True)}


def _merge_small(labels: I32, resolution: float, min_area: float) -> I32:
    """Regions under ``min_area`` merged into their largest neighbour, smallest first."""
    n = int(labels.max())
    if n == 0:
        return labels
    area = np.bincount(labels.ravel(), minlength=n + 1).astype(np.float64) * resolution**2
    area[0] = np.inf
    neighbours: dict[int, set[int]] = {i: set() for i in range(1, n + 1)}
    for a, b in _adjacency(labels):
        neighbours[a].add(b)
        neighbours[b].add(a)
    parent = np.arange(n + 1)
    alive = set(range(1, n + 1))
    isolated: list[int] = []
    while True:
        small = [i for i in alive if area[i] < min_area]
        if not small:
            break
        i = min(small, key=lambda j: (area[j], j))
        alive.discard(i)
        nb_ = neighbours.pop(i)
        if not nb_:
            isolated.append(i)
            continue
        j = max(nb_, key=lambda k: (area[k], -k))
        parent[i] = j
        area[j] += area[i]
        for k in nb_:
            neighbours[k].discard(i)
            if k != j:
                neighbours[k].add(j)
                neighbours[j].add(k)
    # Resolve chains of merges to their final region.
    for i in range(1, n + 1):
        r = i
        while parent[r] != r:
            r = parent[r]
        parent[i] = r
    out = parent[labels].astype(np.int32)
    if isolated and alive:
        pocket = np.isin(labels, isolated)
        others = (out > 0) & ~pocket
        _, (ri, ci) = ndimage.distance_transform_edt(~others, return_indices=True)
        out[pocket] = out[ri[pocket], ci[pocket]]
    return out


def _renumber(labels: I32) -> I32:
    """Labels 0..K-1 by row-major order of each region's first cell; -1 elsewhere."""
    flat = labels.ravel()
    ids, first = np.unique(flat, return_index=True)
    keep = ids > 0
    ids, first = ids[keep], first[keep]
    order = ids[np.argsort(first)]
    table = np.full(int(labels.max()) + 1, -1, dtype=np.int32)
    table[order] = np.arange(len(order), dtype=np.int32)
    return table[labels]


def cut_regions(
    free: Mask,
    resolution: float,
    *,
    min_area: float = 4.0,
    door_width: float = 1.2,
    max_area: float = 400.0,
) -> I32:
    """Cut the free space of a prior map into regions (rooms, corridors, tiles).

    Parameters
    ----------
    free : ndarray of bool, shape (rows, cols)
        The prior map's free cells (row 0 at the top, as every sonarmap grid).
    resolution : float
        Cell side, metres.
    min_area : float
        Smallest region, m^2 (4): smaller pieces merge into their largest neighbour.
    door_width : float
        Widest opening that separates two regions, metres (1.2: the thesis is silent;
        doors are 0.7-1.2 m wide). A corridor no wider than this has no core of its own
        and is shared out among the spaces it joins.
    max_area : float
        Largest region, m^2 (400): a bigger one is cut into equal tiles of its bounding
        box. A tile that absorbs a sliver under ``min_area`` may exceed it by that much.

    Returns
    -------
    ndarray of int32, shape (rows, cols)
        Region 0..K-1 of every free cell, -1 elsewhere; numbered by the row-major order
        of each region's first cell.

    Examples
    --------
    >>> free = np.ones((40, 80), dtype=bool)
    >>> free[:, 39:41] = False
    >>> free[18:22, 39:41] = True  # a 0.4 m door
    >>> labels = cut_regions(free, 0.1, min_area=1.0)
    >>> int(labels.max()) + 1, int(labels[5, 5]), int(labels[5, 70])
    (2, 0, 1)
    """
    _check_positive(
        resolution=resolution, min_area=min_area, door_width=door_width, max_area=max_area
    )
    free = np.asarray(free, dtype=bool)
    if free.ndim != 2:
        raise ConfigError(f"free must be a 2-D mask, got shape {free.shape}")
    if not free.any():
        return np.full(free.shape, -1, dtype=np.int32)
    labels = _grow(free, _seeds(free, resolution, door_width))
    labels = _split_components(labels)
    labels = _tile(labels, resolution, max_area)
    labels = _merge_small(labels, resolution, min_area)
    return _renumber(labels)


def mission_regions(
    prior: OccupancyMap,
    radius: float = 0.3,
    min_area: float = 4.0,
    *,
    region: Mask | None = None,
) -> I32:
    """The regions a mission cuts its prior map into: :func:`cut_regions`, at the
    defaults, of the free cells a robot of ``radius`` metres (0.3) can be on.

    Those are :func:`~sonarmap.patrol.reach.reach`'s watched cells from every piece of
    the map where the robot fits and that covers at least ``min_area`` m^2 (4, the
    smallest region), not only the largest: a room the prior shows behind a closed
    door keeps its regions. Left in no region (-1, as obstacles): free cells no robot
    covers (a strip outside a wall, a SLAM map's specks of free) and pieces smaller than
    ``min_area`` (the inside of a shelf drawn as an outline). A map where the robot
    fits nowhere is cut on all its free cells.

    Parameters
    ----------
    prior : OccupancyMap
        The prior map.
    radius : float
        The robot's radius, metres (0.3).
    min_area : float
        Smallest piece kept and smallest region, m^2 (4).
    region : ndarray of bool, optional
        The mission's territory mask on the prior's cells (default None: the whole
        prior). The robot's centre stays inside it and no free cell outside it is in a
        region, so a drawn plan's free outside is not cut. When the robot fits nowhere
        inside it, its free cells are cut; when it holds no free cell, the whole prior
        is cut as without a mask (``team run`` and ``team node`` refuse such a prior).
    """
    free = prior.classes() == FREE
    if region is not None:
        region = np.asarray(region, dtype=bool)
        if region.shape != free.shape:
            raise ValueError(f"a territory mask of {region.shape} for a prior of {free.shape}")
        if not (free & region).any():
            region = None
    terr = Territory.from_map(prior)
    ok = terr.passable(radius)
    if region is not None:
        ok = ok & region
    pieces, n = ndimage.label(ok, structure=_EIGHT)
    if n == 0:
        return cut_regions(free if region is None else free & region, prior.grid.resolution)
    ids, first = np.unique(pieces.ravel(), return_index=True)
    starts = np.column_stack(np.unravel_index(first[ids > 0], ok.shape)).astype(np.intp)
    watched = reach(terr, radius, starts=starts, region=region).watched
    parts, m = ndimage.label(watched, structure=_EIGHT)
    area = np.bincount(parts.ravel(), minlength=m + 1) * prior.grid.resolution**2
    big = area >= min_area
    big[0] = False
    if big.any():
        watched = big[parts]
    return cut_regions(watched, prior.grid.resolution)


def region_sizes(labels: I32, resolution: float) -> npt.NDArray[np.float64]:
    """Area (m^2) of each region 0..K-1."""
    k = int(labels.max()) + 1
    return np.bincount(labels[labels >= 0], minlength=k).astype(np.float64) * resolution**2


def region_of(labels: I32, grid: Grid, x: float, y: float) -> int:
    """The region of world point (x, y): that of its cell, or, on an obstacle or off the
    map, that of the nearest free cell (the first in row-major order among equals).

    Raises
    ------
    ValueError
        When ``labels`` has no region at all.
    """
    if labels.shape != grid.shape:
        raise ValueError(f"labels of shape {labels.shape} on a grid of {grid.shape}")
    r, c = (int(v) for v in grid.world_to_cell(x, y))
    if grid.contains(r, c) and labels[r, c] >= 0:
        return int(labels[r, c])
    rows, cols = np.nonzero(labels >= 0)
    if len(rows) == 0:
        raise ValueError("the map has no region")
    k = int(np.argmin((rows - r) ** 2 + (cols - c) ** 2))
    return int(labels[rows[k], cols[k]])


def region_adjacency(labels: I32) -> dict[int, set[int]]:
    """Which regions touch: two regions are adjacent when a cell of one shares a side
    with a cell of the other (4-neighbour contact; a corner alone does not count).

    Parameters
    ----------
    labels : ndarray of int, shape (rows, cols)
        Regions 0..K-1, negative elsewhere (as :func:`cut_regions` gives).

    Returns
    -------
    dict of int to set of int
        Every region present, each with the set of its neighbours (empty for one that
        touches no other); symmetric.

    Examples
    --------
    >>> labels = np.array([[0, 0, 1], [2, -1, 1], [2, 3, 3]], dtype=np.int32)
    >>> region_adjacency(labels)
    {0: {1, 2}, 1: {0, 3}, 2: {0, 3}, 3: {1, 2}}
    """
    lab = np.asarray(labels)
    if lab.ndim != 2 or not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels must be a 2-D integer array, got {lab.dtype} {lab.shape}")
    out: dict[int, set[int]] = {int(r): set() for r in np.unique(lab[lab >= 0])}
    for a, b in ((lab[:, :-1], lab[:, 1:]), (lab[:-1, :], lab[1:, :])):
        touch = (a >= 0) & (b >= 0) & (a != b)
        if not touch.any():
            continue
        pairs = np.unique(np.stack([a[touch], b[touch]], axis=1), axis=0)
        for i, j in pairs.tolist():
            out[int(i)].add(int(j))
            out[int(j)].add(int(i))
    return out
