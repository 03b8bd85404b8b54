"""Streaming: the strategies' bounds, the engines against the offline objective, replay."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sonarmap.api import build_map
from sonarmap.cli import main
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.mappers import GradientMapper, make_mapper
from sonarmap.mappers._pool import ReadingPool
from sonarmap.mappers._thrun import index_arrays
from sonarmap.mappers._thrun_common import posterior
from sonarmap.mappers.em_thrun import ThrunEMMapper, ThrunEMStream
from sonarmap.mappers.gradient import STEP, GradientStream, _stream_steps, stream_step_sizes
from sonarmap.metrics import agreement, score
from sonarmap.raster import rasterise
from sonarmap.readings import Readings, write_readings
from sonarmap.rig import save_rig
from sonarmap.scenarios import Scenario, make_scenario
from sonarmap.selection import (
    FreshestPerCell,
    KeepAll,
    LastN,
    PoseGrid,
    parse_strategy,
)
from sonarmap.streaming import StreamingMapper, replay, time_batches


def _cells_of(sc: Scenario, readings: Readings, offset: float = 0.0) -> list[set[int]]:
    fp = rasterise(
        sc.truth.grid,
        sc.rig.sensor,
        readings.x,
        readings.y,
        readings.theta,
        readings.range,
        offset=offset,
    )
    return [set(fp.free.of(i).tolist()) | set(fp.occ.of(i).tolist()) for i in range(len(readings))]


# -- strategies ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "kind"),
    [
        ("last:5", LastN),
        ("cell:2", FreshestPerCell),
        ("pose:3:0.25:45", PoseGrid),
        ("all", KeepAll),
    ],
)
def test_strategy_text_round_trip(text: str, kind: type) -> None:
    s = parse_strategy(text)
    assert isinstance(s, kind)
    assert parse_strategy(s.spec()).spec() == s.spec()


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("last", "unknown strategy"),
        ("last:0", "needs a count >= 1, got 0"),
        ("cell:-2", "needs a count >= 1, got -2"),
        ("cell:x", "must be numbers"),
        ("pose:1:-1", "pose bin size must be > 0 m"),
        ("window:3", "unknown strategy"),
        ("all:2", "unknown strategy"),
    ],
)
def test_bad_strategies_are_config_errors(text: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_strategy(text)


def test_freshest_per_cell_keeps_exactly_the_readings_some_cell_needs(doorways: Scenario) -> None:
    """Against a brute-force reading of the rule: a reading is in play iff it is among
    the N latest readings of at least one of its cells."""
    r = doorways.readings.take(np.arange(0, 600))
    n_max = 2
    sm = StreamingMapper("gradient", doorways.truth.grid, doorways.rig, strategy=f"cell:{n_max}")
    for a in range(0, len(r), 37):
        sm.add(r.take(np.arange(a, min(a + 37, len(r)))))
    cells = _cells_of(doorways, r, sm.engine.offset)
    latest: dict[int, list[int]] = {}
    for i, cs in enumerate(cells):
        for c in cs:
            latest.setdefault(c, []).append(i)
    wanted = set()
    for ids in latest.values():
        wanted.update(ids[-n_max:])
    assert sm.n_in_play == len(wanted)
    # The pool holds exactly those readings' footprints.
    pool = sm.engine.pool
    alive = pool.alive_slots()
    got = sorted(
        sorted(pool.cell[pool.f_start[s] : pool.f_start[s] + pool.f_len[s] + pool.o_len[s]])
        for s in alive
    )
    want = sorted(sorted(cells[i]) for i in wanted)
    assert got == want


def test_last_n_and_pose_grid_bound_the_readings(doorways: Scenario) -> None:
    r = doorways.readings
    for text, bound in (("last:150", 150), ("pose:2:0.5:90", None)):
        sm = StreamingMapper("gradient", doorways.truth.grid, doorways.rig, strategy=text)
        for a in range(0, len(r), 50):
            sm.add(r.take(np.arange(a, min(a + 50, len(r)))))
            if bound is not None:
                assert sm.n_in_play <= bound
        if bound is None:
            s = sm.strategy
            assert isinstance(s, PoseGrid)
            assert sm.n_in_play <= 2 * s.n_bins
            assert sm.n_in_play < len(r)
        else:
            assert sm.n_in_play == bound


def test_pool_compaction_keeps_footprints(doorways: Scenario) -> None:
    r = doorways.readings.take(np.arange(400))
    g, s = doorways.truth.grid, doorways.rig.sensor
    fp = rasterise(g, s, r.x, r.y, r.theta, r.range)
    pool = ReadingPool(g.cols, sort_band=True)
    slots = pool.add(fp, r.range, r.range < s.r_max)
    rng = np.random.default_rng(1)
    gone = rng.choice(slots, 300, replace=False)
    pool.remove(gone[:150])
    pool.remove(gone[150:])
    pool.compact()
    keep = np.setdiff1d(slots, gone)
    assert pool.n_alive == len(keep)
    assert pool.n_entries == pool.end
    index = {int(sl): i for i, sl in enumerate(slots)}
    f_cells, f_off, b_cells, b_dist, b_off = pool.gather(keep)
    for k, sl in enumerate(keep):
        i = index[int(sl)]
        assert sorted(f_cells[f_off[k] : f_off[k + 1]]) == sorted(fp.free.of(i).tolist())
        band = b_dist[b_off[k] : b_off[k + 1]]
        assert np.all(np.diff(band) >= 0)  # kept sorted by distance
        assert sorted(b_cells[b_off[k] : b_off[k + 1]]) == sorted(fp.occ.of(i).tolist())


def test_pool_sums_and_boxes_follow_each_reading(doorways: Scenario) -> None:
    # Three batches, with removals between, so slots are reused and entries land after
    # dead ones: each slot's weight sums and bounding box are its own reading's.
    r = doorways.readings.take(np.arange(600))
    g, s = doorways.truth.grid, doorways.rig.sensor
    pool = ReadingPool(g.cols)
    for a in (0, 200, 400):
        part = r.take(np.arange(a, a + 200))
        fp = rasterise(g, s, part.x, part.y, part.theta, part.range)
        slots = pool.add(fp, part.range, part.range < s.r_max)
        for i, sl in enumerate(slots):
            free, occ = fp.free, fp.occ
            fw = free.weight[free.offsets[i] : free.offsets[i + 1]]
            ow = occ.weight[occ.offsets[i] : occ.offsets[i + 1]]
            assert pool.f_sum[sl] == pytest.approx(float(fw.sum(dtype=np.float64)), rel=1e-12)
            assert pool.o_sum[sl] == pytest.approx(float(ow.sum(dtype=np.float64)), rel=1e-12)
            cells = np.concatenate([free.of(i), occ.of(i)])
            rows, cols = np.divmod(cells, g.cols)
            if len(cells):
                assert pool.box[sl].tolist() == [rows.min(), rows.max(), cols.min(), cols.max()]
        pool.remove(slots[::3])


# -- engines -----------------------------------------------------------------------------


def test_inverse_stream_with_all_readings_is_the_offline_map(doorways: Scenario) -> None:
    sm = StreamingMapper("inverse", doorways.truth.grid, doorways.rig, strategy="all")
    replay([doorways.readings], sm, period=0.3)
    offline = build_map(doorways.readings, doorways.rig, doorways.truth.grid, "inverse")
    np.testing.assert_array_equal(sm.occupancy_, offline.occupancy)


def test_windowed_inverse_sums_the_readings_in_play(doorways: Scenario) -> None:
    r = doorways.readings
    n = 120
    sm = StreamingMapper(
        "inverse", doorways.truth.grid, doorways.rig, strategy=f"last:{n}", falloff_deg=0.0
    )
    replay([r], sm, period=0.5)
    last = r.take(np.arange(len(r) - n, len(r)))
    values = np.zeros(doorways.truth.grid.size)
    touched = np.zeros(doorways.truth.grid.size, bool)
    mapper = make_mapper("inverse")
    dr = mapper.get_params()["dr"]
    offset = mapper.band_offset_for(doorways.truth.grid)
    lf, lo_ = math.log(0.46 / 0.54), math.log(0.52 / 0.48)
    from sonarmap.raster import accumulate

    accumulate(
        doorways.truth.grid,
        doorways.rig.sensor,
        last.x,
        last.y,
        last.theta,
        last.range,
        values,
        touched,
        inc_free=lf,
        inc_occ=lo_,
        dr=dr,
        offset=offset,
    )
    lo, hi = math.log(0.12 / 0.88), math.log(0.97 / 0.03)
    want = 1 / (1 + np.exp(-np.clip(values, lo, hi)))
    got = sm.occupancy_.ravel()
    assert mapper.get_params()["p_free"] == 0.46
    assert mapper.get_params()["p_occ"] == 0.52
    assert offset == pytest.approx(0.0375)
    np.testing.assert_allclose(got[touched], want[touched], atol=1e-6)


def test_gradient_stream_step_is_the_offline_gradient(doorways: Scenario) -> None:
    """Terms added to the stream give, at the cells they step, the offline objective's
    gradient of the P terms: W^T P'(W x)."""
    g, rig = doorways.truth.grid, doorways.rig
    r = doorways.readings.take(np.arange(300))
    mapper = GradientMapper()
    engine = mapper.stream(g, rig, LastN(10_000))
    assert isinstance(engine, GradientStream)
    engine.add(r.take(np.arange(150)))
    engine.add(r.take(np.arange(150, 300)))
    problem = mapper.start(g, rig).problem(r)
    rng = np.random.default_rng(0)
    x_local = rng.uniform(0.0, 1.0, problem.n_cells)
    want_g = np.asarray(problem.WT @ problem.term_slopes(problem.W @ x_local))
    p = engine.pool
    x = np.full(g.size, 0.5)
    x[problem.cells] = x_local
    step = 1e-4
    _stream_steps(
        p.alive_slots(),
        *p.span_terms(),
        x,
        np.zeros(g.size),
        problem.cells,
        engine.cov,
        np.zeros(g.size, np.int32),
        mapper.a1,
        mapper.a2,
        stream_step_sizes(step),
        1,
        np.zeros((p.capacity, 2)),
        np.full((p.capacity, 2), -np.inf),
        np.zeros(1),
    )
    want_x = np.clip(x_local - step * want_g, 0.0, 1.0)
    np.testing.assert_allclose(x[problem.cells], want_x, atol=1e-9)
    assert STEP["pgd"] == 0.05


def test_gradient_stream_agrees_with_offline_and_memory_is_bounded(doorways: Scenario) -> None:
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    sm = StreamingMapper("gradient", g, rig, strategy="last:200")
    rep = replay([r], sm, period=0.5)
    offline = build_map(r, rig, g, "gradient")
    agree, n = agreement(sm.result(), offline)
    assert n > 0.3 * g.size
    assert agree > 0.97
    # Streaming the log twice over (a robot driving the corridor again) keeps the state.
    size_once = rep.max_state_bytes
    again = Readings.concat(
        [r, Readings(r.t + r.t[-1] + 1, r.sensor, r.x, r.y, r.theta, r.range, r.names)]
    )
    sm2 = StreamingMapper("gradient", g, rig, strategy="last:200")
    rep2 = replay([again], sm2, period=0.5)
    assert rep2.max_in_play == rep.max_in_play == 200
    assert rep2.max_state_bytes <= 1.1 * size_once


def test_gradient_finish_brings_the_stream_to_the_offline_plain_map(doorways: Scenario) -> None:
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    # The stream leaves the robust form out, so its offline counterpart is the plain model.
    offline = make_mapper("gradient", robust=0.0).fit(r, g, rig).result()
    # Folding, so that the objective in play stands in for the whole log's.
    sm = StreamingMapper("gradient", g, rig, strategy="last:200", fold=True)
    rep = replay([r], sm, period=0.5, finish=False)
    assert rep.finish_units == 0
    before, n = agreement(sm.result(), offline)
    held, size = sm.n_in_play, sm.nbytes()
    assert sm.finish(100) == 100
    after, n_after = agreement(sm.result(), offline)
    assert n_after == n
    # The passes take the agreement from 99.20 % to 99.40 % (measured).
    assert after > before + 0.001
    assert after > 0.99
    assert (sm.n_in_play, sm.nbytes()) == (held, size)
    # replay finishes by default, with the same passes.
    sm2 = StreamingMapper("gradient", g, rig, strategy="last:200", fold=True)
    assert replay([r], sm2, period=0.5).finish_units == 100
    np.testing.assert_array_equal(sm2.occupancy_, sm.occupancy_)
    inv = StreamingMapper("inverse", g, rig)
    assert replay([r], inv, period=0.5).finish_units == 0


def test_gradient_stream_folds_only_when_no_echo_readings_clear(doorways: Scenario) -> None:
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    part = r.take(np.arange(400))
    maps = {}
    for no_echo, fold in (("ignore", None), ("free", None), ("ignore", True)):
        sm = StreamingMapper("gradient", g, rig, strategy="last:100", no_echo=no_echo, fold=fold)
        e = sm.engine
        assert isinstance(e, GradientStream)
        replay([part], sm, period=0.5, finish=False)
        assert e.fold == (no_echo == "free" or fold is True)
        # Folding leaves the readings that left in a fixed gradient; forgetting does not.
        assert np.any(e.fixed != 0.0) == e.fold
        maps[no_echo, fold] = sm.occupancy_
    assert not np.array_equal(maps["ignore", None], maps["ignore", True], equal_nan=True)
    assert StreamingMapper("em-thrun", g, rig).engine.fold


def test_the_shipped_default_forgets_and_finishes(doorways: Scenario) -> None:
    """The gradient stream as shipped: no-echo readings ignored, readings that leave
    forgotten, replay ending with finish(); the finish is timed and moves the map."""
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    sm = StreamingMapper("gradient", g, rig, strategy="last:200")
    assert sm.engine.fold is False
    rep = replay([r], sm, period=0.5)
    assert rep.finish_units == 100
    assert rep.summary()["finish_seconds"] == round(rep.finish_time, 3) > 0
    assert rep.finish_time <= rep.wall_time
    assert isinstance(sm.engine, GradientStream)
    assert not np.any(sm.engine.fixed)
    by_hand = StreamingMapper("gradient", g, rig, strategy="last:200")
    replay([r], by_hand, period=0.5, finish=False)
    unfinished = by_hand.occupancy_
    assert by_hand.finish(100) == 100
    np.testing.assert_array_equal(by_hand.occupancy_, sm.occupancy_)
    seen = ~np.isnan(unfinished)
    assert np.abs(sm.occupancy_[seen] - unfinished[seen]).max() > 0.01


def test_a_stop_skips_or_cuts_the_finish(doorways: Scenario) -> None:
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    part = r.take(np.arange(600))
    # Asked only once the whole log is in: the finish is skipped, the replay interrupted.
    sm = StreamingMapper("gradient", g, rig, strategy="last:200")
    rep = replay([part], sm, period=0.5, stop=lambda: sm.n_readings == len(part))
    assert (rep.n_readings, rep.finish_units, rep.interrupted) == (len(part), 0, True)
    # Asked during the finish: it stops between passes.
    asked = 0

    def after_seven_passes() -> bool:
        nonlocal asked
        if sm2.n_readings < len(part):
            return False
        asked += 1
        return asked > 7

    sm2 = StreamingMapper("gradient", g, rig, strategy="last:200")
    rep = replay([part], sm2, period=0.5, stop=after_seven_passes)
    assert (rep.finish_units, rep.interrupted) == (7, True)


@pytest.mark.parametrize("passes", [-1, 1.5, True, "100"])
def test_finish_refuses_passes_that_are_not_a_count(doorways: Scenario, passes: object) -> None:
    sm = StreamingMapper("gradient", doorways.truth.grid, doorways.rig, strategy="last:50")
    with pytest.raises(ConfigError, match="finish passes must be an integer >= 0"):
        sm.finish(passes)  # type: ignore[arg-type]
    assert sm.finish(0) == 0


def test_fold_is_fixed_at_construction_and_only_for_methods_that_fold(
    doorways: Scenario,
) -> None:
    g, rig = doorways.truth.grid, doorways.rig
    sm = StreamingMapper("gradient", g, rig, strategy="last:50", fold=True)
    assert sm.engine.fold is True
    with pytest.raises(AttributeError):
        sm.engine.fold = False  # type: ignore[misc]
    for method in ("inverse", "stochastic"):
        with pytest.raises(ConfigError, match=f"streaming '{method}' cannot fold"):
            StreamingMapper(method, g, rig, fold=False)
        assert StreamingMapper(method, g, rig).engine.fold is False


def test_gradient_stream_memory_counts_its_per_cell_arrays(doorways: Scenario) -> None:
    """The state grows by what the gradient stream keeps per cell: its map, gradient
    and folded evidence (float64), step count (int32), and the base engine's coverage
    (int32), seen and dirty marks (bool) and dirty list (int64): 42 bytes a cell."""
    rig, r = doorways.rig, doorways.readings.take(np.arange(300))
    sizes = []
    g0 = doorways.truth.grid
    for pad in (0, 40):
        g = Grid(g0.resolution, g0.origin, (g0.shape[0] + pad, g0.shape[1] + pad))
        sm = StreamingMapper("gradient", g, rig, strategy="last:100")
        replay([r], sm, period=0.5, finish=False)
        sizes.append((g.size, sm.nbytes(), sm.engine.pool.nbytes()))
    (n0, b0, p0), (n1, b1, p1) = sizes
    assert (b1 - p1) - (b0 - p0) >= 42 * (n1 - n0)


def test_em_thrun_stream_keeps_the_offline_map_in_bounded_memory(doorways: Scenario) -> None:
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    offline = score(doorways.truth, build_map(r, rig, g, "em-thrun")).f1_all
    held: list[int] = []
    sm = StreamingMapper("em-thrun", g, rig, strategy="last:200")
    rep = replay([r], sm, period=0.25, on_update=lambda _b, s: held.append(s.n_in_play))
    streamed = score(doorways.truth, sm.result()).f1_all
    assert offline > 0.2
    assert streamed >= 0.9 * offline
    assert max(held) == rep.max_in_play == 200
    # Forgetting the readings that leave instead of folding them in loses the walls.
    forgetful = StreamingMapper("em-thrun", g, rig, strategy="last:200", fold=False)
    replay([r], forgetful, period=0.25)
    assert score(doorways.truth, forgetful.result()).f1_all < 0.9 * offline
    # The log twice over: the readings held and the state stay where they were.
    again = Readings.concat(
        [r, Readings(r.t + r.t[-1] + 1, r.sensor, r.x, r.y, r.theta, r.range, r.names)]
    )
    sm2 = StreamingMapper("em-thrun", g, rig, strategy="last:200")
    rep2 = replay([again], sm2, period=0.25)
    assert rep2.max_in_play == 200
    assert rep2.max_state_bytes <= 1.1 * rep.max_state_bytes


def test_em_thrun_fold_is_the_posterior_of_the_leaving_readings(doorways: Scenario) -> None:
    """Folded a reading at a time from the store, the leaving readings' votes are each
    cell's log posterior odds over an index of just those readings, the map held."""
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    sm = StreamingMapper("em-thrun", g, rig, strategy="last:200")
    replay([r.take(np.arange(600))], sm)
    e, m = sm.engine, sm.mapper
    assert isinstance(e, ThrunEMStream)
    assert isinstance(m, ThrunEMMapper)
    p = e.pool
    gone = p.alive_slots()
    f_cells, f_off, b_cells, b_dist, b_off = p.gather(gone)
    ix = index_arrays(f_cells, f_off, b_cells, b_dist, b_off, p.z[gone], e.offset)
    arrays = ix.posterior_arrays()
    model = (m.p_rand, m.p_hit, e.sigma, e.sensor.r_max)
    want = np.zeros(g.size)
    want[ix.cells] = posterior(e.occ[ix.cells], arrays, *model)
    assert e.occ.sum() > 50
    assert np.abs(want).max() > 10
    before = e.bias.copy()
    e._leave(gone)
    np.testing.assert_allclose(e.bias - before, want, atol=1e-9)


def test_em_thrun_index_from_the_store_is_the_gathered_index(doorways: Scenario) -> None:
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    sm = StreamingMapper("em-thrun", g, rig, strategy="last:200")
    replay([r.take(np.arange(700))], sm)
    e = sm.engine
    assert isinstance(e, ThrunEMStream)
    p = e.pool
    # Every third slot: slots out of order with the arena, some cells shared, some not.
    sel = p.alive_slots()[::3]
    f_cells, f_off, b_cells, b_dist, b_off = p.gather(sel)
    want = index_arrays(f_cells, f_off, b_cells, b_dist, b_off, p.z[sel], e.offset)
    got = e.index(sel)
    assert got.n_cells > 100
    for name in ("free_off", "free_cell", "band_off", "band_cell", "band_dist", "cell_off"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    for name in ("cell_reading", "cell_kind", "cell_slot", "z", "cells"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))


def test_em_thrun_stream_is_deterministic_and_refuses_the_inverse_start(
    doorways: Scenario,
) -> None:
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    part = r.take(np.arange(300))
    maps = []
    for _ in range(2):
        sm = StreamingMapper("em-thrun", g, rig, strategy="last:100")
        replay([part], sm, period=0.25)
        maps.append(sm.occupancy_)
    np.testing.assert_array_equal(maps[0], maps[1])
    with pytest.raises(ConfigError, match="init=free"):
        StreamingMapper("em-thrun", g, rig, init="inverse")


def test_stochastic_stream_is_deterministic_and_finds_walls(doorways: Scenario) -> None:
    g, rig, r = doorways.truth.grid, doorways.rig, doorways.readings
    maps = []
    for _ in range(2):
        sm = StreamingMapper("stochastic", g, rig, strategy="last:300", effort=2)
        replay([r], sm, period=0.5)
        maps.append(sm.occupancy_)
    np.testing.assert_array_equal(maps[0], maps[1])
    truth = doorways.truth.classes() == 1
    found = OccupancyMap(g, maps[0]).classes() == 1
    known = OccupancyMap(g, maps[0]).classes() != -1
    # Its occupied cells are walls far more often than cells it knows are.
    share = truth[known].mean()
    assert (found & truth).sum() > 3 * share * found.sum()


def test_streaming_refuses_what_it_cannot_bound(doorways: Scenario) -> None:
    g, rig = doorways.truth.grid, doorways.rig
    with pytest.raises(ConfigError, match="no streaming mode"):
        StreamingMapper("em", g, rig)
    with pytest.raises(ConfigError, match="bounded strategy"):
        StreamingMapper("gradient", g, rig, strategy="all")
    with pytest.raises(ConfigError, match="fall-off"):
        StreamingMapper("inverse", g, rig, strategy="last:5", falloff_deg=10.0)
    with pytest.raises(ConfigError, match="no_echo_reach"):
        StreamingMapper(
            "inverse", g, rig, strategy="last:5", falloff_deg=0.0, no_echo="free", no_echo_reach=1.0
        )
    sm = StreamingMapper("gradient", g, rig)
    bad = doorways.readings.take(np.arange(3))
    bad = Readings(
        bad.t, bad.sensor, bad.x, bad.y, bad.theta, np.array([1.0, np.nan, 1.0]), bad.names
    )
    with pytest.raises(ConfigError, match="reading 1"):
        sm.add(bad)


# -- replay ------------------------------------------------------------------------------


def test_time_batches_cut_by_log_time(doorways: Scenario) -> None:
    r = doorways.readings
    chunks = [r.take(np.arange(a, min(a + 97, len(r)))) for a in range(0, len(r), 97)]
    batches = list(time_batches(chunks, 0.5))
    assert sum(len(b) for b in batches) == len(r)
    t0 = r.t[0]
    for b in batches:
        k = np.floor((b.t - t0) / 0.5)
        assert np.all(k == k[0])
    assert len({float(np.floor((b.t[0] - t0) / 0.5)) for b in batches}) == len(batches)


def test_replay_snapshots_and_realtime_pace(doorways: Scenario) -> None:
    r = doorways.readings.take(np.flatnonzero(doorways.readings.t < 4.0))
    sm = StreamingMapper("gradient", doorways.truth.grid, doorways.rig, strategy="last:100")
    times: list[float] = []
    rep = replay(
        [r],
        sm,
        period=0.25,
        realtime=True,
        speed=8.0,
        snapshot_every=1.0,
        on_snapshot=lambda t, s: times.append(t),
    )
    span = float(r.t[-1] - r.t[0])
    assert rep.wall_time >= span / 8.0 - 0.05
    assert rep.improve_units > 0  # the idle time went into improving the map
    assert times[0] >= 1.0
    assert len(times) >= 4
    assert times[-1] == pytest.approx(span)


def test_replay_stops_when_asked_and_warns_when_behind(doorways: Scenario) -> None:
    r = doorways.readings.take(np.flatnonzero(doorways.readings.t < 6.0))
    sm = StreamingMapper("gradient", doorways.truth.grid, doorways.rig, strategy="last:100")
    rep = replay([r], sm, period=0.25, stop=lambda: sm.n_readings >= 50)
    assert rep.interrupted
    assert 50 <= rep.n_readings < len(r)
    assert rep.summary()["interrupted"] is True
    # Slower than the log on purpose: every update waits 0.2 s against 0.25 s of log
    # at 8x speed, so the lag grows and is reported, then reported again once doubled.
    warnings: list[str] = []
    slow = StreamingMapper("gradient", doorways.truth.grid, doorways.rig, strategy="last:100")

    def wait(t: float, s: StreamingMapper) -> None:
        time.sleep(0.2)

    rep = replay(
        [r],
        slow,
        period=0.25,
        realtime=True,
        speed=8.0,
        snapshot_every=0.25,
        on_snapshot=wait,
        on_warning=warnings.append,
    )
    assert rep.max_lag > 2.0
    assert warnings
    assert warnings[0].startswith("falling behind: the map is ")
    assert "x real time so far against --speed 8" in warnings[0]


# -- command line ------------------------------------------------------------------------


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        main(args)
        code = 0
    except SystemExit as e:
        code = int(e.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_stream_command_writes_map_snapshots_animation(
    doorways: Scenario, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doorways.write(tmp_path / "scene")
    d = tmp_path / "scene"
    code, out, err = _run(
        [
            "stream",
            str(d / "readings.csv"),
            "--rig",
            str(d / "rig.yaml"),
            "--like",
            str(d / "truth.yaml"),
            "--truth",
            str(d / "truth.yaml"),
            "-o",
            str(tmp_path / "out"),
            "--snapshot-every",
            "5",
            "--window",
            "last:300",
        ],
        capsys,
    )
    assert code == 0, err
    o = tmp_path / "out"
    info = json.loads((o / "stream.json").read_text())
    assert info["readings"] == len(doorways.readings)
    assert info["strategy"] == "last:300"
    assert info["latency_p99_ms"] >= info["latency_median_ms"] > 0
    assert info["finish_units"] == 100
    assert 0 < info["finish_seconds"] <= info["wall_seconds"]
    assert len(list((o / "snapshots").glob("*.png"))) >= 4
    assert (o / "stream.gif").stat().st_size > 1000
    assert (o / "stream.gif").stat().st_mode & 0o777 == (o / "map.yaml").stat().st_mode & 0o777
    assert (o / "map.yaml").exists()
    assert "realtime_factor" in out
    assert not list(tmp_path.glob(".out.*"))


def test_stream_command_no_finish_ends_at_the_last_update(
    doorways: Scenario, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doorways.write(tmp_path / "scene")
    d = tmp_path / "scene"
    args = ["stream", str(d / "readings.csv"), "--rig", str(d / "rig.yaml")]
    args += ["--like", str(d / "truth.yaml"), "--window", "last:300", "--animation", ""]
    args += ["--snapshot-every", "1000"]
    maps = []
    for flag, passes in (("--no-finish", 0), ("--finish", 100)):
        o = tmp_path / flag.strip("-")
        code, _, err = _run([*args, flag, "-o", str(o)], capsys)
        assert code == 0, err
        info = json.loads((o / "stream.json").read_text())
        assert info["finish_units"] == passes
        assert (info["finish_seconds"] > 0) == (passes > 0)
        maps.append(np.load(o / "map.npy"))
    assert not np.array_equal(maps[0], maps[1], equal_nan=True)


def test_stream_command_bad_input_leaves_nothing(
    doorways: Scenario, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    r = doorways.readings
    write_readings(r, tmp_path / "r.csv")
    save_rig(doorways.rig, tmp_path / "rig.yaml")
    lines = (tmp_path / "r.csv").read_text().splitlines()
    # A bad range far into the file: found while streaming, after snapshots were taken.
    k = len(lines) - 5
    fields = lines[k].split(",")
    fields[-1] = "-1.0"
    lines[k] = ",".join(fields)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    before = set(tmp_path.iterdir())
    code, _out, err = _run(
        [
            "stream",
            str(tmp_path / "bad.csv"),
            "--rig",
            str(tmp_path / "rig.yaml"),
            "--bounds",
            "0",
            "0",
            "6",
            "6",
            "-o",
            str(tmp_path / "out"),
            "--snapshot-every",
            "2",
        ],
        capsys,
    )
    assert code == 2
    assert len(err.strip().splitlines()) == 1
    assert f"bad.csv:{k + 1}" in err
    assert "range" in err
    assert set(tmp_path.iterdir()) == before


def test_stream_command_refuses_an_animation_it_cannot_write(
    doorways: Scenario, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_readings(doorways.readings, tmp_path / "r.csv")
    save_rig(doorways.rig, tmp_path / "rig.yaml")
    code, _out, err = _run(
        [
            "stream",
            str(tmp_path / "r.csv"),
            "--rig",
            str(tmp_path / "rig.yaml"),
            "-o",
            str(tmp_path / "out"),
            "--animation",
            "film.avi",
        ],
        capsys,
    )
    assert code == 2
    assert f"{tmp_path / 'out' / 'film.avi'}: animation must be a .gif or .mp4" in err
    assert not (tmp_path / "out").exists()


def test_office_scenario_is_a_ring_tour() -> None:
    sc = make_scenario("office", duration=2.0)
    assert len(sc.readings) == 16 * 20 * 2
    assert len(sc.rig.mounts) == 16
    assert len(sc.passages) == 8
    occ = np.nan_to_num(sc.truth.occupancy) >= 0.5
    i, j = sc.truth.grid.world_to_cell(sc.trajectory.x, sc.trajectory.y)
    assert not occ[i, j].any()  # the robot never drives through a wall
    m = OccupancyMap(sc.truth.grid, sc.truth.occupancy)
    assert m.grid.shape == (400, 400)


def test_ctrl_c_keeps_the_map_so_far(doorways: Scenario, tmp_path: Path) -> None:
    """Ctrl-C while streaming in real time: snapshots are already in OUT/snapshots, the
    stream stops cleanly, the map so far is written and the exit code is 130."""
    doorways.write(tmp_path / "scene")
    d = tmp_path / "scene"
    out = tmp_path / "out"
    args = ["stream", str(d / "readings.csv"), "--rig", str(d / "rig.yaml")]
    args += ["--like", str(d / "truth.yaml"), "--realtime", "--speed", "1"]
    args += ["--snapshot-every", "1", "-o", str(out), "--method", "inverse"]
    code = "import sys; from sonarmap.cli import main; main(sys.argv[1:])"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    deadline = time.monotonic() + 120
    while not list((out / "snapshots").glob("*.png")) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert list((out / "snapshots").glob("*.png")), "no snapshot appeared while streaming"
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "interrupted after" in stderr
    assert "Traceback" not in stderr
    info = json.loads((out / "stream.json").read_text())
    assert info["interrupted"] is True
    assert 0 < info["readings"] < len(doorways.readings)
    assert (out / "map.yaml").is_file()
    assert (out / "map.pgm").is_file()


@pytest.mark.parametrize("method", ["gradient", "em-thrun", "stochastic"])
def test_idle_improvement_runs_passes_within_its_budget_and_keeps_unseen_cells_unknown(
    doorways: Scenario, method: str
) -> None:
    sm = StreamingMapper(method, doorways.truth.grid, doorways.rig)
    assert sm.improve(1.0) == 0  # no reading yet: nothing to improve
    sm.add(doorways.readings.take(np.arange(0, 120)))
    unseen = np.isnan(sm.occupancy_)
    assert sm.improve(0.0) == 0
    assert sm.improve(0.05) >= 1
    occ = sm.occupancy_
    assert np.array_equal(np.isnan(occ), unseen)
    assert np.nanmin(occ) >= 0.0
    assert np.nanmax(occ) <= 1.0
