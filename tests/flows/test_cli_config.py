"""``bagport convert``'s options are generated from ConvertConfig's fields; ``--config run.yaml``: one file
of run options keyed as those fields, the command line overriding it."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
import yaml
from pydantic import Field

from bagport.config import ConvertConfig
from bagport.dataset.validate import validate_dataset
from bagport.errors import BagportError
from bagport.synth import EpisodeSpec, write_episode_bag
from flows.cli import build_parser, main
from flows.cli_config import (
    COMMAND_LINE_ONLY,
    PRESETS,
    add_config_options,
    config_options,
    convert_config,
    load_encoder,
    resolve_options,
)
from flows.cli_reference import render_cli_reference
from tests.helpers import REPO, SAMPLE_CONTRACT


def _config(argv: list[str]) -> ConvertConfig:
    parser = build_parser()
    return convert_config(parser.parse_args(["convert", *argv]), vars(parser.parse_args(["convert"])))


def _convert_actions() -> dict[str, argparse.Action]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a for a in sub.choices["convert"]._actions}


def test_every_config_field_is_an_option_with_its_description_as_help() -> None:
    actions = _convert_actions()
    for name, field, option in config_options():
        action = actions[option.named or name]
        assert action.option_strings == [option.flag]
        assert field.description and action.help == field.description.replace("%", "%%")
    assert {o.named for _, _, o in config_options() if o.named} == set(PRESETS)  # each preset has a loader


def test_types_choices_and_defaults_come_from_the_fields() -> None:
    actions = _convert_actions()
    assert actions["runner"].choices == ["process", "thread", "dask", "ray"]
    assert actions["runner"].default == "process"
    assert actions["on_qa_fail"].choices == ["exclude", "keep", "fail_run"]
    assert actions["chunks_size"].default == 1000
    workers, size = actions["workers"].type, actions["data_files_size_in_mb"].type
    assert callable(workers) and callable(size) and (workers("3"), size("1.5")) == (3, 1.5)
    assert actions["overwrite"].nargs == 0 and actions["overwrite"].default is False
    assert actions["hdf5_jpeg_quality"].metavar == "QUALITY"
    assert _config(
        ["--glob", "b/*", "--contract", "c", "--output", "o", "--format", "lerobot, hdf5"]
    ).formats == (
        "lerobot",
        "hdf5",
    )
    with pytest.raises(SystemExit):  # a bag source: a manifest or a glob, not both
        build_parser().parse_args(["convert", "--manifest", "m.yaml", "--glob", "b/*"])


def test_a_new_field_becomes_an_option_without_writing_it_again() -> None:
    class Grown(ConvertConfig):
        max_gap_s: float = Field(default=0.5, description="largest gap filled (default: 0.5)")
        dry_run: bool = Field(default=False, description="plan only (100% safe)")

    parser = argparse.ArgumentParser(prog="bagport")
    convert = parser.add_subparsers().add_parser("convert")
    add_config_options(convert, Grown)
    args = parser.parse_args(["convert", "--max-gap-s", "2", "--dry-run", "--glob", "b/*"])
    assert (args.max_gap_s, args.dry_run, args.bags_glob) == (2.0, True, "b/*")
    assert "plan only (100% safe)" in convert.format_help()
    reference = render_cli_reference(parser)
    assert "| `--max-gap-s` `MAX_GAP_S` | `0.5` | largest gap filled (default: 0.5) |" in reference
    assert "| `--dry-run` |  | plan only (100% safe) |" in reference


def test_run_yaml_keys_resolve_as_the_command_line_does() -> None:
    resolved = resolve_options({"codec": "archival", "formats": "hdf5,robodm", "workers": 2})
    assert resolved == {"encoder": load_encoder("archival"), "formats": ("hdf5", "robodm"), "workers": 2}
    assert resolve_options({"formats": ["hdf5"]}) == {"formats": ["hdf5"]}  # a list stays a list


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


def test_an_option_given_at_its_default_still_overrides_the_file(tmp_path: Path) -> None:
    run = tmp_path / "run.yaml"
    run.write_text(
        "bags_glob: /fleet/*\ncontract: c.yaml\noutput: o\nrunner: dask\nchunks_size: 7\nformats: hdf5\n"
    )
    config = _config(
        ["--config", str(run), "--runner", "process", "--chunks-size", "1000", "--format", "lerobot"]
    )
    assert (config.runner, config.chunks_size, config.formats) == ("process", 1000, ("lerobot",))
    assert _config(["--config", str(run)]).runner == "dask"


def test_a_config_that_is_not_a_mapping_is_one_paragraph(tmp_path: Path) -> None:
    run = tmp_path / "run.yaml"
    run.write_text("- just\n- a list\n")
    with pytest.raises(
        BagportError, match=r"^--config .*run\.yaml: not a YAML mapping of run options.*Fix: "
    ):
        _config(["--config", str(run)])


def test_the_command_line_only_options_are_the_convert_options_with_no_field() -> None:
    """COMMAND_LINE_ONLY lists every ``convert`` option that is not a run option, under the key one would
    write for it, and no other."""
    keys = {option.named or name for name, _, option in config_options()}
    others = {
        dest: action.option_strings[-1]
        for dest, action in _convert_actions().items()
        if dest not in keys and dest != "help"
    }
    assert others == COMMAND_LINE_ONLY


@pytest.mark.parametrize(
    ("text", "message"),
    [
        pytest.param(
            "output: o\npush_to_hub: true\n",
            "--config {run}, line 2: push_to_hub is a command-line option only (about the command, not the run: "
            "a run file has no such key). Fix: remove it from the file and give --push-to-hub on the command line.",
            id="push_to_hub",
        ),
        pytest.param(
            "quiet: true\noutput: o\nfull_provenance: true\n",
            "--config {run}: quiet (line 1) and full_provenance (line 3) are command-line options only (about the "
            "command, not the run: a run file has no such key). Fix: remove them from the file and give --quiet "
            "--full-provenance on the command line.",
            id="two",
        ),
    ],
)
def test_a_command_line_only_option_in_the_config_file_names_its_flag(
    tmp_path: Path, text: str, message: str
) -> None:
    """Not pydantic's bare 'Extra inputs are not permitted': the key's line and the flag to give instead."""
    run = tmp_path / "run.yaml"
    run.write_text(text)
    with pytest.raises(BagportError) as caught:
        _config(["--config", str(run)])
    assert str(caught.value) == message.format(run=run)


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


def test_the_example_run_yaml_is_a_valid_config() -> None:
    config = _config(["--config", str(REPO / "configs/run.yaml")])
    assert (config.runner, config.ray_address, config.formats) == (
        "ray",
        "ray://head:10001",
        ("lerobot", "hdf5"),
    )
    assert config.encoder == load_encoder("h264-fast")


def test_a_missing_option_is_named_as_the_user_gives_it(capfd: pytest.CaptureFixture[str]) -> None:
    assert main(["convert", "--manifest", "m.yaml", "--output", "out"]) == 2
    assert "contract: required: give --contract (or contract: in a --config file)" in capfd.readouterr().err
    assert main(["convert", "--contract", "c.yaml", "--output", "out"]) == 2
    assert "give exactly one of --manifest and --glob" in capfd.readouterr().err


def test_push_to_hub_takes_the_repo_id_from_the_config_file(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``repo_id:`` in the run file is the repository a push uses, as ``--repo-id`` is: the run goes on to the
    next check (the token, checked before anything converts)."""
    monkeypatch.delenv("HF_TOKEN", raising=False)
    run = tmp_path / "run.yaml"
    options = {
        "bags_glob": str(tmp_path / "bags/*"),
        "contract": str(SAMPLE_CONTRACT),
        "output": str(tmp_path / "ds"),
    }
    run.write_text(yaml.safe_dump(options))
    assert main(["convert", "--config", str(run), "--push-to-hub"]) == 2
    assert "give --repo-id ORG/NAME (or repo_id: in the --config file)" in capfd.readouterr().err
    run.write_text(yaml.safe_dump({**options, "repo_id": "me/robot"}))
    assert main(["convert", "--config", str(run), "--push-to-hub"]) == 2
    err = capfd.readouterr().err
    assert "HF_TOKEN is not set" in err and "--repo-id" not in err
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize(
    ("argv", "refused"),
    [
        pytest.param(
            ["convert", "--workers", "0"],
            "argument --workers: 0 is not allowed: give 1 or more",
            id="convert",
        ),
        pytest.param(
            ["convert", "--workers", "-2"],
            "argument --workers: -2 is not allowed: give 1 or more",
            id="negative",
        ),
        pytest.param(
            ["convert", "--workers", "two"], "argument --workers: 'two' is not a whole number", id="text"
        ),
        pytest.param(
            ["convert", "--chunks-size", "0"], "argument --chunks-size: 0 is not allowed", id="chunks"
        ),
        pytest.param(
            ["convert", "--data-files-size-in-mb", "0"], "give more than 0", id="float-from-positive-float"
        ),
        pytest.param(
            ["convert", "--hdf5-jpeg", "101"],
            "argument --hdf5-jpeg: 101 is not allowed: give 1 to 100",
            id="range",
        ),
        pytest.param(
            ["qa", "--manifest", "m", "--contract", "c", "--workers", "0"],
            "argument --workers: 0 is not allowed: give 1 or more",
            id="qa",
        ),
        pytest.param(["validate", "d", "--every", "0"], "argument --every: 0 is not allowed", id="validate"),
        pytest.param(
            ["synth", "--out", "s", "--episodes", "0"], "argument --episodes: 0 is not allowed", id="synth"
        ),
        pytest.param(
            ["synth", "--out", "s", "--duration", "-1"],
            "argument --duration: -1 is not allowed: give more than 0",
            id="duration",
        ),
        pytest.param(
            ["contract", "init", "--bag", "b", "--fps", "0"], "argument --fps: 0 is not allowed", id="init"
        ),
    ],
)
def test_a_count_out_of_range_is_refused_by_the_parser(
    argv: list[str], refused: str, capfd: pytest.CaptureFixture[str]
) -> None:
    """``--workers 0`` used to mean 'CPU count' for qa (and -2 'one'): every count, on every command, is
    refused before anything runs, the option named, exit code 2."""
    with pytest.raises(SystemExit) as caught:
        build_parser().parse_args(argv)
    assert caught.value.code == 2
    err = capfd.readouterr().err
    assert refused in err and "Traceback" not in err
