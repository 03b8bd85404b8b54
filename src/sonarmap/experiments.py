"""The research's experiments, one call each: figures, metrics tables and an HTML report.

``run_experiment(name, out)`` writes into ``out``: PNG figures, ``metrics.csv`` and
``metrics.json`` (one row per map), and a self-contained ``report.html`` with the
figures, the tables, every parameter and seed, and the software version. ``quick=True``
runs a small version (used by the tests).

Every comparison is against the tuned inverse baseline (the ``inverse`` defaults, chosen
by a parameter scan; see ``mappers/inverse.py``); the "traditional" inverse setting the
research used is shown beside it.
"""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np

from .errors import ConfigError
from .io._atomic import atomic_write, atomic_write_text
from .io._json import dumps as json_dumps
from .io.rosmap import OccupancyMap, write_map
from .mappers import make_mapper
from .metrics import measure_passage, score
from .plot import save_side_by_side
from .report import Report
from .scenarios import Scenario, load_scene, make_scenario
from .sensors import Noise
from .simulate import PoseNoise, simulate

__all__ = ["EXPERIMENTS", "METHODS", "MethodSpec", "run_experiment"]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class MethodSpec:
    """A method under a label, with its parameters."""

    label: str
    method: str
    params: dict[str, Any] = field(default_factory=dict)


#: Laser-style log-odds (OctoMap's increments, no fall-off, a one-cell band at 5 cm).
TRADITIONAL_INVERSE: dict[str, Any] = {"p_occ": 0.7, "p_free": 0.4, "falloff_deg": 0.0, "dr": 0.05}

METHODS: tuple[MethodSpec, ...] = (
    MethodSpec("inverse-traditional", "inverse", TRADITIONAL_INVERSE),
    MethodSpec("inverse", "inverse"),
    MethodSpec("counting", "counting"),
    MethodSpec("gradient", "gradient"),
    MethodSpec("stochastic", "stochastic"),
    MethodSpec("em", "em"),
)


@dataclass
class _Run:
    """What an experiment accumulates as it goes."""

    out: Path
    report: Report
    rows: list[dict[str, Any]] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    #: A user's scene folder (see scenarios.load_scene) instead of the built-in scene.
    scene: Path | None = None
    #: Parameters of the built-in scene.
    scene_params: dict[str, Any] = field(default_factory=dict)
    #: For ``real``: the log, the sonar rig (None: the default), the cell size.
    log: Path | None = None
    rig: Path | None = None
    resolution: float = 0.1

    def make(self, kind: str, seed: int, noise: Noise | None = None, **defaults: Any) -> Scenario:
        """The experiment's scene: the user's folder, or the built-in one."""
        if self.scene is not None:
            return load_scene(self.scene, seed=seed, noise=noise)
        params = {**defaults, **self.scene_params}
        if noise is not None:
            params["noise"] = noise
        return make_scenario(kind, seed=seed, **params)


def _build(spec: MethodSpec, scene: Scenario) -> OccupancyMap:
    mapper = make_mapper(spec.method, **spec.params)
    return mapper.fit(scene.readings, scene.truth.grid, scene.rig).result()


def _score_row(spec: MethodSpec, scene: Scenario, m: OccupancyMap, **extra: Any) -> dict[str, Any]:
    s = score(scene.truth, m, scene.passages, scene.obstacles).as_dict()
    return {"method": spec.label, **extra, **s}


def _save_fig(fig: Any, path: Path) -> Path:
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=120, bbox_inches="tight", format="png"))
    plt.close(fig)
    return path


def _tables(run: _Run) -> None:
    if not run.rows:
        return
    cols: list[str] = []
    for r in run.rows:
        cols.extend(c for c in r if c not in cols)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    w.writerows(run.rows)
    atomic_write_text(run.out / "metrics.csv", buf.getvalue())
    atomic_write_text(run.out / "metrics.json", json_dumps(run.rows))


def _short(rows: Sequence[dict[str, Any]], keys: Sequence[str]) -> list[dict[str, Any]]:
    return [{k: r.get(k) for k in keys} for r in rows]


_MAP_COLUMNS = (
    "method",
    "accuracy",
    "precision",
    "recall",
    "f1",
    "dist_to_truth",
    "dist_from_truth",
    "passages_open",
    "passages_detected",
    "passages",
    "width_error",
    "small_found",
    "size_error",
)


def _maps_experiment(
    run: _Run,
    name: str,
    scene: Scenario,
    methods: Sequence[MethodSpec],
    progress: Progress | None,
    caption: str,
) -> None:
    maps: dict[str, OccupancyMap] = {}
    for k, spec in enumerate(methods):
        maps[spec.label] = _build(spec, scene)
        write_map(maps[spec.label], run.out / "maps" / spec.label)
        run.rows.append(_score_row(spec, scene, maps[spec.label]))
        if progress is not None:
            progress(k + 1, len(methods))
    fig = save_side_by_side(maps, run.out / f"{name}.png", truth=scene.truth)
    run.report.figure(fig, caption)
    run.report.table(
        _short(run.rows, _MAP_COLUMNS),
        "Maps against the truth (observed cells; distances in metres).",
    )


def _doorways(run: _Run, quick: bool, seed: int, progress: Progress | None) -> None:
    scene = run.make("doorways", seed)
    run.params["scenario"] = scene.params
    run.report.text(
        "The research's synthetic corridor (thesis 000 fig. 4.1): doorways in "
        "both walls, six sonars, exact readings. Figures 4.2 / 4.4 / 6 of the "
        "documents: the truth, each method's map, and the maps binarised at 0.5."
    )
    _maps_experiment(
        run,
        "doorways",
        scene,
        METHODS,
        progress,
        "doorways: truth outlined in red; second row binarised at 0.5.",
    )


def _room_turn(run: _Run, quick: bool, seed: int, progress: Progress | None) -> None:
    kwargs: dict[str, Any] = {"duration": 15.0} if quick else {}
    scene = run.make("room-turn", seed, **kwargs)
    run.params["scenario"] = scene.params
    run.report.text(
        "A robot with four front sonars turns in place at uneven speed in a "
        "room with a door; outliers and a roughly known mounting (figures "
        "4.3 / 4.5 / 7 of the documents)."
    )
    _maps_experiment(
        run,
        "room-turn",
        scene,
        METHODS,
        progress,
        "room-turn: truth outlined in red; second row binarised at 0.5.",
    )


def _passages(run: _Run, quick: bool, seed: int, progress: Progress | None) -> None:
    widths = (0.2, 0.4, 0.6, 0.8) if quick else (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.2)
    seeds = [seed] if quick else [seed + k for k in range(3)]
    noise = Noise(0.0, 1.0, 0.01)
    run.params.update(
        {
            "widths": list(widths),
            "seeds": seeds,
            "noise": {"p_rand": noise.p_rand, "p_hit": noise.p_hit, "sigma": noise.sigma},
        }
    )
    run.report.text(
        "Gaps of increasing width in a thin wall beside the robot's path "
        "(thesis 002, figs 4.9-4.10), 1 cm range noise, one scene per seed. A "
        "passage is detected when the map shows a gap bounded by obstacles on "
        "both sides with an observed free cell in it; its recovered width is "
        "that gap. Undetected passages count as width 0 in the plot."
    )
    per: list[dict[str, Any]] = []
    total = len(seeds) * len(METHODS)
    done = 0
    for sd in seeds:
        scene = run.make("passages", sd, noise, widths=widths)
        run.params.setdefault("scenario", scene.params)
        for spec in METHODS:
            m = _build(spec, scene)
            write_map(m, run.out / "maps" / f"seed{sd}" / spec.label)
            run.rows.append(_score_row(spec, scene, m, seed=sd))
            for res in (measure_passage(scene.truth, m, p) for p in scene.passages):
                per.append(
                    {
                        "method": spec.label,
                        "seed": sd,
                        "passage": res.name,
                        "true_width": round(res.true_width, 3),
                        "width": res.width if res.detected else 0.0,
                        "detected": res.detected,
                    }
                )
            done += 1
            if progress is not None:
                progress(done, total)
    summary = _passage_summary(per, [s.label for s in METHODS])
    atomic_write_text(run.out / "passages.json", json_dumps(per))
    atomic_write_text(run.out / "summary.json", json_dumps(summary))
    run.report.figure(
        _plot_widths(per, [s.label for s in METHODS], run.out / "widths.png"),
        "Recovered against true passage width, mean and spread over seeds "
        "(the dashed line is exact).",
    )
    run.report.figure(
        _plot_narrowest(summary, run.out / "narrowest.png"),
        "Narrowest passage detected per method: mean over seeds, bars to "
        "the narrowest and widest seed.",
    )
    run.report.table(
        summary,
        "Narrowest passage detected (metres) and mean width error of "
        "detected passages, over seeds; ratio = tuned inverse / method.",
    )
    run.report.table(
        _short(
            run.rows,
            (
                "method",
                "seed",
                "f1",
                "passages_detected",
                "passages",
                "width_error",
                "small_found",
                "size_error",
            ),
        ),
        "Per map.",
    )


def _passage_summary(per: list[dict[str, Any]], labels: list[str]) -> list[dict[str, Any]]:
    """Per method: narrowest passage detected over seeds (mean, min, max), width error."""
    out = []
    for label in labels:
        rows = [r for r in per if r["method"] == label]
        seeds = sorted({r["seed"] for r in rows})
        narrow = np.array(
            [
                min(
                    (r["true_width"] for r in rows if r["seed"] == s and r["detected"]),
                    default=math.nan,
                )
                for s in seeds
            ]
        )
        seen = narrow[np.isfinite(narrow)]
        errs = [abs(r["width"] - r["true_width"]) for r in rows if r["detected"]]
        out.append(
            {
                "method": label,
                "narrowest_mean": float(seen.mean()) if len(seen) else math.nan,
                "narrowest_min": float(seen.min()) if len(seen) else math.nan,
                "narrowest_max": float(seen.max()) if len(seen) else math.nan,
                "detected": sum(r["detected"] for r in rows),
                "passages": len(rows),
                "width_error": float(np.mean(errs)) if errs else math.nan,
            }
        )
    base = next((r["narrowest_mean"] for r in out if r["method"] == "inverse"), math.nan)
    for row in out:
        row["ratio_vs_tuned_inverse"] = base / row["narrowest_mean"]
    return out


def _plot_widths(per: list[dict[str, Any]], labels: list[str], path: Path) -> Path:
    widths = sorted({r["true_width"] for r in per})
    fig, ax = plt.subplots(figsize=(7, 5))
    for label in labels:
        means, stds = [], []
        for w in widths:
            vals = [
                r["width"] for r in per if r["method"] == label and abs(r["true_width"] - w) < 1e-6
            ]
            means.append(np.mean(vals))
            stds.append(np.std(vals))
        ax.errorbar(widths, means, yerr=stds, marker="o", capsize=3, label=label)
    ax.plot([0, max(widths)], [0, max(widths)], "k--", lw=0.8)
    ax.set_xlabel("true passage width [m]")
    ax.set_ylabel("recovered width [m]")
    ax.legend()
    ax.grid(alpha=0.3)
    return _save_fig(fig, path)


def _plot_narrowest(summary: list[dict[str, Any]], path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7, 4))
    labels = [r["method"] for r in summary]
    mean = np.array([r["narrowest_mean"] for r in summary], dtype=float)
    # Clipped: mean - min can come out a hair below zero in floating point.
    lo = np.clip(mean - np.array([r["narrowest_min"] for r in summary], dtype=float), 0, None)
    hi = np.clip(np.array([r["narrowest_max"] for r in summary], dtype=float) - mean, 0, None)
    ax.bar(
        labels,
        np.nan_to_num(mean),
        yerr=[np.nan_to_num(lo), np.nan_to_num(hi)],
        capsize=4,
        color="tab:blue",
    )
    ax.set_ylabel("narrowest passage detected [m]")
    ax.tick_params(axis="x", rotation=30)
    ax.grid(axis="y", alpha=0.3)
    return _save_fig(fig, path)


def _noise(run: _Run, quick: bool, seed: int, progress: Progress | None) -> None:
    base = run.make("doorways", seed)
    levels: dict[str, list[float]] = (
        {"p_rand": [0.0, 0.05], "sigma": [0.0, 0.02], "pose_sigma": [0.0, 0.03]}
        if quick
        else {
            "p_rand": [0.0, 0.02, 0.05, 0.1],
            "sigma": [0.0, 0.01, 0.02, 0.05],
            "pose_sigma": [0.0, 0.02, 0.05],
        }
    )
    methods = [m for m in METHODS if m.label != "counting"] if quick else list(METHODS)
    run.params.update({"levels": levels, "seed": seed, "scenario": base.params})
    run.report.text(
        "Map quality on the doorways scene as one kind of noise grows, the others "
        "off: outlier probability p_rand, range noise sigma (metres), and pose "
        "noise (metres on x and y, and sigma / 2 radians on the heading) added to "
        "the recorded poses."
    )
    total = sum(len(v) for v in levels.values()) * len(methods)
    done = 0
    for kind, values in levels.items():
        for v in values:
            scene = _noisy(base, kind, v, seed)
            for spec in methods:
                m = _build(spec, scene)
                run.rows.append(_score_row(spec, scene, m, noise=kind, level=v))
                done += 1
                if progress is not None:
                    progress(done, total)
    run.report.figure(
        _plot_noise(run.rows, levels, [m.label for m in methods], run.out / "noise.png"),
        "F1 of occupied cells (top) and doorways left open (bottom) against each kind of noise.",
    )
    run.report.table(
        _short(
            run.rows,
            (
                "method",
                "noise",
                "level",
                "f1",
                "accuracy",
                "passages_open",
                "passages",
                "dist_to_truth",
            ),
        ),
        "Per map.",
    )


def _noisy(base: Scenario, kind: str, v: float, seed: int) -> Scenario:
    noise = Noise(
        p_rand=v if kind == "p_rand" else 0.0, p_hit=1.0, sigma=v if kind == "sigma" else 0.0
    )
    pose = PoseNoise(v, v / 2) if kind == "pose_sigma" else None
    rig = replace(base.rig, sensor=replace(base.rig.sensor, noise=noise))
    readings = simulate(base.truth, rig, base.trajectory, noise=noise, pose_noise=pose, seed=seed)
    return replace(base, rig=rig, readings=readings)


def _plot_noise(
    rows: list[dict[str, Any]], levels: dict[str, list[float]], labels: list[str], path: Path
) -> Path:
    fig, axes = plt.subplots(2, len(levels), figsize=(4.5 * len(levels), 7), squeeze=False)
    for j, kind in enumerate(levels):
        for label in labels:
            pick = [r for r in rows if r["method"] == label and r["noise"] == kind]
            xs = [r["level"] for r in pick]
            axes[0, j].plot(xs, [r["f1"] for r in pick], marker="o", label=label)
            axes[1, j].plot(xs, [r["passages_open"] for r in pick], marker="o", label=label)
        axes[0, j].set_title(kind)
        axes[1, j].set_xlabel(kind)
        axes[0, j].set_ylabel("F1")
        axes[1, j].set_ylabel("doorways open")
        for ax in axes[:, j]:
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    return _save_fig(fig, path)


#: The laser reference map: the inverse model with laser increments (OctoMap's), the
#: narrow laser beam, a half-cell band, no-return beams ignored.
LASER_REFERENCE: dict[str, Any] = {
    "p_occ": 0.7,
    "p_free": 0.4,
    "falloff_deg": 0.0,
    "no_echo": "ignore",
}


def _real(run: _Run, quick: bool, seed: int, progress: Progress | None) -> None:
    from .api import grid_for_readings
    from .io.carmen import ConvertSummary, read_carmen
    from .io.udacity import read_udacity
    from .rig import load_rig
    from .virtual import default_ring, virtual_sonar

    if run.log is None:
        raise ConfigError("experiment 'real' needs a log (--log)")
    log = run.log
    if log.name.startswith("measurement"):
        rig = load_rig(run.rig) if run.rig is not None else None
        readings, used = read_udacity(log, log.with_name("poses.txt"), rig=rig)
        _real_sonar(run, readings, used, f"udacity log {log}", progress)
        return
    summary = ConvertSummary()
    laser, laser_rig = read_carmen(log, summary=summary)
    if laser_rig.names[0].startswith("sonar"):
        _real_sonar(run, laser, laser_rig, f"CARMEN sonar log {log}", progress)
        return
    if quick:  # the first 200 scans
        laser = laser.take(np.arange(min(len(laser), 200 * len(laser_rig.mounts))))
    sonar_rig = load_rig(run.rig) if run.rig is not None else default_ring()
    sonar, kept = virtual_sonar(laser, laser_rig, sonar_rig, seed=seed)
    grid = grid_for_readings(sonar, kept, run.resolution)
    ref_params = {**LASER_REFERENCE, "dr": run.resolution / 2}
    reference = make_mapper("inverse", **ref_params).fit(laser, grid, laser_rig).result()
    run.params.update(
        {
            "log": str(log),
            "messages": dict(summary.counts),
            "skipped": dict(summary.skipped),
            "laser_readings": len(laser),
            "sonar_readings": len(sonar),
            "sonars": list(kept.names),
            "sonar_rig": kept.to_dict(),
            "resolution": run.resolution,
            "laser_reference": ref_params,
        }
    )
    run.report.text(
        f"Real building from the laser log {log.name}: a virtual ring of {len(kept.mounts)} "
        "sonars (those of the rig whose beam the laser covers) reads the nearest laser "
        "return inside each beam; the reference map is the inverse model on the laser "
        "itself (narrow beams, laser increments). Maps are scored where the reference is "
        "known."
    )
    write_map(reference, run.out / "maps" / "laser-reference")
    maps: dict[str, OccupancyMap] = {}
    for k, spec in enumerate(METHODS):
        mapper = make_mapper(spec.method, **spec.params)
        t0 = time.perf_counter()
        maps[spec.label] = mapper.fit(sonar, grid, kept).result()
        seconds = time.perf_counter() - t0
        write_map(maps[spec.label], run.out / "maps" / spec.label)
        sc = score(reference, maps[spec.label]).as_dict()
        run.rows.append({"method": spec.label, "seconds": seconds, **sc})
        if progress is not None:
            progress(k + 1, len(METHODS))
    fig = save_side_by_side(
        maps, run.out / "real.png", truth=reference, truth_label="laser reference"
    )
    run.report.figure(
        fig,
        "Laser reference (first panel) and the sonar-only maps; the "
        "reference's obstacles outlined in red.",
    )
    run.report.table(
        _short(
            run.rows,
            (
                "method",
                "seconds",
                "accuracy",
                "precision",
                "recall",
                "f1",
                "dist_to_truth",
                "dist_from_truth",
                "unknown",
            ),
        ),
        "Sonar-only maps against the laser reference (distances in metres).",
    )


def _real_sonar(run: _Run, readings: Any, rig: Any, what: str, progress: Progress | None) -> None:
    from .api import grid_for_readings
    from .mappers.em import EMMapper

    grid = grid_for_readings(readings, rig, run.resolution)
    run.params.update(
        {"log": what, "readings": len(readings), "rig": rig.to_dict(), "resolution": run.resolution}
    )
    run.report.text(
        f"Real sonar data ({what}, {len(readings)} readings): no ground truth. "
        "The maps side by side, how often two methods agree on a cell both "
        "observed, and the readings the probabilistic model (EM) attributes to "
        "its random component."
    )
    maps: dict[str, OccupancyMap] = {}
    for k, spec in enumerate(METHODS):
        mapper = make_mapper(spec.method, **spec.params)
        t0 = time.perf_counter()
        mapper.fit(readings, grid, rig)
        maps[spec.label] = mapper.result()
        row: dict[str, Any] = {
            "method": spec.label,
            "seconds": time.perf_counter() - t0,
            "known": float(np.isfinite(maps[spec.label].occupancy).mean()),
            "occupied": float(np.nanmean(maps[spec.label].occupancy >= 0.5)),
        }
        if isinstance(mapper, EMMapper):
            row["outliers"] = int(np.sum(mapper.outlier_prob_ > 0.5))
            row["outlier_share"] = float(np.mean(mapper.outlier_prob_ > 0.5))
        run.rows.append(row)
        write_map(maps[spec.label], run.out / "maps" / spec.label)
        if progress is not None:
            progress(k + 1, len(METHODS))
    labels = list(maps)
    agree = []
    for a in labels:
        row2: dict[str, Any] = {"method": a}
        for b in labels:
            both = np.isfinite(maps[a].occupancy) & np.isfinite(maps[b].occupancy)
            same = (maps[a].occupancy[both] >= 0.5) == (maps[b].occupancy[both] >= 0.5)
            row2[b] = float(same.mean()) if both.any() else math.nan
        agree.append(row2)
    fig = save_side_by_side(maps, run.out / "real.png")
    run.report.figure(fig, "Maps from the real sonar log; second row binarised at 0.5.")
    run.report.table(
        run.rows,
        "Per method: time, share of cells observed and occupied; for "
        "em, readings it attributes to the random component (posterior > 0.5).",
    )
    run.report.table(
        agree, "Agreement between methods on the cells both observed (binarised at 0.5)."
    )
    atomic_write_text(run.out / "agreement.json", json_dumps(agree))


EXPERIMENTS: dict[str, Callable[[_Run, bool, int, Progress | None], None]] = {
    "doorways": _doorways,
    "passages": _passages,
    "room-turn": _room_turn,
    "noise": _noise,
    "real": _real,
}


def run_experiment(
    name: str,
    out: str | Path,
    *,
    quick: bool = False,
    seed: int = 0,
    progress: Progress | None = None,
    scene: str | Path | None = None,
    scene_params: dict[str, Any] | None = None,
    log: str | Path | None = None,
    rig: str | Path | None = None,
    resolution: float = 0.1,
) -> Path:
    """Run an experiment into folder ``out``; return the path of its ``report.html``.

    Parameters
    ----------
    scene : path, optional
        A scene folder of one's own (truth.yaml, rig.yaml, trajectory.csv and/or
        readings.csv, annotations.yaml) used instead of the built-in scene; with a
        trajectory, the passages experiment simulates each seed's readings from it.
    scene_params : dict, optional
        Parameters of the built-in scene (e.g. ``widths`` for passages).
    log, rig : path, optional
        For ``real``: a CARMEN log or a udacity ``measurement.txt``, and the sonar rig
        (default: :func:`sonarmap.virtual.default_ring` for laser logs).
    resolution : float
        Cell size of ``real`` (metres).
    """
    if scene is not None and scene_params:
        raise ConfigError("give either a scene folder or scene parameters, not both")
    try:
        body = EXPERIMENTS[name]
    except KeyError:
        raise ConfigError(f"unknown experiment '{name}'; valid: {', '.join(EXPERIMENTS)}") from None
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    run = _Run(
        folder,
        Report(f"sonarmap experiment: {name}"),
        scene=Path(scene) if scene is not None else None,
        scene_params=dict(scene_params or {}),
        log=Path(log) if log is not None else None,
        rig=Path(rig) if rig is not None else None,
        resolution=resolution,
    )
    run.params.update(
        {
            "experiment": name,
            "quick": quick,
            "seed": seed,
            "methods": [
                {"label": m.label, "method": m.method, "params": m.params} for m in METHODS
            ],
        }
    )
    run.report.text(
        "Baseline: the tuned inverse model ('inverse', its defaults chosen by a "
        "parameter scan); 'inverse-traditional' is the laser-style setting the "
        "research compared against."
    )
    body(run, quick, seed, progress)
    _tables(run)
    run.report.parameters(run.params)
    return run.report.write(folder / "report.html")
