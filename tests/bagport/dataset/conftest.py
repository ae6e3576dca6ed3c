"""Two small staged episodes (two 32x48 cameras, raw and JPEG), shared by the publish, crash and checksum
tests of this folder; each test module converts them once."""

from __future__ import annotations

import pytest

from bagport.episode import convert_episode
from bagport.staging import EpisodeSummary
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import episode_request

CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=48),
    CameraSpec("wrist", "jpeg", height=32, width=48),
)


@pytest.fixture(scope="module")
def staged(tmp_path_factory: pytest.TempPathFactory) -> list[EpisodeSummary]:
    root = tmp_path_factory.mktemp("bags")
    summaries = []
    for i, name in enumerate(("a", "b")):
        spec = EpisodeSpec(duration_s=0.5, seed=i, cameras=CAMERAS, task=name)
        write_episode_bag(root / name, "mcap", spec)
        summaries.append(convert_episode(episode_request(root / name, root / "staging")))
    return summaries
