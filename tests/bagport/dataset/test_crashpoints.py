"""The crash-point sweep: SIGKILL right after every commit step of a first write, an --overwrite and an
--append, local and on S3 (moto's server). After each kill a reader sees the old or the new dataset or
a clear "needs repair" (never a mix); the next run gives exactly the uninterrupted result, with nothing
left beside the dataset, in the object store or in the temporary directory."""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import tempfile
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import s3fs

from bagport.dataset import write_dataset
from bagport.dataset.crashpoints import STEPS, kill_after, set_hook
from bagport.dataset.repair import interrupted_write, repair_dataset
from bagport.dataset.validate import validate_dataset
from bagport.errors import ValidationError
from bagport.staging import EpisodeSummary
from tests.s3 import s3_bucket

Tree = dict[str, str]
SCENARIOS = ("first", "overwrite", "append")


def _tree(root: Path) -> Tree:
    """Every file's MD5 (what S3 reports as the ETag of a single-part object: one listing compares)."""
    return {
        p.relative_to(root).as_posix(): hashlib.md5(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _s3_tree(fs: s3fs.S3FileSystem, root: str) -> Tree:
    fs.invalidate_cache()
    listing = fs.find(root, detail=True)
    return {path[len(root) + 1 :]: str(item["ETag"]).strip('"') for path, item in listing.items()}


def _write(staged: list[EpisodeSummary], scenario: str, output: str) -> None:
    """The run each scenario makes (onto the old dataset, ``a`` alone, unless ``first``)."""
    if scenario == "append":
        write_dataset(staged[1:], output, robot_type="r", append=True)
    else:
        write_dataset(staged, output, robot_type="r", overwrite=scenario == "overwrite")


def _rerun(staged: list[EpisodeSummary], scenario: str, output: str, exists: Callable[[], bool]) -> None:
    """The same command again, after the repair every run starts with: a committed first write or
    append is found done (``convert`` refuses an existing output; ``--append`` skips converted bags)."""
    repair_dataset(output, clean_scratch=True)
    if scenario == "overwrite" or not exists() or (scenario == "append" and not _appended(output)):
        _write(staged, scenario, output)


def _appended(output: str) -> bool:
    from bagport.dataset.base import read_base  # noqa: PLC0415

    return read_base(output).episodes == 2


@pytest.fixture(scope="module")
def old(staged: list[EpisodeSummary], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The dataset the overwrite and the append start from (bag ``a``)."""
    root = tmp_path_factory.mktemp("old") / "ds"
    write_dataset(staged[:1], str(root), robot_type="r")
    return root


@pytest.fixture(scope="module")
def references(
    staged: list[EpisodeSummary], old: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Tree]:
    """The uninterrupted results (and the old dataset), each validated through LeRobot once."""
    root = tmp_path_factory.mktemp("reference")
    trees = {"old": _tree(old)}
    for scenario in SCENARIOS:
        out = root / scenario
        if scenario != "first":
            shutil.copytree(old, out)
        _write(staged, scenario, str(out))
        assert validate_dataset(out, decode_every=1000).episodes == 2
        trees[scenario] = _tree(out)
    return trees


@pytest.fixture
def scratch(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A temporary directory of the test's own (the killed child inherits it)."""
    folder = tmp_path / "scratch"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    yield folder


def _killed_after(step: str, run: Callable[[], None]) -> None:
    """Run ``run`` in a forked child that SIGKILLs itself right after ``step``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # forking a process with threads (moto's)
        pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        try:
            set_hook(kill_after(step))
            run()
        finally:
            os._exit(3)  # the step was never reached
    _, status = os.waitpid(pid, 0)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL, f"{step} was never reached"


def _cases(kind: str) -> list[tuple[str, str]]:
    if kind == "s3":  # a publish and an append commit through the same steps there
        return [(s, step) for s in SCENARIOS for step in STEPS["s3"]]
    publish = [(s, step) for s in ("first", "overwrite") for step in STEPS["local.publish"]]
    return publish + [("append", step) for step in STEPS["local.append"]]


@pytest.mark.parametrize(("scenario", "step"), _cases("local"), ids=str)
def test_a_local_kill_after_each_step_recovers_to_the_uninterrupted_result(
    scenario: str,
    step: str,
    staged: list[EpisodeSummary],
    references: dict[str, Tree],
    old: Path,
    tmp_path: Path,
    scratch: Path,
) -> None:
    out = tmp_path / "ds"
    if scenario != "first":
        shutil.copytree(old, out)
    _killed_after(step, lambda: _write(staged, scenario, str(out)))

    if interrupted_write(out) is not None:
        with pytest.raises(ValidationError, match=r"needs repair.*Fix: run `bagport repair"):
            validate_dataset(out)
    else:  # what a reader sees is the old or the new dataset, whole
        seen = _tree(out) if out.exists() else None
        assert seen in ({} if scenario == "first" else references["old"], references[scenario], None)
        assert seen is not None or scenario == "first"

    _rerun(staged, scenario, str(out), out.exists)
    assert _tree(out) == references[scenario]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "scratch"]  # no build or old folders
    assert list(scratch.iterdir()) == []  # the killed run's temporary folders are gone too


@pytest.fixture
def s3(s3_env: dict[str, str]) -> s3fs.S3FileSystem:
    return s3_bucket(s3_env, "sweep")


@pytest.mark.slow
@pytest.mark.parametrize(("scenario", "step"), _cases("s3"), ids=str)
def test_an_s3_kill_after_each_step_leaves_readers_a_whole_version_and_recovers(
    scenario: str,
    step: str,
    staged: list[EpisodeSummary],
    references: dict[str, Tree],
    old: Path,
    s3: s3fs.S3FileSystem,
    scratch: Path,
) -> None:
    key = f"sweep/{scenario}-{step}"
    output = f"s3://{key}"
    if scenario != "first":
        s3.put(str(old), key, recursive=True)
    _killed_after(step, lambda: _write(staged, scenario, output))

    after_kill = _s3_tree(s3, key)
    seen = {rel: digest for rel, digest in after_kill.items() if not rel.startswith(".bagport-")}
    if STEPS["s3"].index(step) < STEPS["s3"].index("s3.committing"):  # a kill while uploading (finding 4):
        assert seen == ({} if scenario == "first" else references["old"])  # readers keep the old version
    if "meta/info.json" in seen:  # a reader finds a dataset: the old or the new one, byte for byte
        assert seen in (references["old"], references[scenario]), sorted(seen)
    else:  # no dataset (LeRobot refuses to load), and the record says why
        assert ".bagport-journal.json" in after_kill or not seen

    def exists() -> bool:
        s3.invalidate_cache()
        return bool(s3.exists(f"{key}/meta/info.json"))

    _rerun(staged, scenario, output, exists)
    assert _s3_tree(s3, key) == references[scenario]  # nothing staged or journaled is left
    assert list(scratch.iterdir()) == []


def test_every_step_the_code_marks_is_named_and_swept() -> None:
    import re  # noqa: PLC0415

    from tests.helpers import REPO  # noqa: PLC0415

    marked = {
        step
        for path in (REPO / "src/bagport/dataset").glob("*.py")
        for step in re.findall(r'reached\("([^"]+)"\)', path.read_text())
    }
    assert marked == {step for steps in STEPS.values() for step in steps}
    with pytest.raises(ValueError, match=r"unknown commit step 'local\.publish\.typo'"):
        kill_after("local.publish.typo")
