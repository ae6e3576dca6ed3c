"""`bagport qa`: score a manifest's bags (each episode of a bag the contract splits) without converting
them, with an HTML report."""

from __future__ import annotations

from pathlib import Path

import pytest

from bagport.episode.score import score_manifest
from bagport.synth import CameraSpec, EpisodeSpec, Faults, write_episode_bag
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


SESSION = EpisodeSpec(
    duration_s=7.0,
    cameras=(CameraSpec("front", "raw", "bgr8", height=32, width=48), CameraSpec("wrist", "jpeg", height=32, width=48)),
    events=(
        (0.5, "START"), (2.5, "SUCCESS"), (2.7, "RESET"),
        (4.0, "START"), (6.0, '{"event": "FAIL", "note": "dropped the cube"}'), (6.2, "RESET"),
    ),
    faults=Faults(joint_nan_at_s=5.0),  # inside the failed demonstration only
)  # fmt: skip


def test_qa_scores_each_episode_of_a_segmented_bag_and_lists_labelled_ones_as_excluded(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    write_episode_bag(tmp_path / "session", "mcap", SESSION)
    manifest = tmp_path / "m.yaml"
    manifest.write_text("bags:\n  - uri: session\n  - {uri: session, start_s: 4.5, end_s: 5.5}\n")
    contract = tmp_path / "c.yaml"
    contract.write_text(SAMPLE_CONTRACT.read_text() + "episodes:\n  events: {topic: /episode_events}\n")
    argv = ["qa", "--manifest", str(manifest), "--contract", str(contract), "--workers", "1"]
    code = main(argv)
    out, err = capfd.readouterr()
    session = str(tmp_path / "session")
    lines = out.splitlines()
    assert len(lines) == 3, out
    assert lines[0].split()[0] in ("pass", "warn")  # the NaN is not in this episode: scored on its own
    assert f"bags[0] {session}#0 (success): " in lines[0]
    assert lines[1].startswith("fail ")
    assert f"bags[0] {session}#1 (failed): excluded: labelled failed (dropped the cube)" in lines[1]
    assert lines[2].startswith("fail ")  # a manifest window is scored alone, and is not split again
    assert f"bags[1] {session}: " in lines[2] and "values.non_finite observation.state" in lines[2]
    assert code == 1
    assert "1 of 2 episode(s) pass QA (1 more excluded for their label)" in err

    entries = score_manifest(str(manifest), str(contract), workers=1, keep_failed=True)
    assert [(e.manifest_entry, e.segment, e.label, e.by_label) for e in entries] == [
        (0, 0, "success", False),
        (0, 1, "failed", False),
        (1, None, None, False),
    ]
    assert entries[0].qa.duration_s == pytest.approx(2.0, abs=0.1)
    assert entries[2].qa.duration_s == pytest.approx(1.0, abs=0.1)


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
    before, after = out.splitlines()[:2]
    assert code == 1
    assert not before.startswith("fail"), before  # the NaN at 1.5 s is outside [0, 1.2] s
    assert "content.task_missing" not in out
    assert after.startswith("fail 0.") and "values.non_finite observation.state" in after
