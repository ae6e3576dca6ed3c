"""The reduce of a run as library calls: select the staged episodes the run keeps, write the dataset
(in this process with :func:`reduce_run`; the flow writes each output file as a task, ``flows/reduce.py``),
then the other formats and the staging clean-up. The plan side is :mod:`bagport.run`.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from fsspec.core import url_to_fs

from bagport import __version__
from bagport.bags import source_stamp
from bagport.dataset import DatasetLimits, DatasetReport, write_dataset
from bagport.dataset.history import dataset_report, record_exclusions
from bagport.episode.staged import PlannedEpisode
from bagport.errors import DatasetWriteError
from bagport.formats import write_formats
from bagport.qa import EpisodeQA, QAEntry, episode_ref
from bagport.run import RunPlan, failure_key, up_to_date, write_key
from bagport.segment import kept_segmentation
from bagport.selection import EpisodeFailure, select_episodes
from bagport.staging import EpisodeSummary, StagedFeature, read_summary
from bagport.uris import BUCKET_STORES, is_local, protocol_of
from bagport.video import EncoderSettings

__all__ = [
    "ReduceStart",
    "commit_reduce",
    "finish_up_to_date",
    "read_staged",
    "reduce_run",
    "run_record",
    "start_reduce",
    "summary_json",
]


def finish_up_to_date(plan: RunPlan) -> DatasetReport:
    """The report of a run whose dataset is up to date: the dataset as it stands, every episode reused,
    none converted; the staged episodes are removed unless ``keep_staging`` (as a write would)."""
    if not plan.config.keep_staging:
        _remove_staged(plan, [e.dir_uri for e in plan.reused])
    reused = tuple(episode_ref(e.bag_uri, e.segment) for e in plan.reused)
    report = dataset_report(plan.config.output)
    failed = tuple(
        QAEntry(
            EpisodeQA.failed(f.bag_uri, f.error),
            f.manifest_entry,
            None,
            excluded_reason=f"conversion failed before, the bag unchanged since: {f.error}",
        ).brief()
        for f in plan.settled_failures
    )
    return replace(report, reused=reused, converted=0, outputs=plan.config.format_outputs(), excluded=failed)


def finish_nothing_new(plan: RunPlan) -> DatasetReport:
    """The report of an append (or ingestion) run with no new bag: the dataset as it stands, and where
    each format's output is (as any run's report says)."""
    return replace(dataset_report(plan.config.output), outputs=plan.config.format_outputs())


def run_record(plan: RunPlan, staged: Sequence[PlannedEpisode] = ()) -> dict[str, Any]:
    reused = [episode_ref(e.bag_uri, e.segment) for e in staged if e.reused]
    return {
        "bagport_version": __version__,
        "repo_id": plan.config.resolved_repo_id(),
        "contract": {"uri": plan.config.contract, "text": plan.contract_text},
        "manifest": {
            "uri": plan.config.manifest or plan.config.bags_glob,
            "bags": [b.uri for b in plan.manifest.bags],
            # each windowed entry's window (start_s/end_s...), by manifest entry: an append knows which
            # windows of a bag the dataset holds (bagport.dataset.history.dataset_bags)
            "windows": {
                str(b.entry): b.window.key() for b in plan.manifest.bags if not b.window.is_whole_bag
            },
            "converted_now": [r.bag_uri for r in plan.requests],
            "reused": reused,
        },
        "episodes_reused": len(reused),
        # whether this run's staged episodes stay after its commit (a later append removes them if not)
        "keep_staging": plan.config.keep_staging,
        "encoder": EncoderSettings.from_dict(plan.config.encoder).to_info(),
        "host_cpus": os.cpu_count(),
    }


@dataclass(frozen=True, slots=True)
class ReduceStart:
    """What the reduce writes: the kept episodes (with what the plan decides about each), every bag's QA
        entry, the run record and the size limits. It stays in the flow's process, from the selection to the
    commit (``flows/reduce.py``): only the file writers' small values go to the workers."""

    kept: tuple[EpisodeSummary, ...]
    entries: tuple[QAEntry, ...]
    record: dict[str, Any]
    limits: DatasetLimits


_LEAN = ("alignment", "qa")
"""Fields of a staged summary the reduce does not hold: the run record reads them back from the staged
``episode.json`` as it writes each episode's entry (:func:`bagport.dataset.provenance.episode_provenance`)."""


class _Shared:
    """What many staged summaries have in common, held once: the features (a fleet's are usually one
    tuple) and the keys of their dicts (JSON decoding makes new key strings for every file). The
    alignment and QA digest, which only the run record needs, are left out (:data:`_LEAN`)."""

    _MAX_FEATURES = 16

    def __init__(self) -> None:
        self.features: list[tuple[StagedFeature, ...]] = []
        self.keys: dict[str, str] = {}

    def summary(self, summary: EpisodeSummary) -> EpisodeSummary:
        features = next((f for f in self.features if f == summary.features), None)
        if features is None and len(self.features) < self._MAX_FEATURES:
            self.features.append(summary.features)
        changes = {
            f.name: self._value(value)
            for f in fields(EpisodeSummary)
            if isinstance(value := getattr(summary, f.name), dict | list) and f.name not in _LEAN
        }
        return replace(summary, features=features or summary.features, alignment=[], qa={}, **changes)

    def _value(self, value: Any) -> Any:
        if isinstance(value, dict):
            return {self.keys.setdefault(k, k): self._value(v) for k, v in value.items()}
        if isinstance(value, list):
            return [self._value(v) for v in value]
        return value


def read_staged(staged: Sequence[PlannedEpisode]) -> tuple[list[EpisodeSummary], list[PlannedEpisode]]:
    """The staged summaries with what the current plan decides on each (:meth:`PlannedEpisode.apply`), and
    the planned episodes with their source stamp. The reduce holds every kept summary from the selection to
    the commit, so each is held small: common parts shared, the run record's alignment and QA digest left
    to be read back (:class:`_Shared`)."""
    shared = _Shared()
    summaries: list[EpisodeSummary] = []
    stamped: list[PlannedEpisode] = []
    for episode in staged:
        summary = read_summary(episode.dir_uri)
        if summary is None:
            raise DatasetWriteError(
                f"staged episode {episode.dir_uri} is incomplete (its episode.json is missing or cut short); "
                "re-run the conversion (it stages the episode again)."
            )
        summaries.append(shared.summary(episode.apply(summary)))
        stamped.append(replace(episode, source_stamp=summary.source_stamp))
    return summaries, stamped


def start_reduce(
    plan: RunPlan, staged: Sequence[PlannedEpisode], failures: Sequence[EpisodeFailure] = ()
) -> ReduceStart | DatasetReport:
    """Read the staged summaries, put on each what the current plan decides about it (manifest entry,
    metadata, label: never the staged record's, which may come from another manifest) and apply the QA
    policy. When no episode is kept (an append whose new bags were all excluded), the exclusions are
    recorded and the dataset's report returned: nothing else is written."""
    summaries, stamped = read_staged(staged)
    fs, out_path = url_to_fs(plan.config.output)
    kept, entries = select_episodes(
        summaries,
        failures,
        policy=plan.qa.on_fail,
        keep_labelled=plan.config.keep_failed,
        output=plan.config.output,
        appending=plan.config.append and bool(fs.exists(out_path)),
    )
    limits = DatasetLimits(
        chunks_size=plan.config.chunks_size,
        data_files_size_in_mb=plan.config.data_files_size_in_mb,
        video_files_size_in_mb=plan.config.video_files_size_in_mb,
    )
    record = run_record(plan, staged)
    # each excluded bag's source stamp (its files listed once), so an append or a scheduled ingestion does not
    # retry an unchanged bad bag; a bag that failed for a reason not its own has none: the next run tries it
    retry = {(f.bag_uri, f.segment) for f in failures if f.retryable}
    left_out = [e for e in entries if e.episode_index is None]
    stamp_of = {
        e.qa.bag_uri: source_stamp(e.qa.bag_uri) for e in left_out if (e.qa.bag_uri, e.segment) not in retry
    }
    if not plan.config.append:  # an append's record describes its own episodes only
        record["write_key"] = write_key(plan, stamped, failures)
        record["failures"] = [  # what an unchanged re-run needs to find it is up to date (bagport.run)
            {**failure_key(f), "source_stamp": stamp_of[f.bag_uri]} for f in failures if not f.retryable
        ]
    record["excluded"] = [
        replace(
            e.brief(),
            source_stamp=stamp_of.get(e.qa.bag_uri) if (e.qa.bag_uri, e.segment) not in retry else None,
        ).to_json()
        for e in left_out
    ]
    if not kept:  # an append whose new bags were all excluded: recorded, nothing written
        record_exclusions(plan.config.output, record)
        excluded = tuple(e.brief() for e in entries)
        return replace(dataset_report(plan.config.output), excluded=excluded, qa=excluded)
    return ReduceStart(tuple(kept), tuple(entries), record, limits)


def commit_reduce(
    plan: RunPlan, staged: Sequence[PlannedEpisode], start: ReduceStart, lerobot: DatasetReport | None
) -> DatasetReport:
    """After the LeRobot dataset (``lerobot``, when asked for) is written: the same kept episodes, from the
    same staging, into every other format (no second read of the bags), then the staging clean-up."""
    formats = plan.config.formats
    others = write_formats(
        start.kept,
        plan.config,
        robot_type=plan.contract.robot_type,
        run_record=start.record,
        qa=start.entries,
    )
    report = replace(lerobot or others[formats[0]], outputs=plan.config.format_outputs())
    if not plan.config.keep_staging:
        _remove_staged(plan, [e.dir_uri for e in staged])
    reused = tuple(episode_ref(e.bag_uri, e.segment) for e in staged if e.reused)
    return replace(report, converted=len(staged) - len(reused), reused=reused)  # failures are in excluded


def reduce_run(
    plan: RunPlan, staged: Sequence[PlannedEpisode], failures: Sequence[EpisodeFailure] = ()
) -> DatasetReport:
    """The whole reduce in this process (:func:`start_reduce`, the LeRobot write, :func:`commit_reduce`);
    the flow runs the same steps with each output file as its own task (``flows/reduce.py``). The output
    stays held until the other formats are written from the staged episodes, as the flow holds it: an
    append meanwhile would otherwise take them for a killed run's leftovers and remove them."""
    start = start_reduce(plan, staged, failures)
    if isinstance(start, DatasetReport):
        return start
    if "lerobot" not in plan.config.formats:
        return commit_reduce(plan, staged, start, None)
    return write_dataset(
        start.kept,
        plan.config.output,
        robot_type=plan.contract.robot_type,
        limits=start.limits,
        run_record=start.record,
        overwrite=plan.config.overwrite,
        qa=start.entries,
        qa_config=plan.qa.model_dump(mode="json"),
        append=plan.config.append,
        expect_episodes=plan.dataset_episodes,
        then=lambda lerobot: commit_reduce(plan, staged, start, lerobot),
    )


def _remove_staged(plan: RunPlan, staged_dirs: Sequence[str]) -> None:
    """Remove this run's staged episodes and kept segmentations, then the staging store if it is empty
    (another run may share it)."""
    fs, path = url_to_fs(plan.config.resolved_staging())
    kept_segmentations = (kept_segmentation(r, plan.contract) for r in plan.requests)
    for uri in (*staged_dirs, *(u for u in kept_segmentations if u is not None)):
        _, staged_path = url_to_fs(uri)
        if fs.exists(staged_path):
            fs.rm(staged_path, recursive=True)
    if is_local(fs):
        _remove_empty_folders(Path(path))
    elif protocol_of(fs) not in BUCKET_STORES:  # folders of its own (sftp, memory): removed when empty
        with contextlib.suppress(OSError):
            if fs.exists(path) and not fs.find(path):
                fs.rm(path, recursive=True)


def _remove_empty_folders(root: Path) -> None:
    """Remove ``root``'s empty folders, deepest first, and ``root`` when it ends up empty: each ``rmdir``
    fails on a folder another run has just put an episode in (a shared staging store), where checking that
    the store is empty and then removing it whole could delete that episode. (An object store has no
    folders: nothing is left once the files are gone.)"""
    if not root.is_dir():
        return
    for folder in sorted(
        (p for p in root.rglob("*") if p.is_dir()), key=lambda p: len(p.parts), reverse=True
    ):
        with contextlib.suppress(OSError):  # not empty (another run's), or gone
            folder.rmdir()
    with contextlib.suppress(OSError):
        root.rmdir()


def summary_json(report: DatasetReport) -> str:
    return json.dumps(
        {
            "root": report.root,
            "episodes": report.episodes,
            "frames": report.frames,
            "duration_s": round(report.duration_s, 3),
            "tasks": list(report.tasks),
            "videos": list(report.video_keys),
            "size_bytes": report.size_bytes,
            "excluded": [row.to_json() for row in report.excluded],
            "converted_now": report.converted,
            "reused": len(report.reused),
            "up_to_date": up_to_date(report),
            "outputs": report.outputs,
        },
        indent=2,
    )
