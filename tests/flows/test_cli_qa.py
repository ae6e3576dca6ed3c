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


def test_qa_scores_a_manifest_window_with_the_contract_default_task(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """As a conversion would: only the entry's window is scored, and `default_task` counts as a task."""
    write_episode_bag(
        tmp_path / "nan.bag", "ros1", EpisodeSpec(duration_s=2.5, faults=Faults(joint_nan_at_s=1.5))
    )
    manifest = tmp_path / "m.yaml"
    manifest.write_text("bags:\n  - uri: nan.bag\n    end_s: 1.2\n  - uri: nan.bag\n    start_s: 1.0\n")
    contract = tmp_path / "c.yaml"
    contract.write_text(SAMPLE_CONTRACT.read_text().split("\ntasks:")[0] + "\ndefault_task: pick\n")
    code = main(["qa", "--manifest", str(manifest), "--contract", str(contract), "--workers", "1"])
    out, _ = capfd.readouterr()
    before, after = out.splitlines()
    assert code == 1
    assert not before.startswith("fail"), before  # the NaN at 1.5 s is outside [0, 1.2] s
    assert "content.task_missing" not in out
    assert after.startswith("fail 0.") and "values.non_finite observation.state" in after
