"""The dataset's QA record: ``meta/qa/`` beside (never inside) ``info.json``.

```
meta/qa/chunk-000/file-000.parquet   one row per episode and check (value, verdict, reason, robot_id)
meta/qa/summary.json                 per bag: episode index (null when excluded), score, verdict, reason,
                                     metadata (manifest columns such as robot_id, the events' episode_id)
meta/qa/report.html                  the self-contained report (see bagport.qa.report)
```
Excluded bags and bags that could not be converted are listed too, with the reason.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from bagport.qa import QAEntry
from bagport.qa.report import render_report

__all__ = ["QA_REPORT_PATH", "QA_SUMMARY_PATH", "QA_TABLE_PATH", "QAEntry", "qa_rows", "write_qa"]

QA_TABLE_PATH = "meta/qa/chunk-000/file-000.parquet"
QA_SUMMARY_PATH = "meta/qa/summary.json"
QA_REPORT_PATH = "meta/qa/report.html"


_QA_FIELDS: list[tuple[str, pa.DataType]] = [
    ("bag_uri", pa.string()),
    ("episode_index", pa.int64()),
    ("excluded", pa.bool_()),
    ("check", pa.string()),
    ("subject", pa.string()),
    ("value", pa.float64()),
    ("verdict", pa.string()),
    ("hard", pa.bool_()),
    ("reason", pa.string()),
    ("robot_id", pa.string()),
]
QA_SCHEMA = pa.schema(_QA_FIELDS)


def qa_rows(entries: Sequence[QAEntry]) -> pa.Table:
    rows: dict[str, list[Any]] = {
        name: []
        for name in (
            "bag_uri",
            "episode_index",
            "excluded",
            "check",
            "subject",
            "value",
            "verdict",
            "hard",
            "reason",
            "robot_id",
        )
    }
    for entry in entries:
        for check in entry.qa.checks:
            rows["bag_uri"].append(entry.qa.bag_uri)
            rows["episode_index"].append(entry.episode_index)
            rows["excluded"].append(entry.episode_index is None)
            rows["check"].append(check.check)
            rows["subject"].append(check.subject)
            rows["value"].append(check.value)
            rows["verdict"].append(check.verdict)
            rows["hard"].append(check.hard)
            rows["reason"].append(check.reason)
            robot = entry.metadata.get("robot_id")
            rows["robot_id"].append(None if robot is None else str(robot))
    return pa.table(rows, schema=QA_SCHEMA)


def write_qa(
    root: Path,
    entries: Sequence[QAEntry],
    dataset: dict[str, Any],
    config: dict[str, Any],
    run_number: int = 0,
) -> str:
    """Write the QA table, summary and HTML report under ``root/meta/qa``.

    An append (``run_number`` > 0) adds its own table file and report, and extends the summary.
    Returns the report's path in the dataset (``meta/qa/report[-NNN].html``).
    """
    table_path = root / QA_TABLE_PATH.replace("file-000", f"file-{run_number:03d}")
    table_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(qa_rows(entries), table_path, compression="zstd")
    report_path = (
        QA_REPORT_PATH if run_number == 0 else QA_REPORT_PATH.replace(".html", f"-{run_number:03d}.html")
    )
    summary_path = root / QA_SUMMARY_PATH
    previous = json.loads(summary_path.read_text()) if run_number and summary_path.is_file() else {}
    episodes = [*previous.get("episodes", []), *(e.brief() for e in entries)]
    summary = {
        "episodes": episodes,
        "kept": sum(e["episode_index"] is not None for e in episodes),
        "excluded": sum(e["episode_index"] is None for e in episodes),
        "thresholds": config,
        "reports": [*previous.get("reports", []), report_path.removeprefix("meta/qa/")],
    }
    summary_path.write_text(json.dumps(summary, indent=1))
    (root / report_path).write_text(render_report(entries, dataset), encoding="utf-8")
    return report_path
