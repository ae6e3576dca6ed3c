"""A failure that is not the bag's (a transient I/O error after the retries) is told apart, as typed data,
from bagport's error for a bad bag: the first is tried again by a later run, the second is not."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

import tasks.episode
from bagport.episode import EpisodeRequest
from bagport.errors import BagReadError, TransientError
from bagport.staging import EpisodeSummary
from flows.finished import not_the_bags_fault
from flows.runners import prefect_api
from tasks.episode import convert_batch_task, convert_episode_task


@pytest.fixture(scope="module")
def prefect() -> Iterator[None]:
    with prefect_api():
        yield


def _failing(request: EpisodeRequest) -> EpisodeSummary:
    if request.bag_uri == "flaky":
        raise TransientError("s3://fleet/flaky: download failed (ConnectionResetError); try again")
    if request.bag_uri == "buggy":
        raise RuntimeError("an error bagport did not expect (a bug, an unwrapped I/O error)")
    raise BagReadError("not a bag", uri=request.bag_uri)


@pytest.mark.filterwarnings("ignore:Logger 'prefect.task_runs' attempted")  # a task outside a flow
def test_a_transient_error_after_the_retries_is_not_the_bags_fault(
    prefect: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(tasks.episode, "convert_episode", _failing)
    quick = convert_episode_task.with_options(retry_delay_seconds=0)
    flaky = EpisodeRequest("e", "flaky", 0, str(tmp_path), "", "c.yaml")
    state = quick(flaky, label="flaky", return_state=True)
    assert state.is_failed() and not_the_bags_fault(state)
    state = quick(EpisodeRequest("e", "bad", 0, str(tmp_path), "", "c.yaml"), label="bad", return_state=True)
    assert state.is_failed() and not not_the_bags_fault(state)  # bagport's own error for the bag: settled
    # an error bagport did not expect is not settled either: a later run tries the bag again
    buggy = EpisodeRequest("e", "buggy", 0, str(tmp_path), "", "c.yaml")
    state = quick(buggy, label="buggy", return_state=True)
    assert state.is_failed() and not_the_bags_fault(state)
    # a batch's bag: the same, on its outcome
    monkeypatch.setattr(tasks.episode, "BATCH_RETRY_DELAYS_S", (0, 0))
    bad = EpisodeRequest("e2", "bad", 1, str(tmp_path), "", "c.yaml")
    outcomes = convert_batch_task([flaky, bad], labels=["flaky", "bad"], label="flaky +1")
    assert [(o.error is not None, o.transient) for o in outcomes] == [(True, True), (True, False)]
