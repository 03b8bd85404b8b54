"""The global map: robust pose-graph optimisation, fused local maps, prior alignment."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from sonarmap.errors import ConfigError, InputError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap
from sonarmap.metrics import score
from sonarmap.team.globalmap import (
    align_to_prior,
    fuse_local_maps,
    grid_around,
    layer_frames,
    optimise_graph,
    plot_pose_graph,
)
from sonarmap.team.records import (
    ClosureEdge,
    Landmarks,
    LocalMap,
    OdometryEdge,
    Pose,
    compose,
    invert,
    make_uid,
)

F64 = npt.NDArray[np.float64]
ODO_COV = tuple(np.diag([0.05**2, 0.05**2, 0.02**2]).ravel().tolist())
CLO_COV = tuple(np.diag([0.05**2, 0.05**2, 0.01**2]).ravel().tolist())
# Robot numbers near 2^23 give UIDs near 2^63, the largest a store makes.
ROBOT = 2**23 - 1
GOOD = ((1, 17), (6, 22), (11, 27), (18, 34), (23, 39))
FALSE = ((3, 30, (0.5, 0.3, 0.2)), (10, 37, (0.0, 0.0, 0.0)), (14, 25, (1.0, -1.0, 1.0)))


def _one_landmark() -> Landmarks:
    # Landmarks.empty() cannot be built yet (reshape of a size-0 array to (0, -1)).
    return Landmarks(
        np.zeros((1, 3), dtype=np.float32),
        np.zeros((1, 128), dtype=np.uint8),
        np.full(1, 0.5, dtype=np.float32),
        np.zeros(1),
        np.full(1, -1, dtype=np.int64),
    )


def _pose(uid: int, t: float, est: F64, local: LocalMap | None = None) -> Pose:
    return Pose(uid, t, 0, est, _one_landmark(), local)


def _loop(
    n: int = 40,
) -> tuple[dict[int, Pose], list[OdometryEdge], list[ClosureEdge], dict[int, F64], dict[int, F64]]:
    """Square loop (8 m sides, 2 m steps, 2.5 laps) with biased odometry, 5 good and
    3 false closures; returns poses, odometry, closures, truth and dead reckoning."""
    rng = np.random.default_rng(7)
    uids = [make_uid(ROBOT, k) for k in range(n)]
    truth = {uids[0]: np.zeros(3)}
    dead = {uids[0]: np.zeros(3)}
    odo = []
    for k in range(n - 1):
        step = np.array([2.0, 0.0, math.pi / 2 if (k + 1) % 4 == 0 else 0.0])
        truth[uids[k + 1]] = compose(truth[uids[k]], step)
        meas = step + np.array([0.01, 0.0, 0.02]) + rng.normal(0, [0.02, 0.02, 0.005])
        dead[uids[k + 1]] = compose(dead[uids[k]], meas)
        odo.append(OdometryEdge(uids[k], uids[k + 1], tuple(meas.tolist()), ODO_COV, 25.0))
    closures = []
    for i, j in GOOD:
        rel = compose(invert(truth[uids[i]]), truth[uids[j]])
        rel = rel + rng.normal(0, [0.02, 0.02, 0.005])
        closures.append(ClosureEdge(uids[i], uids[j], tuple(rel.tolist()), CLO_COV, 30, 0.1))
    for i, j, tf in FALSE:
        closures.append(ClosureEdge(uids[i], uids[j], tf, CLO_COV, 30, 0.1))
    # Stored estimates are the dead reckoning; the oldest pose is at its true place.
    poses = {u: _pose(u, float(k), dead[u]) for k, u in enumerate(uids)}
    return poses, odo, closures, truth, dead


def _ate(est: dict[int, F64], truth: dict[int, F64]) -> float:
    d = np.array([est[u][:2] - truth[u][:2] for u in truth])
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def test_gnc_fixes_drift_and_flags_false_closures() -> None:
    poses, odo, closures, truth, dead = _loop()
    res = optimise_graph(poses, odo, closures)
    ate_odo, ate_opt = _ate(dead, truth), _ate(res.estimates, truth)
    assert ate_opt < 0.5 * ate_odo
    assert ate_opt < 0.3
    assert res.inconsistent == (5, 6, 7)
    assert set(res.gnc_outliers) == {5, 6, 7}
    assert np.all(res.weights[:5] > 0.5)
    assert np.all(res.residuals[:5] < 11.35)
    assert np.allclose(res.estimates[min(poses)], 0.0, atol=1e-3)
    assert res.error_final < res.error_initial
    # Without GNC the false closures bend the loop.
    plain = optimise_graph(poses, odo, closures, robust="none")
    assert _ate(plain.estimates, truth) > 2 * ate_opt
    assert set(plain.gate_outliers) & {5, 6, 7}
    assert plain.iterations is not None
    assert plain.iterations >= 1


def test_other_layer_joined_by_closures_and_unknown_poses_skipped() -> None:
    poses, odo, closures, truth, _ = _loop()
    uids = sorted(poses)
    # A second robot's layer: 6 poses beside the loop, its own frame off by a lot.
    other = [make_uid(5, k) for k in range(6)]
    off = np.array([1.5, -1.0, 0.4])
    b_truth = {u: np.array([2.0 * k, 1.0, 0.0]) for k, u in enumerate(other)}
    b_odo = [
        OdometryEdge(a, b, (2.0, 0.0, 0.0), ODO_COV, 25.0) for a, b in itertools.pairwise(other)
    ]
    for k, u in enumerate(other):
        poses[u] = _pose(u, 100.0 + k, compose(off, b_truth[u]))
    links = [
        ClosureEdge(
            uids[i],
            other[j],
            tuple(compose(invert(truth[uids[i]]), b_truth[other[j]])),
            CLO_COV,
            30,
            0.1,
        )
        for i, j in ((0, 0), (1, 1), (2, 2), (3, 3))
    ]
    ghost = ClosureEdge(uids[0], make_uid(9, 0), (0.0, 0.0, 0.0), CLO_COV, 30, 0.1)
    res = optimise_graph(poses, odo + b_odo, [*closures, *links, ghost])
    assert res.skipped == (len(closures) + len(links),)
    assert res.inconsistent == (5, 6, 7)
    assert _ate({u: res.estimates[u] for u in other}, b_truth) < 0.2


def test_bad_graph_input() -> None:
    poses, odo, _, _, _ = _loop()
    with pytest.raises(InputError, match="no pose"):
        optimise_graph([], [], [])
    with pytest.raises(InputError, match="anchor"):
        optimise_graph(poses, odo, [], anchor=12345)
    stray = OdometryEdge(min(poses), 99, (1.0, 0.0, 0.0), ODO_COV, 25.0)
    with pytest.raises(InputError, match="not in the graph"):
        optimise_graph(poses, [*odo, stray], [])
    flat = OdometryEdge(odo[0].a, odo[0].b, (1.0, 0.0, 0.0), (0.0,) * 9, 25.0)
    with pytest.raises(InputError, match="positive definite"):
        optimise_graph(poses, [flat], [])


# --- fusion --------------------------------------------------------------------------


def _plan() -> OccupancyMap:
    """A 12 x 10 m floor plan at 0.1 m: outer walls and two asymmetric inner walls,
    all 0.2 m thick."""
    g = Grid(0.1, (0.0, 0.0), (100, 120))
    x, y = g.all_centres()
    occ = (x < 0.2) | (x > 11.8) | (y < 0.2) | (y > 9.8)
    occ |= (np.abs(x - 7.0) < 0.1) & (y < 6.0)
    occ |= (np.abs(y - 7.0) < 0.1) & (x > 2.0) & (x < 5.0)
    occ |= (np.abs(x - 3.0) < 0.1) & (y > 2.0) & (y < 4.0)
    return OccupancyMap(g, occ.astype(np.float32))


def _cut(plan: OccupancyMap, pose: F64, size: int = 41, h: float = 0.1) -> LocalMap:
    """The plan seen from ``pose``: +2 log-odds on walls, -1 on free cells."""
    half = size * h / 2
    rr, cc = np.indices((size, size))
    lx = (cc + 0.5) * h - half
    ly = half - (rr + 0.5) * h
    c, s = math.cos(pose[2]), math.sin(pose[2])
    wr, wc = plan.grid.world_to_cell(pose[0] + c * lx - s * ly, pose[1] + s * lx + c * ly)
    inside = plan.grid.contains(wr, wc)
    lo = np.zeros((size, size))
    vals = plan.occupancy[wr[inside], wc[inside]]
    lo[inside] = np.where(vals > 0.5, 2.0, -1.0)
    return LocalMap.from_logodds(lo, h)


def _survey(plan: OccupancyMap) -> tuple[list[Pose], dict[int, F64]]:
    rng = np.random.default_rng(3)
    poses, truth = [], {}
    k = 0
    for px in np.arange(1.0, 11.5, 1.5):
        for py in np.arange(1.0, 9.5, 1.5):
            est = np.array([px, py, rng.uniform(-math.pi, math.pi)])
            u = make_uid(1, k)
            truth[u] = est
            poses.append(_pose(u, float(k), est + np.array([5.0, 5.0, 0.0]), _cut(plan, est)))
            k += 1
    return poses, truth


def test_fused_local_maps_reproduce_the_plan() -> None:
    plan = _plan()
    poses, truth = _survey(plan)
    fused = fuse_local_maps(poses, truth, plan.grid)
    s = score(plan, fused)
    assert s.f1 > 0.9
    assert s.unknown < 0.05
    nearest = score(plan, fuse_local_maps(poses, truth, plan.grid, order=0))
    assert nearest.f1 > 0.9
    # The stored estimates (5 m off) are used only where no estimate is given.
    off = fuse_local_maps(poses, None, plan.grid)
    assert score(plan, off).f1 < 0.5
    # A cell no local map reaches is unknown.
    wide = Grid(0.1, (-20.0, -20.0), (500, 500))
    far = fuse_local_maps(poses, truth, wide)
    assert np.isnan(far.occupancy[0, 0])
    assert np.isfinite(far.occupancy).sum() == pytest.approx(
        np.isfinite(fused.occupancy).sum(), rel=0.01
    )


def test_grid_around_covers_every_local_map() -> None:
    est = {1: np.array([0.0, 0.0, 0.3]), 2: np.array([5.0, -2.0, 1.0])}
    g = grid_around(est, 2.05, 0.1, margin=0.5)
    xmin, xmax, ymin, ymax = g.extent
    reach = 2.05 * math.sqrt(2) + 0.5
    assert xmin <= -reach
    assert xmax >= 5.0 + reach
    assert ymin <= -2.0 - reach
    assert ymax >= reach
    assert xmax - xmin < 5.0 + 2 * reach + 0.2


# --- alignment ------------------------------------------------------------------------


def _built_from(plan: OccupancyMap, tf: F64, seed: int = 11) -> OccupancyMap:
    """The plan's walls, 30 % dropped, seen in a frame where ``tf`` maps into the
    plan's: walls only, the rest unknown."""
    rng = np.random.default_rng(seed)
    rr, cc = np.nonzero(plan.classes() == 1)
    keep = rng.random(len(rr)) > 0.3
    x, y = plan.grid.cell_centres(rr[keep], cc[keep])
    inv = invert(tf)
    c, s = math.cos(inv[2]), math.sin(inv[2])
    bx, by = c * x - s * y + inv[0], s * x + c * y + inv[1]
    g = Grid.from_bounds(bx.min() - 1, by.min() - 1, bx.max() + 1, by.max() + 1, 0.1)
    occ = np.full(g.shape, np.nan, dtype=np.float32)
    r, col = g.world_to_cell(bx, by)
    occ[r, col] = 1.0
    return OccupancyMap(g, occ)


def test_alignment_recovers_rotation_and_shift() -> None:
    plan = _plan()
    tf = np.array([3.0, -2.0, math.radians(30.0)])
    built = _built_from(plan, tf)
    al = align_to_prior(built, plan)
    assert math.hypot(*(al.transform[:2] - tf[:2])) < 0.2
    assert abs(math.degrees(math.remainder(al.transform[2] - tf[2], 2 * math.pi))) < 2.0
    assert 1 <= len(al.hypotheses) <= 5
    assert al.hypotheses[0].score >= al.hypotheses[-1].score
    assert al.score < 0.05
    assert al.inlier_fraction > 0.9
    again = align_to_prior(built, plan)
    assert np.array_equal(al.transform, again.transform)


def _fine_plan() -> OccupancyMap:
    """The same floor as :func:`_plan`, at 0.03 m, its grid not a whole number of
    coarse cells and its corner off the origin."""
    g = Grid(0.03, (-1.3, 0.7), (334, 401))
    x, y = g.all_centres()
    x, y = x + 1.3, y - 0.7
    occ = (x < 0.2) | (x > 11.8) | (y < 0.2) | (y > 9.8)
    occ |= (np.abs(x - 7.0) < 0.1) & (y < 6.0)
    occ |= (np.abs(y - 7.0) < 0.1) & (x > 2.0) & (x < 5.0)
    occ |= (np.abs(x - 3.0) < 0.1) & (y > 2.0) & (y < 4.0)
    return OccupancyMap(g, occ.astype(np.float32))


@pytest.mark.parametrize("coarse", [0.1, 0.3])
def test_alignment_on_a_fine_prior_searches_coarse_cells_and_refines(coarse: float) -> None:
    plan = _fine_plan()
    tf = np.array([1.7, -0.4, math.radians(-20.0)])
    built = _built_from(plan, tf)
    # The coarse search alone lands within about a coarse cell of the truth ...
    rough = align_to_prior(built, plan, coarse_resolution=coarse, rounds=0)
    assert math.hypot(*(rough.transform[:2] - tf[:2])) < 0.75 * coarse + 0.03
    assert abs(math.degrees(math.remainder(rough.transform[2] - tf[2], 2 * math.pi))) < 3.0
    # ... and the particle filter at the prior's resolution finishes it.
    al = align_to_prior(built, plan, coarse_resolution=coarse)
    assert math.hypot(*(al.transform[:2] - tf[:2])) < 0.1
    assert abs(math.degrees(math.remainder(al.transform[2] - tf[2], 2 * math.pi))) < 1.0


def _two_rooms(centres: tuple[tuple[float, float], ...]) -> OccupancyMap:
    """Alike 4 x 3 m rooms (0.2 m walls, a door gap and a stub wall that make each
    one-sided) centred at ``centres``, axis-aligned, on a 0.1 m plan."""
    g = Grid.from_bounds(10.0, -10.0, 30.0, 5.0, 0.1)
    x, y = g.all_centres()
    occ = np.zeros(g.shape, dtype=bool)
    for cx, cy in centres:
        u, v = x - cx, y - cy
        inside = (np.abs(u) < 2.1) & (np.abs(v) < 1.6)
        ring = inside & ((np.abs(u) > 1.9) | (np.abs(v) > 1.4))
        ring &= ~((np.abs(v + 1.5) < 0.2) & (u > 0.5) & (u < 1.5))
        stub = (np.abs(u + 0.8) < 0.1) & (v > 0.0) & (v < 1.5)
        occ |= ring | stub
    return OccupancyMap(g, occ.astype(np.float32))


def test_guess_turns_the_map_about_the_believed_start() -> None:
    # The robot believes it started at (0, 0) heading 0; it started there but turned
    # by 15 degrees, and mapped room A 20 m away. Turned by 15 degrees about its
    # centroid, the map lands where the robot thinks it is -- on the alike room B;
    # about the believed start, on A.
    room_a = (20.0, 0.0)
    tf = np.array([0.0, 0.0, math.radians(15.0)])
    unturned = compose(invert(tf), np.array([*room_a, 0.0]))[:2]
    room_b = (round(float(unturned[0]), 1), round(float(unturned[1]), 1))
    plan = _two_rooms((room_a, room_b))
    built = _built_from(_two_rooms((room_a,)), tf)
    centre = np.array(room_a)

    def lands(al_tf: F64) -> F64:
        # Where the alignment puts the point truly at room A's centre.
        return compose(al_tf, compose(invert(tf), np.array([*room_a, 0.0])))[:2]

    # One hypothesis: the weighted correlation's best peak alone seeds the refinement
    # (with more, the alike rooms' walls fit equally well and the guess cannot choose).
    old = align_to_prior(built, plan, guess=(0.0, 0.0, 0.0), n_best=1)
    assert math.hypot(*(lands(old.transform) - np.array(room_b))) < 0.3
    new = align_to_prior(built, plan, guess=(0.0, 0.0, 0.0), guess_start=(0.0, 0.0), n_best=1)
    assert math.hypot(*(lands(new.transform) - centre)) < 0.2
    assert abs(math.degrees(math.remainder(new.transform[2] - tf[2], 2 * math.pi))) < 1.0
    # Without a guess the rooms' two peaks score alike: the weight, not the walls, chose.
    free = align_to_prior(built, plan, n_best=2)
    first, second = free.hypotheses
    assert second.score > 0.9 * first.score
    found = sorted(float(lands(np.array(hp.transform))[1]) for hp in free.hypotheses)
    assert found == pytest.approx([room_b[1], room_a[1]], abs=0.3)


def test_guess_start_must_be_finite() -> None:
    plan = _plan()
    with pytest.raises(ConfigError, match="guess_start must be finite"):
        align_to_prior(plan, plan, guess=(0.0, 0.0, 0.0), guess_start=(math.nan, 0.0))


def test_alignment_needs_occupied_cells() -> None:
    plan = _plan()
    empty = OccupancyMap(plan.grid, np.zeros(plan.grid.shape, dtype=np.float32))
    with pytest.raises(InputError, match="built map has no occupied cell"):
        align_to_prior(empty, plan)
    with pytest.raises(InputError, match="prior map has no occupied cell"):
        align_to_prior(plan, empty)


def test_plot_pose_graph_writes_png(tmp_path: Path) -> None:
    poses, odo, closures, truth, _ = _loop()
    res = optimise_graph(poses, odo, closures)
    out = plot_pose_graph(
        None, res.estimates, odo, closures, tmp_path / "g.png", truth, rejected=res.inconsistent
    )
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(data) > 10_000


def test_a_received_layers_frame_is_found_from_its_closures_to_own_poses_despite_a_false_one() -> (
    None
):
    # Robot 1's poses in its own frame, which lies at `frame` in ours; four true
    # closures from our poses to its poses and one false one (2 m, 1 rad off).
    rng = np.random.default_rng(3)
    frame = np.array([1.2, -0.7, math.radians(9.0)])
    truth = {make_uid(1, k): np.array([2.0 * k, 1.0, 0.3 * k]) for k in range(6)}
    theirs = {u: compose(invert(frame), t) for u, t in truth.items()}
    own = {make_uid(0, k): np.array([2.0 * k + 0.5, 0.0, 0.1]) for k in range(6)}
    closures = []
    for k in range(5):
        a, b = make_uid(0, k), make_uid(1, k)
        rel = compose(invert(own[a]), truth[b]) + rng.normal(0, [0.01, 0.01, 0.002])
        if k == 4:
            rel = rel + np.array([2.0, 0.0, 1.0])
        # Either end may be ours: the closure store keeps the new pose as b.
        c = (a, b, rel) if k % 2 == 0 else (b, a, invert(rel))
        closures.append(ClosureEdge(c[0], c[1], tuple(c[2].tolist()), CLO_COV, 20, 0.1))
    # A closure between two received poses and one to a pose no layer holds: ignored.
    closures.append(ClosureEdge(make_uid(1, 0), make_uid(1, 5), (9.0, 9.0, 1.0), CLO_COV, 20, 0.1))
    closures.append(ClosureEdge(make_uid(0, 0), make_uid(2, 0), (9.0, 9.0, 1.0), CLO_COV, 20, 0.1))
    frames = layer_frames(own, {1: theirs, 3: {make_uid(3, 0): np.zeros(3)}}, closures)
    assert set(frames) == {1}  # layer 3 shares no closure with ours: left out
    assert np.hypot(*(frames[1][:2] - frame[:2])) < 0.05
    assert abs(math.remainder(frames[1][2] - frame[2], 2 * math.pi)) < math.radians(0.5)
