"""Strangers on a keyless team's loopback (issue 40's hostile peers): two honest
``team node`` processes, robots 0 and 1 of a 5 s mission on the office plan, without a
key on 127.0.0.1; strangers connect to robot 0 with routing identities of their
choosing and send, every 20 ms all along the mission, one frame of each category a
hostile peer tries (:func:`categories`): bytes that are not msgpack, msgpack of the
wrong type, envelopes with missing fields, wrong types, another robot's or an unknown
robot's id, another destination, a NaN pose inside a numbered answer, headers declaring
4 GiB, a 64 MiB frame, a 200 000-deep nest of arrays, a replayed ``hello`` and
multi-part frames. Robot 0's summary is then compared, field by field (timings left
out), with the same mission undisturbed.

Run with ``python -m benchmarks.team_strangers [--identities 7,0,none] [--seed 3]
[--folder DIR]`` (``--folder``: where the runs' plans and logs go, a new temporary
folder otherwise);
prints the exit codes, the frames sent by category, robot 0's ``rejected_frames`` and
the summary fields that differ. ``none`` is a socket without an identity (zmq gives it
a random one). Every loop is bounded in count (400 rounds) and time (120 s a run).
"""

from __future__ import annotations

import argparse
import json
import math
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zmq

from sonarmap.io.rosmap import write_map
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.launcher import node_args
from sonarmap.team.mission import MissionConfig
from sonarmap.team.node import SUMMARY_FILE, LockstepParams
from sonarmap.team.records import Landmarks, Pose, encode, make_uid
from sonarmap.team.transport import encode_envelope
from sonarmap.team.wire import VERSION, pack

__all__ = ["categories", "main", "run_team"]

#: Rounds of attack frames at most, and wall seconds a run may take at most.
ROUNDS = 400
LIMIT = 120.0
#: The summary's keys that are timings or traffic, which an attack may change.
_TIMING = ("_ms_", "_s", "wall", "second", "rejected", "bytes", "messages")


def _pack(d: object) -> bytes:
    return bytes(msgpack.packb(d, use_bin_type=True))


def _numbered(q: int, kind: str, body: bytes) -> bytes:
    return _pack({"q": q, "t": 0, "k": kind, "b": body})


def categories() -> dict[str, list[bytes]]:
    """One list of zmq frames per category of hostile frame, addressed to robot 0."""
    uid = make_uid(1, 3)
    pose = msgpack.unpackb(
        encode(Pose(uid, 1.0, 0, np.zeros(3), Landmarks.empty())), strict_map_key=False
    )
    nan_pose = dict(pose, estimate=[math.nan, 0.0, math.inf])
    row = {"src": 1, "r": 0, "s": 1.0, "short": [uid], "full": None}
    row |= {"poses": [_pack(nan_pose)], "edges": []}
    nan_answer = pack({"v": VERSION, "id": 1, "mode": "good", "patches": [row]})
    done = _pack({"ch": 0, "out": False, "ack": 0})
    huge = b"\x86\xa1v\x01\xa3src\x01\xa3dst\x00\xa3seq\x00\xa4kind\xa4lock\xa4body"
    return {
        "not msgpack": [b"\x00garbage\xff" * 10],
        "msgpack list": [_pack([1, 2, 3])],
        "missing fields": [_pack({"v": 1, "src": 1, "dst": 0})],
        "wrong types": [_pack({"v": 1, "src": "1", "dst": 0, "seq": 0.5, "kind": 3, "body": "x"})],
        "nan pose answer": [
            encode_envelope(1, 0, 0, "lock", _numbered(10**5 + 7, "answer", nan_answer))
        ],
        "bin32 header of 4 GiB": [huge + b"\xc6\xff\xff\xff\xff"],
        "inner bin32 of 2 GiB": [encode_envelope(1, 0, 0, "lock", b"\xc6\x7f\xff\xff\xff" + b"x")],
        "oversized 64 MiB": [bytes(64 << 20)],
        "forged src=0 (itself)": [encode_envelope(0, 0, 0, "lock", _numbered(0, "done", done))],
        "forged src=1": [encode_envelope(1, 0, 0, "lock", _numbered(0, "bye", b""))],
        "replayed hello": [encode_envelope(1, 0, 0, "hello", _pack({"next": 0, "ack": 0}))] * 3,
        "unknown robot 9": [encode_envelope(9, 0, 0, "lock", _numbered(0, "done", b""))],
        "another destination": [encode_envelope(1, 5, 0, "lock", b"")],
        "nested arrays 200000 deep": [b"\x91" * 200_000 + b"\xc0"],
        "multi-part": [encode_envelope(1, 0, 0, "hello", b"")] * 3,
    }


def _port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _attack(
    address: str, identities: list[bytes | None], alive: subprocess.Popen[bytes]
) -> dict[str, int]:
    """Send every category from each identity in turn until robot 0 exits; counts sent."""
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    socks = []
    for ident in identities:
        s = ctx.socket(zmq.DEALER)
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDTIMEO, 200)
        if ident is not None:
            s.setsockopt(zmq.IDENTITY, ident)
        s.connect(address)
        socks.append(s)
    frames = categories()
    sent: dict[str, int] = {}
    end = time.monotonic() + LIMIT
    for rnd in range(ROUNDS):
        if alive.poll() is not None or time.monotonic() > end:
            break
        s = socks[rnd % len(socks)]
        for name, parts in frames.items():
            if name == "oversized 64 MiB" and rnd % 50:
                continue  # a few suffice; each is 64 MiB of loopback traffic
            try:
                if name == "multi-part":
                    s.send_multipart(parts)
                else:
                    for part in parts:
                        s.send(part)
                sent[name] = sent.get(name, 0) + 1
            except zmq.Again:
                pass
        time.sleep(0.02)
    for s in socks:
        s.close(0)
    ctx.term()
    return sent


def run_team(
    folder: Path, identities: list[bytes | None] | None, seed: int
) -> tuple[list[int | None], dict[str, Any], dict[str, int]]:
    """A 2-robot keyless team on loopback, attacked by ``identities`` (None: not).

    Returns
    -------
    (list, dict, dict)
        Each node's exit code (None: still running after :data:`LIMIT` s, killed),
        robot 0's summary ({} without one), the attack frames sent by category.
    """
    folder.mkdir(parents=True, exist_ok=False)
    write_map(office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth, folder / "plan")
    timing = LockstepParams(wait_timeout=60.0)
    args = node_args(
        MissionConfig(duration=5.0, seed=seed), ExchangeParams(), 30.0, None, 5.0, timing
    )
    addresses = [f"tcp://127.0.0.1:{_port()}" for _ in range(2)]
    procs: list[subprocess.Popen[bytes]] = []
    codes: list[int | None] = []
    try:
        for i in range(2):
            cmd = [sys.executable, "-m", "sonarmap", "team", "node", "--id", str(i)]
            cmd += ["--listen", addresses[i], "--peers", f"{1 - i}={addresses[1 - i]}"]
            cmd += ["--map", str(folder / "plan.yaml"), "-o", str(folder / f"robot{i}"), *args]
            with (folder / f"robot{i}.log").open("wb") as log:
                procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT))
        start = time.monotonic()
        sent = _attack(addresses[0], identities, procs[0]) if identities is not None else {}
        for p in procs:
            try:
                codes.append(p.wait(timeout=max(1.0, 2 * LIMIT - (time.monotonic() - start))))
            except subprocess.TimeoutExpired:
                codes.append(None)
    finally:
        # An attack that raises (or ^C) must not leave the nodes running.
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    summary = folder / "robot0" / SUMMARY_FILE
    return codes, json.loads(summary.read_text()) if summary.exists() else {}, sent


def _flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out |= _flat(v, f"{prefix}{k}.")
        else:
            out[prefix + k] = v
    return out


def main(argv: list[str] | None = None) -> None:
    """Command line: see the module."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--identities", default="7,0,none")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--folder", type=Path, default=None)
    a = parser.parse_args(argv)
    idents = [None if i == "none" else i.encode() for i in a.identities.split(",")]
    base = a.folder or Path(tempfile.mkdtemp(prefix="team-strangers-"))
    calm_codes, calm, _ = run_team(base / "calm", None, a.seed)
    codes, attacked, sent = run_team(base / "attacked", idents, a.seed)
    f0, f1 = _flat(calm), _flat(attacked)
    differ = sorted(
        k for k in f0 if not any(t in k for t in _TIMING) and f0[k] != f1.get(k, "(missing)")
    )
    print(f"exit codes undisturbed {calm_codes}, attacked {codes}")
    print(f"frames sent by category: {sent}")
    print(f"robot 0 rejected_frames: {attacked.get('rejected_frames')}")
    if attacked:
        print(f"summary fields that differ, of {len(f0)} compared: {differ or 'none'}")
    else:
        print("robot 0 wrote no summary (see its log)")
    print(f"logs: {base}")


if __name__ == "__main__":
    main()
