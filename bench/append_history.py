"""What an ``--append``'s plan spends learning which bags the dataset holds, against the dataset's history.

One real append of 20 one-second bags (W4's shape) gives a run record; copies of it, each naming other bags,
stand for the runs of an hourly ingestion (``run-001.json`` ... ``run-N.json``, 20 episodes each). For each
history length the plan's read (``bagport.dataset.history.dataset_bags``) is timed twice: from the run
records alone (a dataset written before ``meta/provenance/bags.parquet``), and from the table of bags every
commit now writes (built by the commit's own code, ``bagport.dataset.bags_index``), median of 3.

Usage: python bench/append_history.py [--runs 100,1000,4000] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO / "src"), str(REPO)]

from fsspec.implementations.local import LocalFileSystem  # noqa: E402

from bagport.config import ConvertConfig  # noqa: E402
from bagport.dataset.bags_index import bag_rows, write_bags_index  # noqa: E402
from bagport.dataset.history import dataset_bags  # noqa: E402
from bagport.dataset.layout import BAGS_INDEX_PATH  # noqa: E402
from bagport.reduce import reduce_run  # noqa: E402
from bagport.run import plan_run, stage_all  # noqa: E402
from bench.workloads import WORKLOADS, ensure_workload  # noqa: E402


def _one_append(work: Path, bags: int) -> Path:
    """A dataset made by one --append of ``bags`` bags of W4's shape; its root."""
    workload = ensure_workload(replace(WORKLOADS["W4"], episodes=bags), work)
    manifest = work / "m.yaml"
    manifest.write_text("bags:\n" + "".join(f"  - uri: {p}\n" for p in sorted(workload.glob("ep*"))))
    config = ConvertConfig(
        manifest=str(manifest), contract=str(workload / "contract.yaml"), output=str(work / "ds"),
        encoder=yaml.safe_load((REPO / "configs/codecs/h264-fast.yaml").read_text()), append=True,
        on_qa_fail="keep",
    )  # fmt: skip
    plan = plan_run(config)
    reduce_run(plan, stage_all(plan))
    return work / "ds"


def _history(root: Path, runs: int) -> None:
    """``runs`` run records in all (the real one and copies naming other bags)."""
    provenance = root / "meta/provenance"
    for old in provenance.glob("run-*.json"):
        old.unlink()
    (provenance / BAGS_INDEX_PATH.rsplit("/", 1)[-1]).unlink(missing_ok=True)
    template = json.loads((provenance / "run.json").read_text())
    for run in range(1, runs):
        episodes = [{**e, "bag_uri": f"{e['bag_uri']}-run{run}"} for e in template["episodes"]]
        (provenance / f"run-{run:03d}.json").write_text(
            json.dumps({**template, "episodes": episodes}, indent=2)
        )


def _timed(root: Path) -> tuple[float, int]:
    times, kept = [], 0
    for _ in range(3):
        started = time.perf_counter()
        kept = len(dataset_bags(str(root)).kept)
        times.append(time.perf_counter() - started)
    return statistics.median(times), kept


@dataclass(frozen=True, slots=True)
class HistoryRow:
    runs: int
    episodes: int
    records_mb: float
    records_s: float
    table_s: float
    table_mb: float

    def markdown(self) -> str:
        return (
            f"| {self.runs} | {self.episodes} | {self.records_mb:.1f} | {self.records_s:.3f} | "
            f"{self.table_s:.3f} | {self.table_mb:.2f} |"
        )


def measure(work: Path, runs: list[int], bags: int = 20) -> list[HistoryRow]:
    """The plan's read for each history length (``runs`` records of ``bags`` episodes each), both ways."""
    root = _one_append(work, bags)
    out = []
    for count in runs:
        _history(root, count)
        records_mb = sum(p.stat().st_size for p in (root / "meta/provenance").glob("run*.json")) / 1e6
        records_s, kept = _timed(root)
        rows = bag_rows(LocalFileSystem(), str(root))
        write_bags_index(root / BAGS_INDEX_PATH, rows, count - 1)  # run.json is run 0
        table_s, kept_table = _timed(root)
        if kept_table != kept:
            raise AssertionError(f"the table holds {kept_table} bags, the records {kept}")
        table_mb = (root / BAGS_INDEX_PATH).stat().st_size / 1e6
        out.append(HistoryRow(count, kept, records_mb, records_s, table_s, table_mb))
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", default="100,1000,4000")
    parser.add_argument("--work", type=Path, default=None)
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="bagport-history-"))
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}")
    rows = measure(work, [int(r) for r in args.runs.split(",")])
    print(
        "| run records | episodes | records MB | plan's read, records only s | with bags.parquet s | table MB |"
    )
    print("|---|---|---|---|---|---|")
    for row in rows:
        print(row.markdown())
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
