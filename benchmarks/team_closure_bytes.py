"""What a loop closure costs on the wire, in each form it could travel in.

One robot's mission (``--map``, ``--duration``, ``--seed``) gives the closures its store
holds at the end; they are cut into batches of ``--batch`` closures (an answer entry
carries its poses' closures together) and each batch is measured in bytes:

- ``record``: each closure as its record without its feature matches
  (:func:`sonarmap.team.records.encode`), the batch a msgpack list;
- ``compact``: each closure in :mod:`sonarmap.team.peerclosures`' form (pose ids,
  quantised relative pose, float32 covariance, inliers), the batch a msgpack list;

each one raw (msgpack) and compressed as the exchange compresses a body
(:func:`sonarmap.team.wire.pack`: one zstd frame with the preset dictionary, inside a
map ``{"c": batch}``). Printed: bytes per closure, mean over the batches.

Run with ``python -m benchmarks.team_closure_bytes [--map office] [--duration 300]
[--seed 0] [--batch 1 8 32]``.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import msgpack

from sonarmap.cli.common import resolve_map
from sonarmap.team.mission import MissionConfig, RobotAgent
from sonarmap.team.peerclosures import encode_closures
from sonarmap.team.records import ClosureEdge, encode
from sonarmap.team.wire import pack


def batch_bytes(closures: Sequence[ClosureEdge], form: str) -> tuple[int, int]:
    """(raw, compressed) bytes of one batch of ``closures`` in ``form`` (``record`` or
    ``compact``)."""
    if form == "record":
        rows: list[Any] = [encode(replace(c, matches=())) for c in closures]
    elif form == "compact":
        rows = encode_closures(closures)
    else:
        raise ValueError(f"form {form!r}: record or compact")
    raw = len(msgpack.packb(rows, use_bin_type=True))
    return raw, len(pack({"c": rows})) - len(pack({"c": []}))


def measure(closures: Sequence[ClosureEdge], batch: int) -> dict[str, float]:
    """Bytes per closure of each form, raw and compressed, over batches of ``batch``."""
    batches = [closures[i : i + batch] for i in range(0, len(closures), batch)]
    batches = [b for b in batches if len(b) == batch] or batches
    n = sum(len(b) for b in batches)
    out: dict[str, float] = {}
    for form in ("record", "compact"):
        sizes = [batch_bytes(b, form) for b in batches]
        out[f"{form}_raw"] = sum(s[0] for s in sizes) / n
        out[f"{form}_zstd"] = sum(s[1] for s in sizes) / n
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.team_closure_bytes", description=__doc__
    )
    ap.add_argument("--map", default="office")
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 8, 32])
    a = ap.parse_args(argv)
    plan = resolve_map(Path(a.map))
    agent = RobotAgent(plan, MissionConfig(duration=a.duration, seed=a.seed))
    agent.run()
    closures = sorted(agent.store.closures, key=lambda c: (c.b, c.a))
    rows = {str(k): measure(closures, k) for k in a.batch}
    print(
        json.dumps({"map": a.map, "closures": len(closures), "per_closure_bytes": rows}, indent=1)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
