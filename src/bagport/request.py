"""What a worker needs to convert one episode: small, serialisable, no live objects.

A neutral module: the plan (`bagport.run`), segmentation (`bagport.segment`), conversion
(`bagport.episode`) and the flows all pass `EpisodeRequest`s, so it sits below all of them."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from pydantic import JsonValue

from bagport.qa.config import QAConfig
from bagport.qa.result import episode_name
from bagport.timewindow import WHOLE_BAG, TimeWindow
from bagport.video.settings import EncoderSettings

__all__ = ["EpisodeOutcome", "EpisodeRequest", "episode_id_for"]


@dataclass(frozen=True, slots=True)
class EpisodeRequest:
    episode_id: str
    bag_uri: str
    manifest_entry: int
    staging_uri: str
    contract_text: str
    contract_name: str
    encoder: EncoderSettings = field(default_factory=EncoderSettings)
    """The checked encoder settings (``ConvertConfig.encoder``, a preset's keys, is converted when the
    run is planned)."""
    default_task: str | None = None
    metadata: dict[str, JsonValue] = field(default_factory=dict)
    qa: QAConfig = field(default_factory=QAConfig)
    """QA thresholds (the defaults unless the run gives a QA file)."""
    window: TimeWindow = WHOLE_BAG
    """The episode's window of the bag (the manifest entry's, or one a segmentation found)."""
    segment: int | None = None
    """Index of the episode among those of its bag (``None``: the whole bag is one episode)."""
    label: str | None = None
    """``success``, ``failed``, ``discarded`` (from episode events), or ``None``."""
    note: str = ""
    """The event's note, e.g. why an operator marked the demonstration failed."""
    msg_definitions: dict[str, str] = field(default_factory=dict)
    """``{type name: .msg text}`` from ``--msg-path``: workers need no access to the folder."""

    @property
    def name(self) -> str:
        """The bag's file name, with ``#<segment>`` for one episode of several in a bag."""
        return episode_name(self.bag_uri, self.segment)

    def for_window(
        self, segment: int, window: TimeWindow, label: str | None, note: str, episode_id: str = ""
    ) -> EpisodeRequest:
        """The request for one episode of this bag; the recorder's ``episode_id`` (from its episode
        events) joins the episode's metadata."""
        return replace(
            self,
            episode_id=episode_id_for(
                self.bag_uri, self.contract_text, self.encoder, window.key(), self.msg_definitions
            ),
            metadata={**self.metadata, "episode_id": episode_id} if episode_id else self.metadata,
            window=window,
            segment=segment,
            label=label,
            note=note,
        )

    @property
    def contract_sha256(self) -> str:
        return hashlib.sha256(self.contract_text.encode()).hexdigest()

    @property
    def qa_scoring(self) -> dict[str, Any]:
        """The QA settings that shape the staged scores, as JSON (``on_fail`` is applied when the dataset
        is written)."""
        return self.qa.model_dump(mode="json", exclude={"on_fail"})

    @property
    def qa_sha256(self) -> str:
        return hashlib.sha256(json.dumps(self.qa_scoring, sort_keys=True).encode()).hexdigest()


def msg_definitions_sha256(msg_definitions: Mapping[str, str]) -> str:
    """Digest of the ``--msg-path`` definitions a worker decodes with; empty without any."""
    if not msg_definitions:
        return ""
    return hashlib.sha256(json.dumps(sorted(msg_definitions.items())).encode()).hexdigest()


def episode_id_for(
    bag_uri: str,
    contract_text: str,
    encoder: EncoderSettings,
    window: str = "",
    msg_definitions: Mapping[str, str] | None = None,
) -> str:
    """Stable id: the same bag (window), contract, encoder settings and ``--msg-path`` definitions
    (they change decoding) give the same staged episode."""
    digest = hashlib.sha256()
    parts: tuple[str, ...] = (bag_uri, contract_text, encoder.key())
    if window:
        parts += (window,)
    if msg_definitions:
        parts += (f"msg:{msg_definitions_sha256(msg_definitions)}",)
    for part in parts:
        digest.update(part.encode())
        digest.update(b"\0")
    stem = bag_uri.rstrip("/").rsplit("/", 1)[-1]
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in stem)[:40]
    return f"{safe}-{digest.hexdigest()[:12]}"


@dataclass(frozen=True, slots=True)
class EpisodeOutcome:
    """What converting one episode gives the flow: where it was staged and its QA verdict, or bagport's
    one-paragraph error (small and typed: this crosses the task boundary, never arrays)."""

    episode_id: str
    dir_uri: str | None = None
    """The staged episode's folder (``None``: the conversion failed)."""
    frames: int = 0
    qa_verdict: str | None = None
    error: str | None = None
    """bagport's error when the episode could not be converted."""
    transient: bool = False
    """The error is a transient I/O error still there after the retries (not the bag's fault)."""
