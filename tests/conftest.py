"""Shared pytest fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def maps_dir() -> Path:
    """The folder of real ROS maps named by ``SPADE_MAPS_DIR``; the test is skipped when it is absent."""
    value = os.environ.get("SPADE_MAPS_DIR")
    if not value:
        pytest.skip("SPADE_MAPS_DIR is not set (point it at a folder of ROS map yamls, e.g. ../shared/maps)")
    path = Path(value).expanduser()
    if not path.is_dir() or not any(path.rglob("*.yaml")):
        pytest.skip(f"SPADE_MAPS_DIR={path} holds no ROS map yaml files")
    return path
