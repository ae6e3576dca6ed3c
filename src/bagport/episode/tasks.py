"""The task prompt of each frame: from a task topic, the bag's metadata, or the manifest."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from bagport.episode.timeline import TaskMessage
from bagport.errors import ManifestError
from bagport.request import EpisodeRequest

__all__ = ["OPERATOR_PROMPT_KEY", "resolve_tasks"]

OPERATOR_PROMPT_KEY = "lerobot.operator_prompt"


def resolve_tasks(
    messages: Sequence[TaskMessage],
    ticks_ns: npt.NDArray[np.int64],
    custom_data: Mapping[str, str],
    request: EpisodeRequest,
    contract_default: str | None = None,
) -> tuple[list[str], str]:
    """Per-frame task strings and where they came from.

    Priority: the contract's task topic (held per frame; frames before the first
    prompt take the first prompt), then the bag's ``custom_data`` operator prompt
    (Rosetta's recorder), then the manifest entry's ``task``, then the contract's
    ``default_task``.
    """
    prompts = [m for m in messages if m.text.strip()]
    if prompts:
        stamps = np.array([m.stamp_ns for m in prompts], dtype=np.int64)
        order = np.argsort(stamps, kind="stable")
        pos = np.searchsorted(stamps[order], ticks_ns, side="right") - 1
        chosen = order[np.maximum(pos, 0)]
        return [prompts[int(i)].text.strip() for i in chosen], "topic"
    prompt = custom_data.get(OPERATOR_PROMPT_KEY, "").strip()
    if prompt:
        return [prompt] * int(ticks_ns.size), "bag_metadata"
    if request.default_task:
        return [request.default_task] * int(ticks_ns.size), "manifest"
    if contract_default and contract_default.strip():
        return [contract_default.strip()] * int(ticks_ns.size), "contract"
    raise ManifestError(
        f"bag {request.bag_uri} has no task prompt",
        entry=request.manifest_entry,
        fix="add 'task: ...' to its manifest entry, a 'tasks:' topic or a 'default_task' to the contract.",
    )
