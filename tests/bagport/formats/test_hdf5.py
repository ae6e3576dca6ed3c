"""``--format hdf5``: ALOHA/ACT-layout episode files that agree with the LeRobot output frame by frame."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from bagport.errors import DatasetWriteError
from bagport.formats.hdf5 import hdf5_path, write_hdf5_dataset
from bagport.staging import EpisodeSummary
from tests.lerobot_frames import lerobot_frames

pytestmark = pytest.mark.slow

CAMERAS = ("observation.images.front", "observation.images.wrist")


def test_the_mapping_of_contract_keys() -> None:
    assert hdf5_path("observation.state") == "observations/qpos"
    assert hdf5_path("observation.velocity") == "observations/qvel"
    assert hdf5_path("observation.images.front") == "observations/images/front"
    assert hdf5_path("observation.gripper.force") == "observations/gripper/force"
    assert hdf5_path("action") == "action"
    assert hdf5_path("action.base") == "actions/base"


def test_hdf5_episodes_equal_the_lerobot_output_frame_by_frame(
    tmp_path: Path, staged: tuple[Path, list[EpisodeSummary]]
) -> None:
    root, summaries = staged
    out = tmp_path / "ds.hdf5"
    report = write_hdf5_dataset(summaries, str(out), robot_type="bagport_sample_arm", run_record={"run": 1})
    assert report.root == str(out) and report.episodes == 2
    assert sorted(p.name for p in out.iterdir()) == ["episode_0.hdf5", "episode_1.hdf5", "meta"]
    info = json.loads((out / "meta/info.json").read_text())
    assert info["format"] == "hdf5" and info["total_frames"] == sum(s.frames for s in summaries)
    assert info["features"]["observations/qpos"]["key"] == "observation.state"
    assert (
        json.loads((out / "meta/provenance/run.json").read_text())["episodes"][1]["bag_uri"]
        == summaries[1].bag_uri
    )
    files = [h5py.File(out / f"episode_{i}.hdf5", "r") for i in range(2)]
    try:
        for i, f in enumerate(files):
            assert (
                f.attrs["fps"] == 30 and f.attrs["task"] == summaries[i].tasks[0] and not f.attrs["compress"]
            )
            assert json.loads(f.attrs["provenance"])["bag_uri"] == summaries[i].bag_uri
            assert f["observations/qpos"].shape == (summaries[i].frames, 6)
            assert tuple(f["observations/qpos"].attrs["names"])[:1] == ("position.j1",)
            assert f["observations/images/front"].chunks == (1, 32, 32, 3)  # written frame by frame
            assert f["tick_ns"][0] == summaries[i].first_tick_ns
            assert np.all(np.diff(f["tick_ns"][:]) > 0)
        compared = 0
        for frame in lerobot_frames(root / "ds"):
            f, n = files[frame.episode_index], frame.frame_index
            assert f["frame_index"][n] == n
            assert f["timestamp"][n] == np.float32(frame.timestamp)
            assert f["task"][n].decode() == frame.task
            np.testing.assert_array_equal(f["observations/qpos"][n], frame.vectors["observation.state"])
            np.testing.assert_array_equal(f["action"][n], frame.vectors["action"])
            for key in CAMERAS:
                # both decode the same staged bitstream: equal, up to the decoders' rounding
                diff = np.abs(f[hdf5_path(key)][n].astype(int) - frame.images[key].astype(int))
                assert diff.max() <= 1, (key, frame.episode_index, n)
            compared += 1
        assert compared == sum(s.frames for s in summaries)
    finally:
        for f in files:
            f.close()


def test_jpeg_variant_decodes_like_alohas_compressed_episodes(
    tmp_path: Path, staged: tuple[Path, list[EpisodeSummary]]
) -> None:
    root, summaries = staged
    out = tmp_path / "jpeg"
    write_hdf5_dataset(summaries, str(out), robot_type="r", run_record={}, jpeg_quality=95)
    with h5py.File(out / "episode_1.hdf5", "r") as f:
        assert f.attrs["compress"]
        lengths = f["compress_len"][:]
        assert lengths.shape == (2, summaries[1].frames)
        frames = [fr for fr in lerobot_frames(root / "ds") if fr.episode_index == 1]
        for number, key in enumerate(CAMERAS):
            rows = f[hdf5_path(key)]
            assert rows.dtype == np.uint8 and rows.shape[1] >= lengths[number].max()
            for frame in frames:
                decoded = cv2.imdecode(rows[frame.frame_index], 1)  # as ALOHA's loaders read it
                assert decoded is not None
                error = np.abs(decoded.astype(int) - frame.images[key].astype(int)).mean()
                assert error < 3.0, (key, frame.frame_index, error)


def test_existing_output_is_kept_and_a_failed_write_changes_nothing(
    tmp_path: Path, staged: tuple[Path, list[EpisodeSummary]]
) -> None:
    _, summaries = staged
    out = tmp_path / "ds.hdf5"
    write_hdf5_dataset(summaries[:1], str(out), robot_type="r", run_record={})
    with pytest.raises(DatasetWriteError, match="already exists; nothing was written"):
        write_hdf5_dataset(summaries, str(out), robot_type="r", run_record={})
    broken = EpisodeSummary.from_dict({**summaries[1].to_dict(), "frames": summaries[1].frames + 5})
    with pytest.raises(DatasetWriteError, match=r"\d+ frames, the episode has \d+"):
        write_hdf5_dataset([summaries[0], broken], str(out), robot_type="r", run_record={}, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["episode_0.hdf5", "meta"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds.hdf5"]  # no build folder left


def test_staging_and_output_on_an_object_store(
    tmp_path: Path, staged: tuple[Path, list[EpisodeSummary]], s3_env: dict[str, str]
) -> None:
    """Clips streamed from S3 staging, the output uploaded under the journal; equal to a local write."""
    import s3fs  # noqa: PLC0415 - the S3 tests only

    _, summaries = staged
    fs = s3fs.S3FileSystem(endpoint_url=s3_env["AWS_ENDPOINT_URL"])
    fs.mkdir("formats")
    remote = []
    for summary in summaries:
        fs.put(summary.dir_uri, f"formats/staging/{summary.episode_id}", recursive=True)
        remote.append(replace(summary, dir_uri=f"s3://formats/staging/{summary.episode_id}"))
    write_hdf5_dataset(remote[:1], "s3://formats/ds.hdf5", robot_type="r", run_record={})
    write_hdf5_dataset(remote, "s3://formats/ds.hdf5", robot_type="r", run_record={}, overwrite=True)
    assert sorted(p.rsplit("/", 1)[-1] for p in fs.ls("formats/ds.hdf5")) == [
        "episode_0.hdf5",
        "episode_1.hdf5",
        "meta",
    ]
    fs.get("formats/ds.hdf5/episode_1.hdf5", str(tmp_path / "remote.hdf5"))
    write_hdf5_dataset(summaries, str(tmp_path / "local"), robot_type="r", run_record={})
    with (
        h5py.File(tmp_path / "remote.hdf5", "r") as a,
        h5py.File(tmp_path / "local/episode_1.hdf5", "r") as b,
    ):
        for name in (
            "observations/qpos",
            "action",
            "observations/images/front",
            "observations/images/wrist",
            "tick_ns",
        ):
            np.testing.assert_array_equal(a[name][:], b[name][:])
