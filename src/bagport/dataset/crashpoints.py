"""Named commit steps of publishing and appending, and the test-only hook run after each.

Every step that changes what is on disk (or in the object store) calls :func:`reached` with its
name (``local.publish.swapped``, ``s3.committing``...: :data:`STEPS` lists them all). Nothing
happens unless a hook is installed with :func:`set_hook`. The crash-point sweep
(``tests/bagport/dataset/test_crashpoints.py``) installs :func:`kill_after`, which makes the
process SIGKILL itself right after the chosen step; the CLI installs it when the environment
variable ``BAGPORT_CRASH_AT`` names a step (the library itself reads no environment).
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable

__all__ = ["STEPS", "StepHook", "kill_after", "reached", "set_hook"]

StepHook = Callable[[str], None]

STEPS: dict[str, tuple[str, ...]] = {
    "local.publish": ("local.publish.files", "local.publish.built", "local.publish.swapped"),
    "local.append": (
        "local.append.files",
        "local.append.built",
        "local.append.journaled",
        "local.append.moving",
        "local.append.moved",
        "local.append.committed",
        "local.append.cleaned",
    ),
    "s3": (
        "s3.journaled",
        "s3.files",
        "s3.built",
        "s3.staging",
        "s3.staged",
        "s3.committing",
        "s3.retracted",
        "s3.copying",
        "s3.copied",
        "s3.removed",
        "s3.published",
        "s3.cleaned",
    ),
}
"""Every commit step by kind of write (S3 publish and append share theirs), in order."""

_hook: StepHook | None = None


def set_hook(hook: StepHook | None) -> None:
    """Install ``hook`` (called with each step's name as it completes), or remove it with ``None``."""
    global _hook  # noqa: PLW0603 - one process-wide test hook, documented above
    _hook = hook


def reached(step: str) -> None:
    """Mark that ``step`` has completed (runs the installed hook, if any)."""
    if _hook is not None:
        _hook(step)


def kill_after(step: str) -> StepHook:
    """A hook that SIGKILLs this process right after ``step`` (no clean-up of any kind runs)."""
    known = {s for steps in STEPS.values() for s in steps}
    if step not in known:
        raise ValueError(f"unknown commit step {step!r}; known: {', '.join(sorted(known))}")

    def hook(name: str) -> None:
        if name == step:
            os.kill(os.getpid(), signal.SIGKILL)

    return hook
