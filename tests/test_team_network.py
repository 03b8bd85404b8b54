"""The team's simulated network: links (full, limited with range and line of sight,
none), relaying along chains, bandwidth buckets and their changing capacity, losses,
broken links and counters that add up, all deterministic given the seed."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.patrol.network import components
from sonarmap.team.network import Delivery, NetworkParams, SimNetwork

GRID = Grid(resolution=1.0, origin=(0.0, 0.0), shape=(100, 200))


def _open() -> npt.NDArray[np.bool_]:
    return np.ones(GRID.shape, dtype=bool)


def _limited(
    xy: list[tuple[float, float]],
    clear: npt.NDArray[np.bool_] | None = None,
    seed: int = 0,
    **kw: object,
) -> SimNetwork:
    params = NetworkParams(kind="limited", r_max=70.0, **kw)  # type: ignore[arg-type]
    net = SimNetwork(
        params, len(xy), seed=seed, clear=_open() if clear is None else clear, grid=GRID
    )
    net.update(0.0, np.array(xy, dtype=float))
    return net


def _invariant(net: SimNetwork) -> None:
    s = net.stats
    dropped = s.dropped_lost.sum() + s.dropped_link_broken.sum()
    assert s.messages_sent.sum() == s.messages_received.sum() + dropped + net.in_flight


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("kind", "mesh"),
        ("r_max", 0.0),
        ("bandwidth", -5.0),
        ("bandwidth", math.inf),
        ("bandwidth_min_factor", 0.0),
        ("bandwidth_min_factor", 1.5),
        ("bandwidth_period", 0.0),
        ("burst", -1.0),
        ("loss", 1.2),
        ("loss", math.nan),
        ("delay", -0.1),
        ("jitter", "1"),
        ("relay", "yes"),
        ("max_message", 0),
        ("max_message", 10.5),
    ],
)
def test_every_parameter_is_checked_and_named(name: str, value: object) -> None:
    with pytest.raises(ConfigError, match=f"'{name}'"):
        NetworkParams(**{name: value})  # type: ignore[arg-type]


def test_full_and_none_networks() -> None:
    full = SimNetwork(NetworkParams(kind="full"), 3)
    assert full.links().tolist() == [[0, 1], [0, 2], [1, 2]]
    assert full.send(0.0, 0, 2, b"hi")
    (d,) = full.deliver(0.0)
    assert (d.src, d.dst, d.payload, d.hops, d.arrived) == (0, 2, b"hi", 1, 0.0)
    none = SimNetwork(NetworkParams(kind="none"), 3)
    assert none.links().shape == (0, 2)
    assert none.reachable(0) == []
    assert not none.send(0.0, 0, 1, b"hi")
    assert none.stats.dropped_unroutable.tolist() == [1, 0, 0]
    assert none.stats.messages_sent.sum() == 0
    with pytest.raises(ConfigError, match="prior map"):
        SimNetwork(NetworkParams(kind="limited"), 2)


def test_a_chain_relays_only_with_relay() -> None:
    xy = [(10.0, 50.0), (60.0, 50.0), (110.0, 50.0)]  # 50 m apart: 0-1 and 1-2, not 0-2
    net = _limited(xy, relay=True)
    assert net.links().tolist() == [[0, 1], [1, 2]]
    assert net.neighbours(0) == [1]
    assert net.reachable(0) == [1, 2]
    assert net.send(0.0, 0, 2, b"x" * 10)
    (d,) = net.deliver(1.0)
    assert (d.src, d.dst, d.hops) == (0, 2, 2)
    assert net.stats.bytes_relayed.tolist() == [0, 10, 0]
    assert net.stats.bytes_received.tolist() == [0, 0, 10]

    direct = _limited(xy, relay=False)
    assert direct.reachable(0) == [1]
    assert not direct.send(0.0, 0, 2, b"x")
    assert direct.send(0.0, 0, 1, b"x")
    assert [d.dst for d in direct.deliver(1.0)] == [1]


def test_relay_takes_a_shortest_chain() -> None:
    # A ring of five within range of its two neighbours: 0 -> 2 goes through 1, 0 -> 3
    # through 4 (two hops both ways round would be three).
    ang = np.arange(5) * 2 * np.pi / 5
    xy = [(100 + 45 * math.cos(a), 50 + 45 * math.sin(a)) for a in ang]  # sides 52.9 m
    net = _limited(xy)
    assert len(net.links()) == 5
    for dst, hops in ((2, 2), (3, 2), (1, 1)):
        assert net.send(0.0, 0, dst, b"m")
        (d,) = net.deliver(0.0)
        assert d.hops == hops
    assert net.stats.bytes_relayed.tolist() == [0, 1, 0, 0, 1]


def test_a_wall_blocks_a_limited_link_and_reachability_matches_patrol() -> None:
    clear = _open()
    clear[:, 50] = False  # a wall down x = 50..51 m
    clear[:10, 50] = True  # with a gap at the top (y = 90..100 m)
    xy = [(30.0, 50.0), (70.0, 50.0), (30.0, 95.0), (70.0, 95.0), (20.0, 30.0)]
    net = _limited(xy, clear)
    links = {tuple(p) for p in net.links().tolist()}
    assert (0, 1) not in links  # 40 m apart, but the wall is between them
    assert (2, 3) in links  # they see each other through the gap
    x, y = np.array(xy).T
    lab = components("limited", x, y, clear=clear, grid=GRID, r_max=70.0)
    for i in range(len(xy)):
        same = [j for j in range(len(xy)) if j != i and lab[j] == lab[i]]
        assert net.reachable(i) == same
    # Moving robot 1 in front of the gap opens a chain 0 - 2 - 3 - 1.
    net.update(1.0, np.array([*xy[:1], (70.0, 90.0), *xy[2:]]))
    assert net.reachable(0) == [1, 2, 3, 4]


def test_bandwidth_delays_a_message_by_size_over_bandwidth() -> None:
    net = SimNetwork(NetworkParams(bandwidth=1000.0, delay=0.25), 3)
    assert net.send(2.0, 0, 1, b"a" * 5000)  # 5 s on the link, then 0.25 s
    assert net.send(2.0, 0, 1, b"b" * 1000)  # queued behind it
    assert net.send(2.0, 0, 2, b"c" * 1000)  # another link: not held up by them
    (c,) = net.deliver(7.2)
    assert c.payload[:1] == b"c"
    assert c.arrived == pytest.approx(3.25)
    (a,) = net.deliver(7.25)
    assert (a.payload[:1], a.arrived) == (b"a", 7.25)
    (b,) = net.deliver(10.0)
    assert b.payload[:1] == b"b"
    assert b.arrived == pytest.approx(8.25)
    assert net.deliver(20.0) == []


def test_deliveries_come_in_arrival_order() -> None:
    net = SimNetwork(NetworkParams(bandwidth=1000.0, delay=0.25), 3)
    net.send(2.0, 0, 1, b"a" * 5000)
    net.send(2.0, 0, 1, b"b" * 1000)
    net.send(2.0, 2, 1, b"c" * 1000)
    out = net.deliver(20.0)
    assert [d.payload[:1] for d in out] == [b"c", b"a", b"b"]
    assert [d.arrived for d in out] == pytest.approx([3.25, 7.25, 8.25])
    assert all(isinstance(d, Delivery) for d in out)


def test_store_and_forward_pays_bandwidth_on_every_hop() -> None:
    net = _limited([(10.0, 50.0), (60.0, 50.0), (110.0, 50.0)], bandwidth=500.0, delay=0.1)
    net.send(0.0, 0, 2, b"x" * 1000)
    (d,) = net.deliver(10.0)
    assert d.arrived == pytest.approx(2 * (1000 / 500 + 0.1))


def test_a_burst_lets_a_small_message_leave_at_once() -> None:
    net = SimNetwork(NetworkParams(bandwidth=100.0, burst=400.0), 2)
    net.send(0.0, 0, 1, b"x" * 300)  # paid from the full bucket
    net.send(0.0, 0, 1, b"y" * 300)  # 100 left: waits 2 s for the rest
    assert [d.arrived for d in net.deliver(5.0)] == pytest.approx([0.0, 2.0])
    net.send(100.0, 0, 1, b"z" * 1000)  # the bucket refilled to 400 while idle
    (d,) = net.deliver(200.0)
    assert d.arrived == pytest.approx(106.0)


def _stepped(t0: float, need: float, rate: float, period: float) -> float:
    """When a link of constant ``rate`` has carried ``need`` bytes from t0, paid period
    by period as the network paid it before the closed form."""
    t, k = t0, math.floor(t0 / period)
    while True:
        end = (k + 1) * period
        if t + need / rate <= end:
            return t + need / rate
        need -= rate * max(0.0, end - t)
        t, k = max(t, end), k + 1


def test_a_constant_rate_delivers_when_stepping_period_by_period_did() -> None:
    p = NetworkParams(bandwidth=210.0, bandwidth_period=0.1, delay=0.0)
    net = SimNetwork(p, 2)
    rng = np.random.default_rng(3)
    sends = sorted(rng.uniform(0.0, 50.0, 12))
    sizes = rng.integers(1, 5000, 12)
    want, free = [], -math.inf
    for t, size in zip(sends, sizes, strict=True):
        assert net.send(float(t), 0, 1, b"x" * int(size))
        free = _stepped(max(float(t), free), float(size), 210.0, 0.1)
        want.append(free)
    got = [d.arrived for d in net.deliver(1e4)]
    assert got == pytest.approx(want, rel=1e-12, abs=1e-9)
    assert len(got) == 12


def test_a_message_a_varying_link_cannot_carry_within_the_horizon_never_arrives() -> None:
    """Its schedule is stepped through MAX_PERIODS periods at most, not for hours."""
    from sonarmap.team.network import MAX_PERIODS

    p = NetworkParams(bandwidth=1e-6, bandwidth_min_factor=0.5, bandwidth_period=1.0)
    net = SimNetwork(p, 2, seed=1)
    assert net.send(0.0, 0, 1, b"x" * 1000)  # 10^9 s at the best factor
    assert net.send(1.0, 0, 1, b"y")  # behind it, on a link busy for good
    assert net.deliver(10.0 * MAX_PERIODS) == []
    ok = SimNetwork(replace(p, bandwidth=1000.0), 2, seed=1)
    assert ok.send(0.0, 0, 1, b"x" * 1000)
    (d,) = ok.deliver(10.0)
    assert 1.0 <= d.arrived <= 2.0  # at factors in [0.5, 1]


def test_capacity_changes_over_time_and_sets_arrival_times() -> None:
    p = NetworkParams(bandwidth=1000.0, bandwidth_min_factor=0.2, bandwidth_period=2.0)
    net = SimNetwork(p, 3, seed=4)
    caps = [net.capacity(t, 0, 1) for t in np.arange(0.0, 40.0, 0.5)]
    per_period = np.array(caps).reshape(-1, 4)
    assert (per_period == per_period[:, :1]).all()  # constant within a period
    assert len(np.unique(per_period[:, 0])) == len(per_period)  # changes between them
    assert 200.0 <= min(caps) < max(caps) <= 1000.0
    assert net.capacity(1.0, 1, 0) == net.capacity(1.0, 0, 1)
    assert net.capacity(1.0, 0, 2) != net.capacity(1.0, 0, 1)
    # The same factors whatever is asked first, for the same seed only.
    other = SimNetwork(p, 3, seed=4)
    assert [other.capacity(t, 0, 1) for t in np.arange(39.5, -0.5, -0.5)] == caps[::-1]
    assert SimNetwork(p, 3, seed=5).capacity(0.0, 0, 1) != caps[0]
    # A 4000-byte message from t = 1 finishes when the integrated capacity reaches 4000.
    net.send(1.0, 0, 1, b"x" * 4000)
    (d,) = net.deliver(100.0)
    t, left = 1.0, 4000.0
    while left > 0:
        end = (math.floor(t / 2.0) + 1) * 2.0
        rate = net.capacity(t, 0, 1)
        t, left = (
            (t + left / rate, 0.0) if t + left / rate <= end else (end, left - rate * (end - t))
        )
    assert d.arrived == pytest.approx(t)
    constant = SimNetwork(NetworkParams(bandwidth=1000.0), 2)
    assert {constant.capacity(t, 0, 1) for t in range(50)} == {1000.0}


def _lossy_run(seed: int, n: int = 4000, p: float = 0.3) -> list[int]:
    net = SimNetwork(NetworkParams(loss=p, delay=0.01, jitter=0.02), 2, seed=seed)
    for k in range(n):
        assert net.send(k * 0.01, k % 2, 1 - k % 2, b"m")
    out = net.deliver(1e6)
    assert net.stats.dropped_lost.sum() + len(out) == n
    _invariant(net)
    return [d.id for d in out]


def test_loss_rate_is_close_to_p_and_reruns_are_identical() -> None:
    ids = _lossy_run(seed=11)
    assert abs(len(ids) / 4000 - 0.7) < 0.03  # 0.7 +- 4 sigma (sigma 0.0072)
    assert _lossy_run(seed=11) == ids
    assert _lossy_run(seed=12) != ids


def test_loss_applies_on_every_hop() -> None:
    net = _limited([(10.0, 50.0), (60.0, 50.0), (110.0, 50.0)], seed=3, loss=0.2)
    for k in range(3000):
        net.send(float(k), 0, 2, b"m")
    got = len(net.deliver(1e6))
    assert abs(got / 3000 - 0.8**2) < 0.035
    _invariant(net)


def test_jitter_keeps_a_links_order() -> None:
    net = SimNetwork(NetworkParams(delay=0.1, jitter=1.0), 2, seed=0)
    for k in range(200):
        net.send(k * 0.01, 0, 1, k.to_bytes(2, "big"))
    out = net.deliver(100.0)
    assert [int.from_bytes(d.payload, "big") for d in out] == list(range(200))
    assert len({d.arrived - d.sent for d in out}) > 100  # the delays do vary


def test_a_broken_link_drops_what_waits_on_it() -> None:
    net = _limited([(10.0, 50.0), (60.0, 50.0)], bandwidth=100.0)
    for _ in range(3):
        assert net.send(0.0, 0, 1, b"x" * 100)  # leave at 1, 2 and 3 s
    assert net.send(0.0, 1, 0, b"y" * 250)  # the other direction: leaves at 2.5 s
    net.update(1.5, np.array([[10.0, 50.0], [150.0, 50.0]]))  # robot 1 out of range
    assert net.links().shape == (0, 2)
    assert [d.payload[:1] for d in net.deliver(10.0)] == [b"x"]
    assert net.stats.dropped_link_broken.tolist() == [2, 1]
    assert net.in_flight == 0
    assert not net.send(10.0, 0, 1, b"z")
    _invariant(net)
    # The link comes back with a fresh bucket and an empty queue.
    net.update(20.0, np.array([[10.0, 50.0], [60.0, 50.0]]))
    net.send(20.0, 0, 1, b"w" * 100)
    (d,) = net.deliver(30.0)
    assert d.arrived == pytest.approx(21.0)
    # They met twice and parted once, each counted at both robots.
    assert net.stats.links_made.tolist() == [2, 2]
    assert net.stats.links_broken.tolist() == [1, 1]


def test_a_relay_with_no_way_on_drops_the_message() -> None:
    xy = [(10.0, 50.0), (60.0, 50.0), (110.0, 50.0)]
    net = _limited(xy, delay=1.0)
    net.send(0.0, 0, 2, b"x")  # reaches robot 1 at t = 1
    net.update(0.5, np.array([*xy[:2], (190.0, 50.0)]))  # robot 2 leaves meanwhile
    assert net.deliver(5.0) == []
    assert net.stats.dropped_link_broken.tolist() == [1, 0, 0]
    _invariant(net)


def test_counters_add_up_over_a_random_mission() -> None:
    rng = np.random.default_rng(7)
    p = NetworkParams(
        kind="limited",
        bandwidth=2000.0,
        bandwidth_min_factor=0.3,
        bandwidth_period=1.0,
        loss=0.1,
        delay=0.05,
        jitter=0.05,
        max_message=3000,
    )
    runs = []
    for _ in range(2):
        net = SimNetwork(p, 6, seed=21, clear=_open(), grid=GRID)
        xy = np.random.default_rng(1).uniform((0, 0), (200, 100), (6, 2))
        got: list[Delivery] = []
        rng = np.random.default_rng(7)
        for step in range(200):
            t = step * 0.1
            xy = np.clip(xy + rng.normal(0, 3.0, xy.shape), (0, 0), (199, 99))
            net.update(t, xy)
            for _ in range(3):
                src, dst = rng.choice(6, 2, replace=False)
                net.send(t, int(src), int(dst), b"p" * int(rng.integers(1, 4000)))
            got += net.deliver(t)
            _invariant(net)
        got += net.deliver(1e3)
        s = net.stats
        assert net.in_flight == 0
        assert s.messages_received.sum() == len(got)
        assert s.bytes_received.sum() == sum(len(d.payload) for d in got)
        assert s.dropped_oversized.sum() > 0
        assert s.dropped_unroutable.sum() > 0
        assert s.dropped_lost.sum() > 0
        assert s.dropped_link_broken.sum() > 0
        for r in range(6):
            mine = [d for d in got if d.src == r]
            assert s.messages_sent[r] == len(mine) + s.dropped_lost[r] + s.dropped_link_broken[r]
            assert s.bytes_sent[r] >= sum(len(d.payload) for d in mine)
        assert [(d.arrived, d.id) for d in got] == sorted((d.arrived, d.id) for d in got)
        runs.append([(d.id, d.arrived, d.hops) for d in got])
    assert runs[0] == runs[1]


def test_bad_calls_are_input_errors() -> None:
    net = SimNetwork(NetworkParams(max_message=10), 2)
    net.update(5.0, np.zeros((2, 2)))
    with pytest.raises(InputError, match="time goes back"):
        net.send(4.0, 0, 1, b"x")
    with pytest.raises(InputError, match="field 'xy'"):
        net.update(6.0, np.zeros((3, 2)))
    with pytest.raises(InputError, match="field 'dst'"):
        net.send(6.0, 0, 2, b"x")
    with pytest.raises(InputError, match="itself"):
        net.send(6.0, 1, 1, b"x")
    assert not net.send(6.0, 0, 1, b"x" * 11)
    assert net.stats.as_dict(0)["dropped_oversized"] == 1
