"""The synthetic factory writes what its ground truth says, in every storage."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import simplejpeg
from hypothesis import given
from hypothesis import strategies as st

from bagport.bags import open_bag
from bagport.synth import (
    EpisodeSpec,
    bar_means,
    decode_frame_index,
    expected_bar_colours,
    render_frame,
    write_episode_bag,
    write_sample_fleet,
)

NS = 1_000_000_000


@given(index=st.integers(0, 5000), shape=st.sampled_from([(96, 128), (48, 64), (480, 640)]))
def test_frame_index_round_trips(index: int, shape: tuple[int, int]) -> None:
    frame = render_frame(*shape, index)
    assert decode_frame_index(frame) == index % 1024
    np.testing.assert_array_equal(bar_means(frame), expected_bar_colours())


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1"])
def test_bag_matches_ground_truth(tmp_path: Path, storage: str) -> None:
    spec = EpisodeSpec(duration_s=1.0, seed=5)
    path = tmp_path / ("ep.bag" if storage == "ros1" else "ep")
    truth = write_episode_bag(path, storage, spec)  # type: ignore[arg-type]
    with open_bag(str(path)) as reader:
        counts = {t.name: t.count for t in reader.info.topics}
        assert counts["/joint_states"] == truth.joint_stamps_ns().size == 101
        assert counts["/cmd"] == 51
        assert counts["/front/image_raw"] == counts["/wrist/image_raw/compressed"] == 31
        orders = set()
        joint_k = 0
        for m in reader.messages():
            msg = m.msg()
            if m.topic == "/joint_states":
                stamp = truth.joint_stamps_ns()[joint_k]
                assert m.header_stamp_ns() == stamp
                assert m.log_time_ns == stamp + spec.joint_latency_ns
                by_name = dict(zip(msg.name, msg.position, strict=True))
                np.testing.assert_allclose(
                    [by_name[n] for n in spec.joint_names], truth.joint_position(stamp), atol=1e-12
                )
                orders.add(tuple(msg.name))
                joint_k += 1
            elif m.topic == "/front/image_raw":
                assert msg.encoding == "bgr8"
                rgb = np.asarray(msg.data).reshape(msg.height, msg.width, 3)[:, :, ::-1]
                np.testing.assert_array_equal(bar_means(rgb), expected_bar_colours())
                k = int(np.searchsorted(truth.camera_stamps_ns("front"), m.header_stamp_ns() or 0))
                assert decode_frame_index(rgb) == k
            elif m.topic == "/wrist/image_raw/compressed":
                rgb = simplejpeg.decode_jpeg(np.asarray(msg.data).tobytes(), colorspace="RGB")
                assert np.abs(bar_means(rgb) - expected_bar_colours()).max() < 10
        assert len(orders) == 2  # the joint order differs between messages


def test_sample_fleet_cycles_storages_and_writes_a_manifest(tmp_path: Path) -> None:
    paths = write_sample_fleet(tmp_path, episodes=4, duration_s=0.3)
    assert [p.name for p in paths] == ["episode_000", "episode_001", "episode_002.bag", "episode_003"]
    text = (tmp_path / "manifest.yaml").read_text()
    assert "uri: episode_002.bag" in text
    with open_bag(str(paths[1])) as reader:
        assert reader.info.custom_data["lerobot.operator_prompt"] == "place the cube in the bin"
    for path in (paths[0], paths[3]):  # MCAP as `ros2 bag record` writes it: every read checked by CRC
        with open_bag(str(path)) as reader:
            assert reader.info.checksums is not None and reader.info.checksums.checked
