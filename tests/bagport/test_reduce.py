"""The reduce holds every kept staged summary from the selection to the commit: small, and whole again where
the run record needs it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import bagport.reduce
from bagport.config import ConvertConfig
from bagport.dataset import DatasetReport
from bagport.dataset.provenance import episode_provenance
from bagport.dataset.repair import repair_dataset
from bagport.episode.staged import PlannedEpisode
from bagport.errors import DatasetWriteError
from bagport.formats import write_formats
from bagport.reduce import read_staged, reduce_run
from bagport.run import RunPlan, plan_run, stage_all
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT, SMALL_CAMERAS, convert_in_process, staged_episodes


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


def test_the_output_stays_held_while_the_other_formats_are_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``reduce_run`` writes the other formats from the staged episodes after the LeRobot commit, with the
    output still held: an append started meanwhile refuses (its recovery finds the write live) instead of
    taking those staged episodes for a killed run's leftovers and removing them."""
    bag = tmp_path / "ep0"
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=1.0, cameras=SMALL_CAMERAS))
    out = tmp_path / "dataset"
    refusals: list[str] = []

    def write_formats_checked(*args: Any, **kwargs: Any) -> dict[str, DatasetReport]:
        with pytest.raises(DatasetWriteError, match="another bagport run is writing") as refused:
            repair_dataset(str(out))
        refusals.append(str(refused.value))
        assert len(list((tmp_path / "staging").iterdir())) == 1  # what the formats read is there
        return write_formats(*args, **kwargs)

    monkeypatch.setattr(bagport.reduce, "write_formats", write_formats_checked)
    convert_in_process(str(bag), SAMPLE_CONTRACT.read_text(), tmp_path, formats=("lerobot", "hdf5"))
    assert len(refusals) == 1
    assert repair_dataset(str(out)).actions == ()
    assert (tmp_path / "dataset.hdf5").exists() and not (tmp_path / "staging").exists()


def test_a_run_sharing_its_staging_store_never_removes_an_episode_another_run_stages_meanwhile(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The staging store goes when a run leaves it empty; another run's episode published into it at that
    moment (the store shared, --staging) stays whole: only empty folders are removed, one rmdir each, where
    checking the store was empty and then removing it whole deleted what arrived in between."""
    for name in ("a", "b"):
        write_episode_bag(
            tmp_path / "bags" / name, "mcap", EpisodeSpec(duration_s=0.5, cameras=SMALL_CAMERAS)
        )
    contract = tmp_path / "contract.yaml"
    contract.write_text(SAMPLE_CONTRACT.read_text())

    def plan(name: str) -> RunPlan:
        config = ConvertConfig(
            bags_glob=str(tmp_path / "bags" / name), contract=str(contract), output=str(tmp_path / f"out-{name}"),
            staging=str(tmp_path / "staging"), encoder=FAST_CODEC,
        )  # fmt: skip
        return plan_run(config)

    other = plan("b")
    (request,) = other.requests
    early = stage_all(other)  # run b's episode, staged, then moved aside to arrive at the worst moment
    staged_b = Path(early[0].dir_uri)
    aside = tmp_path / "aside"
    staged_b.rename(aside)
    real_rmdir = Path.rmdir

    def arrives_before_the_first_rmdir(folder: Path) -> None:
        if aside.exists():
            aside.rename(staged_b)
        real_rmdir(folder)

    monkeypatch.setattr(Path, "rmdir", arrives_before_the_first_rmdir)
    run_a = plan("a")
    reduce_run(run_a, stage_all(run_a))
    monkeypatch.setattr(Path, "rmdir", real_rmdir)
    assert not aside.exists() and (staged_b / "episode.json").is_file()
    assert reduce_run(other, early).episodes == 1  # run b writes its episode from the staging store
    assert request.bag_uri.endswith("/b") and not (tmp_path / "staging").exists()


def test_a_staging_store_with_folders_of_its_own_is_removed_when_emptied(tmp_path: Path) -> None:
    """Not local and not an object store (fsspec's memory store, like sftp): its empty folders are removed
    as before, the store with them."""
    import fsspec  # noqa: PLC0415

    write_episode_bag(tmp_path / "bags" / "a", "mcap", EpisodeSpec(duration_s=0.5, cameras=SMALL_CAMERAS))
    contract = tmp_path / "contract.yaml"
    contract.write_text(SAMPLE_CONTRACT.read_text())
    config = ConvertConfig(
        bags_glob=str(tmp_path / "bags" / "*"), contract=str(contract), output=str(tmp_path / "out"),
        staging="memory://bagport-test-staging", encoder=FAST_CODEC,
    )  # fmt: skip
    plan = plan_run(config)
    staged = stage_all(plan)
    memory = fsspec.filesystem("memory")
    memory.mkdir("/bagport-test-staging/segments")  # an empty folder of the store's own
    reduce_run(plan, staged)
    assert not memory.exists("/bagport-test-staging")
