"""benchmarks.team_strangers: its node processes never outlive it."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any, ClassVar

import benchmarks.team_strangers as bench
import pytest


class _FakeNode:
    """A node process that never ends by itself."""

    made: ClassVar[list[_FakeNode]] = []

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.killed = False
        _FakeNode.made.append(self)

    def poll(self) -> int | None:
        return -9 if self.killed else None

    def wait(self, timeout: float | None = None) -> int:
        if not self.killed:
            raise subprocess.TimeoutExpired("node", timeout or 0.0)
        return -9

    def kill(self) -> None:
        self.killed = True


def test_the_nodes_are_killed_when_the_attack_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An attack that raised left both team nodes running (they were killed only after
    a normal wait)."""

    def attack(*args: Any) -> dict[str, int]:
        raise RuntimeError("the attack broke")

    _FakeNode.made = []
    monkeypatch.setattr(subprocess, "Popen", _FakeNode)
    monkeypatch.setattr(bench, "_attack", attack)
    with pytest.raises(RuntimeError, match="the attack broke"):
        bench.run_team(tmp_path / "run", [b"7"], seed=0)
    assert len(_FakeNode.made) == 2
    assert all(node.killed for node in _FakeNode.made)
