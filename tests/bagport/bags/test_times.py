"""A bag's times come from its data files' indexes, not from a stale ``metadata.yaml``: the real ``wbag``'s
metadata covers only the last of its five files, and a window (``start_s``/``end_s``) of a bag whose
metadata was written for another file converts exactly as the same window of the bag with true metadata."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml

from bagport.bags import open_bag
from bagport.episode import convert_episode
from bagport.episode.checks import bag_fingerprint
from bagport.synth import EpisodeSpec, write_episode_bag
from bagport.synth.write import SynthStorage
from bagport.timewindow import TimeWindow
from tests.helpers import SMALL_CAMERAS, episode_request, realbag

SPEC = EpisodeSpec(duration_s=2.0, cameras=SMALL_CAMERAS)
NS = 1_000_000_000


def test_the_real_split_bag_spans_all_five_files_and_says_its_metadata_is_stale() -> None:
    with open_bag(str(realbag("rosbag2_split/wbag"))) as reader:
        info = reader.info
        stamps = [m.log_time_ns for m in reader.messages()]
    assert (info.start_ns, info.end_ns) == (min(stamps), max(stamps) + 1) == (1000, 2999)
    stale = [w for w in info.warnings if "metadata.yaml gives" in w]
    assert len(stale) == 1 and "2623..3034 ns" in stale[0] and "from 1000 to 2998 ns" in stale[0], stale


def _stale_copy(bag: Path, target: Path, shift_ns: int) -> Path:
    """The bag with a metadata.yaml written as if the recording began ``shift_ns`` later (and ended as it
    does): what a writer that recorded only its last split file's times leaves."""
    shutil.copytree(bag, target)
    metadata = target / "metadata.yaml"
    data = yaml.safe_load(metadata.read_text())
    info = data["rosbag2_bagfile_information"]
    info["starting_time"]["nanoseconds_since_epoch"] += shift_ns
    info["duration"]["nanoseconds"] -= shift_ns
    metadata.write_text(yaml.safe_dump(data))
    return target


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_window_of_a_bag_with_stale_metadata_converts_as_with_true_metadata(
    tmp_path: Path, storage: SynthStorage
) -> None:
    bag = tmp_path / "true" / "ep"
    write_episode_bag(bag, storage, SPEC)
    stale = _stale_copy(bag, tmp_path / "stale" / "ep", NS)
    with open_bag(str(bag)) as true, open_bag(str(stale)) as edited:
        assert (edited.info.start_ns, edited.info.end_ns) == (true.info.start_ns, true.info.end_ns)
        # the fingerprint hashes the listed times, as before: fingerprints recorded in datasets still match
        assert edited.info.listed_span_ns == (true.info.start_ns + NS, true.info.end_ns)
        listed = replace(edited.info, start_ns=true.info.start_ns + NS, listed_span_ns=None)
        assert bag_fingerprint(edited.info) == bag_fingerprint(listed) != bag_fingerprint(true.info)
        assert not [w for w in true.info.warnings if "metadata.yaml gives" in w]
        assert [w for w in edited.info.warnings if "metadata.yaml gives" in w]
    window = TimeWindow(start_s=0.0, end_s=1.0)  # the first second: before the stale metadata's start
    frames = []
    for name, folder in (("true", bag), ("stale", stale)):
        request = replace(episode_request(folder, tmp_path / f"staging-{name}"), window=window)
        summary = convert_episode(request)
        frames.append(pq.read_table(Path(summary.dir_uri) / "frames.parquet"))
    assert frames[0].num_rows > 20 and frames[1].equals(frames[0])
