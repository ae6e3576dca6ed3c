"""Where one worker's CPU goes per small episode: ``convert_episode`` on a workload's bags, in-process.

Plans the workload as ``bagport convert --codec lerobot-default --on-qa-fail keep`` would (the
benchmark's settings), converts one episode to warm the process up (imports, the type store), then
``--episodes`` more under cProfile, and prints CPU seconds per episode (``time.process_time``: every
thread of this process, the encoder's included; and the main thread's alone, ``time.thread_time``: time
a process-wide clock charges to a step includes the encoder threads' work beside it), the top functions
by their own time and by
cumulative time, and how often per episode the costly steps happen (contract parsed, bag opened,
encoder and decoder opened, parquet writers, JSON dumps, JPEG thumbnails).

    .venv/bin/python bench/episode_profile.py bench/.data/W3-200x2s --episodes 40
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import tempfile
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bagport.config import ConvertConfig
from bagport.episode import convert_episode
from bagport.run import plan_run

REPO = Path(__file__).resolve().parents[1]
COUNTED = {
    "contract parsed": ("contract/load.py", "parse_contract"),
    "bag opened": ("bags/reader.py", "open_bag"),
    "messages read from the bag (both passes; +1 per read)": ("bags/reader.py", "messages"),
    "messages deserialised": ("bags/typesources.py", "__call__"),
    "bag type definitions parsed (rosbags)": ("typesys/msg.py", "get_types_from_msg"),
    "YAML documents loaded": ("yamlsource.py", "load_plain"),
    "video encoder opened": ("video/encode.py", "__init__"),
    "clip containers opened (av.open)": ("~", "<av.container.core.open>"),
    "pyarrow.parquet objects created (writers, files)": ("parquet/core.py", "__init__"),
    "parquet tables read back": ("parquet/core.py", "read_table"),
    "json.dumps": ("json/__init__.py", "dumps"),
    "JPEG thumbnails encoded (QA strip)": ("qa/values.py", "_thumbnail"),
    "JPEG worst-frame panels encoded": ("episode/fidelity.py", "_jpeg_base64"),
}


PHASES = {
    "contract parsed": ("contract/load.py", "parse_contract"),
    "bag's files listed (source stamp)": ("bags/stamp.py", "source_stamp"),
    "dead-scratch sweep": ("bagport/scratch.py", "clean_dead_scratch"),
    "bag opened (metadata, index, types)": ("bags/reader.py", "open_bag"),
    "pass 1: timeline scan": ("episode/timeline.py", "scan_timeline"),
    "alignment": ("episode/alignment.py", "align_sources"),
    "pass 2: read, deserialise, decode JPEG": ("episode/assemble.py", "iter_frames"),
    "sinks: encode, image stats, QA monitor, fidelity refs": ("episode/sinks.py", "add"),
    "encoder flush, frame table close": ("episode/sinks.py", "close"),
    "fidelity check (decode sampled GOPs of the clip)": ("episode/fidelity.py", "check"),
    "QA scoring": ("episode/quality.py", "assess_episode"),
    "qa.json (to_dict + dumps)": ("qa/result.py", "to_dict"),
    "provenance table": ("episode/sinks.py", "write_provenance"),
    "stats partials": ("episode/sinks.py", "stats"),
    "publish to staging (a rename, episode.json)": ("episode/publish.py", "publish_episode"),
    "folders removed (work folder, scratch)": ("shutil.py", "rmtree"),
}
"""Where an episode's time goes: the cumulative time of each step's function (the outermost of that name)."""


def _phases(stats: pstats.Stats, episodes: int) -> dict[str, float]:
    found = dict.fromkeys(PHASES, 0.0)
    for (file, _line, name), (_cc, _calls, _tt, cumulative, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        for what, (where, function) in PHASES.items():
            if file.endswith(where) and name == function:
                found[what] = max(found[what], cumulative / episodes)
    return found


def _counts(stats: pstats.Stats, episodes: int) -> dict[str, float]:
    found = dict.fromkeys(COUNTED, 0.0)
    for (file, _line, name), (_cc, calls, *_rest) in stats.stats.items():  # type: ignore[attr-defined]
        for what, (where, function) in COUNTED.items():
            if where in file and name == function:
                found[what] += calls / episodes
    return found


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workload", type=Path, help="a workload folder (manifest.yaml, contract.yaml)")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--codec", type=Path, default=REPO / "configs" / "codecs" / "lerobot-default.yaml")
    parser.add_argument("--top", type=int, default=30)
    parser.add_argument("--no-profile", action="store_true", help="time only (no cProfile overhead)")
    parser.add_argument("--dump", type=Path, help="write the cProfile stats here (pstats format)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bagport-profile-") as tmp:
        config = ConvertConfig(
            manifest=str(args.workload / "manifest.yaml"),
            contract=str(args.workload / "contract.yaml"),
            output=str(Path(tmp) / "out"),
            encoder=yaml.safe_load(args.codec.read_text()),
            on_qa_fail="keep",
        )
        requests = plan_run(config, reuse=False).requests
        convert_episode(requests[0])  # warm-up: imports, caches
        todo = requests[1 : args.episodes + 1]
        profile = None if args.no_profile else cProfile.Profile()
        cpu_s, main_s, wall_s = time.process_time(), time.thread_time(), time.perf_counter()
        if profile is not None:
            profile.enable()
        for request in todo:
            convert_episode(request)
        if profile is not None:
            profile.disable()
        cpu_s, main_s = time.process_time() - cpu_s, time.thread_time() - main_s
        wall_s = time.perf_counter() - wall_s
    episodes = len(todo)
    print(
        f"{episodes} episodes: {cpu_s / episodes:.4f} CPU s ({main_s / episodes:.4f} on the main thread, the rest "
        f"the encoder's threads), {wall_s / episodes:.4f} wall s per episode"
    )
    if profile is None:
        return
    stats = pstats.Stats(profile)
    total = stats.total_tt / episodes  # type: ignore[attr-defined]
    print(f"profiled: {total:.4f} s per episode (cProfile's clock; the encoder's own threads not included)")
    for what, seconds in _phases(stats, episodes).items():
        print(f"  {1000 * seconds:7.2f} ms  {what}")
    for what, calls in _counts(stats, episodes).items():
        print(f"  {what}: {calls:g} per episode")
    if args.top:
        stats.sort_stats("tottime").print_stats(args.top)
        stats.sort_stats("cumulative").print_stats(args.top)
    if args.dump is not None:
        stats.dump_stats(args.dump)


if __name__ == "__main__":
    main()
