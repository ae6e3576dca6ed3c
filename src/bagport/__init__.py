"""bagport: ROS bags (rosbag2 MCAP/SQLite, ROS 1) to LeRobot v3.0 datasets."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("bagport")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
