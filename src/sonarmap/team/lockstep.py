"""The team's one clock: the lock-step loop that both the simulated team
(:func:`~.simulation.run_team`) and a ZeroMQ node (:func:`~.node.run_node`) drive.

The ticks are the union of every robot's route time stamps, then the quiet phase's
ticks of the routes' median step (``request_every`` for a route of one step). At each
tick of the routes every robot processes its route up to the tick and then exchanges;
after the routes the robots stand still and keep exchanging until the network is
*quiet*: no exchanger has added or deleted a pose for ``quiet`` seconds and none awaits
an answer, or ``settle`` seconds have passed since the routes ended. The loops differ
only in how a tick's messages are delivered and how the team's figures are gathered
(the sum over the simulated exchangers; the peers' ``done`` markers over ZeroMQ), which
are the caller's ``tick`` and ``team`` callables.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["LockstepClock", "quiet_seconds", "team_ticks"]

F64 = npt.NDArray[np.float64]


def team_ticks(routes: list[F64]) -> F64:
    """The ticks of the routes: the union of their time stamps, sorted."""
    return np.unique(np.concatenate([r[:, 0] for r in routes]))


def quiet_seconds(advert_every: float, request_every: float, quiet: float | None) -> float:
    """Seconds without a change after which the network counts as quiet: ``quiet``, by
    default two adverts and two request rounds."""
    return 2 * advert_every + 2 * request_every if quiet is None else quiet


@dataclass
class LockstepClock:
    """Where a team is on its clock, and the quiet-network rule.

    Parameters
    ----------
    times : ndarray (T,)
        The routes' ticks (:func:`team_ticks`), seconds.
    quiet : float
        Seconds without an added or deleted pose (and nothing awaited) that end the run.
    settle : float
        Seconds of exchange at most after the routes end.
    step : float
        Seconds between two ticks of the quiet phase.

    Attributes
    ----------
    next : int
        The next tick to run.
    t : float
        Mission time of the last tick run after the routes (NaN before).
    last_change : float
        Mission time of the last tick whose team figures changed.
    count : int
        The team's poses added plus deleted by the exchange, as last seen.
    sent : int
        The caller's bytes sent when the routes ended (for per-minute figures).
    settled, done : bool
        Whether the network went quiet; whether the run is over.
    restarts : int
        How often the loop was resumed from a :meth:`state`.
    """

    times: F64
    quiet: float
    settle: float
    step: float
    next: int = 0
    t: float = math.nan
    last_change: float = math.nan
    count: int = 0
    sent: int = 0
    settled: bool = False
    done: bool = False
    restarts: int = 0

    @classmethod
    def for_ticks(
        cls, times: F64, *, quiet: float, settle: float, request_every: float
    ) -> LockstepClock:
        """The clock of ``times``, its quiet phase stepping by the routes' median step."""
        step = float(np.median(np.diff(times))) if len(times) > 1 else request_every
        return cls(np.asarray(times, dtype=np.float64), quiet, settle, step)

    @property
    def end(self) -> float:
        """Mission time the routes end at."""
        return float(self.times[-1])

    @property
    def start(self) -> float:
        return float(self.times[0])

    def run(
        self,
        tick: Callable[[int, float, bool], None],
        team: Callable[[int], tuple[int, bool]],
        *,
        routes_end: Callable[[], int] | None = None,
        after: Callable[[int, float, bool], None] | None = None,
    ) -> None:
        """Run the ticks from :attr:`next` until the run is over.

        Parameters
        ----------
        tick : callable
            ``tick(n, t, driving)``: tick ``n`` at mission time ``t``; ``driving`` while
            the routes last (robots process their routes up to ``t`` and ask for the
            regions they visit next), False in the quiet phase (robots stand still,
            their exchangers finished).
        team : callable
            ``team(n) -> (changes, outstanding)``: the team's poses added plus deleted
            by the exchange so far, and whether any robot awaits an answer, after tick
            ``n``. Called after the routes' last tick and after each quiet tick.
        routes_end : callable, optional
            Called once, after the routes' last tick; returns the bytes sent by then
            (:attr:`sent`).
        after : callable, optional
            ``after(n, t, driving)``, after every tick (progress, checkpoints).
        """
        T = len(self.times)
        end = self.end
        while not self.done:
            n = self.next
            if n < T:
                t = float(self.times[n])
                tick(n, t, True)
                if n == T - 1:
                    self.count, _ = team(n)
                    if routes_end is not None:
                        self.sent = routes_end()
                    self.t = self.last_change = end
                    self.done = not self.t < end + self.settle
                driving = True
            else:
                t = self.t + self.step
                tick(n, t, False)
                changes, outstanding = team(n)
                self.t = t
                if changes != self.count or outstanding:
                    self.count, self.last_change = changes, t
                elif t - self.last_change >= self.quiet:
                    self.settled = self.done = True
                if not self.t < end + self.settle:
                    self.done = True
                driving = False
            self.next = n + 1
            if after is not None:
                after(n, t, driving)

    @property
    def settle_seconds(self) -> float:
        """Seconds the quiet phase took."""
        return self.t - self.end

    @property
    def convergence_s(self) -> float:
        """Seconds from the end of the routes to the last change."""
        return self.last_change - self.end

    def state(self) -> dict[str, Any]:
        """Where the clock is, as plain msgpack values (:meth:`restore`); the ticks and
        settings are the caller's."""
        d = asdict(self)
        for k in ("times", "quiet", "settle", "step"):
            del d[k]
        return d

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take back a :meth:`state`; counts one more restart."""
        self.next = int(state["next"])
        self.t = float(state["t"])
        self.last_change = float(state["last_change"])
        self.count = int(state["count"])
        self.sent = int(state["sent"])
        self.settled = bool(state["settled"])
        self.done = bool(state["done"])
        self.restarts = int(state["restarts"]) + 1
