"""Video fidelity of one episode: a reference recorder per camera while encoding, then QA checks.

The recorders keep block means of the frames given to each encoder in a scratch folder
(never published to staging); after the clips are closed each clip is decoded again and
compared (:mod:`bagport.video.fidelity`). The findings become ``video.*`` QA checks, and the
per-camera numbers (with the worst frame beside its source, when a check did not pass) go
into the episode's QA plots for the HTML report.

Depth cameras (frames given as 12-bit codes, H x W) are encoded losslessly, so their check is
exact (:mod:`bagport.video.depth_fidelity`): every frame is decoded and must give back the
codes it was encoded from; ``video.frame_mismatch`` and ``video.damaged_frames`` apply, PSNR
and copy checks do not.
"""

from __future__ import annotations

import base64
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import simplejpeg
from PIL import Image as PILImage

from bagport.decode import ImageKind
from bagport.qa import CheckResult, judge
from bagport.qa.config import VideoQA
from bagport.video import ClipFidelity, ClipInfo, FidelityParams, FidelityRecorder, compare_clip
from bagport.video.depth_fidelity import DepthFidelityRecorder, compare_depth_clip

__all__ = ["EpisodeFidelity"]

_WORST_IMAGE_WIDTH_PX = 960


class EpisodeFidelity:
    """One episode's recorders (one per camera) and, at the end, its ``video.*`` checks."""

    def __init__(self, config: VideoQA, scratch: Path, gop: int) -> None:
        """``scratch``: the folder of the reference files (``fidelity-<key>.*``); made, and removed by
        :meth:`discard`, when it does not exist (an episode's work folder: only the files go)."""
        self._config = config
        self._scratch = scratch
        self._owns_scratch = False
        """Whether this object made the folder (then it removes it; else only its own files)."""
        self._gop = max(1, gop)
        self._recorders: dict[str, FidelityRecorder] = {}
        self._depth: dict[str, DepthFidelityRecorder] = {}

    def record(
        self,
        key: str,
        rgb: npt.NDArray[np.uint8] | npt.NDArray[np.uint16],
        kind: ImageKind = ImageKind.COLOUR,
    ) -> None:
        """The frame just given to ``key``'s encoder (the same array, in the same order):
        RGB uint8 (H, W, 3), or a depth camera's codes (H, W)."""
        if not self._config.fidelity:
            return
        if kind is ImageKind.DEPTH:
            depth = self._depth.get(key)
            if depth is None:
                depth = self._depth[key] = DepthFidelityRecorder(self._folder() / f"fidelity-{key}.crc32")
            depth.record(rgb.astype(np.uint16, copy=False))
            return
        recorder = self._recorders.get(key)
        if recorder is None:
            recorder = FidelityRecorder(
                self._folder() / f"fidelity-{key}.refs",
                height=rgb.shape[0],
                width=rgb.shape[1],
                block=self._config.block_px,
                sample_every=self._config.sample_every,
                run=self._gop,
            )
            self._recorders[key] = recorder
        recorder.record(rgb.astype(np.uint8, copy=False))

    def _folder(self) -> Path:
        if not self._scratch.is_dir():
            self._scratch.mkdir(parents=True)
            self._owns_scratch = True
        return self._scratch

    def check(self, clips: dict[str, ClipInfo], fps: int) -> tuple[list[CheckResult], dict[str, Any]]:
        """Compare every closed clip with its references; returns the checks and the report data."""
        checks: list[CheckResult] = []
        plots: dict[str, Any] = {}
        for key, depth in self._depth.items():
            found, plots[key] = self._depth_checks(key, compare_depth_clip(clips[key].path, depth, fps=fps))
            checks += found
        for key, recorder in self._recorders.items():
            result = compare_clip(clips[key].path, recorder, fps=fps, params=FidelityParams())
            found, plots[key] = self._colour_checks(key, result)
            checks += found
        self.discard()
        return checks, plots

    def _depth_checks(self, key: str, result: ClipFidelity) -> tuple[list[CheckResult], dict[str, Any]]:
        checks = [
            _frame_check(key, result, self._config),
            _damaged_check(
                key,
                result,
                self._config,
                "depth frame(s) decode with codes other than those encoded (lossless HEVC)",
                f"all {result.sampled_frames} frames checked",
            ),
        ]
        return checks, result.to_dict()

    def _colour_checks(self, key: str, result: ClipFidelity) -> tuple[list[CheckResult], dict[str, Any]]:
        config = self._config
        share = f"{result.sampled_frames} of {result.frames_expected} frames checked"
        psnr = result.psnr_min_db if result.psnr_min_db is not None else 0.0
        where = f" (frame {result.worst_frame_index})" if result.worst_frame_index is not None else ""
        found = [
            _frame_check(key, result, config),
            judge(
                "video.psnr_min_db",
                key,
                psnr,
                config.psnr_min_db,
                f"worst frame {psnr:.1f} dB{where}, median {result.psnr_median_db} dB; {share}",
                lower_is_worse=True,
            ),
            _damaged_check(key, result, config, "frame(s) with stale or foreign blocks", share),
            judge(
                "video.copied_frames",
                key,
                float(result.copied_frames),
                config.copied_frames,
                f"{result.copied_frames} frame(s) decode as a copy of an earlier frame; {share}",
            ),
        ]
        entry = result.to_dict()
        if result.worst is not None and any(c.verdict != "pass" for c in found):
            entry["worst_jpeg_base64"] = _jpeg_base64(result.worst.side_by_side())
        return found, entry

    def discard(self) -> None:
        """Delete the reference files (also after a failed episode)."""
        for recorder in self._recorders.values():
            recorder.discard()
        for depth in self._depth.values():
            depth.discard()
        self._recorders.clear()
        self._depth.clear()
        if self._owns_scratch:
            shutil.rmtree(self._scratch, ignore_errors=True)
            self._owns_scratch = False


def _frame_check(key: str, result: ClipFidelity, config: VideoQA) -> CheckResult:
    """``video.frame_mismatch``: frames missing or extra, timestamps off the grid, decode errors."""
    mismatch = abs(result.frames_expected - result.frames_decoded) + (not result.pts_ok)
    mismatch += result.decode_error is not None
    problems = [
        f"{result.frames_decoded} frames in the clip, {result.frames_expected} encoded"
        if not result.frames_ok
        else "",
        f"timestamp off the grid at frame {result.first_bad_pts_frame}" if not result.pts_ok else "",
        result.decode_error or "",
    ]
    said = "; ".join(p for p in problems if p) or f"{result.frames_decoded} frames, timestamps on the grid"
    return judge("video.frame_mismatch", key, float(mismatch), config.frame_mismatch, said)


def _damaged_check(key: str, result: ClipFidelity, config: VideoQA, what: str, share: str) -> CheckResult:
    """``video.damaged_frames``: how many frames ``what`` (the first ten listed), and how many were checked."""
    listed = ", ".join(str(i) for i in result.damaged_frame_indices[:10])
    said = f"{result.damaged_frames} {what}" + (f" (frames {listed})" if listed else "") + f"; {share}"
    return judge("video.damaged_frames", key, float(result.damaged_frames), config.damaged_frames, said)


def _jpeg_base64(rgb: npt.NDArray[np.uint8]) -> str:
    """The worst-frame panel, at most ``_WORST_IMAGE_WIDTH_PX`` wide, as base64 JPEG for the report."""
    height, width = rgb.shape[:2]
    if width > _WORST_IMAGE_WIDTH_PX:
        size = (_WORST_IMAGE_WIDTH_PX, max(1, round(height * _WORST_IMAGE_WIDTH_PX / width)))
        rgb = np.asarray(PILImage.fromarray(rgb).resize(size, PILImage.Resampling.BILINEAR))
    jpeg = simplejpeg.encode_jpeg(np.ascontiguousarray(rgb), quality=85, colorspace="RGB")
    return base64.b64encode(jpeg).decode("ascii")
