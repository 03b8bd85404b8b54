"""The seeds' remaining mapping pieces (issue 14): the documents' parameter sets as
presets, the printed R2, the filtered pose grid, thesis 002's toy case, and a scene
whose truth is a bare image."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image

from sonarmap.cli import main
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import read_map
from sonarmap.mappers import make_mapper, parse_params, preset_params
from sonarmap.mappers.em import EMMapper
from sonarmap.mappers.em_thrun import ThrunEMMapper
from sonarmap.mappers.gradient import GradientMapper
from sonarmap.readings import Readings, write_readings
from sonarmap.rig import get_rig
from sonarmap.scenarios import make_scenario
from sonarmap.selection import PoseGrid, parse_strategy
from sonarmap.sensors import SensorModel

SENSOR: SensorModel = get_rig("paper-synthetic").sensor
#: 3.5 m x 3 m at 5 cm around a sonar at the origin looking along +x.
GRID = Grid(resolution=0.05, origin=(-0.5, -1.5), shape=(60, 70))


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        main(args)
        code = 0
    except SystemExit as e:
        code = int(e.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def one_place(ranges: list[float], name: str = "s") -> Readings:
    """Readings of one sonar at the origin looking along +x."""
    n = len(ranges)
    z = np.zeros(n)
    return Readings(
        np.arange(n, dtype=np.float64), np.zeros(n, np.int32), z, z, z, np.array(ranges), (name,)
    )


def distance() -> npt.NDArray[np.float64]:
    """Each cell's distance from the sonar, flat."""
    xs = GRID.origin[0] + (np.arange(GRID.cols) + 0.5) * GRID.resolution
    ys = GRID.origin[1] + (np.arange(GRID.rows) + 0.5) * GRID.resolution
    x, y = np.meshgrid(xs, ys)
    return np.asarray(np.hypot(x, y).ravel(), dtype=np.float64)


def test_presets_resolve_and_yield_to_given_parameters(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    got = parse_params("gradient", {"c2": "0.5"}, preset="thesis002")
    assert got == {
        "a1": 0.05,
        "a2": 0.001,
        "c1": 10.0,
        "c2": 0.5,
        "robust": 0.0,
        "band_offset": 0.0,
        "no_echo": "free",
    }
    assert preset_params("stochastic", "thesis002")["r_max"] == 3.5
    unknown = r"unknown preset 'x' for method 'inverse'; valid: traditional"
    with pytest.raises(ConfigError, match=unknown):
        preset_params("inverse", "x")
    code, out, _ = run(["methods"], capsys)
    assert code == 0
    assert "r_max=3.5" in out
    assert "a2=0.001" in out
    # On the command line: the same map as the Python preset gives.
    readings = one_place([2.0] * 5 + [1.0] + [2.0] * 5, name="left_mid")
    write_readings(readings, tmp_path / "r.csv")
    cmd = ["map", str(tmp_path / "r.csv"), "--rig", "paper-synthetic", "--method", "stochastic"]
    code, _, err = run(
        [*cmd, "--preset", "thesis002", "--resolution", "0.1", "-o", f"{tmp_path}/m"], capsys
    )
    assert code == 0, err
    m = read_map(tmp_path / "m.yaml")
    ref = make_mapper("stochastic", **preset_params("stochastic", "thesis002"))
    want = ref.fit(readings, m.grid, SENSOR).occupancy_
    np.testing.assert_array_equal(m.occupancy, want)
    code, _, err = run(
        [*cmd, "--preset", "thesis003", "--resolution", "0.1", "-o", f"{tmp_path}/n"], capsys
    )
    assert code == 2
    assert "unknown preset 'thesis003' for method 'stochastic'; valid: thesis000, thesis002" in err


def test_stochastic_range_limit_turns_far_echoes_into_no_echo() -> None:
    readings = one_place([3.0] * 6)
    maps = {
        r_max: make_mapper("stochastic", r_max=r_max, sweeps=10).fit(readings, GRID, SENSOR)
        for r_max in (None, 2.5)
    }
    d = distance()
    unlimited = maps[None].occupancy_.ravel()
    assert np.sum(np.nan_to_num(unlimited[np.abs(d - 3.0) < 0.2]) > 0.5) > 0
    # Beyond the limit a 3 m echo is no echo: its beam says nothing past 2.5 m.
    limited = maps[2.5].occupancy_.ravel()
    assert np.all(np.isnan(limited[d > 2.5]))
    assert not np.all(np.isnan(limited[d < 2.0]))
    with pytest.raises(ConfigError, match=r"parameter 'r_max' must be in \(0.0, inf\]"):
        make_mapper("stochastic", r_max=0.0)


def test_printed_r2_changes_the_objective_as_its_formula_says() -> None:
    """R2 = c2 |x - 0.5| (the print) against the tent c2 (0.5 - |x - 0.5|), on [0, 1]."""
    readings = one_place([2.0, 1.5])
    tent = GradientMapper(c2=0.7).start(GRID, SENSOR).problem(readings)
    printed = GradientMapper(c2=0.7, r2="abs").start(GRID, SENSOR).problem(readings)
    x = np.random.default_rng(0).uniform(0.0, 1.0, tent.n_cells)
    dev = np.abs(x - 0.5)
    assert printed.value(x) - tent.value(x) == pytest.approx(0.7 * np.sum(dev - (0.5 - dev)))
    # The print pulls a cell towards 0.5, the tent pushes it away.
    at = np.array([0.2, 0.8])
    assert tent.reg_grad(at).tolist() == [0.7, -0.7]
    assert printed.reg_grad(at).tolist() == [-0.7, 0.7]
    # The convex form is solved exactly by ccp: no solver reaches a lower objective.
    ccp = GradientMapper(r2="abs", solver="ccp").fit(readings, GRID, SENSOR)
    pgd = GradientMapper(r2="abs").fit(readings, GRID, SENSOR)
    assert ccp.objective_ <= pgd.objective_ + 1e-6
    with pytest.raises(ConfigError, match=r"parameter 'r2' must be one of tent, abs; got 'l2'"):
        GradientMapper(r2="l2")


def test_filtered_pose_grid_drops_the_lone_range() -> None:
    """Ten 2 m readings then one at 1 m from one pose: the freshest two keep the 1 m
    one, the median filter keeps two 2 m ones."""
    readings = one_place([2.0] * 10 + [1.0])
    slots = np.arange(len(readings), dtype=np.int64)
    empty = np.zeros(len(readings), np.int64)
    kept = {}
    for spec in ("pose:2", "pose:2:0.5:30:median"):
        s = parse_strategy(spec)
        s.start(GRID.size)
        gone = s.admit(slots, readings, empty, empty, np.zeros(0, np.int32))
        kept[spec] = sorted(set(slots.tolist()) - set(gone.tolist()))
    assert kept["pose:2"] == [9, 10]
    assert kept["pose:2:0.5:30:median"] == [8, 9]
    assert parse_strategy("pose:2:median").spec() == "pose:2:0.5:30:median"
    with pytest.raises(ConfigError, match=r"pose filter must be one of freshest, median"):
        PoseGrid(2, keep="mean")


def test_thesis002_toy_case() -> None:
    """Thesis 002 section 4.6: from one place, ten readings at 2 m and one at 1 m.

    The thesis expects the probabilistic model to call the 1 m reading random and the
    deterministic one to put a small obstacle at 1 m. What sonarmap's methods do:

    - ``inverse`` leaves 1 m free and 2 m occupied: not by calling the reading an
      outlier but by votes, ten free against one occupied at each 1 m cell.
    - ``em`` (the relaxed model) at thesis 000's p_hit 0.75, from its neutral start and
      from the inverse map, leaves 1 m free and puts the obstacle at 2 m (at its default
      p_hit 0.3 it marks 1 m occupied too: passes cost little). It does not call the
      1 m reading random either: a cell of the relaxed map reflects with probability
      p_hit * m, and EM explains that reading by a faint reflector at 1 m (m about
      0.03, which the ten 2 m beams crossing it barely notice), free once binarised.
      (Until the fix of the E-step's pass counts, the neutral start learnt nothing
      here: see ``tests/test_em_thrun.py``.)
    - ``em-thrun`` (Thrun 2003's binary map) calls the 1 m reading random and leaves 1 m
      free: an occupied cell there lies in the free part of all ten 2 m beams and makes
      each of them 1 / (1 - p_hit) = 4 times less likely, 10 ln 4 = 13.9 nats, while
      calling the 1 m reading random costs ln((1 - p_rand) p_hit N(0; 0, sigma) /
      (p_rand / r_max)) = 6.4 nats (11.1 with thesis 002's p_rand 0.001): the
      probabilistic model's outlier, as the thesis says.
    - ``gradient``'s optimum does put obstacle area at 1 m: exactly enough for one echo
      (the 1 m reading's Omega_occ sum reaches X0), since that costs the ten free terms
      only a1 X0 each; the exact ``ccp`` solver concentrates it into whole cells, the
      small obstacle the thesis describes. The default solver (pgd) does not get
      there: with today's tent (c2 = 1) the tent's pull on a cell is more than the lone
      reading's, and the band goes to 0 with the echo unexplained. With the constants
      before the band offset (a1 0.2, c2 0.3, band on the echo) pgd explained it with
      area spread thinly over the band (every cell below 0.5), so the binarised map
      showed nothing there either. That is the plain model (``robust=0``); the robust
      form finds the 1 m reading's band seen through by the ten 2 m beams and no other
      band sharing it, weights it down and leaves 1 m empty
      (``tests/test_gradient_robust.py``).
    - ``stochastic`` with thesis 002's own set (p_rand 0.001) also puts an obstacle at
      1 m: with so small a p_rand, calling a reading random (log(0.001 / 3.5), about
      -8) costs more than one occupied cell (w_occ and w_border, about 1.25).
    """
    readings = one_place([2.0] * 5 + [1.0] + [2.0] * 5)
    d = distance()
    near, far = np.abs(d - 1.0) <= 0.1, np.abs(d - 2.0) <= 0.1

    def occupied(occ: npt.NDArray[np.float32], where: npt.NDArray[np.bool_]) -> int:
        return int(np.sum(np.nan_to_num(occ.ravel()[where]) > 0.5))

    inv = make_mapper("inverse").fit(readings, GRID, SENSOR).occupancy_
    assert occupied(inv, near) == 0
    assert occupied(inv, far) > 0

    for init in ("uniform", "inverse"):
        em = EMMapper(init=init, p_hit=0.75).fit(readings, GRID, SENSOR)
        assert occupied(em.occupancy_, near) == 0
        assert occupied(em.occupancy_, far) > 0
        assert em.loglik_[-1] > em.loglik_[0] + 10
        assert np.all(em.outlier_prob_ < 0.5)
        assert 0.0 < np.nanmax(em.em_map_.ravel()[near]) < 0.1

    # At em's default p_hit since issue 39 (0.3, tuned across rigs) a pass through a
    # reflector costs little, and EM explains the lone 1 m reading by an obstacle there,
    # as the deterministic model does.
    weak = EMMapper().fit(readings, GRID, SENSOR)
    assert occupied(weak.occupancy_, near) > 0
    assert occupied(weak.occupancy_, far) > 0

    for p_rand in (0.1, 0.001):
        thrun = make_mapper("em-thrun", p_rand=p_rand).fit(readings, GRID, SENSOR)
        assert isinstance(thrun, ThrunEMMapper)
        assert thrun.outlier_prob_[5] > 0.99
        assert np.all(np.delete(thrun.outlier_prob_, 5) < 0.01)
        assert np.nansum(thrun.binary_map_.ravel()[near]) == 0
        assert np.nansum(thrun.binary_map_.ravel()[far]) > 0
        assert occupied(thrun.occupancy_, far) > 0

    before: dict[str, Any] = {"a1": 0.2, "c2": 0.3, "band_offset": 0.0}
    for params, explained in ((before, True), ({}, False)):
        pgd = GradientMapper(robust=0.0, **params).fit(readings, GRID, SENSOR)
        problem = pgd.problem(readings)
        row = int((~problem.is_occ).sum()) + 5  # the 1 m reading's Omega_occ term
        x = np.nan_to_num(pgd.occupancy_.ravel()[problem.cells], nan=0.5).astype(np.float64)
        share = (problem.W @ x)[row] / problem.X0[row]
        assert share >= 0.95 if explained else share < 0.3
        assert occupied(pgd.occupancy_, near) == 0
        assert occupied(pgd.occupancy_, far) > 0
    ccp = GradientMapper(solver="ccp", robust=0.0).fit(readings, GRID, SENSOR).occupancy_
    assert occupied(ccp, near) > 0

    sto = make_mapper("stochastic", **preset_params("stochastic", "thesis002"))
    assert occupied(sto.fit(readings, GRID, SENSOR).occupancy_, near) > 0


def test_experiment_on_a_scene_whose_truth_is_a_bare_image(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = make_scenario("boxes", layout=2, speed=0.5)
    folder = scene.write(tmp_path / "mine")
    # A black-and-white picture of the plan, as the research's simulator took them.
    black = scene.truth.occupancy > 0.5
    Image.fromarray(np.where(black, 0, 255).astype(np.uint8)).convert("1").save(
        folder / "truth.png"
    )
    for name in ("truth.yaml", "truth.pgm", "truth.npy"):
        (folder / name).unlink()
    image = read_map(folder / "truth.png", resolution=0.1)
    np.testing.assert_array_equal(image.occupancy, scene.truth.occupancy)
    cmd = ["experiment", "boxes", "--scene", str(folder), "-o"]
    code, _, err = run([*cmd, str(tmp_path / "no")], capsys)
    assert code == 2
    assert "truth.png: a bare image needs --resolution" in err
    assert not (tmp_path / "no").exists()
    code, _, err = run(
        [*cmd, str(tmp_path / "exp"), "--resolution", "0.1", "--origin", "0", "0"], capsys
    )
    assert code == 0, err
    rows = json.loads((tmp_path / "exp" / "metrics.json").read_text())
    assert {r["passages"] for r in rows} == {len(scene.passages)}
    maps = sorted((tmp_path / "exp" / "maps" / "mine").glob("*.yaml"))
    assert len(maps) == len(rows)
    assert read_map(maps[0]).grid == scene.truth.grid
