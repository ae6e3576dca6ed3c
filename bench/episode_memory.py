"""Peak memory and wall time of converting one synthetic episode, by episode length.

Usage: .venv/bin/python bench/episode_memory.py SECONDS [WORKDIR]
Writes a bag (2 cameras 320x240: raw bgr8 + jpeg, 32 joints at 500 Hz, actions at 50 Hz) to WORKDIR
on the first call, then converts it in a fresh process and prints frames, wall time and peak RSS.
Not a test: the full benchmark (issue 7) builds on this.
"""

from __future__ import annotations

import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.synth import CameraSpec, EpisodeSpec, write_episode_bag

CONTRACT = """\
robot_type: bench
fps: 30
observations:
  - {key: observation.state, topic: /joint_states, type: sensor_msgs/msg/JointState}
  - {key: observation.images.front, topic: /front/image_raw, type: sensor_msgs/msg/Image}
  - {key: observation.images.wrist, topic: /wrist/image_raw/compressed, type: sensor_msgs/msg/CompressedImage}
actions:
  - {key: action, publish: {topic: /cmd, type: sensor_msgs/msg/JointState}}
tasks:
  - {key: task, topic: /task_prompt}
"""


def main() -> None:
    seconds = float(sys.argv[1])
    work = Path(sys.argv[2]) if len(sys.argv) > 2 else Path(tempfile.mkdtemp(prefix="bagport-mem-"))
    bag = work / f"ep_{seconds:g}s"
    if not bag.exists():
        spec = EpisodeSpec(
            duration_s=seconds,
            joint_names=tuple(f"j{i}" for i in range(32)),
            joint_rate_hz=500,
            cameras=(
                CameraSpec("front", "raw", "bgr8", 240, 320),
                CameraSpec("wrist", "jpeg", height=240, width=320),
            ),
        )
        write_episode_bag(bag, "mcap", spec)
        # convert in a fresh process so peak RSS reflects the conversion alone
        subprocess.run([sys.executable, __file__, sys.argv[1], str(work)], check=True)
        return
    request = EpisodeRequest(
        episode_id_for(str(bag), CONTRACT, {}), str(bag), 0, str(work / "staging"), CONTRACT, "bench", {}
    )
    started = time.perf_counter()
    summary = convert_episode(request)
    wall_s = time.perf_counter() - started
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"episode_s={seconds:g} frames={summary.frames} wall_s={wall_s:.1f} peak_rss_mb={peak_mb:.0f}")


if __name__ == "__main__":
    main()
