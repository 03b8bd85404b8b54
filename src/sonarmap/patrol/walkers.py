"""Robots that walk the patrol graph vertex to vertex: the literature's reactive baselines.

All are decentralised and choose, on reaching a vertex, which neighbour to go to next
(Machado et al. 2002; Almeida et al. 2004; Portugal and Rocha 2013):

- ``cr``, conscientious reactive: the neighbour this robot itself has left unvisited
  longest (its *individual* idleness: the time since it last reached the vertex, or since
  the start);
- ``hcr``, heuristic conscientious reactive: the neighbour with the best sum of the
  *shared* idleness (time since any robot the robot hears of saw the vertex, from its
  fog) divided by the largest among the neighbours, and one less the edge's length
  divided by the longest edge among them. The paper weighs the two terms; here they
  weigh the same (our choice: the paper leaves the weights open).
- ``sebs``, the state exchange Bayesian strategy: the neighbour with the highest
  posterior probability of being worth the move, given its *gain* (shared idleness, s,
  over the edge's length, m) and the other robots' *intentions* (the vertex each is
  bound for). The posterior rises with the gain as ``G1 exp(ln(1/G1) gain / G2)`` up to
  1 at ``gain >= G2``, and is multiplied by ``2**(N - c) / (2**N - 1)`` when ``c`` of
  the other robots the robot hears of are bound for the vertex (N robots in the team):
  a vertex another robot goes to is worth the trip only if its gain is much larger.
  ``G1 = 0.1`` is the paper's; ``G2``, the gain at which a move is certainly worth it,
  the paper tunes per map and team by hand; here it is derived: ``V / (N v)`` for V
  vertices and speed v, the gain of a vertex left for the time a team of N spends on a
  tour through every vertex along edges of the average length (our choice).
  Intentions are those of the robots heard at the moment of the choice (with the full
  network, all of them), as the reference's robots announce theirs on arrival.

Ties go to the lowest vertex index (for ``sebs``, first the larger gain: the posterior
saturates at 1), so a run is deterministic. A robot whose vertex it cannot reach (robots
in the way) chooses again among the neighbours it can reach (:meth:`GraphWalkers.reroute`).
The patrol graph is :class:`~sonarmap.patrol.graph.PatrolGraph`; the metrics that judge
these walkers are the same graph's (:mod:`.monitor`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from .graph import PatrolGraph

__all__ = ["SEBS_G1", "WALKERS", "GraphWalkers"]

#: The graph-walking policies.
WALKERS = ("cr", "hcr", "sebs")
#: SEBS's posterior of a move with no gain (Portugal and Rocha 2013).
SEBS_G1 = 0.1

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]


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
    speed : float
        The robots' speed, m/s (> 0; default 1): sets SEBS's default ``g2``.
    g2 : float, optional
        SEBS's gain, s/m, from which a move is certainly worth it (> 0); default
        V / (n speed) for V vertices and n robots (see the module's notes).
    """

    def __init__(
        self,
        graph: PatrolGraph,
        policy: str,
        cells: npt.ArrayLike,
        *,
        speed: float = 1.0,
        g2: float | None = None,
    ) -> None:
        if policy not in WALKERS:
            raise ValueError(f"unknown graph walker {policy!r}; valid: {', '.join(WALKERS)}")
        rc = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
        home = graph.region[rc[:, 0], rc[:, 1]]
        if (home < 0).any():
            raise ValueError("a robot starts outside the patrol graph's cells")
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be > 0 m/s, got {speed}")
        if g2 is None:
            g2 = len(graph) / (len(rc) * speed)
        if not (math.isfinite(g2) and g2 > 0):
            raise ValueError(f"SEBS's g2 must be > 0 s/m, got {g2}")
        self.graph = graph
        self.policy = policy
        #: SEBS's saturating gain, s/m.
        self.g2 = float(g2)
        #: The vertex each robot goes to.
        self.target = home.astype(np.int64)
        #: The vertex each robot last reached (at the start, the one it goes to).
        self.left = home.astype(np.int64)
        #: When each robot last reached each vertex, seconds (0: the start).
        self.reached = np.zeros((len(rc), len(graph)))

    def __len__(self) -> int:
        return len(self.target)

    def goal_cell(self, i: int) -> tuple[int, int]:
        """Robot i's target vertex's cell (row, column)."""
        r, c = self.graph.cells[self.target[i]]
        return int(r), int(c)

    def arrive(self, i: int, t: float, last_seen: F64, heard: B | None = None) -> int:
        """Robot i reached its target at time ``t``: choose the next one and return it.

        Parameters
        ----------
        i : int
            The robot.
        t : float
            The time, seconds.
        last_seen : ndarray of float, shape (V,)
            Per vertex, when the robot's fog last saw it, seconds.
        heard : ndarray of bool, shape (n,), optional
            The robots whose intentions robot i hears (its network component; its own
            entry is ignored); default every robot.
        """
        u = int(self.target[i])
        self.reached[i, u] = t
        self.left[i] = u
        nb = self.graph.neighbours[u]
        if len(nb):
            self.target[i] = self._choose(i, t, nb, self.graph.lengths[u], last_seen, heard)
        return int(self.target[i])

    def reroute(
        self, i: int, t: float, last_seen: F64, reachable: B, heard: B | None = None
    ) -> int:
        """Robot i cannot reach its target (robots in the way): choose again, by its
        policy, among the neighbours of the vertex it last reached that it can reach
        (``reachable``, per vertex), other than the target. Keeps the target when there
        is none; returns the target. Other arguments as :meth:`arrive`.

        Standing still until the way clears is no answer: the robot in the way may be
        waiting for this one to move (it gave way), and the two would stand for good.
        """
        u = int(self.left[i])
        nb, ln = self.graph.neighbours[u], self.graph.lengths[u]
        ok = np.asarray(reachable, dtype=bool)[nb] & (nb != self.target[i])
        if ok.any():
            self.target[i] = self._choose(i, t, nb[ok], ln[ok], last_seen, heard)
        return int(self.target[i])

    def _choose(
        self, i: int, t: float, nb: I64, length: F64, last_seen: F64, heard: B | None
    ) -> int:
        """The neighbour among ``nb`` (edge lengths ``length``, metres) robot i goes to."""
        if self.policy == "cr":
            return int(nb[int(np.argmax(t - self.reached[i, nb]))])
        idle = t - np.asarray(last_seen, dtype=np.float64)[nb]
        if self.policy == "hcr":
            top = float(idle.max())
            score = (idle / top if top > 0 else np.zeros(len(nb))) + 1.0 - length / length.max()
            return int(nb[int(np.argmax(score))])
        # SEBS. An edge no longer than a cell would make the gain blow up.
        gain = idle / np.maximum(length, self.graph.grid.resolution)
        post = np.where(
            gain < self.g2, SEBS_G1 * np.exp(math.log(1.0 / SEBS_G1) * gain / self.g2), 1.0
        )
        n = len(self)
        others = np.ones(n, dtype=bool) if heard is None else np.asarray(heard, dtype=bool).copy()
        others[i] = False
        count = (self.target[others][None, :] == nb[:, None]).sum(axis=1)
        post = np.where(count > 0, post * 2.0 ** (n - count) / (2.0**n - 1.0), post)
        # The highest posterior; among equals (saturated ones) the larger gain, then the
        # lowest index.
        return int(nb[np.lexsort((nb, -gain, -post))[0]])

    def state(self) -> dict[str, Any]:
        """A copy of what changes during a run (for :meth:`restore`)."""
        return {
            "target": self.target.copy(),
            "left": self.left.copy(),
            "reached": self.reached.copy(),
        }

    def restore(self, state: dict[str, Any]) -> None:
        """Go back to a :meth:`state`."""
        self.target = np.asarray(state["target"], dtype=np.int64).copy()
        self.left = np.asarray(state.get("left", state["target"]), dtype=np.int64).copy()
        self.reached = np.asarray(state["reached"], dtype=np.float64).copy()
