"""The footprint default on a small drawn building with its south entrance widened
(issue 37 review; ``docs/results/2026-12-07-team-footprint.md``).

Run with ``python -m benchmarks.footprint_entrances``: per entrance width, the share of
the inside's free area the door-wide footprint alone leaves out, the disagreement with
the 4 m disc's footprint, and the default's call. The building is the one of
``tests/test_team_footprint.py``: 8 x 6 m, one-cell walls, a 1.2 m door between its two
rooms, 5 m of free outside, drawn at 0.1 m.
"""

from __future__ import annotations

import argparse

import numpy as np
import numpy.typing as npt

from sonarmap.grid import Grid
from sonarmap.io.rosmap import FREE, OccupancyMap
from sonarmap.team.territory import building_footprint, default_territory, footprint


def building(width: float) -> tuple[OccupancyMap, npt.NDArray[np.bool_]]:
    """The plan with a ``width`` metres entrance centred at x = 6 m, and its inside."""
    grid = Grid.from_bounds(-5.0, -5.0, 13.0, 11.0, 0.1)
    occ = np.zeros(grid.shape, dtype=np.float32)
    x, y = grid.all_centres()
    ring = (x > 0.0) & (x < 8.0) & (y > 0.0) & (y < 6.0)
    inner = (x > 0.1) & (x < 7.9) & (y > 0.1) & (y < 5.9)
    occ[ring & ~inner] = 1.0
    occ[ring & (y < 0.1) & (np.abs(x - 6.0) < 0.5 * width)] = 0.0
    occ[ring & (np.abs(x - 4.05) < 0.05) & ~((y > 2.4) & (y < 3.6))] = 1.0
    return OccupancyMap(grid, occ), np.asarray(ring)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--widths", type=float, nargs="+", default=[1.2, 2.0, 3.0, 4.5, 6.0])
    a = p.parse_args(argv)
    print("| entrance, m | inside's free area left out by the door-wide footprint "
          "| 4 m disc's footprint differs by | drawn | default |")  # fmt: skip
    print("|---|---|---|---|---|")
    for w in a.widths:
        plan, inside = building(w)
        free = plan.classes() == FREE
        left = free & inside & ~building_footprint(plan)
        fp = footprint(plan)
        call = "whole map" if default_territory(plan) is None else "footprint"
        print(f"| {w:g} | {left.sum() / (free & inside).sum():.3f} | "
              f"{fp.disagreement:.4f} | {'yes' if fp.drawn else 'no'} | {call} |")  # fmt: skip


if __name__ == "__main__":
    main()
