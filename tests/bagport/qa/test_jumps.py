"""The data-driven jump check: a 1 rad spike warns against the fleet's own step distribution, with no
limit declared; the clean episodes of the same fleet pass."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bagport.config import ConvertConfig
from bagport.qa import QAConfig
from bagport.qa.jumps import step_outlier_checks
from bagport.reduce import reduce_run
from bagport.run import plan_run, stage_all
from bagport.stats import VectorSketch
from bagport.synth import CameraSpec, EpisodeSpec, Faults, write_episode_bag
from tests.helpers import FAST_CODEC, SAMPLE_CONTRACT


def test_a_spike_is_judged_against_the_fleet_step_and_named_by_joint() -> None:
    rng = np.random.default_rng(0)
    fleet = VectorSketch.of(np.abs(rng.normal(0, 0.01, size=(5000, 2))))
    values = QAConfig().values
    names = {"observation.state": ("shoulder", "elbow")}
    spike = step_outlier_checks(
        {"observation.state": ([0.02, 1.0], [5, 45])}, {"observation.state": fleet}, names, values, 30
    )
    assert [(c.check, c.verdict, c.hard) for c in spike] == [("values.step_outlier", "warn", False)]
    assert "observation.state elbow" in spike[0].reason and "frame 45 (1.50 s)" in spike[0].reason
    calm = step_outlier_checks(
        {"observation.state": ([0.03, 0.02], [5, 45])}, {"observation.state": fleet}, names, values, 30
    )
    assert [c.verdict for c in calm] == ["pass"]
    off = QAConfig.model_validate({"values": {"step_outlier": {"warn": None}}}).values
    assert (
        step_outlier_checks(
            {"observation.state": ([0.02, 1.0], [5, 45])}, {"observation.state": fleet}, names, off, 30
        )
        == []
    )


@pytest.mark.slow
def test_a_one_radian_spike_warns_by_default_in_a_converted_fleet(tmp_path: Path) -> None:
    camera = (
        CameraSpec("front", "raw", "bgr8", height=24, width=32),
        CameraSpec("wrist", "jpeg", height=24, width=32),
    )
    names = []
    for i in range(5):
        faults = Faults(joint_spike=(1.5, 1.0)) if i == 3 else Faults()
        write_episode_bag(
            tmp_path / f"b{i}",
            "mcap",
            EpisodeSpec(duration_s=3.0, seed=i, cameras=camera, faults=faults, mcap_crcs=True),
        )
        names.append(f"b{i}")
    manifest = tmp_path / "manifest.yaml"
    manifest.write_text("bags:\n" + "".join(f"  - uri: {n}\n" for n in names))
    out = tmp_path / "ds"
    config = ConvertConfig(
        manifest=str(manifest), contract=str(SAMPLE_CONTRACT), output=str(out), encoder=FAST_CODEC
    )
    plan = plan_run(config)
    reduce_run(plan, stage_all(plan))
    episodes = json.loads((out / "meta/qa/summary.json").read_text())["episodes"]
    verdicts = [e["verdict"] for e in episodes]
    assert verdicts == ["pass", "pass", "pass", "warn", "pass"], [e["reason"] for e in episodes]
    assert "values.step_outlier" in episodes[3]["reason"] and "j" in episodes[3]["reason"]
    assert episodes[3]["score"] < 0.9
    table = pd.read_parquet(out / "meta/qa/chunk-000/file-000.parquet")
    ratios = table[table["check"] == "values.step_outlier"].groupby("bag_uri")["value"].max()
    assert ratios.iloc[3] > 20 and max(ratios.drop(ratios.index[3])) < 2  # a wide margin both ways
