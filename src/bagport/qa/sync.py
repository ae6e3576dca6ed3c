"""Checks of the aligned frames: how far each value is from its tick, and camera-to-action gaps."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.qa.config import TimeQA
from bagport.qa.result import CheckResult, judge

__all__ = ["AlignedStamps", "alignment_checks", "sync_checks"]

Int64Array = npt.NDArray[np.int64]
_HISTOGRAM_BINS = 20


@dataclass(frozen=True, slots=True)
class AlignedStamps:
    """The source time (in the clock used for alignment) behind each frame of one feature source."""

    key: str
    topic: str
    used_ns: Int64Array
    valid: npt.NDArray[np.bool_]
    """False where the frame has no message of this source (filled)."""
    is_camera: bool


def _histogram(error_ms: npt.NDArray[np.float64]) -> dict[str, Any]:
    if error_ms.size == 0:
        return {"edges_ms": [], "counts": []}
    top = max(float(error_ms.max()), 1e-3)
    counts, edges = np.histogram(error_ms, bins=_HISTOGRAM_BINS, range=(0.0, top))
    return {"edges_ms": edges.round(3).tolist(), "counts": counts.tolist()}


def sync_checks(
    sources: list[AlignedStamps], ticks_ns: Int64Array, config: TimeQA
) -> tuple[list[CheckResult], dict[str, Any]]:
    """Camera-to-action gap per camera (vs the first action source), and alignment error histograms."""
    plots = {f"{s.key}@{s.topic}": _histogram(np.abs(ticks_ns - s.used_ns)[s.valid] / 1e6) for s in sources}
    steps_ns = np.diff(ticks_ns)
    backwards = int((steps_ns <= 0).sum())
    checks = [
        CheckResult(
            "time.output_monotonic", "episode", float(backwards), "fail" if backwards else "pass", True,
            f"{backwards} frame timestamp(s) not after the previous one" if backwards
            else f"{ticks_ns.size} frame timestamps strictly increasing",
        )
    ]  # fmt: skip
    action = next((s for s in sources if s.key == "action" or s.key.startswith("action.")), None)
    if action is not None:
        limit_ms = config.camera_action_gap_ms
        for camera in (s for s in sources if s.is_camera):
            both = camera.valid & action.valid
            gap_ms = np.abs(camera.used_ns - action.used_ns)[both] / 1e6
            share = float((gap_ms > limit_ms).mean()) if gap_ms.size else 0.0
            worst = float(gap_ms.max()) if gap_ms.size else 0.0
            checks.append(
                judge("time.camera_action_gap_share", camera.key, share, config.camera_action_gap_share,
                      f"{share:.1%} of frames have the {camera.key} image more than {limit_ms:g} ms from the "
                      f"{action.key} command (worst {worst:.0f} ms)")
            )  # fmt: skip
    return checks, {"alignment_error_ms": plots}


def alignment_checks(report: Sequence[dict[str, Any]], config: TimeQA) -> list[CheckResult]:
    """Per source of the alignment report: error p95 and filled frames; the clock stream's drift."""
    checks = []
    for entry in report:
        subject = f"{entry['key']}@{entry['topic']}"
        error = entry["error_ms"]
        if error["p95"] is not None:
            checks.append(
                judge("time.alignment_error_p95_ms", subject, error["p95"], config.alignment_error_p95_ms,
                      f"|tick - {entry['stamp']} stamp| median {error['median']:.1f} ms, p95 {error['p95']:.1f} ms, "
                      f"max {error['max']:.1f} ms under '{entry['strategy']}'; {entry['held_frames']} held, "
                      f"{entry['interpolated_frames']} interpolated frame(s)")
            )  # fmt: skip
        filled = entry["filled_frames"]
        checks.append(
            judge("time.filled_frames", subject, filled, config.filled_frames,
                  f"{filled} frame(s) without a message under '{entry['strategy']}', filled by "
                  f"'{entry['fill']}'; {entry['dropped_frames']} frame(s) of the episode dropped")
        )  # fmt: skip
        clock = entry.get("clock")
        if clock is not None:
            drift = clock["drift_ms"]
            checks.append(
                judge("time.clock_drift_ms", subject, drift["max"], config.clock_drift_ms,
                      f"frames follow {clock['key']} ({clock['rate_hz']:.2f} Hz): their true time is off "
                      f"frame_index / fps by median {drift['median']:.1f} ms, max {drift['max']:.1f} ms")
            )  # fmt: skip
    return checks
