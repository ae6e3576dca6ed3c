"""Which staged episodes go into the dataset: the QA policy, labels and failed bags, as QA entries."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

from pydantic import JsonValue

from bagport.errors import QualityError
from bagport.qa import EpisodeQA, QAEntry
from bagport.request import EpisodeRequest
from bagport.segment import EXCLUDED_LABELS, label_reason
from bagport.staging import QA_FILE, EpisodeSummary

__all__ = ["EpisodeFailure", "select_episodes"]


@dataclass(frozen=True, slots=True)
class EpisodeFailure:
    """A bag whose conversion failed: its request and bagport's one-paragraph error."""

    bag_uri: str
    manifest_entry: int
    error: str
    segment: int | None = None
    label: str | None = None
    note: str = ""
    metadata: dict[str, JsonValue] = field(default_factory=dict)
    retryable: bool = False
    """Not the bag's fault (a transient I/O error after the retries, a crashed task run): a later run
    tries the bag again, where an unchanged bag that failed for itself is not retried."""
    episode_id: str = ""
    """The request's id: the bag's window, the contract, the encoder and the message definitions it was
    converted with (a failure is settled for these only)."""

    @classmethod
    def of(cls, request: EpisodeRequest, error: str, *, retryable: bool = False) -> EpisodeFailure:
        return cls(
            request.bag_uri,
            request.manifest_entry,
            error,
            request.segment,
            request.label,
            request.note,
            dict(request.metadata),
            retryable,
            request.episode_id,
        )


@dataclass(frozen=True, slots=True)
class _Episode:
    segment: int | None
    label: str | None
    note: str
    metadata: dict[str, JsonValue]


def _read_qa(summary: EpisodeSummary) -> QAEntry:
    """The staged episode's QA entry, holding the digest of its record (:meth:`QAEntry.of_staged`)."""
    uri = summary.file(QA_FILE)
    return QAEntry.of_staged(EpisodeQA.read(uri), uri, summary.manifest_entry)


def select_episodes(
    summaries: Sequence[EpisodeSummary],
    failures: Sequence[EpisodeFailure],
    *,
    policy: str,
    keep_labelled: bool,
    output: str,
    appending: bool,
) -> tuple[list[EpisodeSummary], list[QAEntry]]:
    """Apply the QA policy (``on_fail``): which staged episodes go into the dataset at ``output``, and
    every bag's QA entry.

    ``exclude`` leaves out failing episodes and failed bags (listed with the reason), ``keep``
    keeps failing episodes (flagged in ``meta/qa``), ``fail_run`` stops before anything is written.
    ``keep_labelled`` keeps episodes labelled failed or discarded; ``appending`` (to an existing
    dataset) allows keeping nothing, so the exclusions are still recorded.
    """
    rows = _rows(summaries, failures)
    by_label = [not keep_labelled and row[3].label in EXCLUDED_LABELS for row in rows]
    failing = [
        (entry, base.qa)
        for (entry, base, summary, _), labelled in zip(rows, by_label, strict=True)
        if base.qa.verdict == "fail" and summary is not None and not labelled
    ]
    failed = [
        f for f in failures if keep_labelled or f.label not in EXCLUDED_LABELS
    ]  # a failed demonstration that could not be converted either is left out by its label
    if policy == "fail_run" and (failing or failed):
        raise _fail_run_error(failing, failed, len(rows), output)
    kept: list[EpisodeSummary] = []
    entries: list[QAEntry] = []
    for (_, base, summary, episode), labelled in zip(rows, by_label, strict=True):
        qa = base.qa
        if labelled:
            row = replace(base, excluded_reason=label_reason(episode.label, episode.note), by_label=True)
        elif summary is None:
            row = replace(base, excluded_reason=f"conversion failed: {qa.error}")
        elif qa.verdict == "fail" and policy == "exclude":
            row = replace(base, excluded_reason=f"excluded by QA: {qa.headline()}")
        else:
            row = replace(base, episode_index=len(kept))
            kept.append(summary)
        entries.append(
            replace(
                row,
                segment=episode.segment,
                label=episode.label,
                note=episode.note,
                metadata=episode.metadata,
            )
        )
    if not kept and not appending:
        # (an append still records the exclusions, so an unchanged bad bag is not retried by every run)
        raise _nothing_kept_error(entries)
    return kept, entries


_Row = tuple[int, QAEntry, EpisodeSummary | None, _Episode]
"""A bag's (or segment's) manifest entry, QA entry, staged summary (``None``: not converted), labels."""


def _rows(summaries: Sequence[EpisodeSummary], failures: Sequence[EpisodeFailure]) -> list[_Row]:
    """Every staged episode and failed bag, in manifest order (then bag, then segment)."""
    rows: list[_Row] = [
        (s.manifest_entry, _read_qa(s), s, _Episode(s.segment, s.label, s.note, s.metadata))
        for s in summaries
    ]
    rows += [
        (
            f.manifest_entry,
            QAEntry(EpisodeQA.failed(f.bag_uri, f.error), f.manifest_entry, None),
            None,
            _Episode(f.segment, f.label, f.note, f.metadata),
        )
        for f in failures
    ]
    rows.sort(key=lambda row: (row[0], row[1].qa.bag_uri, -1 if row[3].segment is None else row[3].segment))
    return rows


def _fail_run_error(
    failing: Sequence[tuple[int, EpisodeQA]], failed: Sequence[EpisodeFailure], bags: int, output: str
) -> QualityError:
    """``on_fail: fail_run`` with episodes failing QA (``failing``: manifest entry, QA) or not converted."""
    lines = [f"- bags[{entry}] {qa.bag_uri}: {qa.headline()}" for entry, qa in failing]
    lines += [f"- bags[{f.manifest_entry}] {f.bag_uri}: {f.error}" for f in failed]
    return QualityError(
        f"{len(lines)} of {bags} bag(s) {QualityError.MARKER} and on_fail is 'fail_run'; nothing was "
        f"written at {output}.\n" + "\n".join(lines),
    )


def _nothing_kept_error(entries: Sequence[QAEntry]) -> QualityError:
    """Every bag was left out (a new dataset would be empty): each one's reason, and what to change for the
    reasons there are (a conversion error is fixed at its cause: no QA setting keeps a bag that failed)."""
    reasons = "\n".join(f"- bags[{e.manifest_entry}] {e.qa.bag_uri}: {e.excluded_reason}" for e in entries)
    fixes = []
    if any(e.qa.error is not None and not e.by_label for e in entries):
        fixes.append("correct what each conversion error above names (each ends with its own fix)")
    if any(e.qa.error is None and not e.by_label for e in entries):
        fixes.append(
            "relax the QA thresholds of your --qa file (bagport's defaults: configs/qa.yaml) or pass --on-qa-fail "
            "keep to keep failing episodes"
        )
    if any(e.by_label for e in entries):
        fixes.append("pass --keep-failed to keep episodes labelled failed or discarded")
    return QualityError(
        f"no episode is left to write: all {len(entries)} bag(s) {QualityError.MARKER}.\n{reasons}\n"
        f"Fix: {'; '.join(fixes)}."
    )
