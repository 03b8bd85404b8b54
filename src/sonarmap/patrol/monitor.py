"""The metrics graph patrolling reports (patrolling_sim's monitor), on a patrol graph.

Fed the robots' positions once a step, a :class:`Monitor` keeps, for every vertex of a
:class:`~sonarmap.patrol.graph.PatrolGraph`, when it was last covered, and turns that
into the literature's numbers: visit intervals (the idleness a visit finds) with their
average, spread, median and worst, complete patrol cycles, interference between
robots, and idleness over time. ``docs/patrol.md`` ("Patrol graph and idleness
metrics") gives each definition with its formula.

A vertex is covered at a step when some robot's centre is within ``visit_radius`` of it
(default the vision radius). With the robots' centres moved to their cells' centres,
as the fog sees from them, a vertex's idleness is then exactly the fog's TB of the
vertex's cell under disc vision.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from .graph import PatrolGraph

__all__ = ["Monitor"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: The idleness series keeps at most this many rows by default.
MAX_ROWS = 2000


class _Growing:
    """A numpy array appended to in blocks, doubling its room when full."""

    def __init__(self, dtype: type[np.generic], size: int = 1024) -> None:
        self.data = np.empty(size, dtype=dtype)
        self.n = 0

    def extend(self, values: npt.NDArray[Any]) -> None:
        need = self.n + len(values)
        if need > len(self.data):
            grown = np.empty(max(need, 2 * len(self.data)), dtype=self.data.dtype)
            grown[: self.n] = self.data[: self.n]
            self.data = grown
        self.data[self.n : need] = values
        self.n = need

    @property
    def view(self) -> npt.NDArray[Any]:
        return self.data[: self.n]

    def set(self, values: npt.ArrayLike) -> None:
        v = np.asarray(values, dtype=self.data.dtype)
        self.data = np.empty(max(1024, len(v)), dtype=self.data.dtype)
        self.n = 0
        self.extend(v)


def _fmt(v: float) -> str:
    return "" if not math.isfinite(v) else f"{v:.6g}"


class Monitor:
    """Visits, idleness, cycles and interference on a patrol graph, step by step.

    Parameters
    ----------
    graph : PatrolGraph
        The vertices watched (and the grid robots' cells are read on).
    visit_radius : float, optional
        A vertex is covered while some robot's centre is within this many metres of it;
        default the graph's vision radius.
    start_idleness : float
        Idleness of every vertex at ``start_time``, seconds (as the fog's start fog;
        default 0: the territory just seen).
    start_time : float
        Time of the start, seconds (default 0).
    interference_distance : float, optional
        Two robots interfere while their centres are closer than this, metres; default
        1.5 times the least separation of two discs of ``robot_radius`` (3 x radius:
        their rims less than one radius apart, where one step of a robot at the
        thesis's speed can bring the collision rule into play).
    robot_radius : float
        Robots' radius, metres (default 1, the thesis's); sets the default
        ``interference_distance``.
    snap : bool
        Measure coverage from the centre of each robot's cell, as the fog sees
        (default True); False uses the positions as given.
    max_rows : int
        Most rows of the idleness series (default 2,000): a row every ``k`` steps, ``k``
        doubling whenever the rows would exceed it.

    Examples
    --------
    Fed from a run's ``on_step`` callback, after one update with the starts at time 0
    (so that a vertex's idleness is the fog's TB at its cell, step by step)::

        from sonarmap.patrol.graph import PatrolGraph
        from sonarmap.patrol.monitor import Monitor
        from sonarmap.plot import save_idleness_plot

        passable = territory.passable(config.radius)
        r, c = territory.grid.world_to_cell(starts[:, 0], starts[:, 1])
        graph = PatrolGraph.from_territory(
            territory, passable, config.vision, starts=list(zip(r.tolist(), c.tolist()))
        )
        mon = Monitor(graph, start_idleness=config.start_fog, robot_radius=config.radius)
        mon.update(0.0, starts[:, 0], starts[:, 1])
        run_patrol(territory, config, starts=starts,
                   on_step=lambda t, team, fog: mon.update(t, team.x, team.y))
        summary = mon.summary()               # JSON-ready numbers for summary.json
        text = mon.idleness_csv()             # idleness.csv
        save_idleness_plot(mon.idleness_series(), "idleness.png")

    Memory is O(V) plus one number pair per visit (the visit intervals, kept exactly
    for their median) and at most ``max_rows`` series rows: never the trajectory.
    """

    def __init__(
        self,
        graph: PatrolGraph,
        *,
        visit_radius: float | None = None,
        start_idleness: float = 0.0,
        start_time: float = 0.0,
        interference_distance: float | None = None,
        robot_radius: float = 1.0,
        snap: bool = True,
        max_rows: int = MAX_ROWS,
    ) -> None:
        self.graph = graph
        self.visit_radius = float(graph.vision if visit_radius is None else visit_radius)
        self.interference_distance = float(
            3.0 * robot_radius if interference_distance is None else interference_distance
        )
        for name, v in (
            ("visit_radius", self.visit_radius),
            ("interference_distance", self.interference_distance),
        ):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0 metres, got {v}")
        if not (math.isfinite(start_idleness) and start_idleness >= 0):
            raise ValueError(f"start_idleness must be >= 0 seconds, got {start_idleness}")
        if max_rows < 2:
            raise ValueError(f"max_rows must be >= 2, got {max_rows}")
        self.start_idleness = float(start_idleness)
        self.start_time = float(start_time)
        self.snap = snap
        self.max_rows = int(max_rows)
        self._tree = cKDTree(graph.xy)
        # Vertex and robot cells are on one grid of exact centres: a hair of slack keeps
        # a vertex exactly at the radius covered, as the fog's disc keeps its cell.
        self._reach = self.visit_radius + 1e-9 * max(1.0, self.visit_radius)
        self._reset()

    def _reset(self) -> None:
        v = len(self.graph)
        #: Time of the latest update (the start before any).
        self.t = self.start_time
        self.steps = 0
        self.robots = 0
        # When each vertex was last covered: its idleness is t - last.
        self._last = np.full(v, self.start_time - self.start_idleness)
        self._covered = np.zeros(v, dtype=bool)
        # Sum over updates of idleness x the time since the previous update.
        self._area = np.zeros(v)
        self._worst_now = np.full(v, self.start_idleness)
        self._visits = np.zeros(v, dtype=np.int64)
        self._iv_vertex = _Growing(np.int64)
        self._iv_value = _Growing(np.float64)
        self._since_cycle = np.zeros(v, dtype=bool)
        self._cycle_times: list[float] = []
        self._close = np.zeros((0, 0), dtype=bool)
        self._events = 0
        # Time integrals of the mean and the max of idleness over the vertices.
        self._area_mean = 0.0
        self._area_max = 0.0
        self._series: list[tuple[int, float, float, float]] = []
        self._stride = 1
        self._latest: tuple[int, float, float, float] | None = None

    # --- feeding -------------------------------------------------------------------

    def update(self, t: float, x: npt.ArrayLike, y: npt.ArrayLike) -> None:
        """The robots' centres (world metres) at time ``t`` (seconds, later than the
        previous update's and not before the start)."""
        t = float(t)
        if self.steps and not t > self.t:
            raise ValueError(f"updates must move forward in time: {t} after {self.t}")
        if not t >= self.start_time:
            raise ValueError(f"an update at {t} s before the start at {self.start_time} s")
        px = np.atleast_1d(np.asarray(x, dtype=np.float64))
        py = np.atleast_1d(np.asarray(y, dtype=np.float64))
        if px.shape != py.shape or px.ndim != 1:
            raise ValueError(f"x and y must be 1-D of one length, got {px.shape}, {py.shape}")
        if self.steps and len(px) != self.robots:
            raise ValueError(f"{len(px)} robots, the monitor has seen {self.robots}")
        self.robots = len(px)
        dt = t - self.t
        self.t = t
        self.steps += 1
        self._cover(t, px, py)
        self._interfere(px, py)
        idle = t - self._last
        self._area += idle * dt
        np.maximum(self._worst_now, idle, out=self._worst_now)
        mean, top = float(idle.mean()), float(idle.max())
        self._area_mean += mean * dt
        self._area_max += top * dt
        self._record(mean, top)

    def _cover(self, t: float, px: F64, py: F64) -> None:
        if self.snap:
            g = self.graph.grid
            px, py = g.cell_centres(*g.world_to_cell(px, py))
        hits = self._tree.query_ball_point(np.column_stack([px, py]), self._reach)
        flat = [j for h in hits for j in h]
        now = np.zeros(len(self._last), dtype=bool)
        now[flat] = True
        idx = np.flatnonzero(now)
        new = idx[~self._covered[idx]]
        # A run under way at the first update is a visit too (of interval the start
        # idleness, 0 by default): a vertex watched from the start on is not unvisited.
        gap = t - self._last[new]
        if len(new):
            self._iv_vertex.extend(new)
            self._iv_value.extend(gap)
            self._visits[new] += 1
            self._since_cycle[new] = True
            if self._since_cycle.all():
                self._cycle_times.append(t)
                self._since_cycle[:] = False
        self._last[idx] = t
        self._covered = now

    def _interfere(self, px: F64, py: F64) -> None:
        d = np.hypot(px[:, None] - px[None, :], py[:, None] - py[None, :])
        close = np.triu(d < self.interference_distance, k=1)
        if self._close.shape == close.shape:
            self._events += int((close & ~self._close).sum())
        else:
            self._events += int(close.sum())
        self._close = close

    def _record(self, mean: float, top: float) -> None:
        row = (self.steps, self.t, mean, top)
        self._latest = row
        if (self.steps - 1) % self._stride:
            return
        self._series.append(row)
        if len(self._series) >= self.max_rows:
            # Keep every other row: steps 1, 1 + 2k, 1 + 4k, ... stay evenly spaced.
            self._series = self._series[::2]
            self._stride *= 2

    # --- per vertex ----------------------------------------------------------------

    def idleness(self) -> F64:
        """Instantaneous idleness of every vertex at the latest update, seconds: 0 while
        covered, else the time since it was last covered (or since the start, plus the
        start idleness)."""
        return self.t - self._last

    def intervals(self) -> tuple[I64, F64]:
        """Every visit interval so far, in order: the vertex visited and the interval
        (seconds). New arrays."""
        return self._iv_vertex.view.copy(), self._iv_value.view.copy()

    def per_vertex(self) -> dict[str, npt.NDArray[Any]]:
        """Per vertex: ``visits``; ``avg``, ``std``, ``median``, ``worst`` of its visit
        intervals (NaN with no visit); ``mean_idleness`` (time average of its
        instantaneous idleness) and ``worst_idleness`` (largest instantaneous idleness
        at an update, or at the start)."""
        n = len(self.graph)
        vert, val = self._iv_vertex.view, self._iv_value.view
        count = self._visits
        with np.errstate(invalid="ignore", divide="ignore"):
            avg = np.bincount(vert, val, minlength=n) / count
            dev = val - avg[vert]
            std = np.sqrt(np.bincount(vert, dev * dev, minlength=n) / count)
        worst = np.full(n, -np.inf)
        np.maximum.at(worst, vert, val)
        worst[count == 0] = np.nan
        median = np.full(n, np.nan)
        if len(val):
            order = np.lexsort((val, vert))
            sv = val[order]
            start = np.concatenate([[0], np.cumsum(count)[:-1]])
            seen = count > 0
            lo = start[seen] + (count[seen] - 1) // 2
            hi = start[seen] + count[seen] // 2
            median[seen] = 0.5 * (sv[lo] + sv[hi])
        span = self.t - self.start_time
        mean_idle = self._area / span if span > 0 else self.idleness()
        return {
            "visits": count.copy(),
            "avg": avg,
            "std": std,
            "median": median,
            "worst": worst,
            "mean_idleness": mean_idle,
            "worst_idleness": self._worst_now.copy(),
        }

    # --- reports -------------------------------------------------------------------

    def summary(self) -> dict[str, Any]:
        """The run's numbers, JSON-ready (NaN where nothing was measured yet; the
        project's ``json_dumps`` writes it as null).

        ``avg_idleness``, ``std_idleness`` (population), ``median_idleness`` and
        ``worst_idleness_visits`` are over every visit interval (patrolling_sim's);
        ``worst_instantaneous_idleness`` is the largest idleness of any vertex at an
        update, never-visited vertices included; ``mean_instantaneous_idleness`` and
        ``mean_max_idleness`` are time averages of the mean and the max of idleness over
        the vertices (the graph's mean TB and MTB). ``interference_events`` counts
        onsets of a close pair (closer than ``interference_distance`` at an update and
        not at the one before; a pair already close at the first update counts there).
        """
        _, val = self.intervals()
        span = self.t - self.start_time
        ij, _ = self.graph.edges()
        nan = math.nan
        minutes = span / 60.0
        return {
            "graph_vertices": len(self.graph),
            "graph_edges": len(ij),
            "graph_connected": self.graph.connected(),
            "graph_spacing_m": self.graph.spacing,
            "visit_radius_m": self.visit_radius,
            "monitor_steps": self.steps,
            "monitor_seconds": span,
            "visits": len(val),
            "avg_idleness": float(val.mean()) if len(val) else nan,
            "std_idleness": float(val.std()) if len(val) else nan,
            "median_idleness": float(np.median(val)) if len(val) else nan,
            "worst_idleness_visits": float(val.max()) if len(val) else nan,
            "worst_instantaneous_idleness": float(self._worst_now.max()),
            "mean_instantaneous_idleness": self._area_mean / span if span > 0 else nan,
            "mean_max_idleness": self._area_max / span if span > 0 else nan,
            "never_visited_vertices": int((self._visits == 0).sum()),
            "complete_cycles": len(self._cycle_times),
            "last_cycle_time": self._cycle_times[-1] if self._cycle_times else nan,
            "interference_distance_m": self.interference_distance,
            "interference_events": self._events,
            "interference_rate_per_robot_min": (
                self._events / self.robots / minutes if self.robots and minutes > 0 else nan
            ),
        }

    def cycle_times(self) -> F64:
        """Times (seconds) at which each complete patrol cycle ended."""
        return np.array(self._cycle_times, dtype=np.float64)

    def idleness_series(self) -> dict[str, F64]:
        """The idleness over time: ``step`` (from 1), ``t`` (s), ``mean`` and ``max``
        idleness over the vertices (s), every ``k``-th step and the latest."""
        rows = list(self._series)
        if self._latest is not None and (not rows or rows[-1][0] != self._latest[0]):
            rows.append(self._latest)
        a = np.array(rows, dtype=np.float64).reshape(-1, 4)
        return {"step": a[:, 0], "t": a[:, 1], "mean": a[:, 2], "max": a[:, 3]}

    def idleness_csv(self) -> str:
        """``idleness.csv``: step, t (s), mean_idleness and max_idleness (s) over the
        vertices, at most ``max_rows`` + 1 rows below the header."""
        s = self.idleness_series()
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["step", "t", "mean_idleness", "max_idleness"])
        for k, t, m, top in zip(s["step"], s["t"], s["mean"], s["max"], strict=True):
            w.writerow([int(k), f"{t:g}", f"{m:.6g}", f"{top:.6g}"])
        return buf.getvalue()

    def per_vertex_csv(self) -> str:
        """One row per vertex: its number, cell, position (m), degree, visits, the
        average, std, median and worst of its visit intervals (s; empty with no
        visit), and its time-average and worst instantaneous idleness (s)."""
        pv = self.per_vertex()
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(
            [
                "vertex",
                "row",
                "col",
                "x",
                "y",
                "degree",
                "visits",
                "avg_interval",
                "std_interval",
                "median_interval",
                "worst_interval",
                "mean_idleness",
                "worst_idleness",
            ]
        )
        g = self.graph
        for i in range(len(g)):
            w.writerow(
                [
                    i,
                    int(g.cells[i, 0]),
                    int(g.cells[i, 1]),
                    f"{g.xy[i, 0]:.6g}",
                    f"{g.xy[i, 1]:.6g}",
                    len(g.neighbours[i]),
                    int(pv["visits"][i]),
                    *(_fmt(float(pv[k][i])) for k in ("avg", "std", "median", "worst")),
                    _fmt(float(pv["mean_idleness"][i])),
                    _fmt(float(pv["worst_idleness"][i])),
                ]
            )
        return buf.getvalue()

    # --- checkpoints ---------------------------------------------------------------

    def _params(self) -> dict[str, Any]:
        return {
            "visit_radius": self.visit_radius,
            "start_idleness": self.start_idleness,
            "start_time": self.start_time,
            "interference_distance": self.interference_distance,
            "snap": self.snap,
            "max_rows": self.max_rows,
        }

    def state(self) -> dict[str, Any]:
        """Everything the monitor has gathered, as plain values (:meth:`restore`)."""
        return {
            "params": self._params(),
            "t": self.t,
            "steps": self.steps,
            "robots": self.robots,
            "last": self._last.tolist(),
            "covered": self._covered.tolist(),
            "area": self._area.tolist(),
            "worst_now": self._worst_now.tolist(),
            "visits": self._visits.tolist(),
            "iv_vertex": self._iv_vertex.view.tolist(),
            "iv_value": self._iv_value.view.tolist(),
            "since_cycle": self._since_cycle.tolist(),
            "cycle_times": list(self._cycle_times),
            "close": self._close.tolist(),
            "events": self._events,
            "area_mean": self._area_mean,
            "area_max": self._area_max,
            "series": [list(r) for r in self._series],
            "stride": self._stride,
            "latest": None if self._latest is None else list(self._latest),
        }

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state` of a monitor on the same graph, with the same
        parameters."""
        v = len(self.graph)
        if len(state["last"]) != v:
            raise ValueError(f"a state of {len(state['last'])} vertices for a graph of {v}")
        if dict(state["params"]) != self._params():
            raise ValueError(
                f"a state of a monitor set up otherwise: {dict(state['params'])}, "
                f"not {self._params()}"
            )
        self.t = float(state["t"])
        self.steps = int(state["steps"])
        self.robots = int(state["robots"])
        self._last = np.array(state["last"], dtype=np.float64)
        self._covered = np.array(state["covered"], dtype=bool)
        self._area = np.array(state["area"], dtype=np.float64)
        self._worst_now = np.array(state["worst_now"], dtype=np.float64)
        self._visits = np.array(state["visits"], dtype=np.int64)
        self._iv_vertex.set(state["iv_vertex"])
        self._iv_value.set(state["iv_value"])
        self._since_cycle = np.array(state["since_cycle"], dtype=bool)
        self._cycle_times = [float(x) for x in state["cycle_times"]]
        close = np.array(state["close"], dtype=bool)
        self._close = close.reshape(self.robots, self.robots) if close.size else close
        self._events = int(state["events"])
        self._area_mean = float(state["area_mean"])
        self._area_max = float(state["area_max"])
        self._series = [(int(r[0]), float(r[1]), float(r[2]), float(r[3])) for r in state["series"]]
        self._stride = int(state["stride"])
        latest = state["latest"]
        self._latest = (
            None
            if latest is None
            else (int(latest[0]), float(latest[1]), float(latest[2]), float(latest[3]))
        )
