"""`bagport inspect` on real bags and `bagport validate` on a broken dataset, as a user runs them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from flows.cli import main
from tests.helpers import realbag


def test_inspect_prints_what_ros2_bag_info_prints(capsys: pytest.CaptureFixture[str]) -> None:
    mcap = realbag("rerun_humble_sensors/rosbag2_2025_09_10-13_03_56_0.mcap")
    ros1 = realbag("rosbagjs_turtlesim/example-lz4.bag")
    assert main(["inspect", str(mcap), str(ros1)]) == 0
    out = capsys.readouterr().out
    assert "Storage id:        mcap" in out
    assert "Duration:          5.479618124s" in out
    assert "Topic: /joint_state" in out
    assert "Type: sensor_msgs/msg/JointState" in out
    assert "Count:      15" in out
    assert "Storage id:        ros1" in out
    assert "Topic: /turtle1/pose" in out
    # neither carries checksums: both say so, with the recorder setting that would add them
    assert (
        "Checksums:         none: MCAP without chunk CRCs (rosbag2_2025_09_10-13_03_56_0.mcap was written"
        in out
    )
    assert "Checksums:         none: ROS 1 bags carry no checksums" in out
    assert out.count("Warning:") == 2 and "`noCRC: false`" in out


def test_inspect_of_a_non_bag_is_one_clear_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    junk = tmp_path / "notes.txt"
    junk.write_text("hello")
    assert main(["inspect", str(junk)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bagport inspect: error: ")
    assert "is not a ROS bag" in err
    assert "Traceback" not in err


def test_validate_exits_nonzero_with_the_violation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "ds"
    (root / "meta").mkdir(parents=True)
    (root / "meta/info.json").write_text(json.dumps({"codebase_version": "v2.1"}))
    assert main(["validate", str(root)]) == 2
    err = capsys.readouterr().err
    assert "meta/info.json: missing fields" in err
