"""Test-wide environment: Prefect and Hugging Face state inside the work tree, offline."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REALBAGS = REPO.parent / "shared" / "realbags"

os.environ.setdefault("PREFECT_HOME", str(REPO / ".prefect"))
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("HF_HOME", str(REPO / ".prefect" / "hf"))
os.environ["HF_HUB_OFFLINE"] = "1"
