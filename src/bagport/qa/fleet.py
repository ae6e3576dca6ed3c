"""The fleet QA report: one main page over every episode of a dataset, from a compact per-episode index.

The index (:data:`INDEX_SCHEMA`, one row per episode or excluded bag, written once per run) holds what
the main page needs: verdict, score, the checks that warned or failed, where the bag came from (robot,
folder, day) and whether a detail page exists. The main page is rebuilt from the index after every run,
so an append never reads the old episodes' checks or plots. It shows the run and dataset summary,
verdict counts, warnings and failures per check, a score histogram, breakdowns by robot type, bag
folder and day, the 20 worst episodes, and an episode table that sorts and filters in the browser
(hand-written script, nothing loaded from anywhere). Warned and failed episodes link to their detail
page (:func:`bagport.qa.report.render_episode_page`); a passing one is one row.
"""

from __future__ import annotations

import json
import posixpath
from collections import Counter, defaultdict
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from html import escape
from importlib.resources import files
from typing import Any

import pyarrow as pa

from bagport.qa.plots import score_histogram
from bagport.qa.report import CSS
from bagport.qa.result import QAEntry

__all__ = ["INDEX_SCHEMA", "detail_path", "index_table", "metadata_json", "render_fleet_page"]

_INDEX_FIELDS: list[tuple[str, pa.DataType]] = [
    ("run", pa.int64()),
    ("position", pa.int64()),
    ("manifest_entry", pa.int64()),
    ("episode_index", pa.int64()),
    ("name", pa.string()),
    ("bag_uri", pa.string()),
    ("segment", pa.int64()),
    ("label", pa.string()),
    ("note", pa.string()),
    ("robot_type", pa.string()),
    ("folder", pa.string()),
    ("day", pa.string()),
    ("score", pa.float64()),
    ("verdict", pa.string()),
    ("excluded", pa.bool_()),
    ("excluded_by_label", pa.bool_()),
    ("reason", pa.string()),
    ("duration_s", pa.float64()),
    ("frames", pa.int64()),
    ("video_psnr_min_db", pa.float64()),
    ("video_damaged_frames", pa.int64()),
    ("fails", pa.list_(pa.string())),
    ("warns", pa.list_(pa.string())),
    ("detail", pa.bool_()),
    ("metadata", pa.string()),  # the manifest entry's columns and the recorder's episode_id, as JSON
]
INDEX_SCHEMA = pa.schema(_INDEX_FIELDS)
_VERDICTS = ("pass", "warn", "fail")
_WORST = 20
_BREAKDOWN_ROWS = 30
_REASON_CHARS = 90


def _clipped(text: str, limit: int) -> str:
    """``text`` in at most ``limit`` characters, a cut one ending in an ellipsis (the whole reason is on the
    episode's detail page)."""
    return text if len(text) <= limit else text[: limit - 1].rstrip() + "\u2026"


def detail_path(run: int, position: int) -> str:
    """A detail page's path under ``meta/qa/`` (the script builds the same)."""
    return f"details/run-{run:03d}/{position:06d}.html"


def _day(entry: QAEntry) -> str:
    window = entry.qa.plots.get("window_ns")
    if not window:
        return "unknown"
    return datetime.fromtimestamp(int(window[0]) / 1e9, tz=UTC).strftime("%Y-%m-%d")


def metadata_json(metadata: Mapping[str, Any] | None) -> str | None:
    """An episode's metadata as the index keeps it (``None``: none); an index written before this column
    reads back as ``None`` too."""
    return json.dumps(dict(metadata), separators=(",", ":"), default=str) if metadata else None


def index_table(entries: Sequence[QAEntry], run: int, robot_type: str) -> pa.Table:
    """This run's rows of the index; ``detail`` is true for warned and failed episodes."""
    rows: dict[str, list[Any]] = {name: [] for name in INDEX_SCHEMA.names}
    for position, entry in enumerate(entries):
        brief = entry.brief().to_json()
        values = {
            **{k: brief[k] for k in brief if k in rows},
            "run": run,
            "position": position,
            "name": entry.name + (f" ({entry.label})" if entry.label else ""),
            "robot_type": robot_type,
            "folder": posixpath.dirname(entry.qa.bag_uri.rstrip("/")) or ".",
            "day": _day(entry),
            "fails": sorted({c.check for c in entry.qa.checks if c.verdict == "fail"}),
            "warns": sorted({c.check for c in entry.qa.checks if c.verdict == "warn"}),
            "detail": entry.qa.verdict != "pass",
            "metadata": metadata_json(entry.metadata),
        }
        for name, column in rows.items():
            column.append(values.get(name))
    return pa.table(rows, schema=INDEX_SCHEMA)


def _table(head: Sequence[str], rows: Sequence[Sequence[object]], cls: str = "") -> str:
    header = "".join(f"<th>{escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>" for row in rows)
    return f'<table class="{cls}"><tr>{header}</tr>{body}</table>'


def _share(count: int, total: int) -> str:
    return f"{100 * count / total:.1f}%" if total else "-"


def _breakdown(rows: list[dict[str, Any]], field: str, title: str) -> str:
    groups: dict[str, Counter[str]] = defaultdict(Counter)
    scores: dict[str, float] = defaultdict(float)
    for row in rows:
        groups[row[field]][row["verdict"]] += 1
        groups[row[field]]["excluded"] += int(row["excluded"])
        scores[row[field]] += row["score"]
    ordered = (
        sorted(groups, reverse=True)  # days: the latest first
        if field == "day"
        else sorted(groups, key=lambda g: (-groups[g]["fail"], -groups[g]["warn"], g))
    )
    lines = [
        [escape(g), sum(groups[g][v] for v in _VERDICTS), groups[g]["pass"], groups[g]["warn"], groups[g]["fail"],
         groups[g]["excluded"], f"{scores[g] / max(sum(groups[g][v] for v in _VERDICTS), 1):.2f}"]
        for g in ordered[:_BREAKDOWN_ROWS]
    ]  # fmt: skip
    more = (
        f'<p class="small">{len(ordered) - _BREAKDOWN_ROWS} more, fewest failures</p>'
        if len(ordered) > _BREAKDOWN_ROWS
        else ""
    )
    head = [title, "episodes", "pass", "warn", "fail", "excluded", "mean score"]
    return f'<div class="block"><h3>By {escape(title)}</h3>{_table(head, lines)}{more}</div>'


def _per_check(rows: list[dict[str, Any]]) -> str:
    fails: Counter[str] = Counter(c for r in rows for c in r["fails"])
    warns: Counter[str] = Counter(c for r in rows for c in r["warns"])
    total = len(rows)
    checks = sorted(set(fails) | set(warns), key=lambda c: (-fails[c], -warns[c], c))
    lines = [
        [escape(c), fails[c], _share(fails[c], total), warns[c], _share(warns[c], total)] for c in checks
    ]
    if not lines:
        return "<p>No check warned or failed.</p>"
    return _table(["check", "episodes failed", "share", "episodes warned", "share"], lines)


def _worst(rows: list[dict[str, Any]]) -> str:
    worst = sorted(
        (r for r in rows if r["verdict"] != "pass"), key=lambda r: (r["score"], r["run"], r["position"])
    )
    lines = [
        [f'<a href="{detail_path(r["run"], r["position"])}">{escape(r["name"])}</a>',
         "excluded" if r["episode_index"] is None else r["episode_index"], r["run"], f"{r['score']:.2f}",
         f'<span class="{r["verdict"]}">{r["verdict"]}</span>', escape(_clipped(r["reason"], 200))]
        for r in worst[:_WORST]
    ]  # fmt: skip
    if not lines:
        return "<p>Every episode passed.</p>"
    return _table(["bag", "episode", "run", "score", "verdict", "reason"], lines)


def _data(rows: list[dict[str, Any]]) -> str:
    """The episode table's rows, compact: strings that repeat are indices into lists."""
    lists: dict[str, dict[str, int]] = {"checks": {}, "folders": {}, "days": {}, "robots": {}}

    def ref(kind: str, value: str) -> int:
        return lists[kind].setdefault(value, len(lists[kind]))

    data = [
        [r["run"], r["episode_index"], r["name"], round(r["score"], 3), _VERDICTS.index(r["verdict"]),
         int(r["excluded"]), [ref("checks", c) for c in r["fails"]], [ref("checks", c) for c in r["warns"]],
         ref("folders", r["folder"]), ref("days", r["day"]), ref("robots", r["robot_type"]), int(r["detail"]),
         r["position"], _clipped(r["reason"], _REASON_CHARS) if r["verdict"] != "pass" else ""]
        for r in rows
    ]  # fmt: skip
    payload = {kind: list(values) for kind, values in lists.items()} | {"rows": data}
    return json.dumps(payload, separators=(",", ":")).replace("</", "<\\/")


def render_fleet_page(index: pa.Table, dataset: dict[str, Any], run: int) -> str:
    """The main page over every row of ``index`` (all runs); ``dataset``: facts about the dataset and run."""
    rows = index.to_pylist()
    total = len(rows)
    counts = Counter(r["verdict"] for r in rows)
    excluded = sum(r["excluded"] for r in rows)
    facts = "".join(
        f"<tr><th>{escape(str(k))}</th><td>{escape(str(v))}</td></tr>" for k, v in dataset.items()
    )
    this_run = [r for r in rows if r["run"] == run]
    run_counts = Counter(r["verdict"] for r in this_run)
    verdicts = _table(
        ["verdict", "episodes", "share", "this run"],
        [
            [f'<span class="{v}">{v}</span>', counts[v], _share(counts[v], total), run_counts[v]]
            for v in _VERDICTS
        ]
        + [["excluded", excluded, _share(excluded, total), sum(r["excluded"] for r in this_run)]],
    )
    runs = sorted({r["run"] for r in rows})
    run_options = "".join(f'<option value="{n}">run {n}</option>' for n in runs)
    script = files("bagport.qa").joinpath("fleet.js").read_text(encoding="utf-8")
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>bagport QA report</title>"
        f"<style>{CSS}{_FLEET_CSS}</style></head><body><h1>bagport QA report</h1>"
        f"<p>{total} episode(s) over {len(runs)} run(s); this page covers the whole dataset (run {run} is the "
        f"latest).</p><div class='blocks'><div class='block'><h3>Dataset and run</h3><table>{facts}</table></div>"
        f"<div class='block'><h3>Verdicts</h3>{verdicts}</div>"
        f"<div class='block'><h3>Scores</h3>{score_histogram([r['score'] for r in rows])}</div></div>"
        f"<h2>Warnings and failures per check</h2>{_per_check(rows)}"
        f"<h2>Breakdown</h2><div class='blocks'>{_breakdown(rows, 'robot_type', 'robot type')}"
        f"{_breakdown(rows, 'folder', 'bag folder')}{_breakdown(rows, 'day', 'day')}</div>"
        f"<h2>{_WORST} worst episodes</h2>{_worst(rows)}"
        "<h2>Episodes</h2><div id='controls'>verdict <select id='f-verdict'><option value=''>all</option>"
        "<option>pass</option><option>warn</option><option>fail</option><option>excluded</option></select> "
        "check <select id='f-check'><option value=''>all</option></select> "
        f"run <select id='f-run'><option value=''>all</option>{run_options}</select> "
        "search <input id='f-text' type='search' placeholder='bag, folder, day, check, reason'> "
        "<button id='prev'>&lt;</button> <span id='ep-count'></span> <button id='next'>&gt;</button></div>"
        "<table id='episodes'><thead><tr><th data-col='0'>run</th><th data-col='1'>episode</th>"
        "<th data-col='2'>bag</th><th data-col='3'>score</th><th data-col='4'>verdict</th>"
        "<th data-col='5'>checks warned / failed</th><th data-col='6'>folder</th><th data-col='7'>day</th>"
        "<th data-col='8'>robot</th><th>reason</th></tr></thead><tbody id='ep-body'></tbody></table>"
        f"<script type='application/json' id='qa-data'>{_data(rows)}</script><script>{script}</script>"
        "</body></html>"
    )


_FLEET_CSS = """
.blocks{display:flex;flex-wrap:wrap;gap:24px;align-items:flex-start}.block h3{margin:6px 0}
#episodes th[data-col]{cursor:pointer}#episodes th.sorted-asc::after{content:" \\25B2"}
#episodes th.sorted-desc::after{content:" \\25BC"}#controls{margin:8px 0;font-size:13px}
.chk-fail{color:#c62828}.chk-warn{color:#b35900}
"""
