"""``bagport qa``: score a bag against a contract without converting it.

The same checks as a conversion, except the camera content checks (frozen and dark
frames), which need decoded images: no image is decoded and no video is encoded, so
this costs one pass over stamps plus decoding the numeric topics.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

from bagport.bags import BagReader, BagWindow, open_bag
from bagport.contract import FeatureKind, parse_contract
from bagport.episode.alignment import align_sources
from bagport.episode.assemble import Frame, assemble_frames
from bagport.episode.checks import check_bag_fits, check_window_has_data
from bagport.episode.quality import assess_episode, safety_check, task_check
from bagport.episode.request import EpisodeRequest
from bagport.episode.tasks import resolve_tasks
from bagport.episode.timeline import scan_plan_timeline
from bagport.errors import BagportError, ManifestError
from bagport.manifest import load_manifest
from bagport.qa import EpisodeQA, QAConfig, QAEntry, ValueMonitor, load_qa_config
from bagport.uris import read_text

__all__ = ["score_bag", "score_manifest"]


def score_bag(request: EpisodeRequest) -> EpisodeQA:
    """QA of one bag; a bag that cannot be read or aligned gets a failing record with the reason."""
    plan = parse_contract(request.contract_text, request.contract_name)
    config = QAConfig.model_validate(request.qa)
    uri = request.bag_uri
    try:
        with open_bag(uri, msg_definitions=request.msg_definitions) as whole:
            info = whole.info
            check_bag_fits(info, plan)
            window = request.window_ns(info.start_ns, info.end_ns)  # a manifest entry's window, as converted
            reader: BagReader = whole if window is None else BagWindow(whole, *window)
            timeline = scan_plan_timeline(whole, plan, window)
            if window is not None:
                check_window_has_data(timeline, window, info.start_ns, uri)
            sources, ticks, alignment = align_sources(plan, timeline, uri)
            try:
                frame_tasks, _ = resolve_tasks(
                    timeline.tasks, ticks, info.custom_data, request, plan.contract.default_task
                )
            except ManifestError:
                frame_tasks = []
            monitor = ValueMonitor(config.values, plan.fps, int(ticks.size))

            def on_frame(frame: Frame) -> None:
                monitor.add_vectors(frame.index, frame.vectors)

            vectors = [f for f in plan.features if f.kind is FeatureKind.VECTOR]
            vector_sources = [s for s in sources if s.kind is FeatureKind.VECTOR]
            if vector_sources:
                assemble_frames(reader, uri, vectors, vector_sources, ticks, on_frame)
            extra = [
                *safety_check(reader, config, int(ticks[0]), int(ticks[-1])),
                task_check(config, frame_tasks),
            ]
            return assess_episode(
                uri, config, timeline, sources, ticks, monitor, extra, plan.fps, alignment=alignment
            )
    except BagportError as err:
        return EpisodeQA.failed(uri, str(err))


def score_manifest(
    manifest_uri: str,
    contract_uri: str,
    qa_uri: str | None = None,
    *,
    workers: int | None = None,
    msg_definitions: dict[str, str] | None = None,
) -> list[QAEntry]:
    """Score every bag of a manifest (in parallel processes), in manifest order."""
    contract_text = read_text(contract_uri, "contract")
    parse_contract(contract_text, contract_uri)  # a bad contract stops here, once
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
            qa=qa.model_dump(mode="json"),
            msg_definitions=dict(msg_definitions or {}),
            **bag.window,
        )
        for bag in manifest.bags
    ]
    count = min(workers or os.cpu_count() or 1, len(requests))
    if count <= 1:
        results = [score_bag(r) for r in requests]
    else:
        # spawn, not fork: the caller may run threads (Prefect, fsspec), and fork would copy their locks.
        with ProcessPoolExecutor(max_workers=count, mp_context=multiprocessing.get_context("spawn")) as pool:
            results = list(pool.map(score_bag, requests))
    return [
        QAEntry(qa_result, r.manifest_entry, None) for qa_result, r in zip(results, requests, strict=True)
    ]
