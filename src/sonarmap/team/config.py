"""The settings of a robot's mission (:class:`MissionConfig`): every number of
:mod:`.mission`, whose notes give the choices where the thesis is silent."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..errors import ConfigError
from .association import AssociationParams
from .store import StoreParams

__all__ = ["MissionConfig"]


@dataclass(frozen=True)
class MissionConfig:
    """Every number of a mission (see the module's notes for the choices)."""

    duration: float = 600.0
    pose_every: float = 1.0
    pose_turn: float = 0.5
    local_size: float = 6.0
    local_resolution: float = 0.1
    map_resolution: float = 0.1
    mapper: str = "inverse"
    mapper_params: dict[str, Any] = field(
        default_factory=lambda: {
            "p_occ": 0.6,
            "p_free": 0.45,
            "falloff_deg": 20.0,
            "dr": 0.05,
            # The inverse mapper's default: its band 0.75 cell behind the echo.
            "band_offset": None,
        }
    )
    mapping_range: float = 3.0
    max_speed: float = 1.0
    start_error: tuple[float, float] = (1.0, math.radians(10.0))
    batch: int = 25
    correct_xy: float = 0.3
    correct_theta: float = math.radians(5.0)
    rig: str = "ring16"
    seed: int = 0
    store: StoreParams = field(default_factory=StoreParams)
    #: Association as :class:`AssociationParams`, but a closure is refused when its
    #: refit puts the new pose less surely than half the scoring tolerance: standard
    #: deviations of 0.15 m (worst direction) and 2.5 degrees, chosen on training plans
    #: (docs/results/2026-12-03-team-code-notes.md).
    association: AssociationParams = field(
        default_factory=lambda: AssociationParams(
            max_sigma_xy=0.15, max_sigma_theta=math.radians(2.5)
        )
    )
    #: The odometry gate: a candidate's closure must put the new pose within
    #: ``gate_floor`` m + ``gate_sigmas`` standard deviations of where the current
    #: estimates put it (and its heading within ``gate_turn_floor`` rad + as many sigmas),
    #: never beyond the hard bound (top speed x elapsed time).
    gate_floor: float = 0.5
    gate_sigmas: float = 3.0
    gate_turn_floor: float = 0.1

    def __post_init__(self) -> None:
        for name in (
            "duration",
            "pose_every",
            "pose_turn",
            "local_size",
            "local_resolution",
            "mapping_range",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be > 0, got {v}")
        if self.batch < 1:
            raise ConfigError(f"batch must be >= 1, got {self.batch}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
