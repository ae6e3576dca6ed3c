"""Contract parsing: Rosetta contracts load unchanged; mistakes point at the line and say the fix."""

from __future__ import annotations

from pathlib import Path

import pytest

from bagport.contract import FeatureKind, load_contract, parse_contract
from bagport.errors import ContractError

REPO = Path(__file__).resolve().parents[3]

ROSETTA_README_EXAMPLE = """\
robot_type: so101
fps: 30
observations:
  - key: observation.state
    topic: /joint_states
    type: sensor_msgs/msg/JointState
    selector:
      names: [position.j1, velocity.j1]
    align:
      strategy: hold
      stamp: header
    qos: {reliability: best_effort, depth: 10}
  - key: observation.images.top
    topic: /camera/image_raw/compressed
    type: sensor_msgs/msg/CompressedImage
    image:
      resize: [224, 224]
actions:
  - key: action
    publish:
      topic: /joint_commands
      type: sensor_msgs/msg/JointState
      qos: {reliability: reliable, depth: 10}
    selector:
      names: [position.j1, position.j2]
    safety_behavior: hold
tasks:
  - key: task
    topic: /task_prompt
    type: std_msgs/msg/String
adjunct:
  - topic: /tf
    type: tf2_msgs/msg/TFMessage
teleop: {leader: something}
timestamp_source: receive
"""


def test_rosetta_example_loads_unchanged() -> None:
    plan = parse_contract(ROSETTA_README_EXAMPLE, "rosetta.yaml")
    assert plan.robot_type == "so101"
    assert plan.fps == 30
    keys = [(f.key, f.kind) for f in plan.features]
    assert keys == [
        ("observation.state", FeatureKind.VECTOR),
        ("observation.images.top", FeatureKind.VIDEO),
        ("action", FeatureKind.VECTOR),
    ]
    action = plan.features[2].sources[0]
    assert action.topic == "/joint_commands"
    assert action.stamp == "receive"  # contract-level timestamp_source applies to actions
    assert plan.features[1].sources[0].resize_hw == (224, 224)
    assert plan.topics() == (
        "/joint_states",
        "/camera/image_raw/compressed",
        "/joint_commands",
        "/task_prompt",
    )


def test_old_field_names_and_ros1_types_are_accepted() -> None:
    text = "name: r\nrate_hz: 15\nobservations:\n  - {key: observation.state, topic: /js, type: sensor_msgs/JointState}\n"
    plan = parse_contract(text)
    assert plan.robot_type == "r"
    assert plan.fps == 15
    assert plan.sources[0].msgtype == "sensor_msgs/msg/JointState"


def test_same_key_concatenates_in_declaration_order() -> None:
    text = """\
robot_type: r
observations:
  - {key: observation.state, topic: /arm, type: sensor_msgs/msg/JointState}
  - {key: observation.state, topic: /gripper, type: std_msgs/msg/Float64}
"""
    plan = parse_contract(text)
    assert len(plan.features) == 1
    assert [s.topic for s in plan.features[0].sources] == ["/arm", "/gripper"]


@pytest.mark.parametrize(
    "path", sorted((REPO / "configs/contracts").glob("*.yaml")), ids=lambda path: str(path.name)
)
def test_every_bundled_contract_loads_and_compiles(path: Path) -> None:
    plan = load_contract(str(path))
    assert plan.features
    if path.name == "sample_robot_episodes.yaml":
        episodes = plan.contract.episodes
        assert episodes is not None
        assert episodes.events is not None
        assert episodes.events.topic == "/episode_events"
        assert episodes.done_signal is not None
        assert episodes.done_signal.topic == "/done"
        assert episodes.gap_s == 2.0
        lines = plan.episode_lines  # a key left out gives its section's line
        assert (lines["events.topic"], lines["events.field"], lines["done_signal.type"]) == (41, 40, 45)


def test_bundled_sample_contract_loads() -> None:
    plan = load_contract(str(REPO / "configs/contracts/sample_robot.yaml"))
    assert {f.key for f in plan.features} == {
        "observation.state",
        "observation.images.front",
        "observation.images.wrist",
        "action",
    }


@pytest.mark.parametrize(
    ("text", "match"),
    [
        pytest.param(
            "fps: 30\nobservations: []\n",
            r"c\.yaml:1 \(robot_type\): required field is missing",
            id="missing-robot-type",
        ),
        pytest.param(
            "robot_type: r\nobservations:\n  - key: observation.state\n    topik: /js\n    type: std_msgs/msg/Float64\n",
            r"c\.yaml:4 \(observations\[0\]\.topik\): unknown field.*did you mean 'topic'",
            id="typo-suggests-fix",
        ),
        pytest.param("robot_type: r\nfps: 0\nobservations: []\n", r"c\.yaml:2 \(fps\)", id="fps-zero"),
        pytest.param(
            "robot_type: r\nobservations:\n  - {key: observation/state, topic: /js, type: std_msgs/msg/Float64}\n",
            r"must not contain '/'",
            id="slash-in-key",
        ),
        pytest.param(
            "robot_type: r\nobservations:\n  - {key: s, topic: js, type: std_msgs/msg/Float64}\n",
            r"absolute ROS topic",
            id="relative-topic",
        ),
        pytest.param("robot_type: r\nobservations: [\n", r"c\.yaml:\d+: is not valid YAML", id="bad-yaml"),
        pytest.param("- just a list\n", r"must be a YAML mapping", id="not-a-mapping"),
        pytest.param("robot_type: r\n", r"declares no features", id="no-features"),
        pytest.param(
            """\
robot_type: r
observations:
  - {key: observation.images.cam, topic: /a, type: sensor_msgs/msg/Image}
  - {key: observation.images.cam, topic: /b, type: sensor_msgs/msg/Image}
""",
            r"image key 'observation.images.cam' is declared on several topics",
            id="shared-image-key",
        ),
        pytest.param(
            "robot_type: r\nobservations:\n  - {key: s, topic: /a, type: std_msgs/msg/Float64, decoder: nope_mod:f}\n",
            r"decoder module 'nope_mod' cannot be imported",
            id="decoder-missing",
        ),
        pytest.param(
            "robot_type: r\nobservations:\n  - {key: s, topic: /a, type: std_msgs/msg/Float64, align: {strategy: asof}}\n",
            r"needs tol_ms",
            id="asof-without-tol",
        ),
    ],
)
def test_contract_errors_name_line_field_and_fix(text: str, match: str) -> None:
    with pytest.raises(ContractError, match=match):
        parse_contract(text, "c.yaml")


def test_missing_contract_file() -> None:
    with pytest.raises(ContractError, match="does not exist"):
        load_contract("/nonexistent/contract.yaml")


def test_a_contract_file_not_text_or_a_folder_says_so_as_the_run_does(tmp_path: Path) -> None:
    """``contract check`` reads the file as ``convert --contract`` does (it said a bare codec error)."""
    latin1 = tmp_path / "c.yaml"
    latin1.write_bytes("robot_type: bras\xe9\n".encode("latin-1"))
    with pytest.raises(
        ContractError, match=r"c\.yaml: file is not UTF-8 text \(the byte at offset 16 is not\).*iconv"
    ):
        load_contract(str(latin1))
    with pytest.raises(
        ContractError, match=r"file cannot be read \(Is a directory\) Fix: check the --contract path"
    ):
        load_contract(str(tmp_path))


def test_episodes_section_and_default_task_are_optional_extensions() -> None:
    assert parse_contract(ROSETTA_README_EXAMPLE, "c.yaml").contract.episodes is None
    text = ROSETTA_README_EXAMPLE + (
        "default_task: fold the towel\n"
        "episodes:\n"
        "  events: {topic: /teleop/status, type: my_msgs/Status, field: status.code, note_field: status.why}\n"
        "  gap_s: 2.5\n"
        "  done_signal: {topic: /done}\n"
    )
    contract = parse_contract(text, "c.yaml").contract
    assert contract.default_task == "fold the towel"
    assert contract.episodes is not None and contract.episodes.events is not None
    assert (contract.episodes.events.type, contract.episodes.events.field) == (
        "my_msgs/msg/Status",
        "status.code",
    )
    assert contract.episodes.gap_s == 2.5
    assert (
        contract.episodes.done_signal is not None
        and contract.episodes.done_signal.type == "std_msgs/msg/Bool"
    )
    assert contract.episodes.min_duration_s == 1.0
    with pytest.raises(ContractError, match=r"episodes.gap.*Fix: did you mean 'gap_s'"):
        parse_contract(ROSETTA_README_EXAMPLE + "episodes: {gap: 2}\n", "c.yaml")
