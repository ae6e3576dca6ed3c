"""The run's progress is visible from its start: 0/N as soon as the episodes are known, then one step per
finished episode (issue 16, finding 6: a bar that moved only per finished episode, nothing for 5-13 s)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bagport.config import ConvertConfig
from bagport.synth import EpisodeSpec, write_episode_bag
from flows.artifacts import LISTENERS
from flows.convert import run_config
from flows.runners import prefect_api
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT


@pytest.mark.slow
def test_progress_shows_zero_of_n_before_any_episode_finishes(tmp_path: Path) -> None:
    for seed in (1, 2, 3):
        write_episode_bag(tmp_path / f"bags/ep{seed}", "mcap", EpisodeSpec(duration_s=0.5, seed=seed))
    config = ConvertConfig(
        bags_glob=str(tmp_path / "bags/*"),
        contract=str(SAMPLE_CONTRACT),
        output=str(tmp_path / "ds"),
        encoder=FAST_CODEC,
        runner="thread",
        workers=1,
        on_qa_fail="keep",
    )
    seen: list[tuple[int, int]] = []

    def listener(done: int, total: int) -> None:
        seen.append((done, total))

    LISTENERS.append(listener)
    try:
        with prefect_api():
            report = run_config(config)
    finally:
        LISTENERS.remove(listener)
    assert report.episodes == 3
    assert seen[0] == (0, 3)  # before the first episode finished
    assert [done for done, _ in seen[1:]] == [1, 2, 3]  # then one step per episode, in order
