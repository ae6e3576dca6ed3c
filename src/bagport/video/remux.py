"""Join clips into one MP4 by remuxing packets, with exact integer timestamp offsets."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np
import numpy.typing as npt

from bagport.errors import VideoError

__all__ = ["ClipPlacement", "VideoStreamInfo", "concat_clips", "iter_frames", "probe_video"]


@dataclass(frozen=True, slots=True)
class ClipPlacement:
    from_timestamp_s: float
    to_timestamp_s: float
    frames: int


@dataclass(frozen=True, slots=True)
class VideoStreamInfo:
    codec: str
    pix_fmt: str
    width: int
    height: int
    fps: float
    frames: int
    duration_s: float
    has_audio: bool


def _signature(stream: Any) -> tuple[str, int, int, str, Fraction]:
    ctx = stream.codec_context
    return (
        str(stream.codec.canonical_name),
        int(ctx.width),
        int(ctx.height),
        str(ctx.pix_fmt),
        Fraction(stream.time_base),
    )


def concat_clips(clips: Sequence[str | Path], out_path: str | Path, *, fps: int) -> list[ClipPlacement]:
    """Remux ``clips`` in order into ``out_path``; clip ``i`` starts at (frames before it) / fps.

    Offsets are whole frames in the stream time base, never accumulated floats, so the
    start of the 300th clip is as exact as the first.
    """
    if not clips:
        raise VideoError(f"{out_path}: no clips to join")
    placements: list[ClipPlacement] = []
    out: Any = av.open(str(out_path), mode="w", options={"movflags": "faststart"})
    try:
        out_stream: Any = None
        reference: tuple[str, int, int, str, Fraction] | None = None
        ticks_per_frame = 0
        frames_before = 0
        last_dts: int | None = None
        for clip in clips:
            with av.open(str(clip)) as src:
                stream = src.streams.video[0]
                signature = _signature(stream)
                if reference is None:
                    reference = signature
                    per_frame = 1 / (Fraction(fps) * signature[4])
                    if per_frame.denominator != 1:
                        raise VideoError(
                            f"{clip}: time base {signature[4]} cannot represent 1/{fps} s exactly"
                        )
                    ticks_per_frame = int(per_frame)
                    out_stream = out.add_stream_from_template(template=stream, opaque=True)
                    out_stream.time_base = stream.time_base
                elif signature != reference:
                    raise VideoError(
                        f"{clip}: codec/size/pix_fmt/time base {signature[:4]} differ from the first clip's "
                        f"{reference[:4]}; clips can only be joined by remux when they match. Fix: encode every "
                        "episode with the same codec settings and image size."
                    )
                offset = frames_before * ticks_per_frame
                count = 0
                for packet in src.demux(stream):
                    if packet.dts is None:
                        continue
                    packet.pts = packet.pts + offset if packet.pts is not None else None
                    packet.dts = packet.dts + offset
                    if last_dts is not None and packet.dts <= last_dts:
                        raise VideoError(f"{clip}: decode timestamps overlap the previous clip after joining")
                    last_dts = packet.dts
                    packet.stream = out_stream
                    out.mux(packet)
                    count += 1
            placements.append(ClipPlacement(frames_before / fps, (frames_before + count) / fps, count))
            frames_before += count
    finally:
        out.close()
    return placements


def probe_video(path: str | Path) -> VideoStreamInfo:
    """Header facts plus the exact frame count (packets, no decoding)."""
    try:
        container: Any = av.open(str(path))
    except av.error.FFmpegError as err:
        raise VideoError(f"{path}: not a readable video ({err})") from err
    try:
        stream = container.streams.video[0]
        frames = sum(1 for packet in container.demux(stream) if packet.dts is not None)
        ctx = stream.codec_context
        rate = stream.average_rate or stream.guessed_rate
        duration = float(stream.duration * stream.time_base) if stream.duration else 0.0
        return VideoStreamInfo(
            codec=str(stream.codec.canonical_name),
            pix_fmt=str(ctx.pix_fmt),
            width=int(ctx.width),
            height=int(ctx.height),
            fps=float(rate) if rate else 0.0,
            frames=frames,
            duration_s=duration,
            has_audio=bool(container.streams.audio),
        )
    except (av.error.FFmpegError, IndexError) as err:
        raise VideoError(f"{path}: not a readable video ({err})") from err
    finally:
        container.close()


def iter_frames(path: str | Path) -> Iterator[tuple[float, npt.NDArray[np.uint8]]]:
    """Decode every frame: (pts in seconds, RGB HxWx3 uint8)."""
    container: Any = av.open(str(path))
    try:
        stream = container.streams.video[0]
        for frame in container.decode(stream):
            yield float(frame.pts * stream.time_base), frame.to_ndarray(format="rgb24")
    finally:
        container.close()
