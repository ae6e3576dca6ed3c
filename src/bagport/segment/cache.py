"""A bag's segmentation, kept in the staging store so a re-run or resume does not read the bag again.

```
<staging>/segments/<bag name>-<key>.json    the windows and what was left out; one JSON object
```

The key covers everything the windows depend on: the bag URI and its files' stamp (the one staged
episodes are checked against), the contract's ``episodes`` options and, for ``gap_s``, the streams it
scans, a manifest window (none today: a windowed entry is not split), the ``--msg-path`` definitions and
the bagport version. An entry that cannot be read or parsed counts as missing (the bag is segmented
again and the entry rewritten); a partly written entry does not parse (it is one JSON object).
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

import fsspec

from bagport import __version__
from bagport.contract.model import EpisodesOptions
from bagport.request import EpisodeRequest, msg_definitions_sha256
from bagport.segment.windows import EpisodeWindow, Segmentation
from bagport.staging import staged_path, write_json

__all__ = ["read_segmentation", "segmentation_uri", "write_segmentation"]

_FORMAT = 1
"""Bump when the entry's layout or meaning changes."""


def segmentation_uri(
    request: EpisodeRequest, options: EpisodesOptions, stream_topics: tuple[str, ...], stamp: str
) -> str | None:
    """Where the segmentation of the request's bag is kept; ``None`` without a staging store (``bagport
    qa``) or a stamp (the bag's files could not be listed, so a change could not be seen: segment afresh)."""
    if not stamp or not request.staging_uri:
        return None
    digest = hashlib.sha256()
    parts = (
        f"segments-v{_FORMAT}",
        request.bag_uri,
        stamp,
        options.model_dump_json(),
        "\n".join(stream_topics) if options.gap_s is not None else "",
        request.window.key(),
        msg_definitions_sha256(request.msg_definitions),
        __version__,
    )
    for part in parts:
        digest.update(part.encode())
        digest.update(b"\0")
    stem = request.bag_uri.rstrip("/").rsplit("/", 1)[-1]
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in stem)[:40]
    return staged_path(request.staging_uri, "segments", f"{safe}-{digest.hexdigest()[:16]}.json")


def write_segmentation(uri: str, segmentation: Segmentation) -> None:
    write_json(uri, {"format": _FORMAT, **_to_dict(segmentation)})


def read_segmentation(uri: str) -> Segmentation | None:
    """The kept segmentation, or ``None`` if there is none or it is unreadable (partly written, corrupt)."""
    try:
        with fsspec.open(uri, "r", encoding="utf-8") as handle:
            data = json.load(handle)
        if data["format"] != _FORMAT:
            return None
        return _from_dict(data)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _to_dict(segmentation: Segmentation) -> dict[str, Any]:
    windows = [
        {
            "start_ns": w.start_ns,
            "end_ns": w.end_ns,
            "label": w.label,
            "note": w.note,
            "ended_by": w.ended_by,
            "episode_id": w.episode_id,
        }
        for w in segmentation.windows
    ]
    return {"windows": windows, "ignored": list(segmentation.ignored)}


def _from_dict(data: dict[str, Any]) -> Segmentation:
    windows = tuple(
        EpisodeWindow(
            int(w["start_ns"]),
            int(w["end_ns"]),
            None if w["label"] is None else str(w["label"]),
            str(w["note"]),
            str(w["ended_by"]),
            str(w.get("episode_id", "")),
        )
        for w in data["windows"]
    )
    return Segmentation(windows, tuple(str(reason) for reason in data["ignored"]))
