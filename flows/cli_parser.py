"""The ``bagport`` argument parser: every command, option, default and help text, in one place (``convert``'s
run options generated from :class:`~bagport.config.ConvertConfig`'s fields by :mod:`flows.cli_config`).

:mod:`flows.cli` wires each command to its handler; the docs' CLI reference (``docs/cli.md``) is
generated from this parser by :mod:`flows.cli_reference`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping

import annotated_types

from bagport.config import ConvertConfig
from flows.cli_config import POSITIVE_INT, add_config_options, number_type
from flows.cli_push import add_push_command, add_push_options

__all__ = ["Handler", "build_parser"]

Handler = Callable[[argparse.Namespace], int]
type Subparsers = argparse._SubParsersAction[argparse.ArgumentParser]
"""What ``add_subparsers()`` returns (argparse's class is generic to type checkers only; a ``type`` alias is
not evaluated at run time)."""


def build_parser(handlers: Mapping[str, Handler], version: str) -> argparse.ArgumentParser:
    """The `bagport` argument parser, each command calling ``handlers[<command>]`` (the docs' CLI
    reference is generated from it)."""
    parser = argparse.ArgumentParser(prog="bagport", description="ROS bags -> LeRobot v3.0 datasets.")
    parser.add_argument("--version", action="version", version=f"bagport {version}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_convert(sub, handlers["convert"])
    reading_bags = [_add_qa(sub, handlers["qa"]), _add_inspect(sub, handlers["inspect"])]
    _add_dataset_commands(sub, handlers)
    add_push_command(sub)
    reading_bags += _add_contract(sub, handlers)
    _add_synth(sub, handlers["synth"])
    for command in reading_bags:  # convert's is its ConvertConfig field's
        command.add_argument(
            "--msg-path", default=None, help=ConvertConfig.model_fields["msg_path"].description
        )
    return parser


def _add_convert(sub: Subparsers, handler: Handler) -> None:
    convert = sub.add_parser(
        "convert",
        help="convert the bags of a manifest with a contract (Prefect flow)",
        description="Runs the Prefect flow: one task per episode (decode, align to the fps grid, encode, QA), "
        "then the reduce writes the dataset at --output atomically. Every episode is scored by QA: failing "
        "episodes and bags that cannot be converted are left out and listed (--on-qa-fail). A progress bar "
        "shows on a terminal from the first second (0/N as soon as the episodes are known; at N/N it says the "
        "dataset is being written); Prefect's console "
        "lines are off unless --verbose, so each failure prints once (they still reach the Prefect API). The "
        "last line counts this run's episodes (converted, reused from the staging store, with QA warnings, "
        "kept although QA failed them with --on-qa-fail keep, excluded) and what the dataset holds. An "
        "--append whose contract or codec gives other features, fps, robot type or camera encoder settings "
        "than the dataset's meta/info.json is refused before anything converts.",
    )
    convert.add_argument(
        "--config",
        default=None,
        help="a YAML file of run options, keyed as ConvertConfig's fields (manifest, bags_glob, contract, "
        "output, runner, workers, codec, formats...); options given on the command line override it",
    )
    add_config_options(convert)  # one option per ConvertConfig field
    convert.add_argument(
        "--push-to-hub",
        action="store_true",
        help="after converting, push the LeRobot dataset to the Hugging Face Hub as --repo-id (HF_TOKEN from the "
        "environment; see `bagport push`)",
    )
    add_push_options(convert)
    loudness = convert.add_mutually_exclusive_group()
    loudness.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bar and no JSON summary; errors, excluded bags and the one-line summary still print "
        "(on stderr)",
    )
    loudness.add_argument("--verbose", action="store_true", help="show Prefect's flow and task logs")
    convert.set_defaults(func=handler)


def _add_qa(sub: Subparsers, handler: Handler) -> argparse.ArgumentParser:
    qa = sub.add_parser(
        "qa",
        help="score bags against a contract without converting them (no video)",
        description="Scores every episode without converting it (no image decoded, no video encoded): bags are "
        "split into episodes as `convert` splits them (manifest windows, the contract's episodes section), one "
        "line per episode (verdict, score, `bags[i] <bag>#<n> (label)`, what failed), an optional "
        "self-contained HTML report. Exits 1 when an episode that counts fails.",
    )
    qa.add_argument(
        "--manifest", required=True, help="manifest of the bags to score (YAML or CSV), as convert takes"
    )
    qa.add_argument("--contract", required=True, help="contract YAML the episodes are scored against")
    qa.add_argument("--qa", default=None, help="QA thresholds YAML (default: built-in)")
    qa.add_argument("--report", default=None, help="write a self-contained HTML report here")
    qa.add_argument(
        "--workers", type=POSITIVE_INT, default=None, help="bags scored in parallel (default: CPU count)"
    )
    qa.add_argument(
        "--keep-failed",
        action="store_true",
        help="score episodes labelled failed or discarded like the others (default: listed as excluded)",
    )
    qa.set_defaults(func=handler)
    return qa


def _add_inspect(sub: Subparsers, handler: Handler) -> argparse.ArgumentParser:
    inspect = sub.add_parser(
        "inspect",
        help="print what `ros2 bag info` prints, without ROS",
        description="Prints storage, files, size, duration, start/end, and per topic its type, count and mean "
        "rate; whether checksums cover its bytes (Checksums:, with a warning naming the recorder setting that "
        "adds them when none do); any warning about the bag's layout (e.g. a stale metadata.yaml), one line per "
        "problem; for a remote bag, how it was read and the bytes that cost (an MCAP on S3: its summary only); "
        "then every topic whose type no source defines.",
    )
    inspect.add_argument("uri", nargs="+", help="bag folder, .mcap, .db3 or .bag (local or fsspec URI)")
    inspect.set_defaults(func=handler)
    return inspect


def _add_dataset_commands(sub: Subparsers, handlers: Mapping[str, Handler]) -> None:
    """``validate`` and ``repair``: the commands on a written dataset."""
    validate = sub.add_parser(
        "validate",
        help="check checksums, load a dataset with LeRobot and decode every frame",
        description="Says 'needs repair' if a write into the dataset did not finish; checks every file's "
        "SHA-256 against the run record (naming a changed, missing or unrecorded file) and the LeRobot v3.0 "
        "invariants, then loads the dataset with lerobot.LeRobotDataset (offline) and decodes every frame. "
        "Exits 2 with a precise message on the first violation.",
    )
    validate.add_argument("root", help="dataset folder")
    validate.add_argument(
        "--repo-id",
        default=None,
        help="repo id LeRobot loads the dataset under (default: local/<folder name>)",
    )
    validate.add_argument(
        "--every",
        type=POSITIVE_INT,
        default=1,
        help="decode every n-th frame plus each episode's last (default: all)",
    )
    validate.set_defaults(func=handlers["validate"])

    repair = sub.add_parser(
        "repair",
        help="finish or undo a write into a dataset that a crash interrupted, and say what was done",
        description="Finishes or undoes a write into OUT (local or s3://...) that a crash interrupted, from its "
        "intent record (.bagport-journal.json), and prints what it did (or 'nothing to repair'); also removes "
        "temporary folders of dead bagport runs. Every convert does the same first, so a scheduled run never "
        "appends onto an unrecovered dataset. Exits 2 when OUT does not exist, or while another run writes it.",
    )
    repair.add_argument("output", help="dataset folder or URI (as given to convert --output)")
    repair.set_defaults(func=handlers["repair"])


def _add_contract(sub: Subparsers, handlers: Mapping[str, Handler]) -> list[argparse.ArgumentParser]:
    """``contract check`` and ``contract init``, returned (both read bags)."""
    contract = sub.add_parser("contract", help="work with contracts")
    contract_sub = contract.add_subparsers(dest="contract_command", required=True)
    check = contract_sub.add_parser(
        "check",
        help="validate a contract, alone or against bags, and print the feature table",
        description="Validates a contract (file, line, field and fix on error) and prints its feature table: "
        "key, dtype, shape, names, source topics with strategy/stamp/fill. With --bag, also checks every topic "
        "exists with the declared type, that selected joints and fields exist in the first messages, and "
        "resolves shapes and image sizes; the episodes section's event and done-signal topics too.",
    )
    check.add_argument("contract", help="contract YAML")
    check.add_argument("--bag", action="append", help="check against this bag (repeatable)")
    check.set_defaults(func=handlers["contract check"])
    init = contract_sub.add_parser(
        "init",
        help="draft a contract from a bag's topics, for you to edit",
        description="Drafts a contract from a bag's topics: cameras -> observation.images.<name>, joint states "
        "-> observation.state, command-like JointState/Twist topics (cmd, command, target, leader...) and every "
        "JointTrajectory/MultiDOFCommand topic -> action, prompt-like String topics -> tasks; lists what it did "
        "not map. Edit it, then `contract check` it.",
    )
    init.add_argument("--bag", required=True, help="bag to draft from")
    init.add_argument(
        "--out", default=None, help="write the draft here, a file that does not exist yet (default: print it)"
    )
    init.add_argument("--robot-type", default="my_robot", help="the draft's robot_type (default: my_robot)")
    init.add_argument(
        "--fps", type=POSITIVE_INT, default=30, help="the draft's frames per second (default: 30)"
    )
    init.set_defaults(func=handlers["contract init"])
    return [check, init]


def _add_synth(sub: Subparsers, handler: Handler) -> None:
    synth = sub.add_parser(
        "synth",
        help="write a synthetic fleet of bags with known ground truth",
        description="Writes a synthetic fleet of bags with known ground truth (MCAP folder, SQLite folder and "
        "ROS 1 .bag in turn), plus DIR/manifest.yaml.",
    )
    synth.add_argument("--out", required=True, help="folder for the bags and manifest.yaml")
    synth.add_argument("--episodes", type=POSITIVE_INT, default=4, help="bags to write (default: 4)")
    synth.add_argument(
        "--duration", type=number_type(float, annotated_types.Gt(0)), default=3.0, help="seconds per episode"
    )
    synth.add_argument(
        "--seed", type=int, default=0, help="first random seed; bag i uses seed + i (default: 0)"
    )
    synth.set_defaults(func=handler)
