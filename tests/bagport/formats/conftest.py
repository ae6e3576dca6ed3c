"""Two staged episodes of the sample contract and their LeRobot dataset (``<root>/ds``), shared by the
tests of the other formats, which compare their output with it."""

from __future__ import annotations

from pathlib import Path

import pytest

from bagport.dataset import write_dataset
from bagport.staging import EpisodeSummary
from tests.helpers import staged_episodes


@pytest.fixture(scope="module")
def staged(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[EpisodeSummary]]:
    root = tmp_path_factory.mktemp("formats")
    summaries = staged_episodes(root, durations_s=(0.5, 0.8))
    write_dataset(summaries, str(root / "ds"), robot_type="bagport_sample_arm")
    return root, summaries
