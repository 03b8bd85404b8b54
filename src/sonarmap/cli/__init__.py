"""The ``sonarmap`` command line: a thin layer over the Python API.

Every library error becomes one line on stderr and exit code 2; outputs are written
atomically, so a failed command leaves no partial file.

This module only builds the application: each command group lives in a module of its
own (:mod:`.mapping`, :mod:`.stream`, :mod:`.convert`, :mod:`.patrol`, :mod:`.team`),
imported when one of its commands runs, so that ``sonarmap --version`` and
``sonarmap --help`` start without the numerical stack.
"""

from __future__ import annotations

import importlib
import sys
from typing import Annotated, Any

import typer
from typer.core import TyperCommand, TyperGroup

from ..errors import ConfigError, SonarmapError, quote
from .common import INTERRUPTED, console, err_console, finite_numbers

#: Every command: its module and the one line ``sonarmap --help`` shows for it (the
#: first line of its docstring; a test keeps them equal). In the order they are listed.
COMMANDS: dict[str, tuple[str, str]] = {
    "scenario": (
        "mapping",
        "Write a built-in scenario: truth map, geometry, rig, trajectory, readings, annotations.",
    ),
    "simulate": (
        "mapping",
        "Simulate sonar readings of a rig driven along a trajectory through a floor plan.",
    ),
    "map": (
        "mapping",
        "Build an occupancy map from readings; writes OUT.yaml, OUT.pgm and OUT.npy.",
    ),
    "stream": (
        "stream",
        "Replay a log through a streaming map: latency, throughput, snapshots, animation.",
    ),
    "show": (
        "mapping",
        "Draw a map as a PNG, optionally with the truth outlined and readings overlaid.",
    ),
    "methods": (
        "mapping",
        "List mapping methods, their parameters with defaults, and their presets (--preset).",
    ),
    "demo": (
        "mapping",
        "Map a held-out corridor scene with every method: maps, a picture, a metrics table.",
    ),
    "experiment": (
        "mapping",
        "Run one of the research's experiments: figures, metrics (CSV, JSON), report.html.",
    ),
    "compare": (
        "mapping",
        "Score maps against a truth map on the same grid (YAML, or bare images).",
    ),
    "sweep": ("mapping", "Run a parameter sweep on Dask: results.parquet, results.csv, best.csv."),
    "convert": (
        "convert",
        "Convert a recorded log into a readings CSV and the rig that describes its sensors.",
    ),
    "patrol": ("patrol", "Team patrolling with potential fields (thesis 002, chapter 3)."),
    "team": (
        "team",
        "Team mapping: each robot's bounded store and global map (thesis 002, chapter 2).",
    ),
}


def load_command(name: str) -> Any:
    """The click command (or group) ``name``, its module imported now; every command in
    it refuses NaN and infinity in its number options (:func:`.common.finite_numbers`)."""
    module = importlib.import_module(f"{__name__}.{COMMANDS[name][0]}")
    cmd = typer.main.get_command(module.app)
    if isinstance(cmd, TyperGroup) and name not in ("patrol", "team"):
        cmd = cmd.commands[name]
    _check_numbers(cmd)
    return cmd


def _check_numbers(cmd: Any) -> None:
    """Run :func:`.common.finite_numbers` on every command of ``cmd`` once its options
    are parsed and before it does any work (typer has no hook for all of a command's
    options at once, so each command's ``invoke`` is wrapped)."""
    if isinstance(cmd, TyperGroup):
        for sub in cmd.commands.values():
            _check_numbers(sub)
        return
    invoke = cmd.invoke

    def checked(ctx: Any) -> Any:
        finite_numbers(ctx)
        return invoke(ctx)

    cmd.invoke = checked


class _LazyGroup(TyperGroup):
    """The root group: lists every command from :data:`COMMANDS` and imports a
    command's module only to run it (or to show its own help)."""

    listing = False

    def list_commands(self, ctx: Any) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name not in COMMANDS:
            return None
        if self.listing:
            # The root's help needs only each command's one line.
            return TyperCommand(cmd_name, help=COMMANDS[cmd_name][1])
        return load_command(cmd_name)

    def format_help(self, ctx: Any, formatter: Any) -> None:
        self.listing = True
        try:
            super().format_help(ctx, formatter)
        finally:
            self.listing = False


app = typer.Typer(
    name="sonarmap",
    cls=_LazyGroup,
    help="Occupancy-grid mapping with wide-beam sonars, team patrolling and team mapping. "
    "Documentation: docs/index.md.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


@app.callback(invoke_without_command=True)
def _root(
    version: Annotated[bool, typer.Option("--version", help="Print the version.")] = False,
) -> None:
    if version:
        from importlib.metadata import version as installed

        console.print(f"sonarmap {installed('sonarmap')}")
        raise typer.Exit()


#: Characters of an error line at most, and of one word in it (a path, a quoted value).
MESSAGE_LIMIT = 1000
_WORD_LIMIT = 240


def bounded(message: str) -> str:
    """An error message as one line of bounded length: whitespace runs (a value's own
    newlines included) become one space, an overlong word keeps its start, and the line
    its first :data:`MESSAGE_LIMIT` characters. A value the library did not quote cut
    short (:func:`sonarmap.errors.quote`) still cannot flood a log."""
    words = [w if len(w) <= _WORD_LIMIT else w[:_WORD_LIMIT] + "..." for w in message.split()]
    line = " ".join(words)
    return line if len(line) <= MESSAGE_LIMIT else line[:MESSAGE_LIMIT] + "..."


def _fail(message: str) -> None:
    err_console.print(
        f"sonarmap: error: {bounded(message)}",
        markup=False,
        highlight=False,
        emoji=False,
        soft_wrap=True,
    )
    sys.exit(2)


#: Options taking several numbers, which may also be given as one comma-separated word.
_LIST_OPTIONS = {"--bounds": 4}


def _split_lists(args: list[str]) -> list[str]:
    """``--bounds 0,0,6,6`` (or ``--bounds=0,0,6,6``) as ``--bounds 0 0 6 6``."""
    out: list[str] = []
    i = 0
    while i < len(args):
        a = args[i]
        name, eq, value = a.partition("=")
        if name in _LIST_OPTIONS and (eq or (i + 1 < len(args) and "," in args[i + 1])):
            if not eq:
                i += 1
                value = args[i]
            values = [v.strip() for v in value.split(",")]
            if len(values) != _LIST_OPTIONS[name]:
                raise ConfigError(
                    f"{name} takes {_LIST_OPTIONS[name]} numbers (comma- or space-separated), "
                    f"got {quote(value)}"
                )
            out.append(name)
            out.extend(values)
        else:
            out.append(a)
        i += 1
    return out


def main(argv: list[str] | None = None) -> None:
    """Console entry point: every error becomes one line on stderr and exit code 2."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:
        # Help for a bare command, as for --help (not a usage error).
        args = ["--help"]
    try:
        rv = app(args=_split_lists(args), prog_name="sonarmap", standalone_mode=False)
    except SonarmapError as err:
        _fail(str(err))
    except typer.Abort:
        _fail("aborted")
    except Exception as err:
        # Usage errors of the command-line parser (typer vendors click, whose exception
        # classes are private): they carry format_message() and a context.
        fmt = getattr(err, "format_message", None)
        if fmt is None:
            raise
        ctx = getattr(err, "ctx", None)
        where = f"{ctx.command_path}: " if ctx is not None else ""
        _fail(where + " ".join(str(fmt()).split()))
    if rv == INTERRUPTED:
        # Typer turns Ctrl-C into this exit code. Outputs are written atomically, so an
        # interrupted command leaves none behind.
        err_console.print("sonarmap: interrupted", markup=False, highlight=False)
    if isinstance(rv, int) and rv != 0:
        sys.exit(rv)


if __name__ == "__main__":  # pragma: no cover
    main()
