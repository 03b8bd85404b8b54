"""Parameter sweeps over training scenes on Dask distributed.

A sweep file names scenarios (with their parameters and sonar model), seeds, and per
method the values to try::

    scenarios:
      doorways: {}
      passages: {widths: [0.3, 0.5, 0.7]}
      passages-noisy: {scenario: passages, model: {kind: acoustic, p_rand: 0.05}}
      passages-paper: {scenario: passages, model: {kind: thrun, sigma: 0.01}}
      hall-ring16: {scenario: hall, rig: ring16}
    seeds: [0, 1]
    search: grid            # or: random, with samples: N (per method)
    metrics: [quality, f1_all, passage_f1]
    methods:
      inverse:
        p_occ: [0.55, 0.6, 0.7]
        falloff_deg: [0, 15]

A scenario entry is a label; its ``scenario`` key names the kind when the label is not a
scenario name itself; ``model`` is the sonar model of its readings (default the acoustic
one; see :func:`sonarmap.scenarios.model_from_dict`); the other keys are the
scenario's parameters, ``rig`` among them (a rig preset) where the scenario takes one.
Sweeps tune, so they run on training scenes only: held-out families and seeds are
refused (:mod:`sonarmap.splits`).
Every (scenario, seed, method, parameters) is one task; tasks run on a Dask cluster (a
LocalCluster by default, or an existing scheduler). Results: one row per task with every
metric of :class:`~sonarmap.metrics.MapScore`; the summary ranks each method's parameter
sets by each metric's mean over scenarios and seeds. Rank by ``quality`` (wall F1,
passage F1 and observed-wall recall together; :func:`sonarmap.metrics.quality`), which
neither erasing walls nor trading them for open doors can win.
"""

from __future__ import annotations

import itertools
import json
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .checks import numbers_where_floats
from .errors import ConfigError, InputError
from .files import read_yaml
from .mappers import MAPPERS, make_mapper
from .metrics import MapScore, observed_walls, score
from .parallel import Progress, run_on_dask
from .scenarios import SCENARIOS, Scenario, make_scenario, model_from_dict
from .splits import check_training

__all__ = [
    "SweepConfig",
    "Task",
    "load_sweep",
    "run_sweep",
    "run_task",
    "summarise",
]

#: Metrics where smaller is better; for the others larger is better.
LOWER_IS_BETTER = {
    "width_error",
    "size_error",
    "dist_to_truth",
    "dist_from_truth",
    "unknown",
    "false_openings",
    "false_opening_width",
}
METRICS = tuple(f.name for f in fields(MapScore))


@dataclass(frozen=True)
class Task:
    """One map to build and score."""

    scenario: str
    scenario_params: tuple[tuple[str, Any], ...]
    seed: int
    method: str
    params: tuple[tuple[str, Any], ...]


@dataclass(frozen=True)
class SweepConfig:
    """A parsed sweep file (see the module notes)."""

    scenarios: dict[str, dict[str, Any]]
    seeds: list[int]
    methods: dict[str, dict[str, list[Any]]]
    search: str = "grid"
    samples: int = 20
    random_seed: int = 0
    metrics: list[str] = field(default_factory=lambda: ["quality"])
    #: Whether each method's current defaults are a candidate too (besides the samples).
    include_defaults: bool = True

    def tasks(self) -> list[Task]:
        """Every task, in a fixed order."""
        out = []
        for method, grid in self.methods.items():
            for params in self._param_sets(grid):
                for scen, sparams in self.scenarios.items():
                    for seed in self.seeds:
                        out.append(
                            Task(
                                scen,
                                tuple(sorted(sparams.items())),
                                seed,
                                method,
                                tuple(sorted(params.items())),
                            )
                        )
        return out

    def _param_sets(self, grid: Mapping[str, list[Any]]) -> list[dict[str, Any]]:
        keys = list(grid)
        combos = [
            dict(zip(keys, vals, strict=True))
            for vals in itertools.product(*(grid[k] for k in keys))
        ]
        if self.search == "random" and len(combos) > self.samples:
            rng = np.random.default_rng(self.random_seed)
            pick = rng.choice(len(combos), self.samples, replace=False)
            combos = [combos[i] for i in sorted(pick.tolist())]
        if self.include_defaults and {} not in combos:
            combos.insert(0, {})
        return combos


def load_sweep(path: str | Path) -> SweepConfig:
    """Read and check a sweep file; errors name the key and what is allowed."""
    p = Path(path)
    data = read_yaml(p, "sweep file")
    try:
        return _parse(data)
    except ConfigError as err:
        raise InputError(str(err), path=p) from err


def _parse(data: Any) -> SweepConfig:
    if not isinstance(data, Mapping):
        raise ConfigError("expected a mapping with scenarios, seeds and methods")
    known = {
        "scenarios",
        "seeds",
        "methods",
        "search",
        "samples",
        "random_seed",
        "metrics",
        "include_defaults",
    }
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"unknown key(s) {unknown}; valid: {', '.join(sorted(known))}")
    for key in ("scenarios", "methods"):
        if key not in data:
            raise ConfigError(f"missing key '{key}'")
    scen = data["scenarios"]
    if isinstance(scen, list):
        scen = {name: {} for name in scen}
    if not isinstance(scen, Mapping) or not scen:
        raise ConfigError("'scenarios' must list scenario names or map them to parameters")
    scenarios: dict[str, dict[str, Any]] = {}
    for name, params in scen.items():
        params = dict(params or {})
        kind = params.get("scenario", name)
        if kind not in SCENARIOS:
            raise ConfigError(
                f"scenarios.{name}: unknown scenario '{kind}'; valid: {', '.join(SCENARIOS)}"
            )
        params["scenario"] = kind
        if "model" in params:
            if not isinstance(params["model"], Mapping):
                raise ConfigError(f"scenarios.{name}.model: expected a mapping with 'kind'")
            model_from_dict(dict(params["model"]), f"scenarios.{name}.model")  # validates
        scenarios[str(name)] = params
    seeds = data.get("seeds", [0])
    if (
        not isinstance(seeds, list)
        or not seeds
        or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)
    ):
        raise ConfigError("'seeds' must be a non-empty list of integers >= 0")
    for name, params in scenarios.items():
        for seed in seeds:
            check_training(params["scenario"], seed, where=f"scenarios.{name}")
    meth = data["methods"]
    if not isinstance(meth, Mapping) or not meth:
        raise ConfigError("'methods' must map method names to parameter lists")
    methods: dict[str, dict[str, list[Any]]] = {}
    for name, grid in meth.items():
        if name not in MAPPERS:
            raise ConfigError(
                f"methods: unknown method '{name}'; valid: {', '.join(sorted(MAPPERS))}"
            )
        grid = dict(grid or {})
        valid = MAPPERS[name].param_names()
        for key, values in grid.items():
            if key not in valid:
                raise ConfigError(
                    f"methods.{name}: unknown parameter '{key}'; valid: {', '.join(valid)}"
                )
            if not isinstance(values, list) or not values:
                raise ConfigError(f"methods.{name}.{key}: expected a non-empty list of values")
            # Stored converted, so that the results name 0.01 for a 1e-2 the file gave.
            grid[key] = [numbers_where_floats({key: v}, MAPPERS[name])[key] for v in values]
        for combo in itertools.product(*grid.values()):
            make_mapper(name, **dict(zip(grid, combo, strict=True)))  # validates ranges
        methods[str(name)] = grid
    search = data.get("search", "grid")
    if search not in ("grid", "random"):
        raise ConfigError(f"'search' must be grid or random, got {search!r}")
    samples = data.get("samples", 20)
    if not isinstance(samples, int) or samples < 1:
        raise ConfigError(f"'samples' must be an integer >= 1, got {samples!r}")
    metrics = data.get("metrics", ["quality"])
    if isinstance(metrics, str):
        metrics = [metrics]
    bad = [m for m in metrics if m not in METRICS]
    if bad:
        raise ConfigError(f"unknown metric(s) {bad}; valid: {', '.join(METRICS)}")
    include = data.get("include_defaults", True)
    if not isinstance(include, bool):
        raise ConfigError(f"'include_defaults' must be true or false, got {include!r}")
    return SweepConfig(
        scenarios,
        seeds,
        methods,
        search,
        samples,
        int(data.get("random_seed", 0)),
        list(metrics),
        include,
    )


#: Scenes built by this process with their observed walls, by their description: a
#: worker maps each many times.
_SCENES: dict[str, tuple[Scenario, np.ndarray[Any, np.dtype[np.bool_]]]] = {}


def _scene(
    kind: str, sparams: Mapping[str, Any], seed: int
) -> tuple[Scenario, np.ndarray[Any, np.dtype[np.bool_]]]:
    key = json.dumps([kind, sparams, seed], sort_keys=True, default=str)
    if key not in _SCENES:
        if len(_SCENES) >= 16:
            _SCENES.pop(next(iter(_SCENES)))
        params = dict(sparams)
        if "model" in params:
            params["model"] = model_from_dict(dict(params["model"]))
        scene = make_scenario(kind, seed=seed, **params)
        _SCENES[key] = (scene, observed_walls(scene.truth, scene.rig, scene.readings))
    return _SCENES[key]


def run_task(task: Task) -> dict[str, Any]:
    """Build (or reuse) one scenario, map it and score the map (runs on a Dask worker)."""
    sparams = dict(task.scenario_params)
    kind = sparams.pop("scenario")
    scene, observed = _scene(kind, sparams, task.seed)
    params = dict(task.params)
    t0 = time.perf_counter()
    mapper = make_mapper(task.method, **params)
    m = mapper.fit(scene.readings, scene.truth.grid, scene.rig).result()
    seconds = time.perf_counter() - t0
    s = score(scene.truth, m, scene.passages, scene.obstacles, observed)
    return {
        "scenario": task.scenario,
        "seed": task.seed,
        "method": task.method,
        "params": _params_key(params),
        **{f"param.{k}": v for k, v in params.items()},
        "seconds": seconds,
        **s.as_dict(),
    }


def _params_key(params: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={params[k]!r}" for k in sorted(params)) or "(defaults)"


def run_sweep(
    config: SweepConfig,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: Progress | None = None,
) -> pd.DataFrame:
    """Run every task of ``config`` on Dask (:func:`run_on_dask`); one row per task."""
    rows = run_on_dask(
        run_task, config.tasks(), scheduler=scheduler, workers=workers, progress=progress
    )
    df = pd.DataFrame(rows)
    return df.sort_values(
        ["method", "params", "scenario", "seed"], kind="stable", ignore_index=True
    )


def summarise(df: pd.DataFrame, metrics: list[str]) -> pd.DataFrame:
    """Per method and metric, the parameter set with the best mean over scenarios and seeds."""
    out = []
    for metric in metrics:
        mean = df.groupby(["method", "params"])[metric].mean().reset_index()
        for method, grp in mean.groupby("method"):
            vals = grp[metric].to_numpy(dtype=float)
            if np.all(np.isnan(vals)):
                continue
            lower = metric in LOWER_IS_BETTER
            best = int(np.nanargmin(vals) if lower else np.nanargmax(vals))
            row = grp.iloc[best]
            default = df[(df["method"] == method)]
            out.append(
                {
                    "method": method,
                    "metric": metric,
                    "goal": "min" if lower else "max",
                    "best_params": row["params"],
                    "best_value": float(row[metric]),
                    "worst_value": float(np.nanmax(vals) if lower else np.nanmin(vals)),
                    "runs": len(default),
                }
            )
    return pd.DataFrame(out)
