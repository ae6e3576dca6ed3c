"""`bagport inspect` on real bags and `bagport validate` on a broken dataset, as a user runs them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.writer import Writer

from bagport.dataset import write_dataset
from flows.cli import main
from tests.helpers import realbag, staged_episodes


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


def _bag_with_an_unparsable_service_event(path: Path) -> None:
    """An MCAP whose service-event schema (rosbag2 records services as ``<srv>/_service_event``) does
    not parse: rosbags' parser error spans the whole definition over many lines."""
    definition = (
        "service_msgs/ServiceEventInfo info\n" + "=" * 80 + "\nMSG: service_msgs/ServiceEventInfo\n"
        "uint8 event_type\nbuiltin_interfaces/Time stamp\nchar[16 client_gid\nint64 sequence_number\n"
    )
    with path.open("wb") as handle:
        writer = Writer(handle)
        writer.start(profile="ros2")
        text = writer.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
        event = writer.register_schema(
            "example_interfaces/srv/AddTwoInts_Event", "ros2msg", definition.encode()
        )
        chatter = writer.register_channel("/chatter", "cdr", text)
        writer.register_channel("/add_two_ints/_service_event", "cdr", event)
        writer.add_message(
            chatter, log_time=1, publish_time=1, data=b"\x00\x01\x00\x00\x06\x00\x00\x00hello\x00"
        )
        writer.finish()  # type: ignore[no-untyped-call]


def test_inspect_reports_an_unparsable_type_on_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 21 item 8: the parser's multi-line dump of the definition reached the user."""
    bag = tmp_path / "services.mcap"
    _bag_with_an_unparsable_service_event(bag)
    assert main(["inspect", str(bag)]) == 0
    out = capsys.readouterr().out
    warning = next(line for line in out.splitlines() if "cannot be loaded" in line)
    assert "AddTwoInts_Event" in warning
    assert "syntax error at character" in warning
    assert "near 'char[16 client_gid'" in warning
    assert "int64 sequence_number" not in out  # the rest of the definition is not dumped
    assert "MSG:" not in out


def test_validate_exits_nonzero_with_the_violation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "ds"
    (root / "meta").mkdir(parents=True)
    (root / "meta/info.json").write_text(json.dumps({"codebase_version": "v2.1"}))
    assert main(["validate", str(root)]) == 2
    err = capsys.readouterr().err
    assert "meta/info.json: missing fields" in err


def test_validate_of_a_dataset_whose_video_was_deleted_says_how_to_fix_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The audit's case: `...file-000.mp4: missing, but the run record ... lists it` ended there, no fix."""
    root = tmp_path / "ds"
    write_dataset(staged_episodes(tmp_path, (0.5,)), str(root), robot_type="r")
    video = root / "videos/observation.images.wrist/chunk-000/file-000.mp4"
    video.unlink()
    assert main(["validate", str(root)]) == 2
    err = capsys.readouterr().err
    assert (
        f"{video}: missing, but the run record meta/provenance/run.json lists it. Fix: restore the file"
        in err
    )
    assert "convert the dataset's bags again into a new --output (or --overwrite this one)." in err
    assert "Traceback" not in err
