"""Fidelity of a depth clip: lossless HEVC must give back exactly the 12-bit codes it was fed.

The colour check (:mod:`bagport.video.fidelity`) measures lossy error on block means; a depth
clip is lossless, so its check is exact instead: while encoding, the CRC-32 of each frame's
codes is appended to a scratch file (4 bytes a frame, nothing kept in memory); afterwards every
frame of the clip is decoded (``gray12le``) and its CRC compared. A frame whose codes differ is
reported as damaged. Frame count and timestamps are checked as for colour clips. The result
is a :class:`~bagport.video.fidelity.ClipFidelity` with every frame checked and no PSNR.
"""

from __future__ import annotations

import zlib
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO

import av
import numpy as np
import numpy.typing as npt

from bagport.errors import VideoError
from bagport.video.depth import DEPTH_PIX_FMT
from bagport.video.fidelity import ClipFidelity

__all__ = ["DepthFidelityRecorder", "compare_depth_clip"]

_MAX_LISTED = 50


class DepthFidelityRecorder:
    """CRC-32 of the codes of every frame given to a depth encoder, in order."""

    def __init__(self, path_for_refs: str | Path) -> None:
        self.path = Path(path_for_refs)
        self.frames_recorded = 0
        try:
            self._file: BinaryIO | None = self.path.open("wb")
        except OSError as err:
            raise VideoError(f"{self.path}: cannot create the fidelity reference file ({err})") from err

    def record(self, codes: npt.NDArray[np.uint16]) -> None:
        if self._file is None:
            raise VideoError(f"{self.path}: record() after close(); use one recorder per clip")
        crc = zlib.crc32(np.ascontiguousarray(codes, dtype=np.uint16).tobytes())
        np.array([crc], dtype=np.uint32).tofile(self._file)
        self.frames_recorded += 1

    def references(self) -> npt.NDArray[np.uint32]:
        self.close()
        return np.fromfile(self.path, dtype=np.uint32)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def discard(self) -> None:
        self.close()
        self.path.unlink(missing_ok=True)


def compare_depth_clip(mp4_path: str | Path, recorder: DepthFidelityRecorder, *, fps: int) -> ClipFidelity:
    """Decode every frame of a depth clip and compare its codes with what was encoded."""
    refs = recorder.references()
    damaged: list[int] = []
    first_bad_pts: int | None = None
    decode_error: str | None = None
    decoded = 0
    try:
        container: Any = av.open(str(mp4_path))
    except av.error.FFmpegError as err:
        raise VideoError(f"{mp4_path}: cannot open the depth clip to check it ({err})") from err
    try:
        stream = container.streams.video[0]
        time_base = Fraction(stream.time_base)
        for frame in container.decode(stream):
            if first_bad_pts is None and (
                frame.pts is None or frame.pts * time_base != Fraction(decoded, fps)
            ):
                first_bad_pts = decoded
            codes = frame.to_ndarray(format=DEPTH_PIX_FMT)
            if decoded >= refs.size or zlib.crc32(np.ascontiguousarray(codes).tobytes()) != int(
                refs[decoded]
            ):
                damaged.append(decoded)
            decoded += 1
    except av.error.FFmpegError as err:
        decode_error = f"decoding stopped: {err}"
    finally:
        container.close()
    return ClipFidelity(
        frames_expected=recorder.frames_recorded,
        frames_decoded=decoded,
        pts_ok=first_bad_pts is None,
        first_bad_pts_frame=first_bad_pts,
        decode_error=decode_error,
        sampled_frames=min(decoded, recorder.frames_recorded),
        sample_every=1,
        sample_run=1,
        block=1,
        psnr_min_db=None,
        psnr_median_db=None,
        damaged_frames=len(damaged),
        copied_frames=0,
        damaged_frame_indices=tuple(damaged[:_MAX_LISTED]),
        worst_frame_index=damaged[0] if damaged else None,
        worst_psnr_db=None,
        worst_damaged_blocks=0,
    )
