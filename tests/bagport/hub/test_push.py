"""``bagport push`` and ``convert --push-to-hub`` through the real ``huggingface_hub`` client against a
fake Hub on loopback (``tests/hub.py``): which files, card, branch and tag a push creates, what it
publishes of the provenance, and that the token is in no output, log or file. The fake cannot prove
the Hub itself (its permissions, LFS/Xet uploads, the loader reading the result back)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml

from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from tests.helpers import FAST_CODEC, REPO, SAMPLE_CONTRACT
from tests.hub import FakeHub, fake_hub

pytestmark = pytest.mark.slow

TOKEN = "hf_bagportTestToken0123456789abcdef"
OPERATOR = "ana.operator@example.com"
REPO_ID = "bagport-test/fleet"


@pytest.fixture(scope="module")
def hub() -> Iterator[FakeHub]:
    with fake_hub() as running:
        yield running


def _run(
    root: Path, hub: FakeHub, *args: str, token: str | None = TOKEN, **env_over: str
) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PREFECT_API_URL", "HF_TOKEN")}
    env.update(
        HF_ENDPOINT=hub.endpoint,
        HF_HUB_OFFLINE="0",
        HF_HUB_DISABLE_TELEMETRY="1",
        PREFECT_HOME=str(root / "prefect"),  # its logs and database, searched for the token below
        PREFECT_LOGGING_LEVEL="DEBUG",
    )
    env.update(env_over)
    if token is not None:
        env["HF_TOKEN"] = token
    return subprocess.run(
        [sys.executable, "-m", "flows.cli", *args], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=600, check=False,
    )  # fmt: skip


@pytest.fixture(scope="module")
def converted(
    tmp_path_factory: pytest.TempPathFactory, hub: FakeHub
) -> tuple[Path, subprocess.CompletedProcess[str]]:
    """A fleet converted with ``--push-to-hub --full-provenance`` (a broken bag among them, for the QA record)."""
    root = tmp_path_factory.mktemp("push")
    cameras = (
        CameraSpec("front", "raw", "bgr8", height=32, width=32),
        CameraSpec("wrist", "jpeg", height=32, width=32),
    )
    for i in range(2):
        write_episode_bag(
            root / "fleet" / f"ep{i}", "mcap", EpisodeSpec(duration_s=0.5, seed=i, cameras=cameras)
        )
    (root / "fleet" / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)
    manifest = {
        "bags": [{"uri": "ep0", "metadata": {"operator": OPERATOR}}, {"uri": "broken.mcap"}, {"uri": "ep1"}]
    }
    (root / "fleet" / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    (root / "codec.yaml").write_text(yaml.safe_dump(FAST_CODEC))
    done = _run(
        root, hub, "convert", "--manifest", str(root / "fleet" / "manifest.yaml"), "--contract", str(SAMPLE_CONTRACT),
        "--output", str(root / "ds"), "--codec", str(root / "codec.yaml"), "--runner", "thread", "--workers", "2",
        "--repo-id", "bagport-test/full", "--push-to-hub", "--full-provenance",
    )  # fmt: skip
    assert done.returncode == 1, done.stderr[
        -3000:
    ]  # the broken bag was excluded; the rest converted and pushed
    return root, done


def _dataset_files(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()}


def _assert_token_nowhere(root: Path, *outputs: subprocess.CompletedProcess[str]) -> None:
    for done in outputs:
        assert TOKEN not in done.stdout + done.stderr
    for item in root.rglob("*"):
        if item.is_file():
            assert TOKEN.encode() not in item.read_bytes(), item


def test_convert_push_to_hub_publishes_the_dataset_with_card_and_tag(
    converted: tuple[Path, subprocess.CompletedProcess[str]], hub: FakeHub
) -> None:
    root, done = converted
    assert hub.repos["bagport-test/full"]["type"] == "dataset"
    pushed = hub.files["bagport-test/full@main"]
    assert set(pushed) == _dataset_files(root / "ds") | {"README.md"}
    assert pushed["meta/info.json"] == (root / "ds/meta/info.json").read_bytes()
    assert {"meta/provenance/run.json", "meta/qa/summary.json", "meta/qa/report.html"} <= set(pushed)
    card = pushed["README.md"].decode()
    assert "LeRobot" in card and "data/*/*.parquet" in card and "task_categories:\n- robotics" in card
    assert hub.tags["bagport-test/full"] == {"v3.0": "main"}
    assert OPERATOR.encode() in pushed["meta/provenance/run.json"]  # --full-provenance: as written
    assert "provenance: included as written" in done.stderr
    assert not hub.unknown
    # the token went to the Hub, and nowhere else
    sent = [{k.lower(): v for k, v in headers.items()} for _, _, headers, _ in hub.requests]
    assert sent and all(headers.get("authorization") == f"Bearer {TOKEN}" for headers in sent)
    _assert_token_nowhere(root, done)


def test_push_publishes_a_redacted_provenance_by_default(
    converted: tuple[Path, subprocess.CompletedProcess[str]], hub: FakeHub
) -> None:
    root, _ = converted
    done = _run(root, hub, "push", str(root / "ds"), "--repo-id", REPO_ID, "--private")
    assert done.returncode == 0, done.stderr[-3000:]
    assert hub.repos[REPO_ID]["visibility"] == "private"
    pushed = hub.files[f"{REPO_ID}@main"]
    assert set(pushed) == _dataset_files(root / "ds") | {"README.md"}
    for path in ("meta/provenance/run.json", "meta/qa/summary.json", "meta/qa/report.html"):
        assert str(root).encode() not in pushed[path], path  # no local path left
        assert OPERATOR.encode() not in pushed[path], path
    run = json.loads(pushed["meta/provenance/run.json"])
    assert [e["bag_uri"] for e in run["episodes"]] == ["ep0", "ep1"]
    assert [e["bag_uri"] for e in run["excluded"]] == ["broken.mcap"]
    assert run["manifest"]["uri"] == "manifest.yaml"
    (root / "qa.parquet").write_bytes(pushed["meta/qa/chunk-000/file-000.parquet"])
    assert str(root) not in str(pq.read_table(root / "qa.parquet").to_pylist())
    assert (
        pushed["data/chunk-000/file-000.parquet"]
        == (root / "ds/data/chunk-000/file-000.parquet").read_bytes()
    )
    assert hub.tags[REPO_ID] == {"v3.0": "main"}
    assert "provenance: redacted" in done.stderr and "private" in done.stderr
    _assert_token_nowhere(root, done)


def test_push_to_a_branch_without_provenance_moves_the_tag(
    converted: tuple[Path, subprocess.CompletedProcess[str]], hub: FakeHub
) -> None:
    root, _ = converted
    done = _run(
        root, hub, "push", str(root / "ds"), "--repo-id", REPO_ID, "--revision", "v2", "--exclude-provenance"
    )
    assert done.returncode == 0, done.stderr[-3000:]
    pushed = hub.files[f"{REPO_ID}@v2"]
    assert not [p for p in pushed if p.startswith("meta/provenance/")]
    assert str(root).encode() not in pushed["meta/qa/summary.json"]
    assert "v2" in hub.branches[REPO_ID]
    assert hub.tags[REPO_ID] == {"v3.0": "v2"}  # deleted from main, created on the branch, as LeRobot does
    assert "provenance: left out" in done.stderr
    _assert_token_nowhere(root, done)


def test_push_without_a_token_or_dataset_says_how_to_fix_it(
    converted: tuple[Path, subprocess.CompletedProcess[str]], hub: FakeHub
) -> None:
    root, _ = converted
    done = _run(root, hub, "push", str(root / "ds"), "--repo-id", "bagport-test/none", token=None)
    assert (
        done.returncode == 2
        and "HF_TOKEN is not set; nothing was pushed. Fix: export HF_TOKEN" in done.stderr
    )
    done = _run(root, hub, "push", str(root / "fleet"), "--repo-id", "bagport-test/none")
    assert done.returncode == 2 and "is not a LeRobot dataset (no meta/info.json)" in done.stderr
    assert "bagport-test/none" not in hub.repos


def test_push_refuses_a_bad_repo_id_and_another_formats_output_before_uploading(
    converted: tuple[Path, subprocess.CompletedProcess[str]], hub: FakeHub, tmp_path: Path
) -> None:
    root, _ = converted
    for repo_id in ("fleet", "a/b/c", "-lab/x", "lab/x.", "lab/x..y", "lab/my data"):
        done = _run(root, hub, "push", str(root / "ds"), f"--repo-id={repo_id}")
        assert done.returncode == 2, (repo_id, done.stderr[-2000:])
        assert (
            f"--repo-id {repo_id!r} is not a Hub dataset repo id ORG/NAME; nothing was pushed." in done.stderr
        )
        assert "Traceback" not in done.stderr
    # convert --push-to-hub refuses it before converting anything
    out = tmp_path / "not-written"
    done = _run(
        root, hub, "convert", "--manifest", str(root / "fleet" / "manifest.yaml"), "--contract",
        str(SAMPLE_CONTRACT), "--output", str(out), "--repo-id", "fleet", "--push-to-hub",
    )  # fmt: skip
    assert done.returncode == 2 and "is not a Hub dataset repo id ORG/NAME" in done.stderr, done.stderr[
        -2000:
    ]
    assert not out.exists()
    # an HDF5 (or Robo-DM) output has a meta/info.json of its own: named, not a traceback from LeRobot's reader
    other = tmp_path / "out.hdf5"
    (other / "meta").mkdir(parents=True)
    (other / "meta" / "info.json").write_text(json.dumps({"format": "hdf5", "fps": 30}))
    done = _run(root, hub, "push", str(other), "--repo-id", "bagport-test/other")
    assert done.returncode == 2, done.stderr[-2000:]
    assert (
        f"{other} is the hdf5 output of `bagport convert --format`; only a LeRobot v3.0 dataset is pushed"
        in (done.stderr)
    )
    assert not {"bagport-test/other", "fleet"} & set(hub.repos)


def test_push_says_when_the_hub_cannot_be_reached_or_offline_mode_is_on(
    converted: tuple[Path, subprocess.CompletedProcess[str]], hub: FakeHub
) -> None:
    root, _ = converted
    with socket.socket() as closed:  # a loopback port nothing listens on: connection refused
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    done = _run(
        root,
        hub,
        "push",
        str(root / "ds"),
        "--repo-id",
        "bagport-test/down",
        HF_ENDPOINT=f"http://127.0.0.1:{port}",
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert "the Hub could not be reached to push" in done.stderr and "(ConnectError:" in done.stderr
    assert "Fix: check the network (and HF_ENDPOINT, if set), then push again." in done.stderr
    done = _run(root, hub, "push", str(root / "ds"), "--repo-id", "bagport-test/offline", HF_HUB_OFFLINE="1")
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert "HF_HUB_OFFLINE is set, so huggingface_hub may not reach the Hub" in done.stderr
    assert not {"bagport-test/down", "bagport-test/offline"} & set(hub.repos)
    _assert_token_nowhere(root, done)
