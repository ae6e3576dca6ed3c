"""The last ``meta/`` files of a write: this run's QA record and report, then the checksums."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pyarrow as pa
from fsspec.core import url_to_fs

from bagport.dataset.bags_index import bag_rows, record_rows, write_bags_index
from bagport.dataset.base import DatasetBase
from bagport.dataset.checksums import run_checksums
from bagport.dataset.layout import BAGS_INDEX_PATH
from bagport.dataset.provenance import episode_provenance, run_record_path, write_run_record
from bagport.dataset.qa import write_qa
from bagport.qa import QAEntry
from bagport.staging import EpisodeSummary

if TYPE_CHECKING:
    from bagport.dataset.session import WriteSession

__all__ = ["finish_meta"]


def finish_meta(
    root: Path,
    session: WriteSession,
    summaries: Sequence[EpisodeSummary],
    qa: Sequence[QAEntry],
    qa_config: dict[str, Any],
    base: DatasetBase | None,
    robot_type: str,
    written: Mapping[str, str],
    run_record: dict[str, Any],
) -> tuple[list[QAEntry], str | None]:
    """Write the QA files (earlier runs' index read from the dataset, never copied), then the run record
    with every episode's provenance and the checksums; returns the QA entries with dataset episode indices and the report's path (if any)."""
    plan = session.plan
    total_frames = plan.first_index + sum(s.frames for s in summaries)
    facts = {
        "episodes": plan.first_episode + len(summaries),
        "added by this run": len(summaries),
        "excluded": sum(e.episode_index is None for e in qa),
        "frames": total_frames,
        "duration_s": round(total_frames / plan.fps, 2),
        "fps": plan.fps,
        "tasks": "; ".join(plan.tasks),
    }
    entries = [
        e if e.episode_index is None else replace(e, episode_index=e.episode_index + plan.first_episode)
        for e in qa
    ]
    qa_report = (
        write_qa(
            root,
            entries,
            facts,
            qa_config,
            base.run_number if base is not None else 0,
            robot_type=robot_type,
            names={f.key: f.names for f in session.features},
            previous=base.root if base is not None else None,
        )
        if entries
        else None
    )
    _write_bags(root, base, summaries, run_record)  # before the checksums, which cover it
    carried = {} if base is None else base.checksums
    record_rel = run_record_path(base)
    tail = run_checksums(root, record_rel, carried, written)
    episodes = (episode_provenance(s, i) for i, s in enumerate(summaries, plan.first_episode))
    write_run_record(root / record_rel, run_record, episodes, tail)
    return entries, qa_report


def _write_bags(
    root: Path, base: DatasetBase | None, summaries: Sequence[EpisodeSummary], run_record: dict[str, Any]
) -> None:
    """The bags table (:mod:`bagport.dataset.bags_index`): the dataset's rows so far and this run's."""
    run = base.run_number if base is not None else 0
    this_run = {
        "manifest": run_record.get("manifest", {}),
        "keep_staging": run_record.get("keep_staging"),
        "episodes": [
            {
                "bag_uri": s.bag_uri,
                "manifest_entry": s.manifest_entry,
                "source_stamp": s.source_stamp,
                "bag_fingerprint": s.bag_fingerprint,
                "staged_episode_id": s.episode_id,
            }
            for s in summaries
        ],
        "excluded": run_record.get("excluded", []),
    }
    rows = [record_rows(this_run, run)]
    if base is not None:
        fs, path = url_to_fs(base.root)
        rows.insert(0, bag_rows(fs, path.rstrip("/")))
    write_bags_index(root / BAGS_INDEX_PATH, pa.concat_tables(rows), run)
