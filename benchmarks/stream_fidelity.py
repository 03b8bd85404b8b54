"""Does streaming keep the offline map? Streamed against offline wall F1, and speed.

For each method that streams (``inverse``, ``gradient``, ``em-thrun``) the same
readings are mapped offline (the method's ``fit`` at its defaults) and streamed
(``StreamingMapper`` at the default strategy, or ``--window``; one update per
``--period`` s of log, as fast as possible), and both maps are scored against the
truth. Reported per method: offline wall F1 and time, streamed wall F1, their ratio,
the stream's real-time factor, the most readings it held and its state, and the load
average of the machine (the real-time factors are wall-clock: a shared machine slows
them; the CPU column divides the log's length by the process's CPU time instead, one
numba thread, which other jobs slow less). ``--both-ways`` adds each method that can fold
streamed the other way round (``gradient`` folding, at its default ``no_echo``, and
``em-thrun`` forgetting); each row says which. The stream ends with :meth:`StreamingMapper.finish`
(counted in its time); ``--no-finish`` leaves it out.

Scenes (``--scene``): ``office`` (the ``ring16`` rig, 16 Polaroid sonars at 20 Hz, the
first ``--seconds`` of the tour) or ``corridor`` (six MaxSonar EZ1s); both are held-out
families, so report with ``--seed`` 1000 or above. Tune on training scenes
(``doorways``, ``hall``, ``suite``, seeds below 1000; ``--rig`` names the preset).

Run with ``python -m benchmarks.stream_fidelity --scene office --seconds 60``; also
``[--seed 1000] [--methods inverse,gradient,em-thrun] [--param K=V ...] [--period 0.25]
[--no-offline] [--profile N] [--json F]`` (``--no-offline``: stream only; ``--profile
N``: print the stream's N costliest functions).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from rich.console import Console
from rich.table import Table

from sonarmap.errors import ConfigError
from sonarmap.mappers import make_mapper, parse_params
from sonarmap.metrics import score
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.streaming import StreamingMapper, replay

METHODS = ("inverse", "gradient", "em-thrun")
#: The methods whose streams can fold the readings that leave (``--both-ways`` adds the
#: other way round).
FOLDING = ("gradient", "em-thrun")


def _log(msg: str) -> None:
    print(f"[stream fidelity {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def scene(name: str, seed: int, seconds: float | None, rig: str | None = None) -> Scenario:
    """The scene; ``seconds`` cuts the office tour (the other scenes have their length);
    ``rig`` a preset rig in place of the scene's own."""
    kw: dict[str, Any] = {} if rig is None else {"rig": rig}
    if name == "office":
        return make_scenario("office", seed=seed, duration=seconds or 60.0, **kw)
    return make_scenario(name, seed=seed, **kw)


def method_row(
    sc: Scenario,
    method: str,
    window: str | None,
    period: float,
    offline: bool,
    fold: bool | None = None,
    profile: int = 0,
    finish: bool = True,
    params: dict[str, Any] | None = None,
) -> dict[str, Any]:
    grid, rig, r = sc.truth.grid, sc.rig, sc.readings
    kw = dict(params or {})
    # Compiled kernels loaded before timing. The warm-up's window is shorter than its
    # 500 readings so that readings leave it and the fold's kernels compile here too,
    # not inside the timed stream (the inverse keeps every reading: nothing leaves).
    warm = None if method == "inverse" else "last:100"
    replay(
        [r.take(np.arange(min(500, len(r))))],
        StreamingMapper(method, grid, rig, strategy=warm, fold=fold, **kw),
    )
    sm = StreamingMapper(method, grid, rig, strategy=window, fold=fold, **kw)
    folds = method in FOLDING and sm.engine.fold
    _log(f"{method}: streaming {len(r):,} readings ({sm.strategy.spec()}, fold {folds})")
    prof = cProfile.Profile() if profile else None
    if prof is not None:
        prof.enable()
    cpu0 = time.process_time()
    rep = replay([r], sm, period=period, finish=finish)
    cpu = time.process_time() - cpu0
    if prof is not None:
        prof.disable()
        pstats.Stats(prof, stream=sys.stderr).sort_stats("tottime").print_stats(profile)
    row: dict[str, Any] = {
        "method": method
        + ("" if method not in FOLDING else ", folding" if folds else ", forgetting")
        + ("" if finish else ", unfinished"),
        "fold": folds,
        "strategy": sm.strategy.spec(),
        "f1_streamed": score(sc.truth, sm.result()).f1_all,
        "realtime_factor": rep.realtime_factor,
        "cpu_realtime_factor": rep.data_duration / cpu if cpu > 0 else float("inf"),
        "stream_s": rep.wall_time,
        "max_in_play": rep.max_in_play,
        "state_mb": rep.max_state_bytes / 2**20,
    }
    if offline:
        _log(f"{method}: offline fit")
        t0 = time.perf_counter()
        m = make_mapper(method, **kw).fit(r, grid, rig)
        row["offline_s"] = time.perf_counter() - t0
        row["f1_offline"] = score(sc.truth, m.result()).f1_all
        row["ratio"] = row["f1_streamed"] / row["f1_offline"] if row["f1_offline"] else np.nan
    return row


def print_rows(rows: list[dict[str, Any]], title: str) -> None:
    t = Table(
        "method (strategy)",
        "offline F1",
        "offline [s]",
        "streamed F1",
        "ratio",
        "x real time",
        "x real time (CPU)",
        "in play",
        "state [MB]",
        title=title,
    )
    for s in rows:
        t.add_row(
            f"{s['method']} ({s['strategy']})",
            f"{s['f1_offline']:.3f}" if "f1_offline" in s else "-",
            f"{s['offline_s']:.0f}" if "offline_s" in s else "-",
            f"{s['f1_streamed']:.3f}",
            f"{s['ratio']:.2f}" if "ratio" in s else "-",
            f"{s['realtime_factor']:.1f}",
            f"{s['cpu_realtime_factor']:.1f}",
            f"{s['max_in_play']:,}",
            f"{s['state_mb']:.0f}",
        )
    console = Console(width=150)
    console.print(t)
    console.print(f"load average at the end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--scene", default="office", choices=("office", "corridor", "doorways", "hall", "suite")
    )
    parser.add_argument("--rig", help="a preset rig in place of the scene's own")
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a parameter of every method, offline and streamed (repeatable)",
    )
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--seconds", type=float, help="office: seconds of the tour (60)")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--window", help="strategy for every method (default: each one's)")
    parser.add_argument("--period", type=float, default=0.25)
    parser.add_argument("--no-offline", action="store_true", help="stream only")
    parser.add_argument(
        "--both-ways",
        # The old name, in the commands of the results pages run before the rename.
        "--forget",
        dest="both_ways",
        action="store_true",
        help="also stream gradient and em-thrun the other way round (folding or forgetting)",
    )
    parser.add_argument("--no-finish", action="store_true", help="end the streams without finish()")
    parser.add_argument(
        "--profile", type=int, default=0, help="print the stream's N costliest functions"
    )
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    t0 = time.perf_counter()
    sc = scene(args.scene, args.seed, args.seconds, args.rig)
    dur = float(sc.readings.t[-1] - sc.readings.t[0])
    _log(f"{args.scene} seed {args.seed}: {len(sc.readings):,} readings, {dur:.0f} s of log, "
         f"simulated in {time.perf_counter() - t0:.0f} s")  # fmt: skip
    pairs = dict(p.split("=", 1) for p in args.param if "=" in p)
    if len(pairs) != len(args.param):
        parser.error(f"--param takes KEY=VALUE, got {args.param}")
    rows = []
    for m in args.methods.split(","):
        try:
            params = parse_params(m, pairs)
        except ConfigError as e:
            parser.error(f"--param: {e}")
        rows.append(
            method_row(
                sc,
                m,
                args.window,
                args.period,
                not args.no_offline,
                profile=args.profile,
                finish=not args.no_finish,
                params=params,
            )
        )
        if args.both_ways and m in FOLDING:
            rows.append(
                method_row(
                    sc,
                    m,
                    args.window,
                    args.period,
                    False,
                    fold=not rows[-1]["fold"],
                    finish=not args.no_finish,
                    params=params,
                )
            )
    print_rows(
        rows,
        f"{args.scene} (seed {args.seed}, {len(sc.rig.mounts)} sonars, {dur:.0f} s, "
        f"{len(sc.readings):,} readings), update every {args.period:g} s of log",
    )
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=2, default=float))


if __name__ == "__main__":
    main()
