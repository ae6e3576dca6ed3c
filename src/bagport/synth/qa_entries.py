"""Synthetic QA records of a fleet (no bag behind them), for the report's size benchmark and tests."""

from __future__ import annotations

import numpy as np

from bagport.qa.result import CheckResult, EpisodeQA, QAEntry, Verdict

__all__ = ["CHECK_NAMES", "synth_qa_entries"]

CHECK_NAMES = (
    "coverage.topics", "coverage.min_duration_s", "rates.rate_ratio", "rates.jitter", "rates.gap_periods",
    "rates.dropped_frames", "time.out_of_order", "time.duplicate_stamps", "time.delay_p95_ms",
    "time.clock_offset_ms", "time.camera_action_gap_share", "time.alignment_error_p95_ms", "values.non_finite",
    "values.frozen_state_s", "values.frozen_image_s", "values.dark_or_bright_frames", "values.step_outlier",
    "content.task_missing", "video.psnr_min_db", "video.damaged_frames",
)  # fmt: skip
_DAY_NS = 86_400 * 10**9


def synth_qa_entries(
    count: int,
    *,
    seed: int = 0,
    robots: int = 6,
    days: int = 30,
    warn_share: float = 0.12,
    fail_share: float = 0.03,
) -> list[QAEntry]:
    """``count`` episodes of a fleet of ``robots`` over ``days`` days, with 40 checks each: by default about
    85% pass, 12% warn and 3% fail (a hard failure, excluded); bags under ``s3://fleet/<robot>/<day>/``."""
    rng = np.random.default_rng(seed)
    entries = []
    kept = 0
    for n in range(count):
        robot, day = int(rng.integers(robots)), int(rng.integers(days))
        start_ns = 1_760_000_000 * 10**9 + day * _DAY_NS + int(rng.integers(_DAY_NS))
        roll = rng.random()
        bad: Verdict = "fail" if roll < fail_share else "warn" if roll < fail_share + warn_share else "pass"
        picked = set(rng.choice(len(CHECK_NAMES), size=int(rng.integers(1, 3)), replace=False).tolist())
        checks = []
        for i in range(40):
            name = CHECK_NAMES[i % len(CHECK_NAMES)]
            verdict: Verdict = bad if i % len(CHECK_NAMES) in picked and i < len(CHECK_NAMES) else "pass"
            reason = f"{name} measured {rng.random():.3f} on /robot_{robot}/topic_{i}"
            checks.append(
                CheckResult(name, f"/topic_{i}", float(rng.random()), verdict, verdict == "fail", reason)
            )
        frames = int(rng.integers(150, 3000))
        qa = EpisodeQA.build(
            f"s3://fleet/robot-{robot:02d}/day-{day:02d}/bag-{n:06d}.mcap", checks, duration_s=frames / 30,
            frames=frames, plots={"window_ns": [start_ns, start_ns + frames * 33_333_333]},
        )  # fmt: skip
        index = None if qa.verdict == "fail" else kept
        kept += index is not None
        entries.append(QAEntry(qa, n, index, f"excluded by QA: {qa.headline()}" if index is None else None))
    return entries
