"""``benchmarks.inverse_walls --rule``: one sweep's figures as before, pooled or
incomplete sweeps refused (issue 39)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from benchmarks.inverse_walls import DEFAULTS, main, rule_table

from conftest import refused_in_one_line, training_sweep

GRADIENT = training_sweep("gradient", {DEFAULTS: {"f1": 0.4}})
INVERSE = training_sweep("inverse", {DEFAULTS: {}, "walls": {"recall": 0.8, "f1": 0.25}})


def test_one_sweep_gives_each_settings_figures() -> None:
    got = rule_table(INVERSE, GRADIENT).set_index("setting")
    assert got.index.tolist() == [DEFAULTS, "walls"]
    assert "maps" not in got.columns
    assert got.loc[DEFAULTS, "passages"] == 16
    assert got.loc["walls", "passages_ring16"] == 4
    assert got.loc["walls", "ez1_observed"] == pytest.approx(0.8)
    assert got.loc["walls", "margin_ring16"] == pytest.approx(0.15)
    assert got.loc[DEFAULTS, "margin_ez1-six"] == pytest.approx(0.1)


def test_pooled_sweeps_and_missing_scenes_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A second sweep's file with its own defaults' rows: the defaults on 32 maps.
    other = training_sweep("inverse", {DEFAULTS: {}, "stop": {"recall": 0.9}})
    with pytest.raises(ValueError, match="'walls' has 16 maps, the defaults 32"):
        rule_table(pd.concat([INVERSE, other], ignore_index=True), GRADIENT)
    # The MaxSonar hall missing: NaN, which no comparison would fail.
    with pytest.raises(ValueError, match="no figure for ez1_hall_observed"):
        rule_table(INVERSE[INVERSE.scenario != "hall-ez1"], GRADIENT)
    with pytest.raises(ValueError, match="no figure for margin_ring16"):
        rule_table(INVERSE, GRADIENT[~GRADIENT.scenario.str.endswith("ring16")])
    with pytest.raises(ValueError, match="the gradient has 12 maps, the inverse defaults 16"):
        rule_table(INVERSE, GRADIENT[GRADIENT.scenario != "suite-ez1"].iloc[2:])
    with pytest.raises(ValueError, match="no row of the defaults"):
        rule_table(INVERSE[INVERSE.params != DEFAULTS], GRADIENT)

    files = {"grad": GRADIENT, "inv": INVERSE, "other": other}
    for name, df in files.items():
        df.to_csv(tmp_path / f"{name}.csv", index=False)
    grad, inv, two = (str(tmp_path / f"{n}.csv") for n in files)
    main(["--rule", grad, inv])
    assert "walls" in capsys.readouterr().out
    for args, why in (
        (["--rule", grad, inv, two], "other.csv: setting 'walls' has 16 maps, the defaults 32"),
        (["--rule", grad, str(tmp_path / "none.csv")], "none.csv: no such file"),
        (["--rule", grad], "needs GRADIENT_CSV and at least one INVERSE_CSV"),
    ):
        refused_in_one_line(main, args, why, capsys)
