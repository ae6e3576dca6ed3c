"""Failure handling in the flow: a bad bag fails its episode and the others go on (default), or stops
the run with nothing written (--fail-fast); only transient I/O errors are retried, with backoff."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

import tasks.episode
from bagport.config import ConvertConfig
from bagport.episode import EpisodeRequest
from bagport.errors import BagReadError, TransientError
from bagport.request import EpisodeOutcome
from bagport.staging import EpisodeSummary
from bagport.synth import CameraSpec, EpisodeSpec, Faults, write_episode_bag
from flows.cli import main
from flows.convert import ConversionError, run_config
from flows.runners import prefect_api
from tasks.episode import convert_episode_task
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT

CAMERAS = (
    CameraSpec("front", "raw", "bgr8", height=32, width=32),
    CameraSpec("wrist", "jpeg", height=32, width=32),
)


@pytest.fixture(scope="module")
def prefect() -> Iterator[None]:
    with prefect_api():
        yield


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A bag that is not a bag first, then three good ones."""
    root = tmp_path_factory.mktemp("fleet")
    (root / "broken.mcap").write_bytes(b"this is not an MCAP file")
    for i, name in enumerate(("a", "b", "c")):
        write_episode_bag(root / name, "mcap", EpisodeSpec(duration_s=0.5, seed=i, cameras=CAMERAS))
    (root / "manifest.yaml").write_text(
        "bags:\n" + "".join(f"  - uri: {n}\n" for n in ("broken.mcap", "a", "b", "c"))
    )
    return root


def _config(fleet: Path, out: Path, **options: Any) -> ConvertConfig:
    return ConvertConfig(
        manifest=str(fleet / "manifest.yaml"), contract=str(SAMPLE_CONTRACT), output=str(out),
        staging=str(out) + ".staging", encoder=FAST_CODEC, runner="thread", workers=1, keep_staging=True,
        **options,
    )  # fmt: skip


def _staged(out: Path) -> list[Path]:
    return sorted(Path(str(out) + ".staging").glob("episodes/*/episode.json"))


def test_fail_fast_stops_at_the_first_failed_bag_and_writes_nothing(
    prefect: None, fleet: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    with pytest.raises(
        ConversionError,
        match=r"(?s)bags\[0\] .*broken\.mcap failed QA or conversion \(.*broken\.mcap.*\) and --fail-fast is set: "
        r"the run stopped \([23] of 4 episode\(s\) were not finished\) and nothing was written",
    ):
        run_config(_config(fleet, out, fail_fast=True))
    assert not out.exists()
    assert {p.name for p in tmp_path.iterdir()} <= {"ds.staging"}  # no half-written dataset beside it
    assert len(_staged(out)) <= 1  # one worker: at most the episode already running finished


def test_fail_fast_under_fail_run_stops_at_the_first_episode_failing_qa(
    prefect: None, tmp_path: Path
) -> None:
    fleet = tmp_path / "fleet"
    spec = EpisodeSpec(duration_s=0.5, cameras=CAMERAS)
    write_episode_bag(fleet / "nan", "mcap", replace(spec, faults=Faults(joint_nan_at_s=0.2)))
    write_episode_bag(fleet / "ok", "mcap", spec)
    (fleet / "manifest.yaml").write_text("bags:\n  - uri: nan\n  - uri: ok\n")
    out = tmp_path / "ds"
    with pytest.raises(
        ConversionError, match=r"bags\[0\] .*nan failed QA or conversion \(QA verdict fail, on_fail"
    ):
        run_config(_config(fleet, out, fail_fast=True, on_qa_fail="fail_run"))
    assert not out.exists()


def test_by_default_a_bad_bag_is_reported_and_the_others_are_converted(
    prefect: None, fleet: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    report = run_config(_config(fleet, out))
    assert report.episodes == 3
    assert [(row.manifest_entry, row.bag_uri.rsplit("/", 1)[-1]) for row in report.excluded] == [
        (0, "broken.mcap")
    ]
    assert "conversion failed" in report.excluded[0].reason
    assert len(_staged(out)) == 3


def test_cli_fail_fast_exits_1_with_one_paragraph(
    fleet: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ds"
    code = main([
        "convert", "--manifest", str(fleet / "manifest.yaml"), "--contract", str(SAMPLE_CONTRACT),
        "--output", str(out), "--runner", "thread", "--workers", "1", "--codec", "h264-fast", "--fail-fast",
    ])  # fmt: skip
    assert code == 1
    err = capsys.readouterr().err
    assert "bagport convert: error: bags[0]" in err and "--fail-fast is set" in err
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.filterwarnings("ignore:Logger 'prefect.task_runs' attempted")  # a task outside a flow
def test_only_transient_errors_are_retried_with_backoff(
    prefect: None, fleet: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert (convert_episode_task.retries, convert_episode_task.retry_delay_seconds) == (2, [2, 10])
    calls: list[str] = []
    summary = EpisodeSummary.from_dict(
        {
            "episode_id": "e", "dir_uri": "mem://e", "bag_uri": "a", "storage": "mcap", "bag_size_bytes": 1,
            "bag_fingerprint": "f", "manifest_entry": 0, "fps": 30, "frames": 3, "first_tick_ns": 0,
            "last_tick_ns": 2, "tasks": ["t"], "task_source": "manifest", "features": [], "stamp_sources": {},
            "videos": {},
        }
    )  # fmt: skip

    def flaky(request: EpisodeRequest) -> EpisodeSummary:
        calls.append(request.bag_uri)
        if request.bag_uri == "flaky" and len(calls) == 1:
            raise TransientError("s3://fleet/flaky: download failed (ConnectionResetError); try again")
        if request.bag_uri == "bad":
            raise BagReadError("not a bag", uri="bad")
        return summary

    monkeypatch.setattr(tasks.episode, "convert_episode", flaky)
    quick = convert_episode_task.with_options(retry_delay_seconds=0)  # the same condition, no waiting
    request = EpisodeRequest("e", "flaky", 0, str(tmp_path), "", "c.yaml")
    result = quick(request, label="flaky")
    assert isinstance(result, EpisodeOutcome) and result.frames == 3 and result.error is None
    assert calls == ["flaky", "flaky"]  # retried once, then succeeded
    calls.clear()
    state = quick(replace(request, bag_uri="bad"), label="bad", return_state=True)
    assert state.is_failed() and state.message == "bad: not a bag"
    assert calls == ["bad"]  # a bad bag is not retried
