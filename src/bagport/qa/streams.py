"""Timing checks of the recorded streams: coverage, rates, gaps, stamps and clocks.

Inputs are stamp arrays only (pass 1 of a conversion, or ``bagport qa``), so these
checks cost nothing next to decoding.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from bagport.qa.config import QAConfig
from bagport.qa.result import CheckResult, judge

__all__ = ["StreamStamps", "rate_timeline", "stream_checks"]

Int64Array = npt.NDArray[np.int64]
NS_PER_S = 1_000_000_000
_MAX_GAPS_PLOTTED = 5


@dataclass(frozen=True, slots=True)
class StreamStamps:
    """One recorded topic: log (receive) times and header stamps, in log order."""

    topic: str
    log_ns: Int64Array
    header_ns: Int64Array | None
    stamp_used: str
    """``header``, ``publish`` or ``receive``: the clock alignment used for this topic."""
    is_camera: bool = False
    publish_ns: Int64Array | None = None
    """MCAP publish times, when the topic is aligned on them (``stamp: publish``)."""

    def used_ns(self) -> Int64Array:
        if self.stamp_used == "header" and self.header_ns is not None:
            return self.header_ns
        if self.stamp_used == "publish" and self.publish_ns is not None:
            return self.publish_ns
        return self.log_ns


def _in_window(stamps: Int64Array, start_ns: int, end_ns: int) -> Int64Array:
    ordered = np.sort(stamps)
    return ordered[(ordered >= start_ns) & (ordered <= end_ns)]


def rate_timeline(stamps: Int64Array, start_ns: int, end_ns: int, max_bins: int = 600) -> dict[str, Any]:
    """Messages per second in bins over the window (for the report's rate plot)."""
    duration_s = max((end_ns - start_ns) / NS_PER_S, 1e-9)
    bin_s = max(1.0, float(np.ceil(duration_s / max_bins)))
    edges = start_ns + np.arange(0, duration_s + bin_s, bin_s) * NS_PER_S
    counts, _ = np.histogram(stamps, bins=edges.astype(np.int64))
    return {"bin_s": bin_s, "rate_hz": (counts / bin_s).round(3).tolist()}


def _topic_checks(
    stream: StreamStamps, start_ns: int, end_ns: int, config: QAConfig
) -> tuple[list[CheckResult], dict[str, Any]]:
    rates = config.rates
    topic = stream.topic
    stamps = _in_window(stream.used_ns(), start_ns, end_ns)
    checks: list[CheckResult] = []
    plot: dict[str, Any] = {"count": int(stamps.size), **rate_timeline(stamps, start_ns, end_ns)}
    if stamps.size < 2:
        checks.append(
            CheckResult(
                "coverage.topic", topic, float(stamps.size), "fail", True,
                f"{stamps.size} message(s) inside the episode window: the topic is missing or stalled",
            )
        )  # fmt: skip
        return checks, plot
    periods_ns = np.diff(stamps)
    nominal_hz = rates.nominal_hz.get(topic)
    period_ns = NS_PER_S / nominal_hz if nominal_hz else float(np.median(periods_ns))
    period_ns = max(period_ns, 1.0)
    duration_ns = end_ns - start_ns
    expected = duration_ns / period_ns + 1
    ratio = min(stamps.size / expected, 1.0) if expected > 0 else 1.0
    hz = NS_PER_S / period_ns
    checks.append(
        judge("rates.rate_ratio", topic, ratio, rates.rate_ratio,
              f"{stamps.size} messages, {ratio:.1%} of {expected:.0f} expected at {hz:.1f} Hz",
              lower_is_worse=True)
    )  # fmt: skip
    regular = periods_ns[periods_ns < 1.5 * period_ns]  # gaps are reported on their own, not as jitter
    spread_ns = float(np.std(regular)) if regular.size else 0.0
    jitter = spread_ns / period_ns
    checks.append(
        judge("rates.jitter", topic, jitter, rates.jitter,
              f"period std {spread_ns / 1e6:.2f} ms = {jitter:.2f} of the {period_ns / 1e6:.2f} ms period "
              "(gaps excluded)")
    )  # fmt: skip
    worst = int(np.argmax(periods_ns))
    gap_periods = float(periods_ns[worst] / period_ns)
    gap_at_s = (int(stamps[worst]) - start_ns) / NS_PER_S
    checks.append(
        judge("rates.gap_periods", topic, gap_periods, rates.gap_periods,
              f"longest gap {periods_ns[worst] / 1e6:.0f} ms ({gap_periods:.1f} periods) at {gap_at_s:.2f} s")
    )  # fmt: skip
    missing = np.maximum(np.round(periods_ns / period_ns) - 1, 0)
    order = np.argsort(periods_ns)[::-1][:_MAX_GAPS_PLOTTED]
    plot["gaps"] = [
        {"at_s": round((int(stamps[i]) - start_ns) / NS_PER_S, 3), "ms": round(int(periods_ns[i]) / 1e6, 1)}
        for i in order.tolist()
        if missing[i] > 0
    ]
    if stream.is_camera:
        dropped = float(missing.sum())
        checks.append(
            judge("rates.dropped_frames", topic, dropped, rates.dropped_frames,
                  f"{dropped:.0f} frame(s) missing inside gaps")
        )  # fmt: skip
    if stream.header_ns is not None:
        checks.extend(_header_checks(stream, config))
    return checks, plot


def _header_checks(stream: StreamStamps, config: QAConfig) -> list[CheckResult]:
    """Out-of-order, duplicated and jumping header stamps; recorder delay and clock offset."""
    assert stream.header_ns is not None
    time, topic = config.time, stream.topic
    header, log = stream.header_ns, stream.log_ns
    steps = np.diff(header)
    backwards = float((steps < 0).sum())
    duplicates = float((steps == 0).sum())
    jumps = float((np.abs(steps - np.diff(log)) > time.clock_jump_s * NS_PER_S).sum())
    delay_ms = (log - header) / 1e6
    p95 = float(np.percentile(delay_ms, 95))
    ahead_ms = max(0.0, -float(np.median(delay_ms)))
    return [
        judge("time.out_of_order", topic, backwards, time.out_of_order,
              f"{backwards:.0f} header stamp(s) earlier than the message logged before"),
        judge("time.duplicate_stamps", topic, duplicates, time.duplicate_stamps,
              f"{duplicates:.0f} header stamp(s) equal to the previous one"),
        judge("time.clock_jumps", topic, jumps, time.clock_jumps,
              f"{jumps:.0f} header step(s) differ from the log-time step by more than {time.clock_jump_s:g} s"),
        judge("time.delay_p95_ms", topic, p95, time.delay_p95_ms,
              f"receive minus header stamp: p95 {p95:.1f} ms, median {float(np.median(delay_ms)):.1f} ms"),
        judge("time.clock_offset_ms", topic, ahead_ms, time.clock_offset_ms,
              f"header stamps run {ahead_ms:.1f} ms ahead of receive time (median): another machine's clock"
              if ahead_ms > 0 else "header stamps are not ahead of receive time"),
    ]  # fmt: skip


def stream_checks(
    streams: list[StreamStamps], start_ns: int, end_ns: int, config: QAConfig
) -> tuple[list[CheckResult], dict[str, Any]]:
    """Coverage, duration, rate and clock checks of every stream over the episode window."""
    cov = config.coverage
    duration_s = (end_ns - start_ns) / NS_PER_S
    checks = [
        judge("coverage.min_duration_s", "episode", duration_s, cov.min_duration_s,
              f"episode lasts {duration_s:.2f} s", lower_is_worse=True),
        judge("coverage.max_duration_s", "episode", duration_s, cov.max_duration_s,
              f"episode lasts {duration_s:.2f} s"),
    ]  # fmt: skip
    plots: dict[str, Any] = {}
    for stream in streams:
        topic_checks, plot = _topic_checks(stream, start_ns, end_ns, config)
        checks.extend(topic_checks)
        plots[stream.topic] = plot
    return checks, {"streams": plots}
