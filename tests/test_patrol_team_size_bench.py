"""benchmarks.patrol_team_size refuses bad input with one line and exit 2, before any run."""

from __future__ import annotations

from pathlib import Path

import pytest
from benchmarks import patrol_team_size


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--judge", "/nope/base.json", "b", "c"], "--judge: not a runs file"),
        (["--maps", "no-such-map"], "no such map"),
        (["--maps", "--buildings", "1005"], "held out"),
        (["--maps", "--buildings", "0", "--claim", "nan"], "claim must be"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert patrol_team_size.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err
    assert len(err.splitlines()) == 1


def test_a_judge_file_without_runs_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "x.json"
    bad.write_text('{"duration": 1}')
    assert patrol_team_size.main(["--judge", str(bad), str(bad), str(bad)]) == 2
    assert "not a runs file" in capsys.readouterr().err
