"""Issue 14's held-out goals, read from the folders that ``sonarmap experiment`` wrote.

Run::

    python -m benchmarks.issue14_goals --passages out/exp-passages-1000 out/exp-passages-1005 \
        --doorways out/exp-doorways --real out/real-intel out/real-freiburg

``--passages`` takes one or more ``experiment passages`` folders (e.g. the held-out
scenes split in two runs) and pools their scenes, so the narrowest width reliably
detected is judged over all of them together. For each method it prints the narrowest
reliably detected width (:func:`sonarmap.experiments.narrowest_reliable`), the tuned
inverse's over it, the gaps detected per width, and why the gaps of each width were
missed, re-measured from the saved maps (:func:`sonarmap.metrics.measure_passage`):
*closed* (no free path crosses), *jamb missing* (crossed, but a wall beside it below
:data:`sonarmap.metrics.WALL_SHARE`), *width off* (open, recovered width outside the
tolerance). ``--doorways`` takes an ``experiment doorways`` folder and prints its
doors per method over the scenes. ``--real`` takes ``experiment real`` folders and
prints wall F1 per method and the split of the laser reference's wall cells into
occupied, free and unknown in each sonar map. Markdown tables on standard output;
nothing is written.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sonarmap.errors import ConfigError
from sonarmap.experiments import narrowest_reliable
from sonarmap.io.rosmap import read_map
from sonarmap.metrics import WALL_SHARE, measure_passage
from sonarmap.scenarios import make_scenario

#: Width classes of the per-width tables (metres, inclusive upper bounds).
WIDTH_BINS: tuple[tuple[str, float, float], ...] = (
    ("0.15-0.45 m", 0.0, 0.45),
    ("0.5-0.7 m", 0.46, 0.7),
    ("0.75 m", 0.71, 0.75),
    ("0.8 m", 0.76, 0.8),
    ("0.9 m", 0.81, 0.9),
    ("1.0 m", 0.91, 1.0),
    ("1.2 m", 1.01, 1.2),
)


def _load_json(path: Path) -> Any:
    if not path.is_file():
        raise ConfigError(f"{path}: missing (not an experiment output folder?)")
    return json.loads(path.read_text())


def _labels(rows: Sequence[dict[str, Any]]) -> list[str]:
    out: list[str] = []
    for r in rows:
        if r["method"] not in out:
            out.append(r["method"])
    return out


def _bin(width: float) -> str:
    for name, lo, hi in WIDTH_BINS:
        if lo <= width <= hi + 1e-9:
            return name
    return f"{width:.2f} m"


def _table(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _fmt(x: float, digits: int = 2) -> str:
    return "none" if not math.isfinite(x) else f"{x:.{digits}f}"


def passages_report(folders: Sequence[Path]) -> str:
    """Markdown tables of the pooled ``experiment passages`` folders."""
    per: list[dict[str, Any]] = []
    rows: list[dict[str, Any]] = []
    for folder in folders:
        per += _load_json(folder / "passages.json")
        rows += _load_json(folder / "metrics.json")
    labels = _labels(rows)
    seeds = sorted({r["seed"] for r in per})
    base = narrowest_reliable([r for r in per if r["method"] == "inverse"])
    summary = []
    for label in labels:
        mine = [r for r in per if r["method"] == label]
        maps = [r for r in rows if r["method"] == label]
        nr = narrowest_reliable(mine)
        errs = [abs(r["width"] - r["true_width"]) for r in mine if r["detected"]]
        summary.append(
            [
                label,
                _fmt(nr),
                _fmt(base / nr) + "x" if math.isfinite(nr) and math.isfinite(base) else "-",
                f"{sum(r['detected'] for r in mine)} / {len(mine)}",
                _fmt(float(np.mean(errs))) if errs else "-",
                _fmt(float(np.mean([m["false_openings"] for m in maps])), 1),
                _fmt(float(np.mean([m["f1_all"] for m in maps])), 3),
                _fmt(float(np.mean([m["passage_f1"] for m in maps])), 3),
                _fmt(float(np.mean([m["seconds"] for m in maps])), 2),
            ]
        )
    out = [
        f"Scenes: gaps seeds {', '.join(map(str, seeds))}.",
        "",
        _table(
            (
                "method",
                "narrowest reliably [m]",
                "inverse / method",
                "detected",
                "width error [m]",
                "false openings / map",
                "wall F1",
                "passage F1",
                "s / map",
            ),
            summary,
        ),
        "",
    ]
    bins = [b[0] for b in WIDTH_BINS]
    counts = []
    for label in labels:
        mine = [r for r in per if r["method"] == label]
        cells = []
        for b in bins:
            got = [r["detected"] for r in mine if _bin(r["true_width"]) == b]
            cells.append(f"{sum(got)} / {len(got)}" if got else "-")
        counts.append([label, *cells])
    out += ["Gaps detected per width:", "", _table(("method", *bins), counts), ""]
    out += ["Why gaps were missed (closed / jamb missing / width off):", ""]
    out.append(_table(("method", *bins), _misses(folders, labels, seeds, bins)))
    off = []
    for label in labels:
        cells = []
        for b in bins:
            d = [
                r["width"] - r["true_width"]
                for r in per
                if r["method"] == label
                and r["open"]
                and not r["detected"]
                and _bin(r["true_width"]) == b
            ]
            cells.append(f"{np.median(d):+.2f} ({len(d)})" if d else "-")
        off.append([label, *cells])
    out += ["", "Width-off misses: median recovered minus true width [m] (count):", ""]
    out.append(_table(("method", *bins), off))
    return "\n".join(out)


def _misses(
    folders: Sequence[Path], labels: Sequence[str], seeds: Sequence[int], bins: Sequence[str]
) -> list[list[str]]:
    """Per method and width class: misses that are closed, lack a jamb, or are mis-sized."""
    tally = {(lab, b): [0, 0, 0] for lab in labels for b in bins}
    for sd in seeds:
        scene = make_scenario("gaps", seed=sd)
        for lab in labels:
            # Runs may split the scenes, or the methods, between folders.
            stems = [f / "maps" / f"seed{sd}" / f"{lab}.yaml" for f in folders]
            m = read_map(next(p for p in stems if p.is_file()))
            for p in scene.passages:
                res = measure_passage(scene.truth, m, p)
                if res.detected:
                    continue
                k = 0 if not res.crossed else (1 if min(res.walls) < WALL_SHARE else 2)
                tally[(lab, _bin(res.true_width))][k] += 1
    return [[lab, *("/".join(map(str, tally[(lab, b)])) for b in bins)] for lab in labels]


def doorways_report(folder: Path) -> str:
    """Markdown table of an ``experiment doorways`` folder, per method over its scenes."""
    rows = _load_json(folder / "metrics.json")
    table = []
    for label in _labels(rows):
        mine = [r for r in rows if r["method"] == label]
        errs = [r["width_error"] for r in mine for _ in range(r["passages_detected"])]
        table.append(
            [
                label,
                f"{sum(r['passages_open'] for r in mine)} / {sum(r['passages'] for r in mine)}",
                f"{sum(r['passages_detected'] for r in mine)} / {sum(r['passages'] for r in mine)}",
                _fmt(float(np.mean(errs))) if errs else "-",
                _fmt(float(np.mean([r["false_openings"] for r in mine])), 1),
                _fmt(float(np.mean([r["f1_all"] for r in mine])), 3),
                _fmt(float(np.mean([r["observed_wall_recall"] for r in mine])), 3),
                _fmt(float(np.mean([r["passage_f1"] for r in mine])), 3),
                _fmt(float(np.mean([r["seconds"] for r in mine])), 2),
            ]
        )
    head = (
        "method",
        "doors open",
        "doors detected",
        "width error [m]",
        "false openings / map",
        "wall F1",
        "observed walls",
        "passage F1",
        "s / map",
    )
    return "\n".join([f"{folder.name}:", "", _table(head, table), ""])


def real_report(folders: Sequence[Path]) -> str:
    """Markdown table of ``experiment real`` folders: wall F1 and the reference's walls."""
    out = []
    for folder in folders:
        rows = _load_json(folder / "metrics.json")
        ref = read_map(folder / "maps" / "laser-reference.yaml").classes()
        wall = ref == 1
        base = next(r["f1_all"] for r in rows if r["method"] == "inverse")
        table = []
        for r in rows:
            c = read_map(folder / "maps" / f"{r['method']}.yaml").classes()[wall]
            table.append(
                [
                    r["method"],
                    f"{r['f1_all']:.3f}",
                    f"{r['f1_all'] - base:+.3f}",
                    f"{r['precision_all']:.3f}",
                    f"{r['recall_all']:.3f}",
                    f"{np.mean(c == 1):.3f} / {np.mean(c == 0):.3f} / {np.mean(c == -1):.3f}",
                    f"{r['f1']:.3f}",
                    f"{r['seconds']:.1f}",
                ]
            )
        head = (
            "method",
            "wall F1",
            "minus inverse",
            "wall precision",
            "wall recall",
            "reference walls occupied / free / unknown",
            "F1 (both know)",
            "s",
        )
        out += [
            f"{folder.name} ({int(wall.sum())} reference wall cells):",
            "",
            _table(head, table),
            "",
        ]
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tables; exit code 2 on a missing or malformed folder."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--passages", type=Path, nargs="*", default=[])
    ap.add_argument("--doorways", type=Path, default=None)
    ap.add_argument("--real", type=Path, nargs="*", default=[])
    args = ap.parse_args(argv)
    try:
        if args.passages:
            print(passages_report(args.passages))
        if args.doorways is not None:
            print(doorways_report(args.doorways))
        if args.real:
            print(real_report(args.real))
    except (ConfigError, KeyError, StopIteration, json.JSONDecodeError) as exc:
        print(f"issue14_goals: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
