"""The reduce as a map (issue 15): what an append costs against the size of the dataset, what a second Dask
worker gives the reduce, and whether the commit's memory stays flat with the number of episodes.

- ``append``: 20 new one-second episodes (W4's shape) appended to a dataset of 100 and of 2,000 episodes
  (built from the same staged episodes, repeated): wall seconds of the append, and how many times it
  opened or read an existing data or video file (inotify on every one of them: 0 opens is 0 bytes read).
- ``commit``: the commit step alone (``bagport.dataset.commit.commit_write``: ``meta/``, QA, provenance,
  checksums, publish) for a 100- and a 2,000-episode write, in a fresh process: its peak RSS (VmHWM).
- ``reduce``: the flow process's side of a reduce (issue 14): read the staged summaries, select the episodes
  (``bagport.selection.select_episodes``: every QA entry), open the write, the files written by a worker
  process (as on Dask or Ray; with the local process pool the flow writes them on its own threads, which
  W4's flow-process peak includes), then the commit with the QA entries (``meta/qa``: index, a detail page per
  warned episode, and every W4 episode warns), for 100 and 2,000 episodes, in a fresh process: its peak RSS,
  and with ``--trace`` tracemalloc's figures (what is held after the selection, and the peak).
- ``dask``: the reduce of W1 (8 x 30 s, three 640x480 cameras; staged once) on a local Dask cluster of
  1 and of 2 worker processes: open the write, one ``write_planned_file`` per output file on the
  workers, then the commit; wall seconds.

The machine is shared: every figure comes with the 1-minute load average when it was taken.
Usage: python bench/reduce_map.py [--parts append,commit,reduce,dask] [--trace] [--data DIR] [--report BENCHMARKS.md]
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import multiprocessing
import os
import pickle
import shutil
import statistics
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from bagport.dataset import write_dataset  # noqa: E402
from bagport.dataset.commit import commit_write  # noqa: E402
from bagport.dataset.files import write_planned_file  # noqa: E402
from bagport.dataset.session import open_write  # noqa: E402
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for  # noqa: E402
from bagport.episode.staged import PlannedEpisode  # noqa: E402
from bagport.qa import QAConfig  # noqa: E402
from bagport.reduce import read_staged  # noqa: E402
from bagport.selection import select_episodes  # noqa: E402
from bagport.staging import EpisodeSummary  # noqa: E402
from bagport.video.settings import EncoderSettings  # noqa: E402
from bench.report import write_section  # noqa: E402
from bench.workloads import WORKLOADS, ensure_workload  # noqa: E402

CODEC = EncoderSettings.from_dict(yaml.safe_load((REPO / "configs/codecs/h264-fast.yaml").read_text()))
NEW = 20


def _probe() -> Any:
    """tests/fsprobe.py (inotify), loaded by path: the ``tests`` name may belong to an installed package."""
    spec = importlib.util.spec_from_file_location("fsprobe", REPO / "tests/fsprobe.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _load() -> float:
    return os.getloadavg()[0]


def _stage_one(args: tuple[Path, str, str, int]) -> EpisodeSummary:
    folder, name, contract, entry = args
    bag = str(folder / name)
    request = EpisodeRequest(
        episode_id_for(bag, contract, CODEC), bag, entry, str(folder / "staging"), contract, "bench", CODEC
    )
    return convert_episode(request)


def stage(workload: str, data: Path, episodes: int | None = None) -> list[EpisodeSummary]:
    """The workload's bags (generated once), converted into a staging store beside them (two at a time)."""
    spec = WORKLOADS[workload]
    if episodes is not None:
        spec = spec.scaled(episodes / spec.episodes)
    folder = ensure_workload(spec, data, workers=2)
    names = [e["uri"] for e in yaml.safe_load((folder / "manifest.yaml").read_text())["bags"]]
    contract = (folder / "contract.yaml").read_text()
    with ProcessPoolExecutor(max_workers=2) as pool:
        return list(pool.map(_stage_one, [(folder, n, contract, i) for i, n in enumerate(names)]))


def _repeat(staged: Sequence[EpisodeSummary], count: int) -> list[EpisodeSummary]:
    return [staged[i % len(staged)] for i in range(count)]


def _append_once(staged: list[EpisodeSummary], root: Path, base: int, probe: Any) -> tuple[float, int, int]:
    shutil.rmtree(root, ignore_errors=True)
    write_dataset(_repeat(staged, base), str(root), robot_type="bench_arm")
    old = sorted(p for d in ("data", "videos") for p in (root / d).rglob("*") if p.is_file())
    with probe.watch_opens(old) as opens:
        started = time.perf_counter()
        write_dataset(staged[:NEW], str(root), robot_type="bench_arm", append=True)
        wall = time.perf_counter() - started
    shutil.rmtree(root)
    return wall, len(old), len(opens.events)


def measure_append(
    staged: list[EpisodeSummary], out: Path, bases: Sequence[int], runs: int = 3
) -> list[dict[str, float]]:
    """Each base size ``runs`` times, the sizes alternating; the median wall is reported."""
    probe = _probe()
    walls: dict[int, list[float]] = {base: [] for base in bases}
    rows: dict[int, dict[str, float]] = {}
    for _ in range(runs):
        for base in bases:
            load = _load()
            wall, old, opens = _append_once(staged, out / f"append-{base}", base, probe)
            walls[base].append(wall)
            row = rows.setdefault(base, {"base": base, "old_files": old, "opens": 0, "load": load})
            row["opens"] += opens
            row["load"] = max(row["load"], load)
    for base, row in rows.items():
        row["wall_s"] = float(sorted(walls[base])[len(walls[base]) // 2])
        row["walls"] = walls[base]  # type: ignore[assignment]
        print(f"append {NEW} to {base}: {row}", flush=True)
    return list(rows.values())


def _commit_child(job: Path) -> None:
    """In a fresh process: the commit alone, then its peak RSS (and the RSS before it, imports done)."""
    session, summaries, written = pickle.loads(job.read_bytes())
    before = _status_kb("VmRSS")
    commit_write(session, summaries, written, robot_type="bench_arm")
    print(json.dumps({"before_mb": before / 1024, "peak_mb": _status_kb("VmHWM") / 1024}))


def _status_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise KeyError(field)


def measure_commit(staged: list[EpisodeSummary], out: Path, sizes: Sequence[int]) -> list[dict[str, float]]:
    rows = []
    for count in sizes:
        root = out / f"commit-{count}"
        shutil.rmtree(root, ignore_errors=True)
        summaries = _repeat(staged, count)
        with open_write(summaries, str(root)) as session:
            written = [write_planned_file(session.plan, item, session.build) for item in session.plan.files]
            rows.append(
                {"episodes": count, **_in_child("--commit-child", (session, summaries, written), out)}
            )
        print(f"commit of {count}: {rows[-1]}", flush=True)
        shutil.rmtree(root)
    return rows


def _in_child(flag: str, job: object, out: Path) -> dict[str, float]:
    """Run ``job`` (pickled) in a fresh process of this script (``flag`` says which part); its wall time,
    the load when it started, and the figures it prints last (a JSON object)."""
    path = out / f"{flag.strip('-')}.pickle"
    path.write_bytes(pickle.dumps(job))
    load = _load()
    started = time.perf_counter()
    child = subprocess.run(
        [sys.executable, __file__, flag, str(path)], capture_output=True, text=True, check=True
    )
    wall = time.perf_counter() - started
    path.unlink()
    figures: dict[str, float] = json.loads(child.stdout.splitlines()[-1])
    return {"wall_s": wall, "load": load, **figures}


def _reduce_on(client: Any, staged: list[EpisodeSummary], root: Path) -> tuple[float, int]:
    """One reduce of ``staged`` into ``root`` with the file writers on ``client``: (wall s, files)."""
    shutil.rmtree(root, ignore_errors=True)
    started = time.perf_counter()
    with open_write(staged, str(root)) as session:
        items = list(session.plan.files)
        futures = client.map(
            write_planned_file, [session.plan] * len(items), items, [session.build] * len(items), pure=False
        )
        commit_write(session, staged, client.gather(futures), robot_type="bench_arm")
    wall = time.perf_counter() - started
    shutil.rmtree(root)
    return wall, len(items)


def _reduce_child(job: Path) -> None:
    """In a fresh process, as the flow process does it: every staged summary read, the selection, the files
    written by another process, the commit; then the peak RSS (and tracemalloc's, when asked)."""
    episodes, root, trace = pickle.loads(job.read_bytes())
    before = _status_kb("VmRSS")
    if trace:
        tracemalloc.start()
    summaries, _ = read_staged(
        [PlannedEpisode(uri, bag, entry) for entry, (uri, bag) in enumerate(episodes)]
    )  # as bagport.reduce.start_reduce reads them
    kept, entries = select_episodes(
        summaries, [], policy="keep", keep_labelled=False, output=root, appending=False
    )
    held = tracemalloc.get_traced_memory()[0] if trace else 0
    with (
        open_write(kept, root) as session,
        ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool,
    ):
        items = list(session.plan.files)
        written = list(
            pool.map(write_planned_file, [session.plan] * len(items), items, [session.build] * len(items))
        )
        commit_write(
            session,
            kept,
            written,
            robot_type="bench_arm",
            run_record={},
            qa=entries,
            qa_config=QAConfig().model_dump(mode="json"),
        )
    peak_traced = tracemalloc.get_traced_memory()[1] if trace else 0
    row = {"before_mb": before / 1024, "peak_mb": _status_kb("VmHWM") / 1024}
    if trace:
        row |= {"held_after_selection_mb": held / 2**20, "traced_peak_mb": peak_traced / 2**20}
    print(json.dumps(row))


def measure_reduce(
    staged: list[EpisodeSummary], out: Path, sizes: Sequence[int], *, trace: bool
) -> list[dict[str, float]]:
    rows = []
    for count in sizes:
        root = out / f"reduce-{count}"
        shutil.rmtree(root, ignore_errors=True)
        job = ([(s.dir_uri, s.bag_uri) for s in _repeat(staged, count)], str(root), trace)
        rows.append({"episodes": count, **_in_child("--reduce-child", job, out)})
        print(f"reduce of {count}: {rows[-1]}", flush=True)
        shutil.rmtree(root)
    return rows


def measure_dask(
    staged: list[EpisodeSummary], out: Path, workers: Sequence[int], repeats: int = 5
) -> list[dict[str, float]]:
    """The reduce on clusters of each size, all up at once and taken in turns (1, 2, 1, 2...), so a
    burst of load on the shared machine hits every size alike; the median and the best of ``repeats``."""
    from distributed import Client, LocalCluster  # noqa: PLC0415 - the dask extra

    walls: dict[int, list[float]] = {count: [] for count in workers}
    loads: list[float] = []
    with contextlib.ExitStack() as stack:
        clients = {}
        for count in workers:
            cluster = stack.enter_context(
                LocalCluster(n_workers=count, threads_per_worker=1, processes=True, dashboard_address=None)  # type: ignore[no-untyped-call]
            )
            clients[count] = stack.enter_context(Client(cluster))  # type: ignore[no-untyped-call]
            clients[count].run(lambda: None)
        for _ in range(repeats):
            for count, client in clients.items():
                loads.append(_load())
                wall, files = _reduce_on(client, staged, out / f"dask-{count}")
                walls[count].append(wall)
    rows = [
        {
            "workers": count,
            "wall_s": statistics.median(walls[count]),
            "best_s": min(walls[count]),
            "repeats": repeats,
            "files": files,
            "load": max(loads),
        }
        for count in workers
    ]
    for row in rows:
        print(f"W1 reduce on {row['workers']} Dask worker(s): {row}", flush=True)
    return rows


_TABLES: dict[str, tuple[str, list[str], str]] = {
    "append": (
        f"Appending {NEW} one-second episodes (W4's shape):",
        ["dataset before", "append wall s (median of 3)", "existing data/video files",
         "opens/reads of them (all runs)", "load avg (1 min, max)"],
        "| {base} episodes | {wall_s:.2f} | {old_files} | {opens} | {load:.1f} |",
    ),
    "commit": (
        "The commit step alone, in a fresh process:",
        ["episodes written", "commit wall s", "RSS before (imports) MB", "peak RSS MB", "load avg (1 min)"],
        "| {episodes} | {wall_s:.2f} | {before_mb:.0f} | {peak_mb:.0f} | {load:.1f} |",
    ),
    "reduce": (
        "The flow process's side of a reduce (summaries read, selection, commit with QA), in a fresh process:",
        ["episodes written", "wall s", "RSS before (imports) MB", "peak RSS MB", "load avg (1 min)"],
        "| {episodes} | {wall_s:.2f} | {before_mb:.0f} | {peak_mb:.0f} | {load:.1f} |",
    ),
    "dask": (
        "The reduce of W1 (staged once) on a local Dask cluster:",
        ["workers", "reduce wall s (median)", "best s", "runs (taken in turns)", "output files (tasks)",
         "load avg (1 min, max)"],
        "| {workers} | {wall_s:.2f} | {best_s:.2f} | {repeats} | {files} | {load:.1f} |",
    ),
}  # fmt: skip
"""Each part's table: title, header, row format."""


def _tables(results: dict[str, list[dict[str, float]]]) -> str:
    lines: list[str] = []
    for part, (title, header, row) in _TABLES.items():
        if part in results:
            lines += [title, "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            lines += [row.format(**r) for r in results[part]]
            lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--parts", default="append,commit,reduce,dask")
    parser.add_argument("--data", type=Path, default=REPO / "bench/.data")
    parser.add_argument("--report", type=Path, default=REPO / "BENCHMARKS.md")
    parser.add_argument("--results", type=Path, default=REPO / "bench/reduce_map.json")
    parser.add_argument("--trace", action="store_true", help="reduce: tracemalloc's figures too (slower)")
    parser.add_argument("--commit-child", type=Path, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--reduce-child", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.commit_child is not None:
        _commit_child(args.commit_child)
        return
    if args.reduce_child is not None:
        _reduce_child(args.reduce_child)
        return
    parts = args.parts.split(",")
    out = args.data / "reduce-map"
    out.mkdir(parents=True, exist_ok=True)
    results = json.loads(args.results.read_text()) if args.results.is_file() else {}
    if "append" in parts or "commit" in parts or "reduce" in parts:
        small = stage("W4", args.data, episodes=NEW)
        if "append" in parts:
            results["append"] = measure_append(small, out, (100, 2000))
        if "commit" in parts:
            results["commit"] = measure_commit(small, out, (100, 2000))
        if "reduce" in parts:
            results["reduce"] = measure_reduce(small, out, (100, 2000), trace=args.trace)
    if "dask" in parts:
        results["dask"] = measure_dask(stage("W1", args.data), out, (1, 2))
    args.results.write_text(json.dumps(results, indent=1))
    body = _tables(results) + f"\nCommand: `.venv/bin/python bench/reduce_map.py --parts {args.parts}`."
    print(body)
    write_section(args.report, "reduce-map", body)


if __name__ == "__main__":
    main()
