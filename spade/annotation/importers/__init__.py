"""Importers that turn existing demonstrations (rosbag2 recordings, SKIPP's dataset) into SPADE instances."""
