"""The patrol graph: the places the patrolling literature measures, derived from the map.

Graph patrolling (patrolling_sim, Chevaleyre 2004, Portugal and Rocha 2011) counts visits
to the vertices of a graph; the potential field watches every cell. To measure both on
the same places, the vertices here are the offline tour's lattice (:mod:`.tour`):
points on a square lattice of spacing vision * sqrt(2), so that every place is within
the vision radius of one, each moved to the nearest cell a robot's centre may be on.
Moving a point can break that guarantee near walls, so cells it leaves unwatched get
vertices of their own.

Edges follow the map's topology, not straight lines: every cell takes the label of the
vertex nearest along the grid's 8-connected paths (the wave's metric, a multi-source
Dijkstra), and two vertices are neighbours when their regions touch, i.e. some step of
the grid leads from one region into the other. A wall between two regions has no such
step, a doorway has, so edges run through doors and never across walls; a connected
passable region gives a connected graph. An edge's length is the wave's path length
between its two vertices, in metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ..errors import InputError
from ..grid import Grid
from .paths import Wave
from .territory import Territory

__all__ = ["PatrolGraph", "cell_graph", "lattice_cells", "reachable_cells"]

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]


def lattice_cells(territory: Territory, passable: B, vision: float) -> I64:
    """The lattice points of the offline tour, moved onto passable cells.

    Parameters
    ----------
    territory : Territory
    passable : ndarray of bool, shape territory.grid.shape
        Cells a robot's centre may be on.
    vision : float
        Vision radius, metres. The lattice's spacing is vision * sqrt(2) (whole cells,
        at least one), spread evenly over each side of the map.

    Returns
    -------
    ndarray of int64, shape (K, 2)
        Distinct (row, column) cells, row-major order of their lattice points. A point
        with no free cell within half a spacing is dropped; the others move to the
        nearest passable cell (Euclidean), which may lie in another room.
    """
    g = territory.grid
    step = max(1, math.floor(vision * math.sqrt(2) / g.resolution))
    # The nearest passable cell of every cell (an index map from the distance transform).
    _, (near_r, near_c) = ndimage.distance_transform_edt(~passable, return_indices=True)
    # Lattice lines spread evenly over each side, at most ``step`` apart, so that the
    # map's edges are within reach too.
    rows = ((np.arange(math.ceil(g.rows / step)) + 0.5) * g.rows / math.ceil(g.rows / step)).astype(
        int
    )
    cols = ((np.arange(math.ceil(g.cols / step)) + 0.5) * g.cols / math.ceil(g.cols / step)).astype(
        int
    )
    half = step // 2 + 1
    out: list[tuple[int, int]] = []
    for r in rows.tolist():
        for c in cols.tolist():
            if not territory.free[
                max(0, r - half) : r + half + 1, max(0, c - half) : c + half + 1
            ].any():
                continue  # nothing to watch around this lattice point
            rr, cc = int(near_r[r, c]), int(near_c[r, c])
            if (rr, cc) not in out:
                out.append((rr, cc))
    return np.array(out, dtype=np.int64).reshape(-1, 2)


def cell_graph(mask: B, resolution: float, *, corners: bool = False) -> tuple[csr_matrix, I64]:
    """The wave's grid graph on the cells of ``mask``, as a sparse matrix.

    Steps of one cell (``resolution`` metres) to the 4 side neighbours and of sqrt(2)
    cells to the diagonal ones, a diagonal only when both cells beside it are in
    ``mask`` too (no cutting of corners, as :func:`~sonarmap.patrol.paths.wave`), unless
    ``corners`` (default False): then every diagonal between two cells of ``mask``, as
    along a one-cell-wide skeleton, whose diagonal steps have no cells beside them.

    Returns
    -------
    graph : scipy.sparse.csr_matrix, shape (n, n)
        Symmetric step lengths in metres between the ``n`` cells of ``mask``.
    index : ndarray of int64, shape mask.shape
        Node of every cell of ``mask`` (row-major order), -1 elsewhere.
    """
    mask = np.ascontiguousarray(mask, dtype=np.bool_)
    index = np.full(mask.shape, -1, dtype=np.int64)
    n = int(mask.sum())
    index[mask] = np.arange(n)
    degree = _degrees(mask, corners)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(degree, out=indptr[1:])
    nnz = int(indptr[-1])
    # scipy's own choice of index type for such a matrix (as coo_matrix.tocsr makes it).
    kind = np.int32 if max(nnz, n) <= np.iinfo(np.int32).max else np.int64
    indices: npt.NDArray[np.integer[Any]] = np.empty(nnz, dtype=kind)
    data = np.empty(nnz, dtype=np.float64)
    _fill_edges(mask, index, corners, resolution, resolution * math.sqrt(2.0), indices, data)
    graph = csr_matrix((data, indices, indptr.astype(kind)), shape=(n, n))
    return graph, index


@nb.njit(cache=True)
def _neighbour_ok(mask: B, r: int, c: int, dr: int, dc: int, corners: bool) -> bool:
    # Whether cell (r, c) of ``mask`` has an edge to (r + dr, c + dc) in cell_graph.
    rows, cols = mask.shape
    rr, cc = r + dr, c + dc
    if rr < 0 or rr >= rows or cc < 0 or cc >= cols or not mask[rr, cc]:
        return False
    if dr != 0 and dc != 0 and not corners:
        return bool(mask[r, cc]) and bool(mask[rr, c])
    return True


@nb.njit(cache=True)
def _degrees(mask: B, corners: bool) -> I64:
    """Edges of each cell of ``mask`` (row-major) in :func:`cell_graph`."""
    rows, cols = mask.shape
    out = np.zeros(rows * cols, dtype=np.int64)
    n = 0
    for r in range(rows):
        for c in range(cols):
            if not mask[r, c]:
                continue
            k = 0
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    if (dr != 0 or dc != 0) and _neighbour_ok(mask, r, c, dr, dc, corners):
                        k += 1
            out[n] = k
            n += 1
    return out[:n].copy()


@nb.njit(cache=True)
def _fill_edges(
    mask: B,
    index: I64,
    corners: bool,
    side: float,
    diagonal: float,
    indices: npt.NDArray[np.integer[Any]],
    data: F64,
) -> None:
    """:func:`cell_graph`'s CSR columns and step lengths, each row's in rising order
    of the neighbour's node (row-major: the 8 neighbours from the upper left)."""
    rows, cols = mask.shape
    p = 0
    for r in range(rows):
        for c in range(cols):
            if not mask[r, c]:
                continue
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    if (dr != 0 or dc != 0) and _neighbour_ok(mask, r, c, dr, dc, corners):
                        indices[p] = index[r + dr, c + dc]
                        data[p] = diagonal if dr != 0 and dc != 0 else side
                        p += 1


def reachable_cells(passable: B, starts: Sequence[tuple[int, int]], resolution: float = 1.0) -> B:
    """The passable cells a robot's centre can reach from any of ``starts`` (passable
    (row, column) cells) along the wave's steps."""
    graph, index = cell_graph(passable, resolution)
    _, comp = connected_components(graph, directed=False)
    keep: set[int] = set()
    for r, c in starts:
        node = int(index[int(r), int(c)])
        if node < 0:
            raise InputError(f"start cell ({r}, {c}) is not passable")
        keep.add(int(comp[node]))
    out = np.zeros(passable.shape, dtype=bool)
    out[passable] = np.isin(comp, sorted(keep))
    return out


def _cover(mask: B, grid: Grid, cells: I64, vision: float) -> I64:
    """``cells`` and, in row-major order, vertices for the cells of ``mask`` no vertex
    has within ``vision`` metres (each placed at the cell of ``mask`` nearest the middle
    of the unwatched cells around the first one left, or on that cell itself)."""
    rr, cc = np.nonzero(mask)
    x, y = grid.cell_centres(rr, cc)
    pts = np.column_stack([x, y])
    tree_all = cKDTree(pts)
    # Cell centres are exact multiples of the cell: a hair of slack keeps a cell exactly
    # at the vision radius watched, as the fog's disc does.
    reach = vision + 1e-9 * max(1.0, vision)
    out = [(int(r), int(c)) for r, c in cells.tolist()]
    vx, vy = grid.cell_centres(cells[:, 0], cells[:, 1])
    if len(cells):
        d, _ = cKDTree(np.column_stack([vx, vy])).query(pts, distance_upper_bound=reach)
        watched = np.isfinite(d)
    else:
        watched = np.zeros(len(pts), dtype=bool)

    def mark(k: int) -> None:
        watched[tree_all.query_ball_point(pts[k], reach)] = True

    while not watched.all():
        u = int(np.argmin(watched))  # the first unwatched cell, row-major
        near = np.array(tree_all.query_ball_point(pts[u], reach), dtype=np.int64)
        near = near[~watched[near]]
        _, k = tree_all.query(pts[near].mean(axis=0))
        if np.hypot(*(pts[int(k)] - pts[u])) > reach:
            k = u
        out.append((int(rr[int(k)]), int(cc[int(k)])))
        mark(int(k))
    return np.array(out, dtype=np.int64).reshape(-1, 2)


@dataclass(frozen=True, eq=False)
class PatrolGraph:
    """A patrol graph on a territory's passable cells (see the module's notes).

    Attributes
    ----------
    grid : Grid
        The territory's grid, on which ``cells`` lie.
    cells : ndarray of int64, shape (V, 2)
        Row and column of each vertex (a passable cell).
    xy : ndarray of float64, shape (V, 2)
        World position of each vertex (its cell's centre), metres.
    neighbours : list of ndarray of int64
        Vertex i's neighbours, ascending.
    lengths : list of ndarray of float64
        Path length to each of ``neighbours[i]`` (aligned), metres: the wave's shortest
        8-connected path over the graph's cells, at least the straight distance.
    spacing : float
        The lattice's spacing, metres (vision * sqrt(2) in whole cells).
    vision : float
        The vision radius the lattice was built for, metres.
    region : ndarray of int64, shape grid.shape
        The vertex nearest each cell of the graph along the grid's paths (its geodesic
        Voronoi region), -1 on cells outside the graph.
    """

    grid: Grid
    cells: I64
    xy: F64
    neighbours: list[I64]
    lengths: list[F64]
    spacing: float
    vision: float
    region: I64

    @classmethod
    def from_territory(
        cls,
        territory: Territory,
        passable: B,
        vision: float,
        reachable: B | None = None,
        *,
        starts: Sequence[tuple[int, int]] | None = None,
        cover: bool = True,
    ) -> PatrolGraph:
        """The patrol graph of a territory.

        Parameters
        ----------
        territory : Territory
        passable : ndarray of bool, shape territory.grid.shape
            Cells a robot's centre may be on (``territory.passable(radius)``).
        vision : float
            Vision radius, metres (> 0); sets the lattice's spacing.
        reachable : ndarray of bool, optional
            Keep only these cells (intersected with ``passable``); default all passable
            cells.
        starts : sequence of (row, column), optional
            Keep only the cells reachable from these passable cells (with
            ``reachable``, from them within it).
        cover : bool
            Add vertices for the kept cells that no lattice vertex has within
            ``vision`` metres, so that every kept cell is (default True). False keeps
            the tour's lattice alone.

        Returns
        -------
        PatrolGraph
            Deterministic: the same inputs give the same graph. Its vertices are the
            lattice's (restricted to the kept cells) in the lattice's order, then any
            added ones; every component of the kept cells holds at least one vertex.
        """
        if not (math.isfinite(vision) and vision > 0):
            raise InputError(f"vision must be > 0 metres, got {vision}")
        g = territory.grid
        mask = np.asarray(passable, dtype=bool).copy()
        if reachable is not None:
            mask &= np.asarray(reachable, dtype=bool)
        if starts is not None:
            mask &= reachable_cells(mask, starts, g.resolution)
        if not mask.any():
            raise InputError("no passable place to patrol")
        graph, index = cell_graph(mask, g.resolution)
        lattice = lattice_cells(territory, passable, vision)
        lattice = lattice[mask[lattice[:, 0], lattice[:, 1]]]
        # A component of the kept cells the lattice missed (a small room whose lattice
        # point moved elsewhere) gets a vertex on its cell nearest its middle, so no
        # robot can be somewhere with nothing to patrol.
        n_comp, comp = connected_components(graph, directed=False)
        has = np.zeros(n_comp, dtype=bool)
        has[comp[index[lattice[:, 0], lattice[:, 1]]]] = True
        rr, cc = np.nonzero(mask)
        extra = []
        for k in np.flatnonzero(~has).tolist():
            mine = np.flatnonzero(comp == k)
            mid = np.array([rr[mine].mean(), cc[mine].mean()])
            j = mine[int(np.argmin(np.hypot(rr[mine] - mid[0], cc[mine] - mid[1])))]
            extra.append((int(rr[j]), int(cc[j])))
        cells = np.concatenate([lattice, np.array(extra, dtype=np.int64).reshape(-1, 2)])
        if cover:
            cells = _cover(mask, g, cells, vision)
        nodes = index[cells[:, 0], cells[:, 1]]
        dist, _, source = dijkstra(
            graph, directed=False, indices=nodes, min_only=True, return_predecessors=True
        )
        vertex_of_node = np.full(graph.shape[0], -1, dtype=np.int64)
        vertex_of_node[nodes] = np.arange(len(nodes))
        label = np.where(source >= 0, vertex_of_node[np.maximum(source, 0)], -1)
        region = np.full(mask.shape, -1, dtype=np.int64)
        region[mask] = label
        neighbours, lengths = _edges(graph, label, dist, cells, mask, g.resolution)
        x, y = g.cell_centres(cells[:, 0], cells[:, 1])
        step = max(1, math.floor(vision * math.sqrt(2) / g.resolution))
        return cls(
            grid=g,
            cells=cells,
            xy=np.column_stack([x, y]),
            neighbours=neighbours,
            lengths=lengths,
            spacing=step * g.resolution,
            vision=float(vision),
            region=region,
        )

    def __len__(self) -> int:
        return len(self.cells)

    def edges(self) -> tuple[I64, F64]:
        """Every edge once: (E, 2) vertex pairs (i < j, row-major order) and their
        lengths in metres."""
        pairs = [
            (i, int(j), float(d))
            for i, (nb, ln) in enumerate(zip(self.neighbours, self.lengths, strict=True))
            for j, d in zip(nb.tolist(), ln.tolist(), strict=True)
            if j > i
        ]
        ij = np.array([p[:2] for p in pairs], dtype=np.int64).reshape(-1, 2)
        return ij, np.array([p[2] for p in pairs], dtype=np.float64)

    def to_csgraph(self) -> csr_matrix:
        """The graph as a symmetric sparse matrix of edge lengths (metres), for
        :mod:`scipy.sparse.csgraph`."""
        ij, d = self.edges()
        n = len(self)
        src = np.concatenate([ij[:, 0], ij[:, 1]])
        dst = np.concatenate([ij[:, 1], ij[:, 0]])
        return coo_matrix(
            (np.concatenate([d, d]), (src, dst)),
            shape=(n, n),
        ).tocsr()

    def components(self) -> I64:
        """Component number of every vertex (0, 1, ... in order of first vertex)."""
        _, comp = connected_components(self.to_csgraph(), directed=False)
        return np.asarray(comp, dtype=np.int64)

    def connected(self) -> bool:
        """Whether every vertex can be reached from every other along edges."""
        return len(self) <= 1 or int(self.components().max()) == 0


def _edges(
    graph: csr_matrix, label: I64, dist: F64, cells: I64, mask: B, resolution: float
) -> tuple[list[I64], list[F64]]:
    """Neighbours (regions that touch) and their path lengths (metres)."""
    n_vert = len(cells)
    coo = graph.tocoo()
    a, b = label[coo.row], label[coo.col]
    cross = (a >= 0) & (b >= 0) & (a < b)
    lo, hi = a[cross], b[cross]
    # A path from one vertex through the touching step to the other: an upper bound of
    # their distance, and so the limit of the exact wave from the first.
    via = dist[coo.row[cross]] + coo.data[cross] + dist[coo.col[cross]]
    key = lo * n_vert + hi
    order = np.lexsort((via, key))
    key, via = key[order], via[order]
    first = np.ones(len(key), dtype=bool)
    first[1:] = key[1:] != key[:-1]
    key, bound = key[first], via[first]
    pi, pj = key // n_vert, key % n_vert
    length = np.empty(len(key))
    waver = Wave(mask.shape)
    for i in np.unique(pi).tolist():
        mine = np.flatnonzero(pi == i)
        limit = float(bound[mine].max()) * (1 + 1e-9)
        far, _ = waver(mask, (int(cells[i, 0]), int(cells[i, 1])), resolution, limit=limit)
        length[mine] = far[cells[pj[mine], 0], cells[pj[mine], 1]]
    neighbours: list[list[int]] = [[] for _ in range(n_vert)]
    lengths: list[list[float]] = [[] for _ in range(n_vert)]
    for i, j, d in zip(pi.tolist(), pj.tolist(), length.tolist(), strict=True):
        neighbours[i].append(j)
        lengths[i].append(d)
        neighbours[j].append(i)
        lengths[j].append(d)
    out_n: list[I64] = []
    out_l: list[F64] = []
    for nbrs, ln in zip(neighbours, lengths, strict=True):
        o = np.argsort(nbrs, kind="stable")
        out_n.append(np.asarray(nbrs, dtype=np.int64)[o])
        out_l.append(np.asarray(ln, dtype=np.float64)[o])
    return out_n, out_l
