"""A finished episode's work folder moves into the staging store: renamed whole on a local store on the
same file system, file by file elsewhere; the same files and modes either way, the summary last."""

from __future__ import annotations

import errno
import json
import tempfile
from pathlib import Path

import fsspec
import pytest

from bagport.episode.publish import publish_episode
from bagport.staging import EPISODE_SUMMARY, EpisodeSummary
from tests.helpers import staged_episodes

FILES = ["frames.parquet", "videos/observation.images.front.mp4"]


@pytest.fixture(scope="module")
def summary(tmp_path_factory: pytest.TempPathFactory) -> EpisodeSummary:
    return staged_episodes(tmp_path_factory.mktemp("staged"), (0.3,))[0]


def _work_folder(root: Path) -> Path:
    work = Path(tempfile.mkdtemp(prefix="bagport-episode-", dir=root))  # private (0700), as scratch_dir's
    (work / "videos").mkdir()
    (work / FILES[0]).write_bytes(b"frames")
    (work / FILES[1]).write_bytes(b"clip")
    return work


def _published(target: Path) -> list[str]:
    return sorted(p.relative_to(target).as_posix() for p in target.rglob("*") if p.is_file())


def _mode(path: Path) -> int:
    return path.stat().st_mode & 0o7777


@pytest.mark.parametrize("same_file_system", [True, False])
def test_a_local_store_gets_the_files_the_summary_and_a_new_folders_modes(
    tmp_path: Path, summary: EpisodeSummary, monkeypatch: pytest.MonkeyPatch, same_file_system: bool
) -> None:
    if not same_file_system:  # the folder's rename fails as across file systems: moved file by file

        def cross_device(self: Path, target: object) -> Path:
            raise OSError(errno.EXDEV, "Invalid cross-device link")

        monkeypatch.setattr(Path, "rename", cross_device)
    work = _work_folder(tmp_path)
    private = _mode(work)
    target = tmp_path / "staging" / "episodes" / "ep0"
    target.mkdir(parents=True)
    (target / "from-an-earlier-attempt").write_text("stale")
    publish_episode(work, str(target), summary)
    assert _published(target) == sorted([EPISODE_SUMMARY, *FILES])
    assert (target / FILES[1]).read_bytes() == b"clip"
    assert json.loads((target / EPISODE_SUMMARY).read_text()) == json.loads(json.dumps(summary.to_dict()))
    plain = tmp_path / "plain"
    plain.mkdir()
    assert _mode(target) == _mode(plain) != private  # not the work folder's 0700
    assert work.exists() is not same_file_system  # renamed away whole, or left for the caller to remove


def test_an_object_store_gets_copies(tmp_path: Path, summary: EpisodeSummary) -> None:
    work = _work_folder(tmp_path)
    publish_episode(work, "memory://staging/episodes/ep0", summary)
    fs = fsspec.filesystem("memory")
    found = sorted(p.removeprefix("/staging/episodes/ep0/") for p in fs.find("/staging/episodes/ep0"))
    assert found == sorted([EPISODE_SUMMARY, *FILES])
    assert fs.cat_file("/staging/episodes/ep0/" + FILES[0]) == b"frames"
