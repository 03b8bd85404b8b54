"""The car defaults one knob at a time on the fig. 3.10 map, and the picture of the run.

Setting (issue 36, docs/results/2026-12-07-cars-fig310.md): the built-in ``fig3-10`` map
at the experiments' 0.5 m cells, the map's first ``--cars`` starts, tracking cars
(``PatrolConfig(model="car", refine=True, cell=0.5, duration=D, **knobs)``), crowding
none, seed 0, as :mod:`sonarmap.patrol.experiments` runs them. Rows (``--rows``):

- ``defaults``: the car defaults (:data:`~sonarmap.patrol.simulation.CAR_DEFAULTS`);
- ``plain``: every knob at its :data:`~sonarmap.patrol.simulation.PLAIN_DEFAULTS`
  value;
- ``KNOB`` (a field of ``PLAIN_DEFAULTS``, the page's "- KNOB"): the car defaults with
  that one knob at its plain value (``forward_wave`` also sets ``forward_stale`` 0,
  which needs the forward wave).

For each row one run, printing never seen (% of the reachable map), mean MTB (s), mean
idleness (s), DVT (%) and blocked share (%), a Markdown table at the end. ``--picture
PNG`` also draws the ``defaults`` run: the places never seen at the end (red), each
car's track, and where each car ended, marked with the time from which it stood still
(moved less than 0.1 m) to the end when that is over 60 s; for each such car, in blue,
the cells its forward wave reaches from where it stands: the wave keeping to the
one-way streets' steps (:func:`~sonarmap.patrol.oneway.one_way`, built as the run
builds it) with the cells behind the car closed
(:func:`~sonarmap.patrol.manoeuvre.behind_cells`), and whether the dead-end test
(:func:`~sonarmap.patrol.manoeuvre.leads_on`, which floods the passable cells) says
the way ahead leads on.

It uses only public names, so the same file run against another version's sources
(``PYTHONPATH=OTHER/src``) gives that version's rows. Run with ``python -m
benchmarks.patrol_fig310 [--cars 4] [--duration 900] [--rows defaults plain
forward_wave ...] [--picture F.png]``; one process, one core (``NUMBA_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

import sonarmap
from sonarmap.patrol import PatrolConfig, run_patrol
from sonarmap.patrol.fog import Fog
from sonarmap.patrol.manoeuvre import behind_cells, leads_on
from sonarmap.patrol.maps import builtin_territory
from sonarmap.patrol.oneway import one_way
from sonarmap.patrol.paths import Wave
from sonarmap.patrol.reach import reach
from sonarmap.patrol.robots import Team
from sonarmap.patrol.simulation import PLAIN_DEFAULTS
from sonarmap.patrol.starts import starts_from_dm

CELL = 0.5
#: Every row, in the page's order.
ROWS = (
    "defaults",
    "plain",
    "forward_wave",
    "forward_stale",
    "one_way",
    "turn_time",
    "turn_penalty",
    "round_block",
    "out_of_sight",
)
#: A car standing still longer than this to the end is marked on the picture, s.
STOOD = 60.0


def knobs(row: str) -> dict[str, Any]:
    """The configuration fields a row sets (the rest at the car defaults)."""
    if row == "defaults":
        return {}
    if row == "plain":
        return dict(PLAIN_DEFAULTS)
    if row not in PLAIN_DEFAULTS:
        raise ValueError(f"unknown row {row!r}: one of {', '.join(ROWS)}")
    out: dict[str, Any] = {row: PLAIN_DEFAULTS[row]}
    if row == "forward_wave":
        out["forward_stale"] = 0.0
    return out


def run(row: str, cars: int, duration: float, track: bool) -> tuple[dict[str, Any], Any]:
    """One row's run: its summary and, with ``track``, the tracks and last fog."""
    territory, starts = builtin_territory("fig3-10", CELL)
    config = PatrolConfig(model="car", refine=True, cell=CELL, duration=duration, **knobs(row))
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    hs: list[np.ndarray] = []
    ts: list[float] = []
    last: dict[str, Any] = {}

    def keep(t: float, team: Team, fog: Fog) -> None:
        ts.append(t)
        xs.append(np.array(team.x, dtype=float))
        ys.append(np.array(team.y, dtype=float))
        hs.append(np.array(team.heading, dtype=float))
        last["never"] = fog.never_seen()

    poses = starts_from_dm(starts[:cars], territory)
    res = run_patrol(territory, config, starts=poses, seed=0, on_step=keep if track else None)
    drawn = None
    if track:
        g = territory.grid
        rc = np.column_stack(g.world_to_cell(poses[:, 0], poses[:, 1]))
        where = reach(territory, res.config.radius, starts=rc, vision=res.config.vision)
        drawn = {
            "territory": territory,
            "passable": where.passable,
            "one_way": bool(res.config.one_way),
            "turn_radius": res.config.turn_radius,
            "t": np.array(ts),
            "x": np.array(xs),
            "y": np.array(ys),
            "heading": np.array(hs),
            "never": last["never"],
        }
    return res.summary(), drawn


def picture(path: str, drawn: dict[str, Any], title: str) -> None:
    """Never seen at the end, the tracks, and the cars that stood to the end with the
    cells their forward wave reaches."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    territory = drawn["territory"]
    passable = drawn["passable"]
    ts, xs, ys, hs = drawn["t"], drawn["x"], drawn["y"], drawn["heading"]
    g = territory.grid
    h, w = g.shape
    x0, y0 = g.origin
    extent = (x0, x0 + w * g.resolution, y0, y0 + h * g.resolution)
    rgb = np.ones((h, w, 3))
    rgb[~territory.passable(0.0)] = 0.35
    rgb[drawn["never"]] = (0.85, 0.1, 0.1)
    steps = None
    if drawn["one_way"]:
        streets = one_way(passable, territory.clearance, g.resolution, drawn["turn_radius"])
        steps = streets.steps
    waver = Wave(passable.shape, steps)
    notes = []
    fig, ax = plt.subplots(figsize=(10, 7))
    lines = []
    for i in range(xs.shape[1]):
        moved = np.hypot(xs[:, i] - xs[-1, i], ys[:, i] - ys[-1, i]) > 0.1
        since = float(ts[np.flatnonzero(moved)[-1] + 1]) if moved.any() else float(ts[0])
        stood = float(ts[-1]) - since > STOOD
        lines.append((i, since, stood))
        if not stood:
            continue
        x, y, heading = float(xs[-1, i]), float(ys[-1, i]), float(hs[-1, i])
        r, c = (int(v) for v in g.world_to_cell(x, y))
        back = behind_cells(x, y, heading, g)
        dist, _ = waver(passable, (r, c), g.resolution, closed=back)
        reached = np.isfinite(dist)
        rgb[reached] = (0.2, 0.4, 0.95)
        ahead = leads_on(passable, back, (r, c))
        notes.append(
            f"car {i}: stood from {since:.0f} s; its forward wave reaches "
            f"{int(reached.sum())} cells; dead-end test: " + ("leads on" if ahead else "dead end")
        )
    # Row 0 is the map's top (y largest), as the grid stores it.
    ax.imshow(rgb, extent=extent, origin="upper", interpolation="nearest")
    for i, since, stood in lines:
        (line,) = ax.plot(xs[:, i], ys[:, i], lw=0.8, label=f"car {i}")
        ax.plot(xs[-1, i], ys[-1, i], "X" if stood else "o", color=line.get_color(), ms=10)
        if stood:
            ax.annotate(f"stood from {since:.0f} s", (xs[-1, i], ys[-1, i]), fontsize=9)
    ax.set_title(title + "\nred: never seen at the end; blue: a standing car's forward wave")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    for note in notes:
        print(note, flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cars", type=int, default=4)
    ap.add_argument("--duration", type=float, default=900.0)
    ap.add_argument("--rows", nargs="+", default=list(ROWS))
    ap.add_argument("--picture", help="draw the defaults run to this PNG")
    a = ap.parse_args(argv)
    for row in a.rows:
        try:
            knobs(row)
        except ValueError as e:
            print(f"--rows: {e}", file=sys.stderr)
            return 2
    if a.picture and "defaults" not in a.rows:
        print("--picture draws the defaults row: add it to --rows", file=sys.stderr)
        return 2
    print(f"sources: {os.path.dirname(sonarmap.__file__)}", flush=True)
    table = []
    for row in a.rows:
        wall = time.perf_counter()
        s, drawn = run(row, a.cars, a.duration, track=bool(a.picture) and row == "defaults")
        cells = (
            f"{100 * s['never_seen']:.3f}",
            f"{s['mean_mtb']:.0f}",
            f"{s['mean_idleness']:.0f}",
            f"{s['dvt']:.2f}",
            f"{100 * s['blocked_share']:.2f}",
        )
        table.append((row if row in ("defaults", "plain") else f"- {row}", *cells))
        print(row, *cells, f"wall {time.perf_counter() - wall:.0f} s", flush=True)
        if drawn is not None:
            picture(a.picture, drawn, f"fig3-10, {a.cars} cars, {a.duration:.0f} s, car defaults")
    print(
        f"\n| run ({a.cars} cars, {a.duration:.0f} s) | never seen % | mean MTB s "
        "| mean idleness s | DVT % | blocked % |"
    )
    print("|---|---|---|---|---|---|")
    for line in table:
        print("| " + " | ".join(line) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
