"""Decode a clip and score each sampled frame against block-mean references (see ``fidelity``)."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from itertools import chain
from pathlib import Path
from typing import Any, BinaryIO

import av
import numpy as np
import numpy.typing as npt

from bagport.errors import VideoError
from bagport.video.blockmeans import BlockGrid

__all__ = ["FidelityParams", "FramePair", "FrameScores", "ReferenceFile", "compare_frames", "sampled_slot"]

_RED = np.array([255, 0, 0], np.uint8)

SINGLE_THREAD_DECODE_PIXELS = 320 * 240
"""Clips this small are checked with one decoder thread: for a W3 clip (128x96, 60 AV1 frames) starting
dav1d's threads took more CPU than decoding (the whole clip: 5.4-6.4 ms of CPU threaded, 3.5-3.9 ms
on one thread, also less wall time). Larger clips are decoded on the decoder's own threads."""


class ReferenceFile:
    """The block-mean references of a clip, read one sample at a time from their file.

    Read, not memory-mapped: the pages of a mapping count towards the process's memory and stay
    while it is open, so a long episode's comparison would grow with its length. The file is opened
    once, at the first read, until :meth:`close`.
    """

    def __init__(self, path: Path, dtype: npt.DTypeLike, shape: tuple[int, ...], count: int) -> None:
        self._path = path
        self._dtype = np.dtype(dtype)
        self._shape = shape
        self._bytes = int(np.prod(shape)) * self._dtype.itemsize
        self._count = count
        self._handle: BinaryIO | None = None

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, slot: int) -> npt.NDArray[Any]:
        if not 0 <= slot < self._count:
            raise IndexError(slot)
        if self._handle is None:
            self._handle = self._path.open("rb")
        self._handle.seek(slot * self._bytes)
        data = self._handle.read(self._bytes)
        return np.frombuffer(data, dtype=self._dtype).reshape(self._shape)

    def close(self) -> None:
        """Close the file (idempotent; a later read opens it again)."""
        if self._handle is not None:
            self._handle.close()
            self._handle = None


@dataclass(frozen=True, slots=True)
class FidelityParams:
    """Thresholds of ``compare_clip``; ``*_levels`` are 8-bit intensity levels (0-255).

    Chosen on synthetic clips (tests/bagport/video/test_fidelity.py patterns, 120x160 and
    240x320): the error of a block mean is ~1.3 levels for flat colours after any 8-bit YUV
    round trip, 0.06-0.7 for a lossless yuv444p encode. Honest coding loss stays below the
    floor: the worst block of a noisy textured scene is 16-19 levels under libsvtav1 crf 30-50
    and 13-27 under libx264 crf 35-45 (median 3-6 there, hence ``block_k``), 10-13 for libx264
    crf 23 on the squares pattern. Stale squares and foreign blocks under libsvtav1 crf 30 are
    35-57 levels off. ``copy_*``: a copied frame is much closer to an earlier source frame than
    to its own, and its own error is above the ~1.3-level colour round-trip noise.
    """

    block_k: float = 6.0
    block_floor_levels: float = 24.0
    min_damaged_blocks: int = 1
    copy_ratio: float = 3.0
    copy_floor_levels: float = 1.5
    copy_lookback: int = 2
    psnr_cap_db: float = 99.0
    per_frame: bool = False
    max_listed_frames: int = 50


@dataclass(frozen=True, slots=True)
class FramePair:
    """One decoded frame beside its source reference, for display (all uint8 ``h x w x 3``).

    The source is only known by its block means, so ``reference_blocks_rgb`` is a mosaic;
    ``decoded_blocks_rgb`` is the decoded frame reduced the same way (the images compared).
    """

    index: int
    block: int
    psnr_db: float
    damaged_blocks: int
    copy_of: int | None
    decoded_rgb: npt.NDArray[np.uint8] = field(repr=False)
    decoded_blocks_rgb: npt.NDArray[np.uint8] = field(repr=False)
    reference_blocks_rgb: npt.NDArray[np.uint8] = field(repr=False)
    damaged_mask: npt.NDArray[np.bool_] = field(repr=False)

    def side_by_side(self, gap_px: int = 4) -> npt.NDArray[np.uint8]:
        """Source mosaic | decoded mosaic | decoded frame with damaged blocks outlined in red."""
        outlined = self.decoded_rgb.copy()
        height, width = outlined.shape[:2]
        block = self.block
        for row, col in np.argwhere(self.damaged_mask)[:500]:
            top, left = int(row) * block, int(col) * block
            bottom, right = min(top + block, height) - 1, min(left + block, width) - 1
            outlined[top : bottom + 1, [left, right]] = _RED
            outlined[[top, bottom], left : right + 1] = _RED
        spacer = np.full((height, gap_px, 3), 255, np.uint8)
        parts = [self.reference_blocks_rgb, spacer, self.decoded_blocks_rgb, spacer, outlined]
        return np.concatenate(parts, axis=1)


@dataclass(slots=True)
class FrameScores:
    """Per sampled frame scores (small arrays, not images) and the clip-level checks."""

    frame_index: npt.NDArray[np.int64]
    psnr_db: npt.NDArray[np.float32]
    damaged_blocks: npt.NDArray[np.int32]
    copy_of: npt.NDArray[np.int64]  # -1: not a copy
    damaged: npt.NDArray[np.bool_]
    frames_decoded: int = 0
    first_bad_pts_frame: int | None = None
    decode_error: str | None = None
    worst: FramePair | None = None

    def keep(self, scored: npt.NDArray[np.bool_]) -> None:
        """Drop the slots no decoded frame filled (a shorter or broken clip)."""
        self.frame_index = self.frame_index[scored]
        self.psnr_db = self.psnr_db[scored]
        self.damaged_blocks = self.damaged_blocks[scored]
        self.copy_of = self.copy_of[scored]
        self.damaged = self.damaged[scored]


@dataclass(slots=True)
class _Worst:
    key: tuple[bool, int, float] = (False, -1, 0.0)
    index: int = -1
    psnr_db: float = 0.0
    damaged_blocks: int = 0
    copy_of: int | None = None
    decoded: npt.NDArray[np.uint8] | None = None
    decoded_means: npt.NDArray[np.float32] | None = None
    reference_means: npt.NDArray[np.float32] | None = None
    mask: npt.NDArray[np.bool_] | None = None


def sampled_slot(n: int, sample_every: int, run: int) -> int | None:
    """Where frame ``n``'s reference is among the sampled ones, or ``None`` when not sampled.

    Frames are sampled in runs of ``run`` consecutive frames (a GOP: ``g`` of the encoder),
    every ``sample_every``-th run: so a sampled run starts at a key frame and the clip can be
    checked by decoding only the sampled runs, and inter frames are checked as often as key
    frames (with ``g=2``, sampling single frames 0, 4, 8, ... would only ever see key frames).
    """
    group, offset = divmod(n, run)
    if group % sample_every:
        return None
    return (group // sample_every) * run + offset


def compare_frames(
    mp4_path: str | Path,
    refs: ReferenceFile,
    grid: BlockGrid,
    sampling: tuple[int, int],
    fps: int | None,
    params: FidelityParams,
) -> FrameScores:
    """Score the sampled frames of ``mp4_path`` against ``refs``; ``sampling`` is ``(sample_every, run)``.

    Frames are indexed in presentation order (the rank of their pts). Only the packets from
    the key frame before a sampled frame on are decoded, so the cost follows the sampled share.
    """
    sample_every, run = sampling
    size = len(refs)
    scores = FrameScores(
        frame_index=np.zeros(size, np.int64),
        psnr_db=np.zeros(size, np.float32),
        damaged_blocks=np.zeros(size, np.int32),
        copy_of=np.full(size, -1, np.int64),
        damaged=np.zeros(size, np.bool_),
    )
    scored = np.zeros(size, np.bool_)
    worst = _Worst()
    recent: deque[tuple[int, npt.NDArray[np.float32]]] = deque(maxlen=max(params.copy_lookback, 0))
    container = _open(mp4_path, grid)
    try:
        stream = container.streams.video[0]
        rank = _presentation_ranks(container, stream, fps, scores)
        for frame in _sampled_gops(container, stream, rank, sample_every, run):
            n = rank.get(frame.pts, -1)
            slot = sampled_slot(n, sample_every, run) if n >= 0 else None
            if slot is None or slot >= size or scored[slot]:
                continue
            rgb = frame.to_ndarray(format="rgb24")
            decoded = grid.means(rgb)
            reference = refs[slot].astype(np.float32)
            psnr, mask, copy_of = _score(decoded, reference, recent, params)
            recent.append((n, reference))
            blocks = int(mask.sum())
            is_damaged = blocks >= params.min_damaged_blocks or copy_of is not None
            scores.frame_index[slot] = n
            scores.psnr_db[slot] = psnr
            scores.damaged_blocks[slot] = blocks
            scores.copy_of[slot] = -1 if copy_of is None else copy_of
            scores.damaged[slot] = is_damaged
            scored[slot] = True
            key = (is_damaged, blocks, -psnr)
            if key > worst.key:
                worst = _Worst(key, n, psnr, blocks, copy_of, rgb, decoded, reference, mask)
    except av.error.FFmpegError as err:
        scores.decode_error = f"decoding stopped: {err}"
    finally:
        container.close()
        refs.close()
    scores.keep(scored)
    scores.worst = _frame_pair(worst, grid)
    return scores


def _sampled_gops(
    container: Any, stream: Any, rank: dict[int, int], sample_every: int, run: int
) -> Iterator[Any]:
    """The decoded frames of every GOP that holds a sampled frame (from the clip's start), in decoding
    order: the packets from each key frame on are held until one of them is sampled, and a GOP with none
    is never decoded."""
    container.seek(0)
    unfed: list[Any] = []
    live = False  # the decoder has this GOP's key frame
    packets = (p for p in container.demux(stream) if p.pts is not None and p.size)
    for packet in chain(packets, [None]):  # lazily: a list of every packet grows with the clip
        if packet is not None:
            if packet.is_keyframe:
                unfed, live = [], False
            unfed.append(packet)
            if not live and sampled_slot(rank.get(packet.pts, -1), sample_every, run) is None:
                continue
            batch, unfed, live = unfed, [], True
        else:
            batch = [None]  # flush the decoder
        for item in batch:
            yield from stream.codec_context.decode(item)


def _presentation_ranks(container: Any, stream: Any, fps: int | None, scores: FrameScores) -> dict[int, int]:
    """Demux only (no decoding): every frame's pts, its rank, the frame count and the pts check."""
    period_s = _frame_period_s(stream, fps)
    time_base = Fraction(stream.time_base) if stream.time_base else None
    stamps = sorted(p.pts for p in container.demux(stream) if p.pts is not None and p.size)
    scores.frames_decoded = len(stamps)
    if time_base is None:
        scores.first_bad_pts_frame = 0 if stamps else None
    else:  # pts * time_base == n * period_s, in integers (Fractions cost 1 ms a small clip)
        pts_scale = time_base.numerator * period_s.denominator
        n_scale = period_s.numerator * time_base.denominator
        scores.first_bad_pts_frame = next(
            (n for n, pts in enumerate(stamps) if pts * pts_scale != n * n_scale), None
        )
    return {pts: n for n, pts in enumerate(stamps)}


def _open(mp4_path: str | Path, grid: BlockGrid) -> Any:
    try:
        container: Any = av.open(str(mp4_path))
    except av.error.FFmpegError as err:
        raise VideoError(f"{mp4_path}: cannot open the clip to check its fidelity ({err})") from err
    if not container.streams.video:
        container.close()
        raise VideoError(f"{mp4_path}: no video stream to check")
    stream = container.streams.video[0]
    ctx = stream.codec_context
    if int(ctx.height) * int(ctx.width) <= SINGLE_THREAD_DECODE_PIXELS:
        ctx.thread_count = 1  # the decoder's thread pool costs more than it brings (see the constant)
    else:
        stream.thread_type = "AUTO"
    if (int(ctx.height), int(ctx.width)) != (grid.height, grid.width):
        container.close()
        raise VideoError(
            f"{mp4_path}: the clip is {ctx.width}x{ctx.height} but the recorder saw {grid.width}x"
            f"{grid.height} frames. Fix: record the frames exactly as they are given to the encoder."
        )
    return container


def _frame_period_s(stream: Any, fps: int | None) -> Fraction:
    rate = fps or stream.average_rate or stream.guessed_rate
    return 1 / Fraction(rate) if rate else Fraction(0)


def _score(
    decoded: npt.NDArray[np.float32],
    reference: npt.NDArray[np.float32],
    recent: deque[tuple[int, npt.NDArray[np.float32]]],
    params: FidelityParams,
) -> tuple[float, npt.NDArray[np.bool_], int | None]:
    diff = decoded - reference
    block_err = np.abs(diff).mean(axis=2)
    mse = float(np.mean(diff * diff))
    psnr = params.psnr_cap_db if mse <= 0 else min(params.psnr_cap_db, 10 * math.log10(255.0**2 / mse))
    threshold = max(params.block_k * float(np.median(block_err)), params.block_floor_levels)
    mask = block_err > threshold
    own = float(block_err.mean())
    copy_of: int | None = None
    if own > params.copy_floor_levels:
        best = own / params.copy_ratio
        for index, previous in recent:
            other = float(np.abs(decoded - previous).mean())
            if other < best:
                best, copy_of = other, index
    return psnr, mask, copy_of


def _frame_pair(worst: _Worst, grid: BlockGrid) -> FramePair | None:
    if worst.decoded is None or worst.decoded_means is None or worst.reference_means is None:
        return None
    if worst.mask is None:
        return None
    return FramePair(
        index=worst.index,
        block=grid.block,
        psnr_db=worst.psnr_db,
        damaged_blocks=worst.damaged_blocks,
        copy_of=worst.copy_of,
        decoded_rgb=worst.decoded,
        decoded_blocks_rgb=grid.mosaic(worst.decoded_means),
        reference_blocks_rgb=grid.mosaic(worst.reference_means),
        damaged_mask=worst.mask,
    )
