"""``benchmarks.patrol``'s refusals: ``--setup`` below one, absurd cells and durations,
two modes at once (its runs are the benchmark's)."""

from __future__ import annotations

import pytest
from benchmarks import patrol


@pytest.mark.parametrize("bad", ["0", "-2", "two"])
def test_setup_refuses_a_count_below_one_in_one_line(
    bad: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as e:
        patrol.main([f"--setup={bad}"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "--setup" in err, err


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--cells", "0"], "--cells"),
        (["--cells", "nan"], "--cells"),
        (["--duration", "-1"], "--duration"),
        (["--setup", "1", "--profile", "5"], "--profile"),
    ],
)
def test_absurd_cells_durations_and_two_modes_are_one_line(
    argv: list[str], named: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as e:
        patrol.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert named in err, err
