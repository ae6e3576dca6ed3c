"""A write opened and not committed leaves nothing behind: no build folder beside a local output, no
staged prefix or intent record in the object store; the output is as it was."""

from __future__ import annotations

from pathlib import Path

import pytest
import s3fs

from bagport.dataset import write_dataset
from bagport.dataset.files import write_planned_file
from bagport.dataset.session import open_write
from bagport.staging import EpisodeSummary


def test_a_failed_local_write_leaves_no_build_folder(tmp_path: Path, staged: list[EpisodeSummary]) -> None:
    out = tmp_path / "ds"
    write_dataset(staged[:1], str(out), robot_type="r")
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    with (
        pytest.raises(RuntimeError, match="worker lost"),
        open_write(staged[1:], str(out), append=True) as session,
    ):
        write_planned_file(session.plan, session.plan.files[0], session.build)
        assert Path(session.build).parent == tmp_path and any(Path(session.build).rglob("*.parquet"))
        raise RuntimeError("worker lost")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before


def test_a_failed_s3_write_drops_its_staged_uploads_and_record(
    s3_env: dict[str, str], staged: list[EpisodeSummary]
) -> None:
    fs = s3fs.S3FileSystem(endpoint_url=s3_env["AWS_ENDPOINT_URL"])
    fs.mkdir("sessions")
    write_dataset(staged[:1], "s3://sessions/ds", robot_type="r")
    fs.invalidate_cache()
    before = sorted(fs.find("sessions/ds"))
    writing = open_write(staged[1:], "s3://sessions/ds", append=True)
    with pytest.raises(RuntimeError, match="worker lost"), writing as session:
        assert session.remote and "/.bagport-staged-" in session.build
        write_planned_file(session.plan, session.plan.files[0], session.build)
        fs.invalidate_cache()
        assert fs.find(session.build) and fs.exists("sessions/ds/.bagport-journal.json")
        raise RuntimeError("worker lost")
    fs.invalidate_cache()
    assert sorted(fs.find("sessions/ds")) == before
