"""An append touches only what it changes: every existing data and video file stays byte-identical and
is never opened (inotify locally, the S3 client's reads on moto's server), and the old ``meta/`` files
are neither copied nor downloaded."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import pytest
import s3fs

from bagport.dataset import write_dataset
from bagport.dataset.validate import validate_dataset
from bagport.staging import EpisodeSummary
from tests.fsprobe import watch_opens
from tests.s3 import s3_bucket


def _old_files(root: Path) -> list[Path]:
    return sorted(p for folder in ("data", "videos") for p in (root / folder).rglob("*") if p.is_file())


def test_a_local_append_opens_no_existing_data_or_video_file(
    tmp_path: Path, staged: list[EpisodeSummary]
) -> None:
    out = tmp_path / "ds"
    write_dataset(staged[:1], str(out), robot_type="r")
    old = _old_files(out)
    digests = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in old}
    old_meta = {p: p.stat().st_ino for p in (out / "meta").rglob("*") if p.is_file()}
    with watch_opens(old) as opens:
        write_dataset(staged[1:], str(out), robot_type="r", append=True)
    assert len(old) == 3 and opens.events == []  # one data and two video files, never opened
    assert {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in old} == digests
    kept = [p for p, inode in old_meta.items() if p.is_file() and p.stat().st_ino == inode]
    assert out / "meta/episodes/chunk-000/file-000.parquet" in kept  # linked, not copied
    assert validate_dataset(out, repo_id="test/append-reads", decode_every=1).episodes == 2


def test_the_probe_sees_a_read(tmp_path: Path) -> None:
    path = tmp_path / "f"
    path.write_bytes(b"x")
    with watch_opens([path]) as opens:
        path.read_bytes()
    assert (path, "open") in opens.events


@pytest.fixture
def s3(s3_env: dict[str, str]) -> s3fs.S3FileSystem:
    return s3_bucket(s3_env, "reads")


def test_an_s3_append_reads_no_existing_data_or_video_object(
    s3: s3fs.S3FileSystem, staged: list[EpisodeSummary], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write_dataset(staged[:1], "s3://reads/ds", robot_type="r")
    s3.invalidate_cache()
    before = {p: s3.info(p)["ETag"] for p in s3.find("reads/ds")}
    read: list[str] = []
    for name in ("_open", "_cat_file", "_get_file"):
        method = getattr(s3fs.S3FileSystem, name)

        def spy(self: Any, path: str, *args: Any, _method: Any = method, **kwargs: Any) -> Any:
            read.append(str(path))
            return _method(self, path, *args, **kwargs)

        monkeypatch.setattr(s3fs.S3FileSystem, name, spy)
    s3fs.S3FileSystem.clear_instance_cache()  # new instances bind their sync methods to the spies
    write_dataset(staged[1:], "s3://reads/ds", robot_type="r", append=True)
    monkeypatch.undo()
    s3fs.S3FileSystem.clear_instance_cache()
    old_read = [p for p in read if p.split("reads/ds/", 1)[-1].startswith(("data/", "videos/"))]
    assert old_read == []
    assert any("meta/info.json" in p for p in read)  # the spy sees reads: the few small meta/ files
    s3.invalidate_cache()
    after = {p: s3.info(p)["ETag"] for p in s3.find("reads/ds")}
    assert all(after[p] == etag for p, etag in before.items() if "/meta/" not in p)
    local = tmp_path / "downloaded"
    s3.get("reads/ds", str(local), recursive=True)
    assert validate_dataset(local, repo_id="test/s3-append-reads").episodes == 2
