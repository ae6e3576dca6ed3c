"""Reuse camera clips across contract changes: a camera whose frames come from the same messages,
decoded and encoded the same way, is not decoded or encoded again.

Each staged episode records a *clip key* per camera: a digest of the bag (URI and file stamp), the
camera's contract source (topic, type, stamp, strategy, resize, decoder, fill), which message feeds
every frame (the per-tick selection), the frame ticks, the fps, the encoder and QA settings, the
``--msg-path`` definitions and the bagport version; for a camera recorded as video also the stream's
decoding: the packets skipped before its first key frame, the pre-roll from the key frame before the
window, and the decoder library versions. When a new contract changes something else (a
state selector, an action, a task topic), the frame grid and the camera's selection stay the same, so
the key does too, and the clip (with its image stats and its image/video QA results) is copied from
the earlier staged episode of the same bag. Reuse needs the earlier episode in the staging store:
keep it with ``--keep-staging``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, fields, replace
from typing import Any

import fsspec
import numpy as np

from bagport import __version__
from bagport.contract import FeatureKind
from bagport.decode.video import decoder_settings
from bagport.episode.alignment import Alignment
from bagport.episode.staged import staged_with_prefix
from bagport.qa import CheckResult
from bagport.request import EpisodeRequest, msg_definitions_sha256
from bagport.staging import (
    QA_FILE,
    STATS_FILE,
    EpisodeSummary,
    StagedFeature,
    read_summary,
)

__all__ = ["ReusedClip", "clip_keys", "find_reusable_clips"]

IMAGE_CHECKS = ("values.frozen_image_s", "values.dark_or_bright_frames")
"""QA checks computed from a camera's decoded frames (besides the ``video.*`` fidelity checks)."""


@dataclass(frozen=True, slots=True)
class ReusedClip:
    """A camera clip staged by an earlier conversion of the same bag, and what was measured on it."""

    episode_id: str
    clip_uri: str
    feature: StagedFeature
    stats: dict[str, Any]
    checks: list[CheckResult]
    fidelity_plot: dict[str, Any] | None
    image_means: list[float] | None


def _digest_value(digest: Any, value: object) -> None:
    if isinstance(value, np.ndarray):
        digest.update(str(value.dtype).encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    else:
        digest.update(repr(value).encode())
    digest.update(b"\0")


def clip_keys(
    request: EpisodeRequest,
    stamp: str,
    fps: int,
    alignment: Alignment,
) -> dict[str, str]:
    """The clip key of every camera source (see the module docstring); empty without a file stamp."""
    if not stamp:
        return {}
    keys: dict[str, str] = {}
    for source in alignment.sources:
        if source.kind is not FeatureKind.VIDEO:
            continue
        digest = hashlib.sha256()
        settings = json.dumps(
            [request.encoder.key(), request.qa_scoring, msg_definitions_sha256(request.msg_definitions)],
            sort_keys=True,
            default=str,
        )
        src = replace(source.src, line=None)  # where the entry sits in the file does not change the clip
        for part in (request.bag_uri, stamp, __version__, fps, settings, src, source.stamp_used):
            _digest_value(digest, part)
        for field in fields(source.selection):
            _digest_value(digest, getattr(source.selection, field.name))
        _digest_value(digest, source.filled)
        _digest_value(digest, alignment.ticks_ns)
        if source.timeline.skipped_packets is not None:  # a video stream: how it was decoded
            timeline = source.timeline
            _digest_value(digest, (timeline.skipped_packets, timeline.preroll_ns, decoder_settings()))
        keys[source.src.key] = digest.hexdigest()
    return keys


def _earlier_episodes(request: EpisodeRequest) -> list[EpisodeSummary]:
    """Completed staged episodes of the same bag URI under other contracts or settings."""
    stem = request.episode_id.rsplit("-", 1)[0]  # episode ids are <bag name>-<digest>
    found = []
    for folder in staged_with_prefix(request.staging_uri, f"{stem}-"):  # the store as it is now
        summary = read_summary(folder)
        if (
            summary is not None
            and summary.bag_uri == request.bag_uri
            and summary.episode_id != request.episode_id
        ):
            found.append(summary)
    return found


def _read_json(uri: str) -> Any:
    with fsspec.open(uri, "r", encoding="utf-8") as handle:
        return json.load(handle)


def find_reusable_clips(request: EpisodeRequest, keys: dict[str, str]) -> dict[str, ReusedClip]:
    """Camera key -> a staged clip with the same clip key, from an earlier episode of the same bag."""
    reused: dict[str, ReusedClip] = {}
    if not keys:
        return reused
    for earlier in _earlier_episodes(request):
        matching = [k for k, v in keys.items() if k not in reused and earlier.clip_keys.get(k) == v]
        if not matching:
            continue
        stats = _read_json(earlier.file(STATS_FILE))
        qa = _read_json(earlier.file(QA_FILE))
        features = {f.key: f for f in earlier.features}
        for key in matching:
            checks = [
                CheckResult(**c)
                for c in qa.get("checks", [])
                if c["subject"] == key and (c["check"].startswith("video.") or c["check"] in IMAGE_CHECKS)
            ]
            plots = qa.get("plots", {})
            reused[key] = ReusedClip(
                earlier.episode_id,
                earlier.file(earlier.videos[key]),
                features[key],
                stats[key],
                checks,
                plots.get("fidelity", {}).get(key),
                plots.get("image_means", {}).get(key),
            )
    return reused
