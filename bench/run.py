"""`make bench`: bagport vs the LeRobot-writer baseline vs the codec floor, on W1/W2/W3; W4, a fleet of
2,000 one-second bags, converted once and re-run (``bench/fleet.py``); REDUCE, the reduce as a map
(``bench/reduce_map.py``: appends against the dataset's size, the commit's memory, W1's reduce on Dask);
HISTORY, an append's plan against the dataset's history (``bench/append_history.py``, printed).

Each tool runs as a fresh process tree on the same generated bags; wall time, CPU seconds (the
tree's, from the kernel's child accounting), peak RSS of the whole tree (sampled every 0.2 s) and
output size are recorded; numbers are medians over ``--runs``. Results go to bench/results.json
and into BENCHMARKS.md between the result markers (the rest of that file is prose, kept as is).

Usage: python bench/run.py [--workloads W1,W2,W3,W4] [--tools bagport,lerobot,lerobot-streaming,floor]
                           [--runs 3] [--scale 1.0] [--data bench/.data] [--report BENCHMARKS.md]
                           [--results bench/results.json] [--keep-other-results]
                           [--keep-outputs] [--baseline-runs N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from importlib.metadata import version
from pathlib import Path
from typing import Any

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.fleet import fleet_table, measure_fleet
from bench.report import write_section
from bench.workloads import WORKLOADS, ensure_workload
from flows.local_server import LocalServer

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
TOOLS = ("bagport", "lerobot", "lerobot-streaming", "floor")
EXTRA_TOOLS = ("bagport-dask1", "bagport-dask2", "bagport-h264", "bagport-nofidelity", "bagport-server")
"""Not run by default: bagport on a local Dask cluster of 1 or 2 worker processes (scaling),
bagport with its own default codec (H.264) instead of LeRobot's settings, bagport without the
video fidelity check (the work the other tools do), and bagport against a Prefect server that is
already running (``PREFECT_API_URL``, as a fleet runs it: :func:`running_server`)."""
BASELINES = ("lerobot", "lerobot-streaming")


def _command(tool: str, workload: Path, out: Path) -> list[str]:
    python = sys.executable
    if tool.startswith("bagport"):
        command = [
            str(Path(python).with_name("bagport")), "convert", "--manifest", str(workload / "manifest.yaml"),
            "--contract", str(workload / "contract.yaml"), "--output", str(out), "--quiet",
        ]  # fmt: skip
        if tool == "bagport-nofidelity":  # the same work as the other tools: no video fidelity check
            qa = workload / "qa-no-fidelity.yaml"
            qa.write_text("video: {fidelity: false}\n")
            command += ["--qa", str(qa)]
        if tool != "bagport-h264":
            # LeRobot's codec settings, as the other tools use; every episode kept (AV1 damages some
            # frames of these cameras, which the fidelity check would otherwise exclude)
            command += ["--codec", "lerobot-default", "--on-qa-fail", "keep"]
        if tool.startswith("bagport-dask"):
            command += ["--runner", "dask", "--workers", tool.removeprefix("bagport-dask")]
        return command
    if tool == "lerobot":
        return [python, str(BENCH / "baseline_lerobot.py"), str(workload), str(out)]
    if tool == "lerobot-streaming":
        return [python, str(BENCH / "baseline_lerobot.py"), str(workload), str(out), "--streaming"]
    return [python, str(BENCH / "codec_floor.py"), str(workload), str(out)]


def measure(
    command: list[str], out: Path, *, fresh: bool = True, server: LocalServer | None = None
) -> dict[str, float]:
    """Run one command; wall, CPU seconds and peak RSS of its whole process tree and of the process
    started (bagport's flow process), output size. ``fresh``: remove the output and staging first.
    ``server``: a running Prefect server the command uses (``PREFECT_API_URL``); the CPU it spends
    while the command runs is counted in ``cpu_s`` (and alone in ``server_cpu_s``)."""
    if fresh:
        shutil.rmtree(out, ignore_errors=True)
        shutil.rmtree(out.with_name(out.name + ".staging"), ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    # stderr into a file, not a pipe read at the end: the encoder's banners (SVT_LOG unset) and the
    # workers' logs fill a pipe's 64 KB and block the run
    with tempfile.TemporaryFile() as log:
        env = None if server is None else {**os.environ, "PREFECT_API_URL": server.api_url}
        server_cpu_s = _cpu_s(server)
        proc = psutil.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=log, env=env)
        peak, peak_process, peak_root = 0, 0, 0
        while proc.poll() is None:
            try:
                rss = [p.memory_info().rss for p in [proc, *proc.children(recursive=True)] if p.is_running()]
                peak, peak_process = max(peak, sum(rss)), max(peak_process, *rss)
                peak_root = max(peak_root, proc.memory_info().rss)
            except (psutil.Error, ValueError):
                pass
            time.sleep(0.2)
        wall = time.perf_counter() - started
        server_cpu_s = _cpu_s(server) - server_cpu_s
        log.seek(0)
        stderr = log.read().decode(errors="replace")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{command[:3]} failed ({proc.returncode}):\n{stderr[-3000:]}")
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) if out.exists() else 0
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    served = {} if server is None else {"server_cpu_s": server_cpu_s}
    return served | {
        "wall_s": wall,
        "cpu_s": cpu + server_cpu_s,
        "peak_rss_mb": peak / 2**20,
        "peak_process_rss_mb": peak_process / 2**20,
        "root_rss_mb": peak_root / 2**20,
        "output_mb": size / 1e6,
    }


def _cpu_s(server: LocalServer | None) -> float:
    if server is None:
        return 0.0
    times = psutil.Process(server.pid).cpu_times()
    return float(times.user + times.system)


@contextmanager
def running_server(tools: list[str]) -> Iterator[LocalServer | None]:
    """For ``bagport-server``: bagport's temporary server app (SQLite), started before the runs and stopped
    after them, one for all of them, so the runs measure a conversion against a server that is up, as
    a fleet's long-running one is (``make stack``'s runs on PostgreSQL), without the temporary server's
    boot (about 2 s on 2 cores) on their path. Its CPU during a run is counted, its memory is not."""
    if "bagport-server" not in tools:
        yield None
        return
    server = LocalServer()
    try:
        server.wait_ready(120)
        yield server
    finally:
        server.stop()


def _machine() -> dict[str, Any]:
    model = "unknown"
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        model = next(
            (
                ln.split(":", 1)[1].strip()
                for ln in cpuinfo.read_text().splitlines()
                if ln.startswith("model name")
            ),
            model,
        )
    return {
        "cores": os.cpu_count(),
        "cpu": model,
        "memory_gb": round(psutil.virtual_memory().total / 2**30, 1),
        "python": platform.python_version(),
        "versions": {p: version(p) for p in ("bagport", "lerobot", "av", "prefect", "rosbags")},
    }


def _table(results: dict[str, Any]) -> str:
    lines = [f"Machine: {results['machine']['cores']} cores, {results['machine']['cpu']}, "
             f"{results['machine']['memory_gb']} GB; versions {results['machine']['versions']}; "
             f"scale {results['scale']}; runs per cell in the table.", ""]  # fmt: skip
    for name, workload in results["workloads"].items():
        if "tools" not in workload:
            continue
        lines += [f"**{name}** ({workload['description']}; {workload['recorded_s']:.0f} s recorded)", ""]
        lines += ["| tool | runs | wall s | recorded s / wall s | CPU s | peak RSS MB (tree) | largest process MB | output MB | bagport vs this |",
                  "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        tools = workload["tools"]
        ours = tools.get("bagport", {}).get("wall_s")
        for tool, m in tools.items():
            ratio = (
                f"bagport {m['wall_s'] / ours:.2f}x faster" if ours and not tool.startswith("bagport") else ""
            )
            if ours and tool == "floor":
                ratio = f"bagport takes {ours / m['wall_s']:.2f}x the floor"
            lines.append(
                f"| {tool} | {m['runs']} | {m['wall_s']:.1f} | {workload['recorded_s'] / m['wall_s']:.2f} | "
                f"{m['cpu_s']:.1f} | {m['peak_rss_mb']:.0f} | {m['peak_process_rss_mb']:.0f} | "
                f"{m['output_mb']:.1f} | {ratio} |"
            )
        lines.append("")
    return "\n".join(lines)


def write_report(results: dict[str, Any], report: Path) -> None:
    write_section(report, "results", _table(results))
    fleet = results["workloads"].get("W4")
    if fleet is not None:
        write_section(report, "fleet", fleet_table(fleet["fleet"], fleet["description"]))


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--workloads",
        default="W1,W2,W3,W4,REDUCE,HISTORY",
        help="REDUCE: the reduce as a map (bench/reduce_map.py); HISTORY: an append's plan against the "
        "dataset's history (bench/append_history.py, printed)",
    )
    parser.add_argument("--tools", default=",".join(TOOLS))
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument(
        "--baseline-runs", type=int, default=None, help="runs of the LeRobot baselines (default: --runs)"
    )
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--data", type=Path, default=BENCH / ".data")
    parser.add_argument("--report", type=Path, default=REPO / "BENCHMARKS.md")
    parser.add_argument("--results", type=Path, default=BENCH / "results.json")
    parser.add_argument(
        "--keep-other-results",
        action="store_true",
        help="keep the results already in --results for workloads and tools not run now",
    )
    parser.add_argument(
        "--keep-outputs", action="store_true", help="keep each tool's last output under DATA/out"
    )
    return parser


def _tool_cells(name: str, folder: Path, tools: list[str], args: argparse.Namespace) -> dict[str, Any]:
    """Each tool's medians on one workload, the tools' runs interleaved (this machine's speed drifts)."""
    counts = {t: args.baseline_runs if t in BASELINES and args.baseline_runs else args.runs for t in tools}
    measured: dict[str, list[dict[str, float]]] = {t: [] for t in tools}
    with running_server(tools) as server:
        for round_index in range(max(counts.values())):
            for tool in tools:
                if round_index < counts[tool]:
                    out = args.data / "out" / f"{name}-{tool}"
                    on = server if tool == "bagport-server" else None
                    measured[tool].append(measure(_command(tool, folder, out), out, server=on))
    cells: dict[str, Any] = {}
    for tool, runs in measured.items():
        cells[tool] = {key: statistics.median(r[key] for r in runs) for key in runs[0]} | {"runs": len(runs)}
        print(f"{name} {tool}: {cells[tool]}", file=sys.stderr, flush=True)
    return cells


def _workload_result(
    name: str, tools: list[str], args: argparse.Namespace, earlier: dict[str, Any]
) -> dict[str, Any]:
    """One workload's entry in the results: W4's fleet runs, or each tool's cells (beside ``earlier``'s)."""
    workload = WORKLOADS[name].scaled(args.scale)
    print(
        f"{name}: generating {workload.episodes} x {workload.duration_s:g} s ...", file=sys.stderr, flush=True
    )
    folder = ensure_workload(workload, args.data)
    entry: dict[str, Any] = {"description": workload.description, "recorded_s": workload.recorded_s}
    if name == "W4":  # a fleet: bagport's first run and re-runs, not a comparison of tools
        return entry | {"fleet": measure_fleet(folder, args.data / "out", workload.episodes)}
    cells = _tool_cells(name, folder, tools, args)
    return entry | {"tools": {**earlier.get("tools", {}), **cells}}  # tools measured before stay


def main() -> None:
    args = _parser().parse_args()
    tools = [t for t in args.tools.split(",") if t]
    results: dict[str, Any] = {"machine": _machine(), "runs": args.runs, "scale": args.scale, "workloads": {}}
    if args.keep_other_results and args.results.exists():  # add to the workloads measured before
        before = json.loads(args.results.read_text())
        if before.get("scale") == args.scale:
            results["workloads"] = before.get("workloads", {})
    for name in args.workloads.split(","):
        if name == "REDUCE":  # appends vs dataset size, the commit's memory, W1's reduce on 1 vs 2 workers
            script = [
                sys.executable,
                str(BENCH / "reduce_map.py"),
                "--data",
                str(args.data),
                "--report",
                str(args.report),
            ]
            subprocess.run(script, check=True, cwd=REPO)
            continue
        if name == "HISTORY":  # the plan's read of a dataset's bags, from its records and from bags.parquet
            subprocess.run([sys.executable, str(BENCH / "append_history.py")], check=True, cwd=REPO)
            continue
        earlier = results["workloads"].get(name, {})
        results["workloads"][name] = _workload_result(name, tools, args, earlier)
        args.results.write_text(json.dumps(results, indent=1))
        write_report(results, args.report)
    if not args.keep_outputs:
        shutil.rmtree(args.data / "out", ignore_errors=True)


if __name__ == "__main__":
    main()
