"""How one episode's task run ended, as the flow reads it: staged, failed for its bag, or failed for a
reason a later run should try again (typed data from the task's outcome or its Prefect state)."""

from __future__ import annotations

from typing import Any, NamedTuple

from prefect.client.schemas.objects import State
from prefect.exceptions import FailedRun

from bagport.episode import EpisodeRequest

__all__ = ["Finished", "not_the_bags_fault"]


class Finished(NamedTuple):
    """How one episode's conversion ended: staged (``error`` ``None``, its QA ``verdict``), or failed;
    ``retryable``: the failure was not the bag's (a transient I/O error after the retries, a crashed or
    cancelled task run), so a later run tries the bag again (:attr:`bagport.selection.EpisodeFailure.retryable`)."""

    request: EpisodeRequest
    error: str | None
    verdict: str | None
    retryable: bool = False


def not_the_bags_fault(state: State[Any]) -> bool:
    """Whether a task run that did not complete failed for a reason other than its bag. Only bagport's own
    error for a bad bag is the bag's: the task returns it as a Failed state, which carries no exception. A
    crash, a cancellation, a transient I/O error still there after Prefect's retries, any other exception,
    or a state whose result cannot be read back is not: a later run tries the bag again rather than skip it
    for good."""
    if state.is_crashed() or state.is_cancelled():
        return True
    try:
        raised = state.result(raise_on_failure=False, retry_result_failure=False)  # never waits
    except Exception:  # unknown, so not settled
        return True
    # bagport's own Failed state carries no exception (read back as None, or as Prefect's FailedRun wrapper)
    return isinstance(raised, BaseException) and not isinstance(raised, FailedRun)
