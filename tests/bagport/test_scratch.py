"""Temporary folders carry their process id; a run removes those of dead processes and no others."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from bagport.scratch import clean_dead_scratch, scratch_dir


def _dead_pid() -> int:
    child = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], check=True, capture_output=True, text=True
    )
    return int(child.stdout)


def test_only_the_folders_of_dead_processes_are_removed(tmp_path: Path) -> None:
    dead = _dead_pid()
    for kind in ("episode", "link", "append", "dataset", "clips"):
        (tmp_path / f"bagport-{kind}-{dead}-x1y2z3").mkdir()
    (tmp_path / f"bagport-episode-{dead}-x1y2z3" / "clip.mp4").write_bytes(b"...")
    alive = [
        f"bagport-episode-{os.getpid()}-abc",  # this process
        f"bagport-link-{os.getppid()}-abc",  # a live one
        "bagport-episode-k2j3h4",  # no pid in the name (an older bagport): not ours to judge
        f"other-episode-{dead}-abc",  # not bagport's
    ]
    for name in alive:
        (tmp_path / name).mkdir()
    (tmp_path / f"bagport-dataset-{dead}-file").write_text("a file, not a folder")
    removed = clean_dead_scratch(tmp_path)
    assert len(removed) == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*alive, f"bagport-dataset-{dead}-file"])


def test_a_scratch_folder_names_its_process() -> None:
    import tempfile  # noqa: PLC0415

    folder = scratch_dir("episode")
    try:
        assert folder.parent == Path(tempfile.gettempdir())
        assert folder.name.startswith(f"bagport-episode-{os.getpid()}-")
    finally:
        folder.rmdir()
