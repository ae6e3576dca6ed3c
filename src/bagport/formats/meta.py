"""What every non-LeRobot output holds beside its episode files: ``meta/info.json`` and provenance.

``meta/info.json`` names the format, fps, robot type, totals, the episode files (with their bag and
frame count) and how contract keys map to the format's names; ``meta/provenance/`` is the LeRobot
output's (per frame and source: topic, log time, header stamp; ``run.json``: contract, manifest,
bags, encoder), written by the same code (:func:`bagport.dataset.provenance.write_provenance`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bagport.dataset import DatasetReport
from bagport.dataset.data_files import DataPlacement
from bagport.dataset.layout import INFO_PATH
from bagport.dataset.provenance import write_provenance
from bagport.qa import QAEntry
from bagport.staging import EpisodeSummary

__all__ = ["write_format_meta"]


def write_format_meta(
    root: Path,
    fmt: str,
    summaries: Sequence[EpisodeSummary],
    files: Sequence[str],
    *,
    robot_type: str,
    features: dict[str, Any],
    run_record: dict[str, Any],
    qa: Sequence[QAEntry],
    extra: dict[str, Any] | None = None,
) -> DatasetReport:
    """Write ``meta/`` for the episode ``files`` (one per summary, relative to ``root``) and report."""
    placements = []
    first = 0
    for summary in summaries:
        placements.append(DataPlacement(0, 0, first, first + summary.frames))
        first += summary.frames
    write_provenance(root, summaries, placements, run_record)
    fps = summaries[0].fps
    tasks = list(dict.fromkeys(t for s in summaries for t in s.tasks))
    info = {
        "format": fmt,
        "robot_type": robot_type,
        "fps": fps,
        "total_episodes": len(summaries),
        "total_frames": first,
        "tasks": tasks,
        "features": features,
        **(extra or {}),
        "episodes": [
            {
                "episode_index": i,
                "file": name,
                "frames": s.frames,
                "tasks": list(s.tasks),
                "bag_uri": s.bag_uri,
            }
            for i, (s, name) in enumerate(zip(summaries, files, strict=True))
        ],
    }
    (root / INFO_PATH).parent.mkdir(parents=True, exist_ok=True)
    (root / INFO_PATH).write_text(json.dumps(info, indent=2))
    size = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    video_keys = tuple(f.key for f in summaries[0].features if f.video_info is not None)
    return DatasetReport(
        str(root),
        len(summaries),
        first,
        tuple(tasks),
        video_keys,
        size,
        first / fps,
        tuple(e.brief() for e in qa if e.episode_index is None),
        tuple(e.brief() for e in qa),
    )
