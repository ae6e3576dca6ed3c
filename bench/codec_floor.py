"""The codec floor: decode every source image and encode it with PyAV at LeRobot's settings, nothing else.

One process per episode at a time, as many as cores (what the encoder alone costs on this machine).
Usage: python bench/codec_floor.py WORKLOAD_DIR OUT [--workers N]
"""

from __future__ import annotations

import argparse
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import av
import numpy as np
import simplejpeg
import yaml
from rosbags.highlevel import AnyReader

OPTIONS = {"g": "2", "crf": "30", "preset": "12"}


def encode_episode(bag: Path, out: Path, fps: int) -> int:
    frames = 0
    with AnyReader([bag]) as reader:
        for conn in [c for c in reader.connections if "image" in c.msgtype.lower()]:
            path = out / f"{bag.name}-{conn.topic.strip('/').replace('/', '_')}.mp4"
            with av.open(str(path), "w") as container:
                stream: Any = None
                for _, _, raw in reader.messages(connections=[conn]):
                    msg: Any = reader.deserialize(raw, conn.msgtype)
                    if conn.msgtype.endswith("CompressedImage"):
                        rgb = simplejpeg.decode_jpeg(msg.data.tobytes(), colorspace="RGB")
                    else:
                        rgb = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.width, 3)[
                            :, :, ::-1
                        ]
                    if stream is None:
                        stream = container.add_stream("libsvtav1", rate=fps, options=OPTIONS)
                        stream.width, stream.height, stream.pix_fmt = rgb.shape[1], rgb.shape[0], "yuv420p"
                    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
                    for packet in stream.encode(frame):
                        container.mux(packet)
                    frames += 1
                if stream is not None:
                    for packet in stream.encode():
                        container.mux(packet)
    return frames


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("workload", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    bags = [
        args.workload / b["uri"]
        for b in yaml.safe_load((args.workload / "manifest.yaml").read_text())["bags"]
    ]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        frames = sum(pool.map(encode_episode, bags, [args.out] * len(bags), [30] * len(bags)))
    print(f"{frames} frames encoded")


if __name__ == "__main__":
    main()
