"""Inline SVG charts and pictures for the QA pages (no scripts, no external files)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from html import escape
from typing import Any

import numpy as np

__all__ = [
    "episode_plots",
    "fidelity_table",
    "histogram",
    "line_chart",
    "score_histogram",
    "thumbnail_strips",
]

_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


def _polyline(
    values: Sequence[float], x_step: float, box: tuple[float, float, float, float], colour: str
) -> str:
    x0, y0, lo, hi = box
    span = (hi - lo) or 1.0
    data = np.asarray(values, dtype=np.float64)
    kept = np.flatnonzero(np.isfinite(data))  # a gap in the line where a value is missing
    xs, ys = x0 + kept * x_step, y0 - (data[kept] - lo) / span * 100
    points = " ".join(map("{:.1f},{:.1f}".format, xs.tolist(), ys.tolist()))
    return f'<polyline fill="none" stroke="{colour}" stroke-width="1.2" points="{points}"/>'


def line_chart(title: str, series: Mapping[str, Sequence[float]], x_label: str, x_max: float) -> str:
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
    legend = " ".join(
        f'<span style="color:{_COLOURS[i % len(_COLOURS)]}">&#9632; {escape(str(name))}</span>'
        for i, name in enumerate(data)
    )  # full names (joints, camera keys) in HTML below the chart: they wrap instead of being cut
    return (
        f'<div class="plot"><h4>{escape(title)}</h4><svg width="350" height="135" '
        f'xmlns="http://www.w3.org/2000/svg"><rect x="40" y="15" width="300" height="100" fill="#fafafa" '
        f'stroke="#ccc"/><text x="2" y="20" font-size="9">{hi:.3g}</text><text x="2" y="115" font-size="9">'
        f'{lo:.3g}</text><text x="300" y="127" font-size="9">{x_max:.1f} {escape(x_label)}</text>{lines}'
        f'</svg><div class="legend">{legend}</div></div>'
    )


def histogram(
    title: str, edges: Sequence[float], counts: Sequence[int], unit: str = "ms", colours: Sequence[str] = ()
) -> str:
    if not counts:
        return ""
    top = max(*counts, 1)
    width = 300 / len(counts)
    bars = "".join(
        f'<rect x="{40 + i * width:.1f}" y="{115 - c / top * 100:.1f}" width="{width - 1:.1f}" '
        f'height="{c / top * 100:.1f}" fill="{colours[i] if colours else "#1f77b4"}"/>'
        for i, c in enumerate(counts)
    )
    return (
        f'<div class="plot"><h4>{escape(title)}</h4><svg width="350" height="135" xmlns="http://www.w3.org/2000/svg">'
        f'<rect x="40" y="15" width="300" height="100" fill="#fafafa" stroke="#ccc"/>{bars}'
        f'<text x="2" y="20" font-size="9">{top}</text><text x="40" y="127" font-size="9">{edges[0]:g} {unit}</text>'
        f'<text x="290" y="127" font-size="9">{edges[-1]:g} {unit}</text></svg></div>'
    )


def score_histogram(scores: Sequence[float], bins: int = 20) -> str:
    """Episodes per score bin in [0, 1] (fail below 0.4, warn from 0.5 to 0.9, pass 1)."""
    counts = [0] * bins
    for score in scores:
        counts[min(int(score * bins), bins - 1)] += 1
    colours = [
        "#c62828" if (i + 1) / bins <= 0.4 else "#b35900" if (i + 1) / bins <= 0.9 else "#1a7f37"
        for i in range(bins)
    ]
    title = f"score of {len(scores)} episode(s): fail < 0.4, warn 0.5-0.9, pass 1"
    return histogram(title, [0.0, 1.0], counts, unit="", colours=colours)


def episode_plots(
    plots: dict[str, Any], duration_s: float, names: Mapping[str, Sequence[str] | None] | None = None
) -> str:
    """Rates, alignment, numeric traces (dimensions labelled by ``names[key]``, e.g. joint names) and
    camera brightness (by full camera key)."""
    parts = []
    streams: dict[str, Any] = plots.get("streams", {})
    if streams:
        parts.append(
            line_chart(
                "messages per second, by topic",
                {t: s["rate_hz"] for t, s in streams.items()},
                "s",
                duration_s,
            )
        )
    for name, hist in plots.get("alignment_error_ms", {}).items():
        parts.append(
            histogram(f"alignment error |tick - source| of {name}", hist["edges_ms"], hist["counts"])
        )
    for key, trace in plots.get("vectors", {}).items():
        dims = list(zip(*trace, strict=False)) if trace else []
        labels = list((names or {}).get(key) or [])
        series = {labels[i] if i < len(labels) else f"[{i}]": d for i, d in enumerate(dims)}
        parts.append(line_chart(f"{key} (first {len(dims)} dims)", series, "s", duration_s))
    means = plots.get("image_means", {})
    if means:
        parts.append(line_chart("camera mean grey level", means, "s", duration_s))
    gaps = [
        f"{escape(topic)}: " + ", ".join(f"{g['ms']:.0f} ms at {g['at_s']:.2f} s" for g in s.get("gaps", []))
        for topic, s in streams.items()
        if s.get("gaps")
    ]
    gap_list = f'<p class="small">Longest gaps: {"; ".join(gaps)}</p>' if gaps else ""
    return f'<div class="plots">{"".join(parts)}</div>{gap_list}'


def fidelity_table(clips: dict[str, Any]) -> str:
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


def thumbnail_strips(thumbnails: dict[str, list[dict[str, Any]]], fps: int | None = None) -> str:
    """One strip of small frames per camera, labelled by its full key."""
    strips = []
    for key, frames in thumbnails.items():
        pictures = "".join(
            f'<figure class="thumb"><img alt="{escape(key)} frame {f["frame"]}" '
            f'src="data:image/jpeg;base64,{f["jpeg"]}"><figcaption>frame {f["frame"]}'
            f"{f' ({f["frame"] / fps:.1f} s)' if fps else ''}</figcaption></figure>"
            for f in frames
        )
        strips.append(f'<div class="strip"><h4>{escape(key)}</h4><div class="frames">{pictures}</div></div>')
    return "".join(strips)
