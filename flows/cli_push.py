"""``bagport push`` and the push options ``convert --push-to-hub`` shares (see :mod:`bagport.hub`)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bagport.errors import PushError

if TYPE_CHECKING:
    from bagport.hub import ProvenanceChoice

__all__ = ["add_push_command", "add_push_options", "hf_token", "push_from_args"]


def hf_token() -> str:
    token = os.environ.get("HF_TOKEN", "")
    if not token:
        raise PushError(
            "HF_TOKEN is not set; nothing was pushed. Fix: export HF_TOKEN=<a write token of your Hugging Face "
            "account> (it is read from the environment only, never from an option, and never printed)."
        )
    return token


def push_from_args(root: str, repo_id: str, args: argparse.Namespace) -> int:
    from bagport.hub import push_dataset  # noqa: PLC0415 - keep `--help` fast

    provenance: ProvenanceChoice = (
        "excluded" if args.exclude_provenance else "full" if args.full_provenance else "redacted"
    )
    report = push_dataset(
        Path(root),
        repo_id,
        token=hf_token(),
        private=True if args.private else None,
        revision=args.revision,
        provenance=provenance,
    )
    print(report.summary(), file=sys.stderr)
    return 0


def _cmd_push(args: argparse.Namespace) -> int:
    return push_from_args(args.root, args.repo_id, args)


def add_push_options(command: argparse.ArgumentParser) -> None:
    command.add_argument("--private", action="store_true", help="create the Hub repo private")
    command.add_argument("--revision", default=None, help="push to this branch (default: main)")
    choice = command.add_mutually_exclusive_group()
    choice.add_argument(
        "--exclude-provenance",
        action="store_true",
        help="do not publish meta/provenance (the QA record redacted)",
    )
    choice.add_argument(
        "--full-provenance",
        action="store_true",
        help="publish meta/provenance and meta/qa as written, with bag paths and manifest metadata "
        "(default: a redacted copy, paths reduced to bag names, metadata removed)",
    )


def add_push_command(sub: Any) -> None:
    push = sub.add_parser(
        "push",
        help="upload a LeRobot dataset to the Hugging Face Hub (HF_TOKEN from the environment)",
        description="Uploads the LeRobot dataset at OUT (a local folder) to the Hugging Face Hub as LeRobot's own "
        "push_to_hub does: the dataset card, the v3.0 tag LeRobot's loader looks for, meta/provenance and the "
        "QA report (redacted by default: bag paths reduced to their names, manifest metadata dropped). "
        "HF_TOKEN is read from the environment and never logged. `convert --push-to-hub` does the same after "
        "converting.",
    )
    push.add_argument("root", help="dataset folder (local)")
    push.add_argument("--repo-id", required=True, help="Hub dataset repo, ORG/NAME")
    add_push_options(push)
    push.set_defaults(func=_cmd_push)
