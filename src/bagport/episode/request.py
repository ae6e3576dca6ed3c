"""What a worker needs to convert one bag: small, serialisable, no live objects."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from typing import Any

__all__ = ["EpisodeRequest", "episode_id_for"]


@dataclass(frozen=True, slots=True)
class EpisodeRequest:
    episode_id: str
    bag_uri: str
    manifest_entry: int
    staging_uri: str
    contract_text: str
    contract_name: str
    encoder: dict[str, Any] = field(default_factory=dict)
    default_task: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    qa: dict[str, Any] = field(default_factory=dict)
    """QA thresholds (a :class:`bagport.qa.QAConfig` as a dict); empty: the defaults."""
    msg_definitions: dict[str, str] = field(default_factory=dict)
    """``{type name: .msg text}`` from ``--msg-path``: workers need no access to the folder."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def contract_sha256(self) -> str:
        return hashlib.sha256(self.contract_text.encode()).hexdigest()

    @property
    def qa_sha256(self) -> str:
        return hashlib.sha256(json.dumps(self.qa, sort_keys=True).encode()).hexdigest()


def episode_id_for(bag_uri: str, contract_text: str, encoder: dict[str, Any]) -> str:
    """Stable id: the same bag, contract and encoder settings give the same staged episode."""
    digest = hashlib.sha256()
    for part in (bag_uri, contract_text, repr(sorted(encoder.items()))):
        digest.update(part.encode())
        digest.update(b"\0")
    stem = bag_uri.rstrip("/").rsplit("/", 1)[-1]
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in stem)[:40]
    return f"{safe}-{digest.hexdigest()[:12]}"
