"""The early process pool: its workers spawn (and import the episode task) before the flow starts,
and the flow's runner, a duplicate, converts in them; without a flow the pool stops."""

from __future__ import annotations

import os

from prefect import flow, task

from flows.runners import EarlyProcessPoolTaskRunner, prefect_api


@task
def _pid() -> int:
    return os.getpid()


@flow
def _pids(count: int) -> list[int]:
    return [future.result() for future in [_pid.submit() for _ in range(count)]]


def _early_pids(runner: EarlyProcessPoolTaskRunner) -> set[int]:
    ((_, executor),) = runner._early
    return set(executor._processes)


def test_the_flow_runs_its_tasks_in_the_workers_started_before_it() -> None:
    runner = EarlyProcessPoolTaskRunner(max_workers=2)
    runner.start_early()
    early = _early_pids(runner)
    try:
        with prefect_api():
            first = _pids.with_options(task_runner=runner)(4)
            second = _pids.with_options(task_runner=runner)(2)  # a second run: a pool of its own
    finally:
        runner.close_early()
    assert len(early) == 2
    assert set(first) <= early
    assert not set(second) & early
    assert not runner._early


def test_a_pool_no_flow_adopted_stops_with_its_workers() -> None:
    runner = EarlyProcessPoolTaskRunner(max_workers=2)
    runner.start_early()
    ((_, executor),) = runner._early
    workers = list(executor._processes.values())
    runner.close_early()
    assert len(workers) == 2
    assert not any(worker.is_alive() for worker in workers)
    assert not runner._early
