"""Codec study: size, encode speed and fidelity of encoder settings, on frames like the benchmark's.

For each frame size (96x128, 240x320, 480x640) and each setting (libsvtav1 presets, crf and g;
libx264; the archival preset), encode the same frames with bagport's encoder, then check the
clip with bagport's fidelity check on every frame (block means, see bagport.video.fidelity).
Two kinds of content: ``camera`` (the synthetic camera of the workloads: colour bars, an encoded
frame index, sensor noise) and ``edges`` (small high-contrast squares moving over flat colour,
the pattern that exposes stale and foreign blocks).

Usage: .venv/bin/python bench/codec_study.py [--frames 60] [--report BENCHMARKS.md]
Writes a table between ``<!-- codec:start -->`` and ``<!-- codec:end -->`` in the report.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bagport.synth.pixels import render_frame
from bagport.video import EncoderSettings, FidelityRecorder, StreamingEncoder, compare_clip
from bench.report import write_section

SIZES = ((96, 128), (240, 320), (480, 640))
SETTINGS: dict[str, dict[str, Any]] = {
    "svtav1 p12 crf30 g2 (LeRobot default)": {},
    "svtav1 p12 crf20 g2": {"crf": 20},
    "svtav1 p12 crf40 g2": {"crf": 40},
    "svtav1 p10 crf30 g2": {"preset": 10},
    "svtav1 p8 crf30 g2": {"preset": 8},
    "svtav1 p12 crf30 g10": {"g": 10},
    "x264 veryfast crf23 g2 (h264-fast)": {"codec": "libx264", "crf": 23, "preset": "veryfast"},
    "x264 veryfast crf18 g2": {"codec": "libx264", "crf": 18, "preset": "veryfast"},
    "x264 crf0 yuv444p g2 (archival)": {
        "codec": "libx264",
        "crf": 0,
        "preset": "veryfast",
        "pix_fmt": "yuv444p",
    },
}
Frame = npt.NDArray[np.uint8]


def camera(k: int, h: int, w: int) -> Frame:
    return render_frame(h, w, k, np.random.default_rng(k), 3.0)


def edges(k: int, h: int, w: int) -> Frame:
    """Flat colour patches with small saturated squares moving a few pixels per frame."""
    img = np.empty((h, w, 3), np.uint8)
    img[:, : w // 2] = (40, 90, 200)
    img[:, w // 2 :] = (220, 200, 60)
    size = max(4, h // 12)
    for n in range(6):
        y = int((h - size) * (0.5 + 0.45 * np.sin(k / (5 + n) + n)))
        x = int((w - size) * (0.5 + 0.45 * np.cos(k / (7 + n) + 2 * n)))
        img[y : y + size, x : x + size] = (255, 255, 255) if n % 2 else (10, 10, 10)
    return img


def study(
    frames: int, content: Callable[[int, int, int], Frame], h: int, w: int, tmp: Path
) -> list[dict[str, Any]]:
    source = [content(k, h, w) for k in range(frames)]
    rows = []
    for name, options in SETTINGS.items():
        settings = EncoderSettings.from_dict(options)
        clip = tmp / "clip.mp4"
        recorder = FidelityRecorder(tmp / "clip.refs", height=h, width=w)
        started = time.perf_counter()
        with StreamingEncoder(clip, fps=30, width=w, height=h, settings=settings) as encoder:
            for frame in source:
                encoder.write(frame)
        encode_s = time.perf_counter() - started
        for frame in source:
            recorder.record(frame)
        result = compare_clip(clip, recorder, fps=30)
        recorder.discard()
        rows.append(
            {
                "setting": name,
                "kb_per_frame": clip.stat().st_size / 1e3 / frames,
                "encode_fps": frames / encode_s,
                "psnr_min_db": result.psnr_min_db,
                "psnr_median_db": result.psnr_median_db,
                "damaged": result.damaged_frames,
                "frames": frames,
            }
        )
    return rows


def table(results: dict[tuple[str, int, int], list[dict[str, Any]]], frames: int) -> str:
    lines = [
        f"{frames} frames per clip, encoded one clip at a time (the encoder uses every core); fidelity on every "
        "frame, on 8x8 block means (PSNR there is higher than pixel PSNR). `damaged`: frames with at least one "
        "block far worse than the rest of the frame (stale or foreign blocks).",
        "",
    ]
    for (content, h, w), rows in results.items():
        lines += [f"**{content} {h}x{w}**", "", "| setting | kB/frame | encode fps | PSNR min dB | PSNR median dB | damaged frames |",
                  "|---|---|---|---|---|---|"]  # fmt: skip
        lines += [
            f"| {r['setting']} | {r['kb_per_frame']:.1f} | {r['encode_fps']:.0f} | {r['psnr_min_db']} | "
            f"{r['psnr_median_db']} | {r['damaged']} / {r['frames']} |"
            for r in rows
        ]
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--report", type=Path, default=Path(__file__).resolve().parents[1] / "BENCHMARKS.md")
    args = parser.parse_args()
    results: dict[tuple[str, int, int], list[dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for content in (camera, edges):
            for h, w in SIZES:
                results[(content.__name__, h, w)] = study(args.frames, content, h, w, Path(tmp))
                print(f"{content.__name__} {h}x{w} done", file=sys.stderr, flush=True)
    write_section(args.report, "codec", table(results, args.frames))


if __name__ == "__main__":
    main()
