"""Publishing a LeRobot dataset on the Hugging Face Hub, the way LeRobot's own ``push_to_hub`` does.

The same calls as ``LeRobotDataset.push_to_hub`` (lerobot 0.6.1): create the dataset repo
(``exist_ok``), the branch when a revision is asked for, upload the folder (``images/`` left out) with
``huggingface_hub``'s ``upload_folder`` (large files go through its LFS/Xet upload), LeRobot's own
dataset card (``create_lerobot_dataset_card``), then move the ``v3.0`` tag LeRobot's loader looks for to
the new commit. One difference: the card is committed with the files in one commit, where LeRobot
makes a second one (``DatasetCard.push_to_hub`` validates the card against huggingface.co itself,
whatever the endpoint; the commit validates it against the endpoint in use).

What is published of ``meta/provenance`` and ``meta/qa`` is the caller's choice
(:mod:`bagport.hub.redact`). The token is passed in and never written or logged; an error message from
the Hub is scrubbed of it before it is raised.
"""

from __future__ import annotations

import json
import re
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bagport.dataset.layout import CODEBASE_VERSION, INFO_PATH
from bagport.errors import PushError
from bagport.hub.redact import ProvenanceChoice, publish_view
from bagport.scratch import scratch_folder

__all__ = ["PushReport", "check_repo_id", "push_dataset"]

_PROVENANCE_WORDS = {
    "full": "included as written (bag paths and manifest metadata)",
    "redacted": "redacted (bag, manifest and contract paths reduced to their names; manifest metadata removed)",
    "excluded": "left out (meta/provenance not pushed; the QA record redacted)",
}


_REPO_PART = r"[A-Za-z0-9](?:[A-Za-z0-9._-]{0,94}[A-Za-z0-9])?"
_REPO_ID = re.compile(rf"{_REPO_PART}/{_REPO_PART}")
"""A Hub dataset repo id as bagport pushes it: ``ORG/NAME``, each part letters, digits, ``-``, ``_`` and ``.``,
starting and ending with a letter or digit (the Hub's own rules, which ``huggingface_hub`` checks too)."""


def check_repo_id(repo_id: str) -> None:
    """Refuse a repo id that is not ``ORG/NAME`` before anything is converted or uploaded: without the
    organisation the Hub would put the dataset under whichever account the token belongs to."""
    if _REPO_ID.fullmatch(repo_id) is None or "--" in repo_id or ".." in repo_id:
        raise PushError(
            f"--repo-id {repo_id!r} is not a Hub dataset repo id ORG/NAME; nothing was pushed. Fix: give the "
            "organisation (or user) and the dataset's name, letters, digits, '-', '_' and '.', such as "
            "my-lab/pick-cube."
        )


@dataclass(frozen=True, slots=True)
class PushReport:
    repo_id: str
    revision: str
    commit_url: str
    tag: str
    files: tuple[str, ...]
    provenance: ProvenanceChoice
    private: bool | None

    def summary(self) -> str:
        visibility = {True: "private", False: "public", None: "the organisation's default visibility"}
        return (
            f"pushed {len(self.files)} file(s) to dataset {self.repo_id} ({self.revision}; "
            f"{visibility[self.private]}), tagged {self.tag}: {self.commit_url}\n"
            f"provenance: {_PROVENANCE_WORDS[self.provenance]}"
        )


def push_dataset(
    root: Path,
    repo_id: str,
    *,
    token: str,
    private: bool | None = None,
    revision: str | None = None,
    provenance: ProvenanceChoice = "redacted",
    license: str = "apache-2.0",
) -> PushReport:
    """Upload the LeRobot dataset at ``root`` to the Hub's dataset repo ``repo_id``."""
    check_repo_id(repo_id)
    _check_lerobot_dataset(root)
    try:
        import httpx  # noqa: PLC0415 - huggingface_hub's HTTP client
        from huggingface_hub import HfApi  # noqa: PLC0415 - comes with the lerobot extra
        from huggingface_hub.errors import (  # noqa: PLC0415
            HfHubHTTPError,
            OfflineModeIsEnabled,
            RevisionNotFoundError,
        )
        from lerobot.datasets.io_utils import load_info  # noqa: PLC0415
        from lerobot.datasets.utils import create_lerobot_dataset_card  # noqa: PLC0415
    except ImportError as err:
        raise PushError(
            f"push needs LeRobot and huggingface_hub ({err}). Fix: pip install 'bagport[lerobot]'."
        ) from err
    api: Any = HfApi(token=token)
    try:
        with scratch_folder("push") as tmp:
            view = Path(tmp)
            files = publish_view(root, view, provenance)
            card = create_lerobot_dataset_card(dataset_info=load_info(root), license=license, repo_id=repo_id)
            (view / "README.md").write_text(str(card), encoding="utf-8")
            api.create_repo(repo_id=repo_id, private=private, repo_type="dataset", exist_ok=True)
            if revision:
                api.create_branch(repo_id=repo_id, branch=revision, repo_type="dataset", exist_ok=True)
            commit = api.upload_folder(
                repo_id=repo_id,
                folder_path=view,
                repo_type="dataset",
                revision=revision,
                commit_message=f"bagport: LeRobot {CODEBASE_VERSION} dataset ({len(files)} files)",
            )
            with suppress(RevisionNotFoundError):
                api.delete_tag(repo_id, tag=CODEBASE_VERSION, repo_type="dataset")
            api.create_tag(repo_id, tag=CODEBASE_VERSION, revision=revision, repo_type="dataset")
    except HfHubHTTPError as err:
        raise PushError(
            f"the Hub refused the push of {root} to {repo_id}: {_scrubbed(err, token)}. Fix: check that HF_TOKEN "
            "is a write token of an account that may create or write dataset repos in that organisation."
        ) from None
    except OfflineModeIsEnabled:
        raise PushError(
            f"HF_HUB_OFFLINE is set, so huggingface_hub may not reach the Hub; nothing of {root} was pushed. "
            "Fix: run the push with HF_HUB_OFFLINE unset (or 0); bagport's scripts/env.sh sets it for its tests "
            "and demo."
        ) from None
    except httpx.TransportError as err:
        raise PushError(
            f"the Hub could not be reached to push {root} to {repo_id} ({type(err).__name__}: "
            f"{_scrubbed(err, token)}); the push may have stopped part-way, the dataset's v3.0 tag only moves "
            "when it completes. Fix: check the network (and HF_ENDPOINT, if set), then push again."
        ) from None
    return PushReport(
        repo_id,
        revision or "main",
        str(commit.commit_url),
        CODEBASE_VERSION,
        tuple(sorted([*files, "README.md"])),
        provenance,
        private,
    )


def _scrubbed(err: BaseException, token: str) -> str:
    return str(err).replace(token, "***") if token else str(err)


def _check_lerobot_dataset(root: Path) -> None:
    """A local LeRobot v3.0 dataset, or a :class:`PushError` saying what ``root`` is instead (another
    ``--format``'s output, whose ``meta/info.json`` names it, or no dataset at all)."""
    info_path = root / INFO_PATH
    if not info_path.is_file():
        raise PushError(
            f"{root} is not a LeRobot dataset (no {INFO_PATH}); nothing was pushed. Fix: give the --output "
            "folder of a finished `bagport convert` (a local folder)."
        )
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise PushError(
            f"{info_path} cannot be read as JSON ({err}); nothing was pushed. Fix: run `bagport validate {root}`, "
            "then restore the dataset or write it again."
        ) from None
    fmt = info.get("format") if isinstance(info, dict) else None
    version = info.get("codebase_version") if isinstance(info, dict) else None
    if version != CODEBASE_VERSION:
        what = (
            f"the {fmt} output of `bagport convert --format`"
            if isinstance(fmt, str)
            else (f"not a LeRobot {CODEBASE_VERSION} dataset (its codebase_version is {version!r})")
        )
        raise PushError(
            f"{root} is {what}; only a LeRobot {CODEBASE_VERSION} dataset is pushed, nothing was. Fix: push the "
            "LeRobot output of the run (its --output folder)."
        )
