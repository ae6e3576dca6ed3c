"""Peak memory and wall time of converting one synthetic episode, by episode length.

Usage: .venv/bin/python bench/episode_memory.py SECONDS [WORKDIR] [--video]
Writes a bag (2 cameras 320x240: raw bgr8 + jpeg, 32 joints at 500 Hz, actions at 50 Hz) to WORKDIR
on the first call, then converts it in a fresh process and prints frames, wall time and peak RSS.
``--video``: one 640x480 camera recorded as H.264 (foxglove CompressedVideo, B-frames, a key frame
every 30), 6 joints at 100 Hz, actions at 50 Hz: the memory of the streaming video decoder.
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
from bagport.video.settings import EncoderSettings

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
VIDEO_CONTRACT = """\
robot_type: bench
fps: 30
observations:
  - {key: observation.state, topic: /joint_states, type: sensor_msgs/msg/JointState}
  - {key: observation.images.front, topic: /front/video, type: foxglove_msgs/msg/CompressedVideo}
actions:
  - {key: action, publish: {topic: /cmd, type: sensor_msgs/msg/JointState}}
tasks:
  - {key: task, topic: /task_prompt}
"""


def _spec(seconds: float, video: bool) -> EpisodeSpec:
    if video:
        camera = CameraSpec("front", "video", height=480, width=640, bframes=2, gop=30)
        return EpisodeSpec(duration_s=seconds, cameras=(camera,))
    return EpisodeSpec(
        duration_s=seconds,
        joint_names=tuple(f"j{i}" for i in range(32)),
        joint_rate_hz=500,
        cameras=(
            CameraSpec("front", "raw", "bgr8", 240, 320),
            CameraSpec("wrist", "jpeg", height=240, width=320),
        ),
    )


def main() -> None:
    args = [a for a in sys.argv[1:] if a != "--video"]
    video = "--video" in sys.argv[1:]
    seconds = float(args[0])
    work = Path(args[1]) if len(args) > 1 else Path(tempfile.mkdtemp(prefix="bagport-mem-"))
    bag = work / f"ep_{seconds:g}s{'_video' if video else ''}"
    contract = VIDEO_CONTRACT if video else CONTRACT
    if not bag.exists():
        write_episode_bag(bag, "mcap", _spec(seconds, video))
        # convert in a fresh process so peak RSS reflects the conversion alone
        again = [sys.executable, __file__, args[0], str(work), *(["--video"] if video else [])]
        subprocess.run(again, check=True)
        return
    request = EpisodeRequest(
        episode_id_for(str(bag), contract, EncoderSettings()),
        str(bag),
        0,
        str(work / "staging"),
        contract,
        "bench",
    )
    started = time.perf_counter()
    summary = convert_episode(request)
    wall_s = time.perf_counter() - started
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    kind = " video=h264-640x480" if video else ""
    print(
        f"episode_s={seconds:g}{kind} frames={summary.frames} wall_s={wall_s:.1f} peak_rss_mb={peak_mb:.0f}"
    )


if __name__ == "__main__":
    main()
