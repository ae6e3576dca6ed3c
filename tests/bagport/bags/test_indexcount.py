"""Index counts inside a window agree with the messages a full read finds there, per format."""

from __future__ import annotations

import random
from collections import Counter
from pathlib import Path

import pytest
from mcap.writer import Writer as McapWriter
from rosbags.typesys import Stores, get_typestore

from bagport.bags.indexcount import window_counts
from bagport.bags.typeload import TolerantAnyReader
from tests.helpers import realbag

REAL = {
    "mcap-2-chunks": "rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap",
    "mcap-split": "rosbag2_split/wbag",
    "sqlite3": "stinger_localization/localization_bag",
    "sqlite3-bare": "foxglove_chatter_db3/chatter.db3",
    "ros1": "rosbagjs_turtlesim/example.bag",
    "ros1-lz4": "rosbagjs_turtlesim/example-lz4.bag",
}


@pytest.mark.parametrize("relative", REAL.values(), ids=REAL.keys())
def test_window_counts_equal_the_messages_logged_in_the_window(relative: str) -> None:
    reader = TolerantAnyReader([realbag(relative)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
    with reader:
        logged = [(conn.topic, log_ns) for conn, log_ns, _ in reader.messages()]
        start, end = int(reader.start_time), int(reader.end_time)
        rng = random.Random(7)
        for _ in range(25):
            a = rng.randint(start - 2, end)
            b = rng.randint(a, end + 2)
            truth = Counter(topic for topic, log_ns in logged if a <= log_ns < b)
            counts = window_counts(reader, reader.connections, a, b)
            assert set(counts) == {c.topic for c in reader.connections}
            assert {t: n for t, n in counts.items() if n} == dict(truth), (a, b)


def test_an_mcap_without_chunks_has_no_window_count(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    string = "std_msgs/msg/String"
    path = tmp_path / "flat.mcap"
    with path.open("wb") as handle:
        writer = McapWriter(handle, use_chunking=False)
        writer.start(profile="ros2")
        schema = writer.register_schema(
            string, "ros2msg", store.generate_msgdef(string, ros_version=2)[0].encode()
        )
        channel = writer.register_channel("/s", "cdr", schema)
        for i in range(3):
            data = bytes(store.serialize_cdr(store.types[string](data=f"{i}"), string))
            writer.add_message(channel, log_time=10 + i, data=data, publish_time=10 + i)
        writer.finish()  # type: ignore[no-untyped-call]
    with TolerantAnyReader([path], default_typestore=store) as reader:
        assert window_counts(reader, reader.connections, 11, 12) == {}
