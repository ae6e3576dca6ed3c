"""The selection's QA entries hold a digest of each staged record (no plots but the index's, only the checks
that did not pass), and the commit's QA files come out as from the whole records."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from bagport.dataset.qa import write_qa
from bagport.episode import convert_episode
from bagport.qa import CheckResult, EpisodeQA, QAEntry
from bagport.selection import select_episodes
from bagport.staging import QA_FILE, read_summary
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import SMALL_CAMERAS, episode_request


@pytest.fixture(scope="module")
def staged(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A clean episode with two cameras, converted into a staging store."""
    tmp_path = tmp_path_factory.mktemp("selection")
    bag = tmp_path / "clean"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=3.0, cameras=SMALL_CAMERAS, mcap_crcs=True))
    return Path(convert_episode(episode_request(bag, tmp_path / "staging")).dir_uri)


def test_entries_hold_no_thumbnails_and_a_fleet_warning_still_shows_them(
    staged: Path, tmp_path: Path
) -> None:
    summary = read_summary(str(staged))
    assert summary is not None
    _, (entry,) = select_episodes(
        [summary], [], policy="keep", keep_labelled=False, output=str(tmp_path / "out"), appending=False
    )
    record = EpisodeQA.read(str(staged / QA_FILE))
    assert record.verdict == "pass" and record.plots["thumbnails"]  # the staged record has them
    assert set(entry.qa.plots) <= {"window_ns", "fidelity"}  # the entry does not: nothing grows per episode
    assert entry.qa.checks == [] and entry.staged is not None and entry.staged.passed == len(record.checks)

    # a check against the fleet (at the commit) turns it into a warning: its page must show everything
    jump = [
        CheckResult("values.step_outlier", "action", 9.0, "warn", False, "largest step is 9x the fleet's")
    ]
    whole = replace(QAEntry(record, 0, 0), segment=entry.segment, metadata=entry.metadata).with_checks(jump)
    for name, entries in (("digest", [entry.with_checks(jump)]), ("whole", [whole])):
        write_qa(tmp_path / name, entries, {"fps": 30}, {}, 0, robot_type="arm")
    files = sorted(p.relative_to(tmp_path / "whole") for p in (tmp_path / "whole").rglob("*") if p.is_file())
    for rel in files:  # the QA table, index, summary, report and the detail page: the same bytes
        assert (tmp_path / "digest" / rel).read_bytes() == (tmp_path / "whole" / rel).read_bytes(), rel
    page = (tmp_path / "digest/meta/qa/details/run-000/000000.html").read_text()
    assert page.count('class="strip"') == 2 and page.count('<figure class="thumb">') >= 8
    assert "values.step_outlier" in page
