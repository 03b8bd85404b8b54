"""Reading YAML files with errors that name the file and the line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ..errors import InputError


def read_yaml(path: str | Path, what: str = "file") -> Any:
    """Parse a YAML file (safe loader); unreadable or malformed files raise InputError."""
    p = Path(path)
    try:
        return yaml.safe_load(p.read_text())
    except OSError as err:
        raise InputError(f"cannot read {what} ({err.strerror})", path=p) from err
    except UnicodeDecodeError as err:
        raise InputError(f"{what} is not text ({err.reason})", path=p) from err
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        problem = getattr(err, "problem", None) or type(err).__name__
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise InputError(f"not valid YAML ({problem}{where})", path=p) from err
