"""Object-store outputs: a bucket that does not exist is an error before anything is converted, never a
new bucket (on moto's real S3 HTTP endpoint, through s3fs)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from s3fs import S3FileSystem

from bagport.config import ConvertConfig
from bagport.errors import ContractError, DatasetWriteError, ManifestError
from bagport.manifest import load_manifest
from bagport.run import plan_run
from bagport.uris import check_writable, output_fs, read_text
from flows.cli import main
from tests.helpers import SAMPLE_CONTRACT
from tests.s3 import moto_s3


def _manifest(tmp_path: Path) -> Path:
    manifest = tmp_path / "manifest.yaml"
    (tmp_path / "never_read.mcap").write_bytes(b"")  # bags are read by the workers, after these checks
    manifest.write_text("bags:\n  - uri: never_read.mcap\n")
    return manifest


def test_output_in_a_missing_bucket_is_refused_and_no_bucket_is_made(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest = _manifest(tmp_path)
    with moto_s3():
        fs = S3FileSystem()
        fs.mkdir("real-bucket")
        config = ConvertConfig(
            manifest=str(manifest), contract=str(SAMPLE_CONTRACT), output="s3://typo-bucket/out"
        )
        with pytest.raises(
            DatasetWriteError, match=r"s3://typo-bucket/out: the bucket 'typo-bucket' does not exist"
        ):
            plan_run(config)
        staged = config.model_copy(
            update={"output": "s3://real-bucket/out", "staging": "s3://typo-staging/st"}
        )
        with pytest.raises(
            DatasetWriteError, match=r"s3://typo-staging/st: the bucket 'typo-staging'.*Fix: "
        ):
            plan_run(staged)
        plan = plan_run(config.model_copy(update={"output": "s3://real-bucket/out"}))
        assert len(plan.requests) == 1  # an existing bucket passes (the bag is only read later)

        code = main(
            [
                "convert",
                "--manifest",
                str(manifest),
                "--contract",
                str(SAMPLE_CONTRACT),
                "--output",
                "s3://typo-bucket/o",
            ]
        )
        fs.invalidate_cache()
        assert sorted(b.rstrip("/") for b in fs.ls("")) == ["real-bucket"]
    err = capsys.readouterr().err
    assert code == 2
    assert "bagport convert: error: s3://typo-bucket/o: the bucket 'typo-bucket' does not exist" in err
    assert "Traceback" not in err


def test_a_missing_contract_or_qa_file_names_both_places_it_may_come_from(tmp_path: Path) -> None:
    with pytest.raises(ContractError, match=r"contract file does not exist") as err:
        read_text(str(tmp_path / "robot.yaml"), "contract")
    assert "Fix: check the path given as --contract (or contract: in a --config file)" in str(err.value)


def test_a_small_file_that_is_not_text_or_not_a_file_is_one_paragraph(tmp_path: Path) -> None:
    binary = tmp_path / "qa.yaml"
    binary.write_bytes(b"\x89PNG\r\n")
    with pytest.raises(ContractError, match=r"qa file is not UTF-8 text \(the byte at offset 0 is not\)"):
        read_text(str(binary), "qa")
    with pytest.raises(ContractError, match=r"contract file cannot be read \(Is a directory\)"):
        read_text(str(tmp_path), "contract")


def test_an_output_on_a_protocol_fsspec_does_not_know_is_one_paragraph() -> None:
    with pytest.raises(DatasetWriteError, match=r"--output bogus://x/y: fsspec cannot open it .*nothing was"):
        output_fs("bogus://x/y", "--output")


def test_a_local_output_or_staging_that_is_or_lies_under_a_file_is_refused_before_converting(
    tmp_path: Path,
) -> None:
    """Each episode failed to stage with a bare NotADirectoryError; now said once, at the plan."""
    a_file = tmp_path / "notes.txt"
    a_file.write_text("x")
    with pytest.raises(
        DatasetWriteError, match=rf"--output {a_file}/ds lies under {a_file}, which is a file"
    ):
        output_fs(str(a_file / "ds"), "--output")
    with pytest.raises(DatasetWriteError, match=rf"--staging {a_file} is a file; nothing was converted"):
        output_fs(str(a_file), "--staging")
    assert output_fs(str(tmp_path / "new" / "ds"), "--output")[1] == str(tmp_path / "new" / "ds")
    with pytest.raises(DatasetWriteError, match="--output is empty; nothing was converted"):
        output_fs("", "--output")  # it said "error:  already exists"
    assert not [
        p for p in tmp_path.rglob("*") if p.name.startswith(".bagport")
    ]  # the write checks leave nothing


def test_a_local_output_or_staging_nobody_can_write_is_refused_before_converting(tmp_path: Path) -> None:
    """Each episode failed with 'Task run encountered an exception PermissionError' (or FileNotFoundError
    under /proc); now one paragraph at the plan, naming the folder that refused."""
    with pytest.raises(
        DatasetWriteError, match=r"--output /proc/bagport/ds: nothing can be written in /proc \(No such file"
    ):
        check_writable(
            *output_fs("/proc/bagport/ds", "--output"), "/proc/bagport/ds", "--output", beside=True
        )
    with pytest.raises(
        DatasetWriteError, match=r"--staging /proc/st: nothing can be written in /proc.*read-only"
    ):
        check_writable(*output_fs("/proc/st", "--staging"), "/proc/st", "--staging")
    locked = tmp_path / "locked"
    locked.mkdir()
    (locked / "ds").mkdir()
    locked.chmod(0o500)  # the dataset's build folder goes beside it, in its parent
    try:
        if os.geteuid() != 0:  # root writes whatever the mode says
            with pytest.raises(DatasetWriteError, match=rf"nothing can be written in {locked} \(Permission"):
                check_writable(
                    *output_fs(str(locked / "ds"), "--output"), str(locked / "ds"), "--output", beside=True
                )
        check_writable(
            *output_fs(str(locked / "ds"), "--staging"), str(locked / "ds"), "--staging"
        )  # itself only
    finally:
        locked.chmod(0o700)


def test_a_contract_or_manifest_on_a_protocol_fsspec_does_not_know_is_one_paragraph(tmp_path: Path) -> None:
    """Reviewed: `--contract foo://c.yaml` and `--manifest gs://b/m.yaml` (gcsfs not installed) were tracebacks."""
    with pytest.raises(
        ContractError, match=r"foo://c.yaml: contract file cannot be opened: fsspec does not know"
    ):
        read_text("foo://c.yaml", "contract")
    with pytest.raises(ManifestError, match=r"nope://m.yaml: file cannot be opened: fsspec does not know"):
        load_manifest("nope://m.yaml")
