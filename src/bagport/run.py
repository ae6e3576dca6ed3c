"""A conversion run as library calls: plan the episodes, then reduce staged results.

The orchestration (fan-out, retries, runners) lives in ``flows/``; these
functions are what it calls before and after the per-episode map.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from fsspec.core import url_to_fs

from bagport import __version__
from bagport.bags import read_msg_path, source_stamp
from bagport.config import ConvertConfig
from bagport.contract import ContractPlan, parse_contract
from bagport.dataset import DatasetLimits, DatasetReport, write_dataset
from bagport.dataset.base import read_base
from bagport.dataset.history import converted_bags, dataset_report, record_exclusions
from bagport.dataset.layout import DEFAULT_FEATURES
from bagport.dataset.repair import repair_dataset
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.episode.staged import PlannedEpisode, list_staged, split_staged
from bagport.errors import DatasetWriteError
from bagport.formats import check_format_outputs, write_formats
from bagport.manifest import Manifest, load_manifest, parse_manifest
from bagport.qa import QAConfig, QAEntry, load_qa_config
from bagport.segment import kept_segmentation, segment_request, segments_bags
from bagport.selection import EpisodeFailure, select_episodes
from bagport.staging import EpisodeSummary, read_summary
from bagport.uris import read_text, require_bucket
from bagport.video import EncoderSettings

__all__ = [
    "EpisodeFailure",
    "PlannedEpisode",
    "ReduceStart",
    "RunPlan",
    "commit_reduce",
    "plan_run",
    "reduce_run",
    "segment_all",
    "stage_all",
    "start_reduce",
]


@dataclass(frozen=True, slots=True)
class RunPlan:
    config: ConvertConfig
    contract: ContractPlan
    manifest: Manifest
    requests: tuple[EpisodeRequest, ...]
    contract_text: str
    qa: QAConfig
    reused: tuple[PlannedEpisode, ...] = ()
    """Episodes staged already with a matching key: not converted again (``requests`` holds the rest)."""
    staged_ids: frozenset[str] = frozenset()
    """Every completed staged episode when the run was planned (episodes of split bags are matched
    against it once the bag is split)."""


def plan_run(config: ConvertConfig, *, reuse: bool = True) -> RunPlan:
    """Validate the manifest, contract and encoder settings; one request per bag.

    Everything that can be checked without reading bags is checked here, before
    any work starts, and the output must not exist unless ``overwrite``. With ``reuse``, the
    staging store is listed once and episodes staged already with a matching key go to
    :attr:`RunPlan.reused` instead of :attr:`RunPlan.requests` (``bagport.episode.staged``).
    """
    contract_text = read_text(config.contract, "contract")
    contract = parse_contract(contract_text, config.contract)
    EncoderSettings.from_dict(config.encoder)
    qa = load_qa_config(read_text(config.qa, "qa") if config.qa else None, config.qa or "qa.yaml")
    if config.on_qa_fail is not None:
        qa = qa.model_copy(update={"on_fail": config.on_qa_fail})
    glob_manifest = config.manifest_text()
    if glob_manifest is not None:
        manifest = parse_manifest(*glob_manifest)
    else:
        assert config.manifest is not None  # the config validates that one of the two is given
        manifest = load_manifest(config.manifest)
    fs, out_path = url_to_fs(config.output)
    require_bucket(fs, out_path, config.output)
    staging = config.resolved_staging()
    staging_fs, staging_path = url_to_fs(staging)
    require_bucket(staging_fs, staging_path, staging)
    repair_dataset(config.output, clean_scratch=True)  # before reading what an --append adds to
    done: set[tuple[str, str]] = set()
    stamps: dict[str, str] = {}

    def stamp_of(uri: str) -> str:  # each bag's files are listed at most once per plan
        if uri not in stamps:
            stamps[uri] = source_stamp(uri)
        return stamps[uri]

    if config.append and fs.exists(out_path):
        done = converted_bags(config.output)
        _refuse_incompatible_append(config, contract)
    elif fs.exists(out_path) and not config.overwrite:
        raise DatasetWriteError(
            f"{config.output} already exists; nothing was written. Fix: choose a new --output, or pass "
            "--overwrite to replace it (the old dataset stays until the new one is complete)."
        )
    check_format_outputs(config)
    msg_definitions = read_msg_path(config.msg_path) if config.msg_path else {}
    requests = tuple(
        EpisodeRequest(
            episode_id=episode_id_for(
                bag.uri, contract_text, config.encoder, window_key(bag.window), msg_definitions
            ),
            bag_uri=bag.uri,
            manifest_entry=bag.entry,
            staging_uri=staging,
            contract_text=contract_text,
            contract_name=config.contract,
            encoder=dict(config.encoder),
            default_task=bag.task,
            metadata=bag.metadata,
            qa=qa.model_dump(mode="json"),
            **bag.window,
            msg_definitions=msg_definitions,
        )
        for bag in manifest.bags
        if not done or (bag.uri, stamp_of(bag.uri)) not in done
    )
    plan = RunPlan(config, contract, manifest, requests, contract_text, qa)
    return _take_staged(plan, stamp_of) if reuse else plan


def _take_staged(plan: RunPlan, stamp_of: Callable[[str], str]) -> RunPlan:
    """The plan with the episodes staged already (one listing of the staging store) moved to ``reused``.

    Bags the contract splits into episodes are split first (in the flow); their episodes are matched
    against ``staged_ids`` then.
    """
    staged_ids = list_staged(plan.config.resolved_staging()) if plan.requests else frozenset()
    if not staged_ids or segments_bags(plan.contract):
        return replace(plan, staged_ids=staged_ids)
    split = split_staged(plan.requests, staged_ids, stamp_of)
    return replace(plan, requests=split.todo, reused=split.reused, staged_ids=staged_ids)


def _refuse_incompatible_append(config: ConvertConfig, contract: ContractPlan) -> None:
    """Before anything converts: an append whose contract gives other features (or fps) than the
    dataset's ``meta/info.json`` would be refused after converting every bag."""
    info = read_base(config.output).info
    have = sorted(set(info["features"]) - set(DEFAULT_FEATURES))
    want = sorted(f.key for f in contract.features)
    if have == want and info["fps"] == contract.fps:
        return
    differences = (
        [f"fps: dataset {info['fps']}, contract {contract.fps}"] if info["fps"] != contract.fps else []
    )
    if only_dataset := [k for k in have if k not in want]:
        differences.append(f"only in the dataset: {', '.join(only_dataset)}")
    if only_contract := [k for k in want if k not in have]:
        differences.append(f"only in the contract: {', '.join(only_contract)}")
    raise DatasetWriteError(
        f"cannot append to {config.output} with {config.contract}: its features differ from the dataset's "
        f"({'; '.join(differences)}); nothing was converted. Fix: append with the contract the dataset was "
        "made with, or convert into a new --output."
    )


def window_key(window: dict[str, Any]) -> str:
    """A manifest window as the text its request's :meth:`EpisodeRequest.window_key` gives."""
    if not window:
        return ""
    return EpisodeRequest("", "", 0, "", "", "", **window).window_key()


def segment_all(plan: RunPlan) -> tuple[tuple[EpisodeRequest, ...], tuple[str, ...]]:
    """Every episode request of the run: each bag split into its episodes (serially; the flow maps
    :func:`bagport.segment.segment_request` over the bags instead). Also what segmentation left out."""
    if not segments_bags(plan.contract):
        return plan.requests, ()
    requests: list[EpisodeRequest] = []
    ignored: list[str] = []
    for request in plan.requests:
        found = segment_request(request)
        requests += found.requests
        ignored += [f"{request.bag_uri}: {reason}" for reason in found.ignored]
    return tuple(requests), tuple(ignored)


def stage_all(plan: RunPlan, requests: Sequence[EpisodeRequest] | None = None) -> list[PlannedEpisode]:
    """Convert the plan's episodes (or ``requests``: a split bag's, from :func:`segment_all`) serially in
    this process, and return every episode :func:`reduce_run` writes, the reused ones included (the
    flow maps the conversions as tasks instead)."""
    todo = plan.requests if requests is None else requests
    for request in todo:
        convert_episode(request)
    return [*plan.reused, *(PlannedEpisode.of(r) for r in todo)]


def run_record(plan: RunPlan, staged: Sequence[PlannedEpisode] = ()) -> dict[str, Any]:
    reused = [_episode_name(e.bag_uri, e.segment) for e in staged if e.reused]
    return {
        "bagport_version": __version__,
        "repo_id": plan.config.resolved_repo_id(),
        "contract": {"uri": plan.config.contract, "text": plan.contract_text},
        "manifest": {
            "uri": plan.config.manifest or plan.config.bags_glob,
            "bags": [b.uri for b in plan.manifest.bags],
            "converted_now": [r.bag_uri for r in plan.requests],
            "reused": reused,
        },
        "episodes_reused": len(reused),
        "encoder": EncoderSettings.from_dict(plan.config.encoder).to_info(),
        "host_cpus": os.cpu_count(),
    }


def _episode_name(bag_uri: str, segment: int | None) -> str:
    return bag_uri if segment is None else f"{bag_uri}#{segment}"


@dataclass(frozen=True, slots=True)
class ReduceStart:
    """What the reduce writes: the kept episodes (with what the plan decides about each), every bag's QA
    entry, the run record and the size limits; small and serialisable (it travels to the commit task)."""

    kept: tuple[EpisodeSummary, ...]
    entries: tuple[QAEntry, ...]
    record: dict[str, Any]
    limits: DatasetLimits


def start_reduce(
    plan: RunPlan, staged: Sequence[PlannedEpisode], failures: Sequence[EpisodeFailure] = ()
) -> ReduceStart | DatasetReport:
    """Read the staged summaries, put on each what the current plan decides about it (manifest entry,
    metadata, label: never the staged record's, which may come from another manifest) and apply the QA
    policy. When no episode is kept (an append whose new bags were all excluded), the exclusions are
    recorded and the dataset's report returned: nothing else is written."""
    summaries: list[EpisodeSummary] = []
    for episode in staged:
        summary = read_summary(episode.dir_uri)
        if summary is None:
            raise DatasetWriteError(
                f"staged episode {episode.dir_uri} is incomplete (no episode.json); re-run the conversion."
            )
        summaries.append(episode.apply(summary))
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
    # with their source stamp, so an append or a scheduled ingestion does not retry an unchanged bad bag
    record["excluded"] = [
        {**e.brief(), "source_stamp": source_stamp(e.qa.bag_uri)} for e in entries if e.episode_index is None
    ]
    if not kept:  # an append whose new bags were all excluded: recorded, nothing written
        record_exclusions(plan.config.output, record)
        excluded = tuple(e.brief() for e in entries)
        return replace(dataset_report(plan.config.output), excluded=excluded, qa=excluded)
    return ReduceStart(tuple(kept), tuple(entries), record, limits)


def commit_reduce(
    plan: RunPlan,
    staged: Sequence[PlannedEpisode],
    failures: Sequence[EpisodeFailure],
    start: ReduceStart,
    lerobot: DatasetReport | None,
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
    reused = tuple(_episode_name(e.bag_uri, e.segment) for e in staged if e.reused)
    return replace(report, converted=len(staged) + len(failures) - len(reused), reused=reused)


def reduce_run(
    plan: RunPlan, staged: Sequence[PlannedEpisode], failures: Sequence[EpisodeFailure] = ()
) -> DatasetReport:
    """The whole reduce in this process (:func:`start_reduce`, the LeRobot write, :func:`commit_reduce`);
    the flow runs the same steps with each output file as its own task (``flows/reduce.py``)."""
    start = start_reduce(plan, staged, failures)
    if isinstance(start, DatasetReport):
        return start
    lerobot = (
        write_dataset(
            start.kept,
            plan.config.output,
            robot_type=plan.contract.robot_type,
            limits=start.limits,
            run_record=start.record,
            overwrite=plan.config.overwrite,
            qa=start.entries,
            qa_config=plan.qa.model_dump(mode="json"),
            append=plan.config.append,
        )
        if "lerobot" in plan.config.formats
        else None
    )
    return commit_reduce(plan, staged, failures, start, lerobot)


def _remove_staged(plan: RunPlan, staged_dirs: Sequence[str]) -> None:
    """Remove this run's staged episodes and kept segmentations, then the staging store if it is empty
    (another run may share it)."""
    fs, path = url_to_fs(plan.config.resolved_staging())
    kept_segmentations = (kept_segmentation(r, plan.contract) for r in plan.requests)
    for uri in (*staged_dirs, *(u for u in kept_segmentations if u is not None)):
        _, staged_path = url_to_fs(uri)
        if fs.exists(staged_path):
            fs.rm(staged_path, recursive=True)
    try:
        if fs.exists(path) and not fs.find(path):
            fs.rm(path, recursive=True)
    except OSError:
        pass


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
            "excluded": list(report.excluded),
            "converted_now": report.converted,
            "reused": len(report.reused),
            "outputs": report.outputs,
        },
        indent=2,
    )
