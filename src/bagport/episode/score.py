"""``bagport qa``: score bags against a contract without converting them.

The same checks as a conversion, except the camera content checks (frozen and dark
frames), which need decoded images: no image is decoded and no video is encoded, so
this costs one pass over stamps plus decoding the numeric topics. Bags are split into
episodes exactly as a conversion splits them (manifest windows, the contract's
``episodes`` section), and every episode is scored on its own.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor

from bagport.bags import open_bag
from bagport.contract import FeatureKind, parse_contract
from bagport.episode.assemble import iter_frames
from bagport.episode.prepare import prepare_episode
from bagport.episode.quality import assess_episode, bag_checks
from bagport.episode.tasks import resolve_tasks
from bagport.errors import BagportError, ManifestError
from bagport.manifest import load_manifest
from bagport.qa import EpisodeQA, QAEntry, ValueMonitor, load_qa_config
from bagport.request import EpisodeRequest
from bagport.segment import EXCLUDED_LABELS, label_reason, segment_request, segments_bags
from bagport.uris import read_text

__all__ = ["score_bag", "score_manifest"]


def score_bag(request: EpisodeRequest) -> EpisodeQA:
    """QA of one episode (a bag, or its window); one that cannot be read or aligned gets a failing
    record with the reason. The steps of a conversion, with the value monitor as the only sink."""
    plan = parse_contract(request.contract_text, request.contract_name)
    config = request.qa
    uri = request.bag_uri
    try:
        with open_bag(uri, msg_definitions=request.msg_definitions) as whole:
            episode = prepare_episode(whole, plan, request)
            alignment = episode.alignment
            try:
                frame_tasks, _ = resolve_tasks(
                    episode.timeline.tasks, alignment.ticks_ns, whole.info.custom_data, request,
                    plan.contract.default_task,
                )  # fmt: skip
            except ManifestError:
                frame_tasks = []
            monitor = ValueMonitor(config.values, plan.fps, alignment.frames)
            vectors = [f for f in plan.features if f.kind is FeatureKind.VECTOR]
            vector_sources = alignment.of({f.key for f in vectors})
            if vector_sources:
                frames = iter_frames(
                    episode.reader, uri, vectors, vector_sources, alignment.ticks_ns, plan.source_name
                )
                for frame in frames:
                    monitor.add_vectors(frame.index, frame.vectors)
            extra = bag_checks(episode.reader, config, alignment, frame_tasks)
            return assess_episode(uri, config, episode.timeline, alignment, monitor, extra, plan.fps)
    except BagportError as err:
        return EpisodeQA.failed(uri, str(err))


def segment_for_qa(request: EpisodeRequest) -> tuple[tuple[EpisodeRequest, ...], EpisodeQA | None]:
    """The bag's episode requests, or a failing record when it cannot be split into episodes."""
    try:
        found = segment_request(request)
    except BagportError as err:
        return (), EpisodeQA.failed(request.bag_uri, str(err))
    if not found.requests:
        return (), EpisodeQA.failed(request.bag_uri, found.none_found())
    return found.requests, None


def _entry(qa: EpisodeQA, request: EpisodeRequest, keep_failed: bool) -> QAEntry:
    by_label = not keep_failed and request.label in EXCLUDED_LABELS
    reason = label_reason(request.label, request.note) if by_label else None
    return QAEntry(
        qa,
        request.manifest_entry,
        None,
        reason,
        request.segment,
        request.label,
        request.note,
        by_label,
        dict(request.metadata),
    )


def score_manifest(
    manifest_uri: str,
    contract_uri: str,
    qa_uri: str | None = None,
    *,
    workers: int | None = None,
    msg_definitions: dict[str, str] | None = None,
    keep_failed: bool = False,
) -> list[QAEntry]:
    """Score every episode of a manifest's bags (in parallel processes), in manifest order.

    A bag the contract's ``episodes`` section splits gives one entry per episode (``segment``,
    ``label``); episodes labelled ``failed`` or ``discarded`` are scored and marked ``by_label``
    (left out by a conversion) unless ``keep_failed``. A bag that cannot be split gets one failing entry.
    """
    contract_text = read_text(contract_uri, "contract")
    plan = parse_contract(contract_text, contract_uri)  # a bad contract stops here, once
    qa = load_qa_config(read_text(qa_uri, "qa") if qa_uri else None, qa_uri or "qa.yaml")
    manifest = load_manifest(manifest_uri)
    requests = [
        EpisodeRequest(
            episode_id=f"qa-{bag.entry}",
            bag_uri=bag.uri,
            manifest_entry=bag.entry,
            staging_uri="",
            contract_text=contract_text,
            contract_name=contract_uri,
            default_task=bag.task,
            metadata=bag.metadata,
            qa=qa,
            msg_definitions=dict(msg_definitions or {}),
            window=bag.window,
        )
        for bag in manifest.bags
    ]
    count = min(workers or os.cpu_count() or 1, len(requests))
    if count <= 1:
        return _score(None, requests, segments_bags(plan), keep_failed)
    # spawn, not fork: the caller may run threads (Prefect, fsspec), and fork would copy their locks.
    with ProcessPoolExecutor(max_workers=count, mp_context=multiprocessing.get_context("spawn")) as pool:
        return _score(pool, requests, segments_bags(plan), keep_failed)


def _map[In, Out](pool: Executor | None, fn: Callable[[In], Out], items: Sequence[In]) -> list[Out]:
    return [fn(item) for item in items] if pool is None else list(pool.map(fn, items))


def _score(
    pool: Executor | None, requests: list[EpisodeRequest], segment: bool, keep_failed: bool
) -> list[QAEntry]:
    """Split the bags into episodes (when the contract asks), then score every episode."""
    entries: list[QAEntry] = []
    episodes = list(requests)
    if segment:
        episodes = []
        for request, (found, failed) in zip(requests, _map(pool, segment_for_qa, requests), strict=True):
            episodes += found
            if failed is not None:
                entries.append(QAEntry(failed, request.manifest_entry, None, metadata=dict(request.metadata)))
    scores = _map(pool, score_bag, episodes)
    entries += [_entry(qa, r, keep_failed) for qa, r in zip(scores, episodes, strict=True)]
    entries.sort(key=lambda e: (e.manifest_entry, -1 if e.segment is None else e.segment))
    return entries
