"""A team over ZeroMQ: one process per robot on loopback, against the simulated team."""

from __future__ import annotations

import copy
import json
import logging
import math
import os
import signal
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

from sonarmap.builtins import builtin_plan
from sonarmap.cli import main
from sonarmap.errors import ConfigError
from sonarmap.io.rosmap import OccupancyMap, write_map
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.checkpoint import read_state
from sonarmap.team.exchange import LEAN, ExchangeParams, Exchanger
from sonarmap.team.launcher import ZmqTeamResult, node_args, run_zmq_team
from sonarmap.team.link import ReliableLink
from sonarmap.team.mission import MissionConfig
from sonarmap.team.network import NetworkParams, SimNetwork
from sonarmap.team.node import (
    LockstepParams,
    load_routes,
    parse_exchange,
    parse_peers,
    store_digest,
)
from sonarmap.team.patrolling import patrol_routes
from sonarmap.team.prior import degrade_plan, parse_prior_error
from sonarmap.team.records import Landmarks, Pose, make_uid
from sonarmap.team.simulation import TeamResult, run_team
from sonarmap.team.store import RobotStore, StoreParams
from sonarmap.team.transport import SimHub, ZmqTransport
from sonarmap.team.world import patrol_route

#: Summary keys measured on the wall clock: they differ between identical runs.
WALL = {"wall_seconds", "association_ms_median", "association_ms_p99", "global_map_batch_s"}
#: Scores of the received poses at their true poses: a node knows a peer's merges only
#: from the merge records it was sent, the simulator knows every robot's, so a received
#: pose merged away may be scored in one and not the other (compared loosely below).
HELD = {"map_f1_held_true_poses", "map_poses_held"}
#: 20 s of mission with regions of two poses: every robot compresses, so its own store
#: depends on what it received and when.
#: 32 kB in every region (no area term), so that compression runs within 20 s.
CONFIG = MissionConfig(
    duration=20.0, seed=1, store=StoreParams(region_limit=32_768, region_density=0.0)
)


@pytest.fixture(scope="module")
def plan() -> OccupancyMap:
    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


#: The thesis's protocol, and the lean one with its byte target and merging at closures,
#: whose decisions a restarted node must take back from its checkpoint.
SETTINGS = {
    "thesis": (CONFIG, ExchangeParams()),
    "lean": (
        MissionConfig(
            duration=20.0,
            seed=1,
            store=StoreParams(
                region_limit=32_768, region_density=0.0, fold=True, merge_on_closure=8
            ),
        ),
        replace(LEAN, hold=5.0),
    ),
}


@pytest.fixture(scope="module", params=sorted(SETTINGS))
def setting(request: pytest.FixtureRequest) -> tuple[MissionConfig, ExchangeParams]:
    return SETTINGS[request.param]


@pytest.fixture(scope="module")
def simulated(plan: OccupancyMap, setting: tuple[MissionConfig, ExchangeParams]) -> TeamResult:
    cfg, ex = setting
    return run_team(plan, cfg, 3, network=NetworkParams(kind="full"), exchange=ex, seed=3)


#: The tick (of 40 on the routes, then about 28 quiet ones) robot 1 is killed after.
KILL_AT = 25


def _tick_of(state: Path) -> int:
    """The tick a node's checkpoint resumes at (-1 if none yet)."""
    if not state.exists():
        return -1
    return int(read_state(state)["clock"]["next"])


@pytest.fixture(scope="module")
def killed(
    plan: OccupancyMap,
    setting: tuple[MissionConfig, ExchangeParams],
    tmp_path_factory: pytest.TempPathFactory,
) -> ZmqTeamResult:
    """Three node processes; robot 1 is killed (SIGKILL) once it has checkpointed, and
    the launcher starts it again on its state."""
    cfg, ex = setting
    folder = tmp_path_factory.mktemp("zmq")
    out: dict[str, Any] = {}

    def team() -> None:
        try:
            out["result"] = run_zmq_team(
                plan,
                cfg,
                3,
                exchange=ex,
                seed=3,
                folder=folder,
                timing=LockstepParams(checkpoint_every=0.2, wait_timeout=240.0),
                timeout=400.0,
            )
        except Exception as e:  # handed to the test thread
            out["error"] = e

    runner = threading.Thread(target=team)
    runner.start()
    state = folder / "robot1.state" / "state.msgpack"
    deadline = time.monotonic() + 300.0
    while _tick_of(state) < KILL_AT and runner.is_alive() and time.monotonic() < deadline:
        time.sleep(0.02)
    if runner.is_alive():
        os.kill(int((folder / "robot1.pid").read_text()), signal.SIGKILL)
    runner.join()
    if "error" in out:
        raise out["error"]
    result: ZmqTeamResult = out["result"]
    return result


def _nan_none(v: object) -> object:
    return None if isinstance(v, float) and math.isnan(v) else v


def test_zmq_team_gives_the_simulated_teams_results(
    killed: ZmqTeamResult, simulated: TeamResult
) -> None:
    z, s = killed.summary, simulated.summary
    assert killed.held == simulated.held
    assert z["store_digests"] == [store_digest(r.store) for r in simulated.robots]
    for zr, sr in zip(copy.deepcopy(z["robots"]), copy.deepcopy(s["robots"]), strict=True):
        # The same closures are judged (the stores are equal), but a node knows a
        # peer's merges only from the merge records it was sent (as with HELD): a peer's
        # closure to a pose whose merge chain it lacks has no known truth there
        # (scoring.origin_of) and is unscored in a node, not in the simulator.
        zu, su = (r["association_stages"]["graph"].pop("kept_unscored") for r in (zr, sr))
        assert zu >= su
        assert (
            zr["association_stages"]["graph"]["kept_false"]
            == (sr["association_stages"]["graph"]["kept_false"])
        )
        # A node's rows come through JSON, where an undefined score (NaN) is None.
        assert {k: _nan_none(v) for k, v in zr.items() if k not in WALL | HELD} == {
            k: _nan_none(v) for k, v in sr.items() if k not in WALL | HELD and k in zr
        }
        assert 0 <= sr["map_poses_held"] - zr["map_poses_held"] <= 2
        assert zr["map_f1_held_true_poses"] == pytest.approx(sr["map_f1_held_true_poses"], abs=0.01)
    for key in ("duplicate_poses", "identical_maps", "settle_seconds", "settled"):
        assert z[key] == s[key], key
    # The naive baseline's bytes too: robot 1's meter came through its restart (with
    # folding, still pricing each pose with its map as made).
    for key in (
        "bytes_per_robot_minute",
        "bytes_per_robot_minute_all",
        "naive_bytes_per_robot_minute",
        "share_of_naive",
    ):
        assert z[key] == pytest.approx(s[key]), key
    assert 0 < z["share_of_naive"] < 2
    # Read back from the maps the nodes wrote.
    assert z["map_agreement"] == pytest.approx(s["map_agreement"], abs=0.01)
    # Compression ran, so the stores depended on the exchange's timing.
    assert any(r["poses_local"] < r["poses_made"] for r in z["robots"])


def test_a_killed_node_resumes_without_losing_or_duplicating_poses(
    killed: ZmqTeamResult, simulated: TeamResult
) -> None:
    assert killed.summary["restarts"] == [0, 1, 0]
    assert killed.summary["duplicate_poses"] == 0
    assert killed.summary["identical_maps"] is True
    # Every robot holds every own pose of every robot: none lost, none twice.
    own = set().union(*(r.store.local.poses for r in simulated.robots))
    assert all(h == own for h in killed.held)
    log = (killed.folder / "robot1.log").read_text()
    resumed = int(log.split("resumes at tick ")[1].split()[0])
    assert KILL_AT <= resumed < killed.nodes[1]["ticks"]


def _link(robot: int) -> tuple[ReliableLink, ZmqTransport]:
    peer_t = ZmqTransport(1 - robot, "tcp://127.0.0.1:0")
    t = ZmqTransport(robot, "tcp://127.0.0.1:0", {1 - robot: peer_t.address})
    peer_t.connect(robot, t.address)
    return ReliableLink(
        t, [1 - robot], wait_timeout=LockstepParams().wait_timeout, retry=LockstepParams().retry
    ), peer_t


def _pump_until(link: ReliableLink, test: Any) -> None:
    deadline = time.monotonic() + 30.0
    while not test() and time.monotonic() < deadline:
        link.pump(0.05)


def _send(peer: ZmqTransport, dst: int, body: bytes, kind: str) -> None:
    deadline = time.monotonic() + 30.0
    while not peer.send(dst, body, kind) and time.monotonic() < deadline:
        time.sleep(0.02)


def test_bad_frames_are_rejected_and_logged_and_good_ones_still_taken(
    caplog: pytest.LogCaptureFixture,
) -> None:
    link, peer = _link(0)
    try:
        bad = [
            (b"\x93\x01", "lock"),  # truncated msgpack
            (msgpack.packb({"q": 0, "t": 0, "k": "advert"}), "lock"),  # a key missing
            (msgpack.packb({"q": -1, "t": 0, "k": "advert", "b": b""}), "lock"),
            (msgpack.packb({"q": 0, "t": 0, "k": "nonsense", "b": b""}), "lock"),
            (msgpack.packb({"q": 0, "t": 0, "k": "done", "b": b"junk"}), "lock"),
            (msgpack.packb({"q": 10**9, "t": 0, "k": "advert", "b": b""}), "lock"),
            (msgpack.packb({"next": "x", "ack": 0}), "hello"),
            (b"", "gossip"),
        ]
        with caplog.at_level(logging.WARNING, logger="sonarmap.team.node"):
            for body, kind in bad:
                _send(peer, 0, bytes(body), kind)
            _pump_until(link, lambda: link.rejected >= len(bad))
        assert link.rejected == len(bad)
        assert sum("rejected a frame from robot 1" in r.message for r in caplog.records) == 8
        # Nothing was taken, and the next good frame is.
        assert link.next_q[1] == 0
        good = msgpack.packb({"q": 0, "t": 0, "k": "advert", "b": b"x"})
        _send(peer, 0, bytes(good), "lock")
        _pump_until(link, lambda: link.next_q[1] == 1)
        assert [f.body for f in link.inbox[1]] == [b"x"]
    finally:
        link.zmq.close()
        peer.close()


def test_frames_out_of_order_or_twice_are_taken_once_in_order() -> None:
    link, peer = _link(1)
    try:
        frames = [(2, "request"), (0, "advert"), (0, "advert"), (1, "done"), (2, "request")]
        for q, k in frames:
            body = b"" if k != "done" else msgpack.packb({"ch": 3, "out": False, "ack": 0})
            _send(peer, 1, bytes(msgpack.packb({"q": q, "t": 4, "k": k, "b": body})), "lock")
        _pump_until(link, lambda: link.next_q[0] == 3)
        assert [f.q for f in link.inbox[0]] == [0, 2]
        assert link.done[0] == 4
        assert link.markers[0][4] == (3, False)
    finally:
        link.zmq.close()
        peer.close()


def _node_cli(plan_yaml: Path, out: Path, *args: str) -> list[str]:
    return [
        "team",
        "node",
        "--map",
        str(plan_yaml),
        "--duration",
        "5",
        "-o",
        str(out),
        *args,
    ]


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--id", "0", "--listen", "udp://127.0.0.1:5"], "not a tcp://HOST:PORT address"),
        (["--id", "0", "--listen", "tcp://192.0.2.1:5555"], "cannot listen on"),
        (
            ["--id", "0", "--listen", "tcp://127.0.0.1:0", "--peers", "1=tcp://127.0.0.1"],
            "not a tcp://HOST:PORT address",
        ),
        (["--id", "0", "--listen", "tcp://127.0.0.1:0", "--peers", "2=tcp://a:1"], "0..N-1"),
    ],
)
def test_a_bad_address_fails_with_one_line(
    plan: OccupancyMap,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    args: list[str],
    expected: str,
) -> None:
    write_map(plan, tmp_path / "plan")
    with pytest.raises(SystemExit) as e:
        main(_node_cli(tmp_path / "plan.yaml", tmp_path / "out", *args))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert expected in err


def test_an_unreachable_peer_fails_with_one_line(
    plan: OccupancyMap, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_map(plan, tmp_path / "plan")
    silent = ZmqTransport(5, "tcp://127.0.0.1:0")  # a port nobody answers on
    address = silent.address
    silent.close()
    args = ["--id", "1", "--listen", "tcp://127.0.0.1:0", "--peers", f"0={address}"]
    with pytest.raises(SystemExit) as e:
        main(_node_cli(tmp_path / "plan.yaml", tmp_path / "out", *args, "--wait-timeout", "1"))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "peer robot 0" in err
    assert "sent nothing for 1 s" in err
    assert not (tmp_path / "out" / "summary.json").exists()


def test_peers_and_exchange_options() -> None:
    assert parse_peers("tcp://a:1,tcp://b:2", 1) == {0: "tcp://a:1", 2: "tcp://b:2"}
    assert parse_peers("2=tcp://b:2, 0=tcp://a:1", 1) == {2: "tcp://b:2", 0: "tcp://a:1"}
    with pytest.raises(ConfigError, match="twice"):
        parse_peers("0=tcp://a:1,0=tcp://b:2", 1)
    with pytest.raises(ConfigError, match="ID=ADDRESS"):
        parse_peers("0=tcp://a:1,tcp://b:2", 1)
    ex = parse_exchange(["mode=limited", "cap_bytes=1000", "advert_every=2.5"])
    assert (ex.mode, ex.cap_bytes, ex.advert_every) == ("limited", 1000, 2.5)
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_exchange(["speed=3"])
    with pytest.raises(ConfigError, match="int expected"):
        parse_exchange(["cap_bytes=lots"])
    with pytest.raises(ConfigError, match="zmq transport runs good and limited"):
        parse_exchange(["mode=naive"])
    # The launcher writes booleans as Python prints them; bool("False") would be True.
    assert parse_exchange(["ternary_maps=False"]).ternary_maps is False
    assert parse_exchange(["ternary_maps=true", "descriptor_bits=3"]).ternary_maps is True
    with pytest.raises(ConfigError, match="bool expected"):
        parse_exchange(["ternary_maps=maybe"])
    # What the launcher writes is what a node reads back, the lean settings included.
    args = node_args(CONFIG, LEAN, 30.0, None, 120.0, LockstepParams())
    items = [args[i + 1] for i, a in enumerate(args) if a == "--exchange"]
    assert parse_exchange(items) == LEAN


def test_the_launcher_refuses_a_simulated_network(plan: OccupancyMap) -> None:
    with pytest.raises(ConfigError, match="real network"):
        run_zmq_team(plan, CONFIG, 2, network=NetworkParams(kind="full", loss=0.1))
    with pytest.raises(ConfigError, match="duration, seed, pose_limit"):
        run_zmq_team(plan, MissionConfig(duration=5.0, batch=3), 2)


def test_a_checkpoint_keeps_the_hold_and_what_it_let_out() -> None:

    from sonarmap.team.exchange import Exchanger
    from sonarmap.team.store import RobotStore

    def exchanger() -> tuple[Exchanger, RobotStore]:
        store = RobotStore(0)
        for k in range(3):
            p = Pose(make_uid(0, k), float(k), k % 2, np.zeros(3), Landmarks.empty())
            store.add_own_pose(p, None, [], float(k))
        hub = SimHub(SimNetwork(NetworkParams(kind="full"), 2))
        return Exchanger(store, hub.transport(0), ExchangeParams(hold=1.5)), store

    e, _ = exchanger()
    e.step(3.0)  # poses 0 and 1 are out, pose 2 is held
    state = msgpack.unpackb(msgpack.packb(e.state()), raw=False)
    back, _ = exchanger()
    back.restore(state)
    assert (
        set(back.outgoing.offered.poses)
        == set(e.outgoing.offered.poses)
        == {make_uid(0, 0), make_uid(0, 1)}
    )
    assert back.advert() == e.advert()
    assert e.stats.bytes_by_kind["advert"] > 0
    assert back.stats.bytes_by_kind == e.stats.bytes_by_kind
    back.stats.bytes_by_kind["advert"] += 1  # still a Counter after the round trip
    e.finish()
    state = msgpack.unpackb(msgpack.packb(e.state()), raw=False)
    back.restore(state)
    back.step(3.5)
    assert set(back.outgoing.offered.poses) == {make_uid(0, k) for k in range(3)}


def test_a_zmq_team_patrols_on_the_routes_the_simulation_would_drive(
    tmp_path: Path,
) -> None:
    """``team run --transport zmq --patrol``: the nodes drive the potential-field
    patrol's routes (drawn once, handed to every node), not their own seeded ones."""
    out = tmp_path / "out"
    args = ["--map", "building:0", "--robots", "2", "--duration", "10", "--seed", "2"]
    main(["team", "run", *args, "--transport", "zmq", "--patrol", "-o", str(out)])
    plan = builtin_plan("building:0")
    patrolled, _ = patrol_routes(plan, 2, 10.0, seed=2)
    handed = load_routes(out / "nodes" / "routes", 2)
    for mine, theirs in zip(handed, patrolled, strict=True):
        np.testing.assert_array_equal(mine, theirs)
    seeded = patrol_route(plan, 10.0, seed=2)
    n = min(len(seeded), len(handed[0]))
    assert n >= 10
    assert not np.array_equal(handed[0][:n, 1:3], seeded[:n, 1:3])
    s = json.loads((out / "summary.json").read_text())
    assert s["duplicate_poses"] == 0


def test_a_zmq_team_with_a_prior_gives_the_simulated_teams_results(tmp_path: Path) -> None:
    """The nodes take the prior the launcher hands them (``team node --prior``): the
    same stores and figures as the simulated team given the same prior, and not those
    of a team given the plan (here the stores match either way; the alignment error
    tells the runs apart)."""
    plan = builtin_plan("building:0")
    prior, report = degrade_plan(plan, parse_prior_error("close-doors=2,scale=0.03", seed=1))
    assert len(report.doors_closed) == 2
    cfg = replace(CONFIG, duration=10.0)
    full, ex = NetworkParams(kind="full"), ExchangeParams()
    sim = run_team(plan, cfg, 2, network=full, exchange=ex, seed=3, prior=prior)
    exact = run_team(plan, cfg, 2, network=full, exchange=ex, seed=3)
    z = run_zmq_team(
        plan, cfg, 2, exchange=ex, seed=3, folder=tmp_path / "zmq", prior=prior, timeout=300.0
    )
    assert z.summary["store_digests"] == [store_digest(r.store) for r in sim.robots]
    rows = zip(z.summary["robots"], sim.summary["robots"], exact.summary["robots"], strict=True)
    for zr, sr, er in rows:
        for key in ("map_f1", "ate_m", "alignment_error_m", "poses_local", "poses_made"):
            assert zr[key] == pytest.approx(sr[key]), key
        # The global map is placed in the prior's frame and scored against the plan.
        assert zr["alignment_error_m"] != pytest.approx(er["alignment_error_m"])
