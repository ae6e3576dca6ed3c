"""Remote MCAP bags are read in place: the summary, then only the chunks holding the topics asked
for, each byte fetched at most once; bytes read are measured against the file size."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Literal

import fsspec
import numpy as np
import pyarrow.parquet as pq
import pytest
import s3fs
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType, Writer
from rosbags.typesys import Stores, get_typestore

from bagport.bags import BagMessage, open_bag
from bagport.bags.remote import RemoteBag, RemotePath
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.errors import TransientError
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import FAST_SETTINGS, SAMPLE_CONTRACT
from tests.s3 import moto_s3

NS = 1_000_000_000
CAMERA, JOINTS = "/camera/image_raw", "/joint_states"
Layout = Literal["time", "topic"]


@pytest.fixture(scope="module")
def s3() -> Iterator[s3fs.S3FileSystem]:
    with moto_s3() as env:
        fs = s3fs.S3FileSystem(endpoint_url=env["AWS_ENDPOINT_URL"])
        fs.mkdir("bags")
        yield fs


def write_camera_and_joints(path: Path, layout: Layout, duration_s: int = 1) -> None:
    """A 320x240 rgb8 camera at 30 Hz and six joints at 100 Hz, uncompressed chunks of 0.25 s.

    ``time``: each chunk holds every topic of its time range, as rosbag2 records.
    ``topic``: each time range is split into one chunk per topic.
    """
    store = get_typestore(Stores.ROS2_HUMBLE)
    image_t, joint_t = "sensor_msgs/msg/Image", "sensor_msgs/msg/JointState"
    types = store.types
    rng = np.random.default_rng(0)

    def header(t_ns: int) -> Any:
        stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // NS, nanosec=t_ns % NS)
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id="base")

    def image(t_ns: int) -> bytes:
        pixels = rng.integers(0, 256, 240 * 320 * 3, dtype=np.uint8)
        msg = types[image_t](header(t_ns), 240, 320, "rgb8", 0, 960, pixels)
        return bytes(store.serialize_cdr(msg, image_t))

    def joints(t_ns: int) -> bytes:
        value = np.full(6, t_ns / NS, dtype=np.float64)
        msg = types[joint_t](header(t_ns), [f"j{i}" for i in range(6)], value, value, value)
        return bytes(store.serialize_cdr(msg, joint_t))

    start = 1_700_000_000 * NS
    events = [(start + k * NS // 30, CAMERA) for k in range(30 * duration_s)]
    events += [(start + k * NS // 100, JOINTS) for k in range(100 * duration_s)]
    with path.open("wb") as handle:
        writer = Writer(handle, compression=CompressionType.NONE, chunk_size=1 << 30)
        writer.start(profile="ros2", library="bagport-test")
        channels = {}
        for topic, msgtype in ((CAMERA, image_t), (JOINTS, joint_t)):
            text = store.generate_msgdef(msgtype, ros_version=2)[0]
            schema = writer.register_schema(msgtype, "ros2msg", text.encode())
            channels[topic] = writer.register_channel(topic, "cdr", schema)
        quarter = NS // 4
        for block in range(4 * duration_s):
            lo, hi = start + block * quarter, start + (block + 1) * quarter
            in_block = sorted(e for e in events if lo <= e[0] < hi)
            groups = (
                [in_block]
                if layout == "time"
                else [[e for e in in_block if e[1] == t] for t in (JOINTS, CAMERA)]
            )
            for group in groups:
                for t_ns, topic in group:
                    data = image(t_ns) if topic == CAMERA else joints(t_ns)
                    writer.add_message(channels[topic], log_time=t_ns, data=data, publish_time=t_ns)
                writer.flush()  # type: ignore[no-untyped-call]
        writer.finish()  # type: ignore[no-untyped-call]


def _values(messages: Iterator[BagMessage]) -> list[tuple[str, int, int | None, list[float]]]:
    return [
        (m.topic, m.log_time_ns, m.header_stamp_ns(), [float(x) for x in m.msg().position]) for m in messages
    ]


def _upload(s3: s3fs.S3FileSystem, local: Path, key: str) -> str:
    if local.is_dir():
        s3.put(str(local), f"bags/{key}", recursive=True)
    else:
        s3.put_file(str(local), f"bags/{key}")
    return f"s3://bags/{key}"


def test_joint_topic_of_per_topic_chunks_is_read_without_the_camera(
    s3: s3fs.S3FileSystem, tmp_path: Path
) -> None:
    local = tmp_path / "per_topic.mcap"
    write_camera_and_joints(local, "topic")
    uri = _upload(s3, local, "per_topic.mcap")
    size = local.stat().st_size
    with open_bag(str(local)) as reader:
        expected = _values(reader.messages([JOINTS]))
        assert reader.transfer.access == "local"
    with open_bag(uri) as reader:
        assert reader.transfer.access == "ranged"
        assert reader.info.size_bytes == size
        assert reader.info.topic(CAMERA).count == 30  # type: ignore[union-attr]
        assert _values(reader.messages([JOINTS])) == expected
        first_pass = reader.transfer.bytes_read
        assert len(expected) == 100
        assert first_pass < 0.05 * size, (first_pass, size)
        assert _values(reader.messages([JOINTS])) == expected
        assert reader.transfer.bytes_read == first_pass  # a second pass fetches nothing again
        log_ns, publish_ns = reader.publish_times_ns([JOINTS])[JOINTS]  # through the mcap library
        assert log_ns.tolist() == publish_ns.tolist() == [t for _, t, _, _ in expected]
        assert reader.transfer.bytes_read - first_pass < 1024  # the same chunks, already spilled
        first_pass = reader.transfer.bytes_read
        frames = [m.msg().data.size for m in reader.messages([CAMERA])]
        assert frames == [240 * 320 * 3] * 30
        assert first_pass < reader.transfer.bytes_read <= size


def test_rosbag2_like_time_chunks_hold_every_topic_so_every_chunk_is_read(
    s3: s3fs.S3FileSystem, tmp_path: Path
) -> None:
    local = tmp_path / "per_time.mcap"
    write_camera_and_joints(local, "time")
    uri = _upload(s3, local, "per_time.mcap")
    size = local.stat().st_size
    with open_bag(str(local)) as reader:
        expected = _values(reader.messages([JOINTS]))
    with open_bag(uri) as reader:
        assert _values(reader.messages([JOINTS])) == expected
        assert 0.9 * size < reader.transfer.bytes_read <= size
        list(reader.messages([JOINTS]))
        assert reader.transfer.bytes_read <= size  # never more than a download, whatever the passes


def test_inspecting_a_remote_mcap_reads_only_its_summary(s3: s3fs.S3FileSystem, tmp_path: Path) -> None:
    local = tmp_path / "inspect.mcap"
    write_camera_and_joints(local, "time")
    uri = _upload(s3, local, "inspect.mcap")
    with open_bag(uri) as reader:
        info = reader.info
        assert [(t.name, t.count) for t in info.topics] == [(CAMERA, 30), (JOINTS, 100)]
        assert reader.transfer.bytes_read < 0.01 * info.size_bytes
        assert reader.transfer.requests <= 4


@pytest.mark.parametrize(
    ("storage", "name", "access"),
    [
        ("mcap", "ep_mcap", "ranged"),
        ("mcap", "named_like_ros1.bag", "ranged"),
        ("sqlite3", "ep_db3", "download"),
    ],
)
def test_rosbag2_folders_on_s3(
    s3: s3fs.S3FileSystem, tmp_path: Path, storage: str, name: str, access: str
) -> None:
    local = tmp_path / name
    write_episode_bag(local, storage, EpisodeSpec(duration_s=0.5, seed=3))  # type: ignore[arg-type]
    uri = _upload(s3, local, name)
    with open_bag(str(local)) as reader:
        expected = _values(reader.messages([EpisodeSpec.JOINT_TOPIC]))
        custom = reader.info.custom_data
    with open_bag(uri) as reader:
        assert reader.transfer.access == access
        assert reader.info.custom_data == custom
        assert _values(reader.messages([EpisodeSpec.JOINT_TOPIC])) == expected
        assert reader.transfer.bytes_read > 0


def test_episode_from_s3_records_how_the_bag_was_read(s3: s3fs.S3FileSystem, tmp_path: Path) -> None:
    local = tmp_path / "ep"
    write_episode_bag(local, "mcap", EpisodeSpec(duration_s=0.5, seed=5))
    uri = _upload(s3, local, "convert/ep")
    text = SAMPLE_CONTRACT.read_text()
    summaries = []
    for bag in (str(local), uri):
        request = EpisodeRequest(
            episode_id=episode_id_for(bag, text, FAST_SETTINGS),
            bag_uri=bag,
            manifest_entry=0,
            staging_uri=str(tmp_path / "staging"),
            contract_text=text,
            contract_name="contract.yaml",
            encoder=FAST_SETTINGS,
        )
        summaries.append(convert_episode(request))
    here, remote = summaries
    size = sum(p.stat().st_size for p in local.iterdir())
    assert here.bag_read == {"access": "local", "bytes_read": 0, "requests": 0, "warnings": []}
    assert remote.bag_read["access"] == "ranged"
    assert 0 < remote.bag_read["bytes_read"] <= size  # three passes, each byte fetched once
    frames = [pq.read_table(Path(s.dir_uri) / "frames.parquet") for s in summaries]
    assert frames[0].equals(frames[1])


def test_a_remote_read_that_fails_in_transit_is_transient_and_leaves_no_scratch(
    s3: s3fs.S3FileSystem, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    local = tmp_path / "flaky.mcap"
    write_camera_and_joints(local, "topic")
    uri = _upload(s3, local, "flaky.mcap")
    reader = open_bag(uri)
    scratch = reader._remote.scratch  # type: ignore[attr-defined]
    assert scratch.is_dir()

    def refuse(*args: object, **kwargs: object) -> bytes:
        raise ConnectionError("connection reset by peer")

    monkeypatch.setattr(reader._remote.fs, "cat_file", refuse)  # type: ignore[attr-defined]
    with pytest.raises(TransientError, match=r"s3://bags/flaky\.mcap: ranged read of .* failed.*try again"):
        list(reader.messages([JOINTS]))
    reader.close()
    reader.close()
    assert not scratch.exists()


@settings(max_examples=60, deadline=None)
@given(
    reads=st.lists(
        st.tuples(st.integers(0, 70_000), st.integers(0, 40_000), st.sampled_from(["read", "peek"])),
        min_size=1,
        max_size=25,
    )
)
def test_ranged_files_return_the_bytes_asked_for_and_fetch_each_byte_once(
    reads: list[tuple[int, int, str]],
) -> None:
    content = np.random.default_rng(1).integers(0, 256, 65_537, dtype=np.uint8).tobytes()
    fs = fsspec.filesystem("memory")
    fs.pipe("/ranged/blob.bin", content)
    fetched: list[tuple[int, int]] = []
    cat_file = fs.cat_file

    def recording_cat_file(path: str, start: int, end: int) -> bytes:
        fetched.append((start, end))
        return bytes(cat_file(path, start=start, end=end))

    bag = RemoteBag(fs, "memory://ranged/blob.bin")
    bag.fs = SimpleNamespace(cat_file=recording_cat_file, size=fs.size)
    try:
        with RemotePath(bag, "/ranged/blob.bin").open() as handle:
            for offset, size, how in reads:
                handle.seek(offset)
                got = handle.read(size) if how == "read" else handle.read(min(size, 8))
                assert got == content[offset : offset + (size if how == "read" else min(size, 8))]
        fetched.sort()
        assert all(a_end <= b_start for (_, a_end), (b_start, _) in itertools.pairwise(fetched))
        assert bag.stats.bytes_read == sum(end - start for start, end in fetched) <= len(content)
    finally:
        bag.close()
