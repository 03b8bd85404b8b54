"""The README's and the getting-started page's examples run as written.

The README's commands run in order in one temporary folder. ``docs/getting-started.md``
repeats the README's first map; its commands must each be one of the README's (run
there) or cheap, and the others run in a folder of their own.

Convention (README, "Examples as tests"): a fenced block whose info string is ``sh`` is
run, one command a line, in order, in one temporary folder per page; a line ending in
``\\`` continues on the next, and ``#`` starts a comment. Blocks fenced ``text``,
``console`` or anything else are shown only. Two kinds of line in a run block are the
setup this test already stands in: ``make ...`` (the test runs inside ``make test``, after
the venv exists) and ``. .venv/bin/activate`` (the test puts the venv's ``sonarmap`` first
on ``PATH``). The README's ``python`` block is executed too.

The guides' blocks are not run: many of them take minutes (experiments, sweeps) or need
``../shared/data``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GETTING_STARTED = ROOT / "docs" / "getting-started.md"
#: Commands of the getting-started page that need not be the README's.
CHEAP = ("sonarmap --help",)
FENCE = re.compile(r"^```(\S*)\s*$")
#: One command may take this long (a cold numba cache compiles on first use).
COMMAND_TIMEOUT_S = 180
SETUP = (re.compile(r"^make(\s|$)"), re.compile(r"^\.\s+\.venv/bin/activate$"))


def fenced_blocks(text: str) -> list[tuple[str, str]]:
    """``(info string, body)`` of every fenced block of a Markdown text, in order."""
    blocks: list[tuple[str, str]] = []
    info: str | None = None
    lines: list[str] = []
    for line in text.splitlines():
        m = FENCE.match(line)
        if info is None:
            if m:
                info, lines = m.group(1), []
        elif line.strip() == "```":
            blocks.append((info, "\n".join(lines)))
            info = None
        else:
            lines.append(line)
    if info is not None:
        raise ValueError("unclosed fenced block")
    return blocks


def strip_comment(line: str) -> str:
    """``line`` without a ``#`` comment (a ``#`` at the start or after white space, outside
    quotes)."""
    quote: str | None = None
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip()
    return line.rstrip()


def shell_commands(body: str) -> list[str]:
    """The commands of a ``sh`` block: continuations joined, comments and blanks dropped."""
    commands: list[str] = []
    pending = ""
    for raw in body.splitlines():
        line = raw.rstrip()
        if line.endswith("\\"):
            pending += strip_comment(line[:-1]) + " "
            continue
        command = (pending + strip_comment(line)).strip()
        pending = ""
        if command:
            commands.append(re.sub(r"\s+", " ", command))
    if pending.strip():
        commands.append(pending.strip())
    return commands


def page_commands(page: Path) -> list[str]:
    """Every command to run from ``page``: its ``sh`` blocks' lines less the setup lines."""
    commands = []
    for info, body in fenced_blocks(page.read_text(encoding="utf-8")):
        if info == "sh":
            commands += [c for c in shell_commands(body) if not any(s.match(c) for s in SETUP)]
    return commands


def test_parsing_follows_the_convention() -> None:
    text = (
        "```sh\nmake demo   # set up\n. .venv/bin/activate\n"
        "sonarmap a --x 1 \\\n    --y '#2'   # note\n\n# only a comment\n```\n"
        "```text\nsonarmap not-run\n```\n```console\n$ sonarmap not-run\n```\n"
    )
    blocks = fenced_blocks(text)
    assert [info for info, _ in blocks] == ["sh", "text", "console"]
    commands = shell_commands(blocks[0][1])
    assert commands == ["make demo", ". .venv/bin/activate", "sonarmap a --x 1 --y '#2'"]


def test_readme_has_examples() -> None:
    commands = page_commands(README)
    assert any(c.startswith("sonarmap patrol run") for c in commands)
    assert any(c.startswith("sonarmap team run") for c in commands)
    assert sum(1 for info, _ in fenced_blocks(README.read_text()) if info == "python")


def _environment() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env.setdefault("MPLBACKEND", "Agg")
    return env


def _run_all(page: Path, commands: list[str], folder: Path) -> None:
    env = _environment()
    for command in commands:
        start = time.monotonic()
        done = subprocess.run(
            command,
            shell=True,
            executable="/bin/bash",
            cwd=folder,
            env=env,
            capture_output=True,
            text=True,
            timeout=COMMAND_TIMEOUT_S,
            check=False,
        )
        took = time.monotonic() - start
        assert done.returncode == 0, (
            f"{page.name}: `{command}` exited {done.returncode} after {took:.1f} s\n"
            f"stdout:\n{done.stdout[-2000:]}\nstderr:\n{done.stderr[-2000:]}"
        )


def test_readme_shell_examples_run(tmp_path: Path) -> None:
    commands = page_commands(README)
    assert commands, "README.md: no sh block to run"
    _run_all(README, commands, tmp_path)


def test_getting_started_examples_run(tmp_path: Path) -> None:
    readme = set(page_commands(README))
    commands = page_commands(GETTING_STARTED)
    assert commands, "getting-started.md: no sh block to run"
    others = [c for c in commands if c not in readme]
    assert all(c in CHEAP for c in others), (
        f"getting-started.md: commands neither in the README nor cheap: {others}"
    )
    _run_all(GETTING_STARTED, others, tmp_path)


def test_readme_python_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    blocks = [body for info, body in fenced_blocks(README.read_text()) if info == "python"]
    for body in blocks:
        exec(compile(body, "README.md (python block)", "exec"), {"__name__": "readme"})
    assert (tmp_path / "em.yaml").exists()


def test_readme_links_resolve() -> None:
    """Every relative link and image of the README names a file of the repository (the
    docs site's own links are checked by ``mkdocs build --strict``)."""
    text = README.read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    local = [t.split("#")[0] for t in targets if "://" not in t and not t.startswith("#")]
    assert local
    missing = [t for t in local if t and not (ROOT / t).exists()]
    assert not missing, f"README.md links to missing files: {missing}"
