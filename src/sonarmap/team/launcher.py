"""A local team of ZeroMQ nodes: :func:`run_zmq_team` starts one process per robot
(``python -m sonarmap team node``, :func:`~.node.run_node`) on loopback ports, restarts
a node killed by a signal (it resumes from its checkpoint), and gathers the nodes'
summaries into the team's, built as the simulated team's
(:mod:`.summary`)."""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import ConfigError, InputError
from ..files import atomic_folder, atomic_write_text, json_dumps
from ..io.rosmap import OccupancyMap, read_map, write_map
from .config import check_team_size
from .exchange import ExchangeParams
from .inputs import mission_routes
from .keys import make_team_key
from .mission import MissionConfig
from .network import NetworkParams
from .node import MIB, SUMMARY_FILE, LockstepParams, save_routes
from .outputs import run_inputs, write_prior
from .prior import check_prior
from .simulation import map_agreement
from .store import StoreParams
from .summary import mission_figures, team_figures
from .territory import NO_TERRITORY, is_no_territory, territory_of
from .transport import DEFAULT_MAX_MESSAGE

__all__ = ["KEY_FILE", "ZmqTeamResult", "node_args", "run_zmq_team", "run_zmq_team_into"]

logger = logging.getLogger("sonarmap.team.node")

F64 = npt.NDArray[np.float64]
Progress = Callable[[int, int], None]

#: The team key's file (:mod:`.keys`) in the nodes' folder.
KEY_FILE = "team.key"


@dataclass
class ZmqTeamResult:
    """What a team of node processes made.

    Attributes
    ----------
    summary : dict
        run_team's summary keys (``robots`` rows, ``duplicate_poses``,
        ``identical_maps``, ``bytes_per_robot_minute``, ``naive_bytes_per_robot_minute``,
        ``share_of_naive``, ``settle_seconds``, ``settled``, ``robots_n``, ``network``,
        ``exchange``, ``seed``) and
        ``transport`` ("zmq"), ``wall_seconds``, ``restarts`` (per robot) and
        ``store_digests`` (per robot, :func:`store_digest`).
    held : list of set of int
        The pose UIDs each robot held once the network was quiet.
    nodes : list of dict
        Each node's ``summary.json``.
    folder : Path
        Where the nodes wrote (their outputs ``robotK/``, states ``robotK.state/``,
        logs ``robotK.log`` and process ids ``robotK.pid``).
    """

    summary: dict[str, Any]
    held: list[set[int]]
    nodes: list[dict[str, Any]]
    folder: Path


def _free_ports(n: int) -> list[int]:
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [int(s.getsockname()[1]) for s in socks]
    finally:
        for s in socks:
            s.close()


def node_args(
    cfg: MissionConfig,
    exchange: ExchangeParams,
    lookahead: float,
    quiet: float | None,
    settle: float,
    timing: LockstepParams,
) -> list[str]:
    """The command-line options every node of a team gets (``team node``), besides its
    id, addresses, map, output and state folders; :class:`ConfigError` for a mission
    setting a node's command line cannot carry."""
    base = MissionConfig(
        duration=cfg.duration,
        seed=cfg.seed,
        store=StoreParams(
            pose_limit=cfg.store.pose_limit,
            region_limit=cfg.store.region_limit,
            region_density=cfg.store.region_density,
            store_limit=cfg.store.store_limit,
            fold=cfg.store.fold,
            merge_on_closure=cfg.store.merge_on_closure,
        ),
        pcm=cfg.pcm,
    )
    if base != cfg:
        raise ConfigError(
            "run_zmq_team: the nodes take only the mission's duration, seed, pose_limit, "
            "region_limit, region_density, store_limit, fold, merge_on_closure and pcm; other "
            "MissionConfig settings differ from their defaults"
        )
    args = [
        "--duration",
        repr(float(cfg.duration)),
        "--seed",
        str(cfg.seed),
        "--pose-limit",
        str(cfg.store.pose_limit),
        "--region-limit",
        str(cfg.store.region_limit),
        "--region-density",
        repr(float(cfg.store.region_density)),
        "--store-limit",
        str(cfg.store.store_limit),
        "--fold" if cfg.store.fold else "--no-fold",
        "--pcm" if cfg.pcm else "--no-pcm",
        "--merge-on-closure",
        str(cfg.store.merge_on_closure),
        "--lookahead",
        repr(float(lookahead)),
        "--settle",
        repr(float(settle)),
        "--wait-timeout",
        repr(float(timing.wait_timeout)),
        "--checkpoint-every",
        repr(float(timing.checkpoint_every)),
        "--max-queue",
        repr(float(timing.max_queue) / MIB),
    ]
    if quiet is not None:
        args += ["--quiet", repr(float(quiet))]
    for f in fields(exchange):
        args += ["--exchange", f"{f.name}={getattr(exchange, f.name)!r}".replace("'", "")]
    return args


def _last_line(path: Path) -> str:
    try:
        lines = [s for s in path.read_text(errors="replace").splitlines() if s.strip()]
    except OSError:
        return ""
    return lines[-1].strip() if lines else ""


def node_territory(
    territory: str | Path | None, plan: OccupancyMap
) -> tuple[npt.NDArray[np.bool_] | None, list[str]]:
    """The territory mask the launcher draws its routes in (on the plan's cells; None:
    the whole plan) and the ``team node`` arguments that make every node work out the
    same one (:func:`.territory.territory_of`): none for the default, ``--territory
    none`` for the whole plan, ``--territory FILE`` (absolute) for a mask file."""
    mask = territory_of(territory, plan)
    region = None if mask is None else mask.region
    if territory is None:
        return region, []
    if is_no_territory(territory):
        return region, ["--territory", NO_TERRITORY]
    return region, ["--territory", str(Path(territory).resolve())]


def run_zmq_team(
    plan: OccupancyMap | Path,
    cfg: MissionConfig,
    robots: int,
    *,
    network: NetworkParams | None = None,
    exchange: ExchangeParams | None = None,
    seed: int = 0,
    progress: Progress | None = None,
    lookahead: float = 30.0,
    quiet: float | None = None,
    settle: float = 120.0,
    folder: Path | None = None,
    timing: LockstepParams | None = None,
    restarts: int = 3,
    timeout: float | None = None,
    python: str | None = None,
    routes: Sequence[F64 | None] | None = None,
    prior: OccupancyMap | None = None,
    territory: str | Path | None = None,
) -> ZmqTeamResult:
    """Run ``robots`` robots as local processes (``python -m sonarmap team node``) on
    loopback ports, exchanging over ZeroMQ; the same mission as :func:`run_team`.

    Parameters
    ----------
    plan : OccupancyMap or Path
        The floor, or a map_server YAML of it.
    cfg : MissionConfig
        Only ``duration``, ``seed`` and the store's two limits may differ from the
        defaults (they are what a node's command line takes).
    robots : int
        Robots (processes), ids 0..robots-1; >= 1.
    network : NetworkParams, optional
        The real network is what it is: only ``kind="full"`` with no loss, delay,
        jitter or bandwidth cap describes it (else :class:`ConfigError`); recorded in
        the summary.
    exchange : ExchangeParams, optional
    seed : int
        The simulated network's seed in run_team; recorded only.
    progress : callable, optional
        ``progress(done, robots)`` as nodes finish.
    lookahead, quiet, settle : float
        As in :func:`run_team`.
    folder : Path, optional
        Where the nodes write; a temporary folder (removed) when not given.
    timing : LockstepParams, optional
    restarts : int
        Times a node killed by a signal is started again (it resumes from its state).
    timeout : float, optional
        Wall seconds for the whole team; default 600 + 10 x the mission's seconds.
    python : str, optional
        The interpreter; this one by default.
    routes : sequence of ndarray (T, 4) or None, optional
        One per robot, as run_team's: a given route replaces the robot's patrol route.
        The launcher draws the others and hands every node all of them, so that no
        node spends its start drawing routes.
    prior : OccupancyMap, optional
        Every robot's prior map, as run_team's (written beside the plan and handed to
        every node); the plan itself when not given.
    territory : str or Path, optional
        A territory mask file (:mod:`.territory`; the patrol's formats): the routes
        drawn here and every node's landmarks and routes stay inside it; each node is
        handed the file (``--territory``). ``"none"`` (:data:`.territory.NO_TERRITORY`):
        the whole plan, and so for every node. None: the default
        (:func:`.territory.default_territory`: the building's footprint on a drawn
        plan whose outside is free, the whole plan elsewhere), which every node works
        out alike.

    Returns
    -------
    ZmqTeamResult
    """
    # Refused, not attempted: each robot is a process of its own.
    check_team_size(robots, processes=True)
    net = network if network is not None else NetworkParams(kind="full")
    if (
        net.kind != "full"
        or net.loss
        or net.delay
        or net.jitter
        or net.bandwidth is not None
        or net.max_message != DEFAULT_MAX_MESSAGE
    ):
        raise ConfigError(
            "the zmq transport runs over the real network: only --network full, with no "
            "--bandwidth or --loss, describes it (use --transport sim for the others)"
        )
    ex = exchange if exchange is not None else ExchangeParams()
    timing = timing if timing is not None else LockstepParams()
    args = node_args(cfg, ex, lookahead, quiet, settle, timing)
    limit = 600.0 + 10.0 * cfg.duration if timeout is None else timeout
    with tempfile.TemporaryDirectory(prefix="sonarmap-zmq-") as scratch:
        where = Path(folder) if folder is not None else Path(scratch)
        where.mkdir(parents=True, exist_ok=True)
        if isinstance(plan, OccupancyMap):
            write_map(plan, where / "plan")
            plan_path = where / "plan.yaml"
        else:
            plan_path = Path(plan)
            plan = read_map(plan_path)
        if routes is not None and len(routes) != robots:
            raise ConfigError(f"routes: {len(routes)} given for {robots} robots")
        region, territory_args = node_territory(territory, plan)
        drawn = mission_routes(
            plan,
            cfg.duration,
            seed=cfg.seed,
            robots=robots,
            region=region,
            given=None if routes is None else dict(enumerate(routes)),
        )
        save_routes(
            where / "routes", [np.asarray(drawn[i], dtype=np.float64) for i in range(robots)]
        )
        # A fresh key per team: even on loopback, another process of this machine must
        # not be able to join it or pose as one of its robots.
        make_team_key(robots).write(where / KEY_FILE)
        args = [*args, "--routes", str(where / "routes"), "--key", str(where / KEY_FILE)]
        args += territory_args
        if prior is not None:
            check_prior(plan, prior, "prior")
            write_map(prior, where / "prior")
            args += ["--prior", str(where / "prior.yaml")]
        addresses = [f"tcp://127.0.0.1:{p}" for p in _free_ports(robots)]
        return _launch(
            where,
            plan_path,
            robots,
            addresses,
            args,
            net,
            ex,
            seed,
            restarts,
            limit,
            python,
            progress,
        )


def run_zmq_team_into(
    out: str | Path,
    plan: OccupancyMap | Path,
    cfg: MissionConfig,
    robots: int,
    *,
    preset: str | None,
    prior: OccupancyMap | None = None,
    prior_record: dict[str, Any] | None = None,
    territory: str | Path | None = None,
    territory_record: dict[str, Any] | None = None,
    network: NetworkParams | None = None,
    exchange: ExchangeParams | None = None,
    seed: int = 0,
    progress: Progress | None = None,
    lookahead: float = 30.0,
    quiet: float | None = None,
    settle: float = 120.0,
    timing: LockstepParams | None = None,
    restarts: int = 3,
    timeout: float | None = None,
    python: str | None = None,
    routes: Sequence[F64 | None] | None = None,
) -> dict[str, Any]:
    """:func:`run_zmq_team` with its outputs in the folder ``out``, written at once at the
    end (or nothing): the nodes' in ``out/nodes``, the team's summary in
    ``out/summary.json`` and the prior the robots were given (if any) in ``out/prior.*``.

    Parameters
    ----------
    out : str or Path
        The folder, replaced as a whole.
    plan, cfg, robots
        As :func:`run_zmq_team`.
    preset : str or None
        The exchange and store preset applied (:mod:`.presets`; None for none),
        recorded in the summary as ``preset``.
    prior : OccupancyMap, optional
        The robots' prior map (:func:`~.prior.make_prior`; None: the plan).
    prior_record, territory_record : dict, optional
        What the summary records of the prior and the territory (as ``prior`` and
        ``territory``; nothing when None).
    territory : str or Path, optional
        As :func:`run_zmq_team`.
    network, exchange, seed, progress, lookahead, quiet, settle, timing, restarts
        As :func:`run_zmq_team` (same defaults).
    timeout, python, routes
        As :func:`run_zmq_team` (same defaults).

    Returns
    -------
    dict
        The team's summary, as written.
    """
    with atomic_folder(Path(out)) as tmp:
        result = run_zmq_team(
            plan,
            cfg,
            robots,
            network=network,
            exchange=exchange,
            seed=seed,
            progress=progress,
            lookahead=lookahead,
            quiet=quiet,
            settle=settle,
            folder=tmp / "nodes",
            timing=timing,
            restarts=restarts,
            timeout=timeout,
            python=python,
            routes=routes,
            prior=prior,
            territory=territory,
        )
        result.summary["preset"] = preset
        result.summary.update(run_inputs(prior_record, territory_record))
        write_prior(tmp, prior)
        atomic_write_text(tmp / "summary.json", json_dumps(result.summary))
    return result.summary


def _launch(
    where: Path,
    plan_path: Path,
    robots: int,
    addresses: list[str],
    args: list[str],
    net: NetworkParams,
    ex: ExchangeParams,
    seed: int,
    restarts: int,
    limit: float,
    python: str | None,
    progress: Progress | None,
) -> ZmqTeamResult:
    exe = python or sys.executable
    cmds = []
    for i in range(robots):
        peers = ",".join(f"{j}={addresses[j]}" for j in range(robots) if j != i)
        cmd = [exe, "-m", "sonarmap", "team", "node", "--id", str(i), "--listen", addresses[i]]
        if peers:
            cmd += ["--peers", peers]
        cmd += ["--map", str(plan_path), "-o", str(where / f"robot{i}")]
        cmd += ["--state", str(where / f"robot{i}.state"), *args]
        cmds.append(cmd)
    env = dict(os.environ)
    src = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH")) if p)
    procs: dict[int, subprocess.Popen[bytes]] = {}
    logs: dict[int, Any] = {}
    used = dict.fromkeys(range(robots), 0)
    lock = threading.Lock()

    def start(i: int) -> None:
        log = logs.get(i)
        if log is None:
            log = logs[i] = open(where / f"robot{i}.log", "ab")  # noqa: SIM115
        procs[i] = subprocess.Popen(cmds[i], stdout=log, stderr=subprocess.STDOUT, env=env)
        atomic_write_text(where / f"robot{i}.pid", f"{procs[i].pid}\n")

    t0 = time.monotonic()
    try:
        with lock:
            for i in range(robots):
                start(i)
        finished: set[int] = set()
        while len(finished) < robots:
            if time.monotonic() - t0 > limit:
                raise InputError(f"the zmq team did not finish within {limit:g} s (see {where})")
            for i in range(robots):
                if i in finished:
                    continue
                rc = procs[i].poll()
                if rc is None:
                    continue
                if rc == 0:
                    finished.add(i)
                    if progress is not None:
                        progress(len(finished), robots)
                elif rc < 0 and used[i] < restarts:
                    # Killed by a signal: started again, it resumes from its state.
                    used[i] += 1
                    logger.warning("robot %d killed (signal %d); starting it again", i, -rc)
                    start(i)
                else:
                    why = _last_line(where / f"robot{i}.log") or f"exit code {rc}"
                    raise InputError(f"robot {i}'s node failed: {why}")
            time.sleep(0.1)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGKILL)
                p.wait()
        for log in logs.values():
            log.close()
    nodes = [json.loads((where / f"robot{i}" / SUMMARY_FILE).read_text()) for i in range(robots)]
    return _team_summary(nodes, net, ex, seed, time.monotonic() - t0, where)


def _team_summary(
    nodes: list[dict[str, Any]],
    net: NetworkParams,
    ex: ExchangeParams,
    seed: int,
    wall: float,
    where: Path,
) -> ZmqTeamResult:
    robots = len(nodes)
    held = [set(n["held"]) for n in nodes]
    rows = [n["row"] for n in nodes]
    settled = all(bool(n["settled"]) for n in nodes)
    # Nodes of a release before the meter report none.
    metered = all("naive_bytes" in n for n in nodes)
    maps = [where / f"robot{i}" / "map.yaml" for i in range(robots)]
    agreement = (
        map_agreement([read_map(m) for m in maps]) if all(m.exists() for m in maps) else None
    )
    summary: dict[str, Any] = mission_figures(rows)
    summary.update(
        team_figures(
            rows,
            held=held,
            duplicates=sum(int(n["duplicates"]) for n in nodes),
            route_seconds=float(nodes[0]["route_seconds"]),
            sent_in_mission=sum(int(n["bytes_sent_mission"]) for n in nodes),
            naive_bytes=sum(int(n["naive_bytes"]) for n in nodes) if metered else None,
            converged=settled,
            convergence_s=float(nodes[0]["last_change_s"]),
            settle_seconds=max(float(n["settle_seconds"]) for n in nodes),
            settled=settled,
        )
    )
    summary["convergence_s"] = summary["convergence_s"] if summary["identical_maps"] else None
    summary.update(
        {
            "map_agreement": agreement,
            # The central bound needs every robot's data in one process: 'team run
            # --transport sim'.
            "map_f1_central": None,
            "central": None,
            "network": asdict(net),
            "exchange": asdict(ex),
            "seed": seed,
            "transport": "zmq",
            "wall_seconds": wall,
            "restarts": [int(n["restarts"]) for n in nodes],
            "store_digests": [n["local_digest"] for n in nodes],
        }
    )
    return ZmqTeamResult(summary, held, nodes, where)
