"""A conversion run as library calls: plan the episodes (the reduce is :mod:`bagport.reduce`).

The orchestration (fan-out, retries, runners) lives in ``flows/``; these
functions are what it calls before and after the per-episode map.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from fsspec import AbstractFileSystem

from bagport import __version__
from bagport.append_plan import bags_to_append, check_append_fits
from bagport.bags import read_msg_path, source_stamp
from bagport.config import ConvertConfig
from bagport.contract import ContractPlan, FeatureKind, parse_contract
from bagport.dataset import DatasetReport
from bagport.dataset.history import dataset_bags, recorded_failures, recorded_write_key
from bagport.dataset.repair import repair_dataset
from bagport.dataset.replace import refuse_existing, refuse_output_in_a_bag
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.episode.staged import PlannedEpisode, list_staged, remove_finished_staging, split_staged
from bagport.formats import check_format_outputs
from bagport.manifest import BagEntry, Manifest, load_manifest, parse_manifest
from bagport.qa import QAConfig, load_qa_config
from bagport.scratch import scratch_folder
from bagport.segment import segment_request, segments_bags
from bagport.selection import EpisodeFailure
from bagport.uris import check_writable, is_local, output_fs, read_text, require_bucket
from bagport.video import EncoderSettings
from bagport.video.encode import check_encoder
from bagport.window_overlaps import WindowOverlap, window_overlaps

__all__ = [
    "EpisodeFailure",
    "PlannedEpisode",
    "RunPlan",
    "plan_run",
    "segment_all",
    "stage_all",
    "up_to_date",
    "write_key",
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
    up_to_date: bool = False
    """The dataset at the output is what this run would write (the same write key, every episode
    reused): nothing converts and nothing is written (:func:`finish_up_to_date`)."""
    settled_failures: tuple[EpisodeFailure, ...] = ()
    """In an up-to-date plan: the bags that failed to convert in the run that wrote the dataset, unchanged
    since (the same source stamp), so they would fail the same way: not tried again."""
    dataset_episodes: int | None = None
    """An append's: the episodes the dataset held when the plan chose the bags it does not hold yet (0: no
    dataset yet). The write is refused if another run changed that number since."""
    staging_removed: tuple[str, ...] = ()
    """An append's: staged episodes the dataset holds already, left in the staging store by a run killed
    after its commit, which this plan removed (not with ``--keep-staging``)."""
    overlaps: tuple[WindowOverlap, ...] = ()
    """Planned episodes whose window overlaps another window of their bag (another entry's, or one the
    dataset holds): warned of, not refused (:mod:`bagport.window_overlaps`)."""

    def staging_note(self) -> str:
        """One line on :attr:`staging_removed`, for the run's log and the CLI."""
        return (
            f"removed {len(self.staging_removed)} staged episode(s) from {self.config.resolved_staging()} that "
            f"{self.config.output} holds already (a run killed after its commit left them)"
        )


def plan_run(config: ConvertConfig, *, reuse: bool = True) -> RunPlan:
    """Validate the manifest, contract and encoder settings; one request per bag.

    Everything that can be checked without reading bags is checked here, before
    any work starts, and the output must not exist unless ``overwrite``. With ``reuse``, the
    staging store is listed once and episodes staged already with a matching key go to
    :attr:`RunPlan.reused` instead of :attr:`RunPlan.requests` (``bagport.episode.staged``).
    """
    contract_text = read_text(config.contract, "contract")
    contract = parse_contract(contract_text, config.contract)
    encoder = EncoderSettings.from_dict(config.encoder)
    qa = _qa_config(config)
    manifest = _manifest(config)
    fs, out_path, staging = _ready_output(config, manifest)
    stamps: dict[str, str] = {}

    def stamp_of(uri: str) -> str:  # each bag's files are listed at most once per plan
        if uri not in stamps:
            stamps[uri] = source_stamp(uri)
        return stamps[uri]

    msg_definitions = read_msg_path(config.msg_path) if config.msg_path else {}
    bags = manifest.bags
    dataset_episodes = 0 if config.append else None
    removed: tuple[str, ...] = ()
    held: Iterable[tuple[str, str | None]] = ()
    if config.append and fs.exists(out_path):
        known = dataset_bags(config.output)
        if not config.keep_staging:  # a local output's recovery above refused if a write were live
            finished = known.committed_staged | (known.newest_staged if is_local(fs) else set())
            removed = remove_finished_staging(staging, finished)
        bags = bags_to_append(bags, known, stamp_of, msg_definitions)
        dataset_episodes = check_append_fits(config, contract, adding=bool(bags))
        held = _held_windows(known.kept, bags, stamp_of)
    elif not config.append:
        refuse_existing(config.output, overwrite=config.overwrite, inputs=[bag.uri for bag in manifest.bags])
    check_format_outputs(config)
    # fmt: off
    requests = tuple(
        EpisodeRequest(
            episode_id=episode_id_for(bag.uri, contract_text, encoder, bag.window.key(), msg_definitions),
            bag_uri=bag.uri, manifest_entry=bag.entry, staging_uri=staging, contract_text=contract_text,
            contract_name=config.contract, encoder=encoder, default_task=bag.task, metadata=bag.metadata,
            qa=qa, window=bag.window, msg_definitions=msg_definitions,
        )
        for bag in bags
    )
    plan = RunPlan(
        config, contract, manifest, requests, contract_text, qa,
        dataset_episodes=dataset_episodes, staging_removed=removed,
        overlaps=window_overlaps(bags, held, whole_bag_split=segments_bags(contract)),
    )
    # fmt: on
    plan = _mark_up_to_date(_take_staged(plan, stamp_of), stamp_of) if reuse else plan
    _check_encoder_once(plan, encoder)
    return plan


def _check_encoder_once(plan: RunPlan, encoder: EncoderSettings) -> None:
    """Settings the encoder refuses, said once at the plan instead of by every episode (only when episodes
    will be converted and the contract has videos)."""
    if plan.requests and any(f.kind is FeatureKind.VIDEO for f in plan.contract.features):
        with scratch_folder("encoder") as folder:
            check_encoder(encoder, folder)


def _ready_output(config: ConvertConfig, manifest: Manifest) -> tuple[AbstractFileSystem, str, str]:
    """The output's and the staging store's places checked (their buckets exist, the output is in none of
    the run's bags) and the output repaired; its filesystem, path, and the staging URI."""
    fs, out_path = output_fs(config.output, "--output")
    require_bucket(fs, out_path, config.output)
    staging = config.resolved_staging()
    staging_fs, staging_path = output_fs(staging, "--staging")
    require_bucket(staging_fs, staging_path, staging)
    bags = [bag.uri for bag in manifest.bags]
    refuse_output_in_a_bag(config.output, bags)  # before anything writes there
    refuse_output_in_a_bag(staging, bags, "--staging")
    check_writable(fs, out_path, config.output, "--output", beside=True)
    check_writable(staging_fs, staging_path, staging, "--staging")
    repair_dataset(config.output, clean_scratch=True)  # before reading what an --append adds to
    return fs, out_path, staging


def _held_windows(
    kept: Mapping[tuple[str, str | None], Mapping[str, str]],
    bags: Sequence[BagEntry],
    stamp_of: Callable[[str], str],
) -> list[tuple[str, str | None]]:
    """``(URI, window key)`` of the dataset's episodes of the planned bags' recordings as they are now (the
    same source stamp): a re-recorded bag's windows are not compared with the old recording's."""
    uris = {bag.uri for bag in bags}
    return [(uri, key) for (uri, key), stamps in kept.items() if uri in uris and stamp_of(uri) in stamps]


def _qa_config(config: ConvertConfig) -> QAConfig:
    """The run's QA settings: ``--qa``'s file (bagport's defaults without one), ``--on-qa-fail`` over it."""
    qa = load_qa_config(read_text(config.qa, "qa") if config.qa else None, config.qa or "qa.yaml")
    return qa if config.on_qa_fail is None else qa.model_copy(update={"on_fail": config.on_qa_fail})


def _manifest(config: ConvertConfig) -> Manifest:
    """The run's bags: ``--manifest``'s file, or the bags ``--bags`` matches."""
    glob_manifest = config.manifest_text()
    if glob_manifest is not None:
        return parse_manifest(*glob_manifest)
    assert config.manifest is not None  # the config validates that one of the two is given
    return load_manifest(config.manifest)


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


_NOT_IN_WRITE_KEY = frozenset({
    "manifest", "bags_glob", "contract", "qa", "msg_path", "on_qa_fail",  # their content is in the key
    "output", "staging", "workers", "runner", "dask_address", "ray_address", "overwrite", "keep_staging", "fail_fast",
})  # fmt: skip
"""Options that do not change what is written, or whose effect the key holds otherwise (any other,
a new one included, is part of the key)."""


def write_key(
    plan: RunPlan, episodes: Sequence[PlannedEpisode], failures: Sequence[EpisodeFailure] = ()
) -> str:
    """A digest of all that decides the dataset a run writes: its episodes in order (staged episode, bag
    stamp, what the plan puts on it), failures, contract, QA, encoder, options and bagport's version.
    Kept in the run record; a re-run planning the same key writes nothing (:attr:`RunPlan.up_to_date`)."""
    options = plan.config.model_dump(mode="json", exclude=set(_NOT_IN_WRITE_KEY))
    facts = {
        "bagport_version": __version__,
        "options": options,
        "contract_sha256": hashlib.sha256(plan.contract_text.encode()).hexdigest(),
        "robot_type": plan.contract.robot_type,
        "qa": plan.qa.model_dump(mode="json"),
        "encoder": EncoderSettings.from_dict(plan.config.encoder).to_info(),
        "repo_id": plan.config.resolved_repo_id(),
        "episodes": [  # in the order they are written: the manifest's
            e.key_fields()
            for e in sorted(
                episodes, key=lambda e: (e.manifest_entry, -1 if e.segment is None else e.segment)
            )
        ],
        "failures": sorted(  # as the run record keeps each (failure_key), in a stable order
            (failure_key(f) for f in failures), key=lambda row: json.dumps(row, sort_keys=True)
        ),
    }
    text = json.dumps(facts, sort_keys=True, default=str, separators=(",", ":"))
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def failure_key(failure: EpisodeFailure) -> dict[str, Any]:
    """A failed bag as the run record keeps it, with what :func:`write_key` holds of it."""
    return {
        "manifest_entry": failure.manifest_entry,
        "bag_uri": failure.bag_uri,
        "segment": failure.segment,
        "episode_id": failure.episode_id,
        "error": failure.error,
    }


def _mark_up_to_date(plan: RunPlan, stamp_of: Callable[[str], str]) -> RunPlan:
    """The plan marked up to date when the dataset at the output (replaced with ``--overwrite``; LeRobot
    only) was written with the key this run would write: such a re-run costs the plan.

    The key holds each episode's id (bag, contract, encoder, window) and its bag's stamp, so episodes no
    longer staged (a run without ``--keep-staging`` removed them) are judged by their bag's stamp now: an
    unchanged fleet is up to date without its staging, a changed bag is not (its stamp differs). A
    contract that splits bags into episodes is written again (its episodes are known once split, in the flow).
    """
    config = plan.config
    if (
        not (plan.requests or plan.reused)
        or segments_bags(plan.contract)
        or config.append
        or not config.overwrite
        or config.formats != ("lerobot",)
    ):
        return plan
    recorded = recorded_write_key(config.output)  # before any bag's stamp: none on a first run
    if recorded is None:
        return plan
    unstaged = tuple(PlannedEpisode.reused_of(r, stamp_of(r.bag_uri)) for r in plan.requests)
    episodes = (*plan.reused, *unstaged)
    if recorded == write_key(plan, episodes):
        return replace(plan, requests=(), reused=episodes, up_to_date=True)
    # bags the recorded run could not convert for their own sake, unchanged since, fail the same way
    # (the same request, as its id says: bag, window, contract, encoder; the same bag files, as its stamp says)
    settled = {
        (f.get("manifest_entry"), f.get("episode_id")): f
        for f in recorded_failures(config.output)
        if "error" in f
    }
    if not settled:
        return plan
    failed: list[EpisodeFailure] = []
    converted: list[PlannedEpisode] = []
    for request, episode in zip(plan.requests, unstaged, strict=True):
        found = settled.get((request.manifest_entry, request.episode_id))
        if found is not None and found.get("source_stamp") == episode.source_stamp:
            failed.append(EpisodeFailure.of(request, str(found["error"])))
        else:
            converted.append(episode)
    episodes = (*plan.reused, *converted)
    if recorded != write_key(plan, episodes, failed):
        return plan
    return replace(plan, requests=(), reused=episodes, up_to_date=True, settled_failures=tuple(failed))


def up_to_date(report: DatasetReport) -> bool:
    """Whether the report is of a run that wrote nothing: every episode reused, no QA row written."""
    return not report.converted and bool(report.reused) and not report.qa


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
