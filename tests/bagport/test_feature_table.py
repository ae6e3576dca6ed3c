"""`bagport contract check`: the feature table, alone and resolved against a bag."""

from __future__ import annotations

from pathlib import Path

import pytest

from bagport.contract import load_contract, parse_contract
from bagport.errors import ContractError
from bagport.feature_table import describe_features, format_feature_table
from bagport.synth import EpisodeSpec, write_episode_bag
from flows.cli import main
from tests.helpers import SAMPLE_CONTRACT


def test_table_alone_and_against_a_bag(tmp_path: Path) -> None:
    plan = load_contract(str(SAMPLE_CONTRACT))
    alone = {row.key: row for row in describe_features(plan)}
    assert alone["observation.state"].shape == (6,)
    assert alone["observation.images.front"].shape is None  # size comes from the bag
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=0.3))
    resolved = {row.key: row for row in describe_features(plan, str(tmp_path / "ep"))}
    assert resolved["observation.images.front"].shape == (96, 128, 3)
    assert resolved["action"].names == tuple(f"position.j{i}" for i in range(1, 7))
    text = format_feature_table(plan, list(resolved.values()))
    assert "<- /front/image_raw (sensor_msgs/msg/Image) hold/header/fail" in text


def test_unknown_joint_and_missing_topic_are_caught_before_converting(tmp_path: Path) -> None:
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=0.3))
    plan = parse_contract(SAMPLE_CONTRACT.read_text().replace("position.j6]", "position.elbow]", 1), "c.yaml")
    with pytest.raises(
        ContractError,
        match=r"c\.yaml:6 \(observations\[key=observation\.state\]\.selector\.names\): no message on /joint_states "
        r"in .* carries all of the joints \[.*'elbow'\] \(no message names \['elbow'\]; joint lists seen: "
        r"\['j1', 'j2', 'j3', 'j4', 'j5', 'j6'\]",
    ):
        describe_features(plan, str(tmp_path / "ep"))
    plan = parse_contract(SAMPLE_CONTRACT.read_text().replace("/cmd", "/command"), "c.yaml")
    with pytest.raises(ContractError, match=r"topic /command .* is not in bag"):
        describe_features(plan, str(tmp_path / "ep"))


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_episode_bag(tmp_path / "ep", "ros1", EpisodeSpec(duration_s=0.3))
    assert main(["contract", "check", str(SAMPLE_CONTRACT), "--bag", str(tmp_path / "ep")]) == 0
    out = capsys.readouterr().out
    assert "against" in out
    assert "observation.images.wrist  video  shape=[96, 128, 3]" in out
