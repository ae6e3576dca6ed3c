"""``bagport convert --config run.yaml``: one file of run options (ConvertConfig's fields), the command line
overriding it; and every ConvertConfig field can be set from the command line."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from bagport.config import ConvertConfig
from bagport.dataset.validate import validate_dataset
from bagport.errors import BagportError
from bagport.synth import EpisodeSpec, write_episode_bag
from flows.cli import build_parser, main
from flows.cli_config import CONFIG_FIELDS, convert_config, load_encoder
from tests.helpers import SAMPLE_CONTRACT


def _config(argv: list[str]) -> ConvertConfig:
    parser = build_parser()
    return convert_config(parser.parse_args(["convert", *argv]), vars(parser.parse_args(["convert"])))


def test_every_config_field_has_a_command_line_option() -> None:
    reachable = {field for field in CONFIG_FIELDS.values() if field != "codec"} | {"encoder"}
    assert reachable == set(ConvertConfig.model_fields)


def test_the_command_line_overrides_the_file(tmp_path: Path) -> None:
    run = tmp_path / "run.yaml"
    run.write_text(
        yaml.safe_dump(
            {
                "bags_glob": "/fleet/*",
                "contract": "robot.yaml",
                "output": "datasets/robot",
                "runner": "thread",
                "workers": 1,
                "codec": "archival",
                "formats": "lerobot,hdf5",
                "keep_staging": True,
            }
        )
    )
    config = _config(["--config", str(run), "--workers", "2", "--manifest", "m.yaml", "--output", "x"])
    assert (config.manifest, config.bags_glob) == ("m.yaml", None)  # the command line's bag source wins
    assert (config.contract, config.output, config.runner, config.workers) == ("robot.yaml", "x", "thread", 2)
    assert config.encoder == load_encoder("archival")
    assert config.formats == ("lerobot", "hdf5")
    assert config.keep_staging is True  # not given on the command line: the file's value stands
    assert _config(["--contract", "c.yaml", "--output", "o", "--glob", "b/*"]).encoder == load_encoder(None)


def test_a_config_that_is_not_a_mapping_is_one_paragraph(tmp_path: Path) -> None:
    run = tmp_path / "run.yaml"
    run.write_text("- just\n- a list\n")
    with pytest.raises(
        BagportError, match=r"^--config .*run\.yaml: not a YAML mapping of run options.*Fix: "
    ):
        _config(["--config", str(run)])


@pytest.mark.slow
def test_convert_runs_from_a_config_file(tmp_path: Path) -> None:
    for seed in (1, 2):
        write_episode_bag(tmp_path / f"bags/ep{seed}", "mcap", EpisodeSpec(duration_s=0.5, seed=seed))
    run = tmp_path / "run.yaml"
    out = tmp_path / "ds"
    run.write_text(
        yaml.safe_dump(
            {
                "bags_glob": str(tmp_path / "bags/*"),
                "contract": str(SAMPLE_CONTRACT),
                "output": str(out),
                "runner": "thread",
                "workers": 1,
                "on_qa_fail": "keep",
            }
        )
    )
    assert main(["convert", "--config", str(run), "--quiet"]) == 0
    assert validate_dataset(out, repo_id="test/config").episodes == 2
