"""Patrol and team runs recorded as ROS 2 bags (read back with rosbags) and served live
over the Foxglove WebSocket protocol (answered by a client on 127.0.0.1)."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import websockets
import yaml
from rosbags.highlevel import AnyReader

from sonarmap.cli import main
from sonarmap.grid import Grid
from sonarmap.io.record import Recorder, make_recorder, trinary
from sonarmap.io.rosmap import OccupancyMap, read_map, write_map
from sonarmap.patrol import PatrolConfig, Territory, run_patrol
from sonarmap.patrol.publish import PatrolPublisher, robot_frame, territory_levels
from sonarmap.scenarios import Scenario

#: The SDK's server takes the protocol under its new name; Foxglove offers both.
SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]
TIMEOUT = 20.0


def _plan(tmp_path: Path) -> Path:
    """A 40 x 30 m floor with a wall across the middle, two robots' start file."""
    g = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(300, 400))
    occ = np.zeros(g.shape, np.float32)
    occ[140:160, 100:300] = 1.0
    write_map(OccupancyMap(g, occ), tmp_path / "plan")
    (tmp_path / "starts.txt").write_text("2\n50 50 0\n350 250 0\n")
    return tmp_path / "plan.yaml"


def _grid_values(msg: Any) -> np.ndarray[Any, np.dtype[np.int8]]:
    """An OccupancyGrid's data as sonarmap's arrays hold it (row 0 at the top)."""
    data = np.asarray(msg.data, dtype=np.int8).reshape(msg.info.height, msg.info.width)
    return data[::-1]


def _read(bag: Path) -> dict[str, list[tuple[int, Any]]]:
    out: dict[str, list[tuple[int, Any]]] = {}
    with AnyReader([bag]) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out


def test_patrol_run_records_a_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = _plan(tmp_path)
    out = tmp_path / "run"
    args = ["patrol", "run", "--map", str(plan), "--starts", str(tmp_path / "starts.txt")]
    main([*args, "--duration", "20", "--network", "limited", "--bag", "-o", str(out)])
    assert "bag/" in capsys.readouterr().out
    meta = yaml.safe_load((out / "bag" / "metadata.yaml").read_text())
    assert meta["rosbag2_bagfile_information"]["storage_identifier"] == "mcap"
    with AnyReader([out / "bag"]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
    assert types["/map"] == types["/fog"] == "nav_msgs/msg/OccupancyGrid"
    assert types["/tf"] == "tf2_msgs/msg/TFMessage"
    assert types["/robot0/path"] == "nav_msgs/msg/Path"
    assert types["/network"] == "visualization_msgs/msg/MarkerArray"
    assert types["/mtb"] == "std_msgs/msg/Float64"
    msgs = _read(out / "bag")
    territory = Territory.from_map(read_map(plan), cell=PatrolConfig().cell)
    [(_, grid)] = msgs["/map"]
    np.testing.assert_array_equal(_grid_values(grid), territory_levels(territory))
    assert grid.info.resolution == pytest.approx(territory.grid.resolution)
    # 40 steps of 0.5 s: one pose per robot per step, stamped in simulated time.
    steps = 40
    per_robot: Counter[str] = Counter()
    for t, msg in msgs["/tf"]:
        for tr in msg.transforms:
            assert tr.header.frame_id == "map"
            per_robot[tr.child_frame_id] += 1
            assert tr.header.stamp.sec + 1e-9 * tr.header.stamp.nanosec == pytest.approx(t * 1e-9)
    assert per_robot == {robot_frame(0): steps, robot_frame(1): steps}
    assert [t for t, _ in msgs["/tf"]][-1] == 20 * 10**9
    # The fog at its lower rate (every 5 s), scaled 0-100, -1 where not watched.
    assert len(msgs["/fog"]) == 4
    fog = _grid_values(msgs["/fog"][-1][1])
    assert fog.max() == 100
    assert set(np.unique(fog[~territory.free]).tolist()) == {-1}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == steps


def test_patrol_bad_fog_rate_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = _plan(tmp_path)
    out = tmp_path / "run"
    args = ["patrol", "run", "--map", str(plan), "--robots", "1", "--duration", "5"]
    with pytest.raises(SystemExit) as e:
        main([*args, "--bag", "--fog-every", "0", "-o", str(out)])
    assert e.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not out.exists()


def test_recorder_due_gates_a_slower_topic() -> None:
    rec = Recorder()
    assert not rec
    due = [t for t in np.arange(0.0, 10.0, 0.5).tolist() if rec.due("fog", t, 2.0)]
    assert due == [0.0, 2.0, 4.0, 6.0, 8.0]


# --- live ----------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def _watch(port: int, want: set[str], deadline: float) -> dict[str, Any]:
    """Connect, take serverInfo and the advertised channels, subscribe to ``want`` and
    collect one message of each; every wait bounded by ``deadline``."""
    seen: dict[str, Any] = {"channels": {}, "data": {}}
    uri = f"ws://127.0.0.1:{port}"
    ws: Any = None
    while ws is None:
        try:
            ws = await websockets.connect(uri, subprotocols=SUBPROTOCOLS, open_timeout=2)  # type: ignore[arg-type]
        except (OSError, websockets.exceptions.InvalidHandshake):
            # Not listening yet, or still starting.
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    async with ws:
        subscribed: dict[int, str] = {}
        while set(seen["data"]) != want:
            left = deadline - time.monotonic()
            assert left > 0, f"timed out: {sorted(seen['data'])} of {sorted(want)}"
            frame = await asyncio.wait_for(ws.recv(), left)
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "serverInfo":
                    seen["serverInfo"] = msg
                elif msg["op"] == "status" and "Unknown channel" in msg.get("message", ""):
                    # The SDK can refuse a subscription sent just as it advertises the
                    # channel: ask again, under a new subscription id.
                    await asyncio.sleep(0.2)
                    channel = int(msg["message"].rsplit(":", 1)[1])
                    topic = next(t for t, c in seen["channels"].items() if c["id"] == channel)
                    sid = len(subscribed) + 1
                    subscribed[sid] = topic
                    sub = {"id": sid, "channelId": channel}
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [sub]}))
                elif msg["op"] == "advertise":
                    subs = []
                    for ch in msg["channels"]:
                        seen["channels"][ch["topic"]] = ch
                        if ch["topic"] in want and ch["topic"] not in subscribed.values():
                            sid = len(subscribed) + 1
                            subscribed[sid] = ch["topic"]
                            subs.append({"id": sid, "channelId": ch["id"]})
                    if subs:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif frame[0] == 1:  # messageData: opcode, subscription id, log time, payload
                sid, log_time = struct.unpack_from("<IQ", frame, 1)
                seen["data"].setdefault(subscribed[sid], (log_time, bytes(frame[13:])))
    return seen


def test_a_live_patrol_answers_a_foxglove_client(tmp_path: Path) -> None:
    plan = _plan(tmp_path)
    territory = Territory.from_map(read_map(plan), cell=0.5)
    config = PatrolConfig(duration=60.0)
    want = {"/map", "/tf", "/fog", "/network"}
    result: dict[str, Any] = {}
    # Paced at 10x real time: the run lasts 6 s, long enough for the client to join.
    with make_recorder(live_port=0, live_rate=10.0) as rec:
        assert rec.url is not None
        port = int(rec.url.rsplit(":", 1)[1])
        publisher = PatrolPublisher(rec, territory, config)

        def run() -> None:
            run_patrol(territory, config, robots=2, seed=1, on_step=publisher)
            result["steps"] = publisher.steps

        worker = threading.Thread(target=run, daemon=True)
        worker.start()
        seen = asyncio.run(_watch(port, want, time.monotonic() + TIMEOUT))
        worker.join(TIMEOUT)
    assert not worker.is_alive()
    assert result["steps"] == 120
    assert seen["serverInfo"]["name"] == "sonarmap"
    assert seen["channels"]["/map"]["schemaName"] == "nav_msgs/msg/OccupancyGrid"
    assert seen["channels"]["/map"]["encoding"] == "cdr"
    assert seen["channels"]["/tf"]["schemaEncoding"] == "ros2msg"
    assert set(seen["data"]) == want


def test_patrol_run_live_serves_on_the_port_given(tmp_path: Path) -> None:
    """The command as a user runs it: its own process (so the client here does not
    share an interpreter with the run), a free port on 127.0.0.1."""
    plan = _plan(tmp_path)
    port = _free_port()
    out = tmp_path / "run"
    args = ["patrol", "run", "--map", str(plan), "--robots", "2", "--duration", "40"]
    args += ["--live", "--live-port", str(port), "--live-rate", "4", "-o", str(out)]
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    with subprocess.Popen(
        [sys.executable, "-m", "sonarmap", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    ) as run:
        try:
            seen = asyncio.run(_watch(port, {"/map", "/tf"}, time.monotonic() + 90.0))
            said, _ = run.communicate(timeout=90.0)
        finally:
            if run.poll() is None:
                run.kill()
    assert run.returncode == 0
    assert f"live: ws://127.0.0.1:{port}" in said
    assert "serverInfo" in seen
    assert {"/map", "/fog", "/tf"} <= set(seen["channels"])
    assert (out / "summary.json").exists()
    assert not (out / "bag").exists()


# --- team ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def floor() -> OccupancyMap:
    from sonarmap.scenarios import office
    from sonarmap.sensors import Noise

    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


def test_team_run_records_a_bag(
    tmp_path: Path, floor: OccupancyMap, capsys: pytest.CaptureFixture[str]
) -> None:
    write_map(floor, tmp_path / "plan")
    out = tmp_path / "out"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--duration", "20",
          "--bag", "--map-every", "5", "-o", str(out)])  # fmt: skip
    assert "bag/ (2 files)" in capsys.readouterr().out
    meta = yaml.safe_load((out / "bag" / "metadata.yaml").read_text())
    assert meta["rosbag2_bagfile_information"]["storage_identifier"] == "mcap"
    msgs = _read(out / "bag")
    [(_, grid)] = msgs["/map"]
    np.testing.assert_array_equal(_grid_values(grid), trinary(floor.classes()))
    assert len(msgs["/robot0/map"]) >= 4  # every 5 s of 20, and the final one
    assert all(len(m.transforms) == 1 for _, m in msgs["/tf"])
    assert len(msgs["/tf"]) == len(msgs["/bytes_sent"])


def test_team_publisher_sends_each_robots_map(tmp_path: Path, floor: OccupancyMap) -> None:
    from sonarmap.io.record import BagSink
    from sonarmap.team.exchange import ExchangeParams
    from sonarmap.team.mission import MissionConfig
    from sonarmap.team.network import NetworkParams
    from sonarmap.team.publish import TeamPublisher, global_map_now
    from sonarmap.team.publish import robot_frame as team_frame
    from sonarmap.team.simulation import run_team

    with Recorder([BagSink(tmp_path / "bag")]) as rec:
        pub = TeamPublisher(rec, floor, map_every=5.0)
        team = run_team(floor, MissionConfig(duration=20.0), 2, network=NetworkParams(),
                        exchange=ExchangeParams(), seed=0, on_tick=pub)  # fmt: skip
        pub.finish()
    msgs = _read(tmp_path / "bag")
    for k, agent in enumerate(team.agents):
        last = msgs[f"/robot{k}/map"][-1][1]
        held = global_map_now(agent)
        np.testing.assert_array_equal(_grid_values(last), trinary(held.classes()))
        assert (last.info.width, last.info.height) == (held.grid.cols, held.grid.rows)
        graph = msgs[f"/robot{k}/graph"][-1][1]
        poses = [m for m in graph.markers if m.ns == "poses"]
        assert len(poses[0].points) == len(agent.store.local.poses)
    # One pose per robot per tick in /tf, at the tick's time.
    children: Counter[str] = Counter()
    for _, msg in msgs["/tf"]:
        children.update(tr.child_frame_id for tr in msg.transforms)
    assert children == {team_frame(0): pub.ticks, team_frame(1): pub.ticks}
    assert msgs["/bytes_sent"][-1][1].data == sum(e.stats.bytes_sent for e in team.exchangers)


# --- stream --------------------------------------------------------------------------


def test_stream_live_serves_the_mapping_topics(doorways: Scenario, tmp_path: Path) -> None:
    doorways.write(tmp_path / "scene")
    d = tmp_path / "scene"
    port = _free_port()
    args = ["stream", str(d / "readings.csv"), "--rig", str(d / "rig.yaml")]
    args += ["--like", str(d / "truth.yaml"), "--method", "inverse", "--animation", ""]
    # 20 s of log at 4x: 5 s of serving.
    args += ["--live", "--live-port", str(port), "--live-rate", "4", "-o", str(tmp_path / "out")]
    worker = threading.Thread(target=main, args=(args,), daemon=True)
    worker.start()
    want = {"/map", "/tf", "/tf_static"}
    seen = asyncio.run(_watch(port, want, time.monotonic() + 60.0))
    worker.join(60.0)
    assert not worker.is_alive()
    assert seen["channels"]["/map"]["schemaName"] == "nav_msgs/msg/OccupancyGrid"
    assert any(t.startswith("/sonar/") for t in seen["channels"])
    assert set(seen["data"]) == want
    assert (tmp_path / "out" / "map.yaml").exists()
    assert not (tmp_path / "out" / "bag").exists()


def test_shipped_layouts_are_the_generated_ones() -> None:
    from sonarmap.io.layouts import LAYERS, layout

    folder = Path(__file__).parents[1] / "docs" / "layouts"
    for name in LAYERS:
        text = (folder / f"{name}.json").read_text()
        assert text == layout(name), f"docs/layouts/{name}.json: run write_layouts again"
        topics = json.loads(text)["content"]["items"][0]["content"]["config"]["topics"]
        assert "/map" in topics


def test_a_live_team_answers_a_foxglove_client(floor: OccupancyMap) -> None:
    from sonarmap.team.exchange import ExchangeParams
    from sonarmap.team.mission import MissionConfig
    from sonarmap.team.network import NetworkParams
    from sonarmap.team.publish import TeamPublisher
    from sonarmap.team.simulation import run_team

    want = {"/map", "/tf", "/robot0/map", "/robot1/graph", "/bytes_sent"}
    with make_recorder(live_port=0, live_rate=5.0) as rec:
        assert rec.url is not None
        port = int(rec.url.rsplit(":", 1)[1])
        pub = TeamPublisher(rec, floor, map_every=2.0)

        def run() -> None:
            run_team(floor, MissionConfig(duration=20.0), 2, network=NetworkParams(),
                     exchange=ExchangeParams(), seed=0, on_tick=pub)  # fmt: skip

        worker = threading.Thread(target=run, daemon=True)
        worker.start()
        # The team's set-up (world, robots, first tick) takes a while on a busy machine.
        seen = asyncio.run(_watch(port, want, time.monotonic() + 120.0))
        worker.join(120.0)
    assert not worker.is_alive()
    assert seen["channels"]["/robot0/map"]["schemaName"] == "nav_msgs/msg/OccupancyGrid"
    assert seen["channels"]["/bytes_sent"]["schemaName"] == "std_msgs/msg/Float64"
    assert set(seen["data"]) == want


def test_the_live_server_takes_the_subprotocol_the_guide_names() -> None:
    """docs/guides/live-view.md: a client offering ``foxglove.sdk.v1``, or only the
    spec's ``foxglove.websocket.v1``, gets serverInfo, the advertised channels and
    their data; one offering neither is refused with HTTP 400."""
    from sonarmap.io.live import LiveSink
    from sonarmap.io.rosmsg import FLOAT, float_message, serialize

    async def session(uri: str, offer: list[str]) -> Any:
        """(subprotocol chosen, first op, topics advertised, payload of /figure), or
        the HTTP status of a refusal; publishes until the data comes, within 10 s."""
        async with asyncio.timeout(10):
            try:
                ws = await websockets.connect(uri, subprotocols=offer, open_timeout=5)  # type: ignore[arg-type]
            except websockets.exceptions.InvalidStatus as err:
                return err.response.status_code
            async with ws:
                first = json.loads(await ws.recv())["op"]
                advertised = json.loads(await ws.recv())
                assert advertised["op"] == "advertise"
                [channel] = [c for c in advertised["channels"] if c["topic"] == "/figure"]
                sub = {"id": 7, "channelId": channel["id"]}
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [sub]}))
                for k in range(100):  # the sink sends on publish only: publish until seen
                    sink.publish("/figure", FLOAT, float_message(2.5), t=float(k))
                    try:
                        frame = await asyncio.wait_for(ws.recv(), 0.1)
                    except TimeoutError:
                        continue
                    if isinstance(frame, bytes) and frame[0] == 1:
                        assert struct.unpack_from("<I", frame, 1) == (7,)
                        return (
                            ws.subprotocol,
                            first,
                            [c["topic"] for c in advertised["channels"]],
                            frame[13:],
                        )
                raise AssertionError("no data after 100 messages")

    port = _free_port()
    sink = LiveSink(port=port, rate=None)
    try:
        assert sink.url == f"ws://127.0.0.1:{port}"
        sink.declare("/figure", FLOAT)
        want = serialize(float_message(2.5), FLOAT)
        # The name chosen: the one offered, the SDK's when both are.
        for offer, chosen in [
            (["foxglove.websocket.v1"], "foxglove.websocket.v1"),
            (["foxglove.sdk.v1"], "foxglove.sdk.v1"),
            (SUBPROTOCOLS, "foxglove.sdk.v1"),
        ]:
            got = asyncio.run(session(sink.url, offer))
            assert got == (chosen, "serverInfo", ["/figure"], want), offer
        assert asyncio.run(session(sink.url, ["chat"])) == 400
    finally:
        sink.close()


def test_a_busy_live_port_is_one_line_and_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = _plan(tmp_path)
    out = tmp_path / "run"
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        args = ["patrol", "run", "--map", str(plan), "--robots", "1", "--duration", "5"]
        with pytest.raises(SystemExit) as e:
            main([*args, "--bag", "--live", "--live-port", str(port), "-o", str(out)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert f"cannot serve on 127.0.0.1:{port}" in err
    assert not out.exists()
