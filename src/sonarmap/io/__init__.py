"""File formats: ROS map_server maps, readings and trajectory CSV."""

from .rosmap import OccupancyMap, read_map, write_map

__all__ = ["OccupancyMap", "read_map", "write_map"]
