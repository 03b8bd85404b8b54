"""What a patrol run measured (:class:`PatrolResult`): MTB(t), the mean TB(t) and the
DVT per step, the robots' final state, and the files a run writes.

:func:`~sonarmap.patrol.simulation.run_patrol` returns one; its notes say how the
reported MTB is averaged (after a warm-up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from .monitor import Monitor
from .reach import Reach
from .settings import PatrolConfig
from .starts import format_starts
from .territory import Territory

__all__ = ["PatrolResult"]

F64 = npt.NDArray[np.float64]


@dataclass
class PatrolResult:
    """Per step: time, MTB(t), mean TB(t); and the robots' final state."""

    t: F64
    mtb: F64
    mean_tb: F64
    positions: F64
    config: PatrolConfig
    wall_seconds: float
    blocked_steps: npt.NDArray[np.int64]
    #: TB of every cell at the end.
    final_tb: F64
    #: Steps each robot spent in the dead-end escape mode (cars only).
    escape_steps: npt.NDArray[np.int64]
    #: The team's mean DVT so far, in %, after each step.
    dvt: F64
    #: The cells the metric watches (:attr:`Reach.watched`).
    watched: npt.NDArray[np.bool_]
    #: Share of the watched cells no robot ever saw.
    unseen: float = 0.0
    #: What the team patrolled and what was left out (:mod:`.reach`).
    reach: Reach | None = None
    #: World (x, y, heading) of every robot at the start.
    starts: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    #: Watched cells no robot ever saw.
    never_seen: npt.NDArray[np.bool_] | None = None
    #: patrolling_sim's metrics on the patrol graph (``run_patrol(graph=True)``).
    monitor: Monitor | None = None
    #: Share of the watched cells the cars had given up at the end (:mod:`.giveup`).
    given_up: float = 0.0
    #: Tracking cars: the stalls each car was found in (:meth:`.robots.Car.unstall`);
    #: None for other robots.
    stalls: npt.NDArray[np.int64] | None = None
    #: Tracking cars: the stall watch's ``stall_radius`` (m) and ``stall_steps``,
    #: recorded in ``summary.json``'s params; None for other robots.
    stall_watch: tuple[float, int] | None = None

    def dvt_per_robot(self) -> F64:
        """Share of the run each robot spent escaping dead ends, in %."""
        return 100.0 * self.escape_steps / max(1, len(self.t))

    def summary(self) -> dict[str, Any]:
        after = self.t > self.config.warmup_s
        return {
            "mean_mtb": float(self.mtb[after].mean()) if after.any() else math.nan,
            "mean_mtb_all_steps": float(self.mtb.mean()),
            "worst_idleness": float(self.mtb.max()),
            "mean_idleness": float(self.mean_tb[after].mean()) if after.any() else math.nan,
            # Holonomic robots never enter the dead-end escape mode: 0 for them.
            "dvt": float(self.dvt_per_robot().mean()),
            "dvt_per_robot": [round(float(v), 3) for v in self.dvt_per_robot()],
            "blocked_share": float(self.blocked_steps.sum() / (len(self.t) * len(self.positions))),
            # Places no robot has seen yet: while any is left, MTB(t) is the time itself
            # and the mean MTB says only that the run was too short.
            "never_seen": self.unseen,
            # Never-seen places tracking cars stopped going for (they still count above).
            "given_up": self.given_up,
            **(self.reach.summary() if self.reach is not None else {}),
            "steps": len(self.t),
            "sim_seconds": float(self.t[-1]) if len(self.t) else 0.0,
            "wall_seconds": round(self.wall_seconds, 3),
            "robots": len(self.positions),
            **({"graph": self.monitor.summary()} if self.monitor is not None else {}),
            **(
                {"stalls": int(self.stalls.sum()), "stalls_per_robot": self.stalls.tolist()}
                if self.stalls is not None
                else {}
            ),
        }

    def metrics_csv(self) -> str:
        """``metrics.csv``: per step its number (from 1), time (s), MTB (s), mean TB (s)
        and the team's mean DVT so far (%)."""
        import csv
        import io

        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["step", "t", "mtb", "mean_tb", "dvt"])
        for k in range(len(self.t)):
            w.writerow(
                [
                    k + 1,
                    f"{self.t[k]:g}",
                    f"{self.mtb[k]:g}",
                    f"{self.mean_tb[k]:.4g}",
                    f"{self.dvt[k]:.4g}",
                ]
            )
        return buf.getvalue()

    def batch_output(self, period: int = 1) -> str:
        """The thesis's batch output: ``step MTB DVT`` every ``period`` steps."""
        period = max(1, int(period))
        rows = [
            f"{k + 1} {self.mtb[k]:g} {self.dvt[k]:.4g}"
            for k in range(len(self.t))
            if (k + 1) % period == 0
        ]
        return "\n".join(rows) + "\n"

    def write(
        self,
        folder: str | Path,
        territory: Territory,
        *,
        seed: int,
        source: str = "",
        batch: tuple[str, int] | None = None,
        animation: Any = None,
    ) -> list[Path]:
        """Write the run's results into ``folder``, all or none (atomically).

        Parameters
        ----------
        folder : str or path-like
            The output folder, created (or replaced) whole.
        territory : Territory
            The territory patrolled (for ``fog.png`` and the cell size).
        seed : int
            The run's seed, recorded in ``summary.json``.
        source : str
            The map's name or file, recorded in ``summary.json``.
        batch : (str, int), optional
            The thesis's batch output: a file name (in ``folder``) and its period in
            steps (``setup.json``'s ``output_file`` and ``log_period_steps``).
        animation : sonarmap.plot.FogAnimation, optional
            Frames recorded during the run, saved as ``patrol.gif``.

        Returns
        -------
        list of Path
            The files written: ``metrics.csv``, ``summary.json``, ``fog.png``,
            ``starts.txt`` (the starts used, in the start-file format); with the patrol
            graph's monitor ``idleness.csv`` (the idleness of its vertices over time),
            ``vertices.csv`` (per vertex) and ``idleness.png``; then the batch output
            and ``patrol.gif`` when asked for.
        """
        # Imported here: the plotting stack is only needed to write.
        from ..files import atomic_folder, atomic_write_text, json_dumps
        from ..plot import save_fog_picture, save_idleness_plot

        out = Path(folder)
        robots = self.summary()["robots"]
        names = ["metrics.csv", "summary.json", "fog.png", "starts.txt"]
        with atomic_folder(out) as tmp:
            atomic_write_text(tmp / "starts.txt", format_starts(self.starts, territory))
            if animation is not None:
                animation.title = f"{self.config.policy}, {robots} robots"
                animation.save(tmp / "patrol.gif")
            atomic_write_text(tmp / "metrics.csv", self.metrics_csv())
            if batch is not None:
                name = Path(batch[0]).name
                atomic_write_text(tmp / name, self.batch_output(batch[1]))
                names.append(name)
            summary: dict[str, Any] = {
                **self.summary(),
                "map": source,
                "cell_m": territory.grid.resolution,  # the cell used (whole map pixels)
                "seed": seed,
                "params": {
                    **self.config.as_dict(),
                    **(
                        {"stall_radius": self.stall_watch[0], "stall_steps": self.stall_watch[1]}
                        if self.stall_watch is not None
                        else {}
                    ),
                },
            }
            atomic_write_text(tmp / "summary.json", json_dumps(summary) + "\n")
            if self.monitor is not None:
                atomic_write_text(tmp / "idleness.csv", self.monitor.idleness_csv())
                atomic_write_text(tmp / "vertices.csv", self.monitor.per_vertex_csv())
                save_idleness_plot(
                    self.monitor.idleness_series(),
                    tmp / "idleness.png",
                    title=f"{robots} robots, {len(self.monitor.graph)} patrol-graph vertices",
                )
                names += ["idleness.csv", "vertices.csv", "idleness.png"]
            save_fog_picture(
                territory.grid,
                territory.free,
                self.final_tb,
                self.positions,
                tmp / "fog.png",
                radius=self.config.radius,
                title=f"{robots} robots, t = {self.t[-1]:.0f} s",
                outside=territory.free & ~self.watched,
                unknown=territory.unknown,
                never_seen=self.never_seen,
            )
        if animation is not None:
            names.append("patrol.gif")
        return [out / n for n in names]
