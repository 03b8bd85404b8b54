"""One-way streets: a direction for every street too narrow for a car to turn round in.

Where a street is narrower than a car's turning circle, two cars meeting head-on, or a
car whose next place lies behind it, must reverse. Real traffic avoids this with a
one-way street system, and so can the cars here, each deriving the same system from the
map alone (no messages, deterministic):

1. **Street graph.** The passable cells are thinned to their skeleton (Zhang and Suen's
   thinning); skeleton cells with three or more skeleton neighbours are junctions
   (8-connected groups of them one junction each), cells with one are ends. The skeleton
   with its junctions removed falls into segments: the streets, edges between the
   junctions (or an end) they touch; a ring of streets with no junction is cut at its
   first cell, a junction of its own, and a segment looping back to its own junction
   within that junction's reach (a corner spur of the thinning) joins the junction.
   Every passable cell belongs to the skeleton cell
   nearest it along the grid's paths, and so to a street or a junction.
2. **Orientation** (Robbins' theorem): a street graph has a strongly connected
   orientation iff it is 2-edge-connected. Bridges (dead-end stubs, a lone street to a
   part of the map) stay two-way; every other street is directed by a depth-first
   search, tree edges away from the root and the others back towards it, which makes
   each 2-edge-connected part strongly connected. Streets as wide as the turning circle
   (twice their median clearance at least ``2 * turn_radius``) are then opened both ways
   again, which keeps every place reachable from every other.
   With ``orient`` 'short' (:func:`one_way`) the depth-first directions are only the
   start of a local search that shortens the detours (:func:`_shorten`): each street
   becomes a node at its midpoint, halfway along it, and the search flips one-way
   streets, one at a time or a directed cycle at a time, while the summed shortest path
   between the midpoints, each pair weighted by the two streets' lengths, falls. A flip
   that leaves a midpoint unreachable from another is never taken, so every
   orientation it passes through is strongly connected; it is deterministic and
   bounded (:data:`SHORT_PASSES` passes over the streets).
4. **Check.** The skeleton is 8-connected and may cross a diagonal-only pinch of the
   passable cells that the wave's steps (no cutting of corners) cannot, so the street
   graph can differ from the wave's. The allowed steps are therefore checked on the
   wave's own step rule (:func:`strong_sets`): while some passable cells are not in the
   largest strongly connected set of their (two-way) connected part, the one-way streets
   on them and next to them are opened both ways again, and the check repeats (at most
   once per street, and the last resort opens every street of that part).
3. **Allowed steps.** A one-way street's cells carry their distance along it from its
   tail (:attr:`OneWay.along`). The wave's step from one of them to another of the same
   street must not lower that distance by more than half a cell (the nearest skeleton
   cell of neighbouring cells may jitter by a cell across the street, never by one step
   against it). Junction cells, and a street's cells within its junction's reach of
   either end (the largest clearance on the junction's skeleton cells, plus a cell) are
   two-way, so that a car turns from one street into another through the junction.

The result is a mask of allowed steps per cell for :class:`~sonarmap.patrol.paths.Wave`
(bit j of a cell: step :data:`~sonarmap.patrol.paths.STEPS` [j] out of it is allowed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import networkx as nx
import numba as nb
import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from .graph import cell_graph
from .paths import STEPS

__all__ = ["ORIENTS", "OneWay", "Search", "one_way", "strong_sets", "thin"]

B = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]

#: Every step allowed (the mask of a two-way cell).
ALL_STEPS = 255
#: Slack, in cells, of a step within a one-way street against its direction: the nearest
#: skeleton cell of two neighbouring cells differs by at most about a cell across a
#: street, while a step against it lowers the distance along it by a whole cell.
ALONG_SLACK = 0.5
#: The orientations of the one-way streets (:func:`one_way`'s ``orient``): 'dfs', any
#: strongly connected one (a depth-first search's); 'short', that one improved by a
#: local search for shorter detours (:func:`_shorten`).
ORIENTS = ("dfs", "short")
#: Most passes of the local search over the one-way streets (:func:`_shorten`); each
#: pass tries every street's two flips once. A pass with no flip taken ends it sooner.
SHORT_PASSES = 20


@nb.njit(cache=True)
def _thin_pass(img: npt.NDArray[np.uint8], first: bool) -> bool:
    """One sub-iteration of Zhang-Suen thinning on ``img`` (0/1, a zero border), in
    place; True when it removed a cell."""
    rows, cols = img.shape
    remove = []
    for r in range(1, rows - 1):
        for c in range(1, cols - 1):
            if img[r, c] == 0:
                continue
            # Neighbours P2..P9 clockwise from north.
            p = (
                img[r - 1, c],
                img[r - 1, c + 1],
                img[r, c + 1],
                img[r + 1, c + 1],
                img[r + 1, c],
                img[r + 1, c - 1],
                img[r, c - 1],
                img[r - 1, c - 1],
            )
            b = 0
            for k in range(8):
                b += p[k]
            if b < 2 or b > 6:
                continue
            a = 0
            for k in range(8):
                if p[k] == 0 and p[(k + 1) % 8] == 1:
                    a += 1
            if a != 1:
                continue
            if first:
                if p[0] * p[2] * p[4] != 0 or p[2] * p[4] * p[6] != 0:
                    continue
            elif p[0] * p[2] * p[6] != 0 or p[0] * p[4] * p[6] != 0:
                continue
            remove.append((r, c))
    for r, c in remove:
        img[r, c] = 0
    return len(remove) > 0


def thin(mask: B) -> B:
    """The skeleton of ``mask`` (Zhang and Suen 1984): one cell wide, 8-connected,
    keeping the topology of each component (a loop of streets stays a loop)."""
    img = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2), dtype=np.uint8)
    img[1:-1, 1:-1] = mask
    # Each pass removes at least one layer of cells: bounded by the mask's size.
    for _ in range(max(mask.shape) + 1):
        a = _thin_pass(img, True)
        b = _thin_pass(img, False)
        if not (a or b):
            break
    out: B = img[1:-1, 1:-1].astype(bool)
    return out


@dataclass(frozen=True)
class Search:
    """What the 'short' orientation's local search (:func:`_shorten`) did on the street
    graph, in its own model (streets as midpoint nodes; see the module's notes).

    Attributes
    ----------
    streets : int
        One-way streets the search could flip.
    flipped : int
        Of them, those it left directed against the depth-first direction.
    before, after : float
        The model's summed one-way over two-way shortest path between the midpoints
        (each pair weighted by the two streets' lengths) at the depth-first directions
        and at the search's; inf when the depth-first directions leave a pair unjoined,
        1.0 with no one-way street.
    """

    streets: int
    flipped: int
    before: float
    after: float


@dataclass(frozen=True)
class OneWay:
    """A one-way street system on a grid (see the module's notes).

    Attributes
    ----------
    steps : ndarray of uint8, shape grid
        Allowed steps out of each cell: bit j for :data:`~sonarmap.patrol.paths.STEPS`
        [j]; 255 on two-way cells and off the passable cells.
    street : ndarray of int64, shape grid
        The street each passable cell belongs to; -1 on junctions and elsewhere.
    along : ndarray of float64, shape grid
        Distance along its street from its tail, cells; NaN off the one-way streets.
    one_way : ndarray of bool, shape (streets,)
        Which streets are one-way.
    widths : ndarray of float64, shape (streets,)
        Each street's width, metres (twice the median clearance on its skeleton).
    bridges : ndarray of bool, shape (streets,)
        Which streets are left two-way as bridges of the street graph, and the streets
        not in it (``in_graph`` False), which are left two-way too.
    stubs : ndarray of bool, shape (streets,)
        The dead-end stubs: streets of the street graph that are bridges of it with a
        side holding no cycle of streets (a dead end, which a car that drives in leaves
        the way it came), narrower than the turning circle (``widths`` below
        ``2 * turn_radius``), so that a car must reverse to leave.
    in_graph : ndarray of bool, shape (streets,)
        Which streets are edges of the street graph: False for a segment touching no
        junction or three of them.
    two_way : ndarray of bool, shape grid
        Passable cells where the street's direction does not hold: junctions, cells of
        two-way streets, and a one-way street's cells within its junction's reach of
        either end. Every step between two of them is allowed (a step from one of them
        into the one-way part of a street still keeps to its direction).
    stub_ends : ndarray of bool, shape grid
        The passable cells of the junctions that lie beyond a stub (cut off by it
        from every cycle of streets) and whose streets are all stubs: where a dead end
        bends or branches, or the thinning forks at its far end, the graph makes a
        junction there, whose cells belong to no street but are as much a dead end.
        A junction touched by a street that is no stub (one a car turns round in, or
        one left out of the street graph) is none.
    search : Search or None
        With ``orient`` 'short' (:func:`one_way`), what its local search did; None with
        'dfs' (the default).
    """

    steps: npt.NDArray[np.uint8]
    street: I64
    along: F64
    one_way: B
    widths: F64
    bridges: B
    stubs: B
    in_graph: B
    two_way: B
    stub_ends: B
    search: Search | None = None

    @property
    def share(self) -> float:
        """Share of the streets' cells that lie on one-way streets (0 without streets)."""
        on = self.street >= 0
        if not on.any():
            return 0.0
        return float(self.one_way[self.street[on]].mean())


def _orient(n_nodes: int, ends: list[tuple[int, int]]) -> tuple[B, B]:
    """Directions of a multigraph's edges ``ends`` (u, v) over nodes 0..n-1: True when
    an edge keeps u -> v, False when reversed; and which edges are bridges. Non-bridge
    edges get a strongly connected orientation of each 2-edge-connected part (depth
    first from the lowest node: tree edges away from the root, the others back)."""
    g = nx.MultiGraph()
    g.add_nodes_from(range(n_nodes))
    for k, (u, v) in enumerate(ends):
        g.add_edge(u, v, key=k)
    bridge = np.zeros(len(ends), dtype=bool)
    pairs = {frozenset(e) for e in nx.bridges(g)}
    for k, (u, v) in enumerate(ends):
        # A bridge is never a loop nor one of parallel edges (nx.bridges sees to both).
        if u != v and frozenset((u, v)) in pairs:
            bridge[k] = True
    forward = np.ones(len(ends), dtype=bool)
    incident: list[list[int]] = [[] for _ in range(n_nodes)]
    for k, (u, v) in enumerate(ends):
        if not bridge[k]:
            incident[u].append(k)
            if v != u:
                incident[v].append(k)
    used = np.zeros(len(ends), dtype=bool)
    seen = np.zeros(n_nodes, dtype=bool)
    for root in range(n_nodes):
        if seen[root]:
            continue
        seen[root] = True
        stack = [(root, iter(sorted(incident[root])))]
        while stack:
            u, it = stack[-1]
            nxt: int | None = next(it, None)
            if nxt is None:
                stack.pop()
                continue
            if used[nxt]:
                continue
            used[nxt] = True
            a, b = ends[nxt]
            v = b if a == u else a
            # Leaving u: a tree edge to a new node, or (an undirected depth-first search
            # has no cross edges) a back edge to an ancestor still on the stack.
            forward[nxt] = a == u
            if not seen[v]:
                seen[v] = True
                stack.append((v, iter(sorted(incident[v]))))
    return forward, bridge


def _midpoint_graph(
    n_nodes: int, ends: I64, half: F64, forward: B, directed: B
) -> tuple[csr_matrix, I64]:
    """The street graph with each edge ``ends`` [k] split at a midpoint node
    ``n_nodes + k``, ``half`` [k] from either end: a ``directed`` edge one way (u -> v
    when ``forward``), any other both ways; and the midpoints' node numbers."""
    k = np.arange(len(ends), dtype=np.int64)
    mid = n_nodes + k
    tail = np.where(forward, ends[:, 0], ends[:, 1])
    head = np.where(forward, ends[:, 1], ends[:, 0])
    # A loop's two halves already go both ways; listed again, csr_matrix would sum them.
    two = ~directed & (tail != head)
    rows = np.concatenate([tail, mid, head[two], mid[two]])
    cols = np.concatenate([mid, head, mid[two], tail[two]])
    w = np.concatenate([half, half, half[two], half[two]])
    n = n_nodes + len(ends)
    graph = csr_matrix((w, (rows, cols)), shape=(n, n))
    return graph, mid


def _detour_cost(graph: csr_matrix, mid: I64, weight: F64, pairs: B) -> float:
    """Summed shortest path of ``graph`` between its midpoints ``mid`` over the
    ``pairs`` (the pairs joined two-way), each weighted by ``weight`` of both ends;
    inf when a pair has no path (the orientation is not strongly connected)."""
    d = dijkstra(graph, directed=True, indices=mid)[:, mid]
    d = d[pairs]
    if not np.isfinite(d).all():
        return math.inf
    return float((d * np.outer(weight, weight)[pairs]).sum())


def _cycle_back(graph: csr_matrix, n_nodes: int, head: int, tail: int) -> list[int]:
    """The edges (midpoint ``n_nodes + k``) of ``graph``'s shortest path from node
    ``head`` to node ``tail``; empty when there is none."""
    _, pred = dijkstra(graph, directed=True, indices=head, return_predecessors=True)
    out: list[int] = []
    at = tail
    # A path visits each node at most once: bounded by the graph's size.
    for _ in range(graph.shape[0]):
        if at == head:
            return out
        at = int(pred[at])
        if at < 0:
            return []
        if at >= n_nodes:
            out.append(at - n_nodes)
    return []


def _shorten(
    n_nodes: int, ends: list[tuple[int, int]], length: F64, forward: B, directed: B
) -> tuple[B, float, float]:
    """A strongly connected orientation of the ``directed`` edges ``ends`` (u, v) of a
    multigraph over nodes 0..n-1 with shorter detours than ``forward`` (True: u -> v),
    itself strongly connected on each connected part: a local search (see the module's
    notes) minimising the summed shortest path between the edges' midpoints, each pair
    weighted by the two edges' ``length`` (the other edges two-way).

    Each pass visits the directed edges in order and tries, for each, flipping it alone
    and flipping the directed cycle it closes with the shortest path back from its head
    to its tail; a try is taken when it lowers the sum (by more than a relative 1e-9) and
    keeps every pair joined. At most :data:`SHORT_PASSES` passes, fewer when one takes
    nothing. Deterministic: the same input gives the same directions.

    Cost: each try runs a shortest-path search from every midpoint, so with s directed
    edges (and the graph's nodes growing with the edges) a pass costs about s^3 log s,
    cubic in the one-way streets.

    Returns the directions and the summed one-way over two-way shortest path between
    the midpoints (weighted as above) before and after (:class:`Search`)."""
    out = forward.copy()
    k_dir = np.flatnonzero(directed)
    if len(k_dir) == 0:
        return out, 1.0, 1.0
    e = np.asarray(ends, dtype=np.int64).reshape(-1, 2)
    half = np.maximum(np.asarray(length, dtype=np.float64), 1.0) / 2.0
    weight = 2.0 * half
    two_way, mid = _midpoint_graph(n_nodes, e, half, out, np.zeros(len(e), dtype=bool))
    d2 = dijkstra(two_way, directed=True, indices=mid)[:, mid]
    pairs = np.isfinite(d2)
    np.fill_diagonal(pairs, False)
    two_cost = float((d2[pairs] * np.outer(weight, weight)[pairs]).sum())
    graph, _ = _midpoint_graph(n_nodes, e, half, out, directed)
    best = _detour_cost(graph, mid, weight, pairs)
    start = best / two_cost if two_cost > 0 else 1.0
    if not math.isfinite(best):
        return out, math.inf, math.inf  # not strongly connected to start with
    for _ in range(SHORT_PASSES):
        taken = False
        for k in k_dir.tolist():
            u, v = e[k]
            tail, head = (int(u), int(v)) if out[k] else (int(v), int(u))
            back = _cycle_back(graph, n_nodes, head, tail) if u != v else []
            tries = [[k]]
            cycle = [k] + [j for j in back if directed[j]]
            if len(cycle) > 1:
                tries.append(cycle)
            for flip in tries:
                trial = out.copy()
                trial[flip] = ~trial[flip]
                g_t, _ = _midpoint_graph(n_nodes, e, half, trial, directed)
                cost = _detour_cost(g_t, mid, weight, pairs)
                if cost < best * (1.0 - 1e-9):
                    out, graph, best, taken = trial, g_t, cost, True
                    break
        if not taken:
            break
    return out, start, best / two_cost if two_cost > 0 else 1.0


def _multigraph(n_nodes: int, ends: list[tuple[int, int]], bridge: B) -> tuple[nx.MultiGraph, B]:
    """The multigraph over nodes 0..n-1 with edges ``ends`` (u, v), keyed by index, and
    which nodes end an edge that is not a ``bridge`` (lie on a cycle)."""
    g = nx.MultiGraph()
    g.add_nodes_from(range(n_nodes))
    for k, (u, v) in enumerate(ends):
        g.add_edge(u, v, key=k)
    on_cycle = np.zeros(n_nodes, dtype=bool)
    for k, (u, v) in enumerate(ends):
        if not bridge[k]:
            on_cycle[u] = on_cycle[v] = True
    return g, on_cycle


def _beyond(n_nodes: int, ends: list[tuple[int, int]], bridge: B, stub: B) -> B:
    """Which nodes of a multigraph over nodes 0..n-1 with edges ``ends`` (u, v) lie
    beyond a ``stub`` edge (a ``bridge``): without it, on the side holding no cycle
    while the other side holds one. In a graph with no cycle no node does (no side is
    the street's far end)."""
    g, on_cycle = _multigraph(n_nodes, ends, bridge)
    out = np.zeros(n_nodes, dtype=bool)
    for k in np.flatnonzero(stub & bridge).tolist():
        u, v = ends[k]
        g.remove_edge(u, v, key=k)
        sides = [sorted(nx.node_connected_component(g, side)) for side in (u, v)]
        g.add_edge(u, v, key=k)
        cyclic = [bool(on_cycle[side].any()) for side in sides]
        if cyclic[0] != cyclic[1]:
            out[sides[1] if cyclic[0] else sides[0]] = True
    return out


def _dead_ends(n_nodes: int, ends: list[tuple[int, int]], bridge: B) -> B:
    """Which edges ``ends`` (u, v) of a multigraph over nodes 0..n-1 are bridges
    (``bridge``) with a dead-end side: without the edge, the part of one of its ends
    holds no edge that is not a bridge (no cycle: loops and parallel edges are none)."""
    g, on_cycle = _multigraph(n_nodes, ends, bridge)
    out = np.zeros(len(ends), dtype=bool)
    for k in np.flatnonzero(bridge).tolist():
        u, v = ends[k]
        g.remove_edge(u, v, key=k)
        out[k] = any(
            not on_cycle[sorted(nx.node_connected_component(g, side))].any() for side in (u, v)
        )
        g.add_edge(u, v, key=k)
    return out


@nb.njit(cache=True)
def _allowed(street: I64, along: F64, free: B, steps: I64, slack: float) -> npt.NDArray[np.uint8]:
    """Allowed steps per cell (see the module's notes): no step between two cells of one
    street that lowers the distance along it by more than ``slack`` cells, unless both
    are ``free`` (two-way)."""
    rows, cols = street.shape
    out = np.full((rows, cols), 255, dtype=np.uint8)
    for r in range(rows):
        for c in range(cols):
            e = street[r, c]
            if e < 0:
                continue
            m = 0
            for j in range(8):
                rr = r + steps[j, 0]
                cc = c + steps[j, 1]
                ok = True
                if 0 <= rr < rows and 0 <= cc < cols and street[rr, cc] == e:
                    against = along[rr, cc] < along[r, c] - slack
                    ok = not against or (free[r, c] and free[rr, cc])
                if ok:
                    m |= 1 << j
            out[r, c] = m
    return out


def _step_index() -> I64:
    """Index into :data:`STEPS` of each step, at (dr + 1) * 3 + dc + 1 (-1 for no step)."""
    out = np.full(9, -1, dtype=np.int64)
    for j, (dr, dc) in enumerate(STEPS.tolist()):
        out[(dr + 1) * 3 + dc + 1] = j
    return out


@nb.njit(cache=True)
def _kept_graph(
    indptr: npt.NDArray[np.int32],
    indices: npt.NDArray[np.int32],
    rc: I64,
    steps: npt.NDArray[np.uint8],
    step_index: I64,
) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int32]]:
    """The CSR structure (``indptr``, ``indices``) of a graph over cells ``rc`` keeping
    only the edges that are steps their tail cell's ``steps`` allows (bit
    :func:`_step_index` of the step), each row's edges in their order."""
    n = len(indptr) - 1
    out_ptr = np.zeros(n + 1, dtype=np.int32)
    out_idx = np.empty(len(indices), dtype=np.int32)
    m = 0
    for a in range(n):
        allowed = np.int64(steps[rc[a, 0], rc[a, 1]])
        for p in range(indptr[a], indptr[a + 1]):
            b = indices[p]
            dr = rc[b, 0] - rc[a, 0]
            dc = rc[b, 1] - rc[a, 1]
            j = step_index[(dr + 1) * 3 + dc + 1]
            if (allowed >> j) & 1:
                out_idx[m] = b
                m += 1
        out_ptr[a + 1] = m
    return out_ptr, out_idx[:m].copy()


def _labels(graph: csr_matrix, index: I64, steps: npt.NDArray[np.uint8]) -> I64:
    """Strongly connected set of each node of the wave's ``graph`` (:func:`cell_graph`,
    cells ``index``; its rows' columns sorted, as ``tocsr`` leaves them) keeping only
    the steps ``steps`` allows."""
    rc = np.argwhere(index >= 0)
    n = len(rc)
    indptr, indices = _kept_graph(graph.indptr, graph.indices, rc, steps, _step_index())
    m = csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
    _, label = connected_components(m, directed=True, connection="strong")
    out: I64 = label.astype(np.int64)
    return out


def strong_sets(passable: B, steps: npt.NDArray[np.uint8]) -> I64:
    """The strongly connected sets of ``passable`` under the allowed ``steps``.

    A step is the wave's (:class:`~sonarmap.patrol.paths.Wave`): to one of the 8
    neighbours, a diagonal only when both cells beside it are passable too, and only
    where bit j of the cell's ``steps`` allows step :data:`~sonarmap.patrol.paths.STEPS`
    [j].

    Parameters
    ----------
    passable : ndarray of bool
    steps : ndarray of uint8, same shape
        Allowed steps out of each cell (:attr:`OneWay.steps`).

    Returns
    -------
    ndarray of int64, shape (sets,)
        Each set's number of cells, largest first (empty without passable cells). Every
        passable cell reaches every other iff there is one set.
    """
    mask = np.asarray(passable, dtype=bool)
    if steps.shape != mask.shape:
        raise ValueError(f"allowed steps of {steps.shape} for passable cells of {mask.shape}")
    if not mask.any():
        return np.zeros(0, dtype=np.int64)
    graph, index = cell_graph(mask, 1.0)
    sizes: I64 = np.sort(np.bincount(_labels(graph, index, steps)))[::-1].astype(np.int64)
    return sizes


def _trapped(graph: csr_matrix, index: I64, weak: I64, steps: npt.NDArray[np.uint8]) -> B:
    """Cells of ``index`` outside the largest strongly connected set of their connected
    part (``weak``, per node) under ``steps``."""
    strong = _labels(graph, index, steps)
    n = len(strong)
    # Size of each strong set, and the largest within each weak part.
    size = np.bincount(strong)[strong]
    keep = _largest_sets(strong, weak, size, int(weak.max()) + 1 if n else 0)
    out = np.zeros(index.shape, dtype=bool)
    rc = np.argwhere(index >= 0)
    bad = strong != keep[weak]
    out[rc[bad, 0], rc[bad, 1]] = True
    return out


@nb.njit(cache=True)
def _largest_sets(strong: I64, weak: I64, size: I64, n_weak: int) -> I64:
    """The largest strong set (``strong``, of ``size`` cells, per node) of each weak
    part (``weak``, per node, 0..``n_weak`` - 1); ties go to the set of the lowest
    node."""
    keep = np.full(n_weak, -1, dtype=np.int64)
    best = np.zeros(n_weak, dtype=np.int64)
    for node in range(len(strong)):
        w = weak[node]
        if size[node] > best[w]:
            best[w] = size[node]
            keep[w] = strong[node]
    return keep


def _touches(segment: I64, node_of: I64, n_segments: int) -> list[set[int]]:
    """The junctions (``node_of`` >= 0) next to each segment (``segment`` >= 0)."""
    rows, cols = segment.shape
    touches: list[set[int]] = [set() for _ in range(n_segments)]
    sr, sc = np.nonzero(segment >= 0)
    for dr, dc in STEPS.tolist():
        rr, cc = sr + dr, sc + dc
        ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        nodes = np.full(len(sr), -1, dtype=np.int64)
        nodes[ok] = node_of[rr[ok], cc[ok]]
        for s, n in zip(
            segment[sr, sc][nodes >= 0].tolist(), nodes[nodes >= 0].tolist(), strict=True
        ):
            touches[s].add(n)
    return touches


def _parts(mask: B) -> I64:
    """The connected part of each cell of ``mask`` (row-major, as :func:`cell_graph`
    numbers its nodes) in the wave's grid graph, numbered from 0.

    A diagonal step of that graph joins two cells only when both cells beside it are
    in ``mask``, i.e. through two side steps: its parts are the 4-connected parts of
    ``mask`` (the same cells together as the graph's own connected components, which
    number them otherwise)."""
    labels, _ = ndimage.label(mask)
    out: I64 = labels[mask].astype(np.int64) - 1
    return out


def _farthest_from(junction: B, box: tuple[slice, slice], pix: B, bound: float) -> float:
    """The largest distance (cells) from a cell ``pix`` of ``box`` to the nearest
    ``junction`` cell, as the whole map's ``distance_transform_edt(~junction)`` gives
    it, when that is at most ``bound``; some value > ``bound`` otherwise.

    Worked out in ``box`` widened by m = ceil(bound) + 1 cells on every side instead of
    over the whole map: a junction cell outside that window lies more than m cells from
    every cell of ``box``, so a cell whose nearest junction in the window is at most m
    away has that nearest junction in the whole map too (the same offset, so the same
    float), and a cell with none that near is more than m > ``bound`` from every
    junction either way."""
    rows, cols = junction.shape
    m = math.ceil(bound) + 1
    r0, r1 = max(box[0].start - m, 0), min(box[0].stop + m, rows)
    c0, c1 = max(box[1].start - m, 0), min(box[1].stop + m, cols)
    window = junction[r0:r1, c0:c1]
    if not window.any():
        return math.inf
    near = ndimage.distance_transform_edt(~window)
    inner = near[box[0].start - r0 : box[0].stop - r0, box[1].start - c0 : box[1].stop - c0]
    far = float(inner[pix].max())
    return far if far <= m else math.inf


def _symmetric_dijkstra(graph: csr_matrix, starts: I64) -> tuple[F64, I64]:
    """Length of the shortest path to each node of the symmetric ``graph`` from the
    nearest of ``starts``, and which start that is (-1: none reaches it).

    As scipy's undirected ``dijkstra(..., min_only=True)``, without its transpose: on
    a symmetric graph that scans each edge twice, the second time finding the very
    same length, which never lowers one (scipy lowers only a strictly longer length),
    so the lengths and starts are the same."""
    d, _, source = dijkstra(
        graph, directed=True, indices=starts, min_only=True, return_predecessors=True
    )
    return d, source.astype(np.int64)


def one_way(
    passable: B,
    clearance: F64,
    resolution: float,
    turn_radius: float,
    orient: str = "dfs",
) -> OneWay:
    """The one-way street system of a map's passable cells (see the module's notes).

    Parameters
    ----------
    passable : ndarray of bool
        Cells a car's centre may be on.
    clearance : ndarray of float64, same shape
        Distance from each cell to the nearest obstacle, metres
        (:attr:`~sonarmap.patrol.territory.Territory.clearance`).
    resolution : float
        Cell side, metres.
    turn_radius : float
        The cars' turning radius, metres: streets narrower than twice it are one-way.
    orient : {'dfs', 'short'}
        The one-way streets' directions (:data:`ORIENTS`): 'dfs' (the default), a
        depth-first search's strongly connected orientation; 'short', that one with
        shorter detours (:func:`_shorten`), at a cost growing about with the cube of
        the one-way streets' number (each flip tried runs a shortest-path search from
        every street's midpoint), on top of the 'dfs' build.

    Returns
    -------
    OneWay
        Deterministic: the same map gives the same system.

    Raises
    ------
    ValueError
        If ``passable`` is not 2-D, ``clearance`` is not of its shape, ``resolution`` is
        not > 0, ``turn_radius`` not >= 0 or ``orient`` not one of :data:`ORIENTS`.
    """
    mask = np.asarray(passable, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"passable cells must be a 2-D grid, got shape {mask.shape}")
    if np.shape(clearance) != mask.shape:
        raise ValueError(
            f"clearance of shape {np.shape(clearance)} for passable cells of {mask.shape}"
        )
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution must be > 0 metres, got {resolution}")
    if not (math.isfinite(turn_radius) and turn_radius >= 0):
        raise ValueError(f"turn_radius must be >= 0 metres, got {turn_radius}")
    if orient not in ORIENTS:
        raise ValueError(f"unknown orient {orient!r}; valid: {', '.join(ORIENTS)}")
    clearance = np.asarray(clearance, dtype=np.float64)
    skel = thin(mask)
    nbrs = ndimage.convolve(skel.astype(np.int64), np.ones((3, 3), dtype=np.int64), mode="constant")
    nbrs = np.where(skel, nbrs - 1, 0)
    junction = skel & (nbrs >= 3)
    eight = np.ones((3, 3), dtype=bool)
    # A closed ring of streets with no junction (a lone block) gets one at its first
    # cell, so that it is a loop with two ends like any other.
    segment, n_segments = ndimage.label(skel & ~junction, structure=eight)
    touching = ndimage.binary_dilation(junction, structure=eight)
    # Each label's cells are looked for in its bounding box only (the first in
    # row-major order there is the first in the map).
    for s, box in enumerate(ndimage.find_objects(segment), start=1):
        pix = segment[box] == s
        if not (pix & touching[box]).any() and not (pix & (nbrs[box] == 1)).any():
            at = np.argwhere(pix)[0]
            junction[box[0].start + at[0], box[1].start + at[1]] = True
    # A loop back to its own junction that never leaves the junction's reach (a corner
    # spur of the thinning, a cell or two) is part of the junction, not a street.
    node_of, _ = ndimage.label(junction, structure=eight)
    segment, n_segments = ndimage.label(skel & ~junction, structure=eight)
    node_of = node_of.astype(np.int64) - 1
    segment = segment.astype(np.int64) - 1
    touches = _touches(segment, node_of, n_segments)
    # The junctions as they are before the loop below adds to them: its test reads
    # each cell's distance to those.
    junction_before = junction.copy()
    seg_box = ndimage.find_objects(segment + 1)
    node_box = ndimage.find_objects(node_of + 1)

    def cells_of(labels: I64, boxes: list[Any], k: int) -> tuple[tuple[slice, slice], B]:
        # Label k's bounding box and its cells there (row-major, as in the map).
        box = boxes[k]
        assert box is not None
        return box, labels[box] == k

    for s in range(n_segments):
        box, pix = cells_of(segment, seg_box, s)
        if len(touches[s]) != 1 or (pix & (nbrs[box] == 1)).any():
            continue
        (n,) = touches[s]
        nbox, npix = cells_of(node_of, node_box, n)
        reach_cells = float(clearance[nbox][npix].max()) / resolution + 1.0
        if _farthest_from(junction_before, box, pix, reach_cells) <= reach_cells:
            junction[box] |= pix
    node_of, n_junctions = ndimage.label(junction, structure=eight)
    segment, n_segments = ndimage.label(skel & ~junction, structure=eight)
    node_of = node_of.astype(np.int64) - 1  # -1 off the junctions
    segment = segment.astype(np.int64) - 1
    # Each segment's junctions (the nodes touching it) and ends (skeleton ends).
    touches = _touches(segment, node_of, n_segments)
    seg_box = ndimage.find_objects(segment + 1)
    node_box = ndimage.find_objects(node_of + 1)
    n_nodes = n_junctions
    ends: list[tuple[int, int]] = []
    tails: list[int] = []
    for s in range(n_segments):
        t = sorted(touches[s])
        if len(t) == 2:
            ends.append((t[0], t[1]))
        elif len(t) == 1:
            # A stub to a skeleton end, or a loop back to the same junction: a new node
            # for the end keeps it a bridge; a loop is its own cycle.
            # In the segment's bounding box: the whole map's test once per street.
            box, pix = cells_of(segment, seg_box, s)
            is_end = bool((pix & (nbrs[box] == 1)).any())
            if is_end:
                ends.append((t[0], n_nodes))
                n_nodes += 1
            else:
                ends.append((t[0], t[0]))
        else:
            # No junction (a closed ring or a lone line) or a segment glued to three
            # junctions: left out of the system (two-way).
            ends.append((-1, -1))
        tails.append(-1)
    valid = [k for k, e in enumerate(ends) if e[0] >= 0]
    forward = np.ones(n_segments, dtype=bool)
    bridge = np.ones(n_segments, dtype=bool)
    dead_end = np.zeros(n_segments, dtype=bool)
    if valid:
        f, b = _orient(n_nodes, [ends[k] for k in valid])
        forward[valid] = f
        bridge[valid] = b
        dead_end[valid] = _dead_ends(n_nodes, [ends[k] for k in valid], b)

    widths = np.zeros(n_segments)
    for s in range(n_segments):
        box, pix = cells_of(segment, seg_box, s)
        widths[s] = 2.0 * float(np.median(clearance[box][pix]))
    directed = ~bridge & (widths < 2.0 * turn_radius)
    search: Search | None = None
    if orient == "short":
        search = Search(streets=0, flipped=0, before=1.0, after=1.0)
    if orient == "short" and valid:
        # A street's length: its skeleton cells (a diagonal step counts as one).
        seg_len = np.bincount(segment[segment >= 0], minlength=n_segments).astype(np.float64)
        dfs_forward = forward[valid].copy()
        forward[valid], before, after = _shorten(
            n_nodes, [ends[k] for k in valid], seg_len[valid], dfs_forward, directed[valid]
        )
        search = Search(
            streets=int(directed[valid].sum()),
            flipped=int((forward[valid] != dfs_forward).sum()),
            before=before,
            after=after,
        )
    stubs = dead_end & (widths < 2.0 * turn_radius)
    # A junction beyond a stub whose streets are all stubs: the stub's far end.
    end_node = np.zeros(n_junctions, dtype=bool)
    if valid:
        far = _beyond(n_nodes, [ends[k] for k in valid], bridge[valid], stubs[valid])
        end_node = far[:n_junctions].copy()
        # Read from the cells the segments touch, not the graph's ends: a segment left
        # out of the graph (glued to three junctions) is no stub and clears them too.
        for k in np.flatnonzero(~stubs).tolist():
            for x in touches[k]:
                end_node[x] = False
    # Distance along each directed segment from the cell touching its tail junction.
    along_skel = np.full(mask.shape, np.nan)
    reach = np.zeros(n_nodes)
    for n in range(n_junctions):
        box, here = cells_of(node_of, node_box, n)
        reach[n] = float(clearance[box][here].max()) + resolution
    seg_margin = np.zeros(n_segments)
    rows, cols = mask.shape
    for s in np.flatnonzero(directed).tolist():
        u, v = ends[s]
        tail, head = (u, v) if forward[s] else (v, u)
        # The segment's bounding box and one cell round it: all a cell of it touches.
        box = seg_box[s]
        assert box is not None
        r0, r1 = max(box[0].start - 1, 0), min(box[0].stop + 1, rows)
        c0, c1 = max(box[1].start - 1, 0), min(box[1].stop + 1, cols)
        win = (slice(r0, r1), slice(c0, c1))
        pix = segment[win] == s
        near_tail = node_of[win] == tail
        near_tail = ndimage.binary_dilation(near_tail, structure=eight) & pix
        if u == v:
            # A loop: start at its cells next to the junction with the lowest index.
            cand = np.argwhere(near_tail)
            near_tail = np.zeros(pix.shape, dtype=bool)
            near_tail[tuple(cand[0])] = True
        g_s, idx_s = cell_graph(pix, 1.0, corners=True)
        starts = idx_s[near_tail]
        d = _symmetric_dijkstra(g_s, starts)[0]
        along_skel[win][pix] = d[idx_s[pix]]
        ends_reach = [reach[x] if x < n_junctions else 0.0 for x in (tail, head)]
        seg_margin[s] = max(ends_reach) / resolution
    # Every passable cell takes the skeleton cell nearest it along the grid's paths.
    g_all, idx_all = cell_graph(mask, resolution)
    sk = np.argwhere(skel & mask)
    source = _symmetric_dijkstra(g_all, idx_all[sk[:, 0], sk[:, 1]])[1]
    flat_rc = np.argwhere(mask)
    street = np.full(mask.shape, -1, dtype=np.int64)
    along = np.full(mask.shape, np.nan)
    src_ok = source >= 0
    src_rc = flat_rc[np.maximum(source, 0)]
    seg_of = np.where(src_ok, segment[src_rc[:, 0], src_rc[:, 1]], -1)
    al = np.where(src_ok, along_skel[src_rc[:, 0], src_rc[:, 1]], np.nan)
    node_at = np.where(src_ok, node_of[src_rc[:, 0], src_rc[:, 1]], -1)
    street[mask] = seg_of
    along[mask] = al
    stub_ends = np.zeros(mask.shape, dtype=bool)
    stub_ends[mask] = np.append(end_node, False)[node_at]  # node -1 (none): the False
    length = np.zeros(n_segments)
    for s in np.flatnonzero(directed).tolist():
        box, pix = cells_of(segment, seg_box, s)
        length[s] = float(np.nanmax(along_skel[box][pix]))
    m = seg_margin[np.maximum(street, 0)]
    ln = length[np.maximum(street, 0)]
    weak = _parts(mask)
    # Each round opens at least one street (the last resort all of a part): bounded.
    for _ in range(n_segments + 1):
        is_dir = (street >= 0) & directed[np.maximum(street, 0)]
        with np.errstate(invalid="ignore"):
            free = ~is_dir | (along <= m) | (along >= ln - m)
        along_dir = np.where(is_dir, along, 0.0)
        steps = _allowed(street, np.nan_to_num(along_dir, nan=0.0), free, STEPS, ALONG_SLACK)
        if not directed.any():
            break
        trapped = _trapped(g_all, idx_all, weak, steps)
        if not trapped.any():
            break
        near = ndimage.binary_dilation(trapped, structure=eight) & (street >= 0)
        opened = np.unique(street[near])
        opened = opened[directed[opened]]
        if len(opened) == 0:
            # No one-way street at the trap: open every one of its connected parts.
            parts = np.unique(weak[idx_all[trapped]])
            part_of = np.where(idx_all >= 0, weak[np.maximum(idx_all, 0)], -1)
            opened = np.unique(street[(street >= 0) & np.isin(part_of, parts)])
            opened = opened[directed[opened]]
            if len(opened) == 0:
                break
        directed[opened] = False
    along[~is_dir] = np.nan
    return OneWay(
        steps=steps,
        street=street,
        along=along,
        one_way=directed,
        widths=widths,
        bridges=bridge,
        stubs=stubs,
        in_graph=np.array([e[0] >= 0 for e in ends], dtype=bool),
        two_way=free & mask,
        stub_ends=stub_ends,
        search=search,
    )
