"""End to end: one bag with several demonstrations becomes several LeRobot episodes, each with its label
and task; failed ones are left out (listed) unless kept; manifest windows and gaps split bags too."""

from __future__ import annotations

import json
from collections import Counter
from contextlib import AbstractContextManager
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest

from bagport.bags import BagReader, open_bag
from bagport.config import ConvertConfig
from bagport.dataset.validate import validate_dataset
from bagport.episode import convert_episode
from bagport.reduce import reduce_run
from bagport.run import plan_run, segment_all, stage_all
from bagport.synth import CameraSpec, EpisodeSpec, Window, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT

S = 1_000_000_000
CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=48),
    CameraSpec("wrist", "jpeg", height=32, width=48),
)
TASKS = ("pick up the red cube", "stack the blue block", "place the cube in the bin")
DEMOS = ((0.5, 3.0), (4.5, 7.0), (8.5, 11.0))
"""(START, outcome) of each demonstration in seconds; a RESET follows each outcome by 0.2 s."""
SPEC = EpisodeSpec(
    duration_s=12.0,
    cameras=CAMERAS,
    joint_rate_hz=50.0,
    task=TASKS[0],
    prompts=((4.0, TASKS[1]), (8.0, TASKS[2])),
    events=(
        (0.5, "START"), (3.0, '{"event": "SUCCESS", "note": "clean grasp"}'), (3.2, "RESET"),
        (4.5, "START"), (7.0, '{"event": "FAIL", "note": "dropped the cube"}'), (7.2, "RESET"),
        (8.5, "START"), (11.0, "SUCCESS"), (11.2, "RESET"),
    ),
)  # fmt: skip
GAP_CONTRACT = """
robot_type: arm
fps: 30
observations:
  - {key: observation.state, topic: /joint_states, type: sensor_msgs/msg/JointState, selector: {names: [j1, j2]}}
  - {key: observation.images.front, topic: /front/image_raw, type: sensor_msgs/msg/Image}
actions:
  - key: action
    publish: {topic: /cmd, type: sensor_msgs/msg/JointState}
    selector: {names: [j1, j2]}
default_task: wipe the table
episodes: {gap_s: 1.0}
"""
EPISODES = """
episodes:
  events: {topic: /episode_events, type: std_msgs/msg/String}
"""


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("session")
    write_episode_bag(root / "session", "mcap", SPEC)
    (root / "manifest.yaml").write_text("bags:\n  - uri: session\n")
    (root / "contract.yaml").write_text(SAMPLE_CONTRACT.read_text() + EPISODES)
    return root


def _convert(root: Path, out: Path, contract: str = "contract.yaml", **options: object) -> ConvertConfig:
    config = ConvertConfig(
        manifest=str(root / "manifest.yaml"),
        contract=str(root / contract),
        output=str(out),
        staging=str(root / "staging"),
        encoder=FAST_CODEC,
        keep_staging=True,
        **options,  # type: ignore[arg-type]
    )
    plan = plan_run(config)
    requests, _ = segment_all(plan)
    staged = stage_all(plan, requests)
    reduce_run(plan, staged)
    return config


def _frame_tasks(out: Path) -> list[list[str]]:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    dataset = LeRobotDataset("test/segments", root=out)
    by_episode: dict[int, list[str]] = {}
    for i in range(0, len(dataset), 7):
        item = dataset.hf_dataset[i]
        by_episode.setdefault(int(item["episode_index"]), []).append(
            dataset.meta.tasks.index[int(item["task_index"])]
        )
    return [by_episode[k] for k in sorted(by_episode)]


def test_three_demonstrations_with_one_fail_give_two_episodes_and_one_excluded(
    session: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    _convert(session, out)
    validated = validate_dataset(out, repo_id="test/segments", decode_every=10)
    assert validated.episodes == 2
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [(e["label"], e["label_note"]) for e in episodes] == [("success", "clean grasp"), ("success", "")]
    assert [e["tasks"] for e in episodes] == [[TASKS[0]], [TASKS[2]]]
    assert [set(tasks) for tasks in _frame_tasks(out)] == [{TASKS[0]}, {TASKS[2]}]
    # every frame lies inside its demonstration (bag log time, less the streams' latency), none in a reset
    run = json.loads((out / "meta/provenance/run.json").read_text())
    for record, (start_s, end_s) in zip(run["episodes"], (DEMOS[0], DEMOS[2]), strict=True):
        assert record["label"] == "success"
        first_s = (record["first_tick_ns"] - SPEC.start_ns) / S
        last_s = (record["last_tick_ns"] - SPEC.start_ns) / S
        assert start_s - 0.05 <= first_s < start_s + 0.1
        assert end_s - 0.1 < last_s <= end_s
    excluded = run["excluded"]
    assert [(e["segment"], e["label"], e["note"], e["excluded_by_label"]) for e in excluded] == [
        (1, "failed", "dropped the cube", True)
    ]
    assert excluded[0]["reason"].startswith("labelled failed (dropped the cube)")
    summary = json.loads((out / "meta/qa/summary.json").read_text())
    assert [(e["episode_index"], e["segment"], e["label"]) for e in summary["episodes"]] == [
        (0, 0, "success"),
        (None, 1, "failed"),
        (1, 2, "success"),
    ]
    assert set(pq.read_table(out / "meta/tasks.parquet").to_pandas().index) == {TASKS[0], TASKS[2]}
    assert "session#1 (failed)" in (out / "meta/qa/report.html").read_text()


def test_keep_failed_keeps_the_failed_demonstration_with_its_label_and_task(
    session: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    _convert(session, out, keep_failed=True)
    assert validate_dataset(out, repo_id="test/segments", decode_every=10).episodes == 3
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["label"] for e in episodes] == ["success", "failed", "success"]
    assert [e["tasks"] for e in episodes] == [[t] for t in TASKS]
    assert [set(tasks) for tasks in _frame_tasks(out)] == [{t} for t in TASKS]
    assert list(pq.read_table(out / "meta/tasks.parquet").to_pandas().index) == list(TASKS)


def test_manifest_windows_in_seconds_and_ros_time(session: Path, tmp_path: Path) -> None:
    start_ns = SPEC.start_ns + 8 * S
    (session / "windows.yaml").write_text(
        "bags:\n"
        "  - {uri: session, start_s: 1.0, end_s: 2.5, task: first part}\n"
        f"  - {{uri: session, start_ns: {start_ns}, end_ns: {start_ns + 2 * S}}}\n"
    )
    config = ConvertConfig(
        manifest=str(session / "windows.yaml"),
        contract=str(SAMPLE_CONTRACT),
        output=str(tmp_path / "ds"),
        staging=str(session / "staging-windows"),
        encoder=FAST_CODEC,
    )
    plan = plan_run(config)
    assert len({r.episode_id for r in plan.requests}) == 2
    staged = stage_all(plan)
    reduce_run(plan, staged)
    assert validate_dataset(tmp_path / "ds", repo_id="test/windows", decode_every=10).episodes == 2
    run = json.loads((tmp_path / "ds/meta/provenance/run.json").read_text())
    spans = [
        ((e["first_tick_ns"] - SPEC.start_ns) / S, (e["last_tick_ns"] - SPEC.start_ns) / S)
        for e in run["episodes"]
    ]
    bag_start_s = SPEC.joint_latency_ns / S  # seconds count from the bag's first message
    # ticks start at the first stamp of the latest stream inside the window and end before it closes
    # (stamps are header stamps, up to a frame period and the camera latency before the log time)
    for (first_s, last_s), (start_s, end_s) in zip(
        spans, ((1.0 + bag_start_s, 2.5 + bag_start_s), (8.0, 10.0)), strict=True
    ):
        assert start_s - 0.02 <= first_s < start_s + 0.06
        assert end_s - 0.1 < last_s <= end_s
    # the task topic wins over the manifest task (held from the prompt at 0 s and at 8 s)
    episodes = pq.read_table(tmp_path / "ds/meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["tasks"] for e in episodes] == [[TASKS[0]], [TASKS[2]]]
    assert [e["label"] for e in episodes] == [None, None]


def test_a_silence_longer_than_gap_s_splits_the_bag(tmp_path: Path) -> None:
    spec = replace(
        SPEC,
        duration_s=6.0,
        events=(),
        prompts=(),
        pauses=(Window(2.5, 1.5),),
        task=None,
        cameras=CAMERAS[:1],
    )
    write_episode_bag(tmp_path / "paused", "mcap", spec)
    (tmp_path / "contract.yaml").write_text(GAP_CONTRACT)
    (tmp_path / "manifest.yaml").write_text("bags:\n  - uri: paused\n")
    _convert(tmp_path, tmp_path / "ds")
    assert validate_dataset(tmp_path / "ds", repo_id="test/gaps", decode_every=10).episodes == 2
    run = json.loads((tmp_path / "ds/meta/provenance/run.json").read_text())
    last_first = (run["episodes"][0]["last_tick_ns"] - SPEC.start_ns) / S
    first_second = (run["episodes"][1]["first_tick_ns"] - SPEC.start_ns) / S
    assert last_first < 2.5
    assert 4.0 <= first_second < 4.1
    assert [e["task_source"] for e in run["episodes"]] == ["contract", "contract"]
    assert np.all([e["segment"] is not None for e in run["episodes"]])


def _count_opens(monkeypatch: pytest.MonkeyPatch, *modules: str) -> Counter[str]:
    """How often each module opens a bag from now on."""
    opens: Counter[str] = Counter()
    for module in modules:

        def counting(uri: str, _module: str = module, **options: Any) -> AbstractContextManager[BagReader]:
            opens[_module] += 1
            return open_bag(uri, **options)

        monkeypatch.setattr(f"{module}.open_bag", counting)
    return opens


def test_a_resumed_run_reads_only_the_bags_of_episodes_not_staged_yet(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    demos = ((0.5, "START"), (2.0, "SUCCESS"), (2.5, "START"), (4.5, "SUCCESS"))
    small = (
        CameraSpec("front", "raw", "bgr8", height=16, width=16),
        CameraSpec("wrist", "jpeg", height=16, width=16),
    )
    for i in range(2):
        write_episode_bag(
            tmp_path / f"bag{i}", "mcap", EpisodeSpec(duration_s=5.0, cameras=small, events=demos, seed=i)
        )
    (tmp_path / "manifest.yaml").write_text("bags:\n  - uri: bag0\n  - uri: bag1\n")
    (tmp_path / "contract.yaml").write_text(SAMPLE_CONTRACT.read_text() + EPISODES)
    config = ConvertConfig(
        manifest=str(tmp_path / "manifest.yaml"),
        contract=str(tmp_path / "contract.yaml"),
        output=str(tmp_path / "ds"),
        staging=str(tmp_path / "staging"),
        encoder=FAST_CODEC,
    )
    requests, _ = segment_all(plan_run(config))
    assert len(requests) == 4
    convert_episode(requests[0])  # the run dies after its first episode
    opens = _count_opens(monkeypatch, "bagport.segment.scan", "bagport.episode.convert")
    plan = plan_run(config)  # the resume
    assert segment_all(plan)[0] == requests
    assert opens["bagport.segment.scan"] == 0  # no bag is read to split it again
    staged = stage_all(plan, requests)
    assert opens["bagport.episode.convert"] == 3  # the remaining episodes only
    reduce_run(plan, staged)
    assert validate_dataset(tmp_path / "ds", repo_id="test/resume").episodes == 4
    assert not (tmp_path / "staging").exists()  # the kept segmentations go with the staged episodes


def test_a_discarded_demonstration_is_left_out_with_its_reason(tmp_path: Path) -> None:
    spec = replace(
        SPEC,
        duration_s=5.0,
        prompts=(),
        events=(
            (0.5, "START"),
            (2.0, "SUCCESS"),
            (2.2, "RESET"),
            (2.7, "START"),
            (4.0, "DISCARD"),
            (4.2, "RESET"),
        ),
    )
    write_episode_bag(tmp_path / "session", "mcap", spec)
    (tmp_path / "manifest.yaml").write_text("bags:\n  - uri: session\n")
    (tmp_path / "contract.yaml").write_text(SAMPLE_CONTRACT.read_text() + EPISODES)
    out = tmp_path / "ds"
    _convert(tmp_path, out)
    assert validate_dataset(out, repo_id="test/discard", decode_every=10).episodes == 1
    run = json.loads((out / "meta/provenance/run.json").read_text())
    assert [e["label"] for e in run["episodes"]] == ["success"]
    assert [(e["segment"], e["label"], e["excluded_by_label"]) for e in run["excluded"]] == [
        (1, "discarded", True)
    ]
    assert run["excluded"][0]["reason"].startswith("labelled discarded")
