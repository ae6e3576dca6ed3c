"""Errors that teach: every contract mistake names the file and line, says what is wrong and how to fix it.

One test per mistake the issue lists; those that need a bag check the contract against one.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bagport.contract import parse_contract
from bagport.errors import ContractError
from bagport.feature_table import describe_features
from bagport.synth import EpisodeSpec, write_episode_bag
from tests.helpers import realbag

FLOAT = "std_msgs/msg/Float64"


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A synthetic arm: /joint_states (j1..j6), cameras, /cmd, /task_prompt."""
    path = tmp_path_factory.mktemp("errors") / "ep"
    write_episode_bag(path, "mcap", EpisodeSpec(duration_s=0.3))
    return str(path)


def _raises(text: str, match: str) -> None:
    with pytest.raises(ContractError, match=match):
        parse_contract(text, "robot.yaml")


def test_unknown_top_level_key_suggests_the_nearest() -> None:
    _raises(
        f"robot_type: r\nfsp: 30\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}}}\n",
        r"^robot\.yaml:2 \(fsp\): unknown field Fix: did you mean 'fps'\?",
    )
    _raises(
        f"robot_type: r\nobservation:\n  - {{key: s, topic: /a, type: {FLOAT}}}\n",
        r"^robot\.yaml:2 \(observation\): unknown field.*did you mean 'observations'\?",
    )


def test_missing_required_field() -> None:
    _raises(
        f"robot_type: r\nfps: 30\nobservations:\n  - key: s\n    type: {FLOAT}\n",
        # the field's advice on its format (topics are absolute) is for a value given, not a key left out
        r"^robot\.yaml:4 \(observations\[0\]\.topic\): required field is missing Fix: add its 'topic:' key; "
        r"see the contract format in docs/contracts\.md\.$",
    )
    _raises(
        "robot_type: r\nactions:\n  - key: action\n    publish: {topic: /cmd}\n",
        r"^robot\.yaml:4 \(actions\[0\]\.publish\.type\): required field is missing Fix: add its 'type:' key",
    )
    _raises(  # a value given that is not a topic keeps the field's advice
        f"robot_type: r\nfps: 30\nobservations:\n  - key: s\n    topic: [a]\n    type: {FLOAT}\n",
        r"^robot\.yaml:5 \(observations\[0\]\.topic\): .* Fix: ROS topic names are absolute",
    )


@pytest.mark.parametrize("fps", ["0", "-5", "29.97", "thirty", "true"])
def test_fps_must_be_a_positive_integer(fps: str) -> None:
    _raises(
        f"robot_type: r\nfps: {fps}\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}}}\n",
        r"^robot\.yaml:2 \(fps\): .* Fix: fps is the dataset's frame rate, a whole number",
    )


def test_fps_above_the_limit_is_refused_at_load() -> None:
    _raises(
        f"robot_type: r\nfps: 100000\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}}}\n",
        r"^robot\.yaml:2 \(fps\): fps 100000 is above 1000 .* Fix: .*from 1 to 1000",
    )
    parse_contract(f"robot_type: r\nfps: 1000\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}}}\n")


@pytest.mark.parametrize(
    ("size", "match"),
    [
        ("[100000, 100000]", r"resize \[100000, 100000\] asks for frames larger than 8192 pixels a side"),
        ("[240, 9000]", r"larger than 8192 pixels a side"),
        ("[0, 320]", r"greater than 0"),
    ],
)
def test_image_resize_is_bounded_at_load(size: str, match: str) -> None:
    text = (
        "robot_type: r\nobservations:\n  - key: observation.images.a\n    topic: /a\n"
        f"    type: sensor_msgs/msg/Image\n    image: {{resize: {size}}}\n"
    )
    _raises(
        text, r"^robot\.yaml:6 \(observations\[0\]\.image\.resize.*\): .*" + match + r".* Fix: image\.resize"
    )
    parse_contract(text.replace(size, "[8192, 8192]"))


def test_key_containing_a_slash() -> None:
    _raises(
        f"robot_type: r\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}}}\n"
        f"  - key: observation/state\n    topic: /b\n    type: {FLOAT}\n",
        r"^robot\.yaml:4 \(observations\[1\]\.key\): feature key 'observation/state' .*must not contain '/'.*"
        r"Fix: use '\.' to structure keys",
    )


def test_image_key_shared_between_topics() -> None:
    _raises(
        "robot_type: r\nobservations:\n"
        "  - {key: observation.images.cam, topic: /a, type: sensor_msgs/msg/Image}\n"
        "  - {key: observation.images.cam, topic: /b, type: sensor_msgs/msg/CompressedImage}\n",
        r"^robot\.yaml:4 \(observation\.images\.cam\): image key 'observation\.images\.cam' is declared on "
        r"several topics \(/a, /b\) Fix: give each camera its own key",
    )


def test_decoder_that_does_not_import() -> None:
    _raises(
        f"robot_type: r\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}}}\n"
        f"  - {{key: s, topic: /b, type: {FLOAT}, decoder: acme_missing.decoders:grip}}\n",
        r"^robot\.yaml:4 \(observations\[key=s\]\.decoder\): decoder module 'acme_missing\.decoders' cannot be "
        r"imported \(ModuleNotFoundError.*Fix: install the package",
    )
    _raises(
        f"robot_type: r\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}, decoder: json:no_such_function}}\n",
        r"^robot\.yaml:3 .*module 'json' has no callable 'no_such_function'",
    )
    _raises(
        f"robot_type: r\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}, decoder: 'os:getcwd'}}\n",
        r"^robot\.yaml:3 .*decoder 'os:getcwd' must accept two positional arguments \(msg, spec\)",
    )


def test_selector_naming_a_joint_no_message_has(bag: str) -> None:
    text = (
        "robot_type: r\nobservations:\n"
        "  - key: observation.state\n"
        "    topic: /joint_states\n"
        "    type: sensor_msgs/msg/JointState\n"
        "    selector: {names: [position.j1, position.elbow]}\n"
    )
    with pytest.raises(
        ContractError,
        match=r"^robot\.yaml:3 \(observations\[key=observation\.state\]\.selector\.names\): no message on "
        r"/joint_states in .* carries all of the joints \['j1', 'elbow'\] \(no message names \['elbow'\]; joint lists "
        r"seen: \['j1', 'j2', 'j3', 'j4', 'j5', 'j6'\]",
    ):
        describe_features(parse_contract(text, "robot.yaml"), bag)


@pytest.mark.parametrize(
    ("path", "message", "missing", "fields"),
    [
        ("twist.linear.q", "geometry_msgs/msg/Twist", "twist", "'linear', 'angular'"),
        ("linear.q", "geometry_msgs/msg/Vector3", "q", "'x', 'y', 'z'"),
    ],
    ids=["top", "nested"],
)
def test_selector_dot_path_naming_a_field_the_message_does_not_have(
    path: str, message: str, missing: str, fields: str
) -> None:
    twist = realbag("rosbag2parquet/base_msgs")  # one real geometry_msgs/msg/Twist on /one_shot/twist
    text = (
        "robot_type: r\nobservations:\n"
        "  - key: observation.state\n"
        "    topic: /one_shot/twist\n"
        "    type: geometry_msgs/msg/Twist\n"
        f"    selector: {{names: [linear.x, {path}]}}\n"
    )
    with pytest.raises(
        ContractError,
        match=rf"^robot\.yaml:3 \(observations\[key=observation\.state\]\.selector\): selector '{re.escape(path)}': "
        rf"{message} has no field '{missing}' \(fields: \[{fields}\]\) \(first message on /one_shot/twist in "
        rf".*base_msgs\) Fix: fix selector\.names in the contract\.$",
    ):
        describe_features(parse_contract(text, "robot.yaml"), str(twist))


def test_type_mismatch_between_contract_and_bag(bag: str) -> None:
    text = (
        "robot_type: r\nobservations:\n"
        f"  - {{key: a, topic: /task_prompt, type: std_msgs/msg/String}}\n"
        f"  - {{key: observation.state, topic: /joint_states, type: {FLOAT}}}\n"
    )
    with pytest.raises(
        ContractError,
        match=r"^robot\.yaml:4 \(observation\.state\.type\): topic /joint_states in bag .* has type "
        r"sensor_msgs/msg/JointState, the contract says std_msgs/msg/Float64 "
        r"Fix: set 'type: sensor_msgs/msg/JointState'",
    ):
        describe_features(parse_contract(text, "robot.yaml"), bag)


def test_tf_lookups_name_a_frame_the_bag_has(bag: str) -> None:
    _raises(
        "robot_type: r\nobservations:\n  - {key: ee, topic: /tf, type: tf2_msgs/msg/TFMessage}\n",
        r"^robot\.yaml:3 \(observations\[key=ee\]\.selector\.child_frame\): 'ee' reads /tf .* say which one",
    )
    _raises(
        f"robot_type: r\nobservations:\n  - {{key: s, topic: /a, type: {FLOAT}, selector: {{child_frame: tool0}}}}\n",
        r"^robot\.yaml:3 .*child_frame / parent_frame only apply to tf2_msgs/msg/TFMessage",
    )


def test_errors_point_into_the_file_on_disk(tmp_path: Path) -> None:
    from bagport.contract import load_contract  # noqa: PLC0415

    path = tmp_path / "team" / "contract.yaml"
    path.parent.mkdir()
    path.write_text(f"robot_type: r\n\n\nobservations:\n  - {{key: a/b, topic: /a, type: {FLOAT}}}\n")
    with pytest.raises(ContractError, match=rf"^{path}:5 \(observations\[0\]\.key\)"):
        load_contract(str(path))


def test_a_key_given_twice_is_refused_at_its_line() -> None:
    """YAML keeps the last of two equal keys without a word; a contract refuses them."""
    text = (
        f"robot_type: r\nfps: 30\nobservations:\n  - key: s\n    topic: /a\n    key: t\n    type: {FLOAT}\n"
    )
    with pytest.raises(
        ContractError, match=r"key 'key' is given twice \(also line 4\).*Fix: keep one 'key:'"
    ) as caught:
        parse_contract(text, "robot.yaml")
    assert (caught.value.file, caught.value.line, caught.value.field) == ("robot.yaml", 6, "observations[0]")


@pytest.mark.parametrize(
    ("section", "entry"),
    [
        (
            "observations",
            f"  - {{key: observation.state, topic: /a, type: {FLOAT}}}\n  - key: observation.state\n",
        ),
        (
            "rewards",
            "  - {key: next.reward, topic: /a, type: std_msgs/msg/Float64, dtype: float32}\n  - key: r\n",
        ),
    ],
)
@pytest.mark.parametrize("dtype", ["int8", "string"])
def test_a_dtype_a_numeric_feature_cannot_have_lists_those_it_can(
    section: str, entry: str, dtype: str
) -> None:
    """The error names the entry that asks for the dtype (line 5, not the key's first entry) and every
    dtype allowed."""
    text = (
        f"robot_type: r\nfps: 30\n{section}:\n{entry}    topic: /b\n    type: {FLOAT}\n    dtype: {dtype}\n"
    )
    with pytest.raises(ContractError) as caught:
        parse_contract(text, "robot.yaml")
    key = "observation.state" if section == "observations" else "r"
    assert (caught.value.file, caught.value.line, caught.value.field) == ("robot.yaml", 5, f"{key}.dtype")
    assert f"dtype '{dtype}' of key '{key}' is not one a numeric feature can have" in str(caught.value)
    allowed = "['bool', 'float16', 'float32', 'float64', 'int16', 'int32', 'int64', 'uint8']"
    assert f"Fix: use one of {allowed}" in str(caught.value)
