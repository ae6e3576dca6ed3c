"""W4, fleet operation: what a first run, a re-run with nothing new and a re-run after touching a few bags
cost, with the staging store kept between runs (``--keep-staging``, as a scheduled re-conversion does).

Phases, each a fresh ``bagport convert`` process tree measured by :func:`bench.run.measure`:

- ``first 100``: the first 100 bags alone (fresh staging): the flow process's peak memory at 100 episodes;
- ``first``: every bag (fresh staging);
- ``no-op re-run``: the same again with ``--overwrite``: every episode is staged and the dataset's write
  key is the plan's, so nothing is converted or written ("up to date");
- ``no-op append``: ``--append`` of the same manifest into the dataset: nothing new, nothing submitted;
- ``no-op re-run 100``: the first 100 again with ``--overwrite`` (a small fleet's re-run);
- ``staged, new output 100``: the first 100 into a new output with their staging kept: nothing is
  converted, but the whole dataset is written from the staged episodes (the reduce alone);
- ``touched re-run``: :data:`TOUCHED` bags' files get a new modification time, then ``--overwrite``:
  exactly those convert again (last: it changes bags of the first 100 too).

Each phase is compared with the first run of the same bags (its baseline).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import yaml

from bench.prefect_records import TABLES, count_records, prefect_database, records_added

__all__ = ["TOUCHED", "fleet_table", "measure_fleet"]

TOUCHED = 20
SMALL = 100


def _command(
    workload: Path, manifest: Path, out: Path, *extra: str, staging: Path | None = None
) -> list[str]:
    bagport = str(Path(sys.executable).with_name("bagport"))
    return [
        bagport, "convert", "--manifest", str(manifest), "--contract", str(workload / "contract.yaml"),
        "--output", str(out), "--staging", str(staging or f"{out}.staging"), "--keep-staging",
        "--codec", "lerobot-default",
        "--on-qa-fail", "keep", "--quiet", *extra,
    ]  # fmt: skip


def _touch(workload: Path, count: int) -> None:
    """Give the files of ``count`` bags, spread over the fleet, a new modification time."""
    bags = yaml.safe_load((workload / "manifest.yaml").read_text())["bags"]
    step = max(1, len(bags) // count)
    for entry in bags[::step][:count]:
        for item in sorted((workload / entry["uri"]).rglob("*")):
            if item.is_file():
                stat = item.stat()
                os.utime(item, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))


def measure_fleet(workload: Path, out_root: Path, episodes: int) -> dict[str, dict[str, float]]:
    from bench.run import measure  # noqa: PLC0415 - bench.run imports this module

    out_root.mkdir(parents=True, exist_ok=True)
    manifest = workload / "manifest.yaml"
    small = workload / f"manifest-first-{SMALL}.yaml"
    bags = yaml.safe_load(manifest.read_text())["bags"]
    small.write_text(yaml.safe_dump({"bags": bags[:SMALL]}))
    out, out_small = out_root / "W4-fleet", out_root / "W4-small"
    first_small = f"first {min(SMALL, episodes)}"
    phases: dict[str, tuple[list[str], int, bool, str]] = {
        first_small: (_command(workload, small, out_small), min(SMALL, episodes), True, first_small),
        "first": (_command(workload, manifest, out), episodes, True, "first"),
        "no-op re-run": (_command(workload, manifest, out, "--overwrite"), episodes, False, "first"),
        "no-op append": (_command(workload, manifest, out, "--append"), episodes, False, "first"),
        f"no-op re-run {min(SMALL, episodes)}": (
            _command(workload, small, out_small, "--overwrite"),
            min(SMALL, episodes),
            False,
            first_small,
        ),
        f"staged, new output {min(SMALL, episodes)}": (
            _command(workload, small, out_root / "W4-small-new", staging=Path(f"{out_small}.staging")),
            min(SMALL, episodes),
            False,
            first_small,
        ),
        f"touched re-run ({TOUCHED} bags)": (
            _command(workload, manifest, out, "--overwrite"),
            episodes,
            False,
            "first",
        ),
    }
    results: dict[str, dict[str, float]] = {}
    database = prefect_database()
    for name, (command, count, fresh, baseline) in phases.items():
        if name.startswith("touched"):
            _touch(workload, TOUCHED)
        before = count_records(database) if database is not None else None
        measured = measure(command, Path(command[command.index("--output") + 1]), fresh=fresh)
        if database is not None and before is not None:
            measured.update(records_added(before, count_records(database)))
        measured["episodes"] = count
        measured["baseline"] = list(phases).index(baseline)
        results[name] = measured
        print(f"W4 {name}: {measured}", flush=True)
    shutil.rmtree(out_root / "W4-small-new", ignore_errors=True)
    shutil.rmtree(out_root / "W4-small.staging", ignore_errors=True)
    return results


def fleet_table(fleet: dict[str, dict[str, float]], description: str) -> str:
    names = list(fleet)
    lines = [
        f"**W4** ({description}; staging kept between runs)",
        "",
        "| run | wall s | of its first run | CPU s | of first run | wall s / episode | CPU s / episode | flow process peak RSS MB | peak RSS MB (tree) | Prefect records written |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for name, m in fleet.items():
        first = fleet[names[int(m["baseline"])]] if "baseline" in m else fleet.get("first", {})
        share = {k: f"{100 * m[k] / first[k]:.1f}%" if first.get(k) else "" for k in ("wall_s", "cpu_s")}
        lines.append(
            f"| {name} | {m['wall_s']:.1f} | {share['wall_s']} | {m['cpu_s']:.1f} | {share['cpu_s']} | "
            f"{m['wall_s'] / m['episodes']:.3f} | {m['cpu_s'] / m['episodes']:.3f} | {m['root_rss_mb']:.0f} | "
            f"{m['peak_rss_mb']:.0f} | {_records(m)} |"
        )
    return "\n".join(lines)


def _records(measured: dict[str, float]) -> str:
    """The Prefect rows a run added (:mod:`bench.prefect_records`), e.g. ``1 flow runs, 7 task runs, ...``;
    empty for results measured before they were counted."""
    if f"prefect_{next(iter(TABLES))}" not in measured:
        return ""
    return ", ".join(f"{measured[f'prefect_{table}']:.0f} {what}" for table, what in TABLES.items())
