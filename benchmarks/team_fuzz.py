"""A key-holding insider fuzzing a live node (issue 38, item 7): crashes, hangs, memory.

Robot 0 runs as a ``team node`` process on 127.0.0.1 with the team's key; this module
plays robot 1 with robot 1's key, so every frame it sends passes the CURVE handshake
and reaches the decoders. It sends ``--frames`` frames drawn from a seeded generator
(:func:`fuzz_frames`): valid frames with bits flipped, cut short or extended, msgpack
maps re-encoded with fields swapped or retyped, bad versions, headers declaring huge
sizes, a compression bomb, multi-part and spoofed envelopes, forged ``hello`` claims,
and exchanger bodies mutated alike inside well-formed numbered frames (these reach the
exchanger's decoder; half the answers carry a closure,
:mod:`sonarmap.team.peerclosures`). Then it ends the mission honestly: a ``done`` marker for every
tick and a ``bye``, sending again what the node asks for. The node must exit 0 within
the time limit, having counted the rejections in its summary, with bounded peak RSS.

Run with ``python -m benchmarks.team_fuzz [--frames 50000] [--seed 0] [--timeout 300]
[--folder DIR]`` (``--timeout``: seconds the node waits for its peer, and the bound on
each phase of a run; ``--folder``: keep the runs' plans, keys and logs there, a
temporary folder otherwise); prints a
markdown table row: frames sent, rejected (the node's ``rejected_frames``), crashes,
hangs, peak RSS and its growth. Every socket is on 127.0.0.1; every loop is bounded in
count and in time.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgpack
import numpy as np
import zmq
import zstandard

from sonarmap.io.rosmap import write_map
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.keys import TeamKey, make_team_key, read_team_key
from sonarmap.team.launcher import KEY_FILE, node_args
from sonarmap.team.mission import MissionConfig
from sonarmap.team.node import SUMMARY_FILE, LockstepParams
from sonarmap.team.peerclosures import encode_closures
from sonarmap.team.records import ClosureEdge, Landmarks, Pose, encode, make_uid
from sonarmap.team.transport import ZmqTransport, encode_envelope
from sonarmap.team.wire import KINDS, PRESET_DICTIONARY, VERSION, pack

__all__ = ["FuzzResult", "fuzz_frames", "fuzz_node", "main"]

#: Ticks the honest end marks done: more than the short mission below has.
_TICKS = 400


def _pack(d: object) -> bytes:
    return bytes(msgpack.packb(d, use_bin_type=True))


def _answer(rng: np.random.Generator) -> bytes:
    """A plausible exchanger answer's msgpack map (not yet compressed)."""
    uid = make_uid(1, int(rng.integers(0, 1000)))
    pose = encode(Pose(uid, float(rng.random()), 0, np.zeros(3), Landmarks.empty()))
    row = {"src": 1, "r": 0, "s": 1.0, "short": [uid], "full": None}
    row |= {"poses": [pose], "edges": []}
    if rng.random() < 0.5:
        # A closure from the pose sent to one of the node's own, so that mutations
        # reach the closures' decoder too.
        tf = tuple(float(v) for v in rng.normal(0.0, 1.0, 3))
        other = make_uid(0, int(rng.integers(0, 1000)))
        cov = (1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-5)
        row["c"] = encode_closures([ClosureEdge(uid, other, (tf[0], tf[1], tf[2]), cov, 9, 0.1)])
    return _pack({"v": VERSION, "id": int(rng.integers(0, 9)), "mode": "good", "patches": [row]})


def _retype(v: object, rng: np.random.Generator) -> object:
    choices: list[object] = [None, True, -1, 2**63, 1.5, "x" * 70, b"\x00" * 9, [v, v], {"k": v}]
    return choices[int(rng.integers(0, len(choices)))]


def _confuse(raw: bytes, rng: np.random.Generator) -> bytes:
    """A msgpack map re-encoded with two fields' values swapped, one retyped, a key
    dropped or added: type confusion the bytes' structure does not reveal."""
    d = msgpack.unpackb(raw, strict_map_key=False)
    if not isinstance(d, dict) or not d:
        return raw
    rows = [k for k, v in d.items() if isinstance(v, list) and v and isinstance(v[0], dict)]
    if rows and rng.random() < 0.5:
        # A field of a nested map (an answer's patch row) confused instead.
        d[rows[0]][0] = msgpack.unpackb(_confuse(_pack(d[rows[0]][0]), rng), strict_map_key=False)
        return _pack(d)
    keys = list(d)
    a, b = (keys[int(rng.integers(0, len(keys)))] for _ in range(2))
    how = int(rng.integers(0, 4))
    if how == 0:
        d[a], d[b] = d[b], d[a]
    elif how == 1:
        d[a] = _retype(d[a], rng)
    elif how == 2:
        del d[a]
    else:
        d["extra" if rng.random() < 0.5 else 7] = _retype(d[a], rng)
    return _pack(d)


def _mutate(raw: bytes, rng: np.random.Generator) -> bytes:
    """Bit flips, a cut, an extension or type confusion of ``raw``."""
    how = int(rng.integers(0, 4))
    bad = bytearray(raw)
    if how == 0:
        for _ in range(int(rng.integers(1, 4))):
            at = int(rng.integers(0, len(bad)))
            bad[at] ^= 1 << int(rng.integers(0, 8))
        return bytes(bad)
    if how == 1:
        return bytes(bad[: int(rng.integers(0, len(bad)))])
    if how == 2:
        return bytes(bad) + rng.bytes(int(rng.integers(1, 64)))
    return _confuse(raw, rng)


#: msgpack headers declaring far more than follows (str32, bin32, array32, map32, ext32).
_HUGE = [b"\xdb\xff\xff\xff\xff", b"\xc6\xff\xff\xff\xff", b"\xdd\xff\xff\xff\xff"]
_HUGE += [b"\xdf\xff\xff\xff\xff", b"\xc9\xff\xff\xff\xff\x01"]


def _bomb() -> bytes:
    """A compressed exchanger body of 64 MiB of zeros (a few kB on the wire)."""
    return pack({"v": VERSION, "id": 0, "mode": "good", "pad": bytes(64 << 20)})


def _exchange_body(rng: np.random.Generator, bomb: bytes) -> bytes:
    """A mutated, compressed exchanger body (or a bad version, a huge size, the bomb)."""
    how = int(rng.integers(0, 5))
    if how == 0:
        return bomb
    if how == 1:
        d = msgpack.unpackb(_answer(rng))
        d["v"] = int(rng.integers(-3, 2**31)) if rng.random() < 0.8 else "6"
        return pack(d)
    if how == 2:
        return rng.bytes(int(rng.integers(0, 200)))
    raw = _answer(rng)
    raw = _HUGE[int(rng.integers(0, len(_HUGE)))] + raw[:32] if how == 3 else _mutate(raw, rng)
    # Compressed as sent, so that the mutation reaches the msgpack decoder.
    return _ZSTD.compress(raw)


_ZSTD = zstandard.ZstdCompressor(
    level=1,
    dict_data=zstandard.ZstdCompressionDict(
        PRESET_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT
    ),
)

#: Envelope kinds of the fuzzed frames: the two a node takes, and others.
_ENVELOPE_KINDS = ("lock", "hello", "lock", "hello", "data", "x" * 16)


def fuzz_frames(n: int, seed: int) -> Iterator[tuple[str, list[bytes]]]:
    """``n`` attack frames from robot 1 to robot 0, from ``seed``.

    Yields
    ------
    (str, list of bytes)
        ``("raw", parts)``: the zmq message parts to send as they are (an envelope,
        mutated or not, or several parts); or ``(kind, [body])``: an exchanger body of
        that kind (mutated) the sender wraps in its next in-sequence numbered frame.
    """
    rng = np.random.default_rng(seed)
    bomb = _bomb()
    # Fuzzed numbered frames lie past every number the sender's own frames can take
    # (at most n, then the honest end's): kept aside or refused as too far ahead, they
    # never take an honest frame's place. (When they could, a "done" for a later tick
    # taking one's place crashed the node: test_team_security's skipped-ticks test.)
    ahead = n + _TICKS + 1
    lock_kinds = [*KINDS, "done", "bye", "hello", ""]
    for i in range(n):
        how = int(rng.integers(0, 8))
        if how == 0:
            yield KINDS[int(rng.integers(0, len(KINDS)))], [_exchange_body(rng, bomb)]
            continue
        seq = int(rng.integers(0, 2**20))
        if how == 1:
            done = _pack({"ch": 0, "out": False, "ack": 0})
            kind = lock_kinds[int(rng.integers(0, len(lock_kinds)))]
            body = done if kind == "done" else _exchange_body(rng, bomb)
            frame = _pack({"q": ahead + i, "t": int(rng.integers(0, 50)), "k": kind, "b": body})
            env = encode_envelope(1, 0, seq, "lock", _mutate(frame, rng))
        elif how == 2:
            hello = _pack({"next": int(rng.integers(0, 100)), "ack": 0})
            env = encode_envelope(1, 0, seq, "hello", _mutate(hello, rng))
        elif how == 3:
            # Claims of frames never sent: huge, negative, or past the end.
            claim = [2**62 - 1, 2**64 - 1, -1, 10**6][int(rng.integers(0, 4))]
            env = encode_envelope(1, 0, seq, "hello", _pack({"next": claim, "ack": claim}))
        elif how == 4:
            kind = _ENVELOPE_KINDS[int(rng.integers(0, len(_ENVELOPE_KINDS)))]
            env = _mutate(encode_envelope(1, 0, seq, kind, rng.bytes(40)), rng)
        elif how == 5:
            d = {"v": 1, "src": 1, "dst": 0, "seq": seq, "kind": "lock", "body": b""}
            field = ["src", "dst", "v", "kind", "seq"][int(rng.integers(0, 5))]
            d[field] = [0, 2, 9, -1, 2**40, "1", None][int(rng.integers(0, 7))]
            env = _pack(d)
        elif how == 6:
            parts = [encode_envelope(1, 0, seq, "lock", b"")] * int(rng.integers(2, 4))
            yield "raw", parts if rng.random() < 0.8 else [b""]
            continue
        else:
            head = _HUGE[int(rng.integers(0, len(_HUGE)))]
            env = head + rng.bytes(int(rng.integers(0, 100))) if rng.random() < 0.5 else head
        yield "raw", [env]


def _rss(pid: int) -> tuple[float, float]:
    """The process's resident and peak resident set, MB (0 once it is gone)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0.0, 0.0
    kb = {
        k: float(v.split()[0])
        for k, v in (s.split(":", 1) for s in text.splitlines())
        if k in ("VmRSS", "VmHWM")
    }
    return kb.get("VmRSS", 0.0) / 1024, kb.get("VmHWM", 0.0) / 1024


@dataclass(frozen=True)
class FuzzResult:
    """What :func:`fuzz_node` saw.

    Attributes
    ----------
    sent : int
        Attack frames sent (the generator's count; a send refused after waiting
        counts in ``refused``).
    refused : int
        Attack frames the insider's socket could not hand on within its timeout.
    inner : int
        Attack frames that were exchanger bodies in well-formed numbered frames (the
        exchanger rejects them; the node's ``rejected_frames`` counts the others).
    rejected : int
        The node's ``rejected_frames`` (its summary; -1 without one).
    exit_code : int or None
        The node's exit code (None: still running at the time limit, then killed).
    hung : bool
        The node did not exit within the time limit.
    asked : int
        ``hello`` requests the node sent the insider: it kept answering under attack.
    rss_start_mb, rss_attacked_mb, rss_peak_mb : float
        The node's resident set once it was up, right after the attack's last frame (the
        node still waiting for robot 1, holding what the attack left it), and its peak
        over the run (VmHWM).
    seconds : float
        Wall time from the first attack frame to the node's exit.
    last_line : str
        The last line the node wrote (its error, if it failed).
    """

    sent: int
    refused: int
    inner: int
    rejected: int
    exit_code: int | None
    hung: bool
    asked: int
    rss_start_mb: float
    rss_attacked_mb: float
    rss_peak_mb: float
    seconds: float
    last_line: str

    @property
    def crashed(self) -> bool:
        """The node exited other than 0 and not with its one-line error naming robot 1
        (exit code 2): a traceback, a signal (not a hang)."""
        clean = self.exit_code == 2 and "robot 1" in self.last_line
        return self.exit_code not in (0, None) and not clean


def _dealer(ctx: zmq.Context[zmq.Socket[bytes]], address: str, key: TeamKey) -> zmq.Socket[bytes]:
    """Robot 1's own connection to robot 0: its key, its identity."""
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDTIMEO, 2000)
    sock.setsockopt(zmq.SNDHWM, 100_000)
    sock.setsockopt(zmq.IDENTITY, b"1")
    sock.setsockopt(zmq.CURVE_SERVERKEY, key.public[0])
    sock.setsockopt(zmq.CURVE_PUBLICKEY, key.public[1])
    sock.setsockopt(zmq.CURVE_SECRETKEY, key.secret[1])
    sock.connect(address)
    return sock


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def fuzz_node(frames: int, seed: int, folder: Path, *, timeout: float = 120.0) -> FuzzResult:
    """Start robot 0 as a keyed node on 127.0.0.1, attack it with ``frames`` frames of
    :func:`fuzz_frames` as robot 1 (holding robot 1's key), then end the mission
    honestly and wait for the node's exit.

    Parameters
    ----------
    frames : int
    seed : int
    folder : Path
        Where the plan, the key, the node's output and its log go.
    timeout : float
        Seconds for the node to start, and again for the attack and its end; past
        them the node is a hang (killed).

    Returns
    -------
    FuzzResult
    """
    folder.mkdir(parents=True, exist_ok=True)
    plan = office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth
    write_map(plan, folder / "plan")
    make_team_key(2).write(folder / KEY_FILE)
    key = read_team_key(folder / KEY_FILE)
    cfg = MissionConfig(duration=5.0, seed=seed)
    timing = LockstepParams(wait_timeout=timeout)
    args = node_args(cfg, ExchangeParams(), 30.0, None, 5.0, timing)
    addresses = [f"tcp://127.0.0.1:{_free_port()}" for _ in range(2)]
    cmd = [sys.executable, "-m", "sonarmap", "team", "node", "--id", "0"]
    cmd += ["--listen", addresses[0], "--peers", f"1={addresses[1]}"]
    cmd += ["--map", str(folder / "plan.yaml"), "-o", str(folder / "robot0")]
    cmd += ["--key", str(folder / KEY_FILE), *args]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(Path(__file__).resolve().parents[1] / "src"), env.get("PYTHONPATH")) if p
    )
    honest: list[bytes] = []

    def numbered(tick: int, kind: str, body: bytes) -> None:
        frame = _pack({"q": len(honest), "t": tick, "k": kind, "b": body})
        honest.append(encode_envelope(1, 0, 0, "lock", frame))

    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    log = open(folder / "robot0.log", "wb")  # noqa: SIM115
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
    sent = refused = asked = inner = 0
    rss_start = rss_attacked = 0.0
    peak = 0.0
    try:
        with ZmqTransport(1, addresses[1], key=key) as me:
            # Up: the node asks robot 1 for its frames while it waits for tick 0's end.
            end = time.monotonic() + timeout
            while not asked and proc.poll() is None and time.monotonic() < end:
                asked += sum(m.kind == "hello" for m in me.poll(0.2))
            rss_start, peak = _rss(proc.pid)
            sock = _dealer(ctx, addresses[0], key)
            t0 = time.monotonic()
            end = t0 + timeout
            for kind, parts in fuzz_frames(frames, seed):
                if time.monotonic() > end or proc.poll() is not None:
                    break
                if kind != "raw":
                    inner += 1
                    numbered(0, kind, parts[0])
                    parts = [honest[-1]]
                try:
                    sock.send_multipart(parts)
                    sent += 1
                except zmq.Again:
                    refused += 1
                if sent % 200 == 0:
                    asked += sum(m.kind == "hello" for m in me.poll(0.0))
                    peak = max(peak, _rss(proc.pid)[1])
            # Left a moment to take in what is queued before it is measured.
            settle_end = time.monotonic() + 1.0
            while time.monotonic() < settle_end and proc.poll() is None:
                asked += sum(m.kind == "hello" for m in me.poll(0.1))
            rss_attacked = _rss(proc.pid)[0]
            for tick in range(_TICKS):
                numbered(tick, "done", _pack({"ch": 0, "out": False, "ack": 0}))
            numbered(_TICKS, "bye", b"")
            start = len(honest) - _TICKS - 1
            _resend(sock, honest, start)
            last = 0.0
            while proc.poll() is None and time.monotonic() < end:
                for m in me.poll(0.1):
                    if m.src == 0 and m.kind == "hello":
                        asked += 1
                        nxt = msgpack.unpackb(m.payload)["next"]
                        if time.monotonic() - last > 0.5:
                            # The node lacks frames from here on: sent again, as a
                            # robot's link does.
                            _resend(sock, honest, int(nxt))
                            last = time.monotonic()
                peak = max(peak, _rss(proc.pid)[1])
            seconds = time.monotonic() - t0
            sock.close(0)
    finally:
        hung = proc.poll() is None
        if hung:
            proc.kill()
        proc.wait()
        log.close()
        ctx.term()
    summary = folder / "robot0" / SUMMARY_FILE
    rejected = int(json.loads(summary.read_text())["rejected_frames"]) if summary.exists() else -1
    lines = [s for s in (folder / "robot0.log").read_text(errors="replace").splitlines() if s]
    return FuzzResult(
        sent=sent,
        refused=refused,
        inner=inner,
        rejected=rejected,
        exit_code=None if hung else proc.returncode,
        hung=hung,
        asked=asked,
        rss_start_mb=rss_start,
        rss_attacked_mb=rss_attacked,
        rss_peak_mb=peak,
        seconds=seconds,
        last_line=lines[-1] if lines else "",
    )


def _resend(sock: zmq.Socket[bytes], honest: list[bytes], start: int) -> None:
    for env in honest[max(0, start) :]:
        try:
            sock.send(env)
        except zmq.Again:
            return  # asked for again later


def main(argv: list[str] | None = None) -> None:
    """Command line: see the module."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=50_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=300.0)
    parser.add_argument("--folder", type=Path, default=None)
    a = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="sonarmap-fuzz-") as scratch:
        where = a.folder or Path(scratch)
        # The same node undisturbed: its own mission's memory, which the attack's is
        # measured over.
        ref = fuzz_node(0, a.seed, where / "undisturbed", timeout=a.timeout)
        r = fuzz_node(a.frames, a.seed, where / "fuzzed", timeout=a.timeout)
    print(
        "| frames sent | to the exchanger | rejected by the link | exit | crashes | hangs | "
        "RSS before / after the attack MB | peak RSS MB | undisturbed peak MB | s |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    print(
        f"| {r.sent} | {r.inner} | {r.rejected} | {r.exit_code} | {int(r.crashed)} | "
        f"{int(r.hung)} | "
        f"{r.rss_start_mb:.0f} / {r.rss_attacked_mb:.0f} | {r.rss_peak_mb:.0f} | "
        f"{ref.rss_peak_mb:.0f} | {r.seconds:.1f} |"
    )
    if r.exit_code != 0:
        print(f"node: {r.last_line}", file=sys.stderr)
        raise SystemExit(1)


if __name__ == "__main__":
    main()
