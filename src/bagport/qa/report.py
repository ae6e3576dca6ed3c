"""One episode's QA in HTML (inline CSS and SVG, no scripts, opens offline): its checks, plots
(message rate per topic over time with the longest gaps, alignment error histograms, numeric feature
traces labelled by joint name, camera brightness by camera key), a thumbnail strip per camera, and per
camera how the encoded clip matches its source (with the worst frame beside its source when a video
check failed).

:func:`render_episode_page` is the detail page a dataset's fleet report (:mod:`bagport.qa.fleet`) links
to for each warned or failed episode; :func:`render_report` puts every episode of a small run on one
page (``bagport qa --report``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from html import escape
from typing import Any

from bagport.qa.plots import episode_plots, fidelity_table, thumbnail_strips
from bagport.qa.result import CheckResult, QAEntry

__all__ = ["CSS", "render_episode", "render_episode_page", "render_report"]

Names = Mapping[str, Sequence[str] | None]

CSS = """
body{font-family:system-ui,sans-serif;margin:24px;color:#222}
table{border-collapse:collapse;margin:8px 0}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px;text-align:left}
th{background:#f0f0f0}.pass{color:#1a7f37}.warn{color:#b35900}.fail{color:#c62828;font-weight:bold}
.plots{display:flex;flex-wrap:wrap;gap:12px}.plot{border:1px solid #ddd;padding:4px}
.plot h4{margin:2px 0;font-size:12px;font-weight:normal}details{margin:10px 0}summary{cursor:pointer;font-size:15px}
.small{font-size:12px;color:#555}.legend{font-size:11px;max-width:350px}
.strip h4{margin:6px 0 2px;font-size:12px}.frames{display:flex;gap:4px;flex-wrap:wrap}
.thumb{margin:0;font-size:10px;color:#555;text-align:center}.thumb img{display:block;height:64px}
"""


def _table(checks: Sequence[CheckResult]) -> str:
    rows = "".join(
        f'<tr><td class="{c.verdict}">{c.verdict}</td><td>{escape(c.check)}</td><td>{escape(c.subject)}</td>'
        f"<td>{c.value:.4g}</td><td>{escape(c.reason)}</td></tr>"
        for c in checks
    )
    return f"<table><tr><th>verdict</th><th>check</th><th>subject</th><th>value</th><th>reason</th></tr>{rows}</table>"


def _checks_table(entry: QAEntry) -> str:
    """Failed and warned checks up front; the passed ones folded away."""
    order = {"fail": 0, "warn": 1, "pass": 2}
    problems = sorted(entry.qa.problems, key=lambda c: order[c.verdict])
    passed = [c for c in entry.qa.checks if c.verdict == "pass"]
    html = _table(problems) if problems else ""
    if passed:
        html += f"<details><summary class='small'>{len(passed)} passed check(s)</summary>{_table(passed)}</details>"
    return html


def _segment(entry: QAEntry) -> str:
    """``#n`` and the label of one of several episodes in a bag."""
    if entry.segment is None:
        return ""
    return f"#{entry.segment}" + (f" ({escape(entry.label)})" if entry.label else "")


def render_episode(entry: QAEntry, names: Names | None = None, fps: int | None = None) -> str:
    """The body of one episode's QA: error, checks, plots, thumbnails and video fidelity."""
    qa = entry.qa
    body = f"<p class='small'>{escape(qa.error)}</p>" if qa.error else ""
    body += _checks_table(entry) + (episode_plots(qa.plots, qa.duration_s, names) if qa.plots else "")
    thumbnails = qa.plots.get("thumbnails", {})
    if thumbnails and qa.verdict != "pass":  # a strip per camera where something is to be looked at
        body += "<h3>Cameras</h3>" + thumbnail_strips(thumbnails, fps)
    return body + fidelity_table(qa.plots.get("fidelity", {}))


def _title(entry: QAEntry) -> str:
    qa = entry.qa
    return (
        f'<span class="{qa.verdict}">{qa.verdict}</span> {escape(qa.bag_uri)}{_segment(entry)} — score '
        f"{qa.score:.2f}, {qa.frames} frames, {qa.duration_s:.1f} s"
    )


def render_episode_page(entry: QAEntry, names: Names | None, fps: int | None, back_href: str) -> str:
    """A standalone page for one episode, linking back to the fleet report."""
    index = "excluded" if entry.episode_index is None else f"episode {entry.episode_index}"
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>QA {escape(entry.name)}</title><style>{CSS}</style></head><body>"
        f'<p><a href="{escape(back_href)}">&larr; QA report</a></p><h1>{_title(entry)}</h1>'
        f'<p class="small">{index}; {escape(entry.reason)}</p>'
        f"{render_episode(entry, names, fps)}</body></html>"
    )


def render_report(entries: Sequence[QAEntry], dataset: dict[str, Any], names: Names | None = None) -> str:
    """Every episode on one page (for ``bagport qa --report`` over a manifest)."""
    kept = sum(e.episode_index is not None for e in entries)
    facts = "".join(
        f"<tr><th>{escape(str(k))}</th><td>{escape(str(v))}</td></tr>" for k, v in dataset.items()
    )
    rows = []
    for n, entry in enumerate(entries):
        index = "excluded" if entry.episode_index is None else str(entry.episode_index)
        rows.append(
            f'<tr><td><a href="#ep{n}">{escape(entry.name)}</a></td>'
            f'<td>{index}</td><td>{entry.qa.score:.2f}</td><td class="{entry.qa.verdict}">{entry.qa.verdict}</td>'
            f"<td>{escape(entry.reason)}</td></tr>"
        )
    sections = [
        f'<details id="ep{n}"{" open" if entry.qa.verdict != "pass" else ""}><summary>{_title(entry)}</summary>'
        f"{render_episode(entry, names)}</details>"
        for n, entry in enumerate(entries)
    ]
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>bagport QA report</title>"
        f"<style>{CSS}</style></head><body><h1>bagport QA report</h1>"
        f"<p>{kept} of {len(entries)} episode(s) kept.</p><table>{facts}</table>"
        "<h2>Episodes</h2><table><tr><th>bag</th><th>episode</th><th>score</th><th>verdict</th><th>reason</th></tr>"
        f"{''.join(rows)}</table><h2>Details</h2>{''.join(sections)}</body></html>"
    )
