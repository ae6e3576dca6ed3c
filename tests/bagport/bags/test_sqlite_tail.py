"""A SQLite bag file cut short (a copy or download not finished) is said to be one, with where its bytes
end and the length its header gives, and the fix for it: not SQLite's "database disk image is malformed"."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from bagport.bags import open_bag
from bagport.bags.sqlite_tail import SALVAGE_COMMAND, sqlite_cut
from bagport.episode import convert_episode
from bagport.errors import BagportError, BagReadError
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import SMALL_CAMERAS, episode_request

SPEC = EpisodeSpec(duration_s=1.5, cameras=SMALL_CAMERAS)


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("whole") / "ep"
    write_episode_bag(folder, "sqlite3", SPEC)
    return folder


def _page_size(data: bytes) -> int:
    raw = int.from_bytes(data[16:18], "big")
    return 65_536 if raw == 1 else raw


def _cut_copy(bag: Path, target: Path, size: int) -> Path:
    """A copy of the bag folder whose data file keeps its first ``size`` bytes."""
    shutil.copytree(bag, target)
    db3 = target / "ep.db3"
    db3.write_bytes(db3.read_bytes()[:size])
    return target


def test_a_whole_file_and_one_that_is_not_sqlite_have_no_cut(bag: Path, tmp_path: Path) -> None:
    assert sqlite_cut(bag / "ep.db3") is None
    other = tmp_path / "other.db3"
    other.write_bytes(b"not a database" * 100)
    assert sqlite_cut(other) is None


def test_a_file_cut_mid_page_names_its_size_and_the_length_its_header_gives(
    bag: Path, tmp_path: Path
) -> None:
    data = (bag / "ep.db3").read_bytes()
    page = _page_size(data)
    assert len(data) % page == 0 and len(data) // page >= 4
    size = 3 * page + 123
    cut = sqlite_cut(_cut_copy(bag, tmp_path / "ep", size) / "ep.db3")
    assert cut is not None
    assert (cut.size, cut.expected, cut.page_size) == (size, len(data), page)
    said = cut.describe()
    assert f"the file ends at byte {size}, but its header says it holds {len(data) // page} pages" in said
    assert "3 page(s) before are whole" in said and "cut short" in said
    assert f"the whole file is {len(data)} bytes" in cut.fix(metadata_yaml=True)


def test_a_file_cut_at_a_page_boundary_or_inside_its_header_is_cut_too(bag: Path, tmp_path: Path) -> None:
    data = (bag / "ep.db3").read_bytes()
    page = _page_size(data)
    at_boundary = sqlite_cut(_cut_copy(bag, tmp_path / "boundary", 2 * page) / "ep.db3")
    assert at_boundary is not None and at_boundary.expected == len(data)
    in_header = sqlite_cut(_cut_copy(bag, tmp_path / "header", 40) / "ep.db3")
    assert in_header is not None and in_header.expected is None
    assert "inside SQLite's 100-byte header" in in_header.describe()


def test_without_a_page_count_only_a_partial_page_is_a_cut(bag: Path, tmp_path: Path) -> None:
    """A header whose page count is not valid (its valid-for number differs from the change counter, as a
    SQLite older than 3.7.0 leaves it) gives no length to compare: whole pages pass, a partial one is cut."""
    data = bytearray((bag / "ep.db3").read_bytes())
    page = _page_size(bytes(data))
    data[92:96] = (int.from_bytes(data[24:28], "big") + 1).to_bytes(4, "big")
    legacy = tmp_path / "legacy.db3"
    legacy.write_bytes(bytes(data[: 2 * page]))
    assert sqlite_cut(legacy) is None
    legacy.write_bytes(bytes(data[: 2 * page + 7]))
    cut = sqlite_cut(legacy)
    assert cut is not None and cut.expected is None
    assert f"7 bytes into page 3 (a SQLite file is whole pages of {page} bytes)" in cut.describe()


@pytest.mark.parametrize("share", [0.25, 0.9])
def test_opening_or_converting_a_cut_bag_says_it_was_cut_short(
    bag: Path, tmp_path: Path, share: float
) -> None:
    whole = (bag / "ep.db3").stat().st_size
    size = int(whole * share)
    cut = _cut_copy(bag, tmp_path / "ep", size)
    for attempt in (
        lambda: open_bag(str(cut)).close(),
        lambda: convert_episode(episode_request(cut, tmp_path / "s")),
    ):
        with pytest.raises(BagportError) as caught:
            attempt()
        message = str(caught.value)
        assert isinstance(caught.value, BagReadError), message
        assert f"ep.db3: the file ends at byte {size}" in message and "cut short" in message, message
        assert f"the whole file is {whole} bytes" in message and ".dump" in message, message
        assert "malformed" not in message and "Error" not in message, message


@pytest.mark.skipif(shutil.which("sqlite3") is None, reason="the sqlite3 command-line tool is not installed")
def test_the_salvage_the_fix_gives_makes_a_bag_that_converts(bag: Path, tmp_path: Path) -> None:
    """The fix's command, run as given, keeps the rows before the cut, and bagport reads the new file alone."""
    whole = (bag / "ep.db3").stat().st_size
    cut = _cut_copy(bag, tmp_path / "ep", whole // 2)
    command = SALVAGE_COMMAND.replace("FILE", str(cut / "ep.db3"))
    subprocess.run(["bash", "-c", command], cwd=tmp_path, check=True, capture_output=True)
    with open_bag(str(tmp_path / "FIXED.db3")) as salvaged, open_bag(str(bag)) as original:
        assert 0 < salvaged.info.message_count < original.info.message_count
        kept = [(m.topic, m.log_time_ns, m.raw_size, m.header_stamp_ns()) for m in salvaged.messages()]
        first = [(m.topic, m.log_time_ns, m.raw_size, m.header_stamp_ns()) for m in original.messages()]
    assert set(kept) <= set(first)  # the rows kept are recorded ones (topic, time, size, stamp)


def test_a_longer_file_or_one_with_a_write_ahead_log_is_not_called_cut(bag: Path, tmp_path: Path) -> None:
    """Bytes past the header's length are damage, not a cut; a log beside the file holds pages a recorder
    killed mid-checkpoint had not written into it yet."""
    data = (bag / "ep.db3").read_bytes()
    longer = tmp_path / "longer.db3"
    longer.write_bytes(data + b"\0" * 100)
    assert sqlite_cut(longer) is None
    cut = _cut_copy(bag, tmp_path / "ep", len(data) // 2)
    (cut / "ep.db3-wal").write_bytes(b"\0" * 32)
    assert sqlite_cut(cut / "ep.db3") is None


def _damage_a_leaf_page(db3: Path) -> None:
    """The b-tree page type of the messages table's first leaf page, changed: damage, not a cut."""
    data = bytearray(db3.read_bytes())
    page = _page_size(bytes(data))
    leaf = next(at for at in range(page, len(data), page) if data[at] == 0x0D)
    data[leaf] = 0xFF
    db3.write_bytes(bytes(data))


_IN_FOLDER = "convert FIXED.db3 on its own (the folder's metadata.yaml promises the lost messages)."


@pytest.mark.parametrize("kind", ["cut", "damaged"])
@pytest.mark.parametrize("shape", ["bare-db3", "folder-without-metadata", "folder-with-metadata"])
def test_what_to_convert_after_the_salvage_depends_on_a_metadata_yaml(
    bag: Path, tmp_path: Path, kind: str, shape: str
) -> None:
    """Only a folder whose metadata.yaml promises the lost messages is told to convert the salvaged file on
    its own; a .db3 given alone (or a folder without metadata.yaml) has no metadata.yaml to speak of."""
    folder = _cut_copy(bag, tmp_path / "ep", (bag / "ep.db3").stat().st_size)
    db3 = folder / "ep.db3"
    if kind == "cut":
        db3.write_bytes(db3.read_bytes()[: db3.stat().st_size // 2])
    else:
        _damage_a_leaf_page(db3)
    if shape == "bare-db3":
        target = tmp_path / "alone.db3"
        db3.rename(target)
    else:
        target = folder
        if shape == "folder-without-metadata":
            (folder / "metadata.yaml").unlink()
    with pytest.raises(BagReadError) as caught, open_bag(str(target)) as reader:
        list(reader.messages())
    message = str(caught.value)
    fix = caught.value.fix
    assert message.endswith(f"Fix: {fix}") and SALVAGE_COMMAND in fix, message
    if shape == "folder-with-metadata":
        assert fix.endswith(_IN_FOLDER), fix
    else:
        assert fix.endswith("keeps the rows SQLite can still read; convert FIXED.db3 instead."), fix
        assert "metadata.yaml" not in message, message
