"""Message definitions as real bags carry them: ros2idl with ``#include``, definitions that do not match
the recorded bytes (from --msg-path, or embedded). Each either reads, or fails in one paragraph naming
topic, type, where the definition came from and what to do; never a traceback."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from bagport.bags import open_bag
from bagport.contract import parse_contract
from bagport.errors import BagReadError, DecodeError
from bagport.feature_table import describe_features
from flows.cli import main

START_NS = 1_700_000_000_000_000_000
STORE = get_typestore(Stores.ROS2_HUMBLE)
STORE.register(get_types_from_msg("float64 curl\n", "acme_msgs/msg/Finger"))
STORE.register(
    get_types_from_msg(
        "std_msgs/Header header\nacme_msgs/Finger finger\nfloat64 width\n", "acme_msgs/msg/Grip"
    )
)
STORE.register(get_types_from_msg("float64 value\nstring label\n", "acme_msgs/msg/Gauge"))
T = STORE.types

GRIP_IDL = """#include "std_msgs/msg/Header.idl"
#include "acme_msgs/msg/Finger.idl"

module acme_msgs {
  module msg {
    struct Grip {
      std_msgs::msg::Header header;
      acme_msgs::msg::Finger finger;
      double width;
    };
  };
};
"""
FINGER_IDL = """module acme_msgs {
  module msg {
    struct Finger {
      double curl;
    };
  };
};
"""


def _grip(k: int) -> bytes:
    t_ns = START_NS + k * 100_000_000
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id="hand"
    )
    msg = T["acme_msgs/msg/Grip"](header=header, finger=T["acme_msgs/msg/Finger"](curl=-k), width=0.5 * k)
    return bytes(STORE.serialize_cdr(msg, "acme_msgs/msg/Grip"))


def _mcap(path: Path, schemas: dict[str, tuple[str, str, bytes]], messages: dict[str, list[bytes]]) -> Path:
    """A bare .mcap: ``schemas`` is ``{topic: (schema name, encoding, data)}``."""
    with path.open("wb") as handle:
        writer = Writer(handle, compression=CompressionType.NONE)
        writer.start(profile="ros2", library="test")
        channels = {}
        for topic, (name, encoding, data) in schemas.items():
            schema_id = writer.register_schema(name, encoding, data)
            channels[topic] = writer.register_channel(topic, "cdr", schema_id)
        for topic, payloads in messages.items():
            for k, payload in enumerate(payloads):
                t_ns = START_NS + k * 100_000_000
                writer.add_message(channels[topic], log_time=t_ns, data=payload, publish_time=t_ns)
        writer.finish()  # type: ignore[no-untyped-call]
    return path


def _grip_bag(path: Path, finger_schema: bool) -> Path:
    schemas = {"/grip": ("acme_msgs/msg/Grip", "ros2idl", GRIP_IDL.encode())}
    messages = {"/grip": [_grip(k) for k in range(5)]}
    if finger_schema:  # another topic of the bag carries the included type's definition
        schemas["/finger"] = ("acme_msgs/msg/Finger", "ros2idl", FINGER_IDL.encode())
        finger = T["acme_msgs/msg/Finger"](curl=9.0)
        messages["/finger"] = [bytes(STORE.serialize_cdr(finger, "acme_msgs/msg/Finger"))]
    return _mcap(path, schemas, messages)


def _read_grips(bag: Path, definitions: dict[str, str] | None = None) -> list[tuple[float, float, str]]:
    with open_bag(str(bag), msg_definitions=definitions) as reader:
        return [
            (m.msg().width, m.msg().finger.curl, m.msg().header.frame_id) for m in reader.messages(["/grip"])
        ]


WANT = [(0.5 * k, -float(k), "hand") for k in range(5)]


def test_idl_includes_resolve_from_the_bag_and_the_bundled_types(tmp_path: Path) -> None:
    assert _read_grips(_grip_bag(tmp_path / "grip.mcap", finger_schema=True)) == WANT


def test_idl_includes_resolve_from_msg_path(tmp_path: Path) -> None:
    bag = _grip_bag(tmp_path / "grip.mcap", finger_schema=False)
    with open_bag(str(bag)) as reader, pytest.raises(BagReadError) as caught:
        list(reader.messages(["/grip"]))
    assert "(it uses acme_msgs/msg/Finger, which is defined nowhere)" in str(caught.value)
    assert "--msg-path DIR with DIR/acme_msgs/msg/Finger.msg" in str(caught.value)
    assert _read_grips(bag, {"acme_msgs/msg/Finger": "float64 curl\n"}) == WANT


def test_idl_that_does_not_parse_is_one_paragraph_and_msg_path_can_replace_it(tmp_path: Path) -> None:
    broken = GRIP_IDL.replace("double width;", "double width")  # a missing semicolon
    bag = _mcap(
        tmp_path / "broken.mcap",
        {"/grip": ("acme_msgs/msg/Grip", "ros2idl", broken.encode())},
        {"/grip": [_grip(k) for k in range(5)]},
    )
    with open_bag(str(bag)) as reader, pytest.raises(BagReadError) as caught:
        list(reader.messages(["/grip"]))
    assert str(caught.value) == (
        f"{bag}: topic /grip has type acme_msgs/msg/Grip, which cannot be loaded: its embedded idl definition "
        "does not parse (syntax error at character 53, near '{') [topic=/grip] Fix: provide the type's .msg "
        "definition with "
        "--msg-path, or drop the topic from the contract."
    )
    definitions = {
        "acme_msgs/msg/Grip": "std_msgs/Header header\nacme_msgs/Finger finger\nfloat64 width\n",
        "acme_msgs/msg/Finger": "float64 curl\n",
    }
    assert _read_grips(bag, definitions) == WANT


def _gauge_bag(path: Path) -> Path:
    """A custom type the bag does not define (no schema text)."""
    gauge = T["acme_msgs/msg/Gauge"](value=1.5, label="psi")
    payload = bytes(STORE.serialize_cdr(gauge, "acme_msgs/msg/Gauge"))
    return _mcap(path, {"/gauge": ("acme_msgs/msg/Gauge", "", b"")}, {"/gauge": [payload] * 3})


def test_msg_path_definition_that_does_not_fit_the_bytes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = _gauge_bag(tmp_path / "gauge.mcap")
    wrong = tmp_path / "msgs" / "acme_msgs" / "msg"
    wrong.mkdir(parents=True)
    (wrong / "Gauge.msg").write_text("string label\nfloat64 value\n")  # fields in the wrong order
    contract = tmp_path / "c.yaml"
    contract.write_text(
        "robot_type: r\nfps: 10\nobservations:\n"
        "  - {key: observation.gauge, topic: /gauge, type: acme_msgs/msg/Gauge, selector: {names: [value]}}\n"
    )
    with pytest.raises(DecodeError) as caught:
        describe_features(
            parse_contract(contract.read_text(), "c.yaml"),
            str(bag),
            {"acme_msgs/msg/Gauge": (wrong / "Gauge.msg").read_text()},
        )
    message = str(caught.value)
    assert message.startswith(
        f"{bag}: a message of type acme_msgs/msg/Gauge does not match --msg-path (acme_msgs/msg/Gauge.msg) "
        "(the bytes do not fit: Invalid string length"
    )
    assert (
        f"[topic=/gauge, t_ns={START_NS}] Fix: the acme_msgs/msg/Gauge.msg under --msg-path is not" in message
    )
    code = main(["contract", "check", str(contract), "--bag", str(bag), "--msg-path", str(tmp_path / "msgs")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err and "AnyReaderError" not in err, err
    assert "does not match --msg-path (acme_msgs/msg/Gauge.msg)" in err


def test_matching_msg_path_definition_reads(tmp_path: Path) -> None:
    bag = _gauge_bag(tmp_path / "gauge.mcap")
    with open_bag(
        str(bag), msg_definitions={"acme_msgs/msg/Gauge": "float64 value\nstring label\n"}
    ) as reader:
        assert [(m.msg().value, m.msg().label) for m in reader.messages(["/gauge"])] == [(1.5, "psi")] * 3


def test_an_empty_placeholder_definition_of_a_standard_type_reads_with_the_bundled_one(
    tmp_path: Path,
) -> None:
    """A recorder that had no definition for ``rcl_interfaces/msg/Log`` embedded an empty one: the bytes are
    read with the bundled Humble definition (before: "CDR message size mismatch", no topic, no fix)."""
    log = T["rcl_interfaces/msg/Log"](
        stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=2),
        level=20,
        name="talker",
        msg="Publishing: 'Hello, world! 0'",
        file="talker.cpp",
        function="main",
        line=38,
    )
    payload = bytes(STORE.serialize_cdr(log, "rcl_interfaces/msg/Log"))
    bag = _mcap(
        tmp_path / "rosout.mcap",
        {"/rosout": ("rcl_interfaces/msg/Log", "ros2msg", b"")},
        {"/rosout": [payload]},
    )
    with open_bag(str(bag)) as reader:
        (message,) = list(reader.messages(["/rosout"]))
        assert (message.msg().name, message.msg().msg, message.msg().line) == (
            "talker",
            "Publishing: 'Hello, world! 0'",
            38,
        )
