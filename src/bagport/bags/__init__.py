"""Reading ROS bags without ROS: rosbag2 (MCAP, SQLite) and ROS 1, from any fsspec URI."""

from __future__ import annotations

from bagport.bags.detect import detect_storage
from bagport.bags.message import BagMessage
from bagport.bags.reader import BagReader, open_bag
from bagport.bags.records import BagInfo, Storage, TopicInfo
from bagport.bags.stamp import source_stamp
from bagport.bags.text import format_bag_info
from bagport.bags.typesources import prepare_reading, read_msg_path
from bagport.bags.window import BagWindow

__all__ = [
    "BagInfo",
    "BagMessage",
    "BagReader",
    "BagWindow",
    "Storage",
    "TopicInfo",
    "detect_storage",
    "format_bag_info",
    "open_bag",
    "prepare_reading",
    "read_msg_path",
    "source_stamp",
]
