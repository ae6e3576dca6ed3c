"""JointState without joint names (``name: []``, positions only), as some drivers publish it: selected by
index (``position[0]``), all positions by default; an empty selection is refused with the fix."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from bagport.contract import parse_contract
from bagport.errors import BagportError, ContractError
from bagport.feature_table import describe_features
from tests.bagport.decode.bagwriter import write_bag
from tests.helpers import convert_in_process

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
START_NS = 1_700_000_000_000_000_000
FPS = 10
FRAMES = 10


def _state(t_ns: int, positions: list[float], velocities: list[float]) -> Any:
    return T["sensor_msgs/msg/JointState"](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id=""
        ),
        name=[],
        position=np.array(positions, dtype=np.float64),
        velocity=np.array(velocities, dtype=np.float64),
        effort=np.array([], dtype=np.float64),
    )


def _bag(path: Path, storage: Literal["mcap", "sqlite3"], empty: bool = False) -> Path:
    msgs = []
    for k in range(FRAMES):
        t_ns = START_NS + k * 10**9 // FPS
        positions = [] if empty else [k, 10 + k, -k / 2]
        velocities = [] if empty else [0.5 * k, 1.0, 2.0]
        msgs.append((t_ns, _state(t_ns, positions, velocities)))
    return write_bag(path, storage, TS, [("/joint_states", "sensor_msgs/msg/JointState", msgs)])


def _contract(selector: str = "") -> str:
    return (
        f"robot_type: r\nfps: {FPS}\ndefault_task: t\nobservations:\n"
        "  - key: observation.state\n    topic: /joint_states\n    type: sensor_msgs/msg/JointState\n"
        "    align: {strategy: hold, stamp: receive}\n" + (f"    selector: {selector}\n" if selector else "")
    )


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_positions_by_index_through_the_pipeline(tmp_path: Path, storage: Literal["mcap", "sqlite3"]) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    bag = _bag(tmp_path / "nameless", storage)
    (row,) = describe_features(parse_contract(_contract(), "c.yaml"), str(bag))
    assert (row.shape, row.names) == ((3,), ("position[0]", "position[1]", "position[2]"))
    picked = "{names: ['position[2]', 'velocity[0]']}"
    (row,) = describe_features(parse_contract(_contract(picked), "c.yaml"), str(bag))
    assert (row.shape, row.names) == ((2,), ("position[2]", "velocity[0]"))
    out = convert_in_process(str(bag), _contract(picked), tmp_path, repo_id="test/nameless")
    dataset = LeRobotDataset("test/nameless", root=out)
    got = np.stack([dataset[k]["observation.state"].numpy() for k in range(FRAMES)])
    np.testing.assert_allclose(got, [[-k / 2, 0.5 * k] for k in range(FRAMES)], atol=1e-6)
    assert dataset.meta.features["observation.state"]["names"] == ["position[2]", "velocity[0]"]


def test_a_joint_name_on_a_nameless_robot_says_select_by_index(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "nameless", "mcap")
    with pytest.raises(
        ContractError, match=r"the robot publishes no joint names: select by index, e.g. 'position\[0\]'"
    ):
        describe_features(parse_contract(_contract("{names: [position.elbow]}"), "c.yaml"), str(bag))


def test_an_empty_selection_is_refused_by_check_and_convert(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "empty", "mcap", empty=True)
    with pytest.raises(ContractError) as caught:
        describe_features(parse_contract(_contract(), "c.yaml"), str(bag))
    assert str(caught.value) == (
        "c.yaml:5 (observations[key=observation.state].selector): 'observation.state' selects no value: the "
        "first message on /joint_states (sensor_msgs/msg/JointState) has nothing where the default selection "
        f"looks (e.g. a JointState with empty name and position) (first message on /joint_states in {bag}) "
        "Fix: list the values in selector.names: dot paths such as 'position[0]', 'velocity[1]' (by index, "
        "for a JointState without joint names), or drop the entry."
    )
    with pytest.raises(BagportError) as failed:
        convert_in_process(str(bag), _contract(), tmp_path, repo_id="test/empty")
    assert "selects no value" in str(failed.value)
    assert "ArrowInvalid" not in str(failed.value) and "list_size" not in str(failed.value)
