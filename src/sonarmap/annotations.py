"""Annotations of a scene: its passages and small obstacles, and their YAML file.

A scene's ``annotations.yaml`` looks like::

    scenario: doorways
    params: {seed: 0}
    passages:
      - {name: door-0, a: [1.0, 2.0], b: [1.0, 2.8], depth: 0.1, width: 0.8}
    small_obstacles:
      - {name: post-0, centre: [3.0, 1.5], size: 0.1}

Coordinates are world metres; ``width`` is written for the reader and ignored on
reading (it is the distance from ``a`` to ``b``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import InputError
from .files import atomic_write_text, dump_yaml, read_yaml

__all__ = ["Passage", "SmallObstacle", "load_annotations", "write_annotations"]


@dataclass(frozen=True)
class Passage:
    """An opening in the floor plan.

    ``a`` and ``b`` are the jamb points (world, metres) on the mid-line of the obstacle
    the opening goes through, ``depth`` that obstacle's thickness across the opening.
    """

    name: str
    a: tuple[float, float]
    b: tuple[float, float]
    depth: float = 0.1

    @property
    def width(self) -> float:
        """The opening's width: the distance from ``a`` to ``b`` (metres)."""
        return math.dist(self.a, self.b)


@dataclass(frozen=True)
class SmallObstacle:
    """A small square obstacle: ``centre`` (world, metres) and side ``size`` (metres)."""

    name: str
    centre: tuple[float, float]
    size: float


def write_annotations(
    path: Path,
    scenario: str,
    params: dict[str, Any],
    passages: Sequence[Passage],
    obstacles: Sequence[SmallObstacle],
) -> None:
    """Write a scene's annotations to ``path`` atomically, in the format above.

    Parameters
    ----------
    path : Path
        The YAML file to write.
    scenario : str
        The scene's name.
    params : dict
        The parameters the scene was made with, written as given.
    passages : sequence of Passage
        Its openings, in order.
    obstacles : sequence of SmallObstacle
        Its small obstacles, in order.
    """
    ann = {
        "scenario": scenario,
        "params": params,
        "passages": [
            {
                "name": p.name,
                "a": [float(v) for v in p.a],
                "b": [float(v) for v in p.b],
                "depth": float(p.depth),
                "width": round(float(p.width), 6),
            }
            for p in passages
        ],
        "small_obstacles": [
            {"name": o.name, "centre": [float(v) for v in o.centre], "size": float(o.size)}
            for o in obstacles
        ],
    }
    atomic_write_text(path, dump_yaml(ann))


def load_annotations(path: str | Path) -> tuple[tuple[Passage, ...], tuple[SmallObstacle, ...]]:
    """Read the passages and small obstacles of a scene's ``annotations.yaml``.

    Parameters
    ----------
    path : str or Path
        The file, in the format above; ``depth`` defaults to 0.1 m and missing or
        empty lists to none.

    Returns
    -------
    passages : tuple of Passage
        In file order.
    obstacles : tuple of SmallObstacle
        In file order.

    Raises
    ------
    InputError
        If the file cannot be read or an entry is malformed; the error names the entry.
    """

    p = Path(path)
    data = read_yaml(p, "annotations")
    if not isinstance(data, dict):
        raise InputError("expected a mapping with 'passages' and 'small_obstacles'", path=p)
    items = data.get("passages") or []
    posts = data.get("small_obstacles") or []
    for key, value in (("passages", items), ("small_obstacles", posts)):
        if not isinstance(value, list):
            raise InputError(f"expected a list under '{key}'", path=p, field=key)
    out = []
    for i, d in enumerate(items):
        try:
            out.append(
                Passage(
                    str(d["name"]),
                    (float(d["a"][0]), float(d["a"][1])),
                    (float(d["b"][0]), float(d["b"][1])),
                    float(d.get("depth", 0.1)),
                )
            )
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(
                f"bad passage entry ({err!r})", path=p, field=f"passages[{i}]"
            ) from err
    small = []
    for i, d in enumerate(posts):
        try:
            small.append(
                SmallObstacle(
                    str(d["name"]), (float(d["centre"][0]), float(d["centre"][1])), float(d["size"])
                )
            )
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(
                f"bad small obstacle entry ({err!r})", path=p, field=f"small_obstacles[{i}]"
            ) from err
    return tuple(out), tuple(small)
