"""The rasterisation of robot states into the four instance images lives in :mod:`spade.data.rasterize` (below
the annotation tool, the metrics' baselines and the planner, which all draw instances or curves with it); its
names stay importable from here."""

from spade.data.rasterize import (
    Instance,
    crop,
    draw_curve,
    fits_robot_frame,
    render,
    robot_instance,
    state_indices,
)

__all__ = ["Instance", "crop", "draw_curve", "fits_robot_frame", "render", "robot_instance", "state_indices"]
