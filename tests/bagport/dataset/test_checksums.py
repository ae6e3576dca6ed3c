"""The run record holds a SHA-256 of every data, video and meta file; validate names the file that changed."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from bagport.dataset import write_dataset
from bagport.dataset.checksums import verify_checksums
from bagport.dataset.invariants import FILE_FIX
from bagport.dataset.validate import validate_dataset
from bagport.errors import ValidationError
from bagport.staging import EpisodeSummary


def _listed(root: Path, record: str) -> set[str]:
    return set(json.loads((root / record).read_text())["files"])


def test_every_file_is_recorded_and_an_append_records_the_whole_dataset(
    staged: list[EpisodeSummary], tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    write_dataset(staged[:1], str(out), robot_type="r")
    files = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    assert _listed(out, "meta/provenance/run.json") == files - {"meta/provenance/run.json"}
    write_dataset(staged[1:], str(out), robot_type="r", append=True)
    files = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    assert _listed(out, "meta/provenance/run-001.json") == files - {"meta/provenance/run-001.json"}
    assert verify_checksums(out) == len(files) - 1


def test_a_byte_changed_in_a_video_fails_validate_naming_that_file(
    staged: list[EpisodeSummary], tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    write_dataset(staged, str(out), robot_type="r")
    files = [p for p in out.rglob("*") if p.is_file()]
    assert validate_dataset(out, decode_every=1000).files_checked == len(files) - 1  # all but the record
    video = out / "videos/observation.images.wrist/chunk-000/file-000.mp4"
    data = bytearray(video.read_bytes())
    data[len(data) // 2] ^= 0x01  # one bit, in the middle of the coded frames
    video.write_bytes(bytes(data))
    with pytest.raises(
        ValidationError, match=r"observation\.images\.wrist/chunk-000/file-000\.mp4: changed since"
    ):
        validate_dataset(out, decode_every=1000)


def test_a_data_file_bagport_did_not_write_fails_validate(
    staged: list[EpisodeSummary], tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    write_dataset(staged, str(out), robot_type="r")
    stray = out / "data/chunk-000/file-001.parquet"  # LeRobot would load its rows with the others
    stray.write_bytes((out / "data/chunk-000/file-000.parquet").read_bytes())
    with pytest.raises(ValidationError, match=r"file-001\.parquet: not written by bagport"):
        verify_checksums(out)


def test_a_damaged_data_file_is_named_not_a_traceback(staged: list[EpisodeSummary], tmp_path: Path) -> None:
    """A byte appended to a parquet file breaks its footer: validate names it as changed (the checksums are
    checked before anything reads it), and, with no run record to check against, as unreadable."""
    out = tmp_path / "ds"
    write_dataset(staged, str(out), robot_type="r")
    data = out / "data/chunk-000/file-000.parquet"
    data.write_bytes(data.read_bytes() + b"x")
    with pytest.raises(ValidationError, match=r"data/chunk-000/file-000\.parquet: changed since"):
        validate_dataset(out, decode_every=1000)
    for record in (out / "meta/provenance").glob("run*.json"):
        record.unlink()
    with pytest.raises(ValidationError, match=r"file-000\.parquet: is not a readable parquet file") as err:
        validate_dataset(out, decode_every=1000)
    assert "Fix: " in str(err.value)


def test_a_deleted_video_is_named_with_its_record_and_the_fix(
    staged: list[EpisodeSummary], tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    write_dataset(staged, str(out), robot_type="r")
    video = out / "videos/observation.images.wrist/chunk-000/file-000.mp4"
    video.unlink()
    with pytest.raises(ValidationError) as caught:
        validate_dataset(out, decode_every=1000)
    assert caught.value.path == str(video)
    assert caught.value.fix == FILE_FIX
    assert str(caught.value) == (
        f"{video}: missing, but the run record meta/provenance/run.json lists it. Fix: restore the file from a "
        "backup (or its object store's earlier version), or convert the dataset's bags again into a new "
        "--output (or --overwrite this one)."
    )


def _delete(relative: str) -> Callable[[Path], None]:
    return lambda root: (root / relative).unlink()


def _truncate(relative: str) -> Callable[[Path], None]:
    def damage(root: Path) -> None:
        path = root / relative
        path.write_bytes(path.read_bytes()[:100])

    return damage


def _edit_info(change: dict[str, object]) -> Callable[[Path], None]:
    def damage(root: Path) -> None:
        path = root / "meta/info.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), **change}))

    return damage


@pytest.mark.parametrize(
    ("damage", "said"),
    [
        (
            _delete("data/chunk-000/file-000.parquet"),
            "file-000.parquet: missing (referenced by episodes [0, 1])",
        ),
        (
            _delete("videos/observation.images.front/chunk-000/file-000.mp4"),
            "file-000.mp4: missing (referenced",
        ),
        (_truncate("videos/observation.images.front/chunk-000/file-000.mp4"), "is not a readable video ("),
        (_delete("meta/stats.json"), "meta/stats.json: missing."),
        (_delete("meta/tasks.parquet"), "meta/tasks.parquet: missing."),
        (_delete("meta/info.json"), "meta/info.json: missing: this is not a LeRobot v3.0 dataset folder."),
        (_edit_info({"codebase_version": "v2.1"}), "codebase_version is 'v2.1', expected 'v3.0'."),
        (_edit_info({"total_frames": 1}), "episodes cover"),
    ],
    ids=["data", "video", "unreadable-video", "stats", "tasks", "info", "version", "frames"],
)
def test_every_finding_without_a_run_record_says_how_to_fix_it(
    staged: list[EpisodeSummary], tmp_path: Path, damage: Callable[[Path], None], said: str
) -> None:
    """With no run record to check against (an older dataset, or one copied without it), the invariants find
    the damage; each finding names the file and gives a fix."""
    out = tmp_path / "ds"
    write_dataset(staged, str(out), robot_type="r")
    for record in (out / "meta/provenance").glob("run*.json"):
        record.unlink()
    damage(out)
    with pytest.raises(ValidationError) as caught:
        validate_dataset(out, decode_every=1000)
    message = str(caught.value)
    assert said in message and caught.value.path is not None and message.startswith(caught.value.path), (
        message
    )
    assert caught.value.fix and message.endswith(f" Fix: {caught.value.fix}"), message
    assert "Traceback" not in message and "\n" not in message, message
