"""A remote bag that cannot be read in place is copied to scratch whole, byte for byte; failures are typed."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import fsspec
import pytest
from fsspec.implementations.memory import MemoryFileSystem

from bagport.bags import download
from bagport.bags.download import download_bag
from bagport.errors import BagReadError, TransientError
from bagport.scratch import scratch_dir


def test_a_local_bag_is_its_own_path_and_nothing_is_copied(tmp_path: Path) -> None:
    bag = tmp_path / "run.db3"
    bag.write_bytes(b"SQLite format 3\x00")
    local, cleanup = download_bag(str(bag), {})
    assert (local, cleanup) == (bag, None)


def test_a_remote_folder_is_copied_whole_with_its_subfolders() -> None:
    fs = fsspec.filesystem("memory")
    files = {"metadata.yaml": b"rosbag2_bagfile_information: {}\n", "run_0.db3": bytes(range(256)) * 3}
    files["nested/extra.bin"] = b"\x00\x01"
    for name, data in files.items():
        fs.pipe(f"/fleet/run/{name}", data)
    local, cleanup = download_bag("memory://fleet/run", {})
    try:
        assert cleanup is not None and local.parent == cleanup and local.name == "run"
        copied = {str(p.relative_to(local)): p.read_bytes() for p in local.rglob("*") if p.is_file()}
        assert copied == files
    finally:
        shutil.rmtree(cleanup or local, ignore_errors=True)


def test_a_missing_remote_bag_names_the_uri_and_leaves_no_scratch(monkeypatch: pytest.MonkeyPatch) -> None:
    made: list[Path] = []

    def recorded(kind: str) -> Path:
        made.append(scratch_dir(kind))
        return made[-1]

    monkeypatch.setattr(download, "scratch_dir", recorded)
    with pytest.raises(BagReadError) as caught:
        download_bag("memory://fleet/gone.db3", {})
    assert caught.value.uri == "memory://fleet/gone.db3"
    assert "does not exist" in str(caught.value) and "check the manifest uri" in str(caught.value)
    assert made and not made[0].exists()


def test_a_dropped_connection_is_transient_and_a_refusal_is_not(monkeypatch: pytest.MonkeyPatch) -> None:
    fsspec.filesystem("memory").pipe("/b/run.db3", b"x")
    failure: list[OSError] = []

    def get_file(self: Any, rpath: str, lpath: str, **kwargs: Any) -> None:
        raise failure[0]

    monkeypatch.setattr(MemoryFileSystem, "get_file", get_file)
    failure[:] = [ConnectionResetError("peer reset the connection")]
    with pytest.raises(TransientError, match="download failed"):
        download_bag("memory://b/run.db3", {})
    failure[:] = [PermissionError("403 AccessDenied")]
    with pytest.raises(BagReadError) as caught:
        download_bag("memory://b/run.db3", {})
    assert caught.value.uri == "memory://b/run.db3"
    assert "access denied" in str(caught.value) and "credentials" in str(caught.value)
