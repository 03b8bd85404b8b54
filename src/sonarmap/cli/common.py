"""What every command group of the ``sonarmap`` command line shares.

Consoles, the progress line, the ``--map`` resolver, the ``-o`` check and the one
mechanism that turns options into the library's config objects. This module imports
only the command-line toolkit and the errors, so that ``sonarmap --version`` and
``sonarmap --help`` start without the numerical stack; everything heavy is imported
where a command uses it.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Protocol, TypeVar, cast

import typer
from rich.console import Console

from ..checks import MAX_MAP_CELLS
from ..errors import ConfigError, InputError, quote

if TYPE_CHECKING:
    from ..grid import Grid
    from ..io.rosmap import OccupancyMap
    from ..readings import TimeOrder

__all__ = [
    "INTERRUPTED",
    "MAX_MAP_CELLS",
    "ImageOrigin",
    "ImageResolution",
    "MethodPreset",
    "Opt",
    "ReorderWindow",
    "StopOnInterrupt",
    "Update",
    "check_grid_size",
    "check_inside_plan",
    "config_from_options",
    "config_options",
    "console",
    "err_console",
    "figure",
    "finite_numbers",
    "given",
    "make_console",
    "named_check",
    "option_name",
    "pairs",
    "progress",
    "read_plan",
    "resolve_map",
    "say_order",
    "writable",
    "wrote",
    "wrote_folder",
]


def make_console(stderr: bool = False) -> Console:
    """A console whose messages stay on one line (soft wrap) and whose tables, in a log
    or a pipe (no terminal, no COLUMNS), get 120 columns instead of rich's 80."""
    stream = sys.stderr if stderr else sys.stdout
    piped = not stream.isatty() and "COLUMNS" not in os.environ
    return Console(stderr=stderr, soft_wrap=True, width=120 if piped else None)


err_console = make_console(stderr=True)
console = make_console()

#: Exit code of a command stopped by Ctrl-C (128 + SIGINT, as shells report it).
INTERRUPTED = 130

ImageResolution = Annotated[
    float | None,
    typer.Option(
        "--resolution",
        help="Metres per pixel of a map given as a bare image (.png, .pgm, ...), as the "
        "research's simulator took them (0.1).",
    ),
]
ImageOrigin = Annotated[
    tuple[float, float],
    typer.Option(
        "--origin",
        metavar="X Y",
        help="World position of a bare image's lower-left corner, metres.",
    ),
]


MethodPreset = Annotated[
    str | None,
    typer.Option(
        "--preset",
        help="A named parameter set of the method (see 'sonarmap methods'), e.g. "
        "thesis002; --param overrides its values.",
    ),
]


#: ``--bag`` of ``patrol run`` and ``team run`` (``stream`` has its own wording).
BagOption = Annotated[
    bool,
    typer.Option(
        "--bag/--no-bag",
        help="Also record the run as a ROS 2 bag in MCAP storage (OUT/bag/); open it in "
        "Foxglove or 'ros2 bag play' it (topics: docs/guides/live-view.md).",
    ),
]
LiveOption = Annotated[
    bool,
    typer.Option(
        "--live",
        help="Serve the run's topics live over the Foxglove WebSocket protocol on "
        "127.0.0.1 (--live-port) while it goes, paced to --live-rate; connect Foxglove "
        "to ws://127.0.0.1:PORT (docs/guides/live-view.md).",
    ),
]
LivePortOption = Annotated[
    int,
    typer.Option("--live-port", help="--live: the TCP port (0: any free one).", min=0, max=65535),
]
LiveRateOption = Annotated[
    float,
    typer.Option(
        "--live-rate",
        help="--live: simulated (or log) seconds per wall second the run is held to.",
    ),
]


ReorderWindow = Annotated[
    float,
    typer.Option(
        "--reorder-window",
        help="Seconds a reading may come after a later one and still be put back in "
        "time order; later ones are dropped and counted (0 drops every one out of order).",
        min=0.0,
    ),
]


def say_order(order: TimeOrder) -> None:
    """Print the note of readings put back in time order, if any."""
    said = order.message(first_line=2)
    if said is not None:
        console.print(f"note: {said}")


def read_plan(path: Path, resolution: float | None, origin: tuple[float, float]) -> OccupancyMap:
    """A map from a map_server YAML, or from a bare image with its resolution
    (:func:`sonarmap.io.rosmap.read_plan`)."""
    from ..io.rosmap import read_plan as read

    return read(path, resolution, origin)


def resolve_map(
    path: Path, resolution: float | None = None, origin: tuple[float, float] = (0.0, 0.0)
) -> OccupancyMap:
    """``--map`` of every command: a file (map_server YAML, or a bare image with
    ``resolution``), or, when no such file exists, a built-in map by name
    (:data:`sonarmap.builtins.BUILTIN_NAMES`); anything else fails in one line that
    lists the built-ins."""
    from ..builtins import builtin_plan

    if not path.exists():
        return builtin_plan(str(path))
    return read_plan(path, resolution, origin)


def check_inside_plan(t: Any, x: Any, y: Any, grid: Grid, path: Path) -> None:
    """Refuse a trajectory or route (times ``t``, positions ``x``, ``y``, metres) that
    leaves the plan's grid, naming ``path``, the first pose outside and the extent: the
    readings or mission along it would be of a world nobody drew."""
    import numpy as np

    xmin, xmax, ymin, ymax = grid.extent
    xs, ys = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    outside = ~((xs >= xmin) & (xs <= xmax) & (ys >= ymin) & (ys <= ymax))
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        raise InputError(
            f"pose {i + 1} (t = {float(t[i]):g} s) at ({xs[i]:g}, {ys[i]:g}) m is outside "
            f"the plan, x {xmin:g}..{xmax:g} m, y {ymin:g}..{ymax:g} m",
            path=path,
        )


def check_grid_size(grid: Grid, option: str) -> None:
    """Refuse a map grid of more than :data:`MAX_MAP_CELLS` cells, naming the option
    that sized it, before any layer is allocated."""
    cells = grid.rows * grid.cols
    if cells > MAX_MAP_CELLS:
        raise ConfigError(
            f"{option}: a grid of {grid.rows} x {grid.cols} cells at {grid.resolution:g} m; "
            f"at most {MAX_MAP_CELLS:.0e} cells (a coarser --resolution, or --bounds)"
        )


def named_check(option: str, check: Callable[[Any], None], value: Any) -> None:
    """``check(value)``, a library check raising :class:`ConfigError`, its message
    prefixed with the option that gave the value (``--workers: workers 100000: ...``)."""
    try:
        check(value)
    except ConfigError as err:
        raise ConfigError(f"{option}: {_reason(err)}", field=err.field) from None


def writable(out: Path) -> Path:
    """-o: refuse at once an output that cannot be written, before any work."""
    from ..files import check_writable

    check_writable(out)
    return out


def wrote(out: Path, names: Sequence[str | Path]) -> str:
    """The last line's list of files: ``wrote OUT/: a, b, c``."""
    shown = [str(Path(n).relative_to(out)) if Path(n).is_absolute() else str(n) for n in names]
    return f"wrote {out}/: {', '.join(shown)}"


def wrote_folder(out: Path) -> str:
    """The last line of a command that fills a folder: every file and folder in it
    (``wrote OUT/: a.yaml, b.png, snapshots/ (12 files)``)."""
    items = []
    for p in sorted(out.iterdir()) if out.is_dir() else []:
        if p.is_dir():
            n = sum(1 for q in p.rglob("*") if q.is_file())
            items.append(f"{p.name}/ ({n} files)")
        else:
            items.append(p.name)
    return wrote(out, items)


class Update(Protocol):
    """A progress callback: ``done`` of ``total`` (0: unknown), and a note."""

    def __call__(self, done: int, total: int, note: str = "") -> None: ...


@contextmanager
def progress(label: str) -> Iterator[Update]:
    """A rich progress bar as a callback (``note`` is shown after the label); when
    stderr is not a terminal (a log, CI), a plain line every 10 % or 30 s instead."""
    if not err_console.is_terminal:
        yield _progress_lines(label)
        return
    from rich.progress import (
        BarColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=True,
    )
    task = bar.add_task(label, total=None)

    def update(done: int, total: int, note: str = "") -> None:
        bar.update(task, completed=done, total=total, description=f"{label} {note}".strip())

    with bar:
        yield update


def _progress_lines(label: str) -> Update:
    start = time.monotonic()
    last: dict[str, Any] = {"t": start, "step": -1, "note": None}

    def update(done: int, total: int, note: str = "") -> None:
        now = time.monotonic()
        step = int(10 * done / total) if total else -1
        # A new phase (a new note) is shown at once: a log tells what the run is doing.
        if step > last["step"] or now - last["t"] >= 30.0 or note != last["note"]:
            last["t"], last["step"], last["note"] = now, step, note
            share = f"{done}/{total} ({100 * done / total:.0f} %)" if total else f"{done}"
            # A phase of unknown length (nothing done of nothing) shows only its name.
            parts = [share] if total or done else []
            parts += [f"{now - start:.0f} s"] + ([note] if note else [])
            print(f"{label}: {', '.join(parts)}", file=sys.stderr, flush=True)

    return update


def pairs(items: list[str] | None, option: str) -> dict[str, str]:
    """Repeated ``KEY=VALUE`` options as a mapping."""
    out: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{option} expects KEY=VALUE, got {quote(item)}")
        out[key.strip()] = value.strip()
    return out


def figure(v: object) -> str:
    """A table cell: floats to two decimals, NaN (not measured) as a dash."""
    if isinstance(v, float):
        return "-" if v != v else f"{v:.2f}"
    return str(v)


class StopOnInterrupt:
    """While active, the first Ctrl-C asks a long job to stop at its next step (so it
    can keep what it has); a second one interrupts at once."""

    def __init__(self) -> None:
        self._asked = False
        self._previous: Any = None

    def asked(self) -> bool:
        """Whether Ctrl-C was pressed once."""
        return self._asked

    def _handle(self, signum: int, frame: Any) -> None:
        if self._asked:
            raise KeyboardInterrupt
        self._asked = True
        err_console.print("stopping at the next update (Ctrl-C again to abort)")

    def __enter__(self) -> StopOnInterrupt:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None


# --- Options onto config objects --------------------------------------------------------


_UNSET: Any = object()


@dataclasses.dataclass(frozen=True)
class Opt:
    """One option of a command that sets one field of a library config object.

    Parameters
    ----------
    field : str
        The config dataclass's field.
    help : str
        What the option does, in a user's words, with units.
    flag : str, optional
        The option's name (default ``--`` and the field with dashes).
    off : str, optional
        A boolean field's negative flag (``--no-refine``); None: a plain flag.
    aliases : tuple of str
        Older spellings, accepted but hidden from ``--help``.
    unset_as : object, optional
        A field whose default depends on others (NaN: "follow the robot's radius")
        takes an option that defaults to None; None is passed on as this value.
    kind : type, optional
        The option's type when it differs from the field's annotation.
    metavar : str, optional
        The value's name in ``--help``.
    default : object, optional
        The option's default when the dataclass has none (a required field).
    """

    field: str
    help: str
    flag: str | None = None
    off: str | None = None
    aliases: tuple[str, ...] = ()
    unset_as: Any = _UNSET
    kind: Any = None
    metavar: str | None = None
    default: Any = _UNSET

    @property
    def name(self) -> str:
        """The option as a user types it."""
        return self.flag or "--" + self.field.replace("_", "-")

    @property
    def param(self) -> str:
        """The Python name the command-line parser gives the option."""
        return self.name.removeprefix("--").replace("-", "_")


_F = TypeVar("_F", bound=Callable[..., Any])
_T = TypeVar("_T")


def _field_default(cls: type, name: str) -> tuple[Any, Any]:
    """A dataclass field's annotation (resolved) and default."""
    import typing

    hints = typing.get_type_hints(cls)
    f = {f.name: f for f in dataclasses.fields(cls)}[name]
    if f.default is not dataclasses.MISSING:
        default = f.default
    elif f.default_factory is not dataclasses.MISSING:
        default = f.default_factory()
    else:
        default = _UNSET
    return hints[name], default


def _parameters(cls: type, opt: Opt) -> list[inspect.Parameter]:
    annotation, default = _field_default(cls, opt.field)
    if opt.default is not _UNSET:
        default = opt.default
    kind = opt.kind if opt.kind is not None else annotation
    # A switch left unset (bool | None) keeps its on/off pair.
    switch = kind is bool or kind == bool | None
    if opt.unset_as is not _UNSET:
        kind, default = kind | None, None
    names = [opt.name] if opt.off is None or not switch else [f"{opt.name}/{opt.off}"]
    info = typer.Option(*names, help=opt.help, metavar=opt.metavar, show_default=True)
    out = [
        inspect.Parameter(
            opt.param,
            inspect.Parameter.KEYWORD_ONLY,
            default=default,
            annotation=Annotated[kind, info],
        )
    ]
    for alias in opt.aliases:
        hidden = typer.Option(alias, hidden=True, help=f"Old name of {opt.name}.")
        out.append(
            inspect.Parameter(
                _alias_param(alias),
                inspect.Parameter.KEYWORD_ONLY,
                default=None,
                annotation=Annotated[kind | None, hidden],
            )
        )
    return out


def _alias_param(alias: str) -> str:
    # The alias's own Python name, so that a settings file may still use it (r_max).
    return alias.removeprefix("--").replace("-", "_")


def config_options(*tables: tuple[type, Sequence[Opt]]) -> Callable[[_F], _F]:
    """Declare a command's options once, from config dataclasses' fields.

    The decorated command gets one option per :class:`Opt` (the field's type and default,
    the table's help), after its own parameters; it receives only its own and builds each
    config with :func:`config_from_options` from ``ctx.params``.

    Parameters
    ----------
    *tables : (type, sequence of Opt)
        A config dataclass and the options that set its fields.
    """

    def decorate(func: _F) -> _F:
        sig = inspect.signature(func, eval_str=True)
        own = list(sig.parameters)
        added = [p for cls, opts in tables for o in opts for p in _parameters(cls, o)]

        @functools.wraps(func)
        def command(**kwargs: Any) -> Any:
            return func(**{k: kwargs[k] for k in own})

        params = list(sig.parameters.values()) + added
        command.__signature__ = sig.replace(parameters=params)  # type: ignore[attr-defined]
        command.__annotations__ = {p.name: p.annotation for p in params}
        del command.__wrapped__
        return cast(_F, command)

    return decorate


def option_name(opts: Sequence[Opt], field: str | None) -> str | None:
    """The option that sets ``field``, or None when no option does."""
    for o in opts:
        if o.field == field:
            return o.name
    return None


def given(ctx: typer.Context, opts: Sequence[Opt]) -> dict[str, str]:
    """The fields whose options were given on the command line or in a settings file
    (not left at their defaults), with the option's name."""
    out = {}
    for o in opts:
        for param in (o.param, *(_alias_param(a) for a in o.aliases)):
            source = ctx.get_parameter_source(param)
            if (source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP")) or (
                param != o.param and ctx.params.get(param) is not None
            ):
                out[o.field] = o.name
    return out


def config_from_options(
    cls: Callable[..., _T],
    params: Mapping[str, Any],
    opts: Sequence[Opt],
    *,
    convert: Mapping[str, Callable[[Any], Any]] | None = None,
    fixed: Mapping[str, Any] | None = None,
) -> _T:
    """A config object from a command's parsed options.

    Each option's value (or its hidden alias's, when given) goes to its field;
    ``convert`` turns a text option into the field's value; ``fixed`` sets fields no
    option sets. A :class:`~sonarmap.errors.ConfigError` that names a field is raised
    again naming the option instead (``--link-range: must be >= 0 metres, got -1``).

    Parameters
    ----------
    cls : callable
        The config class.
    params : mapping
        ``ctx.params``: every parsed option by its Python name.
    opts : sequence of Opt
        The options that set ``cls``'s fields.
    convert : mapping, optional
        Field -> function from the option's value to the field's.
    fixed : mapping, optional
        Field -> value, set as given.

    Returns
    -------
    object
        The config, validated by its own ``__post_init__``.
    """
    values: dict[str, Any] = dict(fixed or {})
    for o in opts:
        v = params.get(o.param)
        for alias in o.aliases:
            if params.get(_alias_param(alias)) is not None:
                v = params[_alias_param(alias)]
        if v is None and o.unset_as is not _UNSET:
            v = o.unset_as
        if convert and o.field in convert:
            try:
                v = convert[o.field](v)
            except ConfigError as err:
                raise ConfigError(f"{o.name}: {_reason(err)}", field=o.field) from None
        values[o.field] = v
    try:
        return cls(**values)
    except ConfigError as err:
        name = option_name(opts, err.field)
        if name is None:
            raise
        raise ConfigError(f"{name}: {_reason(err)}", field=err.field) from None


def finite_numbers(ctx: typer.Context) -> None:
    """Refuse NaN and infinity given to any number option, before the command runs.

    The parser reads ``nan`` and ``inf`` as numbers; no option means anything by them,
    and passed on, NaN would silently become a field's default (the library's "unset"
    sentinel) and infinity a size or a time without end. Values left at their defaults
    are not checked: those are the command's own.

    Parameters
    ----------
    ctx : typer.Context
        The command's context, its options parsed.

    Raises
    ------
    ConfigError
        Naming the first option with such a value.
    """
    for param in ctx.command.params:
        name = param.name
        if name is None or name not in ctx.params:
            continue
        given = ctx.get_parameter_source(name)
        if given is not None and given.name == "DEFAULT":
            continue
        # A settings file (patrol run --config) sets the defaults it holds.
        source = given if given is not None and given.name == "DEFAULT_MAP" else None
        value = ctx.params[name]
        values = value if isinstance(value, tuple | list) else (value,)
        for v in values:
            if isinstance(v, float) and not math.isfinite(v):
                flag = max(getattr(param, "opts", None) or [f"--{name}"], key=len)
                where = " (from the settings file)" if source is not None else ""
                raise ConfigError(f"{flag} {v}{where}: expected a finite number", field=name)


def _reason(err: ConfigError) -> str:
    return err.reason if err.reason is not None else str(err)


def _install_plain_types() -> None:
    """``--help``'s value column in a user's words: nothing after a plain flag (typer
    prints ``<bool>``), a repeatable value's element (``<str>...``, not ``<list[str]>``).
    Typer has no setting for either, so its two display methods are wrapped, once per import
    of this module; wrapping twice would change nothing, as both wrappers are idempotent."""
    from typer.core import TyperArgument, TyperOption

    shown_rich = TyperOption.display_type_rich

    def option_rich(self: Any, ctx: Any) -> str | None:
        if getattr(self, "is_flag", False):
            return None
        return shown_rich(self, ctx)

    for cls in (TyperArgument, TyperOption):
        shown = cls.display_type

        def display(self: Any, ctx: Any, shown: Any = shown) -> str:
            text = str(shown(self, ctx))
            if text.startswith("<list[") and text.endswith("]>"):
                return f"<{text[6:-2]}>..."
            return text

        cls.display_type = display  # type: ignore[method-assign]
    TyperOption.display_type_rich = option_rich  # type: ignore[method-assign]


_install_plain_types()
