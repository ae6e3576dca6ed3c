"""Quality checks of episodes: measured values, thresholds, verdicts and scores.

The library part only measures and judges; where the values come from (a conversion,
or ``bagport qa`` without converting) lives in :mod:`bagport.episode.quality`.
"""

from __future__ import annotations

from bagport.qa.config import Gate, QAConfig, load_qa_config
from bagport.qa.result import (
    CheckResult,
    EpisodeQA,
    QABrief,
    QAEntry,
    Verdict,
    episode_name,
    episode_ref,
    judge,
    score_checks,
)
from bagport.qa.streams import StreamStamps, stream_checks
from bagport.qa.sync import AlignedStamps, alignment_checks, sync_checks
from bagport.qa.values import ValueMonitor

__all__ = [
    "AlignedStamps",
    "CheckResult",
    "EpisodeQA",
    "Gate",
    "QABrief",
    "QAConfig",
    "QAEntry",
    "StreamStamps",
    "ValueMonitor",
    "Verdict",
    "episode_name",
    "episode_ref",
    "alignment_checks",
    "judge",
    "load_qa_config",
    "score_checks",
    "stream_checks",
    "sync_checks",
]
