"""Shared test helpers: ground-truth checks on converted episodes."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import REALBAGS, REPO

SAMPLE_CONTRACT = REPO / "configs" / "contracts" / "sample_robot.yaml"
FAST_CODEC = {"codec": "libx264", "crf": 18, "preset": "ultrafast", "g": 2}
"""Near-lossless and quick: for tests that check pixels exactly, not the default codec."""

__all__ = ["FAST_CODEC", "REALBAGS", "REPO", "SAMPLE_CONTRACT", "realbag"]


def realbag(relative: str) -> Path:
    """A real bag from ../shared/realbags (read-only); skips with the reason when absent."""
    import pytest  # noqa: PLC0415

    path = REALBAGS / relative
    if not path.exists():
        pytest.skip(f"real bag fixture {path} is not available (shared/realbags missing)")
    return path
