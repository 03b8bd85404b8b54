"""Every command's ``--help`` reads in a user's words: no Sphinx markup, no Python types."""

from __future__ import annotations

import re

import pytest
import typer
from typer.testing import CliRunner

from sonarmap.cli import COMMANDS, app, load_command, main

#: What a reader of --help should never see.
FORBIDDEN = (":func:", ":mod:", ":class:", ":data:", "``", "<bool>", "<list[")


def _paths() -> list[list[str]]:
    out: list[list[str]] = []
    for name in COMMANDS:
        cmd = load_command(name)
        out.append([name])
        if isinstance(cmd, typer.core.TyperGroup):
            out += [[name, sub] for sub in cmd.commands]
    return out


@pytest.mark.parametrize("path", _paths(), ids=" ".join)
def test_help_has_no_markup(path: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    main([*path, "--help"])
    text = capsys.readouterr().out
    assert text.strip(), path
    found = [bad for bad in FORBIDDEN if bad in text]
    assert not found, f"sonarmap {' '.join(path)} --help shows {found}"
    assert "docs/" in text, f"sonarmap {' '.join(path)} --help points to no docs page"


def test_stream_help_through_typer_shows_no_python_types() -> None:
    # typer's own runner on the app, not main(): cli.common's display wrappers must hold
    # for any caller of the click command, not only for the sonarmap script.
    result = CliRunner().invoke(app, ["stream", "--help"])
    assert result.exit_code == 0, result.output
    assert "--window" in result.output
    assert [bad for bad in ("<bool>", "<list[") if bad in result.output] == []


def test_root_help_lines_are_the_commands_own() -> None:
    for name, (_, line) in COMMANDS.items():
        cmd = load_command(name)
        first = (cmd.help or "").strip().split("\n\n")[0]
        assert " ".join(first.split()) == line, name


def test_root_help_and_version_import_no_command(capsys: pytest.CaptureFixture[str]) -> None:
    import subprocess
    import sys

    code = (
        "import sys; from sonarmap.cli import main\n"
        "main(['--help'])\n"
        "print(sorted(m for m in sys.modules if m.startswith('sonarmap.cli.')))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert re.search(r"\['sonarmap\.cli\.common'\]$", done.stdout.strip()), done.stdout[-300:]
