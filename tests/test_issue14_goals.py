"""benchmarks.issue14_goals: the tables it reads from experiment folders, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from benchmarks.issue14_goals import doorways_report, main


def _row(method: str, seed: int, opened: int, detected: int, error: float) -> dict[str, object]:
    return {
        "method": method,
        "seed": seed,
        "passages": 5,
        "passages_open": opened,
        "passages_detected": detected,
        "width_error": error,
        "false_openings": 2.0,
        "f1_all": 0.3,
        "observed_wall_recall": 0.8,
        "passage_f1": 0.5,
        "seconds": 1.0,
    }


def test_doorways_sums_doors_and_weights_width_error_by_detections(tmp_path: Path) -> None:
    rows = [_row("a", 1000, 4, 3, 0.1), _row("a", 1001, 2, 1, 0.5), _row("b", 1000, 0, 0, 0.0)]
    (tmp_path / "metrics.json").write_text(json.dumps(rows))
    table = doorways_report(tmp_path)
    line_a = next(ln for ln in table.splitlines() if ln.startswith("| a |"))
    # Four detections at 0.1 m (three) and 0.5 m (one): 0.2 m, not the maps' mean 0.3 m.
    assert line_a.split(" | ")[1:4] == ["6 / 10", "4 / 10", "0.20"]
    line_b = next(ln for ln in table.splitlines() if ln.startswith("| b |"))
    assert line_b.split(" | ")[3] == "-"


def test_missing_folder_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--real", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "nowhere/metrics.json" in err[0]
