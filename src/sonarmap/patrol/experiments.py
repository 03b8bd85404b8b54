"""The thesis's patrol experiments (chapter 3), rerun on the built-in maps, with the
literature's baselines beside them.

Each experiment is a grid of runs -- a variant (force pair, direction method, network,
crowding rule, policy, ...) x a number of robots x seeds -- run on Dask through
:func:`sonarmap.parallel.run_on_dask`. Every run starts the robots at the map's start
positions (the first N of them), so seeds change only the random moves; the tables give
the mean over seeds. The results go into ``runs.csv`` (one row per run),
``table.csv`` (means), ``claims.json`` (each ordering the thesis states, confirmed or
contradicted), figures and ``report.html``.

Only Tables 2-3 (the open field) are comparable number for number; the maps of the other
experiments are lost and the built-in ones stand in for them, so there the orderings are
what is compared. The thesis gives no run length, start fog or number of runs; here a
full run lasts ``duration`` seconds (3600), fog starts at 0 and the first fifth is left
out of the mean MTB (see :mod:`.simulation`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from ..errors import ConfigError
from ..files import atomic_folder, atomic_write_text, json_dumps
from ..parallel import run_on_dask
from ..report import Report
from .forces import FORCE_F, FORCE_G, Force
from .maps import builtin_map, builtin_territory
from .semaphores import polygon_cells
from .simulation import PatrolConfig, run_patrol
from .starts import starts_from_dm

__all__ = ["EXPERIMENTS", "THESIS_TABLE_2", "THESIS_TABLE_3", "PatrolTask", "run_experiment"]

Progress = Callable[[int, int], None]

#: Tables 2-3 of the thesis: mean MTB (s) on the open field, rows f1..f5, columns g1..g5.
THESIS_TABLE_2 = [  # vector sum
    [1476.0, 1306.9, 136.1, 199.2, 763.4],
    [927.5, 290.5, 119.1, 126.0, 218.1],
    [260.3, 143.9, 101.5, 80.7, 111.1],
    [257.9, 119.2, 204.1, 76.1, 120.6],
    [303.4, 125.0, 243.5, 94.3, 125.6],
]
THESIS_TABLE_3 = [  # mode
    [1211.3, 545.6, 132.7, 144.3, 394.2],
    [490.1, 204.7, 127.9, 113.8, 167.1],
    [167.0, 133.0, 98.5, 90.0, 125.8],
    [167.9, 140.8, 118.2, 92.9, 116.5],
    [168.5, 142.3, 192.8, 106.7, 128.3],
]
#: Table 4: fig. 3.10 map, cars, refinement, mode. (MTB, DVT) per robots and crowding rule.
THESIS_TABLE_4 = {
    "none": {1: (632.5, 5.0), 2: (354.3, 4.9), 3: (250.8, 5.4), 4: (194.8, 5.9), 5: (158.2, 5.9)},
    "semaphores": {
        1: (632.5, 5.0),
        2: (340.8, 6.0),
        3: (249.9, 6.5),
        4: (196.4, 6.7),
        5: (153.3, 6.9),
    },
    "obstacles": {
        1: (632.5, 5.0),
        2: (317.7, 5.9),
        3: (233.3, 6.5),
        4: (172.7, 6.5),
        5: (154.6, 6.8),
    },
}
#: Tables 5-6: mean MTB (s) per map, network and direction method, for 2, 3, 4 robots.
THESIS_NETWORK = {
    "fig3-2": {
        ("full", "mode"): (163.8, 124.0, 110.0),
        ("full", "vector"): (158.4, 123.2, 106.8),
        ("limited", "mode"): (178.0, 131.6, 116.0),
        ("limited", "vector"): (176.6, 136.7, 110.0),
        ("none", "mode"): (194.1, 159.9, 142.9),
        ("none", "vector"): (195.5, 175.3, 163.9),
    },
    "fig3-4": {
        ("full", "mode"): (268.7, 225.6, 168.2),
        ("full", "vector"): (264.3, 212.2, 174.1),
        ("limited", "mode"): (313.9, 240.0, 217.5),
        ("limited", "vector"): (289.0, 242.3, 217.7),
        ("none", "mode"): (389.1, 342.7, 339.8),
        ("none", "vector"): (358.0, 339.7, 333.6),
    },
}


@dataclass(frozen=True)
class PatrolTask:
    """One run: a variant of the configuration on a built-in map."""

    experiment: str
    variant: str
    map: str
    robots: int
    seed: int
    #: PatrolConfig fields that differ from the experiment's base.
    config: tuple[tuple[str, Any], ...]
    #: Extra columns of the run's row (e.g. the force pair).
    extra: tuple[tuple[str, Any], ...] = ()


def run_task(task: PatrolTask) -> dict[str, Any]:
    """Run one task (on a Dask worker); its row of results."""
    cfg = dict(task.config)
    force = cfg.pop("force", None)
    config = PatrolConfig(**cfg)
    if force is not None:
        config = replace(config, force=Force(*force))
    territory, starts = builtin_territory(task.map, config.cell)
    if task.robots > len(starts):
        raise ConfigError(f"map {task.map} has {len(starts)} starts, not {task.robots}")
    semaphores = None
    if config.crowding == "semaphores":
        semaphores = [polygon_cells(p, territory.grid) for p in builtin_map(task.map).semaphores]
    res = run_patrol(
        territory,
        config,
        starts=starts_from_dm(starts[: task.robots], territory),
        seed=task.seed,
        semaphores=semaphores,
    )
    s = res.summary()
    return {
        "experiment": task.experiment,
        "map": task.map,
        "variant": task.variant,
        **dict(task.extra),
        "robots": task.robots,
        "seed": task.seed,
        "mean_mtb": s["mean_mtb"],
        "worst_idleness": s["worst_idleness"],
        "mean_idleness": s["mean_idleness"],
        "dvt": s["dvt"],
        "blocked_share": s["blocked_share"],
        "never_seen": s["never_seen"],
        "wall_seconds": s["wall_seconds"],
        "sim_seconds": s["sim_seconds"],
        # A digest of the MTB series: equal runs have equal digests.
        "mtb_digest": float(np.round(res.mtb, 6).sum()) + 1e-3 * float(np.round(res.dvt, 6).sum()),
    }


@dataclass
class Plan:
    """The runs of one experiment and the base configuration they share."""

    name: str
    what: str
    base: dict[str, Any]
    variants: dict[str, dict[str, Any]]
    maps: Sequence[str]
    robots: Sequence[int]
    extra: dict[str, dict[str, Any]] = field(default_factory=dict)

    def tasks(self, seeds: Sequence[int]) -> list[PatrolTask]:
        out = []
        for m in self.maps:
            for label, over in self.variants.items():
                cfg = {**self.base, **over}
                for n in self.robots:
                    for seed in seeds:
                        out.append(
                            PatrolTask(
                                self.name,
                                label,
                                m,
                                n,
                                seed,
                                tuple(sorted(cfg.items())),
                                tuple(self.extra.get(label, {}).items()),
                            )
                        )
        return out


# The thesis's robot: a full step along the chosen direction, its collision rule.
HOLO = {"model": "holonomic", "motion": "straight"}
CARS = {"model": "car", "refine": True}


def _plans() -> dict[str, Plan]:
    pairs = {
        f"{f}{g} {d}": {"force": (f, g, 40.0, 65.0), "direction": d, "paths": "straight"}
        for d in ("vector", "mode")
        for f in FORCE_F
        for g in FORCE_G
    }
    extra = {k: {"f": k[:2], "g": k[2:4], "direction": k.split()[1]} for k in pairs}
    networks = {
        f"{n} {d}": {"network": n, "direction": d}
        for n in ("full", "limited", "none")
        for d in ("mode", "vector")
    }
    return {
        "forces": Plan(
            "forces",
            "Tables 2-3: the 25 force pairs f x g, vector sum and mode, on the open field "
            "(100 x 88 m, no obstacles, 3 holonomic robots at the thesis's starts, straight "
            "paths, a = 40, b = 65 dm).",
            {**HOLO},
            pairs,
            ["open-field"],
            [3],
            extra,
        ),
        "paths": Plan(
            "paths",
            "Path-finding on the fig. 3.2 map: the wave, regions and fast marching "
            "(the thesis's results for this are in a lost figure).",
            {**HOLO},
            {
                "wave": {"paths": "wave"},
                "regions": {"paths": "regions"},
                "marching": {"paths": "marching"},
            },
            ["fig3-2"],
            [2, 3, 5],
        ),
        "direction": Plan(
            "direction",
            "Mode against vector sum among many obstacles (fig. 3.4 map, holonomic, wave).",
            {**HOLO},
            {"mode": {"direction": "mode"}, "vector": {"direction": "vector"}},
            ["fig3-4"],
            [2, 3, 4],
        ),
        "car": Plan(
            "car",
            "Car-like against holonomic robots on the fig. 3.4 map (refinement on for "
            "both): MTB, and DVT per robot as the team grows.",
            {"refine": True},
            {"holonomic": {"model": "holonomic"}, "car": {"model": "car"}},
            ["fig3-4"],
            [1, 2, 3, 4, 5],
        ),
        "refine": Plan(
            "refine",
            "Direction refinement (l 10 m, R_G 2.5 m, r 2 m) on 3 cars on the fig. 3.4 map; "
            "R_G varied with r = 0.8 R_G as in the thesis's tuning.",
            {"model": "car"},
            {
                "plain": {"refine": False},
                "refine R_G 1.5": {"refine": True, "refine_goal": 1.5, "refine_side": 1.2},
                "refine R_G 2.5": {"refine": True},
                "refine R_G 3.5": {"refine": True, "refine_goal": 3.5, "refine_side": 2.8},
            },
            ["fig3-4"],
            [3],
        ),
        "weaken": Plan(
            "weaken",
            "Direction weakening min(1, r / R0) for R0 from 3.5 to 8.5 m, against "
            "refinement and neither, 3 cars on the fig. 3.4 map.",
            {"model": "car"},
            {
                "plain": {},
                "refine": {"refine": True},
                **{f"weaken R0 {r:g}": {"weaken": True, "weaken_r0": r} for r in (3.5, 5.5, 7.5)},
            },
            ["fig3-4"],
            [3],
        ),
        "crowding": Plan(
            "crowding",
            "Table 4: crowding rules on the fig. 3.10 map (240 x 159 m, narrow corridors, "
            "semaphores over the narrow lanes), cars, refinement, mode, 1-5 robots.",
            {**CARS},
            {
                "none": {"crowding": "none"},
                "semaphores": {"crowding": "semaphores"},
                "obstacles": {"crowding": "obstacles"},
            },
            ["fig3-10"],
            [1, 2, 3, 4, 5],
        ),
        "dilation": Plan(
            "dilation",
            "Fog dilation on the fig. 3.10 map with 4 cars (refinement, mode); the wing d "
            "is in cells (0.5 m at the default cell).",
            {**CARS},
            {f"d {d}": {"dilation": d} for d in (0, 1, 2, 4)},
            ["fig3-10"],
            [4],
            {f"d {d}": {"d": d} for d in (0, 1, 2, 4)},
        ),
        "network": Plan(
            "network",
            "Tables 5-6: full, limited (70 m, line of sight) and no network, mode and "
            "vector sum, refinement on, on the fig. 3.2 and fig. 3.4 maps.",
            {**HOLO, "refine": True},
            networks,
            ["fig3-2", "fig3-4"],
            [2, 3, 4],
            # The network and direction are columns of the table too.
            networks,
        ),
        "baselines": Plan(
            "baselines",
            "The potential field against the literature's strategies on every map "
            "(holonomic, wave): random walk, a reactive agent on the fog's places, "
            "conscientious and heuristic conscientious reactive agents and the state "
            "exchange Bayesian strategy on the patrol graph (cr, hcr, sebs), gravitational "
            "(Sampaio et al. 2010) and the offline cyclic tour (Chevaleyre's reference). "
            "On a real map: --map FILE (patrol.baselines).",
            {**HOLO},
            {
                p: {"policy": p}
                for p in (
                    "potential",
                    "random",
                    "reactive",
                    "cr",
                    "hcr",
                    "sebs",
                    "gravity",
                    "cycle",
                )
            },
            ["open-field", "fig3-2", "fig3-4", "fig3-10"],
            [1, 3],
        ),
    }


EXPERIMENTS = tuple(_plans())


def _means(runs: pd.DataFrame) -> pd.DataFrame:
    keys = [c for c in ("map", "variant", "robots") if c in runs]
    agg = runs.groupby(keys, sort=False).agg(
        mean_mtb=("mean_mtb", "mean"),
        mtb_sd=("mean_mtb", "std"),
        worst_idleness=("worst_idleness", "mean"),
        mean_idleness=("mean_idleness", "mean"),
        dvt=("dvt", "mean"),
        never_seen=("never_seen", "max"),
        runs=("seed", "count"),
    )
    return agg.reset_index()


def _claim(text: str, thesis: str, measured: str, ok: bool | None) -> dict[str, Any]:
    verdict = "not tested" if ok is None else ("confirmed" if ok else "contradicted")
    return {"claim": text, "thesis": thesis, "measured": measured, "verdict": verdict}


def _value(t: pd.DataFrame, col: str = "mean_mtb", **where: Any) -> float:
    sel = t
    for k, v in where.items():
        sel = sel[sel[k] == v]
    return float(sel[col].mean()) if len(sel) else math.nan


def _forces(t: pd.DataFrame, report: Report) -> list[dict[str, Any]]:
    claims = []
    for direction, thesis in (("vector", THESIS_TABLE_2), ("mode", THESIS_TABLE_3)):
        ours = _force_grid(t, direction)
        rows = []
        for i, f in enumerate(FORCE_F):
            row: dict[str, Any] = {"f": f}
            for j, g in enumerate(FORCE_G):
                row[g] = f"{ours[i, j]:.1f} ({thesis[i][j]:.1f})"
            rows.append(row)
        report.heading(f"{direction}: mean MTB, ours (thesis), seconds")
        report.table(rows)
        th = np.array(thesis)
        rank = int((ours < ours[2, 3]).sum()) + 1
        rank_th = int((th < th[2, 3]).sum()) + 1
        rho = _spearman(ours.ravel(), th.ravel())
        ratio = ours / th
        report.text(
            f"f3g4 ranks {rank} of 25 here ({rank_th} in the thesis). Spearman rank "
            f"correlation with the thesis's table: {rho:.2f}. Ours / thesis: median "
            f"{np.median(ratio):.2f}, from {ratio.min():.2f} to {ratio.max():.2f}."
        )
        claims.append(
            _claim(
                f"the adopted f3g4 is near the top ({direction})",
                f"rank {rank_th} of 25",
                f"rank {rank} of 25, {ours[2, 3]:.1f} s against {thesis[2][3]:.1f} s",
                rank <= 5,
            )
        )
        claims.append(
            _claim(
                f"the table orders the 25 pairs as the thesis's does ({direction})",
                "Table 2" if direction == "vector" else "Table 3",
                f"Spearman rho {rho:.2f}",
                rho >= 0.6,
            )
        )
    return claims


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3:
        return math.nan
    return float(spearmanr(a[ok], b[ok]).statistic)


def _force_grid(t: pd.DataFrame, direction: str) -> np.ndarray:
    """Mean MTB of every force pair for one direction method, rows f1..f5, columns
    g1..g5 (the layout of Tables 2-3)."""
    return np.array([[_value(t, variant=f"{f}{g} {direction}") for g in FORCE_G] for f in FORCE_F])


def _decreasing(values: Iterable[float]) -> bool:
    v = [x for x in values if math.isfinite(x)]
    return all(b < a for a, b in itertools.pairwise(v))


def _crowding(t: pd.DataFrame, report: Report) -> list[dict[str, Any]]:
    rows = []
    for n in sorted(t["robots"].unique()):
        row: dict[str, Any] = {"robots": int(n)}
        for v in ("none", "semaphores", "obstacles"):
            th = THESIS_TABLE_4[v].get(int(n), (math.nan, math.nan))
            row[f"MTB {v}"] = f"{_value(t, variant=v, robots=n):.1f} ({th[0]:.1f})"
        for v in ("none", "semaphores", "obstacles"):
            th = THESIS_TABLE_4[v].get(int(n), (math.nan, math.nan))
            row[f"DVT {v}"] = f"{_value(t, 'dvt', variant=v, robots=n):.1f} ({th[1]:.1f})"
        rows.append(row)
    report.heading("Table 4: mean MTB (s) and DVT (%), ours (thesis)")
    report.table(rows)
    robots = sorted(int(n) for n in t["robots"].unique())
    claims = []
    for v in ("none", "semaphores", "obstacles"):
        series = [_value(t, variant=v, robots=n) for n in robots]
        claims.append(
            _claim(
                f"more robots, lower MTB ({v})",
                "MTB falls from 1 to 5 robots",
                ", ".join(f"{x:.0f}" for x in series),
                _decreasing(series) if len(series) > 1 else None,
            )
        )
    many = [n for n in robots if n > 1]
    if many:
        gain = [
            _value(t, variant="obstacles", robots=n) < _value(t, variant="none", robots=n)
            for n in many
        ]
        claims.append(
            _claim(
                "artificial obstacles help",
                "obstacles below none for 2-5 robots",
                f"lower for {sum(gain)} of {len(many)} team sizes",
                sum(gain) > len(many) / 2,
            )
        )
    if 1 in robots:
        one = t[t["robots"] == 1]
        digests = {round(float(d), 6) for d in one["digest"]}
        claims.append(
            _claim(
                "one robot runs alike under all three crowding rules",
                "632.5 s and 5.0 % in all three",
                f"{len(digests)} distinct run(s) among the three",
                len(digests) == 1,
            )
        )
    dvt = [_value(t, "dvt", variant="none", robots=n) for n in robots]
    claims.append(
        _claim(
            "DVT grows with the number of robots",
            "5.0 % with one robot to 5.9-6.9 % with five",
            ", ".join(f"{x:.1f}" for x in dvt),
            dvt[-1] > dvt[0] if len(dvt) > 1 else None,
        )
    )
    return claims


def _network(t: pd.DataFrame, report: Report) -> list[dict[str, Any]]:
    claims = []
    gaps = {}
    for m in t["map"].unique():
        rows = []
        robots = sorted(int(n) for n in t[t["map"] == m]["robots"].unique())
        for (net, d), th in THESIS_NETWORK[str(m)].items():
            row: dict[str, Any] = {"network, direction": f"{net}, {d}"}
            for k, n in enumerate((2, 3, 4)):
                if n in robots:
                    row[f"{n} robots"] = (
                        f"{_value(t, map=m, variant=f'{net} {d}', robots=n):.1f} ({th[k]:.1f})"
                    )
            rows.append(row)
        report.heading(f"{m}: mean MTB (s), ours (thesis)")
        report.table(rows)
        order = 0
        total = 0
        for d in ("mode", "vector"):
            for n in robots:
                full, lim, none = (
                    _value(t, map=m, variant=f"{net} {d}", robots=n)
                    for net in ("full", "limited", "none")
                )
                total += 1
                order += int(full <= lim <= none)
                gaps[(str(m), d, n)] = (none - full) / full
        claims.append(
            _claim(
                f"full < limited < none on {m}",
                "in every cell of the table but one",
                f"in {order} of {total} (direction, robots) cells",
                order > total / 2,
            )
        )
    maps = ["fig3-2", "fig3-4"]  # few obstacles, many obstacles
    if all(any(k[0] == m for k in gaps) for m in maps):
        few = np.mean([v for k, v in gaps.items() if k[0] == maps[0]])
        many = np.mean([v for k, v in gaps.items() if k[0] == maps[1]])
        claims.append(
            _claim(
                "losing the network costs more among many obstacles",
                "none/full: +20-50 % on fig. 3.2, +35-100 % on fig. 3.4",
                f"none/full: +{100 * few:.0f} % on {maps[0]}, +{100 * many:.0f} % on {maps[1]}",
                many > few,
            )
        )
    return claims


def _pairs(
    t: pd.DataFrame, report: Report, name: str, first: str, second: str, thesis: str
) -> list[dict[str, Any]]:
    """A claim that variant ``first`` has a lower MTB than ``second``."""
    wins = 0
    cells = 0
    for _, grp in t.groupby(["map", "robots"]):
        a = _value(grp, variant=first)
        b = _value(grp, variant=second)
        if math.isfinite(a) and math.isfinite(b):
            cells += 1
            wins += int(a < b)
    return [
        _claim(
            f"{first} beats {second} ({name})",
            thesis,
            f"lower MTB in {wins} of {cells} (map, robots) cells",
            wins > cells / 2 if cells else None,
        )
    ]


def _generic_table(t: pd.DataFrame, report: Report) -> None:
    cols = {
        "map": "map",
        "variant": "variant",
        "robots": "robots",
        "mean_mtb": "mean MTB [s]",
        "mtb_sd": "sd over seeds",
        "worst_idleness": "worst idleness [s]",
        "mean_idleness": "mean idleness [s]",
        "dvt": "DVT [%]",
        "never_seen": "never seen (share)",
        "runs": "runs",
    }
    rows = [
        {str(k): v for k, v in r.items()}
        for r in t[list(cols)].rename(columns=cols).to_dict("records")
    ]
    report.heading("Mean over seeds")
    report.table(rows)


def _assess(
    name: str, runs: pd.DataFrame, table: pd.DataFrame, report: Report
) -> list[dict[str, Any]]:
    if name == "forces":
        return _forces(table, report)
    _generic_table(table, report)
    if name == "crowding":
        # One digest per (variant, robots) across all seeds: equal runs seed by seed.
        digest = (
            runs.sort_values("seed")
            .groupby(["variant", "robots"])["mtb_digest"]
            .agg(lambda d: round(float(sum(v * (k + 1) for k, v in enumerate(d))), 6))
            .reset_index()
            .rename(columns={"mtb_digest": "digest"})
        )
        return _crowding(table.merge(digest, on=["variant", "robots"]), report)
    if name == "network":
        return _network(table, report)
    if name == "direction":
        return _pairs(
            table, report, name, "mode", "vector", "mode does not degrade among obstacles"
        )
    if name == "refine":
        plain = _value(table, "dvt", variant="plain")
        ref = _value(table, "dvt", variant="refine R_G 2.5")
        ratio = ref / plain if plain > 0 else math.nan
        return [
            *_pairs(table, report, name, "refine R_G 2.5", "plain", "a slight MTB gain"),
            _claim(
                "refinement roughly halves DVT",
                "DVT almost halved",
                f"DVT {plain:.1f} % -> {ref:.1f} % (x{ratio:.2f})",
                ratio <= 0.7 if math.isfinite(ratio) else None,
            ),
        ]
    if name == "weaken":
        best = min(
            (v for v in table["variant"].unique() if str(v).startswith("weaken")),
            key=lambda v: _value(table, variant=v),
        )
        return [
            *_pairs(table, report, name, "refine", str(best), "refinement beats weakening"),
            _claim(
                "R0 near 5.5 m is best among the weakening settings",
                "flat below 6.5 m, worse above",
                f"best {best}",
                str(best) in ("weaken R0 3.5", "weaken R0 5.5"),
            ),
        ]
    if name == "dilation":
        base = _value(table, variant="d 0")
        others = {str(v): _value(table, variant=v) for v in table["variant"].unique() if v != "d 0"}
        best = min(others, key=lambda k: others[k])
        return [
            _claim(
                "fog dilation improves MTB",
                "improves MTB, slightly raises DVT",
                f"d 0: {base:.1f} s; best {best}: {others[best]:.1f} s",
                others[best] < base,
            )
        ]
    if name == "car":
        robots = sorted(int(n) for n in table["robots"].unique())
        dvt = [_value(table, "dvt", variant="car", robots=n) for n in robots]
        return [
            _claim(
                "a car's DVT grows with the number of robots",
                "per-robot DVT grows with robot count",
                ", ".join(f"{n}: {d:.1f} %" for n, d in zip(robots, dvt, strict=True)),
                dvt[-1] > dvt[0] if len(dvt) > 1 else None,
            ),
            *_pairs(table, report, name, "holonomic", "car", "(holonomic robots are faster)"),
        ]
    if name == "paths":
        return [
            *_pairs(table, report, name, "regions", "wave", "better on a static map"),
            *_pairs(table, report, name, "marching", "wave", "(not in the thesis)"),
        ]
    if name == "baselines":
        claims = []
        for other in ("random", "reactive", "cr", "hcr", "sebs", "gravity", "cycle"):
            claims += _pairs(table, report, name, "potential", other, "(not in the thesis)")
        return claims
    return []


def run_experiment(
    name: str,
    out: str | Path,
    *,
    quick: bool = False,
    seeds: int | None = None,
    duration: float | None = None,
    cell: float | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: Progress | None = None,
) -> Path:
    """Run experiment ``name`` into folder ``out``; return the path of its report.

    ``quick``: one seed, 300 s runs on 1 m cells (a smoke run, not a result); otherwise
    3 seeds of ``duration`` (3600 s) on ``cell`` (0.5 m) cells.
    """
    plans = _plans()
    if name not in plans:
        raise ConfigError(f"unknown experiment {name!r}; valid: {', '.join(plans)}")
    plan = plans[name]
    n_seeds = seeds if seeds is not None else (1 if quick else 3)
    if n_seeds < 1:
        raise ConfigError(f"seeds must be >= 1, got {n_seeds}")
    length = duration if duration is not None else (300.0 if quick else 3600.0)
    size = cell if cell is not None else (1.0 if quick else 0.5)
    plan.base = {**plan.base, "duration": length, "cell": size}
    PatrolConfig(**{k: v for k, v in plan.base.items() if k != "force"})  # check early
    tasks = plan.tasks(list(range(n_seeds)))
    rows = run_on_dask(run_task, tasks, scheduler=scheduler, workers=workers, progress=progress)
    runs = pd.DataFrame(rows).sort_values(["map", "variant", "robots", "seed"], ignore_index=True)
    table = _means(runs)
    report = Report(f"sonarmap patrol experiment: {name}")
    report.text(plan.what)
    report.text(
        f"{len(tasks)} runs: {n_seeds} seed(s) x {length:g} s simulated on {size:g} m cells; "
        "mean MTB over the steps after the first fifth; the thesis's numbers in brackets."
    )
    short = runs[runs["never_seen"] > 0]
    if len(short):
        report.text(
            f"In {len(short)} of {len(runs)} runs some places were never seen by the end "
            f"(up to {100 * short['never_seen'].max():.1f} % of the free cells): there MTB(t) "
            "is the time itself, and the mean MTB says only that the run was too short."
        )
    claims = _assess(name, runs, table, report)
    if claims:
        report.heading("What the thesis states, and what we measured")
        report.table(claims)
    folder = Path(out)
    with atomic_folder(folder) as tmp:
        _figures(name, table, tmp, report)
        atomic_write_text(tmp / "runs.csv", runs.to_csv(index=False))
        atomic_write_text(tmp / "table.csv", table.to_csv(index=False))
        atomic_write_text(tmp / "claims.json", json_dumps(claims) + "\n")
        report.parameters({"experiment": name, "seeds": n_seeds, **plan.base})
        report.write(tmp / "report.html")
    return folder / "report.html"


def _figures(name: str, table: pd.DataFrame, folder: Path, report: Report) -> None:
    from ..plot import save_force_tables, save_patrol_series

    if name == "forces":
        grids = {}
        for direction, thesis in (("vector", THESIS_TABLE_2), ("mode", THESIS_TABLE_3)):
            grids[f"{direction}, ours"] = _force_grid(table, direction)
            grids[f"{direction}, thesis"] = np.array(thesis)
        png = save_force_tables(grids, list(FORCE_F), list(FORCE_G), folder / "forces.png")
        report.figure(png, "Mean MTB of every force pair, ours beside the thesis's (log scale).")
        return
    if table["robots"].nunique() > 1:
        png = save_patrol_series(table, folder / "mtb.png")
        report.figure(png, "Mean MTB (and DVT, for cars) against the number of robots.")
