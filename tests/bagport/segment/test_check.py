"""`bagport contract check --bag` checks the `episodes` section: topics, types and field paths."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from bagport.contract import parse_contract
from bagport.errors import ContractError
from bagport.feature_table import describe_features, format_feature_table
from bagport.synth import EpisodeSpec, write_episode_bag
from flows.cli import main
from tests.helpers import REPO, SAMPLE_CONTRACT

EPISODES_CONTRACT = REPO / "configs/contracts/sample_robot_episodes.yaml"
SPEC = EpisodeSpec(duration_s=0.5, events=((0.1, "START"), (0.4, "SUCCESS")), done_at_s=(0.3,))


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("episodes") / "bag"
    write_episode_bag(path, "mcap", SPEC)
    return path


def test_the_example_contract_fits_a_bag_with_events_and_done(
    bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["contract", "check", str(EPISODES_CONTRACT), "--bag", str(bag)]) == 0
    out = capsys.readouterr().out
    assert (
        "  episodes  <- events /episode_events (std_msgs/msg/String), done_signal /done (std_msgs/msg/Bool), "
        "gap_s 2, min_duration_s 1" in out
    )


def _contract(episodes: str) -> str:
    """The sample contract (35 lines) with an episodes section from line 36."""
    text = SAMPLE_CONTRACT.read_text()
    assert text.count("\n") == 35
    return text + episodes


@pytest.mark.parametrize(
    ("episodes", "match"),
    [
        pytest.param(
            "episodes:\n  events: {topic: /events}\n",
            r"c\.yaml:37 \(episodes\.events\.topic\): episodes\.events topic /events is not in bag .*; the bag "
            r"has: .*/episode_events \(std_msgs/msg/String\).* Fix: fix the topic name",
            id="events-topic-missing",
        ),
        pytest.param(
            "episodes:\n  done_signal:\n    topic: /done\n    type: std_msgs/msg/Int32\n",
            r"c\.yaml:39 \(episodes\.done_signal\.type\): episodes\.done_signal topic /done in bag .* has type "
            r"std_msgs/msg/Bool, the contract says std_msgs/msg/Int32 Fix: set 'type: std_msgs/msg/Bool'",
            id="done-type-differs",
        ),
        pytest.param(
            "episodes:\n  events:\n    topic: /episode_events\n    field: text\n",
            r"c\.yaml:39 \(episodes\.events\.field\): selector 'text': std_msgs/msg/String has no field 'text' "
            r"\(fields: \['data'\]\) \(first message on /episode_events\)",
            id="events-field-missing",
        ),
        pytest.param(
            "episodes:\n  events:\n    topic: /episode_events\n    note_field: note\n",
            r"c\.yaml:39 \(episodes\.events\.note_field\): selector 'note'.* has no field 'note'",
            id="note-field-missing",
        ),
        pytest.param(
            "episodes:\n  done_signal: {topic: /episode_events, type: std_msgs/msg/String}\n",
            r"c\.yaml:37 \(episodes\.done_signal\.field\): episodes\.done_signal field 'data' of the first "
            r"message on /episode_events is str 'START', not a number or bool Fix: point 'field:' at a bool",
            id="done-not-a-number",
        ),
    ],
)
def test_episode_topics_that_do_not_fit_the_bag_name_file_and_line(
    bag: Path, episodes: str, match: str
) -> None:
    plan = parse_contract(_contract(episodes), "c.yaml")
    with pytest.raises(ContractError, match=match):
        describe_features(plan, str(bag))


def test_a_bag_without_the_done_topic_is_refused_and_no_episodes_section_prints_nothing(
    tmp_path: Path,
) -> None:
    write_episode_bag(tmp_path / "plain", "mcap", replace(SPEC, events=(), done_at_s=()))
    plan = parse_contract(_contract("episodes:\n  done_signal: {topic: /done}\n"), "c.yaml")
    with pytest.raises(
        ContractError, match=r"c\.yaml:37 \(episodes\.done_signal\.topic\): .*/done is not in bag"
    ):
        describe_features(plan, str(tmp_path / "plain"))
    plain = parse_contract(_contract("episodes: {min_duration_s: 2}\n"), "c.yaml")
    rows = describe_features(plain, str(tmp_path / "plain"))
    assert "episodes" not in format_feature_table(plain, rows)
