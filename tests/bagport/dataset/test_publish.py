"""Local publish: --overwrite never leaves a moment without a dataset (renameat2 exchange), and the
fallback of two renames (no exchange on this system) still recovers."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest

import bagport.dataset.publish
from bagport.dataset import DatasetReport, write_dataset
from bagport.dataset.crashpoints import set_hook
from bagport.dataset.publish import exchange
from bagport.dataset.repair import repair_dataset
from bagport.dataset.validate import validate_dataset
from bagport.errors import DatasetWriteError, OutputTakenError
from bagport.staging import EpisodeSummary


def test_exchange_swaps_two_folders_atomically(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a/which").write_text("a")
    (tmp_path / "b").mkdir()
    (tmp_path / "b/which").write_text("b")
    if not exchange(tmp_path / "a", tmp_path / "b"):
        pytest.skip("this file system has no renameat2(RENAME_EXCHANGE); the fallback is tested below")
    assert ((tmp_path / "a/which").read_text(), (tmp_path / "b/which").read_text()) == ("b", "a")


def test_a_reader_polling_during_slow_overwrites_never_finds_the_dataset_missing_or_mixed(
    staged: list[EpisodeSummary], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "ds"
    write_dataset(staged[:1], str(out), robot_type="r")
    seen: list[object] = []
    stop = threading.Event()

    def poll() -> None:
        while not stop.is_set():
            try:
                info = json.loads((out / "meta/info.json").read_text())
                files = sorted(p.name for p in (out / "data/chunk-000").iterdir())
                seen.append((info["total_episodes"], files))
            except (OSError, ValueError) as err:
                seen.append(err)

    set_hook(lambda step: time.sleep(0.05))  # a slow publish: a pause after every commit step
    rename = Path.rename

    def slow_rename(self: Path, target: Path) -> Path:
        time.sleep(0.05)  # and before every rename (two renames in a row would leave a gap this long)
        return rename(self, target)

    monkeypatch.setattr(Path, "rename", slow_rename)
    reader = threading.Thread(target=poll)
    reader.start()
    try:
        for n in range(6):  # replace the dataset back and forth: 1 episode, 2 episodes, ...
            write_dataset(staged[: 2 - n % 2], str(out), robot_type="r", overwrite=True)
    finally:
        set_hook(None)
        stop.set()
        reader.join()
    assert len(seen) > 50, "the reader did not poll during the publishes"
    assert [s for s in seen if not isinstance(s, tuple)] == []  # never missing, never half there
    assert {s[0] for s in seen if isinstance(s, tuple)} == {1, 2}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


@pytest.mark.parametrize("append", [False, True], ids=["overwrite", "append"])
def test_without_an_atomic_exchange_two_renames_do_the_same(
    staged: list[EpisodeSummary], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, append: bool
) -> None:
    monkeypatch.setattr(bagport.dataset.publish, "exchange", lambda a, b: False)
    out = tmp_path / "ds"
    write_dataset(staged[:1], str(out), robot_type="r")
    write_dataset(staged[1:] if append else staged, str(out), robot_type="r", append=append, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []
    assert validate_dataset(out, decode_every=1000).episodes == 2


def test_an_append_that_fails_while_moving_its_files_in_takes_them_out_again(
    staged: list[EpisodeSummary], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "ds"
    write_dataset(staged[:1], str(out), robot_type="r")
    before = {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def disk_full(step: str) -> None:
        if step == "local.append.moving":
            raise OSError(28, "No space left on device")

    set_hook(disk_full)
    try:
        with pytest.raises(OSError, match="No space left"):
            write_dataset(staged[1:], str(out), robot_type="r", append=True)
    finally:
        set_hook(None)
    assert {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


@pytest.mark.parametrize("exchanges", [True, False], ids=["exchange", "two-renames"])
@pytest.mark.parametrize("mode", ["first", "overwrite", "append"])
def test_the_output_stays_held_after_its_commit_until_the_write_ends(
    staged: list[EpisodeSummary], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, mode: str, exchanges: bool
) -> None:
    """What a run does after its commit (the other formats, from its staged episodes) happens while another
    run's recovery still finds the write live and refuses, whatever the commit did with the build folder: a
    first write renames it into place, an overwrite exchanges it with the old dataset (its lock moves with
    it), an append keeps it."""
    if not exchanges:
        monkeypatch.setattr(bagport.dataset.publish, "exchange", lambda a, b: False)
    out = tmp_path / "ds"
    if mode != "first":
        write_dataset(staged[:1], str(out), robot_type="r")
    episodes = staged[1:] if mode == "append" else staged
    checked: list[int] = []

    def after_commit(report: DatasetReport) -> DatasetReport:
        assert (
            report.episodes == 2 and json.loads((out / "meta/info.json").read_text())["total_episodes"] == 2
        )
        with pytest.raises(DatasetWriteError, match="another bagport run is writing"):
            repair_dataset(str(out))
        with pytest.raises(DatasetWriteError, match="another bagport run is writing"):
            write_dataset(staged, str(out), robot_type="r", overwrite=True)
        checked.append(report.episodes)
        return report

    write_dataset(
        episodes,
        str(out),
        robot_type="r",
        overwrite=mode == "overwrite",
        append=mode == "append",
        then=after_commit,
    )
    assert checked == [2]  # the checks above ran, after the commit and before the write ended
    assert repair_dataset(str(out)).actions == ()  # nothing left to recover: the write ended whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    assert validate_dataset(out, decode_every=1000).episodes == 2


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


@pytest.mark.parametrize(
    "step", ["local.publish.files", "local.publish.built"], ids=["while-building", "at-rename"]
)
def test_a_first_write_never_replaces_a_dataset_another_run_published_meanwhile(
    staged: list[EpisodeSummary], tmp_path: Path, step: str
) -> None:
    """Two first writes to one --output that both passed the 'does it exist' check: the second to publish
    is refused with a clear error and the first one's dataset stays whole (it was replaced without a
    word), whether the other dataset appeared while this one built its meta/ or between the check and
    the rename (a directory not empty)."""
    out = tmp_path / "ds"
    other = tmp_path / "other"
    write_dataset(staged[:1], str(other), robot_type="r")
    published = _files(other)

    def another_run_publishes(reached_step: str) -> None:
        if reached_step == step and not out.exists():
            other.rename(out)

    set_hook(another_run_publishes)
    try:
        with pytest.raises(
            OutputTakenError, match="created by another run while this one was writing"
        ) as err:
            write_dataset(staged, str(out), robot_type="r")
    finally:
        set_hook(None)
    assert "--append" in str(err.value) and err.value.output == str(out)
    assert _files(out) == published
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]  # this run's build folder removed
    assert validate_dataset(out, decode_every=1000).episodes == 1


@pytest.mark.parametrize(
    "step", ["local.publish.files", "local.publish.built"], ids=["while-building", "at-rename"]
)
def test_an_overwrite_replaces_a_dataset_published_meanwhile_as_it_was_asked_to(
    staged: list[EpisodeSummary], tmp_path: Path, step: str
) -> None:
    """Also when the other dataset lands between the check and the rename (a raw ENOTEMPTY before)."""
    out = tmp_path / "ds"
    other = tmp_path / "other"
    write_dataset(staged[:1], str(other), robot_type="r")

    def another_run_publishes(reached_step: str) -> None:
        if reached_step == step and not out.exists():
            other.rename(out)

    set_hook(another_run_publishes)
    try:
        write_dataset(staged, str(out), robot_type="r", overwrite=True)
    finally:
        set_hook(None)
    assert validate_dataset(out, decode_every=1000).episodes == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
