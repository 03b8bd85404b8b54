"""``benchmarks.patrol --setup``: the option's refusals (its runs are the benchmark's)."""

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
