"""Peak memory of writing one staged episode as HDF5 or Robo-DM, by episode length.

Usage: .venv/bin/python bench/format_memory.py SECONDS hdf5|robodm [WORKDIR]
Stages a synthetic episode (2 cameras 320x240: raw bgr8 + jpeg) under WORKDIR on the first call, then
writes it in the given format in a fresh process and prints frames, wall time, peak RSS (and the RSS
after the imports, for comparison) and the output's size. Memory should not grow with SECONDS.
"""

from __future__ import annotations

import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bagport.dataset import DatasetReport
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.formats.hdf5 import write_hdf5_dataset
from bagport.formats.robodm import trajectory_class, write_robodm_dataset
from bagport.staging import EpisodeSummary
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag
from bagport.video.settings import EncoderSettings
from bench.episode_memory import CONTRACT

CODEC = EncoderSettings.from_dict({"codec": "libx264", "crf": 18, "preset": "ultrafast", "g": 2})


def _stage(seconds: float, work: Path) -> Path:
    summary_path = work / f"ep_{seconds:g}s.json"
    if not summary_path.exists():
        bag = work / f"ep_{seconds:g}s"
        cameras = (
            CameraSpec("front", "raw", "bgr8", 240, 320),
            CameraSpec("wrist", "jpeg", height=240, width=320),
        )
        write_episode_bag(bag, "mcap", EpisodeSpec(duration_s=seconds, cameras=cameras))
        request = EpisodeRequest(
            episode_id_for(str(bag), CONTRACT, CODEC),
            str(bag),
            0,
            str(work / "staging"),
            CONTRACT,
            "bench",
            CODEC,
        )
        summary_path.write_text(json.dumps(convert_episode(request).to_dict()))
    return summary_path


def _write(summary_path: Path, fmt: str, work: Path) -> None:
    summary = EpisodeSummary.from_dict(json.loads(summary_path.read_text()))
    out = work / f"{summary_path.stem}.{fmt}"
    shutil.rmtree(out, ignore_errors=True)
    write: Callable[..., DatasetReport] = write_hdf5_dataset if fmt == "hdf5" else write_robodm_dataset
    if fmt == "robodm":
        trajectory_class()  # robodm's own import, before the baseline
    imports_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    started = time.perf_counter()
    write([summary], str(out), robot_type="bench", run_record={})
    wall_s = time.perf_counter() - started
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    size_mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
    print(
        f"format={fmt} frames={summary.frames} wall_s={wall_s:.1f} peak_rss_mb={peak_mb:.0f} "
        f"after_imports_mb={imports_mb:.0f} size_mb={size_mb:.0f}"
    )


def main() -> None:
    seconds, fmt = float(sys.argv[1]), sys.argv[2]
    work = Path(sys.argv[3]) if len(sys.argv) > 3 else Path(tempfile.mkdtemp(prefix="bagport-fmt-mem-"))
    if len(sys.argv) < 5:  # stage here, write in a fresh process so peak RSS is the writer's alone
        _stage(seconds, work)
        subprocess.run([sys.executable, __file__, *sys.argv[1:3], str(work), "write"], check=True)
        return
    _write(work / f"ep_{seconds:g}s.json", fmt, work)


if __name__ == "__main__":
    main()
