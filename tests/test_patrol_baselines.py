"""Policies side by side on one map: the table, issue 36's claims, the command."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sonarmap.cli import main
from sonarmap.errors import ConfigError
from sonarmap.grid import Grid
from sonarmap.io.rosmap import OccupancyMap, write_map
from sonarmap.patrol.baselines import baseline_claims, baseline_table, run_baselines
from sonarmap.patrol.territory import Territory


def _row(policy: str, robots: int, seed: int, mtb: float, **kw: float) -> dict[str, Any]:
    return {
        "map": "m",
        "policy": policy,
        "robots": robots,
        "traffic": "give-way",
        "seed": seed,
        "mean_mtb": mtb,
        "graph_avg_idleness": kw.get("avg", 10.0),
        "graph_worst_idleness": kw.get("worst", 20.0),
        "blocked": kw.get("blocked", 0.0),
        "never_seen": kw.get("never", 0.0),
    }


def test_the_table_averages_seeds_and_keeps_the_worst_shares() -> None:
    rows = [
        _row("potential", 1, 0, 100.0, blocked=0.01),
        _row("potential", 1, 1, 140.0, blocked=0.03, avg=20.0),
    ]
    (t,) = baseline_table(rows)
    assert (t["mean_mtb"], t["graph_avg_idleness"], t["blocked"]) == (120.0, 15.0, 0.03)
    assert t["seeds_mtb"] == [100.0, 140.0]


def test_claims_compare_the_potential_field_with_each_baseline() -> None:
    mtb = {
        "potential": (120.0, 80.0, 50.0),
        "random": (200.0, 120.0, 70.0),  # 1.67x, 1.5x, 1.4x: beaten by >= 1.3x
        "cr": (100.0, 90.0, 60.0),  # better than the potential field with 1 robot
        "sebs": (150.0, 90.0, 95.0),  # not falling from 2 to 4 robots
    }
    rows = [
        _row(p, n, 0, v[k], blocked=0.08 if (p, n) == ("cr", 4) else 0.0, never=0.0)
        for p, v in mtb.items()
        for k, n in enumerate((1, 2, 4))
    ]
    rows.append(_row("hcr", 1, 0, 300.0, never=0.2))
    rows.append(_row("hcr", 4, 0, 40.0, never=0.1))
    verdict = {c["claim"]: c["verdict"] for c in baseline_claims(baseline_table(rows))}
    assert verdict["m: the potential field beats the random walk by >= 1.3x"] == "holds"
    assert verdict["m: the potential field is at least as good as cr"] == "fails"
    assert verdict["m: the potential field is at least as good as sebs"] == "holds"
    # Compared only where both ran: with 4 robots HCR is better.
    assert verdict["m: the potential field is at least as good as hcr"] == "fails"
    assert verdict["m: potential's mean MTB falls as the team grows"] == "holds"
    assert verdict["m: sebs's mean MTB falls as the team grows"] == "fails"
    assert verdict["m: cr's blocked share stays under 5 %"] == "fails"
    assert verdict["m: potential's blocked share stays under 5 %"] == "holds"
    assert verdict["m: with 4 robots every reachable place is seen"] == "fails"
    assert "m: the potential field is at least as good as reactive" not in verdict


def _room() -> OccupancyMap:
    """12 x 8 m at 0.1 m, walls around and half a wall across the middle."""
    g = Grid(resolution=0.1, origin=(0.0, 0.0), shape=(80, 120))
    occ = np.zeros(g.shape, np.float32)
    occ[[0, -1], :] = 1.0
    occ[:, [0, -1]] = 1.0
    occ[:50, 60] = 1.0
    return OccupancyMap(g, occ)


def test_run_baselines_checks_its_input_before_running() -> None:
    t = Territory.from_map(_room(), cell=0.25)
    base = {"radius": 0.3, "speed": 1.0, "vision": 2.0, "cell": 0.25, "duration": 10.0}
    with pytest.raises(ConfigError, match="unknown policy 'dtap'"):
        run_baselines(t, base, policies=["potential", "dtap"])
    with pytest.raises(ConfigError, match="robots"):
        run_baselines(t, base, robots=[0])
    with pytest.raises(ConfigError, match="radius"):
        run_baselines(t, {**base, "radius": -1.0}, robots=[1])


def test_experiment_baselines_on_a_map_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_map(_room(), tmp_path / "room")
    out = tmp_path / "out"
    args = ["patrol", "experiment", "baselines", "--map", str(tmp_path / "room.yaml")]
    main(
        [
            *args,
            *("--cell", "0.25", "--vision", "2", "--duration", "30", "--seeds", "1"),
            *("--robots", "1,2", "--policies", "potential,cr,sebs", "-o", str(out)),
        ]
    )
    printed = capsys.readouterr().out
    assert "| sebs | 2 |" in printed
    assert "potential field is at least as good as cr" in printed
    runs = json.loads((out / "runs.json").read_text())
    assert runs["settings"]["radius"] == 0.3  # the indoor robot by default
    assert [(r["policy"], r["robots"]) for r in runs["runs"]] == [
        (p, n) for p in ("potential", "cr", "sebs") for n in (1, 2)
    ]
    assert all(np.isfinite(r["graph_avg_idleness"]) for r in runs["runs"])
    for name in ("runs.csv", "table.csv", "claims.json", "mtb.png", "report.html"):
        assert (out / name).stat().st_size > 0
    for bad, message in (
        (["--robots", "1,x"], "--robots takes whole numbers"),
        (["--policies", "potential,dtap"], "unknown policy 'dtap'"),
    ):
        with pytest.raises(SystemExit) as e:
            main([*args, *bad, "-o", str(tmp_path / "bad")])
        assert e.value.code == 2
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["patrol", "experiment", "forces", "--radius", "1", "-o", str(tmp_path / "b")])
    assert e.value.code == 2
    assert "--radius only with --map" in capsys.readouterr().err
