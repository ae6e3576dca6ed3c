"""End to end through the real Prefect engine: a fleet in three storage formats -> a dataset
that the real LeRobot loads, checked frame by frame against the synthetic ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from bagport.columns import vector_column
from bagport.dataset.validate import video_backend
from bagport.synth import EpisodeSpec, GroundTruth, bar_means, decode_frame_index, expected_bar_colours
from flows.cli import main
from tests.helpers import SAMPLE_CONTRACT

pytestmark = pytest.mark.slow

EPISODES = 4
DURATION_S = 2.0
FPS = 30
NS = 1_000_000_000


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("e2e")
    bags = root / "bags"
    assert (
        main(["synth", "--out", str(bags), "--episodes", str(EPISODES), "--duration", str(DURATION_S)]) == 0
    )
    out = root / "dataset"
    code = main(
        [
            "convert",
            "--manifest", str(bags / "manifest.yaml"),
            "--contract", str(SAMPLE_CONTRACT),
            "--output", str(out),
            "--repo-id", "test/sample",
            "--workers", "2",
        ]
    )  # fmt: skip
    assert code == 0
    return bags, out


def _truth(index: int) -> GroundTruth:
    # The same specs `bagport synth` wrote (see write_sample_fleet).
    return GroundTruth(
        EpisodeSpec(
            duration_s=DURATION_S, start_ns=1_700_000_000_000_000_000 + index * 3_600 * NS, seed=index
        )
    )


def test_validate_cli_passes_with_lerobot(
    converted: tuple[Path, Path], capfd: pytest.CaptureFixture[str]
) -> None:
    _, out = converted
    assert main(["validate", str(out), "--repo-id", "test/sample"]) == 0
    printed = capfd.readouterr()
    assert f"{EPISODES} episode(s)" in printed.out
    assert "\r" not in printed.err and "decoded" not in printed.err  # not a terminal: no count redrawn


def test_lerobot_loads_every_frame_with_true_values_and_colours(converted: tuple[Path, Path]) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    _, out = converted
    dataset = LeRobotDataset("test/sample", root=out, video_backend=video_backend())
    run = json.loads((out / "meta/provenance/run.json").read_text())
    assert dataset.meta.total_episodes == EPISODES
    assert [e["storage"] for e in run["episodes"]] == ["mcap", "sqlite3", "ros1", "mcap"]
    checked = 0
    code_mismatches = 0
    for ep in range(EPISODES):
        truth = _truth(ep)
        first_tick = run["episodes"][ep]["first_tick_ns"]
        meta = dataset.meta.episodes[ep]
        start, stop = int(meta["dataset_from_index"]), int(meta["dataset_to_index"])
        joint_ns = truth.joint_stamps_ns()
        cams = {c.name: truth.camera_stamps_ns(c.name) for c in truth.spec.cameras}
        for k, index in enumerate(range(start, stop)):
            item = dataset[index]
            tick = first_tick + k * NS // FPS
            assert int(item["frame_index"]) == k
            assert abs(float(item["timestamp"]) - k / FPS) < 1e-6
            # hold: the newest joint sample at or before the tick, selected by joint name
            held = joint_ns[np.searchsorted(joint_ns, tick, side="right") - 1]
            np.testing.assert_allclose(
                item["observation.state"].numpy(), truth.joint_position(held), atol=1e-6
            )
            assert 0 <= tick - held < NS // truth.spec.joint_rate_hz + 1
            for name, stamps in cams.items():
                rgb = (
                    (item[f"observation.images.{name}"].permute(1, 2, 0).numpy() * 255)
                    .round()
                    .astype(np.uint8)
                )
                code_mismatches += (
                    decode_frame_index(rgb) != (np.searchsorted(stamps, tick, side="right") - 1) % 1024
                )
                # red, green, blue bars in that order: a BGR/RGB swap would trade red and blue
                np.testing.assert_allclose(bar_means(rgb), expected_bar_colours(), atol=20)
            checked += 1
    assert checked == dataset.meta.total_frames == len(dataset)
    # Each frame shows the camera image held at its tick.  LeRobot's default AV1 settings leave a few
    # stale blocks on small images (issue 8 measures this), which can flip one code bit; an alignment
    # error (off by a frame) would break most frames.  The exact, per-frame check with a near-lossless
    # codec is in tests/bagport/episode/test_convert.py.
    print(f"frame-code mismatches: {code_mismatches} of {checked * 2}")
    assert code_mismatches <= 0.05 * checked * 2


def test_layout_stats_and_provenance(converted: tuple[Path, Path]) -> None:
    _bags, out = converted
    info = json.loads((out / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0"
    assert info["robot_type"] == "bagport_sample_arm"
    assert info["features"]["observation.state"]["names"] == [f"position.j{i}" for i in range(1, 7)]
    assert info["features"]["observation.images.front"]["info"]["video.codec"] == "h264"  # bagport's default
    assert sorted(p.name for p in (out / "videos/observation.images.front/chunk-000").iterdir()) == [
        "file-000.mp4"
    ]
    stats = json.loads((out / "meta/stats.json").read_text())
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    state = vector_column(data, "observation.state").astype(np.float64)
    np.testing.assert_allclose(stats["observation.state"]["mean"], state.mean(axis=0), rtol=1e-5)
    np.testing.assert_allclose(stats["observation.state"]["min"], state.min(axis=0), rtol=1e-6)
    assert stats["observation.state"]["count"] == [data.num_rows]
    assert np.asarray(stats["observation.images.wrist"]["mean"]).shape == (3, 1, 1)
    prov = pq.read_table(out / "meta/provenance/chunk-000/file-000.parquet")
    keys = set(prov.column("key").to_pylist())
    assert keys == {"observation.state", "action", "observation.images.front", "observation.images.wrist"}
    assert prov.num_rows == data.num_rows * 4
    run = json.loads((out / "meta/provenance/run.json").read_text())
    assert run["contract"]["text"] == SAMPLE_CONTRACT.read_text()
    assert all(e["bag_fingerprint"].startswith("sha256-index:") for e in run["episodes"])
    assert all(e["alignment"] and e["qa"]["verdict"] for e in run["episodes"])  # read back, not held
    assert not Path(f"{out}.staging").exists()  # staging removed after success
