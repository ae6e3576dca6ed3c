"""QA results: one record per check, and the episode's score and verdict."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, Literal

import fsspec
from pydantic import JsonValue

from bagport.errors import DatasetWriteError
from bagport.qa.config import Gate

__all__ = [
    "SCORE_BANDS",
    "CheckResult",
    "EpisodeQA",
    "QABrief",
    "QAEntry",
    "StagedQA",
    "Verdict",
    "episode_name",
    "episode_ref",
    "judge",
    "score_checks",
]

Verdict = Literal["pass", "warn", "fail"]


@dataclass(frozen=True, slots=True)
class CheckResult:
    check: str
    """``group.name``, e.g. ``rates.gap_periods``."""
    subject: str
    """What was measured: a topic, a feature key, or ``episode``."""
    value: float
    verdict: Verdict
    hard: bool
    reason: str
    """One line a data supervisor can act on."""


def judge(
    check: str, subject: str, value: float, gate: Gate, describe: str, *, lower_is_worse: bool = False
) -> CheckResult:
    """Compare ``value`` with the gate; ``describe`` is the measurement in words (with units)."""

    def crosses(limit: float | None) -> bool:
        if limit is None:
            return False
        return value <= limit if lower_is_worse else value >= limit

    if crosses(gate.fail):
        verdict: Verdict = "fail" if gate.hard else "warn"
        limit, which = (
            gate.fail,
            "fail limit {:g}" if gate.hard else "fail limit {:g}; a soft check, so it warns",
        )
    elif crosses(gate.warn):
        verdict, limit, which = "warn", gate.warn, "warn limit {:g}"
    else:
        verdict, limit, which = "pass", None, ""
    side = "at or below" if lower_is_worse else "at or above"
    bound = "" if limit is None else f" ({side} {which.format(limit)})"
    return CheckResult(check, subject, float(value), verdict, gate.hard, describe + bound)


SCORE_BANDS: dict[Verdict, tuple[float, float]] = {"fail": (0.0, 0.4), "warn": (0.5, 0.9), "pass": (1.0, 1.0)}
"""Score range per verdict: any hard failure scores below any warning, any warning below any pass."""


def score_checks(checks: list[CheckResult], passed_elsewhere: int = 0) -> tuple[float, Verdict]:
    """The verdict (the worst check) and a score in [0, 1] that orders by severity first: inside the
    verdict's band (:data:`SCORE_BANDS`) it rises with the share of checks that passed, so a hard
    failure is always below 0.4, a warning in [0.5, 0.9), a clean episode 1. ``passed_elsewhere``: more
    checks that passed, not in ``checks`` (an :meth:`EpisodeQA.digest`'s)."""
    if not checks:
        return 1.0, "pass"
    verdicts = {c.verdict for c in checks}
    verdict: Verdict = "fail" if "fail" in verdicts else "warn" if "warn" in verdicts else "pass"
    low, high = SCORE_BANDS[verdict]
    passed = (sum(c.verdict == "pass" for c in checks) + passed_elsewhere) / (len(checks) + passed_elsewhere)
    return round(low + (high - low) * passed, 4), verdict


@dataclass(frozen=True, slots=True)
class EpisodeQA:
    """Everything QA knows about one episode; ``plots`` holds small series for the HTML report."""

    bag_uri: str
    score: float
    verdict: Verdict
    checks: list[CheckResult]
    duration_s: float = 0.0
    frames: int = 0
    plots: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    """Set when the bag could not be converted at all (the error message)."""

    @classmethod
    def build(
        cls, bag_uri: str, checks: list[CheckResult], *, duration_s: float, frames: int, plots: dict[str, Any]
    ) -> EpisodeQA:
        score, verdict = score_checks(checks)
        return cls(bag_uri, score, verdict, checks, duration_s, frames, plots)

    @classmethod
    def failed(cls, bag_uri: str, error: str) -> EpisodeQA:
        check = CheckResult("coverage.convertible", "episode", 1.0, "fail", True, error)
        return cls(bag_uri, 0.0, "fail", [check], error=error)

    def with_checks(self, extra: list[CheckResult], passed_elsewhere: int = 0) -> EpisodeQA:
        """This record with ``extra`` checks added (judged later, e.g. against the fleet), rescored
        (``passed_elsewhere``: a digest's passing checks left out, :func:`score_checks`)."""
        checks = [*self.checks, *extra]
        score, verdict = score_checks(checks, passed_elsewhere)
        return replace(self, checks=checks, score=score, verdict=verdict)

    def digest(self) -> EpisodeQA:
        """This record without what only its detail page shows: the checks that did not pass, and of the
        plots the episode's window (``window_ns``, the index's day) and each clip's fidelity minima (the
        brief); score and verdict as they are. A fleet's entries hold this (:meth:`QAEntry.of_staged`)."""
        plots: dict[str, Any] = {k: self.plots[k] for k in ("window_ns",) if k in self.plots}
        if "fidelity" in self.plots:
            plots["fidelity"] = {
                key: {k: clip[k] for k in ("psnr_min_db", "damaged_frames") if k in clip}
                for key, clip in self.plots["fidelity"].items()
            }
        return replace(self, checks=self.problems, plots=plots)

    @property
    def problems(self) -> list[CheckResult]:
        return [c for c in self.checks if c.verdict != "pass"]

    @property
    def failed_hard(self) -> list[CheckResult]:
        return [c for c in self.checks if c.verdict == "fail"]

    def headline(self) -> str:
        """``fail: rates.gap_periods /front (...); values.non_finite ...`` or ``pass``."""
        problems = self.failed_hard or self.problems
        if not problems:
            return self.verdict
        return f"{self.verdict}: " + "; ".join(f"{c.check} {c.subject}: {c.reason}" for c in problems[:3])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, as ``asdict`` gives it, but ``plots`` (JSON values already: traces, thumbnails) is
        not copied value by value (``asdict`` walked its ~2,000 values per small episode, 2 ms)."""
        return {f.name: getattr(self, f.name) for f in fields(self)} | {
            "checks": [asdict(c) for c in self.checks]
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EpisodeQA:
        checks = [CheckResult(**c) for c in data["checks"]]
        return cls(**{**data, "checks": checks})

    @classmethod
    def read(cls, uri: str) -> EpisodeQA:
        """A staged episode's record (its ``qa.json``, written by the worker)."""
        try:
            with fsspec.open(uri, "r", encoding="utf-8") as handle:
                return cls.from_dict(json.load(handle))
        except FileNotFoundError as err:
            raise DatasetWriteError(
                f"the staged QA record {uri} is missing (staged by an older bagport, or removed since); nothing "
                "was written. Fix: re-run the conversion (it stages the episode again)."
            ) from err


def episode_ref(bag_uri: str, segment: int | None) -> str:
    """A bag (URI or name), with ``#<segment>`` for one episode of several in a bag."""
    return bag_uri if segment is None else f"{bag_uri}#{segment}"


def episode_name(bag_uri: str, segment: int | None) -> str:
    """The bag's file name, with ``#<segment>`` for one episode of several in a bag."""
    return episode_ref(bag_uri.rstrip("/").rsplit("/", 1)[-1], segment)


@dataclass(frozen=True, slots=True)
class StagedQA:
    """Where a digest entry's whole QA record is (:meth:`QAEntry.of_staged`)."""

    uri: str
    """The staged ``qa.json``."""
    passed: int
    """Its checks that passed (left out of the digest)."""
    problems: int
    """How many of the digest's checks are the record's (those after them were added later)."""


@dataclass(frozen=True, slots=True)
class QAEntry:
    """One bag of the run: its QA, and where it ended up."""

    qa: EpisodeQA
    manifest_entry: int
    episode_index: int | None
    """Index in the dataset; ``None`` when the episode was excluded or failed to convert."""
    excluded_reason: str | None = None
    segment: int | None = None
    """Index of the episode among those of its bag (``None``: the whole bag)."""
    label: str | None = None
    """The episode's label from episode events (``success``, ``failed``, ``discarded``)."""
    note: str = ""
    by_label: bool = False
    """Left out because of its label (failed / discarded), not by QA."""
    metadata: dict[str, JsonValue] = field(default_factory=dict)
    """The episode's metadata: its manifest entry's columns (``robot_id``...) and the recorder's
    ``episode_id`` from episode events."""
    staged: StagedQA | None = None
    """Set when :attr:`qa` is a digest (:meth:`EpisodeQA.digest`) of the staged record; :meth:`whole`
    reads the rest back. ``None``: :attr:`qa` is whole."""

    @classmethod
    def of_staged(cls, qa: EpisodeQA, uri: str, manifest_entry: int) -> QAEntry:
        """The entry of a staged episode whose record ``qa`` was read from ``uri``, holding its digest: a
        fleet's entries stay small from the selection to the commit, which reads each record back once."""
        digest = qa.digest()
        staged = StagedQA(uri, len(qa.checks) - len(digest.checks), len(digest.checks))
        return cls(digest, manifest_entry, None, staged=staged)

    def with_checks(self, extra: list[CheckResult]) -> QAEntry:
        """This entry with ``extra`` checks added to its record (:meth:`EpisodeQA.with_checks`), rescored."""
        passed = 0 if self.staged is None else self.staged.passed
        return replace(self, qa=self.qa.with_checks(extra, passed))

    def whole(self) -> QAEntry:
        """This entry with its whole record (every check, every plot): the staged record read back, with
        the checks added since; itself when it holds its record whole."""
        if self.staged is None:
            return self
        added = self.qa.checks[self.staged.problems :]
        qa = EpisodeQA.read(self.staged.uri).with_checks(added) if added else EpisodeQA.read(self.staged.uri)
        return replace(self, qa=qa, staged=None)

    @property
    def name(self) -> str:
        """The bag's file name, with ``#<segment>`` for one of several episodes in a bag."""
        return episode_name(self.qa.bag_uri, self.segment)

    @property
    def reason(self) -> str:
        """Why it was left out, or the QA headline."""
        return self.excluded_reason or self.qa.headline()

    def brief(self) -> QABrief:
        clips = self.qa.plots.get("fidelity", {}).values()
        psnrs = [c["psnr_min_db"] for c in clips if c.get("psnr_min_db") is not None]
        return QABrief(
            bag_uri=self.qa.bag_uri,
            manifest_entry=self.manifest_entry,
            episode_index=self.episode_index,
            score=self.qa.score,
            verdict=self.qa.verdict,
            excluded=self.episode_index is None,
            reason=self.reason,
            duration_s=round(self.qa.duration_s, 3),
            frames=self.qa.frames,
            video_psnr_min_db=min(psnrs) if psnrs else None,
            video_damaged_frames=sum(int(c.get("damaged_frames", 0)) for c in clips) if clips else None,
            segment=self.segment,
            label=self.label,
            note=self.note,
            excluded_by_label=self.by_label,
            metadata=self.metadata,
        )


@dataclass(frozen=True, slots=True)
class QABrief:
    """One episode's QA in one row: where it went, its score and verdict, video fidelity, and why. What a
    run reports (:class:`bagport.dataset.DatasetReport`), small and typed; :meth:`to_json` is its JSON
    form (the run summary, the run record, the QA index)."""

    bag_uri: str
    manifest_entry: int
    episode_index: int | None
    """Index in the dataset; ``None`` when the episode was excluded or failed to convert."""
    score: float
    verdict: Verdict
    excluded: bool
    reason: str
    duration_s: float
    frames: int
    video_psnr_min_db: float | None
    video_damaged_frames: int | None
    segment: int | None
    label: str | None
    note: str
    excluded_by_label: bool
    metadata: dict[str, JsonValue]
    """The manifest entry's columns and the recorder's ``episode_id`` (user data, as in the manifest)."""
    source_stamp: str | None = None
    """The bag's :func:`bagport.bags.source_stamp` when it was left out (kept in the run record, so an
    unchanged bad bag is not retried); ``None``: not recorded (and absent from the JSON)."""

    @property
    def name(self) -> str:
        """The bag's file name, with ``#<segment>`` for one of several episodes in a bag."""
        return episode_name(self.bag_uri, self.segment)

    def to_json(self) -> dict[str, Any]:
        row = asdict(self)
        if self.source_stamp is None:
            del row["source_stamp"]
        return row
