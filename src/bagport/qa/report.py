"""A self-contained HTML QA report (inline CSS and SVG, no scripts, opens offline).

One table of episodes (score, verdict, what failed), then per episode its checks and
plots: message rate per topic over time with the longest gaps, alignment error
histograms, numeric feature traces and camera brightness, and per camera how the encoded
clip matches its source (with the worst frame beside its source when a video check failed).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from html import escape
from typing import Any

from bagport.qa.result import CheckResult, QAEntry

__all__ = ["render_report"]

_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")
_CSS = """
body{font-family:system-ui,sans-serif;margin:24px;color:#222}
table{border-collapse:collapse;margin:8px 0}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px;text-align:left}
th{background:#f0f0f0}.pass{color:#1a7f37}.warn{color:#b35900}.fail{color:#c62828;font-weight:bold}
.plots{display:flex;flex-wrap:wrap;gap:12px}.plot{border:1px solid #ddd;padding:4px}
.plot h4{margin:2px 0;font-size:12px;font-weight:normal}details{margin:10px 0}summary{cursor:pointer;font-size:15px}
.small{font-size:12px;color:#555}
"""


def _polyline(
    values: Sequence[float], x_step: float, box: tuple[float, float, float, float], colour: str
) -> str:
    x0, y0, lo, hi = box
    span = (hi - lo) or 1.0
    points = " ".join(
        f"{x0 + i * x_step:.1f},{y0 - (v - lo) / span * 100:.1f}"
        for i, v in enumerate(values)
        if math.isfinite(v)
    )
    return f'<polyline fill="none" stroke="{colour}" stroke-width="1.2" points="{points}"/>'


def _line_chart(title: str, series: dict[str, Sequence[float]], x_label: str, x_max: float) -> str:
    data = {k: v for k, v in series.items() if len(v)}
    if not data:
        return ""
    values = [x for v in data.values() for x in v if math.isfinite(x)]
    lo, hi = (min(values), max(values)) if values else (0.0, 1.0)
    length = max(len(v) for v in data.values())
    x_step = 300 / max(length - 1, 1)
    lines = "".join(
        _polyline(v, x_step, (40, 115, lo, hi), _COLOURS[i % len(_COLOURS)])
        for i, v in enumerate(data.values())
    )
    legend = "".join(
        f'<text x="{45 + 75 * (i % 4)}" y="{138 + 10 * (i // 4)}" font-size="9" fill="{_COLOURS[i % len(_COLOURS)]}">'
        f"{escape(str(name))[:14]}</text>"
        for i, name in enumerate(data)
    )
    rows = 1 + (len(data) - 1) // 4
    return (
        f'<div class="plot"><h4>{escape(title)}</h4><svg width="350" height="{135 + 10 * rows}" '
        f'xmlns="http://www.w3.org/2000/svg"><rect x="40" y="15" width="300" height="100" fill="#fafafa" '
        f'stroke="#ccc"/><text x="2" y="20" font-size="9">{hi:.3g}</text><text x="2" y="115" font-size="9">'
        f'{lo:.3g}</text><text x="300" y="127" font-size="9">{x_max:.1f} {escape(x_label)}</text>{lines}{legend}'
        "</svg></div>"
    )


def _histogram(title: str, edges: Sequence[float], counts: Sequence[int]) -> str:
    if not counts:
        return ""
    top = max(*counts, 1)
    width = 300 / len(counts)
    bars = "".join(
        f'<rect x="{40 + i * width:.1f}" y="{115 - c / top * 100:.1f}" width="{width - 1:.1f}" '
        f'height="{c / top * 100:.1f}" fill="#1f77b4"/>'
        for i, c in enumerate(counts)
    )
    return (
        f'<div class="plot"><h4>{escape(title)}</h4><svg width="350" height="135" xmlns="http://www.w3.org/2000/svg">'
        f'<rect x="40" y="15" width="300" height="100" fill="#fafafa" stroke="#ccc"/>{bars}'
        f'<text x="2" y="20" font-size="9">{top}</text><text x="40" y="127" font-size="9">0 ms</text>'
        f'<text x="290" y="127" font-size="9">{edges[-1]:.1f} ms</text></svg></div>'
    )


def _episode_plots(plots: dict[str, Any], duration_s: float) -> str:
    parts = []
    streams: dict[str, Any] = plots.get("streams", {})
    if streams:
        parts.append(
            _line_chart(
                "messages per second, by topic",
                {t: s["rate_hz"] for t, s in streams.items()},
                "s",
                duration_s,
            )
        )
    for name, hist in plots.get("alignment_error_ms", {}).items():
        parts.append(
            _histogram(f"alignment error |tick - source| of {name}", hist["edges_ms"], hist["counts"])
        )
    for key, trace in plots.get("vectors", {}).items():
        dims = list(zip(*trace, strict=False)) if trace else []
        parts.append(
            _line_chart(
                f"{key} (first {len(dims)} dims)", {f"[{i}]": d for i, d in enumerate(dims)}, "s", duration_s
            )
        )
    means = plots.get("image_means", {})
    if means:
        parts.append(_line_chart("camera mean grey level", means, "s", duration_s))
    gaps = [
        f"{escape(topic)}: " + ", ".join(f"{g['ms']:.0f} ms at {g['at_s']:.2f} s" for g in s.get("gaps", []))
        for topic, s in streams.items()
        if s.get("gaps")
    ]
    gap_list = f'<p class="small">Longest gaps: {"; ".join(gaps)}</p>' if gaps else ""
    return f'<div class="plots">{"".join(parts)}</div>{gap_list}'


def _fidelity(clips: dict[str, Any]) -> str:
    """Per camera: how the encoded clip matches its source, and the worst frame when a check failed."""
    if not clips:
        return ""
    rows, pictures = [], []
    for key, c in clips.items():
        rows.append(
            f"<tr><td>{escape(key)}</td><td>{c['frames_decoded']} / {c['frames_expected']}</td>"
            f"<td>{c['sampled_frames']}</td><td>{c['psnr_min_db']}</td><td>{c['psnr_median_db']}</td>"
            f"<td>{c['damaged_frames']}</td><td>{c['copied_frames']}</td><td>{c['worst_frame_index']}</td></tr>"
        )
        if c.get("worst_jpeg_base64"):
            pictures.append(
                f'<figure><img alt="worst frame of {escape(key)}" src="data:image/jpeg;base64,'
                f'{c["worst_jpeg_base64"]}"><figcaption class="small">{escape(key)}, frame '
                f"{c['worst_frame_index']} ({c['worst_psnr_db']} dB): source | encoded clip (both as "
                f"{c['block']} px block means) | encoded clip, damaged blocks outlined in red</figcaption></figure>"
            )
    return (
        "<table><tr><th>camera</th><th>frames in clip / encoded</th><th>checked</th><th>PSNR min dB</th>"
        "<th>PSNR median dB</th><th>damaged</th><th>copies</th><th>worst frame</th></tr>"
        f"{''.join(rows)}</table>{''.join(pictures)}"
    )


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


def render_report(entries: Sequence[QAEntry], dataset: dict[str, Any]) -> str:
    """The whole report as one HTML string."""
    kept = sum(e.episode_index is not None for e in entries)
    facts = "".join(
        f"<tr><th>{escape(str(k))}</th><td>{escape(str(v))}</td></tr>" for k, v in dataset.items()
    )
    rows = []
    for n, entry in enumerate(entries):
        brief = entry.brief()
        index = "excluded" if entry.episode_index is None else str(entry.episode_index)
        rows.append(
            f'<tr><td><a href="#ep{n}">{escape(entry.name)}</a></td>'
            f'<td>{index}</td><td>{entry.qa.score:.2f}</td><td class="{entry.qa.verdict}">{entry.qa.verdict}</td>'
            f"<td>{escape(brief['reason'])}</td></tr>"
        )
    sections = []
    for n, entry in enumerate(entries):
        qa = entry.qa
        body = f"<p class='small'>{escape(qa.error)}</p>" if qa.error else ""
        body += _checks_table(entry) + (_episode_plots(qa.plots, qa.duration_s) if qa.plots else "")
        body += _fidelity(qa.plots.get("fidelity", {}))
        sections.append(
            f'<details id="ep{n}"{" open" if qa.verdict != "pass" else ""}><summary>'
            f'<span class="{qa.verdict}">{qa.verdict}</span> {escape(qa.bag_uri)}{_segment(entry)} — score {qa.score:.2f}, '
            f"{qa.frames} frames, {qa.duration_s:.1f} s</summary>{body}</details>"
        )
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>bagport QA report</title>"
        f"<style>{_CSS}</style></head><body><h1>bagport QA report</h1>"
        f"<p>{kept} of {len(entries)} episode(s) kept.</p><table>{facts}</table>"
        "<h2>Episodes</h2><table><tr><th>bag</th><th>episode</th><th>score</th><th>verdict</th><th>reason</th></tr>"
        f"{''.join(rows)}</table><h2>Details</h2>{''.join(sections)}</body></html>"
    )
