"""Jumps against the fleet's own distribution: a data-driven default that needs no declared limit.

Every staged episode keeps, per dimension of each numeric feature, its largest frame-to-frame step
(and the frame it ends at) and a sketch of all its steps. In the reduce, the dataset's merged step
sketches give per dimension the fleet's ``values.step_quantile`` step (0.999 by default: the step that
99.9% of all frames of the dataset stay within); an episode whose largest step is ``values.step_outlier``
times that (10 by default) is warned: a 1 rad single-frame spike on a joint that moves a few mrad per
frame stands out whatever the robot. A dimension that never moves in the fleet (quantile 0) is judged
against :data:`MIN_STEP`, so any jump in it warns.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from bagport.qa.config import ValuesQA
from bagport.qa.result import CheckResult, judge
from bagport.stats import VectorSketch

__all__ = ["MIN_STEP", "step_outlier_checks"]

MIN_STEP = 1e-6
"""The smallest fleet step a ratio is taken against (feature units per frame)."""


def step_outlier_checks(
    largest: Mapping[str, tuple[Sequence[float], Sequence[int]]],
    fleet: Mapping[str, VectorSketch],
    names: Mapping[str, Sequence[str] | None],
    config: ValuesQA,
    fps: int,
) -> list[CheckResult]:
    """One ``values.step_outlier`` check per feature (its worst dimension), for the features the fleet
    has step sketches of."""
    checks = []
    for key, (steps, frames) in largest.items():
        if key not in fleet or (config.step_outlier.warn is None and config.step_outlier.fail is None):
            continue
        typical = np.maximum(np.nan_to_num(fleet[key].quantile(config.step_quantile)), MIN_STEP)
        ratios = np.asarray(steps, dtype=np.float64) / typical
        if not ratios.size:
            continue
        dim = int(np.argmax(ratios))
        labels = names.get(key)
        label = labels[dim] if labels and dim < len(labels) else f"[{dim}]"
        describe = (
            f"largest step of {key} {label} is {steps[dim]:.4g} at frame {frames[dim]} "
            f"({frames[dim] / fps:.2f} s), {ratios[dim]:.3g}x the fleet's {config.step_quantile:g} "
            f"quantile step ({typical[dim]:.3g})"
        )
        checks.append(judge("values.step_outlier", key, float(ratios[dim]), config.step_outlier, describe))
    return checks
