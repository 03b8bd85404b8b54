"""Strict JSON output: NaN and infinities become null, numpy scalars plain numbers."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def _clean(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def dumps(data: Any) -> str:
    """``json.dumps`` that always produces standard JSON."""
    return json.dumps(_clean(data), indent=2, allow_nan=False)
