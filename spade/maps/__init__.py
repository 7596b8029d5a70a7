"""Occupancy maps: the three-level grid, ROS map_server I/O and procedural maps.

Not imported here: :mod:`spade.maps.frame` (the robot-frame window of a map: robot at a fixed pixel, heading up)
and :mod:`spade.maps.costmap` (a grid's Nav2-style inflated costmap).
"""

from spade.maps.analysis import clear_square_fits, largest_free_component, max_clear_square_m, traversable_mask
from spade.maps.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from spade.maps.procedural import GENERATORS, generate_map
from spade.maps.ros_io import MapFormatError, load_ros_map, read_map_yaml, save_ros_map

__all__ = [
    "FREE",
    "GENERATORS",
    "OCCUPIED",
    "UNKNOWN",
    "MapFormatError",
    "OccupancyMap",
    "clear_square_fits",
    "generate_map",
    "largest_free_component",
    "load_ros_map",
    "max_clear_square_m",
    "read_map_yaml",
    "save_ros_map",
    "traversable_mask",
]
