"""Run settings from a file: the thesis's batch ``setup.json``, or a YAML of our own.

``setup.json`` keys (thesis 002's batch mode): ``map``, ``robot_starting_position`` (a
start file), ``layout`` (a semaphore file: crowding by semaphores), ``robot_number``
(the first N robots of the start file), ``worsening_window`` (fog dilation, cells),
``max_model_time`` (steps), ``output_file`` (a text file of ``step MTB DVT`` lines, in
the output folder) and ``log_period_steps`` (its period).

A YAML (``.yaml``/``.yml``) takes the options of ``sonarmap patrol run`` by name, with
underscores (``policy: reactive``, ``r_obst: 4``, ...). Paths are relative to the file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..files import read_yaml

__all__ = ["MAX_DILATION", "MAX_SECTORS", "SETUP_KEYS", "read_run_file"]

#: Direction sectors at most (one a degree): each step scores every robot's sectors
#: (the thesis uses 8).
MAX_SECTORS = 360
#: Fog dilation at most, cells a step: each step dilates the fog with a window of
#: (2 d + 1)^2 cells (the thesis's experiment tries 0 to 4).
MAX_DILATION = 20

SETUP_KEYS = {
    "map": "map",
    "robot_starting_position": "starts",
    "layout": "semaphores",
    "robot_number": "robots",
    "worsening_window": "dilation",
    "max_model_time": "steps",
    "output_file": "output_file",
    "log_period_steps": "log_period_steps",
}
_PATHS = ("map", "starts", "semaphores")


def read_run_file(path: str | Path, options: set[str]) -> dict[str, Any]:
    """The run options a file sets, named as ``patrol run``'s (``options`` lists them)."""
    p = Path(path)
    if p.suffix.lower() == ".json":
        try:
            raw = json.loads(p.read_text())
        except OSError as err:
            raise InputError(f"cannot read file ({err.strerror or err})", path=p) from err
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise InputError(f"not valid JSON ({err})", path=p) from err
        if not isinstance(raw, dict):
            raise InputError("expected a JSON object of setup keys", path=p)
        out: dict[str, Any] = {}
        for key, value in raw.items():
            if key not in SETUP_KEYS:
                raise InputError(
                    f"unknown setup key; valid: {', '.join(SETUP_KEYS)}", path=p, field=key
                )
            out[SETUP_KEYS[key]] = value
        if "semaphores" in out:
            out.setdefault("crowding", "semaphores")
    else:
        raw = read_yaml(p, "patrol settings")
        if not isinstance(raw, dict):
            raise InputError("expected a YAML mapping of run options", path=p)
        out = {}
        for key, value in raw.items():
            name = str(key).replace("-", "_")
            if name not in options:
                raise InputError(
                    f"unknown option; valid: {', '.join(sorted(options))}", path=p, field=str(key)
                )
            out[name] = value
    for key in _PATHS:
        if key in out:
            if not isinstance(out[key], str):
                raise InputError("expected a file name", path=p, field=key)
            q = Path(out[key])
            out[key] = q if q.is_absolute() else p.parent / q
    return out
