"""Golden digests: what sonarmap computes, fixed before a refactoring and checked after.

A refactoring must leave every result bit for bit as it was. This script runs a fixed set
of cases through the command line (as a user would) and the Python API and records what
they produced:

- every registered mapper's map on three scenes (SHA-256 of the float32 occupancy);
- ``patrol run`` on two built-in maps (every value of ``summary.json`` but the wall-clock
  ones, and a digest of ``metrics.csv``);
- ``team run`` with the simulated and the ZeroMQ transport, each with the default exchange
  (the lean preset) and with ``--lean``, and the simulated one with ``--preset classic``
  (every value of the team's ``summary.json`` but the wall-clock ones,
  and digests of the maps), and one robot alone.

``python -m benchmarks.golden record`` writes ``benchmarks/golden.json``;
``python -m benchmarks.golden check`` runs the cases again and lists every value that
differs. A value recorded and now missing, or changed, fails the check; a key that is new
is listed but does not fail (a summary may gain figures). ``--only PREFIX`` runs the cases
whose name starts with PREFIX. The whole set takes about 10 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

GOLDEN = Path(__file__).with_name("golden.json")

#: Summary keys measured on the wall clock (or naming the output folder): never compared.
WALL_KEYS = frozenset(
    {
        "wall_seconds",
        "association_ms_median",
        "association_ms_p99",
        "global_map_batch_s",
        "pose_interval_s",
        "seconds",
        "map",
    }
)

SCENES = (("doorways", 7), ("corridor", 1000), ("gaps", 1000))
PATROL = {
    "patrol/open-field": ["--map", "{maps}/open-field.yaml", "--robots", "3", "--duration", "300"],
    "patrol/fig3-2-car": [
        "--map",
        "{maps}/fig3-2.yaml",
        "--starts",
        "{maps}/fig3-2.starts.txt",
        "--model",
        "car",
        "--refine",
        "--crowding",
        "obstacles",
        "--duration",
        "300",
        "--seed",
        "2",
    ],
}
TEAM_BASE = ["--map", "office", "--robots", "3", "--duration", "90", "--seed", "0"]
TEAM = {
    "team/alone": ["--map", "office", "--robots", "1", "--duration", "120", "--seed", "1"],
    "team/sim": TEAM_BASE,
    "team/sim-lean": [*TEAM_BASE, "--lean"],
    "team/sim-classic": [*TEAM_BASE, "--preset", "classic"],
    "team/zmq": [*TEAM_BASE, "--transport", "zmq"],
    "team/zmq-lean": [*TEAM_BASE, "--transport", "zmq", "--lean"],
    "team/limited": [
        "--map",
        "building:3",
        "--robots",
        "3",
        "--duration",
        "90",
        "--seed",
        "2",
        "--network",
        "limited",
        "--loss",
        "0.1",
    ],
}


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:24]


def array_digest(a: np.ndarray[Any, Any]) -> str:
    """The digest of an array's dtype, shape and bytes (NaN bit patterns normalised)."""
    a = np.ascontiguousarray(a)
    if a.dtype.kind == "f":
        a = np.where(np.isnan(a), np.nan, a).astype(a.dtype)
    return sha(f"{a.dtype.str}{a.shape}".encode() + a.tobytes())


def flatten(value: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``path -> leaf`` pairs of a JSON value; wall-clock keys left out."""
    if isinstance(value, dict):
        for k in sorted(value):
            if k in WALL_KEYS:
                continue
            yield from flatten(value[k], f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from flatten(v, f"{prefix}[{i}]")
    else:
        yield prefix, value


def _sonarmap(*args: str) -> None:
    cmd = [sys.executable, "-m", "sonarmap", *args]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"failed ({done.returncode}): {' '.join(cmd)}\n{done.stderr[-3000:]}")


def mapper_cases() -> dict[str, Callable[[Path], dict[str, Any]]]:
    from sonarmap.mappers import MAPPERS, make_mapper
    from sonarmap.scenarios import make_scenario

    def case(scene: str, seed: int, method: str) -> Callable[[Path], dict[str, Any]]:
        def run(_: Path) -> dict[str, Any]:
            sc = make_scenario(scene, seed=seed)
            m = make_mapper(method)
            m.fit(sc.readings, sc.truth.grid, sc.rig)
            return {"occupancy": array_digest(m.result().occupancy)}

        return run

    return {
        f"map/{scene}/{method}": case(scene, seed, method)
        for scene, seed in SCENES
        for method in sorted(MAPPERS)
    }


def patrol_case(args: list[str]) -> Callable[[Path], dict[str, Any]]:
    def run(tmp: Path) -> dict[str, Any]:
        maps = tmp / "maps"
        if not maps.exists():
            _sonarmap("patrol", "maps", "-o", str(maps))
        out = tmp / "out"
        _sonarmap("patrol", "run", *[a.format(maps=maps) for a in args], "-o", str(out))
        got = dict(flatten(json.loads((out / "summary.json").read_text())))
        got["metrics.csv"] = sha((out / "metrics.csv").read_bytes())
        return got

    return run


def team_case(args: list[str]) -> Callable[[Path], dict[str, Any]]:
    def run(tmp: Path) -> dict[str, Any]:
        out = tmp / "out"
        _sonarmap("team", "run", *args, "-o", str(out))
        got = dict(flatten(json.loads((out / "summary.json").read_text())))
        for npy in sorted(out.rglob("*.npy")):
            rel = npy.relative_to(out).as_posix()
            if "routes/" in rel or rel.endswith("plan.npy"):
                continue
            got[rel] = array_digest(np.load(npy))
        return got

    return run


def all_cases() -> dict[str, Callable[[Path], dict[str, Any]]]:
    cases: dict[str, Callable[[Path], dict[str, Any]]] = dict(mapper_cases())
    cases.update({name: patrol_case(a) for name, a in PATROL.items()})
    cases.update({name: team_case(a) for name, a in TEAM.items()})
    return cases


def compare(name: str, want: dict[str, Any], got: dict[str, Any]) -> tuple[list[str], list[str]]:
    """The differences that fail (changed or missing values) and the keys that are new."""
    bad = []
    for k, v in want.items():
        if k not in got:
            bad.append(f"{name}: {k} missing (was {v!r})")
        elif not _same(v, got[k]):
            bad.append(f"{name}: {k} = {got[k]!r}, was {v!r}")
    new = [f"{name}: {k} = {got[k]!r} (new)" for k in got if k not in want]
    return bad, new


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b and type(a) is type(b))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.golden", description=__doc__)
    ap.add_argument("action", choices=["record", "check"])
    ap.add_argument("--only", default="", help="Run the cases whose name starts with this.")
    ap.add_argument("--file", type=Path, default=GOLDEN, help="The golden file.")
    a = ap.parse_args(argv)
    cases = {k: v for k, v in all_cases().items() if k.startswith(a.only)}
    if not cases:
        raise SystemExit(f"--only: no case starts with {a.only!r}")
    recorded: dict[str, dict[str, Any]] = json.loads(a.file.read_text()) if a.file.exists() else {}
    failures: list[str] = []
    for i, (name, run) in enumerate(cases.items(), 1):
        with tempfile.TemporaryDirectory(prefix="sonarmap-golden-") as tmp:
            got = json.loads(json.dumps(run(Path(tmp))))
        if a.action == "record":
            recorded[name] = got
            print(f"[{i}/{len(cases)}] {name}: {len(got)} values recorded", flush=True)
            continue
        if name not in recorded:
            failures.append(f"{name}: not recorded")
            continue
        bad, new = compare(name, recorded[name], got)
        failures += bad
        verdict = "same" if not bad else f"{len(bad)} differ"
        print(f"[{i}/{len(cases)}] {name}: {verdict}", flush=True)
        for line in bad[:20] + new[:20]:
            print("   ", line, flush=True)
    if a.action == "record":
        a.file.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
        print(f"wrote {a.file}")
        return 0
    print(f"{len(failures)} differences" if failures else "every golden value is the same")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
