"""sonarmap: occupancy-grid mapping with wide-beam sonars.

The main entry points::

    from sonarmap import make_scenario, build_map, read_map, write_map, score
"""

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
