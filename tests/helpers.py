"""Shared test helpers: ground-truth checks on converted episodes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from pydantic import JsonValue

from bagport.episode import EpisodeRequest, episode_id_for
from bagport.staging import EpisodeSummary
from bagport.synth import CameraSpec
from bagport.video.settings import EncoderSettings
from tests.conftest import REALBAGS, REPO

SAMPLE_CONTRACT = REPO / "configs" / "contracts" / "sample_robot.yaml"
FAST_CODEC: dict[str, JsonValue] = {"codec": "libx264", "crf": 18, "preset": "ultrafast", "g": 2}
"""Near-lossless and quick: for tests that check pixels exactly, not the default codec."""
FAST_SETTINGS = EncoderSettings.from_dict(FAST_CODEC)
""":data:`FAST_CODEC` as the settings a worker gets."""
SMALL_CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=48, width=64),
    CameraSpec("wrist", "jpeg", height=48, width=64),
)
"""The sample contract's two cameras, small: a raw ``bgr8`` one and a JPEG one."""

__all__ = [
    "FAST_CODEC",
    "FAST_SETTINGS",
    "REALBAGS",
    "REPO",
    "SAMPLE_CONTRACT",
    "SMALL_CAMERAS",
    "convert_in_process",
    "episode_request",
    "python_output",
    "realbag",
    "staged_episodes",
]


def realbag(relative: str) -> Path:
    """A real bag from ../shared/realbags (read-only); skips with the reason when absent."""
    import pytest  # noqa: PLC0415

    path = REALBAGS / relative
    if not path.exists():
        pytest.skip(f"real bag fixture {path} is not available (shared/realbags missing)")
    return path


def episode_request(
    bag: Path,
    staging: Path,
    contract_text: str | None = None,
    *,
    encoder: dict[str, Any] | None = None,
    task: str | None = None,
) -> EpisodeRequest:
    """The request a worker gets for one bag (default: the sample contract, :data:`FAST_CODEC`)."""
    text = contract_text if contract_text is not None else SAMPLE_CONTRACT.read_text()
    codec = EncoderSettings.from_dict(FAST_CODEC if encoder is None else encoder)
    return EpisodeRequest(
        episode_id=episode_id_for(str(bag), text, codec),
        bag_uri=str(bag),
        manifest_entry=0,
        staging_uri=str(staging),
        contract_text=text,
        contract_name="contract.yaml",
        encoder=codec,
        default_task=task,
    )


def convert_in_process(bags: str, contract_text: str, tmp_path: Path, **options: Any) -> Path:
    """Plan, split bags into episodes, convert each and reduce in this process (no Prefect): the
    dataset's folder.
    ``bags`` is a glob or a manifest; ``options`` are further :class:`ConvertConfig` fields."""
    from bagport.config import ConvertConfig  # noqa: PLC0415
    from bagport.reduce import reduce_run  # noqa: PLC0415
    from bagport.run import plan_run, stage_all  # noqa: PLC0415
    from bagport.segment import segment_request  # noqa: PLC0415

    contract = tmp_path / "contract.yaml"
    contract.write_text(contract_text)
    out = tmp_path / "dataset"
    source = {"manifest": bags} if bags.endswith((".yaml", ".yml", ".csv")) else {"bags_glob": bags}
    config = ConvertConfig(
        contract=str(contract),
        output=str(out),
        staging=str(tmp_path / "staging"),
        encoder=FAST_CODEC,
        **{"on_qa_fail": "keep", **source, **options},
    )
    plan = plan_run(config)
    episodes = [episode for request in plan.requests for episode in segment_request(request).requests]
    reduce_run(plan, stage_all(plan, episodes))
    return out


def staged_episodes(root: Path, durations_s: tuple[float, ...]) -> list[EpisodeSummary]:
    """Episodes of the sample contract (two 32x32 cameras: raw and JPEG) staged under ``root``/staging,
    one synthetic bag each, with :data:`FAST_CODEC`."""
    from bagport.episode import convert_episode  # noqa: PLC0415
    from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag  # noqa: PLC0415

    cameras = (
        CameraSpec("front", "raw", "bgr8", height=32, width=32),
        CameraSpec("wrist", "jpeg", height=32, width=32),
    )
    summaries = []
    for i, duration_s in enumerate(durations_s):
        bag = root / f"ep{i}"
        write_episode_bag(
            bag, "mcap", EpisodeSpec(duration_s=duration_s, seed=i, cameras=cameras, task=f"task {i}")
        )
        summaries.append(convert_episode(episode_request(bag, root / "staging")))
    return summaries


def python_output(code: str, prefect_home: Path, **env: str) -> list[str]:
    """The words ``code`` prints in a fresh interpreter (process-wide state, such as Prefect's database
    configuration or the garbage collector, starts clean) on its own Prefect home and database, with
    ``env`` added to the environment; a failure raises with its output."""
    environment = {**os.environ, "PREFECT_HOME": str(prefect_home), **env}
    environment.pop("PREFECT_API_DATABASE_CONNECTION_URL", None)
    done = subprocess.run(
        [sys.executable, "-c", code], env=environment, capture_output=True, text=True, check=True, timeout=180
    )
    return done.stdout.split()
