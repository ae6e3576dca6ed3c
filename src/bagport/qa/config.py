"""QA thresholds (``configs/qa.yaml``): every check's warn/fail limits and what a failure does.

The defaults here are the documented defaults; ``configs/qa.yaml`` spells them out with
comments, and a test keeps the two equal.
"""

from __future__ import annotations

from typing import Literal

import pydantic
import yaml
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, PositiveInt

from bagport.errors import ContractError
from bagport.yamlsource import explain_validation, load_yaml

__all__ = ["Gate", "QAConfig", "load_qa_config"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Gate(_Strict):
    """``warn``/``fail`` thresholds of one measured value; ``null`` disables that level.

    ``hard``: a failing hard check excludes the episode (see ``on_fail``); a failing soft
    check only lowers the score and marks the episode ``warn``.
    """

    warn: float | None = None
    fail: float | None = None
    hard: bool = True


def _gate(warn: float | None, fail: float | None, hard: bool = True) -> Gate:
    return Gate(warn=warn, fail=fail, hard=hard)


class CoverageQA(_Strict):
    min_duration_s: Gate = Field(default_factory=lambda: _gate(2.0, 0.2))
    """Lower is worse: warn/fail when the aligned episode is shorter."""
    max_duration_s: Gate = Field(default_factory=lambda: _gate(3600.0, None))


class RatesQA(_Strict):
    """Soft by default: command topics are often event-driven (teleop key presses), so a rate
    estimated from the median period is a hint, not a verdict. Declare ``nominal_hz`` and set
    ``hard: true`` for streams that must be periodic."""

    nominal_hz: dict[str, PositiveFloat] = Field(default_factory=dict)
    """Expected rate per topic; a topic not listed is measured against its median period."""
    rate_ratio: Gate = Field(default_factory=lambda: _gate(0.95, 0.8, hard=False))
    """Lower is worse: messages received / messages expected at the nominal rate."""
    jitter: Gate = Field(default_factory=lambda: _gate(0.3, None, hard=False))
    """Standard deviation of the message periods over the nominal period."""
    gap_periods: Gate = Field(default_factory=lambda: _gate(3.0, 30.0, hard=False))
    """Longest gap between two messages, in nominal periods."""
    dropped_frames: Gate = Field(default_factory=lambda: _gate(1.0, None, hard=False))
    """Per camera: frames missing inside gaps (gap / period - 1, summed)."""


class TimeQA(_Strict):
    out_of_order: Gate = Field(default_factory=lambda: _gate(1.0, None))
    """Header stamps going backwards in log order (count)."""
    duplicate_stamps: Gate = Field(default_factory=lambda: _gate(1.0, None))
    clock_jump_s: PositiveFloat = 1.0
    """A header stamp step this far from the log-time step is a clock jump."""
    clock_jumps: Gate = Field(default_factory=lambda: _gate(None, 1.0))
    delay_p95_ms: Gate = Field(default_factory=lambda: _gate(100.0, 1000.0, hard=False))
    """Receive (log) time minus header stamp, 95th percentile."""
    clock_offset_ms: Gate = Field(default_factory=lambda: _gate(1.0, None))
    """How far header stamps run ahead of receive time (median, another machine's clock)."""
    camera_action_gap_ms: PositiveFloat = 50.0
    camera_action_gap_share: Gate = Field(default_factory=lambda: _gate(0.05, 0.5, hard=False))
    """Share of frames whose camera image and action are further apart than ``camera_action_gap_ms``."""
    alignment_error_p95_ms: Gate = Field(default_factory=lambda: _gate(50.0, None, hard=False))
    """Per source: 95th percentile of ``|tick + offset - source time|`` over frames with a message."""
    filled_frames: Gate = Field(default_factory=lambda: _gate(1.0, None, hard=False))
    """Per source: frames without a valid message under its strategy, filled by ``align.fill``."""
    clock_drift_ms: Gate = Field(default_factory=lambda: _gate(50.0, None, hard=False))
    """With ``clock: <key>``: largest distance of a frame's true time from ``frame_index / fps``."""


class ValuesQA(_Strict):
    non_finite: Gate = Field(default_factory=lambda: _gate(None, 1.0))
    """NaN or inf values in numeric features (count)."""
    limits: dict[str, tuple[float, float]] = Field(default_factory=dict)
    """Per feature key: ``[min, max]`` every dimension must stay in."""
    out_of_limits: Gate = Field(default_factory=lambda: _gate(None, 1.0))
    max_velocity: dict[str, PositiveFloat] = Field(default_factory=dict)
    """Per feature key: the largest plausible change per second (e.g. rad/s for joint positions)."""
    velocity_violations: Gate = Field(default_factory=lambda: _gate(1.0, 10.0))
    frozen_state_s: Gate = Field(default_factory=lambda: _gate(5.0, None))
    """Longest run of identical numeric values (state, action) in seconds."""
    frozen_image_s: Gate = Field(default_factory=lambda: _gate(1.0, 5.0))
    """Longest run of identical camera images in seconds (a stalled driver, or a held dropout)."""
    dark_threshold: float = 8.0
    bright_threshold: float = 247.0
    dark_or_bright_frames: Gate = Field(default_factory=lambda: _gate(1.0, 30.0))
    """Frames whose mean grey level is below ``dark_threshold`` or above ``bright_threshold``."""
    step_quantile: float = Field(default=0.99, gt=0, lt=1)
    """The fleet's own step size per dimension: this quantile of ``|frame-to-frame change|`` over every
    frame of the dataset (merged sketches, see bagport.qa.jumps)."""
    step_outlier: Gate = Field(default_factory=lambda: _gate(5.0, None, hard=False))
    """An episode's largest step in a dimension over the fleet's ``step_quantile`` step (ratio); judged in
    the reduce, once the fleet is known. ``warn: null`` turns it off."""


class SafetyQA(_Strict):
    topic: str | None = None
    """An e-stop / safety topic (``std_msgs/Bool`` or any message with a boolean ``data``)."""
    active: Gate = Field(default_factory=lambda: _gate(None, 1.0))
    """Messages with the safety flag set inside the episode window (count)."""


class ContentQA(_Strict):
    task_missing: Gate = Field(default_factory=lambda: _gate(None, 1.0))
    """1 when no frame has a task prompt."""


class IntegrityQA(_Strict):
    unchecked: Gate = Field(default_factory=lambda: _gate(1.0, None, hard=False))
    """1 when no checksum covers the bag's bytes (MCAP without chunk CRCs, SQLite, ROS 1)."""


class VideoQA(_Strict):
    """Every encoded clip decoded again and compared with the frames fed to the encoder
    (:mod:`bagport.video.fidelity`); errors are measured on ``block_px`` block means."""

    fidelity: bool = True
    """Off: no check, no cost (the video checks are left out)."""
    sample_every: PositiveInt = 4
    """Check every n-th run of ``g`` frames (a GOP; only those are decoded); 1 checks every frame."""
    block_px: PositiveInt = 8
    frame_mismatch: Gate = Field(default_factory=lambda: _gate(None, 1.0))
    """Frames missing or extra in the clip, timestamps off the fps grid, decoding errors (count)."""
    psnr_min_db: Gate = Field(default_factory=lambda: _gate(30.0, 20.0))
    """Lower is worse: the worst checked frame's PSNR against its source (dB, block means)."""
    damaged_frames: Gate = Field(default_factory=lambda: _gate(1.0, None, hard=False))
    """Checked frames with blocks far worse than the rest of the frame (stale or foreign blocks)."""
    copied_frames: Gate = Field(default_factory=lambda: _gate(None, 1.0))
    """Frames that decode as a copy of an earlier frame (they show the wrong moment)."""


class QAConfig(_Strict):
    on_fail: Literal["exclude", "keep", "fail_run"] = "exclude"
    """An episode failing a hard check (or a bag that cannot be converted) is left out of the
    dataset and listed with its reason (``exclude``), kept and flagged (``keep``), or fails the
    whole run before anything is written (``fail_run``)."""
    coverage: CoverageQA = Field(default_factory=CoverageQA)
    rates: RatesQA = Field(default_factory=RatesQA)
    time: TimeQA = Field(default_factory=TimeQA)
    values: ValuesQA = Field(default_factory=ValuesQA)
    safety: SafetyQA = Field(default_factory=SafetyQA)
    content: ContentQA = Field(default_factory=ContentQA)
    integrity: IntegrityQA = Field(default_factory=IntegrityQA)
    video: VideoQA = Field(default_factory=VideoQA)


def load_qa_config(text: str | None, name: str = "qa.yaml") -> QAConfig:
    """Parse QA thresholds; ``None`` gives the defaults."""
    if text is None:
        return QAConfig()
    try:
        source = load_yaml(text, name)
    except yaml.YAMLError as err:
        raise ContractError(f"is not valid YAML: {err}", file=name) from err
    try:
        return QAConfig.model_validate(source.data or {})
    except pydantic.ValidationError as err:
        problem = explain_validation(err, source, QAConfig, "see configs/qa.yaml for every option.")
        raise ContractError(
            problem.what, file=name, line=problem.line, field=problem.field, fix=problem.fix
        ) from err
