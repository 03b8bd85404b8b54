"""The research's claims, measured: every method on the doorways, passages and room-turn
scenes, exact and with noise. Run with ``python -m benchmarks.claims [--json FILE]``.

Per scene and method: doorways left passable (a free 4-connected path through the
opening), passages detected and the narrowest one, the mean error of recovered widths
where detected, F1 of occupied cells, and the time to build the map.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from sonarmap.experiments import TRADITIONAL_INVERSE
from sonarmap.mappers import make_mapper
from sonarmap.metrics import measure_passage, score
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.sensors import Noise

NOISE = Noise(0.05, 1.0, 0.02)
METHODS: list[tuple[str, str, dict[str, Any]]] = [
    ("inverse (traditional)", "inverse", TRADITIONAL_INVERSE),
    ("inverse (tuned default)", "inverse", {}),
    ("counting", "counting", {}),
    ("gradient", "gradient", {}),
    ("gradient a2=0.001", "gradient", {"a2": 0.001}),
    ("gradient lbfgs", "gradient", {"solver": "lbfgs"}),
    ("stochastic", "stochastic", {}),
    ("stochastic thesis000 greedy", "stochastic", {"preset": "thesis000", "schedule": "greedy"}),
    ("em", "em", {}),
]


def scenes() -> dict[str, Scenario]:
    return {
        "doorways": make_scenario("doorways"),
        "passages": make_scenario("passages"),
        "doorways+noise": make_scenario("doorways", noise=NOISE),
        "passages+noise": make_scenario("passages", noise=NOISE),
        "room-turn": make_scenario("room-turn"),
    }


def evaluate(label: str, method: str, params: dict[str, Any], sc: Scenario) -> dict[str, Any]:
    mapper = make_mapper(method, **params)
    t0 = time.perf_counter()
    mapper.fit(sc.readings, sc.truth.grid, sc.rig)
    seconds = time.perf_counter() - t0
    m = mapper.result()
    s = score(sc.truth, m, sc.passages)
    results = [measure_passage(sc.truth, m, p) for p in sc.passages]
    detected = [r for r in results if r.detected]
    return {
        "method": label,
        "open": s.passages_open,
        "detected": s.passages_detected,
        "passages": s.passages,
        "narrowest": min((r.true_width for r in detected), default=math.nan),
        "width_error": float(np.mean([abs(r.width - r.true_width) for r in detected]))
        if detected
        else math.nan,
        "f1": s.f1,
        "seconds": seconds,
        "widths": {r.name: [round(r.true_width, 3), round(r.width, 3)] for r in results},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--json", help="Also write the results to this JSON file.")
    args = parser.parse_args()
    out: dict[str, list[dict[str, Any]]] = {}
    console = Console(width=150)
    for name, sc in scenes().items():
        table = Table(
            "method",
            "open",
            "detected",
            "narrowest [m]",
            "width error [m]",
            "F1",
            "time [s]",
            title=f"{name} ({len(sc.passages)} passages)",
        )
        rows = [evaluate(label, method, params, sc) for label, method, params in METHODS]
        for r in rows:
            table.add_row(
                r["method"],
                f"{r['open']}/{r['passages']}",
                f"{r['detected']}/{r['passages']}",
                f"{r['narrowest']:.2f}",
                f"{r['width_error']:.3f}",
                f"{r['f1']:.3f}",
                f"{r['seconds']:.2f}",
            )
        console.print(table)
        out[name] = rows
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)


if __name__ == "__main__":
    main()
