"""Validate inputs and plan one request per bag (before the map step)."""

from __future__ import annotations

from prefect import get_run_logger, task

from bagport.config import ConvertConfig
from bagport.run import RunPlan, plan_run

__all__ = ["plan_task"]


@task(name="plan-episodes")
def plan_task(config: ConvertConfig) -> RunPlan:
    plan = plan_run(config)
    get_run_logger().info(
        "%d bag(s) from %s, contract %s (%s, %d fps, %d feature(s))",
        len(plan.requests),
        config.manifest,
        config.contract,
        plan.contract.robot_type,
        plan.contract.fps,
        len(plan.contract.features),
    )
    return plan
