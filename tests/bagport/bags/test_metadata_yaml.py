"""metadata.yaml is parsed once per bag open, rosbags' folder reader included, as ruamel parsed it."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest
import rosbags.rosbag2.reader
from rosbags.rosbag2 import Reader, ReaderError
from ruamel.yaml import YAML

from bagport.bags import Storage, detect_storage, metadata_yaml, open_bag
from bagport.bags.layout import plan_reads
from bagport.bags.metadata_yaml import RosbagsMetadataYAML, parse_metadata
from bagport.errors import BagReadError
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import REALBAGS

REAL_METADATA = sorted(REALBAGS.glob("**/metadata.yaml"))


@pytest.mark.parametrize("path", REAL_METADATA, ids=lambda p: str(p.relative_to(REALBAGS).parent))
def test_real_metadata_parses_as_ruamel_parsed_it(path: Path) -> None:
    """rosbags read these with ruamel (YAML 1.2); bagport's libyaml read (1.1) gives the same values."""
    text = path.read_text()
    assert parse_metadata(text) == YAML(typ="safe").load(text)


def test_each_caller_gets_its_own_copy() -> None:
    text = "rosbag2_bagfile_information:\n  version: 9\n  custom_data: {a: b}\n"
    first = parse_metadata(text)
    first["rosbag2_bagfile_information"]["custom_data"]["a"] = "changed"
    assert parse_metadata(text)["rosbag2_bagfile_information"]["custom_data"] == {"a": "b"}


def test_a_bag_open_parses_its_metadata_once(tmp_path: Path) -> None:
    """Detection, layout (custom data with it) and rosbags' reader: three reads of one text, one parse (it was
    four reads and four parses, rosbags' with ruamel)."""
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=0.2))
    metadata_yaml._parsed.cache_clear()
    assert vars(rosbags.rosbag2.reader)["YAML"] is RosbagsMetadataYAML
    with open_bag(str(tmp_path / "ep")) as bag:
        assert bag.info.message_count > 0
    parses = metadata_yaml._parsed.cache_info()
    assert (parses.misses, parses.hits) == (1, 2)


def test_unparsable_metadata_is_still_rosbags_reader_error(tmp_path: Path) -> None:
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(ReaderError, match="Could not load YAML"), Reader(folder):
        pass


BAD_METADATA = pytest.mark.parametrize(
    ("edit", "said"),
    [
        (
            lambda text: b"\xff\xfe" + text.encode(),
            "metadata.yaml is not text (a byte at offset 0 is not UTF-8)",
        ),
        (lambda text: (text + "oops: [unclosed\n").encode(), "metadata.yaml is unreadable (while parsing"),
        (
            lambda text: re.sub(
                r"relative_file_paths:\n(\s+- .*\n)+", "relative_file_paths: 5\n", text
            ).encode(),
            "metadata.yaml is damaged or edited: relative_file_paths is 5, not a list of file names",
        ),
        (
            lambda text: re.sub(r"(?m)^  message_count: \d+", "  message_count: abc", text).encode(),
            "metadata.yaml is damaged or edited: message_count is 'abc', not a whole number",
        ),
        (
            lambda text: b"- " + text.encode().replace(b"\n", b"\n  "),
            "metadata.yaml is damaged or edited: it holds a list, not a mapping with rosbag2_bagfile_information",
        ),
    ],
    ids=["not-text", "not-yaml", "files-not-a-list", "count-not-a-number", "a-list"],
)


def _bag_with_metadata(folder: Path, edit: Callable[[str], bytes]) -> Path:
    write_episode_bag(folder, "mcap", EpisodeSpec(duration_s=0.5, cameras=()))
    metadata = folder / "metadata.yaml"
    metadata.write_bytes(edit(metadata.read_text()))
    return folder


@BAD_METADATA
def test_a_metadata_yaml_of_the_wrong_types_is_one_paragraph(
    tmp_path: Path, edit: Callable[[str], bytes], said: str
) -> None:
    """Fuzzed inputs that escaped as a UnicodeDecodeError or a TypeError from deep in the reader."""
    bag = _bag_with_metadata(tmp_path / "ep", edit)
    with pytest.raises(BagReadError, match=re.escape(said)) as caught:
        open_bag(str(bag))
    assert "Fix: repair metadata.yaml (`ros2 bag reindex`) or delete it" in str(caught.value)


@BAD_METADATA
def test_detection_and_layout_say_the_same_of_a_bad_metadata_yaml(
    tmp_path: Path, edit: Callable[[str], bytes], said: str
) -> None:
    """Whichever reads ``metadata.yaml`` first says the same (detection said other words and fix before)."""
    bag = _bag_with_metadata(tmp_path / "ep", edit)
    with pytest.raises(BagReadError, match=re.escape(said)) as detected:
        detect_storage(bag, "ep")
    with pytest.raises(BagReadError) as planned:
        plan_reads(bag, Storage.MCAP, lambda: tmp_path, "ep")
    assert str(planned.value) == str(detected.value)


def test_a_device_is_no_bag() -> None:
    with pytest.raises(BagReadError, match="is neither a file nor a folder"):
        open_bag("/dev/null")
