"""sonarmap: occupancy-grid mapping with wide-beam sonars.

The main entry points::

    from sonarmap import make_scenario, build_map, read_map, write_map, score

Every name below is loaded from its submodule on first use (PEP 562), so that
``import sonarmap`` stays cheap: numba, scipy and pandas load only when a name that
needs them is used.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

from .version import __version__

if TYPE_CHECKING:
    from .acoustics import AcousticModel
    from .annotations import Passage, SmallObstacle, load_annotations
    from .api import build_map, grid_for_readings
    from .errors import ConfigError, InputError, OutputError, SonarmapError
    from .floorplan import FloorPlan
    from .grid import Grid
    from .io.rosmap import OccupancyMap, classify, read_map, write_map
    from .mappers import MAPPERS, Mapper, make_mapper
    from .metrics import (
        FalseOpening,
        MapScore,
        false_openings,
        measure_obstacle,
        measure_passage,
        passage_open,
        score,
    )
    from .raster import CellSet, Footprint, beam_cells, rasterise
    from .readings import (
        Readings,
        Trajectory,
        iter_readings,
        read_readings,
        read_trajectory,
        write_readings,
        write_trajectory,
    )
    from .rig import Mount, Rig, get_rig, load_rig, save_rig
    from .scenarios import SCENARIOS, Scenario, make_scenario
    from .sensors import Noise, Region, SensorModel, get_sensor, load_sensor
    from .simulate import PoseNoise, make_model, simulate
    from .version import __version__

#: Exported name -> the submodule (relative to this package) that defines it.
_EXPORTS: dict[str, str] = {
    "AcousticModel": "acoustics",
    "Passage": "annotations",
    "SmallObstacle": "annotations",
    "load_annotations": "annotations",
    "build_map": "api",
    "grid_for_readings": "api",
    "ConfigError": "errors",
    "InputError": "errors",
    "OutputError": "errors",
    "SonarmapError": "errors",
    "FloorPlan": "floorplan",
    "Grid": "grid",
    "OccupancyMap": "io.rosmap",
    "classify": "io.rosmap",
    "read_map": "io.rosmap",
    "write_map": "io.rosmap",
    "MAPPERS": "mappers",
    "Mapper": "mappers",
    "make_mapper": "mappers",
    "FalseOpening": "metrics",
    "MapScore": "metrics",
    "false_openings": "metrics",
    "measure_obstacle": "metrics",
    "measure_passage": "metrics",
    "passage_open": "metrics",
    "score": "metrics",
    "CellSet": "raster",
    "Footprint": "raster",
    "beam_cells": "raster",
    "rasterise": "raster",
    "Readings": "readings",
    "Trajectory": "readings",
    "iter_readings": "readings",
    "read_readings": "readings",
    "read_trajectory": "readings",
    "write_readings": "readings",
    "write_trajectory": "readings",
    "Mount": "rig",
    "Rig": "rig",
    "get_rig": "rig",
    "load_rig": "rig",
    "save_rig": "rig",
    "SCENARIOS": "scenarios",
    "Scenario": "scenarios",
    "make_scenario": "scenarios",
    "Noise": "sensors",
    "Region": "sensors",
    "SensorModel": "sensors",
    "get_sensor": "sensors",
    "load_sensor": "sensors",
    "PoseNoise": "simulate",
    "make_model": "simulate",
    "simulate": "simulate",
}

__all__ = [
    "MAPPERS",
    "SCENARIOS",
    "AcousticModel",
    "CellSet",
    "ConfigError",
    "FalseOpening",
    "FloorPlan",
    "Footprint",
    "Grid",
    "InputError",
    "MapScore",
    "Mapper",
    "Mount",
    "Noise",
    "OccupancyMap",
    "OutputError",
    "Passage",
    "PoseNoise",
    "Readings",
    "Region",
    "Rig",
    "Scenario",
    "SensorModel",
    "SmallObstacle",
    "SonarmapError",
    "Trajectory",
    "__version__",
    "beam_cells",
    "build_map",
    "classify",
    "false_openings",
    "get_rig",
    "get_sensor",
    "grid_for_readings",
    "iter_readings",
    "load_annotations",
    "load_rig",
    "load_sensor",
    "make_mapper",
    "make_model",
    "make_scenario",
    "measure_obstacle",
    "measure_passage",
    "passage_open",
    "rasterise",
    "read_map",
    "read_readings",
    "read_trajectory",
    "save_rig",
    "score",
    "simulate",
    "write_map",
    "write_readings",
    "write_trajectory",
]


def __getattr__(name: str) -> Any:
    """Load an exported name from its submodule on first use and keep it here."""
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """This package's module type: an exported name wins over a submodule of that name."""

    def __setattr__(self, name: str, value: Any) -> None:
        # The import system binds each submodule on its package when it first loads it;
        # ``simulate`` names both a submodule and the function exported here, and with
        # eager imports the function was bound last, so it must stay the function.
        if name in _EXPORTS and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
