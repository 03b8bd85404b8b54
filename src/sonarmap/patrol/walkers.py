"""Robots that walk the patrol graph vertex to vertex: the literature's reactive baselines.

Both are decentralised and choose, on reaching a vertex, which neighbour to go to next
(Machado et al. 2002; Almeida et al. 2004):

- ``cr``, conscientious reactive: the neighbour this robot itself has left unvisited
  longest (its *individual* idleness: the time since it last reached the vertex, or since
  the start);
- ``hcr``, heuristic conscientious reactive: the neighbour with the best sum of the
  *shared* idleness (time since any robot the robot hears of saw the vertex, from its
  fog) divided by the largest among the neighbours, and one less the edge's length
  divided by the longest edge among them. The paper weighs the two terms; here they
  weigh the same (our choice: the paper leaves the weights open).

Ties go to the lowest vertex index, so a run is deterministic. The patrol graph is
:class:`~sonarmap.patrol.graph.PatrolGraph`; the metrics that judge these walkers are the
same graph's (:mod:`.monitor`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from .graph import PatrolGraph

__all__ = ["WALKERS", "GraphWalkers"]

#: The graph-walking policies.
WALKERS = ("cr", "hcr")

F64 = npt.NDArray[np.float64]


class GraphWalkers:
    """Where each robot of a team of graph walkers is going.

    Parameters
    ----------
    graph : PatrolGraph
    policy : str
        One of :data:`WALKERS`.
    cells : ndarray of int, shape (n, 2)
        Each robot's start cell; its first target is the vertex whose region holds it
        (the nearest along the grid's paths).
    """

    def __init__(self, graph: PatrolGraph, policy: str, cells: npt.ArrayLike) -> None:
        if policy not in WALKERS:
            raise ValueError(f"unknown graph walker {policy!r}; valid: {', '.join(WALKERS)}")
        rc = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
        home = graph.region[rc[:, 0], rc[:, 1]]
        if (home < 0).any():
            raise ValueError("a robot starts outside the patrol graph's cells")
        self.graph = graph
        self.policy = policy
        #: The vertex each robot goes to.
        self.target = home.astype(np.int64)
        #: When each robot last reached each vertex, seconds (0: the start).
        self.reached = np.zeros((len(rc), len(graph)))

    def goal_cell(self, i: int) -> tuple[int, int]:
        """Robot i's target vertex's cell (row, column)."""
        r, c = self.graph.cells[self.target[i]]
        return int(r), int(c)

    def arrive(self, i: int, t: float, last_seen: F64) -> int:
        """Robot i reached its target at time ``t``: choose the next one and return it.

        ``last_seen`` holds, per vertex, when the robot's fog last saw it (seconds).
        """
        u = int(self.target[i])
        self.reached[i, u] = t
        nb = self.graph.neighbours[u]
        if not len(nb):
            return u
        if self.policy == "cr":
            score = t - self.reached[i, nb]
        else:
            idle = t - np.asarray(last_seen, dtype=np.float64)[nb]
            length = self.graph.lengths[u]
            top = float(idle.max())
            score = (idle / top if top > 0 else np.zeros(len(nb))) + 1.0 - length / length.max()
        self.target[i] = int(nb[int(np.argmax(score))])
        return int(self.target[i])

    def state(self) -> dict[str, Any]:
        return {"target": self.target.copy(), "reached": self.reached.copy()}

    def restore(self, state: dict[str, Any]) -> None:
        self.target = np.asarray(state["target"], dtype=np.int64).copy()
        self.reached = np.asarray(state["reached"], dtype=np.float64).copy()
