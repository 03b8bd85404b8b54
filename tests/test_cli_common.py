"""The command line's shared pieces: options onto config objects, errors naming the
field, presets, the map resolver and results that write themselves."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sonarmap.builtins import BUILTIN_NAMES, builtin_plan
from sonarmap.cli import main
from sonarmap.cli.common import Opt, config_from_options
from sonarmap.errors import ConfigError, InputError
from sonarmap.io.rosmap import read_map
from sonarmap.patrol import PatrolConfig, Territory, run_patrol
from sonarmap.patrol.maps import write_builtin_maps
from sonarmap.team.exchange import LEAN, ExchangeParams
from sonarmap.team.network import NetworkParams
from sonarmap.team.presets import PRESETS, PresetClashError, team_settings
from sonarmap.team.store import StoreParams


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: PatrolConfig(sectors=0), "sectors"),
        (lambda: PatrolConfig(radius=-1.0), "radius"),
        (lambda: PatrolConfig(policy="dance"), "policy"),
        (lambda: StoreParams(pose_limit=0), "pose_limit"),
        (lambda: StoreParams(merge_on_closure=-1), "merge_on_closure"),
        (lambda: ExchangeParams(hold=-1.0), "hold"),
        (lambda: ExchangeParams(descriptor_bits=9), "descriptor_bits"),
        (lambda: ExchangeParams(anchor_share=0.5), "anchor_share"),
        (lambda: NetworkParams(loss=2.0), "loss"),
        (lambda: NetworkParams(kind="mesh"), "kind"),
    ],
)
def test_config_errors_name_their_field(make: object, field: str) -> None:
    with pytest.raises(ConfigError, match=field) as e:
        make()  # type: ignore[operator]
    assert e.value.field == field


OPTS = (
    Opt("radius", "Robot radius, metres."),
    Opt("r_max", "Link range, metres.", flag="--link-range", aliases=("--r-max",)),
    Opt("cell", "Cell, metres.", unset_as=math.nan),
)


def test_config_from_options_names_the_option() -> None:
    with pytest.raises(ConfigError, match=r"^--radius: radius must be > 0, got 0.0$"):
        config_from_options(PatrolConfig, {"radius": 0.0, "link_range": 70.0}, OPTS)
    with pytest.raises(ConfigError, match=r"^--link-range: r_max must be >= 0 metres"):
        config_from_options(PatrolConfig, {"radius": 1.0, "link_range": -1.0}, OPTS)


def test_config_from_options_aliases_and_unset() -> None:
    c = config_from_options(
        PatrolConfig, {"radius": 0.5, "link_range": 70.0, "r_max": 12.0, "cell": None}, OPTS
    )
    assert c.r_max == 12.0  # the old spelling, given, wins over the default
    assert c.cell == 0.25  # None: the field's own rule (half the radius)


def test_lean_preset_conflicts_and_applies() -> None:
    lean = PRESETS["lean"]
    assert lean.conflicts(["cap_bytes", "hold", "budget", "fold"]) == ["hold", "fold"]
    ex, store = lean.apply(ExchangeParams(mode="limited", cap_bytes=1000), StoreParams())
    assert (ex.mode, ex.cap_bytes, ex.anchor_every) == ("limited", 1000, LEAN.anchor_every)
    assert store.fold
    assert store.merge_on_closure == 8
    with pytest.raises(ConfigError, match="the lean preset is for the protocols") as e:
        lean.apply(ExchangeParams(mode="naive"), StoreParams())
    assert e.value.field == "mode"


def test_a_node_gets_the_team_default_unless_told_otherwise() -> None:
    """``team node`` by hand: the lean default fills what was not given, a named
    preset refuses what it would override, and the naive baseline gets none."""
    given_hold = ExchangeParams(mode="limited", hold=5.0)
    ex, store, used = team_settings(None, given_hold, StoreParams(), {"mode", "hold"})
    assert used == "lean"
    assert (ex.mode, ex.hold, ex.anchor_every) == ("limited", 5.0, LEAN.anchor_every)
    assert store.fold
    assert store.merge_on_closure == 8
    ex, store, used = team_settings(None, ExchangeParams(), StoreParams(fold=False), {"fold"})
    assert (used, store.fold, ex.anchor_every) == ("lean", False, LEAN.anchor_every)
    naive = ExchangeParams(mode="naive")
    assert team_settings(None, naive, StoreParams(), {"mode"}) == (naive, StoreParams(), None)
    classic = team_settings("classic", ExchangeParams(), StoreParams(), set())
    assert classic == (ExchangeParams(), StoreParams(fold=False, merge_on_closure=0), "classic")
    with pytest.raises(PresetClashError) as e:
        team_settings("lean", given_hold, StoreParams(), {"mode", "hold"})
    assert e.value.fields == ("hold",)


def test_builtin_maps_are_the_written_ones(tmp_path: Path) -> None:
    write_builtin_maps(tmp_path)
    for name in ("open-field", "fig3-2"):
        a, b = builtin_plan(name), read_map(tmp_path / f"{name}.yaml")
        assert a.grid == b.grid
        np.testing.assert_array_equal(a.occupancy, b.occupancy)
    with pytest.raises(InputError, match=r"^fig3-9: no such file, nor a built-in map; built-ins"):
        builtin_plan("fig3-9")
    assert "building:SEED" in BUILTIN_NAMES


def test_patrol_run_takes_a_builtin_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    main(["patrol", "run", "--map", "open-field", "--robots", "2", "--duration", "5",
          "--cell", "1", "-o", str(tmp_path / "out")])  # fmt: skip
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last == (
        f"wrote {tmp_path / 'out'}/: metrics.csv, summary.json, fog.png, starts.txt, "
        "idleness.csv, vertices.csv, idleness.png"
    )
    with pytest.raises(SystemExit) as e:
        main(["patrol", "run", "--map", "open-feld", "--robots", "2", "-o", str(tmp_path / "x")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "open-feld: no such file, nor a built-in map; built-ins: open-field" in err
    assert not (tmp_path / "x").exists()


def test_patrol_result_writes_itself(tmp_path: Path) -> None:
    territory = Territory.from_map(builtin_plan("open-field"), cell=1.0)
    config = PatrolConfig(duration=5.0, cell=1.0)
    res = run_patrol(territory, config, robots=2, seed=0)
    written = res.write(
        tmp_path / "out", territory, seed=0, source="open-field", batch=("o.txt", 2)
    )
    assert [p.name for p in written] == [
        "metrics.csv",
        "summary.json",
        "fog.png",
        "starts.txt",
        "o.txt",
    ]
    assert all(p.is_file() for p in written)
    lines = (tmp_path / "out" / "metrics.csv").read_text().splitlines()
    assert lines[0] == "step,t,mtb,mean_tb,dvt"
    assert len(lines) == 1 + len(res.t)
    assert len((tmp_path / "out" / "o.txt").read_text().splitlines()) == len(res.t) // 2
