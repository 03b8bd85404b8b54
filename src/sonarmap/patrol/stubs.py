"""Dead-end stubs seen from the street: where a car stands to see a place in a stub.

A dead-end stub (:attr:`~sonarmap.patrol.oneway.OneWay.stubs`: a bridge of the street
graph with a side holding no cycle of streets, narrower than a car's turning circle) is
one a car that drives in must back out of; a street with no junction (a plain corridor)
or a bridge between two loops of streets is none. A real patrol does not
drive into a cul-de-sac whose end it sees from the junction: it looks down it in
passing. So a place in a stub has a *stand point*: the skeleton cell of the streets it
leaves from (the graph's other streets and junctions) nearest it along the passable
cells -- the middle of the junction the stub opens on. When the place lies within
``reach`` metres of that cell, a car sees it from there (vision is a disc) and need not
enter the stub; otherwise it has no stand point and is gone for as any place.

Places off the passable cells (beside a wall) belong to the stub of their nearest
passable cell.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.sparse.csgraph import dijkstra

from .graph import cell_graph
from .oneway import OneWay, thin

__all__ = ["stand_points", "stub_cells", "stub_places"]

B = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]


def stub_cells(passable: B, streets: OneWay) -> B:
    """The passable cells of the dead-end stubs (:attr:`OneWay.stubs`), with the
    junctions the street graph makes at their far ends (:attr:`OneWay.stub_ends`).

    Parameters
    ----------
    passable : ndarray of bool, shape grid
        Cells a car's centre may occupy.
    streets : OneWay
        The street system of ``passable`` (:func:`~sonarmap.patrol.oneway.one_way`).

    Returns
    -------
    ndarray of bool, shape grid
        The passable cells whose street is a stub.

    Raises
    ------
    ValueError
        If ``passable`` and the streets' grid differ in shape.
    """
    if passable.shape != streets.street.shape:
        raise ValueError(f"passable cells of {passable.shape}, streets of {streets.street.shape}")
    on = streets.street >= 0
    out = np.zeros(passable.shape, dtype=bool)
    out[on] = streets.stubs[streets.street[on]]
    return (out | streets.stub_ends) & passable


def stub_places(passable: B, watched: B, streets: OneWay) -> B:
    """The watched places in the dead-end stubs: those whose nearest passable cell (their
    own, or the one beside their wall) is a stub cell (:func:`stub_cells`).

    Parameters
    ----------
    passable, watched : ndarray of bool, shape grid
        Cells a car's centre may occupy; places to be seen.
    streets : OneWay
        The street system of ``passable`` (:func:`~sonarmap.patrol.oneway.one_way`).

    Returns
    -------
    ndarray of bool, shape grid
        The watched places in stubs.

    Raises
    ------
    ValueError
        If ``watched``, ``passable`` and the streets' grid differ in shape.
    """
    if watched.shape != passable.shape:
        raise ValueError(f"watched cells of {watched.shape}, passable of {passable.shape}")
    stub = stub_cells(passable, streets)
    if not passable.any():
        return np.zeros(passable.shape, dtype=bool)
    _, (nr, nc) = ndimage.distance_transform_edt(~passable, return_indices=True)
    out: B = watched & stub[nr, nc]
    return out


def stand_points(passable: B, watched: B, streets: OneWay, resolution: float, reach: float) -> I64:
    """Each watched place's stand point (see the module's notes), as a flat index
    (row-major) into the grid; -1 where it has none (outside the stubs, or farther
    than ``reach`` metres from the stub's junction).

    Parameters
    ----------
    passable, watched : ndarray of bool, shape grid
        Cells a car's centre may occupy; places to be seen.
    streets : OneWay
        The street system of ``passable`` (:func:`~sonarmap.patrol.oneway.one_way`).
    resolution : float
        Cell side, metres.
    reach : float
        How far from its stand point a place may lie, metres (a car's vision less a
        margin), >= 0.

    Returns
    -------
    ndarray of int64, shape grid
        Flat index of each place's stand point, -1 where it has none.

    Raises
    ------
    ValueError
        If ``watched``, ``passable`` and the streets' grid differ in shape, or
        ``resolution`` is not > 0 or ``reach`` not >= 0 (or either not finite).
    """
    if watched.shape != passable.shape:
        raise ValueError(f"watched cells of {watched.shape}, passable of {passable.shape}")
    if not (np.isfinite(resolution) and resolution > 0 and np.isfinite(reach) and reach >= 0):
        raise ValueError(f"resolution must be > 0 and reach >= 0 metres, got {resolution}, {reach}")
    stand = np.full(passable.shape, -1, dtype=np.int64)
    stub = stub_cells(passable, streets)
    core = thin(passable) & passable & ~stub
    if not stub.any() or not core.any():
        return stand
    graph, index = cell_graph(passable, resolution)
    _, _, source = dijkstra(
        graph, directed=False, indices=index[core], return_predecessors=True, min_only=True
    )
    cells = np.flatnonzero(passable.ravel())  # node k is cell cells[k] (row-major)
    # Each watched place's nearest passable cell: its own, or the one beside its wall.
    _, (nr, nc) = ndimage.distance_transform_edt(~passable, return_indices=True)
    rows, cols = np.nonzero(stub_places(passable, watched, streets))
    owner = index[nr[rows, cols], nc[rows, cols]]
    src = source[owner]
    ok = src >= 0
    rows, cols, at = rows[ok], cols[ok], cells[src[ok]]
    sr, sc = np.divmod(at, passable.shape[1])
    near = np.hypot(sr - rows, sc - cols) * resolution <= reach
    stand[rows[near], cols[near]] = at[near]
    return stand
