"""The bags table (meta/provenance/bags.parquet) says what the run records say, and an append reads it
instead of every record: only the records written after it (an append whose new bags were all excluded)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bagport.config import ConvertConfig
from bagport.dataset import bags_index
from bagport.dataset.history import DatasetBags, dataset_bags
from bagport.dataset.validate import validate_dataset
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT, SMALL_CAMERAS


def _bag(root: Path, name: str, duration_s: float, seed: int) -> Path:
    bag = root / "bags" / name
    write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=duration_s, cameras=SMALL_CAMERAS, seed=seed))
    return bag


def _config(root: Path) -> ConvertConfig:
    return ConvertConfig(
        manifest=str(root / "m.yaml"), contract=str(SAMPLE_CONTRACT), output=str(root / "ds"),
        encoder=FAST_CODEC, append=True,
    )  # fmt: skip


def _append(root: Path, entries: str) -> None:
    (root / "m.yaml").write_text("bags:\n" + entries)
    plan = plan_run(_config(root))
    if plan.requests or plan.reused:
        reduce_run(plan, stage_all(plan))


def _from_records(root: Path, monkeypatch: pytest.MonkeyPatch) -> DatasetBags:
    with monkeypatch.context() as patched:
        patched.setattr(bags_index, "_read_index", lambda fs, path: None)
        return dataset_bags(str(root))


def test_the_table_says_what_the_records_say_and_only_later_records_are_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    long_bag, other, short = (
        _bag(tmp_path, n, d, s) for n, d, s in (("a", 2.0, 0), ("b", 1.5, 1), ("c", 0.1, 2))
    )
    _append(tmp_path, f"  - uri: {long_bag}\n    end_s: 1.0\n  - uri: {long_bag}\n    start_s: 1.0\n")
    _append(tmp_path, f"  - uri: {long_bag}\n    end_s: 1.0\n  - uri: {other}\n")
    table = pq.read_table(tmp_path / "ds/meta/provenance/bags.parquet")
    assert table.schema.metadata[b"bagport.covered_run"] == b"1"
    rows = zip(*(table.column(n).to_pylist() for n in ("run", "bag_uri", "window", "kind")), strict=True)
    assert sorted(rows) == [
        (0, str(long_bag), "None:None:1.0:None", "kept"),  # start_s: 1.0
        (0, str(long_bag), "None:None:None:1.0", "kept"),  # end_s: 1.0
        (1, str(other), "", "kept"),  # the whole bag; the first window again is not appended
    ]
    _append(tmp_path, f"  - uri: {short}\n")  # QA fails it (0.1 s): a record of its exclusion, no table
    assert (tmp_path / "ds/meta/provenance/run-002.json").is_file()

    read: list[int] = []
    real = bags_index.record_rows

    def counted(record: Mapping[str, Any], run: int) -> pa.Table:
        read.append(run)
        return real(record, run)

    monkeypatch.setattr(bags_index, "record_rows", counted)
    known = dataset_bags(str(tmp_path / "ds"))
    assert read == [2]  # the exclusion's record only: runs 0 and 1 come from the table
    assert known == _from_records(tmp_path / "ds", monkeypatch)
    assert len(known.kept) == 3 and len(known.left_out) == 1
    # the newest run that added episodes is run 1 (b), not the exclusions' run 2
    assert {staged_id.split("-")[0] for staged_id, _ in known.newest_staged} == {"b"}
    assert {staged_id.split("-")[0] for staged_id, _ in known.committed_staged} == {"a"}
    assert {uri for uri, _, _ in known.left_out} == {str(short)}

    plan = plan_run(_config(tmp_path))
    assert plan.requests == ()  # the excluded bag, unchanged, is not tried again
    assert validate_dataset(tmp_path / "ds", repo_id="test/bags", decode_every=30).episodes == 3


def test_a_table_that_cannot_be_read_falls_back_to_the_records(tmp_path: Path) -> None:
    bag = _bag(tmp_path, "a", 1.5, 0)
    _append(tmp_path, f"  - uri: {bag}\n")
    index = tmp_path / "ds/meta/provenance/bags.parquet"
    known = dataset_bags(str(tmp_path / "ds"))
    index.write_bytes(b"not parquet")
    assert dataset_bags(str(tmp_path / "ds")) == known and len(known.kept) == 1
