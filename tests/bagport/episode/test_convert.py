"""One bag -> one staged episode, checked against the synthetic ground truth."""

from __future__ import annotations

import errno
import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from bagport.columns import vector_column
from bagport.episode import EpisodeRequest, convert_episode
from bagport.errors import AlignmentError, BagReadError, ContractError, DecodeError, ManifestError
from bagport.staging import read_summary
from bagport.synth import (
    CameraSpec,
    EpisodeSpec,
    bar_means,
    decode_frame_index,
    expected_bar_colours,
    write_episode_bag,
)
from bagport.video import iter_frames
from tests.helpers import SAMPLE_CONTRACT, episode_request, realbag


def _request(
    bag: Path, staging: Path, contract_text: str | None = None, task: str | None = None
) -> EpisodeRequest:
    return episode_request(bag, staging, contract_text, task=task)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1"])
def test_episode_matches_ground_truth(tmp_path: Path, storage: str) -> None:
    spec = EpisodeSpec(duration_s=2.0, seed=3)
    bag = tmp_path / ("ep.bag" if storage == "ros1" else "ep")
    truth = write_episode_bag(bag, storage, spec)  # type: ignore[arg-type]
    summary = convert_episode(_request(bag, tmp_path / "staging"))
    assert read_summary(summary.dir_uri) == summary

    frames = pq.read_table(Path(summary.dir_uri) / "frames.parquet")
    prov = pq.read_table(Path(summary.dir_uri) / "provenance.parquet").to_pylist()
    n = frames.num_rows
    assert n == summary.frames
    # The grid starts when every stream has data and ends at the earliest last message.
    cams = [truth.camera_stamps_ns(c.name) for c in spec.cameras]
    starts = [truth.joint_stamps_ns()[0], truth.action_stamps_ns()[0], *(c[0] for c in cams)]
    ends = [truth.joint_stamps_ns()[-1], truth.action_stamps_ns()[-1], *(c[-1] for c in cams)]
    assert summary.first_tick_ns == max(starts)
    assert summary.last_tick_ns <= min(ends) < summary.last_tick_ns + 1_000_000_000 // 30 + 1
    ticks = summary.first_tick_ns + (np.arange(n) * 1_000_000_000) // 30
    np.testing.assert_array_equal(frames.column("frame_index").to_numpy(), np.arange(n))
    np.testing.assert_allclose(frames.column("timestamp").to_numpy(), np.arange(n) / 30, atol=1e-6)

    # State: each frame holds the latest joint message at or before its tick (header stamps), by joint name.
    state = vector_column(frames, "observation.state")
    joint_stamps = truth.joint_stamps_ns()
    latest = joint_stamps[np.searchsorted(joint_stamps, ticks, side="right") - 1]
    np.testing.assert_allclose(state, truth.joint_position(latest), atol=1e-6)
    action = vector_column(frames, "action")
    action_stamps = truth.action_stamps_ns()
    latest_action = action_stamps[np.searchsorted(action_stamps, ticks, side="right") - 1]
    np.testing.assert_allclose(action, truth.action_position(latest_action), atol=1e-6)

    # Provenance names the message behind every value, with both clocks.
    state_rows = [r for r in prov if r["key"] == "observation.state"]
    assert [r["source_header_ns"] for r in state_rows] == latest.tolist()
    assert all(r["stamp_used"] == "header" for r in state_rows)
    assert all(r["source_log_ns"] - r["source_header_ns"] == spec.joint_latency_ns for r in state_rows)

    # Images: the right camera frame (decoded from the pixels) and the right colours (catches BGR/RGB swaps).
    for cam in spec.cameras:
        stamps = truth.camera_stamps_ns(cam.name)
        expected_index = np.searchsorted(stamps, ticks, side="right") - 1
        decoded = list(iter_frames(Path(summary.dir_uri) / f"videos/observation.images.{cam.name}.mp4"))
        assert len(decoded) == n
        for k, (pts_s, rgb) in enumerate(decoded):
            assert abs(pts_s - k / 30) < 1e-4
            assert decode_frame_index(rgb) == expected_index[k] % 1024
            np.testing.assert_allclose(bar_means(rgb), expected_bar_colours(), atol=20)

    stats = json.loads((Path(summary.dir_uri) / "stats.json").read_text())
    np.testing.assert_allclose(
        stats["observation.state"]["mean"], state.astype(np.float64).mean(axis=0), rtol=1e-6
    )
    assert np.asarray(stats["observation.images.front"]["mean"]).shape == (3, 1, 1)
    assert summary.tasks == (spec.task,)
    assert summary.task_source == "topic"


def test_missing_topic_names_the_bag_and_lists_what_it_has(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5))
    text = SAMPLE_CONTRACT.read_text().replace("/wrist/image_raw/compressed", "/wrist/nope")
    with pytest.raises(
        ContractError, match=r"topic /wrist/nope .* is not in bag .*; the bag has: .*/joint_states"
    ):
        convert_episode(_request(bag, tmp_path / "staging", text))
    assert not (tmp_path / "staging").exists()


def test_selector_that_does_not_fit_names_the_contract_line(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5))
    text = SAMPLE_CONTRACT.read_text().replace("position.j6]", "position.j9]", 1)
    line = 1 + text.splitlines().index("  - key: observation.state")
    with pytest.raises(
        AlignmentError,
        match=r"no message on /joint_states carries all of the joints \[.*'j9'\] \(no message names \['j9'\]; "
        rf"joint lists seen: .*\) \(contract\.yaml:{line}, observations\[key=observation\.state\]\)"
        r" \[topic=/joint_states\]",
    ):
        convert_episode(_request(bag, tmp_path / "staging", text))
    assert not (tmp_path / "staging").exists()


def test_no_task_anywhere_is_an_error_and_manifest_task_is_the_fallback(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5, task=None))
    text = SAMPLE_CONTRACT.read_text().split("tasks:")[0]
    with pytest.raises(ManifestError, match=r"has no task prompt.*add 'task: \.\.\.'"):
        convert_episode(_request(bag, tmp_path / "staging", text))
    summary = convert_episode(_request(bag, tmp_path / "staging", text, task="stack blocks"))
    assert summary.tasks == ("stack blocks",)
    assert summary.task_source == "manifest"


def test_asof_gap_is_an_explicit_error(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(
        bag, "mcap", EpisodeSpec(duration_s=0.5, cameras=(CameraSpec("front", "raw", rate_hz=5.0),))
    )
    text = """\
robot_type: r
fps: 30
observations:
  - key: observation.images.front
    topic: /front/image_raw
    type: sensor_msgs/msg/Image
    align: {strategy: asof, tol_ms: 50}
tasks:
  - {key: task, topic: /task_prompt}
"""
    with pytest.raises(
        AlignmentError, match=r"frames have no 'observation.images.front' message .* raise align.tol_ms"
    ):
        convert_episode(_request(bag, tmp_path / "staging", text))


def test_a_type_bagport_cannot_decode_says_how_to_map_it(tmp_path: Path) -> None:
    bag = realbag("rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap")
    text = """\
robot_type: r
fps: 10
observations:
  - {key: observation.state, topic: /joint_state, type: sensor_msgs/msg/JointState}
  - {key: observation.log, topic: /rosout, type: rcl_interfaces/msg/Log}
"""
    with pytest.raises(
        DecodeError,
        match=r"does not know which fields of rcl_interfaces/msg/Log .*topic=/rosout.*Fix: list the fields in selector\.names",
    ):
        convert_episode(_request(bag, tmp_path / "staging", text, task="t"))


def test_type_mismatch_between_contract_and_bag(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.3))
    text = SAMPLE_CONTRACT.read_text().replace(
        "type: sensor_msgs/msg/Image", "type: sensor_msgs/msg/CompressedImage", 1
    )
    with pytest.raises(
        ContractError,
        match=r"/front/image_raw in bag .* has type sensor_msgs/msg/Image, the contract says sensor_msgs/msg/CompressedImage",
    ):
        convert_episode(_request(bag, tmp_path / "staging", text))


def test_rerun_reuses_finished_episodes_until_the_bag_changes(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5))
    first = convert_episode(_request(bag, tmp_path / "staging"))
    marker = Path(first.dir_uri) / "episode.json"
    written_ns = marker.stat().st_mtime_ns
    again = convert_episode(_request(bag, tmp_path / "staging"))
    assert again == first
    assert marker.stat().st_mtime_ns == written_ns  # not converted again
    shutil.rmtree(bag)  # re-recorded under the same name
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.7, seed=9))
    changed = convert_episode(_request(bag, tmp_path / "staging"))
    assert changed.frames != first.frames
    assert changed.source_stamp != first.source_stamp


def test_a_staging_store_on_another_file_system_gets_the_same_files_copied(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The finished files are renamed into a local staging store on the scratch folder's disk, and copied
    (as to an object store) when it is on another one: the same staged episode either way."""
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5))
    renamed = Path(convert_episode(_request(bag, tmp_path / "same-disk")).dir_uri)

    rename = Path.replace

    def across_disks(self: Path, target: str | Path) -> Path:
        if ".partial-" in self.name:  # the summary's own write, renamed within its folder in the store
            return rename(self, target)
        raise OSError(errno.EXDEV, "Invalid cross-device link", str(self))

    monkeypatch.setattr(Path, "replace", across_disks)
    copied = Path(convert_episode(_request(bag, tmp_path / "other-disk")).dir_uri)
    names = sorted(p.relative_to(renamed).as_posix() for p in renamed.rglob("*") if p.is_file())
    assert names == sorted(p.relative_to(copied).as_posix() for p in copied.rglob("*") if p.is_file())
    assert "videos/observation.images.front.mp4" in names
    for name in ("frames.parquet", "provenance.parquet", "stats.json", "videos/observation.images.front.mp4"):
        assert (renamed / name).read_bytes() == (copied / name).read_bytes(), name


def test_a_short_read_against_the_index_is_an_error_not_a_short_dataset(tmp_path: Path) -> None:
    bag = tmp_path / "ep"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=0.5))
    write_episode_bag(tmp_path / "other", "mcap", EpisodeSpec(duration_s=0.3, seed=9))
    (bag / "ep.mcap").unlink()
    (tmp_path / "other" / "other.mcap").rename(bag / "ep.mcap")  # metadata.yaml now promises more
    with pytest.raises(
        BagReadError, match=r"yielded \d+ messages on /joint_states, its index promises \d+.*reindex"
    ):
        convert_episode(_request(bag, tmp_path / "staging"))
