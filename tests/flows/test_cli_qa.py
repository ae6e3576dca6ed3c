"""`bagport qa`: score a manifest's bags without converting them, with an HTML report."""

from __future__ import annotations

from pathlib import Path

import pytest

from bagport.synth import EpisodeSpec, Faults, write_episode_bag
from flows.cli import main
from tests.helpers import SAMPLE_CONTRACT


def test_qa_scores_every_bag_and_exits_1_when_one_fails(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    write_episode_bag(tmp_path / "ok", "mcap", EpisodeSpec(duration_s=2.5))
    write_episode_bag(
        tmp_path / "nan.bag", "ros1", EpisodeSpec(duration_s=2.5, faults=Faults(joint_nan_at_s=1.0))
    )
    manifest = tmp_path / "m.yaml"
    manifest.write_text("bags:\n  - uri: ok\n  - uri: nan.bag\n")
    report = tmp_path / "qa.html"
    argv = ["qa", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT), "--report", str(report)]
    code = main(argv)
    out, err = capfd.readouterr()
    assert code == 1
    lines = out.splitlines()
    assert lines[0].startswith("warn") or lines[0].startswith("pass")
    assert "bags[0]" in lines[0]
    assert lines[1].startswith("fail 0.")
    assert "bags[1]" in lines[1]
    assert "values.non_finite observation.state" in lines[1]
    assert "1 of 2 bag(s) pass QA" in err
    assert "values.non_finite" in report.read_text()
    assert not (tmp_path / "m.staging").exists()
