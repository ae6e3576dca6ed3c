"""Cost of the video fidelity check next to the encode it checks, per frame.

Usage: .venv/bin/python bench/fidelity_cost.py [FRAMES] [WORKDIR]
For 240x320 and 480x640 textured, noisy frames (a moving blob, sensor noise): time per frame of
``StreamingEncoder.write`` (+ close) with each codec preset, ``FidelityRecorder.record``,
``compare_clip`` (decode + compare) and a plain decode; clip sizes and what the check found.
Not a test: numbers depend on the machine and its load.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import yaml

from bagport.synth.pixels import textured_frame
from bagport.video import EncoderSettings, FidelityRecorder, StreamingEncoder, compare_clip, iter_frames

CODECS = Path(__file__).resolve().parent.parent / "configs" / "codecs"


def main(frames: int, workdir: Path) -> None:
    presets = {
        name: EncoderSettings.from_dict(yaml.safe_load((CODECS / f"{name}.yaml").read_text()))
        for name in ("lerobot-default", "h264-fast", "archival")
    }
    print(
        "size     codec            encode ms/f  record ms/f  compare ms/f  decode ms/f  kB/f  psnr min/med  damaged"
    )
    for h, w in ((240, 320), (480, 640)):
        source = [textured_frame(k, h, w) for k in range(frames)]
        for name, settings in presets.items():
            clip = workdir / f"{name}-{h}.mp4"
            recorder = FidelityRecorder(workdir / f"{name}-{h}.refs", height=h, width=w)
            t_encode = t_record = 0.0
            with StreamingEncoder(clip, fps=30, width=w, height=h, settings=settings) as encoder:
                for rgb in source:
                    t0 = time.perf_counter()
                    encoder.write(rgb)
                    t1 = time.perf_counter()
                    recorder.record(rgb)
                    t_record += time.perf_counter() - t1
                    t_encode += t1 - t0
                t0 = time.perf_counter()
            t_encode += time.perf_counter() - t0  # the flush in close()
            t0 = time.perf_counter()
            result = compare_clip(clip, recorder, fps=30)
            t_compare = time.perf_counter() - t0
            t0 = time.perf_counter()
            for _ in iter_frames(clip):
                pass
            t_decode = time.perf_counter() - t0
            recorder.discard()
            ms = 1000 / frames
            print(
                f"{h}x{w:<4} {name:16s} {t_encode * ms:11.2f} {t_record * ms:12.3f} {t_compare * ms:13.2f} "
                f"{t_decode * ms:12.2f} {clip.stat().st_size / 1024 / frames:5.1f}  "
                f"{result.psnr_min_db:5.1f}/{result.psnr_median_db:5.1f}  {result.damaged_frames}"
            )


if __name__ == "__main__":
    count = int(sys.argv[1]) if len(sys.argv) > 1 else 90
    if len(sys.argv) > 2:
        main(count, Path(sys.argv[2]))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            main(count, Path(tmp))
