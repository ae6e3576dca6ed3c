"""Join per-episode clips into ``videos/<key>/chunk-*/file-*.mp4`` by remux (no re-encode)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from fsspec.core import url_to_fs

from bagport.dataset.layout import VIDEO_PATH, next_chunk_file
from bagport.scratch import scratch_folder
from bagport.staging import EpisodeSummary
from bagport.uris import is_local
from bagport.video import concat_clips

__all__ = ["VideoPlacement", "write_video_files"]

_MB = 1024 * 1024


@dataclass(frozen=True, slots=True)
class VideoPlacement:
    chunk_index: int
    file_index: int
    from_timestamp_s: float
    to_timestamp_s: float


def _local_clip(uri: str, scratch: Path, name: str) -> tuple[Path, int]:
    fs, path = url_to_fs(uri)
    size = int(fs.size(path))
    if is_local(fs):
        return Path(path), size
    local = scratch / name
    fs.get_file(path, str(local))
    return local, size


def write_video_files(
    root: Path,
    key: str,
    summaries: Sequence[EpisodeSummary],
    *,
    fps: int,
    file_size_in_mb: float,
    chunks_size: int,
    start: tuple[int, int] = (0, 0),
) -> list[VideoPlacement]:
    """Group clips into files (at least one clip each) and remux; a file rotates as LeRobot's writer rotates
    it, when its size plus the next clip's reaches ``file_size_in_mb``.

    ``start`` (chunk, file): where the first new file goes (after the last one, for an append).
    """
    placements: list[VideoPlacement] = []
    chunk, file = start
    limit = file_size_in_mb * _MB
    with scratch_folder("clips") as tmp:
        scratch = Path(tmp)
        group: list[Path] = []
        group_bytes = 0

        def flush() -> None:
            nonlocal chunk, file, group, group_bytes
            out = root / VIDEO_PATH.format(video_key=key, chunk_index=chunk, file_index=file)
            out.parent.mkdir(parents=True, exist_ok=True)
            placements.extend(
                VideoPlacement(chunk, file, placed.from_timestamp_s, placed.to_timestamp_s)
                for placed in concat_clips(group, out, fps=fps)
            )
            for clip in group:
                if clip.is_relative_to(scratch):
                    clip.unlink()
            chunk, file = next_chunk_file(chunk, file, chunks_size)
            group, group_bytes = [], 0

        for n, summary in enumerate(summaries):
            clip, size = _local_clip(summary.file(summary.videos[key]), scratch, f"{n:06d}.mp4")
            if group and group_bytes + size >= limit:  # LeRobot's test, on clip sizes
                flush()
            group.append(clip)
            group_bytes += size
        if group:
            flush()
    return placements
