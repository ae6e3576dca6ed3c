"""The QA pages' line charts: every finite sample is a point where it belongs; missing ones are gaps."""

from __future__ import annotations

import math
import re

from bagport.qa.plots import line_chart


def _points(svg: str) -> list[list[tuple[float, float]]]:
    return [
        [(float(x), float(y)) for x, y in (p.split(",") for p in found.split())]
        for found in re.findall(r'points="([^"]*)"', svg)
    ]


def test_points_are_placed_by_index_and_value_in_the_plot_box() -> None:
    svg = line_chart("joints", {"a": [0.0, 1.0, 2.0], "b": [2.0, math.nan, 0.0]}, "s", 1.0)
    line_a, line_b = _points(svg)
    # x: 40 + i * 300 / (3 - 1); y: 115 - (v - lo) / (hi - lo) * 100 with lo = 0, hi = 2
    assert line_a == [(40.0, 115.0), (190.0, 65.0), (340.0, 15.0)]
    assert line_b == [(40.0, 15.0), (340.0, 115.0)]  # the NaN sample is left out, its place kept


def test_a_flat_or_single_sample_series_stays_in_the_box() -> None:
    (line,) = _points(line_chart("one", {"x": [5.0]}, "s", 0.0))
    assert line == [(40.0, 115.0)]
    (flat,) = _points(line_chart("flat", {"x": [1.0, 1.0, math.inf, 1.0]}, "s", 1.0))
    assert flat == [(40.0, 115.0), (140.0, 115.0), (340.0, 115.0)]
