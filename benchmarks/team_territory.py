"""Team missions inside a territory mask on drawn plans (issue 37, item 1;
``docs/results/2026-12-07-team-territory.md``).

The training stand-ins for a scanned plan whose outside is drawn free (``scanned:1``,
``scanned:2``: :func:`benchmarks.team_world.scanned_standin`; ``standin:0``:
:func:`benchmarks.team_bound.standin_plan`) and the mask a user would draw for each: the
building's outline as a polygon file.

Run with ``python -m benchmarks.team_territory --out DIR [--seeds 0 1] [--drawn]``:

- writes ``DIR/maps/{scanned1,scanned2,standin0}.yaml`` and the outlines
  ``DIR/maps/{scanned,standin0}-inside.txt``, for ``sonarmap team run --territory``;
- prints, per map and seed, the share of robot 0's route (as ``team run`` draws it,
  1,200 s) and of the world's landmarks inside the outline (shrunk by half a cell, so a
  landmark on the outer wall's outer face counts as outside), without and with the
  mask, and where the masked world's landmarks counted outside lie;
- prints, per map, what the mask leaves the robot (``territory_record``), the area a
  robot reaches without a mask (``territory_reach(plan, None)``) and the pieces a robot
  fits in inside the mask (8-connected passable cells, their areas largest first);
- draws ``DIR/standin0.png``: standin:0's route and landmarks without and with the mask;
- with ``--drawn``, the candidate default of item 3 measured against its rule: whether a
  map "looks drawn" (under 1 % unknown, at least half its border free) and what leaving
  out the free cells connected to the border would leave out;
- with ``--footprint``, the building-footprint default
  (``docs/results/2026-12-07-team-footprint.md``) measured against the rule stated there
  before measuring: the detector's call and figures per map
  (:func:`sonarmap.team.territory.footprint`), the share of the outside's and the
  inside's free area it leaves out, and whether the largest piece a robot fits in is the
  outline's; ``--no-shares`` skips the route and landmark shares (the slow part);
  ``--maps A.yaml B.yaml`` measures those maps instead (held-out ones), against the
  scanned stand-ins' outline or ``--outline FILE``.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from benchmarks.team_bound import standin_plan
from benchmarks.team_world import scanned_standin
from sonarmap.builtins import builtin_plan
from sonarmap.errors import InputError
from sonarmap.io.rosmap import FREE, UNKNOWN, OccupancyMap, read_map, write_map
from sonarmap.patrol.territory import Territory
from sonarmap.team.territory import (
    ROBOT_RADIUS,
    footprint,
    read_territory,
    territory_reach,
    territory_record,
)
from sonarmap.team.world import make_world, patrol_route

SHARED = Path("/work/shared/data/maps")
#: Map label -> (file stem, outline stem, the building's outline x0, y0, x1, y1 in metres).
STANDINS = {
    "scanned:1": ("scanned1", "scanned-inside", (0.0, 0.0, 40.0, 30.0)),
    "scanned:2": ("scanned2", "scanned-inside", (0.0, 0.0, 40.0, 30.0)),
    "standin:0": ("standin0", "standin0-inside", (0.0, 0.0, 100.0, 80.0)),
}
DURATION = 1200.0


def _plan(label: str) -> OccupancyMap:
    kind, _, seed = label.partition(":")
    return scanned_standin(int(seed)) if kind == "scanned" else standin_plan(int(seed))


def write_inputs(folder: Path) -> None:
    """The stand-ins as map files and their outlines as polygon files, as a user has them."""
    folder.mkdir(parents=True, exist_ok=True)
    for label, (stem, outline, (x0, y0, x1, y1)) in STANDINS.items():
        write_map(_plan(label), folder / stem)
        (folder / f"{outline}.txt").write_text(
            f"# the building's outline ({label}), metres in the map's frame\n"
            f"{x0:g} {y0:g}\n{x1:g} {y0:g}\n{x1:g} {y1:g}\n{x0:g} {y1:g}\n"
        )


def _inside(xy: npt.NDArray[np.float64], box: tuple[float, ...], pad: float) -> float:
    x0, y0, x1, y1 = box
    x, y = xy[:, 0], xy[:, 1]
    ok = (x > x0 + pad) & (x < x1 - pad) & (y > y0 + pad) & (y < y1 - pad)
    return float(ok.mean()) if len(ok) else float("nan")


def _outside(xy: npt.NDArray[np.float64], box: tuple[float, ...], pad: float) -> str:
    """The points counted outside the shrunk outline, as their x and y ranges, metres."""
    x0, y0, x1, y1 = box
    x, y = xy[:, 0], xy[:, 1]
    out = ~((x > x0 + pad) & (x < x1 - pad) & (y > y0 + pad) & (y < y1 - pad))
    if not out.any():
        return "none"
    return (
        f"{int(out.sum())} at x = {x[out].min():.2f}-{x[out].max():.2f} m, "
        f"y = {y[out].min():.2f}-{y[out].max():.2f} m"
    )


def pieces(plan: OccupancyMap, region: npt.NDArray[np.bool_]) -> None:
    """The reached area without a mask and the pieces a robot fits in inside the mask."""
    cell = plan.grid.resolution**2
    free = territory_reach(plan, None).watched
    print(f"  without a mask: reached {free.sum() * cell:,.1f} m^2", flush=True)
    ok = Territory.from_map(plan).passable(ROBOT_RADIUS) & region
    labels, n = ndimage.label(ok, structure=np.ones((3, 3), dtype=bool))
    sizes = np.sort(np.bincount(labels.ravel(), minlength=n + 1)[1:])[::-1] * cell
    shown = ", ".join(f"{a:,.1f}" for a in sizes[:8])
    print(
        f"  inside the mask: {n} passable pieces, {shown}{', ...' if n > 8 else ''} m^2 "
        f"(passable cells' area), {sizes.sum():,.1f} m^2 in all",
        flush=True,
    )


def shares(folder: Path, seeds: list[int], picture: Path | None) -> None:
    """The routes' and landmarks' shares inside the outline, without and with the mask."""
    print("| map | seed | route inside, none -> mask | landmarks inside, none -> mask |")
    print("|---|---|---|---|")
    for label, (stem, outline, box) in STANDINS.items():
        plan = read_map(folder / f"{stem}.yaml")
        mask = folder / f"{outline}.txt"
        region = read_territory(mask, plan)
        half = 0.5 * plan.grid.resolution
        for seed in seeds:
            r0 = patrol_route(plan, DURATION, seed=seed)
            r1 = patrol_route(plan, DURATION, seed=seed, region=region)
            w0 = make_world(plan, seed=seed, duration=DURATION)
            w1 = make_world(plan, seed=seed, duration=DURATION, region=region)
            print(
                f"| {label} | {seed} | {_inside(r0[:, 1:3], box, half):.3f} -> "
                f"{_inside(r1[:, 1:3], box, half):.3f} | "
                f"{_inside(w0.points[:, :2], box, half):.3f} (of {len(w0):,}) -> "
                f"{_inside(w1.points[:, :2], box, half):.3f} (of {len(w1):,}) |",
                flush=True,
            )
            print(f"  masked landmarks outside: {_outside(w1.points[:, :2], box, half)}")
            if picture is not None and label == "standin:0" and seed == seeds[0]:
                _draw(plan, [(r0, w0.points), (r1, w1.points)], picture)
        print(f"{label}: {territory_record(mask, plan, region)}", flush=True)
        pieces(plan, region)


def pyplot_and_extent(plan: OccupancyMap) -> tuple[Any, tuple[float, float, float, float]]:
    """Matplotlib's pyplot on the file-only backend, and ``plan``'s extent (x min, x
    max, y min, y max, metres) for ``imshow`` with ``origin="upper"``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = plan.grid
    x0, y0 = g.origin
    return plt, (x0, x0 + g.cols * g.resolution, y0, y0 + g.rows * g.resolution)


def _draw(
    plan: OccupancyMap,
    runs: list[tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]],
    path: Path,
) -> None:
    plt, extent = pyplot_and_extent(plan)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    titles = ("no mask", "--territory (outline)")
    for ax, (route, points), title in zip(axes, runs, titles, strict=True):
        ax.imshow(plan.classes() != FREE, cmap="Greys", extent=extent, origin="upper")
        ax.plot(route[:, 1], route[:, 2], color="tab:blue", lw=0.6)
        ax.scatter(points[:, 0], points[:, 1], s=1, color="tab:green")
        ax.set_title(f"standin:0, robot 0's route (1,200 s) and landmarks: {title}")
        ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def drawn(folder: Path) -> None:
    """Item 3's candidate default measured against the rule stated before measuring."""
    maps = _maps(folder)
    eight = np.ones((3, 3), dtype=bool)
    print("| map | unknown | border free | drawn | free connected to the border | "
          "left out: outside / inside | largest piece as the outline's |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for label, (plan, mask) in maps.items():
        cls = plan.classes()
        free = cls == FREE
        border = np.zeros_like(free)
        border[0, :] = border[-1, :] = border[:, 0] = border[:, -1] = True
        unknown, edge = float((cls == UNKNOWN).mean()), float(free[border].mean())
        labels, _ = ndimage.label(free, structure=eight)
        touching = np.unique(labels[border & free])
        outside = np.isin(labels, touching[touching > 0])
        cells = [f"{unknown:.3f}", f"{edge:.3f}", str(unknown < 0.01 and edge >= 0.5)]
        cells.append(f"{outside.sum() / max(1, free.sum()):.3f}")
        if mask is None:
            cells += ["-", "-"]
        else:
            region = read_territory(mask, plan)
            fin, fout = free & region, free & ~region
            cells.append(f"{(outside & fout).sum() / fout.sum():.3f} / "
                         f"{(outside & fin).sum() / fin.sum():.3f}")  # fmt: skip
            try:
                a = territory_reach(plan, ~outside).passable
                b = territory_reach(plan, region).passable
                cells.append(f"{int((a & b).sum())} of {int(a.sum())} / {int(b.sum())} cells")
            except InputError:
                cells.append("no place left")
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)


def _maps(folder: Path) -> dict[str, tuple[OccupancyMap, Path | None]]:
    maps: dict[str, tuple[OccupancyMap, Path | None]] = {}
    for label, (stem, outline, _) in STANDINS.items():
        maps[label] = (read_map(folder / f"{stem}.yaml"), folder / f"{outline}.txt")
    for name in ("depot", "warehouse", "tb3_sandbox"):
        maps[name] = (read_map(SHARED / f"{name}.yaml"), None)
    for name in ("office", "building:1"):
        maps[name] = (builtin_plan(name), None)
    return maps


def footprints(folder: Path, extra: list[Path] | None = None, outline: Path | None = None) -> None:
    """The footprint default measured against its rule (stated before measuring), on the
    training maps or, given ``extra`` (map YAMLs), on those, against ``outline`` (default:
    the scanned stand-ins' outline)."""
    maps: dict[str, tuple[OccupancyMap, Path | None]]
    if extra:
        mask_of = outline or folder / "scanned-inside.txt"
        maps = {m.stem: (read_map(m), mask_of) for m in extra}
    else:
        maps = _maps(folder)
    print(
        "| map | unknown | border free, off the footprint | walls in the largest piece "
        "| 4 m disc's footprint: differs by | drawn (why) "
        "| left out: outside / inside (cells of the inside's free) "
        "| left out, m^2 | largest piece as the outline's |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for label, (plan, mask) in maps.items():
        fp = footprint(plan)
        f = fp.figures()
        cells = [str(f["plan_unknown_share"]), str(f["margin_share"]), str(f["building_share"])]
        cells.append(str(f["wide_disc_disagreement"]))
        cells.append(f"{'yes' if fp.drawn else 'no'} ({fp.why})")
        if mask is None:
            cells += ["-", "-", "-"]
        else:
            free = plan.classes() == FREE
            region = read_territory(mask, plan)
            fin, fout = free & region, free & ~region
            left = free & ~fp.region
            cells.append(f"{(left & fout).sum() / fout.sum():.3f} / "
                         f"{(left & fin).sum() / fin.sum():.4f} "
                         f"({int((left & fin).sum())} of {int(fin.sum())})")  # fmt: skip
            cells.append(f"{left.sum() * plan.grid.resolution**2:,.1f}")
            try:
                a = territory_reach(plan, fp.region).passable
                b = territory_reach(plan, region).passable
                cells.append(f"{int((a & b).sum())} of {int(a.sum())} / {int(b.sum())} cells")
            except InputError:
                cells.append("no place left")
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--drawn", action="store_true", help="item 3's rule, measured")
    p.add_argument("--footprint", action="store_true", help="the footprint's rule, measured")
    p.add_argument("--no-shares", action="store_true", help="skip the route/landmark shares")
    p.add_argument(
        "--maps",
        type=Path,
        nargs="+",
        help="with --footprint: measure these map YAMLs (held-out ones) instead of the "
        "training maps, against --outline",
    )
    p.add_argument(
        "--outline",
        type=Path,
        help="with --maps: the building's outline (default: the scanned stand-ins')",
    )
    a = p.parse_args(argv)
    folder = a.out / "maps"
    write_inputs(folder)
    if not a.no_shares:
        shares(folder, a.seeds, a.out / "standin0.png")
    if a.drawn:
        drawn(folder)
    if a.footprint:
        footprints(folder, a.maps, a.outline)


if __name__ == "__main__":
    main()
