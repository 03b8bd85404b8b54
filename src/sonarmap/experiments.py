"""The research's experiments, one call each: figures, metrics tables and an HTML report.

``run_experiment(name, out)`` writes into ``out``: PNG figures, ``metrics.csv`` and
``metrics.json`` (one row per map), and a self-contained ``report.html`` with the
figures, the tables, every parameter and seed, and the software version. ``quick=True``
runs a small version (used by the tests).

Every experiment runs by default on **held-out** scenes (:mod:`sonarmap.splits`) read by
the acoustic sonar: families and seeds no method was tuned on, readings from no
method's model. ``paper=True`` re-enacts the research's own scene with Thrun's model
instead, as the documents did: a reproduction, not a claim. ``boxes`` (thesis 002's
stochastic experiment) has no held-out counterpart: it is always that reproduction.

Every comparison is against the tuned inverse baseline (the ``inverse`` defaults); the
"traditional" inverse setting the research compared against is shown beside it, with
the same band as every other method.
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
from .files import atomic_folder, atomic_write, atomic_write_text, json_dumps
from .io.rosmap import OccupancyMap, write_map
from .mappers import make_mapper, preset_params
from .metrics import measure_passage, observed_walls, score
from .plot import save_side_by_side
from .report import Report
from .scenarios import PAPER_NOISE, Scenario, load_scene, make_scenario, model_to_dict
from .sensors import Noise
from .simulate import AcousticModel, PoseNoise, SonarModel, simulate
from .splits import HELD_OUT_SEED

__all__ = [
    "EXPERIMENTS",
    "METHODS",
    "RELIABLE",
    "MethodSpec",
    "narrowest_reliable",
    "run_experiment",
]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class MethodSpec:
    """A method under a label, with its parameters."""

    label: str
    method: str
    params: dict[str, Any] = field(default_factory=dict)


#: The research's baseline: the inverse method's ``traditional`` preset.
TRADITIONAL_INVERSE: dict[str, Any] = preset_params("inverse", "traditional")

METHODS: tuple[MethodSpec, ...] = (
    MethodSpec("inverse-traditional", "inverse", TRADITIONAL_INVERSE),
    MethodSpec("inverse", "inverse"),
    MethodSpec("counting", "counting"),
    MethodSpec("gradient", "gradient"),
    # The papers start the descent from the neutral map; from the inverse map too, to
    # see whether the start is what the forward model lacks.
    MethodSpec("gradient-inverse-start", "gradient", {"init": "inverse"}),
    MethodSpec("stochastic", "stochastic"),
    MethodSpec("em", "em"),
    # EM starts from the neutral map (every cell at 0.5) by default; from the inverse
    # map, as sonarmap's EM did before tuning, for comparison.
    MethodSpec("em-inverse-start", "em", {"init": "inverse"}),
    # Thrun 2003's EM over a binary map, beside ``em``'s relaxed model.
    MethodSpec("em-thrun", "em-thrun"),
)

#: A passage width counts as reliably detected when it, and every wider one, is
#: detected in at least this share of the seeds.
RELIABLE = 0.8


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
    #: The research's own scene and sonar model instead of the held-out ones.
    paper: bool = False
    #: The sonar model (None: the scene's default, acoustic).
    model: SonarModel | None = None
    #: Scenes per experiment (None: the experiment's default).
    n_seeds: int | None = None
    #: For ``real``: the log, the sonar rig (None: the default), the cell size.
    log: Path | None = None
    rig: Path | None = None
    resolution: float = 0.1
    #: Where a scene folder's truth given as a bare image lies: metres per pixel and the
    #: lower-left corner.
    truth_resolution: float | None = None
    truth_origin: tuple[float, float] = (0.0, 0.0)
    #: The methods mapped, in order.
    methods: tuple[MethodSpec, ...] = METHODS

    def make(self, kind: str, seed: int, *, resimulate: bool = False, **defaults: Any) -> Scenario:
        """The experiment's scene: the user's folder, or the built-in one. With
        ``resimulate``, a folder's readings are simulated anew from its trajectory (with
        the run's sonar model, or the acoustic one) when it has a trajectory."""
        if self.scene is not None:
            model = self.model
            if model is None and resimulate and (self.scene / "trajectory.csv").is_file():
                model = AcousticModel()
            return load_scene(
                self.scene,
                seed=seed,
                model=model,
                resolution=self.truth_resolution,
                origin=self.truth_origin,
            )
        params = {**defaults, **self.scene_params}
        if self.model is not None:
            params["model"] = self.model
        elif self.paper:
            params["model"] = PAPER_NOISE[kind]
        return make_scenario(kind, seed=seed, **params)

    def seeds(self, first: int, full: int, quick: bool) -> list[int]:
        n = self.n_seeds if self.n_seeds is not None else (1 if quick else full)
        return [first + k for k in range(n)]


def _build(spec: MethodSpec, scene: Scenario) -> tuple[OccupancyMap, float]:
    mapper = make_mapper(spec.method, **spec.params)
    t0 = time.perf_counter()
    m = mapper.fit(scene.readings, scene.truth.grid, scene.rig).result()
    return m, time.perf_counter() - t0


def _score_row(
    spec: MethodSpec, scene: Scenario, m: OccupancyMap, seconds: float, **extra: Any
) -> dict[str, Any]:
    observed = observed_walls(scene.truth, scene.rig, scene.readings)
    s = score(scene.truth, m, scene.passages, scene.obstacles, observed).as_dict()
    return {"method": spec.label, **extra, "seconds": seconds, **s}


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


#: Table headings of the report, in order: a column name and what it holds.
_HEADINGS = {
    "method": "method",
    "seed": "seed",
    "f1_all": "wall F1",
    "f1": "F1 (known cells)",
    "passages_open": "open",
    "passages_detected": "detected",
    "passages": "passages",
    "width_error": "width error [m]",
    "false_openings": "false openings",
    "passage_f1": "passage F1",
    "dist_to_truth": "to truth [m]",
    "small_found": "posts found",
    "size_error": "post size error [m]",
    "unknown": "unknown",
    "seconds": "time [s]",
    "known": "cells known",
    "occupied": "occupied (of known)",
    "outliers": "outlier readings",
    "outlier_share": "outlier share",
}


def _short(rows: Sequence[dict[str, Any]], keys: Sequence[str]) -> list[dict[str, Any]]:
    return [{_HEADINGS.get(k, k): r.get(k) for k in keys} for r in rows]


def _mean(values: Sequence[float]) -> float:
    vals = [v for v in values if isinstance(v, int | float) and math.isfinite(v)]
    return float(np.mean(vals)) if vals else math.nan


def _per_method(rows: Sequence[dict[str, Any]], labels: Sequence[str]) -> list[dict[str, Any]]:
    """Per method, over its maps: sums of passage counts, means of the rest."""
    out = []
    for label in labels:
        mine = [r for r in rows if r["method"] == label]
        if not mine:
            continue
        detected = [r for r in mine if r["passages_detected"]]
        out.append(
            {
                "method": label,
                "maps": len(mine),
                "f1_all": _mean([r["f1_all"] for r in mine]),
                "passages_open": sum(r["passages_open"] for r in mine),
                "passages_detected": sum(r["passages_detected"] for r in mine),
                "passages": sum(r["passages"] for r in mine),
                # Weighted by detections, so a map with one lucky detection counts once.
                "width_error": _mean(
                    [r["width_error"] for r in detected for _ in range(r["passages_detected"])]
                ),
                "false_openings": _mean([r["false_openings"] for r in mine]),
                "passage_f1": _mean([r["passage_f1"] for r in mine]),
                "seconds": _mean([r["seconds"] for r in mine]),
            }
        )
    return out


_SUMMARY_KEYS = (
    "method",
    "f1_all",
    "passages_open",
    "passages_detected",
    "passages",
    "width_error",
    "false_openings",
    "passage_f1",
    "seconds",
)


def _maps_over_seeds(
    run: _Run,
    name: str,
    scenes: Sequence[Scenario],
    progress: Progress | None,
    caption: str,
) -> None:
    """Every method on every scene; the first scene's maps drawn; tables per method."""
    total = len(scenes) * len(run.methods)
    done = 0
    for k, scene in enumerate(scenes):
        sd = scene.params.get("seed", k)
        maps: dict[str, OccupancyMap] = {}
        for spec in run.methods:
            m, seconds = _build(spec, scene)
            maps[spec.label] = m
            folder = run.out / "maps" / (f"seed{sd}" if len(scenes) > 1 else "")
            write_map(m, folder / spec.label)
            run.rows.append(_score_row(spec, scene, m, seconds, seed=sd))
            done += 1
            if progress is not None:
                progress(done, total)
        if k == 0:
            fig = save_side_by_side(maps, run.out / f"{name}.png", truth=scene.truth)
            run.report.figure(fig, caption)
    labels = [s.label for s in run.methods]
    summary = _per_method(run.rows, labels)
    atomic_write_text(run.out / "summary.json", json_dumps(summary))
    run.report.table(
        _short(summary, _SUMMARY_KEYS),
        f"Per method over {len(scenes)} scene(s): mean wall F1 (every cell, unknown counted "
        "as not occupied), passages open / detected / annotated (summed), mean width "
        "error of detected passages, mean false openings per map, mean passage F1, mean "
        "time to build a map.",
    )
    run.report.table(
        _short(
            run.rows,
            (
                "method",
                "seed",
                "f1_all",
                "f1",
                "passages_open",
                "passages_detected",
                "passages",
                "width_error",
                "false_openings",
                "passage_f1",
                "unknown",
            ),
        ),
        "Per map.",
    )


def _scene_note(run: _Run, family: str, seeds: Sequence[int]) -> str:
    if run.scene is not None:
        return f"Scene: the folder {run.scene}."
    if run.paper:
        return (
            f"Scene: the research's own '{family}' scene, read with Thrun's model as the "
            "documents simulated it (the mappers' forward models are that model): a "
            "reproduction, not a claim."
        )
    return (
        f"Scenes: held-out '{family}' scenes, seeds {seeds[0]} to {seeds[-1]}, read by "
        "the acoustic sonar (sonarmap.acoustics); no method was tuned on this family or "
        "these seeds."
    )


def _doorways(run: _Run, quick: bool, seed: int | None, progress: Progress | None) -> None:
    family = "doorways" if run.paper or run.scene is not None else "corridor"
    first = seed if seed is not None else (0 if run.paper else HELD_OUT_SEED)
    seeds = [first] if run.paper or run.scene is not None else run.seeds(first, 5, quick)
    scenes = [run.make(family, sd) for sd in seeds]
    run.params["scenarios"] = [s.params for s in scenes]
    run.report.text(
        "Doorways (thesis 000 fig. 4.1): a corridor with doorways in both walls, six "
        "sonars passing along it. A doorway is open when both walls beside it are there "
        "and a free path crosses it; detected when its recovered width is within two "
        "cells or 25 %. " + _scene_note(run, family, seeds)
    )
    _maps_over_seeds(
        run,
        "doorways",
        scenes,
        progress,
        f"{scenes[0].name} (seed {seeds[0]}): truth outlined in red; second row: the "
        "classes every score uses (occupied, free, unknown in blue).",
    )


def _room_turn(run: _Run, quick: bool, seed: int | None, progress: Progress | None) -> None:
    kwargs: dict[str, Any] = {"duration": 15.0} if quick else {}
    sd = seed if seed is not None else 0
    scene = run.make("room-turn", sd, **kwargs)
    run.params["scenario"] = scene.params
    run.report.text(
        "A robot with four front sonars turns in place at uneven speed in a room with a "
        "door, its sonar mounting known only roughly (figures 4.3 / 4.5 / 7 of the "
        "documents). A training scene: its numbers re-enact the research's real-data "
        "experiment, they are not claims."
    )
    _maps_over_seeds(
        run,
        "room-turn",
        [scene],
        progress,
        "room-turn: truth outlined in red; second row: the classes every score uses.",
    )


def narrowest_reliable(per: Sequence[dict[str, Any]], share: float = RELIABLE) -> float:
    """The narrowest width detected, together with every wider one, in at least
    ``share`` of the scenes (NaN when even the widest is not).

    ``per`` holds one row per (scene, passage) with ``true_width`` and ``detected``.

    Examples
    --------
    >>> rows = [{"true_width": w, "detected": d} for w, d in
    ...         [(0.2, False), (0.2, True), (0.4, True), (0.4, True), (0.3, True), (0.3, True)]]
    >>> narrowest_reliable(rows)
    0.3
    """
    widths = sorted({round(r["true_width"], 3) for r in per}, reverse=True)
    best = math.nan
    for w in widths:
        got = [r["detected"] for r in per if round(r["true_width"], 3) == w]
        if np.mean(got) < share:
            break
        best = w
    return best


def _passages(run: _Run, quick: bool, seed: int | None, progress: Progress | None) -> None:
    family = "passages" if run.paper or run.scene is not None else "gaps"
    if run.paper:
        first = seed if seed is not None else 0
        seeds = run.seeds(first, 3, quick)
        widths = (0.2, 0.4, 0.6, 0.8) if quick else None
        # The research's ladder with 1 cm range noise, as in thesis 002.
        model = run.model if run.model is not None else replace(PAPER_NOISE["passages"], sigma=0.01)
        params: dict[str, Any] = {"widths": widths} if widths else {}
        params.update(run.scene_params)
        scenes = [make_scenario("passages", seed=sd, model=model, **params) for sd in seeds]
    else:
        first = seed if seed is not None else (0 if run.scene is not None else HELD_OUT_SEED)
        recorded = run.scene is not None and not (run.scene / "trajectory.csv").is_file()
        seeds = [first] if recorded else run.seeds(first, 10, quick)
        kwargs: dict[str, Any] = {"widths": (0.15, 0.3, 0.45, 0.6, 0.8)} if quick else {}
        if run.scene is not None:
            kwargs = {"resimulate": True}
        scenes = [run.make(family, sd, **kwargs) for sd in seeds]
    run.params.update({"seeds": seeds, "scenarios": [s.params for s in scenes]})
    run.report.text(
        "Gaps of different widths in a thin wall beside the robot's path (thesis 002, "
        "figs 4.9-4.10). A passage is detected when both walls beside it are there, a free "
        "path crosses it, and its recovered width (the narrowest gap bounded by occupied "
        f"cells) is within two cells or 25 % of the truth. A width is reliably detected "
        f"when it and every wider one are detected in at least {RELIABLE:.0%} of the "
        "scenes. False openings are see-through gaps where the truth has wall. "
        + _scene_note(run, family, seeds)
    )
    per: list[dict[str, Any]] = []
    total = len(scenes) * len(run.methods)
    done = 0
    first_maps: dict[str, OccupancyMap] = {}
    for scene in scenes:
        sd = scene.params.get("seed", 0)
        for spec in run.methods:
            m, seconds = _build(spec, scene)
            if scene is scenes[0]:
                first_maps[spec.label] = m
            write_map(m, run.out / "maps" / f"seed{sd}" / spec.label)
            run.rows.append(_score_row(spec, scene, m, seconds, seed=sd))
            for res in (measure_passage(scene.truth, m, p) for p in scene.passages):
                per.append(
                    {
                        "method": spec.label,
                        "seed": sd,
                        "passage": res.name,
                        "true_width": round(res.true_width, 3),
                        "width": res.width,
                        "open": res.open,
                        "detected": res.detected,
                    }
                )
            done += 1
            if progress is not None:
                progress(done, total)
    labels = [s.label for s in run.methods]
    summary = _passage_summary(per, run.rows, labels)
    atomic_write_text(run.out / "passages.json", json_dumps(per))
    atomic_write_text(run.out / "summary.json", json_dumps(summary))
    run.report.figure(
        save_side_by_side(first_maps, run.out / "maps.png", truth=scenes[0].truth),
        f"Seed {seeds[0]}: truth outlined in red; second row: the classes every score uses.",
    )
    run.report.figure(
        _plot_detection(per, labels, run.out / "detection.png"),
        "Share of the scenes in which each passage width is detected, per method; the "
        f"dotted line is the {RELIABLE:.0%} that counts as reliable.",
    )
    run.report.figure(
        _plot_widths(per, labels, run.out / "widths.png"),
        "Recovered against true width of the detected passages, mean and spread over "
        "scenes (the dashed line is exact).",
    )
    run.report.table(
        _short(
            summary,
            (
                "method",
                "narrowest_reliable",
                "ratio_vs_tuned_inverse",
                "detected",
                "passages",
                "width_error",
                "false_openings",
                "f1_all",
                "passage_f1",
            ),
        ),
        "Per method over every scene: narrowest reliably detected width (metres), the "
        "tuned inverse's narrowest over the method's, passages detected of those "
        "annotated, mean width error of the detected ones (metres), mean false openings "
        "per map, mean wall F1 and passage F1.",
    )
    run.report.table(
        _short(
            run.rows,
            (
                "method",
                "seed",
                "f1_all",
                "passages_detected",
                "passages",
                "width_error",
                "false_openings",
                "passage_f1",
                "small_found",
                "size_error",
            ),
        ),
        "Per map.",
    )


_HEADINGS.update(
    {
        "narrowest_reliable": "narrowest reliably detected [m]",
        "ratio_vs_tuned_inverse": "inverse / method",
        "detected": "detected",
    }
)


def _passage_summary(
    per: list[dict[str, Any]], rows: list[dict[str, Any]], labels: list[str]
) -> list[dict[str, Any]]:
    """Per method: narrowest reliably detected width, detections, width error, false
    openings, wall and passage F1."""
    out = []
    for label in labels:
        mine = [r for r in per if r["method"] == label]
        maps = [r for r in rows if r["method"] == label]
        errs = [abs(r["width"] - r["true_width"]) for r in mine if r["detected"]]
        out.append(
            {
                "method": label,
                "narrowest_reliable": narrowest_reliable(mine),
                "detected": sum(r["detected"] for r in mine),
                "passages": len(mine),
                "width_error": float(np.mean(errs)) if errs else math.nan,
                "false_openings": _mean([r["false_openings"] for r in maps]),
                "f1_all": _mean([r["f1_all"] for r in maps]),
                "passage_f1": _mean([r["passage_f1"] for r in maps]),
            }
        )
    base = next((r["narrowest_reliable"] for r in out if r["method"] == "inverse"), math.nan)
    for row in out:
        row["ratio_vs_tuned_inverse"] = base / row["narrowest_reliable"]
    return out


def _plot_detection(per: list[dict[str, Any]], labels: list[str], path: Path) -> Path:
    widths = sorted({r["true_width"] for r in per})
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label in labels:
        rate = [
            np.mean([r["detected"] for r in per if r["method"] == label and r["true_width"] == w])
            for w in widths
        ]
        ax.plot(widths, rate, marker="o", label=label)
    ax.axhline(RELIABLE, color="k", ls=":", lw=0.8)
    ax.set_xlabel("true passage width [m]")
    ax.set_ylabel("share of scenes detected")
    ax.set_ylim(-0.03, 1.03)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save_fig(fig, path)


def _plot_widths(per: list[dict[str, Any]], labels: list[str], path: Path) -> Path:
    widths = sorted({r["true_width"] for r in per})
    fig, ax = plt.subplots(figsize=(7, 5))
    for label in labels:
        xs, means, stds = [], [], []
        for w in widths:
            vals = [
                r["width"]
                for r in per
                if r["method"] == label and r["true_width"] == w and r["detected"]
            ]
            if vals:
                xs.append(w)
                means.append(np.mean(vals))
                stds.append(np.std(vals))
        ax.errorbar(xs, means, yerr=stds, marker="o", capsize=3, label=label)
    ax.plot([0, max(widths)], [0, max(widths)], "k--", lw=0.8)
    ax.set_xlabel("true passage width [m]")
    ax.set_ylabel("recovered width [m]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save_fig(fig, path)


def _noise(run: _Run, quick: bool, seed: int | None, progress: Progress | None) -> None:
    sd = seed if seed is not None else HELD_OUT_SEED
    family = "doorways" if run.paper else "corridor"
    base = run.make(family, sd)
    levels: dict[str, list[float]] = (
        {"p_rand": [0.0, 0.05], "sigma": [0.0, 0.03], "pose_sigma": [0.0, 0.03]}
        if quick
        else {
            "p_rand": [0.0, 0.02, 0.05, 0.1],
            "sigma": [0.0, 0.01, 0.03, 0.06],
            "pose_sigma": [0.0, 0.02, 0.05],
        }
    )
    methods = (
        [m for m in run.methods if m.label not in ("counting", "em-inverse-start")]
        if quick
        else list(run.methods)
    )
    run.params.update({"levels": levels, "seed": sd, "scenario": base.params})
    run.report.text(
        "Map quality as one kind of noise grows, the others at the sonar model's "
        "defaults: spurious-reading probability p_rand, range noise sigma (metres), and "
        "pose noise (metres on x and y, and sigma / 2 radians on the heading) added to "
        "the recorded poses. " + _scene_note(run, family, [sd])
    )
    total = sum(len(v) for v in levels.values()) * len(methods)
    done = 0
    for kind, values in levels.items():
        for v in values:
            scene = _noisy(base, kind, v, sd, run.model)
            for spec in methods:
                m, seconds = _build(spec, scene)
                run.rows.append(_score_row(spec, scene, m, seconds, noise=kind, level=v))
                done += 1
                if progress is not None:
                    progress(done, total)
    run.report.figure(
        _plot_noise(run.rows, levels, [m.label for m in methods], run.out / "noise.png"),
        "Wall F1 (top) and passage F1 (bottom) against each kind of noise.",
    )
    run.report.table(
        _short(
            run.rows,
            (
                "method",
                "noise",
                "level",
                "f1_all",
                "passages_detected",
                "passages",
                "false_openings",
                "passage_f1",
            ),
        ),
        "Per map.",
    )


def _noisy(base: Scenario, kind: str, v: float, seed: int, model: SonarModel | None) -> Scenario:
    """The scene re-read with one noise level changed (the geometry is the scene's)."""
    sonar: SonarModel = model if model is not None else AcousticModel()
    if kind == "p_rand":
        sonar = replace(sonar, p_rand=v)
    elif kind == "sigma":
        sonar = replace(sonar, sigma=v)
    pose = PoseNoise(v, v / 2) if kind == "pose_sigma" else None
    world = base.geometry
    if isinstance(sonar, Noise) or world is None:
        world = base.truth
    readings = simulate(world, base.rig, base.trajectory, model=sonar, pose_noise=pose, seed=seed)
    return replace(base, readings=readings, params={**base.params, "model": model_to_dict(sonar)})


_HEADINGS.update({"noise": "noise", "level": "level"})


def _plot_noise(
    rows: list[dict[str, Any]], levels: dict[str, list[float]], labels: list[str], path: Path
) -> Path:
    fig, axes = plt.subplots(2, len(levels), figsize=(4.5 * len(levels), 7), squeeze=False)
    for j, kind in enumerate(levels):
        for label in labels:
            pick = [r for r in rows if r["method"] == label and r["noise"] == kind]
            xs = [r["level"] for r in pick]
            axes[0, j].plot(xs, [r["f1_all"] for r in pick], marker="o", label=label)
            axes[1, j].plot(xs, [r["passage_f1"] for r in pick], marker="o", label=label)
        axes[0, j].set_title(kind)
        axes[1, j].set_xlabel(kind)
        axes[0, j].set_ylabel("wall F1")
        axes[1, j].set_ylabel("passage F1")
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
    # The reference stays as it was measured with: band centred on the echo.
    "band_offset": 0.0,
}


def _real(run: _Run, quick: bool, seed: int | None, progress: Progress | None) -> None:
    from .api import grid_for_readings
    from .io.carmen import ConvertSummary, read_carmen
    from .io.udacity import read_udacity
    from .rig import load_rig
    from .virtual import default_ring, virtual_sonar

    if run.log is None:
        raise ConfigError("experiment 'real' needs a log (--log)")
    log = run.log
    sd = seed if seed is not None else 0
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
    sonar, kept = virtual_sonar(laser, laser_rig, sonar_rig, seed=sd)
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
        "known; wall F1 counts a cell the sonar map leaves unknown as not occupied. No "
        "method was tuned on real data."
    )
    write_map(reference, run.out / "maps" / "laser-reference")
    maps: dict[str, OccupancyMap] = {}
    for k, spec in enumerate(run.methods):
        mapper = make_mapper(spec.method, **spec.params)
        t0 = time.perf_counter()
        maps[spec.label] = mapper.fit(sonar, grid, kept).result()
        seconds = time.perf_counter() - t0
        write_map(maps[spec.label], run.out / "maps" / spec.label)
        sc = score(reference, maps[spec.label]).as_dict()
        run.rows.append({"method": spec.label, "seconds": seconds, **sc})
        if progress is not None:
            progress(k + 1, len(run.methods))
    fig = save_side_by_side(
        maps, run.out / "real.png", truth=reference, truth_label="laser reference", outline=False
    )
    run.report.figure(
        fig,
        "Laser reference (first panel) and the sonar-only maps, with the classes every "
        "score uses below each.",
    )
    run.report.table(
        _short(
            run.rows,
            ("method", "seconds", "f1_all", "f1", "dist_to_truth", "unknown"),
        ),
        "Sonar-only maps against the laser reference (distances in metres).",
    )


def _real_sonar(run: _Run, readings: Any, rig: Any, what: str, progress: Progress | None) -> None:
    from .api import grid_for_readings
    from .mappers.em import EMMapper
    from .metrics import agreement

    grid = grid_for_readings(readings, rig, run.resolution)
    run.params.update(
        {"log": what, "readings": len(readings), "rig": rig.to_dict(), "resolution": run.resolution}
    )
    run.report.text(
        f"Real sonar data ({what}, {len(readings)} readings): no ground truth. "
        "The maps side by side, how often two methods agree on a cell both "
        "know, and the readings the probabilistic model (EM) attributes to "
        "its random component."
    )
    maps: dict[str, OccupancyMap] = {}
    for k, spec in enumerate(run.methods):
        mapper = make_mapper(spec.method, **spec.params)
        t0 = time.perf_counter()
        mapper.fit(readings, grid, rig)
        maps[spec.label] = mapper.result()
        cls = maps[spec.label].classes()
        row: dict[str, Any] = {
            "method": spec.label,
            "seconds": time.perf_counter() - t0,
            "known": float((cls != -1).mean()),
            "occupied": float((cls == 1).sum() / max(int((cls != -1).sum()), 1)),
        }
        if isinstance(mapper, EMMapper):
            row["outliers"] = int(np.sum(mapper.outlier_prob_ > 0.5))
            row["outlier_share"] = float(np.mean(mapper.outlier_prob_ > 0.5))
        run.rows.append(row)
        write_map(maps[spec.label], run.out / "maps" / spec.label)
        if progress is not None:
            progress(k + 1, len(run.methods))
    labels = list(maps)
    agree = []
    for a in labels:
        row2: dict[str, Any] = {"method": a}
        for b in labels:
            row2[b] = agreement(maps[a], maps[b])[0]
        agree.append(row2)
    fig = save_side_by_side(maps, run.out / "real.png")
    run.report.figure(fig, "Maps from the real sonar log; second row: their classes.")
    run.report.table(
        _short(
            run.rows,
            ("method", "seconds", "known", "occupied", "outliers", "outlier_share"),
        ),
        "Per method: time, share of cells known and, of those, occupied; for "
        "em, readings it attributes to the random component (posterior > 0.5).",
    )
    run.report.table(agree, "Agreement between methods on the cells both know.")
    atomic_write_text(run.out / "agreement.json", json_dumps(agree))


#: The boxes experiment's methods: every method at its defaults, and thesis 002's
#: parameter sets of the two forward methods (``--preset thesis002``).
BOX_METHODS: tuple[MethodSpec, ...] = (
    *METHODS,
    MethodSpec("stochastic-thesis002", "stochastic", preset_params("stochastic", "thesis002")),
    MethodSpec("gradient-thesis002", "gradient", preset_params("gradient", "thesis002")),
)


def _boxes(run: _Run, quick: bool, seed: int | None, progress: Progress | None) -> None:
    sd = seed if seed is not None else 0
    # Both maps of the thesis unless the scene or one layout is given.
    layouts: list[int | None] = (
        [None] if run.scene is not None or "layout" in run.scene_params else [1, 2]
    )
    # Quick: the robot drives twice as fast, so half the readings.
    extra: dict[str, Any] = {"speed": 0.5} if quick else {}
    kinds: list[dict[str, Any]] = [{"layout": k} if k else {} for k in layouts]
    # Thesis 002 simulated with its own probabilistic model; --model overrides it.
    scenes = [run.make("boxes", sd, model=PAPER_NOISE["boxes"], **extra, **k) for k in kinds]
    run.params["scenarios"] = [s.params for s in scenes]
    run.report.text(
        "Boxes (thesis 002, section 4.4.2, figs 4.4-4.6): the robot drives along a "
        "corridor between two rows of boxes, three sonars on each side, in two layouts; "
        "the readings come from Thrun's probabilistic model with thesis 002's parameters "
        "(p_rand 0.001, p_hit 0.35), as the thesis simulated them, unless --model says "
        "otherwise. The thesis compared its stochastic method (its parameter set: "
        "'stochastic-thesis002', with the 3.5 m range limit) with the traditional inverse "
        "model. The gaps between neighbouring boxes are the passages. A training scene "
        "read with the mappers' own model: a reproduction, not a claim."
    )
    labels = [m.label for m in run.methods]
    total = len(scenes) * len(run.methods)
    done = 0
    for scene in scenes:
        name = f"layout{scene.params['layout']}" if "layout" in scene.params else scene.name
        maps: dict[str, OccupancyMap] = {}
        for spec in run.methods:
            m, seconds = _build(spec, scene)
            maps[spec.label] = m
            write_map(m, run.out / "maps" / name / spec.label)
            run.rows.append(_score_row(spec, scene, m, seconds, map=name))
            done += 1
            if progress is not None:
                progress(done, total)
        run.report.figure(
            save_side_by_side(maps, run.out / f"boxes-{name}.png", truth=scene.truth),
            f"{name} (seed {sd}): truth outlined in red; below each map the classes every "
            "score uses.",
        )
    summary = _per_method(run.rows, labels)
    atomic_write_text(run.out / "summary.json", json_dumps(summary))
    run.report.table(
        _short(summary, _SUMMARY_KEYS),
        f"Per method over the {len(scenes)} map(s): mean wall F1, gaps open / detected / "
        "annotated (summed), mean width error of the detected gaps, mean false openings, "
        "mean passage F1, mean time to build a map.",
    )
    run.report.table(
        _short(
            run.rows,
            (
                "method",
                "map",
                "f1_all",
                "f1",
                "passages_detected",
                "passages",
                "width_error",
                "false_openings",
                "passage_f1",
                "seconds",
            ),
        ),
        "Per map.",
    )


_HEADINGS["map"] = "map"


EXPERIMENTS: dict[str, Callable[[_Run, bool, int | None, Progress | None], None]] = {
    "doorways": _doorways,
    "passages": _passages,
    "room-turn": _room_turn,
    "noise": _noise,
    "real": _real,
    "boxes": _boxes,
}


def run_experiment(
    name: str,
    out: str | Path,
    *,
    quick: bool = False,
    seed: int | None = None,
    seeds: int | None = None,
    paper: bool = False,
    model: SonarModel | None = None,
    progress: Progress | None = None,
    scene: str | Path | None = None,
    scene_params: dict[str, Any] | None = None,
    log: str | Path | None = None,
    rig: str | Path | None = None,
    resolution: float = 0.1,
    truth_resolution: float | None = None,
    truth_origin: tuple[float, float] = (0.0, 0.0),
    methods: Sequence[MethodSpec] | None = None,
) -> Path:
    """Run an experiment into folder ``out``; return the path of its ``report.html``.

    Parameters
    ----------
    seed : int, optional
        The first scene's seed (default: the first held-out seed, or 0 for the
        research's own scenes).
    seeds : int, optional
        How many scenes (default: the experiment's own, 1 with ``quick``).
    paper : bool
        The research's own scene read with Thrun's model, instead of held-out scenes.
    model : AcousticModel or Noise, optional
        The sonar model of the simulated readings (default: the scene's).
    scene : path, optional
        A scene folder of one's own (truth.yaml, rig.yaml, trajectory.csv and/or
        readings.csv, optional geometry.yaml and annotations.yaml) used instead of the
        built-in scene; with a trajectory, each seed's readings are simulated from it.
    scene_params : dict, optional
        Parameters of the built-in scene (e.g. ``widths`` for passages).
    log, rig : path, optional
        For ``real``: a CARMEN log or a udacity ``measurement.txt``, and the sonar rig
        (default: :func:`sonarmap.virtual.default_ring` for laser logs).
    resolution : float
        Cell size of ``real`` (metres).
    truth_resolution, truth_origin : float and (float, float), optional
        For a ``scene`` folder whose truth is a bare image (``truth.png``): metres per
        pixel, and the world position of its lower-left corner (metres).
    methods : sequence of MethodSpec, optional
        The methods mapped, in order, each under its own label (default: the module's
        :data:`METHODS`; ``boxes``: :data:`BOX_METHODS`).
    """
    if scene is not None and scene_params:
        raise ConfigError("give either a scene folder or scene parameters, not both")
    if scene is not None and paper:
        raise ConfigError("give either a scene folder or --paper, not both")
    if seeds is not None and seeds < 1:
        raise ConfigError(f"seeds must be >= 1, got {seeds}")
    try:
        body = EXPERIMENTS[name]
    except KeyError:
        raise ConfigError(f"unknown experiment '{name}'; valid: {', '.join(EXPERIMENTS)}") from None
    if methods is None:
        specs = BOX_METHODS if name == "boxes" else METHODS
    else:
        specs = tuple(methods)
        labels = [m.label for m in specs]
        if not specs or len(set(labels)) != len(labels):
            # Each method's maps are written into a folder named by its label.
            raise ConfigError(f"methods: want one or more distinct labels, got {labels}")
    folder = Path(out)
    run = _Run(
        folder,
        Report(f"sonarmap experiment: {name}"),
        scene=Path(scene) if scene is not None else None,
        scene_params=dict(scene_params or {}),
        paper=paper,
        model=model,
        n_seeds=seeds,
        log=Path(log) if log is not None else None,
        rig=Path(rig) if rig is not None else None,
        resolution=resolution,
        truth_resolution=truth_resolution,
        truth_origin=truth_origin,
        methods=specs,
    )
    run.params.update(
        {
            "experiment": name,
            "quick": quick,
            "paper": paper,
            "seed": seed,
            "model": model_to_dict(model) if model is not None else "the scene's default",
            "methods": [{"label": m.label, "method": m.method, "params": m.params} for m in specs],
        }
    )
    run.report.text(
        "Baseline: the tuned inverse model ('inverse', its defaults chosen by a "
        "parameter sweep on training scenes); 'inverse-traditional' is the laser-style "
        "setting the research compared against, on the same band."
    )
    # Everything is written beside the folder and moved in at the end: a run that fails
    # on its input (or is interrupted) leaves no folder and no partial results.
    with atomic_folder(folder) as tmp:
        run.out = tmp
        body(run, quick, seed, progress)
        _tables(run)
        run.report.parameters(run.params)
        run.report.write(tmp / "report.html")
    run.out = folder
    return folder / "report.html"
