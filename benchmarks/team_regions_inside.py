"""The store's regions cut inside the mission's territory, against the whole prior
(issue 37; ``docs/results/2026-12-07-team-regions-inside.md``).

Run with ``python -m benchmarks.team_regions_inside --out DIR [--pictures]``:

- writes the training stand-ins ``DIR/maps/{scanned1,scanned2,standin0}.yaml``
  (:func:`benchmarks.team_territory.write_inputs`) for ``sonarmap team run``;
- prints, per map (the stand-ins and the shared ``depot``, ``warehouse``,
  ``tb3_sandbox``), the mission's default territory
  (:func:`sonarmap.team.territory.default_territory`: the footprint on a drawn plan,
  none elsewhere) and, for the regions cut from the whole prior and cut inside that
  territory (:func:`sonarmap.team.regions.mission_regions` without and with
  ``region``): their count, their area (total, smallest, median, largest, m^2), how
  many lie mostly (over half their area) off the territory's mask, their cuts (the
  boundaries between two regions) and how many lie at a door, and the regions robot
  0's route (1,200 s, seed 0, drawn inside the territory as ``team run`` draws it)
  passes through (:func:`sonarmap.team.survey.survey`'s ``regions_cuts``,
  ``regions_cuts_at_doors``, ``regions_on_route``), and the local layer's configured
  bound (:func:`sonarmap.team.store.local_bound` at the default store settings) with
  the regions' own sum of limits; then, per map, how many of the inside cut's regions
  are cell for cell regions of the whole prior's cut, and by how many cells on the
  territory each other one differs from the whole cut's region it overlaps most;
- with ``--pictures``, draws ``DIR/regions-NAME.png`` per map: the regions of both cuts
  in colours over the plan's walls, the territory's outline in red.

``python -m benchmarks.team_regions_inside --out DIR --prior-error SPEC...
[--prior-map scanned:1] [--seed 0]`` prints, per spec, the regions of the prior
``team run --prior-error SPEC --seed SEED`` makes of the stand-in, cut from the whole
prior and inside the plan's footprint put on the prior's cells, with the prior's free
area in a region inside and outside the prior's own footprint.

``python -m benchmarks.team_regions_inside --runs RUN...`` prints one row per
``sonarmap team run`` output folder (one robot): regions, regions used, the own layer's
peak against its bound, ATE against odometry's, association precision and recall, map
F1 against the true-pose map's.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import numpy.typing as npt

from benchmarks.team_territory import (
    DURATION,
    SHARED,
    STANDINS,
    pyplot_and_extent,
    write_inputs,
)
from sonarmap.errors import ConfigError
from sonarmap.io.rosmap import FREE, OCCUPIED, OccupancyMap, read_map
from sonarmap.team.prior import degrade_plan, parse_prior_error
from sonarmap.team.regions import mission_regions, region_sizes
from sonarmap.team.store import StoreParams, local_bound, region_limits
from sonarmap.team.survey import survey
from sonarmap.team.territory import default_territory, mask_on
from sonarmap.team.world import World, make_world, patrol_route

SHARED_MAPS = ("depot", "warehouse", "tb3_sandbox")
#: A region counts as outside when more than this share of its area is off the mask.
MOSTLY = 0.5


def training_maps(folder: Path) -> dict[str, OccupancyMap]:
    """The training stand-ins (written into ``folder``) and the shared maps, by name."""
    write_inputs(folder)
    maps = {stem: read_map(folder / f"{stem}.yaml") for stem, _, _ in STANDINS.values()}
    for name in SHARED_MAPS:
        maps[name] = read_map(SHARED / f"{name}.yaml")
    return maps


def outside_count(labels: npt.NDArray[np.int32], mask: npt.NDArray[np.bool_] | None) -> int:
    """Regions with more than :data:`MOSTLY` of their cells off ``mask`` (0 without one)."""
    if mask is None or labels.max() < 0:
        return 0
    k = int(labels.max()) + 1
    cells = np.bincount(labels[labels >= 0], minlength=k)
    off = np.bincount(labels[(labels >= 0) & ~mask], minlength=k)
    return int((off > MOSTLY * cells).sum())


def same_regions(
    whole: npt.NDArray[np.int32], inside: npt.NDArray[np.int32], mask: npt.NDArray[np.bool_]
) -> tuple[int, list[int]]:
    """Of the inside cut's regions, how many are cell for cell a region of the whole
    prior's cut, and for each other one the cells by which it differs, on the mask, from
    the whole cut's region it overlaps most (cells it gained plus cells it lost)."""
    k = int(inside.max()) + 1
    same, diffs = 0, []
    for lab in range(k):
        mine = inside == lab
        ws, n = np.unique(whole[mine], return_counts=True)
        w = int(ws[np.argmax(n)])
        theirs = whole == w
        if w >= 0 and np.array_equal(mine, theirs):
            same += 1
            continue
        diffs.append(int((mine & ~theirs).sum() + (theirs & mask & ~mine).sum()))
    return same, diffs


def _row(
    plan: OccupancyMap,
    labels: npt.NDArray[np.int32],
    mask: npt.NDArray[np.bool_] | None,
    world: World,
    route: npt.NDArray[np.float64],
) -> str:
    sizes = region_sizes(labels, plan.grid.resolution)
    params = StoreParams()
    f = survey(plan, world, route, labels).figures
    cells = [
        f"{len(sizes)}",
        f"{sizes.sum():,.1f}",
        f"{sizes.min():.1f} / {float(np.median(sizes)):.1f} / {sizes.max():.1f}",
        f"{outside_count(labels, mask)}",
        f"{f['regions_cuts_at_doors']} of {f['regions_cuts']}",
        f"{f['regions_on_route']}",
        f"{sum(region_limits(params, sizes.tolist())) / 1000:,.0f}",
        f"{local_bound(params, sizes.tolist()) / 1000:,.0f}",
    ]
    return " | ".join(cells)


def _regions(labels: npt.NDArray[np.int32]) -> int:
    return int(labels.max()) + 1


def regions_table(maps: dict[str, OccupancyMap], pictures: Path | None) -> None:
    """Print the regions of each map cut from the whole prior and inside its territory."""
    print(
        "| map | territory (free area left out, m^2) | cut | regions | area, m^2 "
        "| smallest / median / largest, m^2 | mostly off the territory "
        "| cuts at a door | on robot 0's route | regions' limits, kB | own layer's bound, kB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    changes: list[str] = []
    for name, plan in maps.items():
        terr = default_territory(plan)
        mask = None if terr is None else terr.region
        world = make_world(plan, seed=0, duration=DURATION, region=mask)
        route = patrol_route(plan, DURATION, seed=0, region=mask)
        whole = mission_regions(plan)
        inside = whole if mask is None else mission_regions(plan, region=mask)
        what = (
            "whole map (no default)"
            if terr is None
            else f"footprint ({terr.record['left_out_free_area_m2']:,.1f})"
        )
        row = _row(plan, whole, mask, world, route)
        print(f"| {name} | {what} | whole prior | {row} |")
        same = " (the same cells)" if np.array_equal(whole, inside) else ""
        row = _row(plan, inside, mask, world, route)
        print(f"| {name} | {what} | inside{same} | {row} |", flush=True)
        on = np.ones(plan.grid.shape, dtype=bool) if mask is None else mask
        kept, diffs = same_regions(whole, inside, on)
        changes.append(
            f"{name}: {kept} of {_regions(inside)} regions of the inside cut are cell for "
            f"cell regions of the whole prior's; the others differ on the territory by "
            f"{diffs} cells"
        )
        if pictures is not None:
            draw(plan, name, whole, inside, mask, pictures / f"regions-{name}.png")
    print()
    print("\n".join(changes))


def draw(
    plan: OccupancyMap,
    name: str,
    whole: npt.NDArray[np.int32],
    inside: npt.NDArray[np.int32],
    mask: npt.NDArray[np.bool_] | None,
    path: Path,
) -> None:
    """Both cuts side by side over the plan's walls, the territory's outline in red."""
    plt, extent = pyplot_and_extent(plan)
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, labels, title in zip(
        axes, (whole, inside), ("cut from the whole prior", "cut inside the territory"),
        strict=True,
    ):  # fmt: skip
        k = int(labels.max()) + 1
        # The same colour for the same label number in both panels.
        colours = np.random.default_rng(0).uniform(0.35, 0.95, size=(max(k, 1), 3))
        img = np.ones((*labels.shape, 3))
        img[labels >= 0] = colours[labels[labels >= 0]]
        img[plan.classes() == OCCUPIED] = 0.0
        ax.imshow(img, extent=extent, origin="upper", interpolation="nearest")
        if mask is not None:
            # Rows run down the image: the mask's row 0 is the top (extent's y max).
            ys = np.linspace(extent[3], extent[2], mask.shape[0])
            xs = np.linspace(extent[0], extent[1], mask.shape[1])
            ax.contour(xs, ys, mask.astype(float), levels=[0.5], colors="red", linewidths=0.8)
        ax.set_title(f"{name}: {k} regions, {title}", fontsize=9)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


def prior_error_table(folder: Path, specs: list[str], label: str, seed: int) -> None:
    """Per ``--prior-error`` spec, the prior ``team run --seed SEED`` makes of the
    stand-in ``label`` (:func:`sonarmap.team.prior.degrade_plan`), cut whole and inside
    the plan's footprint put on the prior's cells (:func:`sonarmap.team.territory.mask_on`,
    as the mission does): the regions, and the prior's free area in a region inside
    and outside the prior's own footprint (:func:`default_territory` of the prior)."""
    write_inputs(folder)
    plan = read_map(folder / f"{STANDINS[label][0]}.yaml")
    terr = default_territory(plan)
    if terr is None:
        raise SystemExit(f"--prior-map {label}: no default territory")
    print(
        "| map | seed | --prior-error | cut | regions | prior's building free area in a "
        "region, m^2 | prior's outside free area in a region, m^2 |"
    )
    print("|---|---|---|---|---|---|---|")
    for spec in specs:
        prior, _ = degrade_plan(plan, parse_prior_error(spec, seed=seed))
        own = default_territory(prior)
        if own is None:
            raise SystemExit(f"--prior-error {spec}: the prior has no footprint of its own")
        free = prior.classes() == FREE
        cell = prior.grid.resolution**2
        mask = mask_on(terr.region, plan.grid, prior.grid)
        for cut, labels in (
            ("whole prior", mission_regions(prior)),
            ("plan's footprint on the prior", mission_regions(prior, region=mask)),
        ):
            held = free & (labels >= 0)
            cells = [
                f"{_regions(labels)}",
                f"{(held & own.region).sum() * cell:,.1f}",
                f"{(held & ~own.region).sum() * cell:,.1f}",
            ]
            print(f"| {label} | {seed} | {spec} | {cut} | " + " | ".join(cells) + " |", flush=True)


def runs_table(runs: list[Path]) -> None:
    """One row per one-robot ``team run`` folder."""
    print(
        "| run | regions | regions used | own layer peak / bound, kB (within) "
        "| ATE, m (odometry) | precision | recall | map F1 (true-pose map) | ratio |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for run in runs:
        s = json.loads((run / "summary.json").read_text())
        r = s["robots"][0] if "robots" in s else s
        cells = [
            str(r["regions"]),
            str(r["regions_used"]),
            f"{r['local_bytes_peak'] / 1000:,.0f} / {r['local_bytes_bound'] / 1000:,.0f} "
            f"({'yes' if r['local_bytes_within_bound'] else 'no'})",
            f"{r['ate_m']:.3f} ({r['ate_odometry_m']:.3f})",
            f"{r['association_precision']:.3f}",
            f"{r['association_recall']:.3f}",
            f"{r['map_f1']:.3f} ({r['map_f1_true_poses']:.3f})",
            f"{r['map_f1'] / r['map_f1_true_poses']:.2f}x",
        ]
        print(f"| {run} | " + " | ".join(cells) + " |")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, help="folder for the stand-in maps and pictures")
    p.add_argument("--pictures", action="store_true", help="draw DIR/regions-NAME.png")
    p.add_argument("--runs", type=Path, nargs="+", help="team run folders to summarise")
    p.add_argument(
        "--prior-error",
        nargs="+",
        metavar="SPEC",
        help="with --out: the regions of the prior each spec makes (team run's --prior-error)",
    )
    p.add_argument(
        "--prior-map", default="scanned:1", choices=list(STANDINS), help="for --prior-error"
    )
    p.add_argument("--seed", type=int, default=0, help="for --prior-error (team run's --seed)")
    a = p.parse_args(argv)
    if a.prior_error:
        if a.out is None:
            p.error("--prior-error needs --out")
        for spec in a.prior_error:  # every spec checked before anything is written
            try:
                parse_prior_error(spec, seed=a.seed)
            except ConfigError as e:
                p.error(str(e))
        prior_error_table(a.out / "maps", a.prior_error, a.prior_map, a.seed)
        return
    if a.runs:
        runs_table(a.runs)
        return
    if a.out is None:
        p.error("--out is required without --runs")
    maps = training_maps(a.out / "maps")
    regions_table(maps, a.out if a.pictures else None)


if __name__ == "__main__":
    main()
