"""The fleet QA report's main page size: measured at N episodes, extrapolated to 10,000.

Synthetic QA records (``bagport.synth.qa_entries``: 40 checks each, ~85% pass, 12% warn, 3% fail, 6
robots over 30 days) are written as a dataset's QA in two runs (the first 80%, then an append of the
rest), as a conversion and an append write them; the main page is measured after each run at several
sizes, a line (bytes = fixed + per-episode x episodes) is fitted, and 10,000 episodes are extrapolated.
The result goes between the ``qa-report`` markers of BENCHMARKS.md.

Usage: python bench/qa_report_size.py [--episodes 2000] [--report BENCHMARKS.md]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bagport.dataset.qa import QA_REPORT_PATH, write_qa
from bagport.synth.qa_entries import synth_qa_entries
from bench.report import write_section

TARGET_EPISODES = 10_000
LIMIT_BYTES = 2 * 1024 * 1024


def measure(episodes: int) -> tuple[int, float, int]:
    """Main page bytes after the append, the append's QA write seconds, and detail pages written."""
    entries = synth_qa_entries(episodes, seed=episodes)
    first = int(episodes * 0.8)
    with tempfile.TemporaryDirectory(prefix="bagport-qa-size-") as tmp:
        root = Path(tmp)
        write_qa(root, entries[:first], {"episodes": first, "fps": 30}, {}, 0, robot_type="arm")
        start = time.perf_counter()
        write_qa(root, entries[first:], {"episodes": episodes, "fps": 30}, {}, 1, robot_type="arm")
        append_s = time.perf_counter() - start
        details = len(list((root / "meta/qa/details").rglob("*.html")))
        return (root / QA_REPORT_PATH).stat().st_size, append_s, details


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--report", type=Path, default=Path(__file__).resolve().parents[1] / "BENCHMARKS.md")
    args = parser.parse_args()
    sizes = sorted({max(args.episodes // 4, 10), max(args.episodes // 2, 20), args.episodes})
    rows = [(n, *measure(n)) for n in sizes]
    slope, intercept = np.polyfit([r[0] for r in rows], [r[1] for r in rows], 1)
    predicted = intercept + slope * TARGET_EPISODES
    lines = [
        "| episodes | main page (bytes) | bytes per episode | detail pages (warned/failed) | append's QA write (s) |",
        "|---|---|---|---|---|",
        *(
            f"| {n} | {size:,} | {size / n:.0f} | {details} | {append_s:.2f} |"
            for n, size, append_s, details in rows
        ),
        f"| {TARGET_EPISODES} (extrapolated: {intercept:,.0f} + {slope:.1f} x episodes) | {predicted:,.0f} | "
        f"{predicted / TARGET_EPISODES:.0f} | | |",
        "",
        f"Limit {LIMIT_BYTES:,} bytes (2 MB): {'within' if predicted <= LIMIT_BYTES else 'OVER'}. "
        f"Command: `.venv/bin/python bench/qa_report_size.py --episodes {args.episodes}`.",
    ]
    body = "\n".join(lines)
    print(body)
    write_section(args.report, "qa-report", body)


if __name__ == "__main__":
    main()
