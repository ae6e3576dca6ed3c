"""Per-frame task prompts: the task topic held per frame, then bag metadata, manifest, contract default."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bagport.config import ConvertConfig
from bagport.episode import convert_episode
from bagport.episode.tasks import OPERATOR_PROMPT_KEY, resolve_tasks
from bagport.episode.timeline import TaskMessage
from bagport.errors import ManifestError
from bagport.reduce import reduce_run
from bagport.run import PlannedEpisode, plan_run
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import episode_request

NS = 1_000_000_000
TICKS = np.arange(0, 10, dtype=np.int64) * (NS // 10)
CONTRACT = """\
robot_type: r
fps: 10
observations:
  - {key: observation.state, topic: /joint_states, type: sensor_msgs/msg/JointState}
tasks:
  - {topic: /task_prompt}
"""


def test_the_task_topic_is_held_per_frame(tmp_path: Path) -> None:
    messages = [
        TaskMessage(NS // 2, "place it in the bin"),
        TaskMessage(0, "pick the cube"),
        TaskMessage(NS, " "),
    ]
    tasks, source = resolve_tasks(messages, TICKS, {}, episode_request(tmp_path, tmp_path, task="manifest"))
    assert source == "topic"
    # a prompt counts from its stamp on (out-of-order messages sorted by stamp; blank prompts ignored)
    assert tasks == ["pick the cube"] * 5 + ["place it in the bin"] * 5


def test_frames_before_the_first_prompt_take_the_first_prompt(tmp_path: Path) -> None:
    tasks, _ = resolve_tasks([TaskMessage(NS // 4, "pour")], TICKS, {}, episode_request(tmp_path, tmp_path))
    assert tasks == ["pour"] * 10


@pytest.mark.parametrize(
    ("topic", "custom", "manifest", "contract", "want"),
    [
        ("topic task", "bag task", "manifest task", "contract task", ("topic task", "topic")),
        (None, "bag task", "manifest task", "contract task", ("bag task", "bag_metadata")),
        (None, None, "manifest task", "contract task", ("manifest task", "manifest")),
        (None, None, None, "contract task", ("contract task", "contract")),
    ],
    ids=["topic-first", "then-bag-metadata", "then-manifest", "then-contract-default"],
)
def test_task_sources_in_order_of_precedence(
    tmp_path: Path,
    topic: str | None,
    custom: str | None,
    manifest: str | None,
    contract: str | None,
    want: tuple[str, str],
) -> None:
    messages = [TaskMessage(0, topic)] if topic else []
    custom_data = {OPERATOR_PROMPT_KEY: custom} if custom else {}
    request = episode_request(tmp_path, tmp_path, task=manifest)
    tasks, source = resolve_tasks(messages, TICKS, custom_data, request, contract)
    assert (tasks[0], source) == want
    assert set(tasks) == {want[0]}


def test_no_task_anywhere_says_where_to_put_one(tmp_path: Path) -> None:
    request = episode_request(tmp_path, tmp_path)
    with pytest.raises(
        ManifestError, match=r"has no task prompt.*Fix: add 'task: \.\.\.' to its manifest entry"
    ):
        resolve_tasks([], TICKS, {}, request, "  ")


@pytest.mark.slow
def test_a_prompt_change_mid_episode_switches_the_frames_task_in_lerobot(tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    spec = EpisodeSpec(duration_s=2.0, cameras=(), prompts=((1.0, "place it in the bin"),))
    write_episode_bag(tmp_path / "ep", "mcap", spec)
    (tmp_path / "contract.yaml").write_text(CONTRACT)
    config = ConvertConfig(
        bags_glob=str(tmp_path / "ep"),
        contract=str(tmp_path / "contract.yaml"),
        output=str(tmp_path / "ds"),
        on_qa_fail="keep",
    )
    plan = plan_run(config)
    summaries = [convert_episode(r) for r in plan.requests]
    reduce_run(plan, [PlannedEpisode.of(r) for r in plan.requests])
    dataset = LeRobotDataset("test/tasks", root=tmp_path / "ds")
    assert set(dataset.meta.tasks.index) == {"pick up the red cube", "place it in the bin"}
    first_tick_ns = summaries[0].first_tick_ns
    for k in range(dataset.meta.total_frames):
        tick_ns = first_tick_ns + k * NS // dataset.fps
        switched = tick_ns >= spec.start_ns + NS  # the second prompt is stamped 1.0 s in
        want = "place it in the bin" if switched else "pick up the red cube"
        assert dataset[k]["task"] == want, k
