"""The output-file plan is pure (summaries and clip sizes in, files out) and follows LeRobot's size rule;
each planned file is written alone, and its small result is all the commit needs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from bagport.dataset import write_dataset
from bagport.dataset.data_files import plan_data_files
from bagport.dataset.files import (
    FilePlan,
    plan_files,
    staged_clip_sizes,
    staged_data_sizes,
    write_planned_file,
)
from bagport.dataset.meta import DatasetLimits
from bagport.dataset.validate import validate_dataset
from bagport.dataset.videos import plan_video_files
from bagport.staging import EpisodeSummary
from tests.s3 import s3_bucket

MB = 1024 * 1024


def test_clips_group_into_files_by_size_and_roll_over_chunks() -> None:
    sizes = [400_000, 400_000, 400_000, 900_000, 100_000]
    groups = plan_video_files(sizes, file_size_in_mb=1.0, chunks_size=2, start=(0, 1))
    # a file takes clips while its size plus the next clip's stays under the limit (1 MiB here)
    assert groups == [((0, 1), [0, 1]), ((1, 0), [2]), ((1, 1), [3, 4])]
    assert plan_video_files([5 * MB], file_size_in_mb=1.0, chunks_size=10) == [((0, 0), [0])]  # never empty


def test_data_files_group_by_lerobots_rule_on_planned_sizes() -> None:
    """LeRobot's data rule: a file rotates when its bytes on disk (4 bytes of magic + its row groups) +
    the episode's frames at the file's average bytes per frame reach the limit; chunks roll over."""
    sizes = [400_000, 600_000, 10_000, 5_000_000, 1_000]
    frames = [100, 100, 10, 1, 1]
    groups = plan_data_files(sizes, frames, file_size_in_mb=1.0, chunks_size=2, start=(0, 1))
    # 1: 400,004 + 100 x 4,000.04 < 1 MiB; 2: 1,000,004 + 10 x 5,000.02 >= 1 MiB (its own 10,000 bytes
    # would have fit: the rule counts the file's average frame, as LeRobot's writer does); 3: one frame
    # at 10,004 / 10 bytes fits, whatever its own size; 4: the file is over the limit
    assert groups == [((0, 1), [0, 1]), ((1, 0), [2, 3]), ((1, 1), [4])]
    assert plan_data_files([5 * MB], [1], file_size_in_mb=1.0, chunks_size=10) == [
        ((0, 0), [0])
    ]  # never empty
    assert plan_data_files([], [], file_size_in_mb=1.0, chunks_size=10) == []


def _plan(
    staged: list[EpisodeSummary], tasks: list[str], limits: DatasetLimits | None = None, **start: Any
) -> FilePlan:
    """The plan of ``staged`` from their staged sizes (``start``: where a dataset continues)."""
    keys = [f.key for f in staged[0].features if f.video_info is not None]
    return plan_files(
        staged,
        staged[0].features,
        tasks,
        limits or DatasetLimits(),
        staged_clip_sizes(staged, keys),
        staged_data_sizes(staged),
        **start,
    )


def test_the_worker_measures_the_row_group_bytes_a_data_file_holds(
    staged: list[EpisodeSummary], tmp_path: Path
) -> None:
    """The plan's estimate: each episode's row group encoded with indices from 0, within a few bytes of
    what it takes on disk at its final indices."""
    plan = _plan(staged, ["a", "b"], first_episode=3, first_index=12_345)
    written = write_planned_file(plan, plan.files[0], str(tmp_path))
    path = tmp_path / written.files[0][0]
    raw = path.read_bytes()
    footer = int.from_bytes(raw[-8:-4], "little")
    row_groups = len(raw) - 4 - footer - 8  # magic, row groups, footer, its length and magic
    planned = sum(s.data_bytes or 0 for s in staged)
    assert all(s.data_bytes for s in staged)
    assert abs(row_groups - planned) <= 16 * len(staged), (row_groups, planned)


def test_an_episode_staged_before_data_bytes_is_sized_by_its_frame_table(
    staged: list[EpisodeSummary],
) -> None:
    older = [
        EpisodeSummary.from_dict({k: v for k, v in s.to_dict().items() if k != "data_bytes"}) for s in staged
    ]
    assert [s.data_bytes for s in older] == [None, None]
    assert staged_data_sizes(older) == [Path(s.file("frames.parquet")).stat().st_size for s in staged]
    assert staged_data_sizes(staged) == [s.data_bytes for s in staged]


def test_the_plan_names_every_staged_input_once(staged: list[EpisodeSummary]) -> None:
    keys = [f.key for f in staged[0].features if f.video_info is not None]
    plan = _plan(staged, ["a", "b"], first_episode=7)
    assert [f.kind for f in plan.files] == ["data", *(["video"] * len(keys))]
    for key in keys:
        (item,) = [f for f in plan.files if f.key == key]
        assert item.episodes == (0, 1)
        assert item.inputs == tuple(s.file(s.videos[key]) for s in staged)
    (item,) = [f for f in plan.files if f.kind == "data"]
    assert item.episodes == (0, 1) and item.inputs == tuple(s.file("frames.parquet") for s in staged)
    tiny = DatasetLimits(data_files_size_in_mb=1e-6, video_files_size_in_mb=1e-6)
    split = _plan(staged, ["a"], tiny, first_index=10, next_data=(0, 3))
    assert len(split.files) == 2 + 2 * len(keys)  # one episode per data file, one clip per video file
    assert [(f.name, f.episodes, f.first_index) for f in split.files if f.kind == "data"] == [
        ("data/chunk-000/file-003.parquet", (0,), 10),
        ("data/chunk-000/file-004.parquet", (1,), 10 + staged[0].frames),
    ]


def test_a_planned_file_reports_what_the_commit_needs(staged: list[EpisodeSummary], tmp_path: Path) -> None:
    plan = _plan(staged, ["a", "b"], first_index=100)
    data = write_planned_file(plan, plan.files[0], str(tmp_path))
    assert [(p.from_index, p.to_index) for p in data.data] == [
        (100, 100 + staged[0].frames),
        (100 + staged[0].frames, 100 + staged[0].frames + staged[1].frames),
    ]
    assert data.task_counts == (((0, staged[0].frames),), ((1, staged[1].frames),))  # task "a", then "b"
    video = write_planned_file(plan, plan.files[1], str(tmp_path))
    ((rel, size, digest),) = video.files
    assert (tmp_path / rel).stat().st_size == size and len(digest) == 64
    assert [round(v.to_timestamp_s - v.from_timestamp_s, 6) for v in video.videos] == [
        round(s.frames / s.fps, 6) for s in staged
    ]
    assert replace(video, files=()).item == plan.files[1]


@pytest.mark.slow
def test_an_s3_build_uploads_every_data_file_its_task_wrote(
    s3_env: dict[str, str], staged: list[EpisodeSummary], tmp_path: Path
) -> None:
    fs = s3_bucket(s3_env, "files")
    report = write_dataset(
        staged, "s3://files/ds", robot_type="r", limits=DatasetLimits(data_files_size_in_mb=1e-6)
    )
    fs.invalidate_cache()
    assert sorted(p.rsplit("/", 2)[-1] for p in fs.find("files/ds/data")) == [
        "file-000.parquet",
        "file-001.parquet",
    ]
    fs.get("files/ds", str(tmp_path / "ds"), recursive=True)
    result = validate_dataset(tmp_path / "ds", repo_id="test/s3-files")
    assert (result.episodes, result.frames_decoded) == (2, report.frames)
