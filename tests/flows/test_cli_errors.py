"""Bad input stops with one clear paragraph (what, where, how to fix) and exit code 2; a bad bag among
good ones is excluded and named (exit code 1)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import flows.cli_commands
from bagport.errors import BagportError, QualityError
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from flows.cli import main
from flows.convert import ConversionError, FlowFailedError
from tests.helpers import REPO, SAMPLE_CONTRACT


def _run(argv: list[str], capfd: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(argv)
    captured = capfd.readouterr()
    assert "Traceback" not in captured.err
    return code, captured.err


def _convert(manifest: Path, contract: Path, out: Path) -> list[str]:
    return ["convert", "--manifest", str(manifest), "--contract", str(contract), "--output", str(out)]


def test_missing_bag_uri(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    manifest = tmp_path / "m.yaml"
    manifest.write_text("bags:\n  - uri: no_such_bag\n")
    code, err = _run(_convert(manifest, SAMPLE_CONTRACT, tmp_path / "out"), capfd)
    assert code == 2
    assert "m.yaml, bags[0]: bag" in err
    assert "no_such_bag' does not exist" in err
    assert "Fix:" in err
    assert not (tmp_path / "out").exists()


def test_a_prefect_home_the_server_cannot_make_is_one_paragraph(tmp_path: Path) -> None:
    """The temporary server cannot make its database's folder (PREFECT_HOME under a file): the server's one
    line and the CLI's paragraph (what to set), exit code 2, no traceback; nothing written."""
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=0.3))
    (tmp_path / "a-file").write_text("")
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env["PREFECT_HOME"] = str(tmp_path / "a-file" / "prefect")
    done = subprocess.run(
        [sys.executable, "-m", "flows.cli", "convert", "--glob", str(tmp_path / "ep"),
         "--contract", str(SAMPLE_CONTRACT), "--output", str(tmp_path / "out")],
        capture_output=True, text=True, check=False, cwd=REPO, env=env, timeout=300,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert f"cannot make its database's folder {tmp_path / 'a-file' / 'prefect'}" in done.stderr
    assert (
        "bagport convert: error: the temporary Prefect server exited (code 1) before it was ready"
        in done.stderr
    )
    assert f"PREFECT_HOME ({tmp_path / 'a-file' / 'prefect'}): make that a folder" in done.stderr
    assert not (tmp_path / "out").exists()


def test_malformed_contract(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=0.3))
    manifest = tmp_path / "m.yaml"
    manifest.write_text("bags:\n  - uri: ep\n")
    contract = tmp_path / "c.yaml"
    contract.write_text(
        SAMPLE_CONTRACT.read_text().replace("    topic: /joint_states", "    topic: joint_states")
    )
    code, err = _run(_convert(manifest, contract, tmp_path / "out"), capfd)
    assert code == 2
    assert f"{contract}:7 (observations[0].topic): topic 'joint_states' must be an absolute" in err
    assert "absolute ROS topic" in err
    assert not (tmp_path / "out").exists()


def test_existing_output_is_not_touched(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=0.3))
    manifest = tmp_path / "m.yaml"
    manifest.write_text("bags:\n  - uri: ep\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code, err = _run(_convert(manifest, SAMPLE_CONTRACT, out), capfd)
    assert code == 2
    assert "already exists; nothing was written" in err
    assert (out / "keep.txt").read_text() == "mine"


@pytest.mark.slow
def test_a_bad_bag_is_excluded_and_named_the_rest_is_written(tmp_path: Path) -> None:
    write_episode_bag(tmp_path / "good", "mcap", EpisodeSpec(duration_s=0.5))
    write_episode_bag(
        tmp_path / "no_wrist.bag", "ros1", EpisodeSpec(duration_s=0.5, cameras=(CameraSpec("front", "raw"),))
    )
    manifest = tmp_path / "m.yaml"
    manifest.write_text("bags:\n  - uri: good\n  - uri: no_wrist.bag\n")
    out = tmp_path / "out"
    # A fresh process, as a user runs it (Prefect binds its console handler once per process).
    command = [
        sys.executable,
        "-m",
        "flows.cli",
        *_convert(manifest, SAMPLE_CONTRACT, out),
        "--runner",
        "thread",
    ]
    # as a user's shell has it: Prefect's analytics setting not set (its telemetry ERROR once showed)
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_SERVER_ANALYTICS_ENABLED"}
    proc = subprocess.run(command, capture_output=True, text=True, check=False, cwd=REPO, env=env)
    code, err = proc.returncode, proc.stderr
    assert "Traceback" not in err
    assert code == 1, err
    assert "excluded bags[1]" in err
    assert "topic /wrist/image_raw/compressed (for 'observation.images.wrist') is not in bag" in err
    assert "Fix: fix the topic name in the contract, or remove this bag from the manifest." in err
    assert re.search(r"this run: 1 episode\(s\) converted \(\d with QA warnings\), 1 excluded", err), err
    assert err.count("is not in bag") == 1  # each failure once (it was printed 4-6 times)
    assert "telemetry" not in err.lower()
    summary = json.loads((out / "meta/qa/summary.json").read_text())
    assert [(e["episode_index"], e["excluded"]) for e in summary["episodes"]] == [(0, False), (None, True)]

    # --on-qa-fail fail_run: nothing is written, the bad bag is named, and converted episodes are kept.
    strict = tmp_path / "strict"
    proc = subprocess.run(
        [sys.executable, "-m", "flows.cli", *_convert(manifest, SAMPLE_CONTRACT, strict), "--runner", "thread",
         "--on-qa-fail", "fail_run", "--quiet"],
        capture_output=True, text=True, check=False, cwd=REPO,
    )  # fmt: skip
    assert "Traceback" not in proc.stderr
    assert proc.stdout == ""  # --quiet
    assert proc.returncode == 1, proc.stderr
    assert (
        "1 of 2 bag(s) failed QA or conversion and on_fail is 'fail_run'; nothing was written" in proc.stderr
    )
    assert "bags[1]" in proc.stderr
    assert not strict.exists()
    assert len(list((tmp_path / "strict.staging" / "episodes").glob("good-*/episode.json"))) == 1


def test_progress_bar_and_loudness_flags(capfd: pytest.CaptureFixture[str]) -> None:
    from flows.cli import _progress_bar  # noqa: PLC0415

    _progress_bar(3, 12)
    assert capfd.readouterr().err == "\r[#######.......................] 3/12 episodes"
    _progress_bar(12, 12)
    assert (
        capfd.readouterr().err == "\r[##############################] 12/12 episodes; writing the dataset ..."
    )
    with pytest.raises(SystemExit) as info:
        main(["convert", "--manifest", "m", "--contract", "c", "--output", "o", "--quiet", "--verbose"])
    assert info.value.code == 2
    assert "not allowed with argument" in capfd.readouterr().err


@pytest.mark.parametrize(
    ("error", "code"),
    [
        (QualityError("2 of 3 episodes were left out"), 1),  # no marker phrase in its text
        (ConversionError("stopped by --fail-fast"), 1),
        (BagportError("a bad manifest that happens to say failed QA or conversion"), 2),
        (FlowFailedError("the flow ended Crashed"), 2),
    ],
    ids=["quality", "fail-fast", "input-with-the-phrase", "flow-failed"],
)
def test_the_exit_code_comes_from_the_error_type_not_its_text(
    error: BagportError, code: int, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    def fail(_args: object) -> int:
        raise error

    monkeypatch.setattr(flows.cli_commands, "cmd_synth", fail)
    assert main(["synth", "--out", str(tmp_path / "x")]) == code


def test_repair_of_a_path_that_does_not_exist_is_an_error_not_nothing_to_repair(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    code, err = _run(["repair", str(tmp_path / "typo")], capfd)
    assert code == 2
    assert "typo does not exist, so there is nothing there to repair. Fix: " in err
    (tmp_path / "ds").mkdir()
    assert main(["repair", str(tmp_path / "ds")]) == 0
    assert "nothing to repair" in capfd.readouterr().out


def test_an_append_whose_new_bags_all_failed_is_not_nothing_to_do() -> None:
    from bagport.dataset import DatasetReport  # noqa: PLC0415
    from bagport.qa import EpisodeQA, QAEntry  # noqa: PLC0415
    from flows.cli import _summary_line  # noqa: PLC0415

    failed = QAEntry(
        EpisodeQA.failed("new.mcap", "not a bag"), 2, None, excluded_reason="conversion failed"
    ).brief()
    report = DatasetReport("ds", 2, 60, ("t",), (), 1, 2.0, excluded=(failed,), qa=(failed,))
    line = _summary_line(report, True, 1.0)
    assert line.startswith("this run: 0 episode(s) converted") and "1 excluded" in line
    assert _summary_line(DatasetReport("ds", 2, 60, ("t",), (), 1, 2.0), True, 1.0).startswith(
        "nothing to do"
    )


def test_an_error_before_the_bar_starts_on_a_line_of_its_own(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """On a terminal, "starting: planning ..." shows at once; a plan that fails erases it before the error
    (it ran into the error's text: "starting: planning ...bagport convert: error: ...")."""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    argv = ["convert", "--manifest", str(tmp_path / "none.yaml"), "--contract", str(SAMPLE_CONTRACT)]
    assert main([*argv, "--output", str(tmp_path / "ds")]) == 2
    err = capfd.readouterr().err
    assert err.startswith("starting: planning ...\r\x1b[Kbagport convert: error: ")


def test_an_append_the_commit_refuses_is_one_paragraph_without_leak_reports(tmp_path: Path) -> None:
    """A vector's other shape is known from the bags only, so the commit refuses the append; its error
    travelled with its traceback, whose frames kept the stats' sketches alive to the process's exit, where
    their library printed ~600 lines of "nanobind: leaked ..." under the error."""
    write_episode_bag(tmp_path / "a", "mcap", EpisodeSpec(duration_s=0.5))
    write_episode_bag(tmp_path / "b", "mcap", EpisodeSpec(duration_s=0.5, seed=3))
    manifest = tmp_path / "m.yaml"
    out = tmp_path / "out"
    three = tmp_path / "three_joints.yaml"
    names = "[position.j1, position.j2, position.j3, position.j4, position.j5, position.j6]"
    three.write_text(SAMPLE_CONTRACT.read_text().replace(names, "[position.j1, position.j2, position.j3]"))
    for bags, contract in (("a", SAMPLE_CONTRACT), ("b", three)):
        manifest.write_text(f"bags:\n  - uri: {bags}\n")
        proc = subprocess.run(
            [sys.executable, "-m", "flows.cli", *_convert(manifest, contract, out), "--append", "--quiet",
             "--runner", "thread", "--codec", "h264-fast"],
            capture_output=True, text=True, check=False, cwd=REPO,
        )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "the new episodes' features differ from the dataset's (action, observation.state" in proc.stderr
    assert "nanobind" not in proc.stderr
    assert len(proc.stderr.splitlines()) <= 2, proc.stderr


def test_a_codec_or_config_file_that_is_not_yaml_is_one_paragraph(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """Fuzzed inputs that escaped as yaml's ParserError (and a file that is not UTF-8)."""
    broken = tmp_path / "broken.yaml"
    broken.write_text("codec: [libx264\n")
    argv = [
        "convert",
        "--glob",
        str(tmp_path / "*.mcap"),
        "--contract",
        str(SAMPLE_CONTRACT),
        "--output",
        "o",
    ]
    assert main([*argv, "--codec", str(broken)]) == 2
    err = capfd.readouterr().err
    assert (
        f"--codec {broken}: {broken} is not valid YAML at line 2, column 1" in err and "Traceback" not in err
    )
    assert main(["convert", "--config", str(broken)]) == 2
    assert f"--config: {broken} is not valid YAML at line 2" in capfd.readouterr().err
    twice = tmp_path / "twice.yaml"
    twice.write_text("output: a\noutput: b\n")
    assert main(["convert", "--config", str(twice)]) == 2
    assert "line 2, column 1 (key 'output' is given twice (lines 1 and 2))" in capfd.readouterr().err
    assert main([*argv, "--codec", str(tmp_path / "missing.yaml")]) == 2
    assert (
        "no such file, and no preset of that name. Fix: give a preset (archival, h264-fast, lerobot-default)"
        in (capfd.readouterr().err)
    )
    latin1 = tmp_path / "latin1.yaml"
    latin1.write_bytes(b"codec: libx264 # caf\xe9\n")
    assert main([*argv, "--codec", str(latin1)]) == 2
    assert (
        f"--codec {latin1}: {latin1} is not UTF-8 text (the byte at offset 20 is not). Fix: save it as UTF-8 "
        "(from Latin-1: `iconv" in capfd.readouterr().err
    )


def test_a_qa_report_that_cannot_be_written_is_one_paragraph_after_the_scores(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    write_episode_bag(tmp_path / "ep", "mcap", EpisodeSpec(duration_s=1.0))
    manifest = tmp_path / "m.yaml"
    manifest.write_text("bags:\n  - uri: ep\n")
    report = tmp_path / "missing" / "report.html"
    argv = ["qa", "--manifest", str(manifest), "--contract", str(SAMPLE_CONTRACT), "--report", str(report)]
    assert main(argv) == 2
    out, err = capfd.readouterr()
    assert "bags[0]" in out  # the scores were printed first
    assert f"--report {report}: cannot be written (No such file or directory); the scores above" in err
    assert "Traceback" not in err


def test_codec_settings_the_encoder_refuses_are_one_paragraph_before_any_bag(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """Fuzzed: crf out of range failed every episode with 'encoding frame 0 failed: [Errno 34] ...
    avcodec_open2' naming a temporary clip, and an unknown pix_fmt as a raw ValueError."""
    write_episode_bag(tmp_path / "bags" / "a", "mcap", EpisodeSpec(duration_s=0.3))
    for name, text, said in (
        ("range", "codec: libsvtav1\ncrf: 99\n", "Numerical result out of range when libsvtav1 opened"),
        (
            "pixfmt",
            "codec: libx264\npix_fmt: yuv9000\n",
            "pix_fmt 'yuv9000' is not a pixel format FFmpeg knows",
        ),
    ):
        codec = tmp_path / f"{name}.yaml"
        codec.write_text(text)
        argv = ["convert", "--glob", str(tmp_path / "bags" / "*"), "--contract", str(SAMPLE_CONTRACT),
                "--output", str(tmp_path / "out"), "--codec", str(codec)]  # fmt: skip
        assert main(argv) == 2
        err = capfd.readouterr().err
        assert f"error: the codec settings cannot encode video: {said}" in err and "Traceback" not in err
        assert "bagport-episode" not in err and not (tmp_path / "out.staging").exists()
