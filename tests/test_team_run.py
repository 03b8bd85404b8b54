"""``sonarmap team run`` with a team (exchange, central bound, patrol routes), the naive
baseline and the patroller's routes (short runs)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sonarmap.cli import main
from sonarmap.io.rosmap import OccupancyMap, write_map
from sonarmap.patrol.simulation import run_patrol
from sonarmap.patrol.starts import random_starts
from sonarmap.patrol.territory import Territory
from sonarmap.scenarios import office
from sonarmap.sensors import Noise
from sonarmap.team.exchange import ExchangeParams
from sonarmap.team.mission import MissionConfig
from sonarmap.team.naive import decode_pose_message, encode_pose_message
from sonarmap.team.network import NetworkParams
from sonarmap.team.patrolling import patrol_config, patrol_routes
from sonarmap.team.records import Landmarks, Pose, encode, make_uid
from sonarmap.team.simulation import TeamResult, run_team
from sonarmap.team.wire import ExchangeError
from sonarmap.team.world import builtin_plan


@pytest.fixture(scope="module")
def plan() -> OccupancyMap:
    return office(duration=1.0, rate=1.0, model=Noise(), resolution=0.1).truth


def test_a_patrolling_team_run_writes_the_team_summary(tmp_path: Path, plan: OccupancyMap) -> None:
    write_map(plan, tmp_path / "plan")
    out = tmp_path / "out"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--robots", "2",
          "--duration", "30", "--patrol", "-o", str(out)])  # fmt: skip
    s = json.loads((out / "summary.json").read_text())
    assert s["robots_n"] == 2
    assert s["duplicate_poses"] == 0
    assert s["identical_maps"] is True  # full network, good protocol by default
    assert s["exchange"]["mode"] == "good"
    assert s["preset"] == "lean"  # a team's default
    assert s["convergence_s"] is not None
    assert s["convergence_s"] >= 0
    assert s["bytes_per_robot_minute"] > 0
    assert 0 < s["map_f1_central"] <= 1
    assert s["map_f1_team"] == pytest.approx(np.mean([r["map_f1"] for r in s["robots"]]))
    for key in ("ate_m", "map_f1", "association_precision"):
        assert key in s
    for row in s["robots"]:
        for key in ("bytes_sent", "bytes_received", "messages", "poses_local", "poses_received"):
            assert row[key] > 0
        # A robot's map fuses the others' poses too, which its own readings at the true
        # poses (map_f1_true_poses) leave out: the bound it is scored beside holds them.
        assert row["map_poses_held"] == row["poses_local"] + row["poses_received"]
        assert row["map_f1"] <= row["map_f1_held_true_poses"] + 0.02
    for name in ("team.png", "map_central.yaml", "map_robot1.yaml", "graph_robot0.png"):
        assert (out / name).stat().st_size > 0


def test_a_team_runs_the_lean_exchange_by_default(tmp_path: Path, plan: OccupancyMap) -> None:
    write_map(plan, tmp_path / "plan")
    out = tmp_path / "out"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--robots", "2",
          "--duration", "40", "-o", str(out)])  # fmt: skip
    s = json.loads((out / "summary.json").read_text())
    assert s["preset"] == "lean"
    ex = s["exchange"]
    assert (ex["anchor_every"], ex["anchor_share"], ex["hold"]) == (12, 0.15, 30.0)
    assert (ex["descriptor_bits"], ex["ternary_maps"]) == (3, True)
    assert (ex["advert_every"], ex["full_advert_every"]) == (10.0, 60.0)
    assert ex["send_closures"] is True
    assert s["robots"][0]["parameters"]["store"]["merge_on_closure"] == 8
    assert s["duplicate_poses"] == 0
    assert s["identical_maps"] is True  # everything is published when the routes end
    assert all(r["poses_received"] > 0 for r in s["robots"])


@pytest.mark.parametrize(
    ("args", "preset", "want"),
    [
        # The thesis's settings, by name.
        (["--preset", "classic"], "classic", (1, 0.0, 0.0, 8, False, 0, False, False)),
        # Options given under the default preset win over it; the rest stays lean.
        (["--anchors", "4", "--no-fold"], "lean", (4, 0.15, 30.0, 3, True, 8, False, True)),
        (["--no-send-closures"], "lean", (12, 0.15, 30.0, 3, True, 8, True, False)),
        # One robot and the naive baseline get no preset unless they name one: the
        # exchange's and the store's defaults (the store folds by default).
        (["--exchange", "naive"], None, (1, 0.0, 0.0, 8, False, 0, True, False)),
    ],
)
def test_presets_and_the_options_given_under_them(
    tmp_path: Path,
    plan: OccupancyMap,
    args: list[str],
    preset: str | None,
    want: tuple[object, ...],
) -> None:
    write_map(plan, tmp_path / "plan")
    out = tmp_path / "out"
    main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--robots", "2",
          "--duration", "10", *args, "-o", str(out)])  # fmt: skip
    s = json.loads((out / "summary.json").read_text())
    ex, store = s["exchange"], s["robots"][0]["parameters"]["store"]
    got = (ex["anchor_every"], ex["anchor_share"], ex["hold"], ex["descriptor_bits"],
           ex["ternary_maps"], store["merge_on_closure"], store["fold"],
           ex["send_closures"])  # fmt: skip
    assert s["preset"] == preset
    assert got == want


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--robots", "0"], "--robots"),
        (["--loss", "1.5"], "--loss"),
        (["--network", "mesh"], "--network"),
        (["--exchange", "gossip"], "--exchange"),
        (["--cap", "0"], "--cap"),
        (["--bandwidth", "-1"], "--bandwidth"),
        (["--budget", "-1"], "--budget"),
        (["--anchors", "0"], "--anchors"),
        (["--hold", "-5"], "--hold"),
        (["--hold", "nan"], "--hold"),
        (["--descriptor-bits", "0"], "--descriptor-bits"),
        (["--lean", "--anchors", "4"], "--lean"),
        (["--lean", "--fold"], "--lean"),
        (["--lean", "--anchors", "1"], "--anchors"),  # a default given is still given
        (["--lean", "--loop-anchors"], "--loop-anchors"),
        (["--lean", "--no-send-closures"], "drop --send-closures"),
        (["--lean", "--merge-on-closure", "0"], "--merge-on-closure"),
        (["--merge-on-closure", "-1"], "--merge-on-closure"),
        (
            ["--anchors", "1", "--anchor-share", "0.2"],
            "--anchor-share: exchange: anchor_share needs anchor_every > 1",
        ),
        (["--anchors", "8", "--anchor-share", "2"], "--anchor-share"),
        (["--lean", "--anchor-share", "0.1"], "--anchor-share"),
        (["--anchors", "1", "--anchor-share", "0", "--loop-anchors"], "--anchors K > 1"),
        (["--lean", "--exchange", "naive"], "--lean"),
        (["--descriptor-bits", "9"], "--descriptor-bits"),
        (["--range", "0", "--network", "limited"], "--link-range: network parameter 'r_max'"),
        (["--link-range", "0", "--network", "limited"], "--link-range"),
        (["--range", "10"], "--link-range is the limited network's"),
        (["--transport", "pigeon"], "--transport"),
        (["--preset", "fast"], "--preset must be one of classic, lean"),
        (["--lean", "--preset", "classic"], "--lean is --preset lean"),
        (["--preset", "lean", "--anchors", "4"], "--preset lean sets"),
        (["--preset", "classic", "--hold", "5"], "--preset classic sets"),
        (["--preset", "lean", "--exchange", "naive"], "--preset lean"),
        # Under the default lean preset --anchors 1 leaves its anchor share without anchors.
        (["--anchors", "1"], "under the default --preset lean"),
        (["--patrol", "--route", "r.csv"], "--patrol"),
    ],
)
def test_bad_team_options_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    with pytest.raises(SystemExit) as e:
        main(["team", "run", "--map", str(tmp_path / "plan.yaml"), "--robots", "2",
              "--duration", "20", *args, "-o", str(tmp_path / "out")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2
    assert message in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_built_in_plans_by_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    office = builtin_plan("office")
    assert office.grid.shape == (200, 200)
    assert (office.classes() == 1).any()
    assert (office.classes() == 0).any()
    a, b = builtin_plan("building:7"), builtin_plan("building:7")
    np.testing.assert_array_equal(a.classes(), b.classes())
    assert not np.array_equal(a.classes(), builtin_plan("building:8").classes())
    with pytest.raises(SystemExit) as e:
        main(["team", "run", "--map", "building:x", "--duration", "20",
              "-o", str(tmp_path / "out")])  # fmt: skip
    assert e.value.code == 2
    assert "building:x: no such file, nor a built-in map; built-ins: open-field" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "out").exists()


def test_patrol_routes_follow_the_patrollers_trajectories(plan: OccupancyMap) -> None:
    routes, _ = patrol_routes(plan, 2, 30.0, seed=4)
    cfg = patrol_config(30.0)
    territory = Territory.from_map(plan, cell=cfg.cell)
    starts = random_starts(2, territory, territory.passable(cfg.radius), cfg.min_separation, 4)
    seen: list[np.ndarray] = []
    run_patrol(
        territory,
        cfg,
        starts=starts,
        seed=4,
        on_step=lambda t, team, fog: seen.append(np.column_stack([team.x, team.y])),
    )
    free = plan.classes() == 0
    for i, r in enumerate(routes):
        assert r.shape == (61, 4)
        np.testing.assert_allclose(r[:, 0], np.arange(61) * 0.5)
        np.testing.assert_array_equal(r[0, 1:3], starts[i, :2])
        np.testing.assert_array_equal(r[1:, 1:3], np.array([s[i] for s in seen]))
        rows, cols = plan.grid.world_to_cell(r[:, 1], r[:, 2])
        assert free[rows, cols].all()
        # The heading is that of the last move.
        d = np.diff(r[:, 1:3], axis=0)
        moved = np.hypot(d[:, 0], d[:, 1]) > 0
        assert moved.sum() > 10
        np.testing.assert_allclose(
            r[1:, 3][moved], np.arctan2(d[moved, 1], d[moved, 0]), atol=1e-12
        )


def _team(plan: OccupancyMap, exchange: ExchangeParams, routes: list[np.ndarray]) -> TeamResult:
    return run_team(
        plan,
        MissionConfig(duration=20.0, seed=1),
        2,
        network=NetworkParams(kind="full"),
        exchange=exchange,
        seed=3,
        routes=routes,
    )


def test_the_naive_baseline_sends_every_new_pose_to_everyone(plan: OccupancyMap) -> None:
    routes, _ = patrol_routes(plan, 2, 20.0, seed=1)
    naive = _team(plan, ExchangeParams(mode="naive"), routes)
    for i, (r, e) in enumerate(zip(naive.robots, naive.exchangers, strict=True)):
        # The robots drove the routes given.
        on_route = {tuple(p) for p in routes[i][:, 1:3].tolist()}
        assert {tuple(t[:2].tolist()) for t in r.truth.values()} <= on_route
        other = naive.robots[1 - i].store.received[i].poses
        assert set(other) >= set(r.store.local.poses)
        # One message per pose and peer, nothing else, each the pose's whole record
        # (deflated: a local map shrinks, descriptors hardly do).
        assert len(other) == e.stats.poses_sent == e.stats.messages_sent
        assert len(other) >= len(r.store.local.poses)
        records = sum(len(encode(p)) for p in other.values())
        descriptors = sum(p.landmarks.descriptors.nbytes for p in other.values())
        assert descriptors <= e.stats.bytes_sent < records
    assert naive.summary["duplicate_poses"] == 0


def test_naive_messages_are_checked_whole() -> None:
    lm = Landmarks.empty(8)
    pose = Pose(make_uid(1, 0), 0.0, 0, np.zeros(3), lm)
    body = encode_pose_message(pose, [])
    assert decode_pose_message(body, 1)[0].uid == pose.uid
    with pytest.raises(ExchangeError, match="not robot 2's"):
        decode_pose_message(body, 2)
    with pytest.raises(ExchangeError) as e:
        decode_pose_message(body[:-3], 1)
    assert e.value.code == "truncated"
    with pytest.raises(ExchangeError, match="region"):
        decode_pose_message(body, 1, regions={5})


def test_every_run_reports_its_share_of_the_naive_baselines_bytes(plan: OccupancyMap) -> None:
    routes, _ = patrol_routes(plan, 2, 20.0, seed=1)
    naive = _team(plan, ExchangeParams(mode="naive"), routes).summary
    assert naive["share_of_naive"] == 1.0
    assert naive["naive_bytes_per_robot_minute"] == naive["bytes_per_robot_minute_all"]
    good = _team(plan, ExchangeParams(), routes).summary
    estimate = good["naive_bytes_per_robot_minute"]
    # The same routes and poses: the estimate is the baseline's bytes up to the estimates
    # the robots' other closures move, a few per cent.
    assert estimate == pytest.approx(naive["bytes_per_robot_minute_all"], rel=0.05)
    assert good["share_of_naive"] == pytest.approx(good["bytes_per_robot_minute_all"] / estimate)


def test_the_naive_meter_prices_what_the_baseline_sends() -> None:
    from sonarmap.team.naive import NaiveExchanger, NaiveMeter
    from sonarmap.team.network import SimNetwork
    from sonarmap.team.records import OdometryEdge
    from sonarmap.team.store import RobotStore
    from sonarmap.team.transport import SimHub

    stores = [RobotStore(r) for r in range(3)]
    meter = NaiveMeter(stores[0])
    hub = SimHub(SimNetwork(NetworkParams(kind="full"), 3))
    ex = [NaiveExchanger(s, hub.transport(s.robot)) for s in stores]
    cov = tuple(float(v) for v in np.eye(3).ravel() * 1e-4)
    for k in range(5):
        pose = Pose(make_uid(0, k), float(k), 0, np.array([k, 0.0, 0.0]), Landmarks.empty(8))
        edge = None if k == 0 else OdometryEdge(make_uid(0, k - 1), pose.uid, (1.0, 0, 0), cov, 5.0)
        stores[0].add_own_pose(pose, edge, [], float(k))
        hub.step(0.5)
        for e in ex:
            e.step(hub.now)
        meter.step(2)
    assert meter.poses == 5
    assert meter.bytes == ex[0].stats.bytes_sent > 0
    assert ex[0].stats.poses_sent == 10
    # Sent poses are shared: the store's fold leaves them as the peers got them.
    assert all(stores[0].shared(u) for u in stores[0].local.poses)


def test_the_naive_meter_prices_a_folded_pose_with_its_map_as_made() -> None:
    from dataclasses import replace

    from sonarmap.team.naive import NaiveMeter
    from sonarmap.team.records import LocalMap
    from sonarmap.team.store import RobotStore

    store = RobotStore(0)
    small = LocalMap(np.zeros((20, 20), dtype=np.int8), 0.1)
    made = Pose(make_uid(0, 0), 0.0, 0, np.zeros(3), Landmarks.empty(8), small)
    store.add_own_pose(made, None, [], 0.0)
    rng = np.random.default_rng(0)
    folded = LocalMap(rng.integers(-100, 100, (20, 20)).astype(np.int8), 0.1)
    store.local.put_pose(replace(made, local_map=folded), 0.0)  # as a fold leaves it
    plain, as_made = NaiveMeter(store), NaiveMeter(store, {made.uid: made})
    plain.step(1)
    as_made.step(1)
    assert as_made.bytes == len(encode_pose_message(made, []))
    assert plain.bytes == len(encode_pose_message(store.local.poses[made.uid], []))
    assert plain.bytes > as_made.bytes + 200


def test_the_naive_meter_leaves_out_poses_merged_at_closures() -> None:
    from sonarmap.team.naive import NaiveMeter
    from sonarmap.team.store import RobotStore

    store = RobotStore(0)
    meter, strict = NaiveMeter(store), NaiveMeter(store, merged=False)
    made = [Pose(make_uid(0, k), float(k), 0, np.zeros(3), Landmarks.empty(8)) for k in range(2)]
    for p in made:
        store.add_own_pose(p, None, [], p.time)
    merged = Pose(make_uid(0, 1 << 39), 2.0, 0, np.zeros(3), Landmarks.empty(8), None, (0, 1))
    store.local.put_pose(merged, 2.0)
    for m in (meter, strict):
        m.step(1)
    # The baseline's store merges only under compression: it sends the two made poses.
    assert strict.poses == 2
    assert strict.bytes == sum(len(encode_pose_message(p, [])) for p in made)
    assert meter.poses == 3
    assert meter.bytes == strict.bytes + len(encode_pose_message(merged, []))
