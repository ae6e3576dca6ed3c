"""Video fidelity: measure an encoded clip against the frames that were fed to the encoder.

Lossy encoders can silently diverge from their input (a block left stale from an older
frame, a foreign grey block, an inter frame decoded as a copy of the previous key frame).
This module keeps a cheap reference of every source frame while the clip is encoded, then
decodes the clip and compares it frame by frame.

Wiring (one recorder per clip)::

    recorder = FidelityRecorder(tmp_dir / "front.refs", height=h, width=w, sample_every=4, run=g)
    with StreamingEncoder(clip, fps=fps, width=w, height=h, settings=settings) as encoder:
        for rgb in frames:
            encoder.write(rgb)
            recorder.record(rgb)          # same frames, same order
    result = compare_clip(clip, recorder, fps=fps)  # after the encoder is closed
    recorder.discard()                    # deletes the reference file
    qa_row = result.to_dict()             # JSON-ready; result.worst holds images for the report

Reference: per sampled frame, the mean of each ``block x block`` pixel block per channel
(:class:`~bagport.video.blockmeans.BlockGrid`), stored as float16 in an append-only file:
``ceil(h/block) * ceil(w/block) * 3 * 2`` bytes per sampled frame (28.8 kB at 480x640,
block 8, i.e. 1/32 of the raw frame). Nothing per frame is kept in memory.

Comparison, per sampled frame (errors in 8-bit levels, on block means):

- ``psnr_db``: PSNR of the decoded block means against the reference (peak 255), capped at
  :attr:`FidelityParams.psnr_cap_db` (99 dB) so identical frames give a finite number.
- damaged blocks: blocks whose error (mean abs error over RGB) exceeds
  ``max(block_k * median block error of the frame, block_floor_levels)``. Encoding noise is
  spread over the frame and lifts the median with it; a stale or foreign block stands out.
- copy: the decoded frame is ``copy_ratio`` times closer to one of the previous
  ``copy_lookback`` sampled source frames than to its own source (and its own error exceeds
  ``copy_floor_levels``). With sampling, only copies of earlier *sampled* frames are
  recognised (within a sampled run of a GOP, the previous frame is one of them).

A frame is damaged when it has ``>= min_damaged_blocks`` damaged blocks or is a copy. The
worst frame is the damaged frame with the most damaged blocks (then the lowest PSNR), or the
lowest-PSNR frame when none is damaged; :class:`FramePair` keeps that one decoded frame (and
the block mosaics) for display. ``damaged_frame_indices`` lists at most ``max_listed_frames``
(50); ``per_frame=True`` adds per-sampled-frame PSNR and damaged-block counts.

Sampling (``sample_every`` > 1) checks every ``sample_every``-th run of ``run`` frames (a GOP)
and decodes only those runs, so the cost follows the sampled share. Frames are indexed in
presentation order (the rank of their pts). ``frames_decoded`` counts the frames in the clip
(every packet, decoded or skipped). Frame count and timestamps (frame ``i`` at ``i / fps`` s
exactly, in the stream's time base) are checked for every frame and reported, never raised: a mismatch is a QA finding, and so is a
decode error mid-clip (``decode_error``). Only an unreadable clip or a clip of another frame
size raises :class:`VideoError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import numpy as np
import numpy.typing as npt

from bagport.errors import VideoError
from bagport.video.blockmeans import BlockGrid
from bagport.video.fidelity_compare import (
    FidelityParams,
    FramePair,
    ReferenceFile,
    compare_frames,
    sampled_slot,
)

__all__ = ["ClipFidelity", "FidelityParams", "FidelityRecorder", "FramePair", "compare_clip"]

_REF_DTYPE = np.float16


@dataclass(frozen=True, slots=True)
class ClipFidelity:
    """How one clip matches its source. ``to_dict`` is JSON-ready; ``worst`` is not serialised."""

    frames_expected: int
    frames_decoded: int
    pts_ok: bool
    first_bad_pts_frame: int | None
    decode_error: str | None
    sampled_frames: int
    sample_every: int
    sample_run: int
    block: int
    psnr_min_db: float | None
    psnr_median_db: float | None
    damaged_frames: int
    copied_frames: int
    damaged_frame_indices: tuple[int, ...]
    worst_frame_index: int | None
    worst_psnr_db: float | None
    worst_damaged_blocks: int
    psnr_db_per_frame: tuple[float, ...] | None = None
    damaged_blocks_per_frame: tuple[int, ...] | None = None
    worst: FramePair | None = field(default=None, compare=False, repr=False)

    @property
    def frames_ok(self) -> bool:
        return self.frames_expected == self.frames_decoded

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            name: getattr(self, name) for name in self.__dataclass_fields__ if name != "worst"
        }
        out["frames_ok"] = self.frames_ok
        for name in ("damaged_frame_indices", "psnr_db_per_frame", "damaged_blocks_per_frame"):
            if out[name] is not None:
                out[name] = list(out[name])
        return out


class FidelityRecorder:
    """Block-mean references of the frames fed to an encoder, appended to a file on local disk.

    ``record`` every frame given to the encoder, in order. Frames are sampled in runs of
    ``run`` consecutive frames (pass the encoder's GOP size ``g``), every ``sample_every``-th
    run (see :func:`~bagport.video.fidelity_compare.sampled_slot`); ``sample_every=1`` keeps
    every frame. Memory stays flat whatever the episode length.
    """

    def __init__(
        self,
        path_for_refs: str | Path,
        *,
        height: int,
        width: int,
        block: int = 8,
        sample_every: int = 1,
        run: int = 1,
    ) -> None:
        if sample_every < 1 or run < 1:
            raise VideoError(f"{path_for_refs}: sample_every={sample_every} and run={run} must be >= 1")
        self.run = run
        self.grid = BlockGrid(height=height, width=width, block=block)
        self.path = Path(path_for_refs)
        self.sample_every = sample_every
        self.frames_recorded = 0
        self.sampled_frames = 0
        self._shape = (height, width, 3)
        try:
            self._file: BinaryIO | None = self.path.open("wb")
        except OSError as err:
            raise VideoError(f"{self.path}: cannot create the fidelity reference file ({err})") from err

    @property
    def ref_shape(self) -> tuple[int, int, int]:
        return (self.grid.rows, self.grid.cols, 3)

    @property
    def ref_bytes_per_sample(self) -> int:
        return self.grid.rows * self.grid.cols * 3 * np.dtype(_REF_DTYPE).itemsize

    def record(self, rgb: npt.NDArray[np.uint8]) -> None:
        """Account for the next encoded frame (uint8 ``height x width x 3``)."""
        if self._file is None:
            raise VideoError(f"{self.path}: record() after close(); use one recorder per clip")
        if rgb.shape != self._shape or rgb.dtype != np.uint8:
            raise VideoError(
                f"{self.path}: frame {self.frames_recorded} is {rgb.dtype}{list(rgb.shape)}, the recorder "
                f"expects uint8{list(self._shape)} (the frames given to the encoder)"
            )
        if sampled_slot(self.frames_recorded, self.sample_every, self.run) is not None:
            self.grid.means(rgb).astype(_REF_DTYPE).tofile(self._file)
            self.sampled_frames += 1
        self.frames_recorded += 1

    def close(self) -> None:
        """Flush and close the reference file (idempotent); the file stays for :func:`compare_clip`."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def references(self) -> ReferenceFile:
        """The sampled references (``rows x cols x 3`` each), read from the file one at a time."""
        self.close()
        return ReferenceFile(self.path, _REF_DTYPE, self.ref_shape, self.sampled_frames)

    def discard(self) -> None:
        """Close and delete the reference file."""
        self.close()
        self.path.unlink(missing_ok=True)

    def __enter__(self) -> FidelityRecorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def compare_clip(
    mp4_path: str | Path,
    recorder: FidelityRecorder,
    *,
    fps: int | None = None,
    params: FidelityParams | None = None,
) -> ClipFidelity:
    """Decode ``mp4_path`` and compare it with ``recorder``'s references (see the module docstring).

    ``fps`` fixes the expected pts step; without it the stream's average rate is used.
    """
    params = params or FidelityParams()
    scores = compare_frames(
        mp4_path, recorder.references(), recorder.grid, (recorder.sample_every, recorder.run), fps, params
    )
    psnrs = np.asarray(scores.psnr_db, np.float64)
    damaged = [int(i) for i in scores.frame_index[scores.damaged]]
    worst = scores.worst
    return ClipFidelity(
        frames_expected=recorder.frames_recorded,
        frames_decoded=scores.frames_decoded,
        pts_ok=scores.first_bad_pts_frame is None,
        first_bad_pts_frame=scores.first_bad_pts_frame,
        decode_error=scores.decode_error,
        sampled_frames=len(psnrs),
        sample_every=recorder.sample_every,
        sample_run=recorder.run,
        block=recorder.grid.block,
        psnr_min_db=round(float(psnrs.min()), 2) if len(psnrs) else None,
        psnr_median_db=round(float(np.median(psnrs)), 2) if len(psnrs) else None,
        damaged_frames=len(damaged),
        copied_frames=int((scores.copy_of >= 0).sum()),
        damaged_frame_indices=tuple(damaged[: params.max_listed_frames]),
        worst_frame_index=worst.index if worst else None,
        worst_psnr_db=round(worst.psnr_db, 2) if worst else None,
        worst_damaged_blocks=worst.damaged_blocks if worst else 0,
        psnr_db_per_frame=tuple(round(float(p), 2) for p in psnrs) if params.per_frame else None,
        damaged_blocks_per_frame=tuple(int(b) for b in scores.damaged_blocks) if params.per_frame else None,
        worst=worst,
    )
