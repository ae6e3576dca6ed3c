"""The output-file plan is pure (summaries and clip sizes in, files out) and follows LeRobot's size rule;
each planned file is written alone, and its small result is all the commit needs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from bagport.dataset.files import plan_files, staged_clip_sizes, write_planned_file
from bagport.dataset.meta import DatasetLimits
from bagport.dataset.videos import plan_video_files
from bagport.staging import EpisodeSummary

MB = 1024 * 1024


def test_clips_group_into_files_by_size_and_roll_over_chunks() -> None:
    sizes = [400_000, 400_000, 400_000, 900_000, 100_000]
    groups = plan_video_files(sizes, file_size_in_mb=1.0, chunks_size=2, start=(0, 1))
    # a file takes clips while its size plus the next clip's stays under the limit (1 MiB here)
    assert groups == [((0, 1), [0, 1]), ((1, 0), [2]), ((1, 1), [3, 4])]
    assert plan_video_files([5 * MB], file_size_in_mb=1.0, chunks_size=10) == [((0, 0), [0])]  # never empty


def test_the_plan_names_every_staged_input_once(staged: list[EpisodeSummary]) -> None:
    keys = [f.key for f in staged[0].features if f.video_info is not None]
    sizes = staged_clip_sizes(staged, keys)
    plan = plan_files(staged, staged[0].features, ["a", "b"], DatasetLimits(), sizes, first_episode=7)
    assert [f.kind for f in plan.files] == ["data", *(["video"] * len(keys))]
    for key in keys:
        (item,) = [f for f in plan.files if f.key == key]
        assert item.episodes == (0, 1)
        assert item.inputs == tuple(s.file(s.videos[key]) for s in staged)
    tiny = plan_files(staged, staged[0].features, ["a"], DatasetLimits(video_files_size_in_mb=1e-6), sizes)
    assert len(tiny.files) == 1 + 2 * len(keys)  # one clip per video file


def test_a_planned_file_reports_what_the_commit_needs(staged: list[EpisodeSummary], tmp_path: Path) -> None:
    keys = [f.key for f in staged[0].features if f.video_info is not None]
    plan = plan_files(
        staged,
        staged[0].features,
        ["a", "b"],
        DatasetLimits(),
        staged_clip_sizes(staged, keys),
        first_index=100,
    )
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
