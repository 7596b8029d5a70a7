"""The robot frame of an instance window lives in :mod:`spade.maps.frame` (below both the annotation tool and the
dataset writer, which records it in every manifest); its names stay importable from here."""

from spade.maps.frame import FRAME_KIND, RobotFrame, WindowPose, heading_from_yaw, path_heading, yaw_from_heading

__all__ = ["FRAME_KIND", "RobotFrame", "WindowPose", "heading_from_yaw", "path_heading", "yaw_from_heading"]
