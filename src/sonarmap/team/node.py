"""A team over a real network (issue 15): every robot its own OS process, exchanging
over ZeroMQ on TCP (:class:`~.transport.ZmqTransport`). :func:`run_node` runs one
robot; :func:`~.launcher.run_zmq_team` starts a local team of such processes
(``python -m sonarmap team node``) and gathers their summaries. The clock is
:class:`~.lockstep.LockstepClock`, the one :func:`~.simulation.run_team` drives; the
frames between nodes are :mod:`.link`'s.

**The clock: lock-step.** A robot's own store does depend on the exchange (its new
poses are associated with the poses it received; closures change landmark stamps, and
so compression, and the graph batches move its estimates), so a node cannot drive its
route alone and exchange afterwards without changing its results. Instead the nodes
advance mission time together, tick by tick, exactly as :func:`~.simulation.run_team`
does on its simulated full network (no loss, no delay, no bandwidth cap):

- The ticks are the union of every robot's route time stamps, then the quiet phase's
  ticks of the median step. Every node needs every route: the launcher draws them once
  (or takes the given ones, e.g. the patroller's) and hands them over as ``.npy`` files
  (:func:`save_routes`, exact float64); a node given none draws them from the seed.
- At tick ``n`` robot ``i`` processes its route up to the tick, then hands its
  exchanger the messages the simulation would have delivered by then: those robots
  ``j < i`` sent at tick ``n`` and robots ``j > i`` sent at tick ``n - 1``, in the
  simulation's order (tick, sender, send order). Then it steps its exchanger and sends
  what the exchanger sent, followed by a ``done`` marker for the tick, which carries
  the robot's count of poses added and deleted by the exchange and whether it awaits
  an answer.
- A node waits (on the wall clock) until those markers arrived. With every node's
  markers of a tick in hand, each evaluates the simulation's quiet-network rule on the
  team's sums and all stop at the same tick.

So "same results" here means: on the same seeded mission (plan, :class:`MissionConfig`,
robots, :class:`ExchangeParams`), each node ends with the same own store, byte for byte
(:func:`store_digest`), the same received layers, the same held pose UIDs (so
``duplicate_poses`` and ``identical_maps`` agree), the same exchange counters and the
same scores as robot ``i`` of ``run_team`` with ``NetworkParams(kind="full")``, except
for the wall-clock keys and the scores of closures to another robot's merged poses
(the node knows a merged pose's origin only from the poses it received; the simulation
looks it up in the other robots' memory). The exchanger's ``request_timeout`` and
``peer_timeout`` count mission time, which stops while a peer is away, so they never
fire on the zmq transport: a peer that vanishes stops the team's clock until it
returns (up to ``wait_timeout`` wall seconds, then each waiting node fails with one
line naming the silent peer).

**Kill and restart.** A node writes its whole state every ``checkpoint_every`` wall
seconds to ``state_dir/state.msgpack`` (msgpack of the records' own encodings, never
pickle; with its SHA-256 and format version, written to a temporary file, fsynced and
renamed: :mod:`.checkpoint`, which also locks the folder against a second process): the
store (all layers, patches, closures and the store's counters), the agent's route
position and scoring counters, the exchanger's stamps, adverts and pending requests, and
the frame logs. Restarted on the same ``state_dir`` it resumes at the tick after its
checkpoint and asks its peers to send again what it has not yet taken; the ticks it
repeats make the same frames with the same numbers (everything is deterministic), which
the peers drop. The team ends as it would have without the kill.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import time
from collections import ChainMap
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt

from ..errors import ConfigError, InputError
from ..files import atomic_folder, atomic_outputs, atomic_write_text, json_dumps
from ..io.rosmap import OccupancyMap, write_map
from .checkpoint import StateLock, read_state, write_state
from .exchange import ExchangeParams, Exchanger
from .inputs import mission_routes
from .keys import TeamKey
from .link import DEFAULT_MAX_QUEUE, LOCK_SLACK, ExchangerPort, ReliableLink
from .lockstep import LockstepClock, quiet_seconds, team_ticks
from .mission import MissionConfig, RobotAgent
from .naive import NaiveMeter
from .records import (
    ClosureEdge,
    Pose,
    RecordError,
    decode_as,
    encode,
    make_uid,
)
from .regions import region_adjacency
from .simulation import held_uids
from .store import RobotStore
from .summary import robot_row
from .transport import DEFAULT_MAX_MESSAGE, Message, ZmqTransport
from .wire import MODES
from .world import ODOMETRY_NOISE, ROUTE_SEED_STEP, make_world, odometry, patrol_route

__all__ = [
    "MIB",
    "STATE_FILE",
    "SUMMARY_FILE",
    "LockstepParams",
    "load_routes",
    "parse_exchange",
    "parse_peers",
    "route_truth",
    "run_node",
    "save_routes",
    "state_fingerprint",
    "store_digest",
]

logger = logging.getLogger("sonarmap.team.node")

F64 = npt.NDArray[np.float64]
Progress = Callable[[int, int], None]

#: Bytes of a MiB (``--max-queue`` counts them).
MIB = 1 << 20
#: The checkpoint's file name in a node's state folder.
STATE_FILE = "state.msgpack"
#: The node's summary in its output folder.
SUMMARY_FILE = "summary.json"
_STATE_VERSION = 1


@dataclass(frozen=True)
class LockstepParams:
    """Wall-clock settings of a node (none changes its results).

    Attributes
    ----------
    wait_timeout : float
        Seconds a node waits for a silent peer before failing: 300.
    retry : float
        Seconds between requests to send again while waiting: 0.5.
    checkpoint_every : float
        Seconds between checkpoints (with a state folder): 5.
    linger : float
        Seconds a finished node stays to serve its peers' last requests: 120.
    max_queue : float
        Bytes of frames kept per peer, sent and not acknowledged, and received ahead of
        the one awaited (each bound on its own; :class:`~.link.ReliableLink`): 64 MiB.
    """

    wait_timeout: float = 300.0
    retry: float = 0.5
    checkpoint_every: float = 5.0
    linger: float = 120.0
    max_queue: float = float(DEFAULT_MAX_QUEUE)

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise ConfigError(f"node: {f.name} must be a number > 0, got {v!r}")
            if not math.isfinite(v):
                raise ConfigError(f"node: {f.name} must be finite, got {v!r}")


def parse_peers(text: str, robot: int) -> dict[int, str]:
    """``--peers``: comma-separated ``ID=ADDRESS`` items, or bare addresses given to the
    robots 0, 1, ... other than ``robot``, in order."""
    items = [s.strip() for s in text.split(",") if s.strip()]
    out: dict[int, str] = {}
    bare = [s for s in items if "=" not in s]
    if bare and len(bare) != len(items):
        raise ConfigError("--peers: give every peer as ID=ADDRESS, or none")
    if bare:
        ids = [j for j in range(len(items) + 1) if j != robot]
        return dict(zip(ids, items, strict=False))
    for s in items:
        key, _, address = s.partition("=")
        if not key.strip().isdigit():
            raise ConfigError(f"--peers: {key.strip()!r} in {s!r} is not a robot id")
        j = int(key)
        if j in out:
            raise ConfigError(f"--peers: robot {j} is given twice")
        out[j] = address.strip()
    return out


def _parse_bool(text: str) -> bool:
    """``true``/``false`` (any case) or ``1``/``0``; ValueError otherwise."""
    low = text.lower()
    if low in ("true", "1"):
        return True
    if low in ("false", "0"):
        return False
    raise ValueError(text)


def parse_exchange(items: Sequence[str]) -> ExchangeParams:
    """``--exchange KEY=VALUE`` items as :class:`ExchangeParams` (the others default)."""
    kinds = {f.name: type(getattr(ExchangeParams(), f.name)) for f in fields(ExchangeParams)}
    values: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or key not in kinds:
            raise ConfigError(
                f"--exchange expects KEY=VALUE with KEY one of {', '.join(kinds)}, got {item!r}"
            )
        try:
            values[key] = _parse_bool(value) if kinds[key] is bool else kinds[key](value)
        except ValueError:
            raise ConfigError(
                f"--exchange {key}: {kinds[key].__name__} expected, got {value!r}"
            ) from None
    ex = ExchangeParams(**values)
    if ex.mode not in MODES:
        raise ConfigError(
            f"--exchange mode: the zmq transport runs {' and '.join(MODES)}, not {ex.mode!r}"
        )
    return ex


def save_routes(folder: Path, routes: Sequence[F64]) -> None:
    """Write each robot's route (T, 4) to ``folder/robotK.npy`` (exact float64: the
    nodes must drive the very routes the launcher drew)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, r in enumerate(routes):
        with atomic_outputs(folder / f"robot{i}.npy") as (tmp,), open(tmp, "wb") as f:
            np.save(f, np.asarray(r, dtype=np.float64), allow_pickle=False)


def load_routes(folder: Path, robots: int) -> list[F64]:
    """The routes :func:`save_routes` wrote for robots 0..robots-1."""
    out: list[F64] = []
    for i in range(robots):
        path = Path(folder) / f"robot{i}.npy"
        try:
            r = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read robot {i}'s route: {e}", path=path) from None
        ok = r.ndim == 2 and r.shape[1] == 4 and len(r) > 0 and r.dtype == np.float64
        if not ok or not np.isfinite(r).all() or (np.diff(r[:, 0]) <= 0).any():
            raise InputError("a route is rows of finite t, x, y, theta, t increasing", path=path)
        out.append(r)
    return out


def _check_team(robot: int, peers: Mapping[int, str]) -> list[int]:
    ids = sorted({robot, *peers})
    if robot in peers:
        raise ConfigError(f"--peers: robot {robot} is this node itself")
    if ids != list(range(len(ids))):
        raise ConfigError(
            f"robot ids must be 0..N-1 (they seed the routes, as in 'team run'), got {ids}"
        )
    return ids


def _pack(d: Any) -> bytes:
    return bytes(msgpack.packb(d, use_bin_type=True))


def store_digest(store: RobotStore) -> str:
    """SHA-256 of a store's local layer (poses and odometry edges, their encodings in
    UID order) and its closures: equal digests, equal own stores byte for byte."""
    h = hashlib.sha256()
    for uid in sorted(store.local.poses):
        h.update(encode(store.local.poses[uid]))
    for e in sorted(store.local.edges, key=lambda x: (x.a, x.b)):
        h.update(encode(e))
    for c in sorted(encode(c) for c in store.closures):
        h.update(c)
    return h.hexdigest()


def state_fingerprint(
    plan: OccupancyMap,
    cfg: MissionConfig,
    robot: int,
    ids: Sequence[int],
    ex: ExchangeParams,
    routes: Sequence[F64],
    prior: OccupancyMap | None = None,
    region: npt.NDArray[np.bool_] | None = None,
) -> str:
    """The fingerprint a node's state file is tied to: what it must belong to.

    A state resumes only under the same plan, prior, mission, team, routes, exchange
    and territory mask (the landmarks are drawn and the regions cut inside the mask).

    Parameters
    ----------
    plan : OccupancyMap
        The floor plan (its cells and frame: origin, resolution, shape).
    cfg : MissionConfig
        The mission's settings.
    robot : int
        The node's robot number.
    ids : sequence of int
        The team's robot numbers.
    ex : ExchangeParams
        The exchange's settings.
    routes : sequence of ndarray
        The team's routes, one ``(n, 4)`` array of ``t, x, y, theta`` per robot.
    prior : OccupancyMap, optional
        The robots' prior map, when it is not the plan (default None).
    region : ndarray of bool, optional
        The territory mask on the plan's cells (default None: no mask). Without a
        mask neither the mask nor the marker of regions cut inside it is hashed.

    Returns
    -------
    str
        The SHA-256 hex digest.
    """
    h = hashlib.sha256()
    for m in (plan,) if prior is None else (plan, prior):
        # The frame too: the same cells at another origin or resolution are another map.
        g = m.grid
        h.update(json.dumps([g.resolution, list(g.origin), list(g.shape)]).encode())
        h.update(np.ascontiguousarray(m.classes()).tobytes())
    for r in routes:
        h.update(np.ascontiguousarray(r, dtype=np.float64).tobytes())
    h.update(json.dumps([asdict(cfg), robot, list(ids), asdict(ex)], default=str).encode())
    if region is not None:
        # Only with a mask: the state files of missions without one keep their prints.
        h.update(b"territory")
        h.update(np.packbits(region).tobytes())
        # The regions are cut inside the mask: a state saved while they were cut from the
        # whole prior numbers its poses' regions otherwise, and must not resume.
        h.update(b"regions inside")
    return h.hexdigest()


# --- one node ------------------------------------------------------------------------------


def route_truth(
    plan: OccupancyMap, cfg: MissionConfig, robot: int, route: F64 | None
) -> tuple[F64, dict[int, F64]]:
    """Another robot's route and the true pose of every pose it makes, by UID (what
    :meth:`RobotAgent.step` decides from odometry alone), for scoring received
    closures as the simulation does."""
    seed = cfg.seed + ROUTE_SEED_STEP * robot
    true = patrol_route(plan, cfg.duration, seed=seed) if route is None else route
    true = np.asarray(true, dtype=np.float64)
    true = true[true[:, 0] <= true[0, 0] + cfg.duration]
    odo, _ = odometry(true, seed=seed + 1, **ODOMETRY_NOISE)
    truth: dict[int, F64] = {}
    prev: int | None = None
    for k in range(len(true)):
        if prev is not None:
            d = odo[k, 1:3] - odo[prev, 1:3]
            turn = abs(math.remainder(odo[k, 3] - odo[prev, 3], 2 * math.pi))
            near = math.hypot(d[0], d[1]) < cfg.pose_every and turn < cfg.pose_turn
            if near and k < len(true) - 1:
                continue
        truth[make_uid(robot, len(truth))] = true[k, 1:4].copy()
        prev = k
    return true, truth


class _Node:
    def __init__(
        self,
        plan: OccupancyMap,
        cfg: MissionConfig,
        robot: int,
        listen: str,
        peers: Mapping[int, str],
        exchange: ExchangeParams,
        *,
        state_dir: Path | None,
        lookahead: float,
        quiet: float | None,
        settle: float,
        timing: LockstepParams,
        max_message: int,
        progress: Progress | None,
        routes: Sequence[F64 | None] | None,
        key: TeamKey | None = None,
        insecure: bool = False,
        prior: OccupancyMap | None = None,
        region: npt.NDArray[np.bool_] | None = None,
    ) -> None:
        ids = _check_team(robot, peers)
        if key is not None and key.robots < len(ids):
            raise ConfigError(
                f"--key: the team key is for {key.robots} robots, the team has {len(ids)}",
                field="key",
            )
        self.robot = robot
        self.others = [j for j in ids if j != robot]
        self.cfg = cfg
        self.exchange = exchange
        self.lookahead = lookahead
        self.quiet = quiet_seconds(exchange.advert_every, exchange.request_every, quiet)
        self.settle = settle
        self.timing = timing
        self.progress = progress
        self.state_path = None if state_dir is None else Path(state_dir) / STATE_FILE
        # The sockets first: a bad or busy address fails before any work.
        self.zmq = ZmqTransport(
            robot, listen, peers, max_message=max_message + LOCK_SLACK, key=key, insecure=insecure
        )
        try:
            self._setup(plan, ids, max_message, routes, prior, region)
        except BaseException:
            self.zmq.close()
            raise

    def _setup(
        self,
        plan: OccupancyMap,
        ids: Sequence[int],
        max_message: int,
        given: Sequence[F64 | None] | None,
        prior: OccupancyMap | None,
        region: npt.NDArray[np.bool_] | None,
    ) -> None:
        cfg, robot = self.cfg, self.robot
        self.territory_cells = None if region is None else int(region.sum())
        if given is not None and len(given) != len(ids):
            raise ConfigError(f"routes: {len(given)} given for a team of {len(ids)}")
        world = make_world(plan, seed=cfg.seed, duration=cfg.duration, region=region)
        if region is not None:
            # Every route drawn here inside the mask, as the launcher draws them.
            drawn = mission_routes(
                plan,
                cfg.duration,
                seed=cfg.seed,
                robots=len(ids),
                region=region,
                given=None if given is None else dict(enumerate(given)),
            )
            given = [drawn[j] for j in ids]
        own = None if given is None else given[robot]
        self.agent = agent = RobotAgent(
            plan,
            cfg,
            prior=prior,
            world=world,
            robot=robot,
            route=own,
            calibrate=False,
            territory=region,
        )
        routes = [agent.route]
        others_truth: dict[int, F64] = {}
        for j in self.others:
            route, truth = route_truth(plan, cfg, j, None if given is None else given[j])
            routes.append(route)
            others_truth.update(truth)
        self.others_truth = others_truth
        self.times = team_ticks(routes)
        self.received_merged: dict[int, Pose] = {}
        self.port = ExchangerPort(robot, self.others, max_message)
        # What the naive baseline would send: the share of it the team reports, and the
        # byte target of ExchangeParams.anchor_share.
        self.meter = NaiveMeter(agent.store, agent.made if cfg.store.fold else None)
        self._views()
        self.exchanger = Exchanger(
            agent.store,
            self.port,
            self.exchange,
            adjacency=region_adjacency(agent.labels),
            on_received=self._received,
            peers=lambda: list(self.others),
            naive_bytes=lambda: float(self.meter.bytes),
        )
        self.link = ReliableLink(
            self.zmq,
            self.others,
            wait_timeout=self.timing.wait_timeout,
            retry=self.timing.retry,
            max_queue=int(self.timing.max_queue),
            durable=self.state_path is not None,
        )
        self.clock = LockstepClock.for_ticks(
            self.times,
            quiet=self.quiet,
            settle=self.settle,
            request_every=self.exchange.request_every,
        )
        self.fingerprint = state_fingerprint(
            plan, cfg, robot, ids, self.exchange, routes, prior, region
        )
        self.last_checkpoint = time.monotonic()

    def _views(self) -> None:
        """Point the scoring's views and the meter at the agent's dict of poses made
        (a restore makes a new one)."""
        agent = self.agent
        agent.peers_truth = ChainMap(agent.truth, self.others_truth)
        agent.peers_made = ChainMap(agent.made, self.received_merged)
        if self.meter.made is not None:
            self.meter.made = agent.made

    def _received(self, source: int, pose: Pose) -> list[ClosureEdge]:
        if pose.merged_from:
            self.received_merged[pose.uid] = pose
        return self.agent.receive(source, pose)

    # state

    def save(self, finished: bool = False) -> None:
        """The checkpoint: the composition of the parts' own states."""
        if self.state_path is None:
            return
        state: dict[str, Any] = {
            "v": _STATE_VERSION,
            "fingerprint": self.fingerprint,
            "finished": finished,
            "clock": self.clock.state(),
            "link": self.link.state(),
        }
        if not finished:
            state["store"] = self.agent.store.state()
            state["agent"] = self.agent.state()
            state["exchanger"] = self.exchanger.state()
            state["meter"] = self.meter.state()
            state["received_merged"] = [encode(p) for p in self.received_merged.values()]
        data = _pack(state)
        acked = dict(self.link.next_q)
        write_state(self.state_path, data)
        self.link.ack_mine = acked
        self.last_checkpoint = time.monotonic()

    def load(self) -> bool:
        """Resume from the state file if there is one; True if it says finished."""
        path = self.state_path
        if path is None or not path.exists():
            return False
        s = read_state(path)
        try:
            if not isinstance(s, dict) or s.get("v") != _STATE_VERSION:
                raise InputError("not a node state of this version")
            if s["fingerprint"] != self.fingerprint:
                raise InputError(
                    "the state belongs to another mission (plan, prior, territory mask, settings, "
                    "robot or team)"
                )
            self.link.restore(s["link"])
            self.clock.restore(s["clock"])
            if not s["finished"]:
                self.agent.store.restore(s["store"])
                self.agent.restore(s["agent"])
                self._views()
                self.exchanger.restore(s["exchanger"])
                # A state saved before the meter has none: it counts from here.
                if "meter" in s:
                    self.meter.restore(s["meter"])
                for b in s["received_merged"]:
                    p = decode_as(b, Pose)
                    self.received_merged[p.uid] = p
        except InputError as e:
            raise InputError(e.reason, path=path) from None
        except (RecordError, KeyError, TypeError, ValueError, OverflowError) as e:
            raise InputError(f"cannot resume from this state: {e}", path=path) from None
        logger.warning(
            "robot %d resumes at tick %d from %s (restart %d)",
            self.robot,
            self.clock.next,
            path,
            self.clock.restarts,
        )
        return bool(s["finished"])

    # the clock

    def _tick(self, n: int, t: float, driving: bool) -> None:
        """Tick ``n`` of the exchange, at mission time ``t``: the messages the simulated
        network would have delivered by then (robots ``j < i`` sent at tick ``n``,
        robots ``j > i`` at tick ``n - 1``, in the simulation's order), one step of the
        exchanger, and what it sent, followed by this tick's ``done`` marker."""
        if driving:
            self.agent.advance_to(t)
        else:
            self.exchanger.finish()
        wanted = self.agent.wanted_regions(self.lookahead) if driving else None
        need = {j: n if j < self.robot else n - 1 for j in self.others}
        link = self.link
        link.wait(lambda: [j for j in self.others if link.done[j] < need[j]], f"tick {n}")
        link.forget_markers(n - 1)
        self.port.inbox = [
            Message(j, self.robot, f.body, f.q, f.kind) for _, j, f in link.take(need)
        ]
        self.exchanger.step(t, wanted)
        self.meter.step(len(self.others))
        out, self.port.outbox = self.port.outbox, []
        for dst, kind, body in out:
            link.send(dst, n, kind, body)
        changes = self.exchanger.stats.poses_added + self.exchanger.stats.poses_deleted
        outstanding = bool(self.exchanger.outstanding)
        self.own_marker = (changes, outstanding)
        link.mark_done(n, changes, outstanding)

    def _team(self, n: int) -> tuple[int, bool]:
        """The team's exchange changes and whether anyone awaits an answer, at tick n."""
        link = self.link
        link.wait(lambda: [j for j in self.others if link.done[j] < n], f"the end of tick {n}")
        total, outstanding = self.own_marker
        for j in self.others:
            marker = link.markers[j].get(n)
            if marker is None:
                # A later tick's marker came in this one's place: the peer holds the
                # key but does not run the mission's clock; one line, not a KeyError.
                where = f"peer robot {j} ({self.zmq.peers.get(j, '?')})"
                raise InputError(
                    f"robot {self.robot}: {where} sent no marker for tick {n}, only one for "
                    f"tick {link.done[j]}: not one of the team, or its node is damaged",
                    field="peers",
                )
            c, o = marker
            total += c
            outstanding = outstanding or o
        return total, outstanding

    def _after(self, n: int, t: float, driving: bool) -> None:
        if driving and self.progress is not None:
            self.progress(n + 1, len(self.times))
        if time.monotonic() - self.last_checkpoint >= self.timing.checkpoint_every:
            self.save()

    def run(self) -> None:
        self.clock.run(
            self._tick,
            self._team,
            routes_end=lambda: self.exchanger.stats.bytes_sent,
            after=self._after,
        )

    def summary(self) -> tuple[dict[str, Any], Any]:
        agent, e, clock = self.agent, self.exchanger, self.clock
        held, twice = held_uids(agent.store)
        result = agent.finish()
        node = {
            "robot": self.robot,
            "row": robot_row(result.summary, agent, e.stats),
            "held": sorted(held),
            "duplicates": twice,
            "bytes_sent_mission": clock.sent,
            "naive_bytes": self.meter.bytes,
            "route_seconds": clock.end - clock.start,
            "settle_seconds": clock.settle_seconds,
            "settled": clock.settled,
            "last_change_s": clock.convergence_s,
            "ticks": clock.next,
            "restarts": clock.restarts,
            "local_digest": store_digest(agent.store),
            "rejected_frames": self.link.rejected + sum(self.zmq.stats.rejected.values()),
        }
        if self.territory_cells is not None:
            # The mask's cells on the plan (only with one: the same as the launcher's).
            node["territory_cells"] = self.territory_cells
        return node, result

    def linger(self) -> None:
        """Say goodbye, then serve the peers' requests to send again until every peer
        said goodbye too (or ``linger`` s passed)."""
        link = self.link
        for j in self.others:
            link.send(j, self.clock.next, "bye", b"")
        deadline = time.monotonic() + self.timing.linger
        last_ask = time.monotonic()
        while set(self.others) - link.bye and time.monotonic() < deadline:
            link.pump(0.05)
            if time.monotonic() - last_ask >= self.timing.retry:
                link.hello(sorted(set(self.others) - link.bye))
                last_ask = time.monotonic()
        missing = sorted(set(self.others) - link.bye)
        if missing:
            logger.warning("robot %d: no goodbye from robots %s; leaving", self.robot, missing)


def run_node(
    plan: OccupancyMap,
    cfg: MissionConfig,
    robot_id: int,
    listen: str,
    peers: Mapping[int, str],
    *,
    out: Path,
    exchange: ExchangeParams | None = None,
    state_dir: Path | None = None,
    lookahead: float = 30.0,
    quiet: float | None = None,
    settle: float = 120.0,
    timing: LockstepParams | None = None,
    max_message: int = DEFAULT_MAX_MESSAGE,
    progress: Progress | None = None,
    routes: Sequence[F64 | None] | None = None,
    key: TeamKey | None = None,
    insecure: bool = False,
    prior: OccupancyMap | None = None,
    region: npt.NDArray[np.bool_] | None = None,
) -> dict[str, Any]:
    """Run robot ``robot_id``'s mission as one node of a team over ZeroMQ.

    Parameters
    ----------
    plan : OccupancyMap
        The floor (also the prior map unless ``prior`` is given).
    cfg : MissionConfig
        The team's mission (every node the same); the robot's route and sensors are
        seeded from ``cfg.seed + ROUTE_SEED_STEP robot_id``, as in :func:`~.simulation.run_team`.
    robot_id : int
        This robot; the team is robots 0..N-1, this one and ``peers``.
    listen : str
        ``tcp://HOST:PORT`` this node binds.
    peers : mapping of int to str
        Every other robot's listen address.
    out : Path
        Folder for ``summary.json`` (this robot's row of run_team's summary, its held
        pose UIDs, :func:`store_digest`, the clock's figures and, with a ``region``,
        ``territory_cells``: its cells on the plan) and ``map.*``.
    exchange : ExchangeParams, optional
    state_dir : Path, optional
        Folder of the checkpoint; a node started on a folder holding one resumes.
    lookahead, quiet, settle : float
        As in :func:`~.simulation.run_team`.
    timing : LockstepParams, optional
    max_message : int
        Largest exchanger message, bytes (the simulated network's default, 1 MiB).
    progress : callable, optional
        ``progress(tick, ticks)`` after each tick of the routes.
    routes : sequence of ndarray (T, 4) or None, optional
        One per robot of the team (``t, x, y, theta``), as run_team's ``routes``; None
        draws a robot's patrol route from the seed.
    key : TeamKey, optional
        The team's key (:mod:`.keys`): connections encrypted and admitted only with it
        (CURVE), each peer known by its key. None: plain TCP, loopback only.
    insecure : bool
        Without a key, listen on an address other than loopback all the same.
    prior : OccupancyMap, optional
        The robot's prior map (:mod:`.prior`), as :func:`~.simulation.run_team`'s: its
        regions and the frame of its global map; scored against ``plan`` all the same.
    region : ndarray of bool, optional
        A user's territory mask on the plan's cells (:mod:`.territory`): the world's
        landmarks and the routes the node draws stay inside it, and the prior's regions
        are cut inside it. None: the whole plan.

    Returns
    -------
    dict
        What ``summary.json`` holds.

    Raises
    ------
    InputError
        A bad or busy address, a peer silent for ``timing.wait_timeout`` s, or a state
        file of another mission.
    """
    ex = exchange if exchange is not None else ExchangeParams()
    with contextlib.ExitStack() as held:
        if state_dir is not None:
            # Before any socket or work: the same robot started twice fails at once.
            held.enter_context(StateLock(Path(state_dir), f"robot {robot_id}"))
        return _run(
            plan,
            cfg,
            robot_id,
            listen,
            peers,
            out=out,
            exchange=ex,
            state_dir=state_dir,
            lookahead=lookahead,
            quiet=quiet,
            settle=settle,
            timing=timing,
            max_message=max_message,
            progress=progress,
            routes=routes,
            key=key,
            insecure=insecure,
            prior=prior,
            region=region,
        )


def _run(
    plan: OccupancyMap,
    cfg: MissionConfig,
    robot_id: int,
    listen: str,
    peers: Mapping[int, str],
    *,
    out: Path,
    exchange: ExchangeParams,
    state_dir: Path | None,
    lookahead: float,
    quiet: float | None,
    settle: float,
    timing: LockstepParams | None,
    max_message: int,
    progress: Progress | None,
    routes: Sequence[F64 | None] | None,
    key: TeamKey | None,
    insecure: bool,
    prior: OccupancyMap | None,
    region: npt.NDArray[np.bool_] | None,
) -> dict[str, Any]:
    ex = exchange
    node = _Node(
        plan,
        cfg,
        robot_id,
        listen,
        peers,
        ex,
        state_dir=state_dir,
        lookahead=lookahead,
        quiet=quiet,
        settle=settle,
        timing=timing if timing is not None else LockstepParams(),
        max_message=max_message,
        progress=progress,
        routes=routes,
        key=key,
        insecure=insecure,
        prior=prior,
        region=region,
    )
    try:
        finished = node.load()
        node.link.hello(node.others)
        if finished:
            summary = json.loads((Path(out) / SUMMARY_FILE).read_text())
        else:
            node.run()
            summary, result = node.summary()
            with atomic_folder(Path(out)) as tmp:
                atomic_write_text(tmp / SUMMARY_FILE, json_dumps(summary))
                write_map(result.global_map, tmp / "map")
            node.save(finished=True)
        node.linger()
        return dict(summary)
    finally:
        node.zmq.close()
