"""The run record holds a SHA-256 of every data, video and meta file; validate names the file that changed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bagport.dataset import write_dataset
from bagport.dataset.checksums import verify_checksums
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
