"""SPADE on a ROS 2 robot without a ROS install: the planner node (``python -m spade.ros``), the ROS 2 messages as
DDS types, their conversions to SPADE's maps and paths, and ROS 2 MCAP recordings.

- :mod:`spade.ros.convert`: ``nav_msgs/OccupancyGrid`` -> :class:`~spade.maps.OccupancyMap`, poses, path poses
  (numpy only);
- :mod:`spade.ros.messages`: the ROS 2 messages as ``cyclonedds`` IDL types (``nav_msgs::msg::dds_::Path_``, ...);
- :mod:`spade.ros.core`: what the node does with each message (plan on a new goal, re-plan off the plan);
- :mod:`spade.ros.node`: the node on DDS (topics ``rt/map``, ``rt/amcl_pose``, ``rt/goal_pose``, ``rt/plan``);
- :mod:`spade.ros.recording`: plans and node sessions as ROS 2 MCAP bags (``rosbags``), and replays of bags;
- :mod:`spade.ros.launch`: what ``python -m spade.ros`` runs (``conf/ros.yaml``).

Nothing is imported here: the DDS modules need the ``cyclonedds`` package (``pip install "spade[deploy]"``).
"""
