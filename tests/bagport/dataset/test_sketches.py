"""Dataset quantiles from merged sketches: within the stated bound of the exact ones before and after an
append, stats.json loads in LeRobot, and an append (local and on S3) reads no existing data or video file
and leaves each byte-identical. Also: ``meta/episodes`` rotates by size and an append adds only new
episode files."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from bagport.dataset import DatasetLimits, write_dataset
from bagport.dataset.data_files import DataPlacement
from bagport.dataset.layout import PROVENANCE_PATH, SKETCHES_PATH
from bagport.dataset.meta import load_episode_stats
from bagport.dataset.sketches import DatasetSketches
from bagport.dataset.validate import validate_dataset
from bagport.episode import convert_episode
from bagport.staging import EpisodeSummary
from bagport.stats import QUANTILES, rank_error
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.fswatch import s3_reads, watch_reads
from tests.helpers import SAMPLE_CONTRACT, episode_request
from tests.s3 import s3_bucket

pytestmark = pytest.mark.slow

FRONT = CameraSpec("front", "raw", "bgr8", height=24, width=32)
CONTRACT = SAMPLE_CONTRACT.read_text().replace(
    """  - key: observation.images.wrist       # CompressedImage, jpeg
    topic: /wrist/image_raw/compressed
    type: sensor_msgs/msg/CompressedImage
    align: {strategy: hold, stamp: header}
""",
    "",
)
FIRST_S = (0.3, 0.5, 1.0, 2.0, 4.0, 8.0, 0.4, 6.0)
"""Episodes of very different lengths; each joint a sinusoid (bimodal) with its own offset per episode."""
APPENDED_S = (3.0, 0.3, 5.0)
VECTORS = ("observation.state", "action", "timestamp", "frame_index", "episode_index", "index", "task_index")
LIMITS = DatasetLimits(chunks_size=3, data_files_size_in_mb=0.02, video_files_size_in_mb=0.05)


def _stage(root: Path, durations: tuple[float, ...], first_seed: int) -> list[EpisodeSummary]:
    summaries = []
    for n, duration in enumerate(durations):
        bag = root / f"bag{first_seed + n}"
        spec = EpisodeSpec(duration_s=duration, seed=first_seed + n, cameras=(FRONT,), task=f"task {n % 2}")
        write_episode_bag(bag, "mcap", spec)
        summaries.append(convert_episode(episode_request(bag, root / "staging", CONTRACT)))
    return summaries


@pytest.fixture(scope="module")
def staged(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[EpisodeSummary], list[EpisodeSummary]]:
    root = tmp_path_factory.mktemp("sketches")
    return _stage(root, FIRST_S, 0), _stage(root, APPENDED_S, 100)


def _assert_quantiles_within_bound(root: Path) -> None:
    frame = pd.concat([pd.read_parquet(p) for p in sorted((root / "data").rglob("*.parquet"))])
    written = json.loads((root / "meta/stats.json").read_text())
    eps = rank_error()
    for key in VECTORS:
        values = np.stack([np.atleast_1d(v) for v in frame[key]]).astype(np.float64)
        for stat, q in QUANTILES.items():
            ours = np.asarray(written[key][stat])
            lo = np.quantile(values, max(q - eps, 0.0), axis=0, method="inverted_cdf")
            hi = np.quantile(values, min(q + eps, 1.0), axis=0, method="inverted_cdf")
            assert ours.shape == lo.shape, (key, stat)
            assert np.all((lo <= ours) & (ours <= hi)), (key, stat, ours, lo, hi)
        assert written[key]["count"] == [len(values)]


def _old_files(root: Path) -> dict[Path, bytes]:
    return {
        p: p.read_bytes()
        for folder in ("data", "videos")
        for p in sorted((root / folder).rglob("*"))
        if p.is_file()
    }


def test_local_append_merges_sketches_and_reads_no_old_file(
    staged: tuple[list[EpisodeSummary], list[EpisodeSummary]], tmp_path: Path
) -> None:
    first, appended = staged
    out = tmp_path / "ds"
    write_dataset(first, str(out), robot_type="r", limits=LIMITS)
    _assert_quantiles_within_bound(out)
    assert (out / SKETCHES_PATH).is_file()
    assert "sketch" not in (out / "meta/info.json").read_text()
    episode_files = sorted((out / "meta/episodes").rglob("*.parquet"))
    old = _old_files(out)
    assert len([p for p in old if p.suffix == ".parquet"]) > 1
    with watch_reads(list(old)) as touched:
        write_dataset(appended, str(out), robot_type="r", append=True)
    assert not touched, sorted(map(str, touched))
    assert {p: p.read_bytes() for p in old} == old
    _assert_quantiles_within_bound(out)
    # meta/episodes: the old files stay as they were, the append wrote new ones after them
    after = sorted((out / "meta/episodes").rglob("*.parquet"))
    assert after[: len(episode_files)] == episode_files and len(after) > len(episode_files)
    result = validate_dataset(out)  # LeRobot loads it (stats.json included) and decodes every frame
    assert result.episodes == len(first) + len(appended)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415

    stats = LeRobotDataset("local/ds", root=out).meta.stats
    assert stats is not None
    assert np.asarray(stats["observation.state"]["q01"]).shape == (6,)


def test_episodes_files_rotate_by_size(
    staged: tuple[list[EpisodeSummary], list[EpisodeSummary]], tmp_path: Path
) -> None:
    first, _ = staged
    out = tmp_path / "ds"
    tiny = DatasetLimits(chunks_size=2, data_files_size_in_mb=0.001, video_files_size_in_mb=1)
    write_dataset(first * 4, str(out), robot_type="r", limits=tiny)  # 32 episodes: 4 batches
    files = sorted((out / "meta/episodes").rglob("*.parquet"))
    assert [p.relative_to(out).as_posix() for p in files[:3]] == [
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/episodes/chunk-000/file-001.parquet",
        "meta/episodes/chunk-001/file-000.parquet",
    ]
    rows = pd.concat([pd.read_parquet(p) for p in files])
    assert rows["episode_index"].tolist() == list(range(4 * len(first)))
    for path in files:  # each row names the file it is in
        chunk, file = int(path.parent.name[6:]), int(path.stem[5:])
        table = pd.read_parquet(path)
        assert set(table["meta/episodes/chunk_index"]) == {chunk}
        assert set(table["meta/episodes/file_index"]) == {file}
    assert validate_dataset(out, decode_every=50).episodes == 4 * len(first)


def test_s3_append_reads_no_old_object(
    staged: tuple[list[EpisodeSummary], list[EpisodeSummary]], s3_env: dict[str, str]
) -> None:
    first, appended = staged
    fs = s3_bucket(s3_env, "fleet")
    write_dataset(first, "s3://fleet/sketched", robot_type="r", limits=LIMITS)
    fs.invalidate_cache()
    old = {p: fs.cat_file(p) for p in fs.find("fleet/sketched") if p.split("/")[2] in ("data", "videos")}
    assert old
    with s3_reads() as reads:
        write_dataset(appended, "s3://fleet/sketched", robot_type="r", append=True)
    read_old = [key for key in reads if key.removeprefix("copy:").lstrip("/") in old]
    assert not read_old, read_old
    assert any(key.endswith(SKETCHES_PATH) for key in reads)  # the stored sketch is what it reads
    fs.invalidate_cache()
    assert {p: fs.cat_file(p) for p in old} == old


def test_an_episode_staged_before_sketches_is_sketched_from_its_staged_frames(
    staged: tuple[list[EpisodeSummary], list[EpisodeSummary]], tmp_path: Path
) -> None:
    summary = staged[0][5]
    old = tmp_path / "old-episode"
    shutil.copytree(summary.dir_uri, old)
    stats = json.loads((old / "stats.json").read_text())
    for values in stats.values():
        for name in ("sketch", "step_sketch", "max_step", "max_step_frame"):
            values.pop(name, None)
    (old / "stats.json").write_text(json.dumps(stats))
    placement = DataPlacement(0, 0, 0, summary.frames)
    tasks = np.zeros(summary.frames, dtype=np.int64)
    current, legacy = DatasetSketches(), DatasetSketches()
    fresh = load_episode_stats(summary, 0, placement, tasks, current)
    again = load_episode_stats(replace(summary, dir_uri=str(old)), 0, placement, tasks, legacy)
    assert again.largest_steps == fresh.largest_steps
    for key in ("observation.state", "action"):
        for kind in ("values", "steps"):
            mine, theirs = getattr(current, kind)[key], getattr(legacy, kind)[key]
            assert mine.to_json() == theirs.to_json(), (key, kind)


def test_meta_row_groups_hold_many_episodes_and_lerobot_loads_them(
    staged: tuple[list[EpisodeSummary], list[EpisodeSummary]], tmp_path: Path
) -> None:
    """A writer keeps every row group's metadata until it closes: ``meta/episodes`` and the provenance
    rows go in row groups of many episodes (the commit's memory stays flat), and LeRobot loads them."""
    first, _ = staged
    out = tmp_path / "ds"
    write_dataset(first * 4, str(out), robot_type="r")
    episodes = pq.read_metadata(out / "meta/episodes/chunk-000/file-000.parquet")
    assert [episodes.row_group(n).num_rows for n in range(episodes.num_row_groups)] == [10, 20, 2]
    provenance = pq.ParquetFile(out / PROVENANCE_PATH.format(chunk_index=0, file_index=0))
    assert provenance.metadata.num_row_groups < len(first) * 4
    index = provenance.read(columns=["episode_index"]).column("episode_index").to_numpy()
    assert np.all(np.diff(index) >= 0) and sorted(set(index.tolist())) == list(range(len(first) * 4))
    assert validate_dataset(out, decode_every=50).episodes == 4 * len(first)
