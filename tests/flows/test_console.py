"""A run whose console goes away (``bagport convert ... | head``) still converts and commits; a run ended by
SIGTERM says so."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from bagport.synth import EpisodeSpec, write_episode_bag
from flows.console import TERMINATED, _ClosedPipeTolerant
from tests.helpers import REPO, SAMPLE_CONTRACT


def test_writing_to_a_closed_pipe_drops_the_text_and_keeps_dropping() -> None:
    read_end, write_end = os.pipe()
    stream = _ClosedPipeTolerant(os.fdopen(write_end, "w", buffering=1))
    stream.write("seen\n")
    assert os.read(read_end, 100) == b"seen\n"
    os.close(read_end)
    stream.write("lost\n")  # raised BrokenPipeError before
    stream.flush()
    assert str(Path(f"/proc/self/fd/{stream.fileno()}").readlink()) == os.devnull
    assert stream.write("and this\n") == len("and this\n")
    stream.close()


@pytest.mark.slow
@pytest.mark.parametrize("runner", ["process", "dask", "ray"])
def test_a_convert_whose_output_reader_exits_still_writes_its_dataset(tmp_path: Path, runner: str) -> None:
    """The reader of stdout and stderr exits after the first log line, as ``| head -1`` does: the run goes
    on to its dataset and exits 0 (it exited 1 with no dataset: rich's console raised SystemExit in the
    flow, or crashed a pool worker's task run and the flow waited for it forever). The same on a local
    Dask cluster and a local Ray instance, whose worker processes the CLI starts after its output left."""
    for name in ("a", "b", "c"):
        write_episode_bag(tmp_path / "bags" / name, "mcap", EpisodeSpec(duration_s=0.5))
    out = tmp_path / "out"
    command = [
        sys.executable, "-m", "flows.cli", "convert", "--glob", str(tmp_path / "bags" / "*"),
        "--contract", str(SAMPLE_CONTRACT), "--output", str(out), "--verbose", "--runner", runner,
    ]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    process = subprocess.Popen(
        command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert process.stdout is not None
    first = process.stdout.readline()
    process.stdout.close()  # the reader is gone: every later write meets a closed pipe
    try:
        code = process.wait(timeout=300)
    finally:
        process.kill()
    assert first  # the run had written a line before its reader left
    assert code == 0
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 3


@pytest.mark.slow
def test_a_convert_ended_by_sigterm_says_what_stands(tmp_path: Path) -> None:
    """SIGTERM (a scheduler's time limit) ends the run at once, as before (exit status 143), with one line
    saying what stands and how to resume; before, only multiprocessing's warning about leaked semaphores."""
    for name in ("a", "b", "c"):
        write_episode_bag(tmp_path / "bags" / name, "mcap", EpisodeSpec(duration_s=2.0))
    command = [
        sys.executable, "-m", "flows.cli", "convert", "--glob", str(tmp_path / "bags" / "*"),
        "--contract", str(SAMPLE_CONTRACT), "--output", str(tmp_path / "out"), "--verbose",
    ]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    process = subprocess.Popen(
        command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert process.stdout is not None
    seen = []
    for line in process.stdout:  # the flow has begun: the run is under way
        seen.append(line)
        if "Beginning flow run" in line:
            process.send_signal(signal.SIGTERM)
            break
    try:
        rest = process.communicate(timeout=120)[0]
    finally:
        process.kill()
    assert process.returncode == -signal.SIGTERM
    output = "".join(seen) + rest
    assert TERMINATED in output
    assert "Traceback" not in output
    assert not (tmp_path / "out").exists()
