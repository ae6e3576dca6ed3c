"""`bagport convert` on a bag holding several demonstrations: segment tasks fan out, then one convert
task per episode; a failed demonstration is left out, listed, and does not make the run fail."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from flows.cli import main
from tests.helpers import SAMPLE_CONTRACT

SPEC = EpisodeSpec(
    duration_s=7.0,
    cameras=(CameraSpec("front", "raw", "bgr8", height=32, width=48), CameraSpec("wrist", "jpeg", height=32, width=48)),
    joint_rate_hz=50.0,
    prompts=((3.0, "stack the blue block"),),
    events=(
        (0.5, "START"), (2.5, "SUCCESS"), (2.7, "RESET"),
        (4.0, "START"), (6.0, '{"event": "FAIL", "note": "dropped the cube"}'), (6.2, "RESET"),
    ),
)  # fmt: skip


def test_convert_cli_splits_a_bag_and_leaves_out_the_failed_demonstration(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    write_episode_bag(tmp_path / "session", "mcap", SPEC)
    (tmp_path / "m.yaml").write_text("bags:\n  - uri: session\n")
    contract = tmp_path / "c.yaml"
    contract.write_text(SAMPLE_CONTRACT.read_text() + "episodes:\n  events: {topic: /episode_events}\n")
    out = tmp_path / "ds"
    argv = [
        "convert",
        "--manifest",
        str(tmp_path / "m.yaml"),
        "--contract",
        str(contract),
        "--output",
        str(out),
    ]
    code = main([*argv, "--workers", "1", "--runner", "thread"])
    _, err = capfd.readouterr()
    assert code == 0, err
    assert "excluded bags[0] " + str(tmp_path / "session") + "#1: labelled failed (dropped the cube)" in err
    info = json.loads((out / "meta/info.json").read_text())
    assert info["total_episodes"] == 1
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [(e["label"], e["tasks"]) for e in episodes] == [("success", ["pick up the red cube"])]
    assert main(["validate", str(out), "--every", "10"]) == 0
