"""The reduce holds every kept staged summary from the selection to the commit: small, and whole again where
the run record needs it."""

from __future__ import annotations

from pathlib import Path

from bagport.dataset.provenance import episode_provenance
from bagport.episode.staged import PlannedEpisode
from bagport.reduce import read_staged
from tests.helpers import staged_episodes


def test_held_summaries_are_lean_and_the_run_record_gets_them_whole(tmp_path: Path) -> None:
    full = staged_episodes(tmp_path, (1.0, 1.0))
    planned = [PlannedEpisode(s.dir_uri, s.bag_uri, 5 + n, {"robot_id": f"r{n}"}) for n, s in enumerate(full)]
    held, stamped = read_staged(planned)
    assert [s.source_stamp for s in full] == [p.source_stamp for p in stamped]
    assert all(s.alignment and s.qa for s in full)  # what the worker staged
    assert all(not s.alignment and not s.qa for s in held)  # what the reduce holds
    assert held[0].features is held[1].features  # one copy of the fleet's features
    assert [s.manifest_entry for s in held] == [5, 6] and held[1].metadata == {"robot_id": "r1"}
    for n, (lean, whole) in enumerate(
        zip(held, (p.apply(s) for p, s in zip(planned, full, strict=True)), strict=True)
    ):
        assert episode_provenance(lean, n) == episode_provenance(whole, n)  # the run record's entry
