"""Join per-episode clips into ``videos/<key>/chunk-*/file-*.mp4`` by remux (no re-encode)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from fsspec.core import url_to_fs

from bagport.dataset.layout import rotate_files
from bagport.scratch import scratch_folder
from bagport.uris import is_local
from bagport.video import concat_clips

__all__ = ["VideoPlacement", "plan_video_files", "write_video_file"]

_MB = 1024 * 1024


@dataclass(frozen=True, slots=True)
class VideoPlacement:
    chunk_index: int
    file_index: int
    from_timestamp_s: float
    to_timestamp_s: float


def plan_video_files(
    clip_sizes: Sequence[int], *, file_size_in_mb: float, chunks_size: int, start: tuple[int, int] = (0, 0)
) -> list[tuple[tuple[int, int], list[int]]]:
    """Group clips (by their sizes, in order) into files: ((chunk, file), positions) each, at least one
    clip a file. A file rotates as LeRobot's writer rotates it, when its size plus the next clip's
    reaches ``file_size_in_mb``; ``start``: where the first new file goes (after the last one, for an
    append)."""
    limit = file_size_in_mb * _MB
    return rotate_files(
        clip_sizes,
        [0] * len(clip_sizes),
        lambda file_bytes, _, n: file_bytes + clip_sizes[n] >= limit,  # LeRobot's test, on clip sizes
        chunks_size=chunks_size,
        start=start,
    )


def write_video_file(
    out: Path, clips: Sequence[str], *, fps: int, chunk_file: tuple[int, int]
) -> list[VideoPlacement]:
    """Remux the staged clips (URIs, in order) into ``out``; one placement per clip. A clip on an object
    store is downloaded into a scratch folder first, one at a time (memory stays flat)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with scratch_folder("clips") as tmp:
        local: list[Path] = []
        for n, uri in enumerate(clips):
            fs, path = url_to_fs(uri)
            if is_local(fs):
                local.append(Path(path))
            else:
                local.append(Path(tmp) / f"{n:06d}.mp4")
                fs.get_file(path, str(local[-1]))
        return [
            VideoPlacement(*chunk_file, placed.from_timestamp_s, placed.to_timestamp_s)
            for placed in concat_clips(local, out, fps=fps)
        ]
