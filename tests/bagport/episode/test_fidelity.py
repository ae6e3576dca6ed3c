"""An episode's video checks: clean clips pass; a replaced frame or a short clip is caught and shown."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import numpy.typing as npt
import simplejpeg

from bagport.episode.fidelity import EpisodeFidelity
from bagport.qa import CheckResult
from bagport.qa.config import VideoQA
from bagport.synth.pixels import render_frame
from bagport.video import EncoderSettings, StreamingEncoder

NEAR_LOSSLESS = EncoderSettings.from_dict({"codec": "libx264", "crf": 0, "pix_fmt": "yuv444p", "g": 2})
H, W, N = 96, 128, 16


def _episode(
    tmp_path: Path, fed: list[npt.NDArray[np.uint8]], seen: list[npt.NDArray[np.uint8]], config: VideoQA
) -> tuple[dict[str, CheckResult], dict[str, object]]:
    tmp_path.mkdir(parents=True, exist_ok=True)
    fidelity = EpisodeFidelity(config, tmp_path / "refs", gop=2)
    with StreamingEncoder(tmp_path / "front.mp4", fps=30, width=W, height=H, settings=NEAR_LOSSLESS) as enc:
        for frame in fed:
            enc.write(frame)
    for frame in seen:
        fidelity.record("front", frame)
    checks, plots = fidelity.check({"front": enc.close()}, 30)
    assert not (tmp_path / "refs").exists()  # scratch references are gone
    return {c.check: c for c in checks}, plots


def test_clean_clip_passes_and_a_replaced_frame_fails_with_a_picture(tmp_path: Path) -> None:
    frames = [render_frame(H, W, k) for k in range(N)]
    every = VideoQA(sample_every=1)
    clean, plots = _episode(tmp_path / "a", frames, frames, every)
    assert {c.verdict for c in clean.values()} == {"pass"}
    assert "worst_jpeg_base64" not in plots["front"]  # type: ignore[operator]

    replaced = [*frames[:7], render_frame(H, W, 12), *frames[8:]]
    broken, plots = _episode(tmp_path / "b", replaced, frames, every)
    assert broken["video.damaged_frames"].verdict == "warn"
    assert "frames 7" in broken["video.damaged_frames"].reason
    assert broken["video.psnr_min_db"].verdict != "pass"
    picture = plots["front"]["worst_jpeg_base64"]  # type: ignore[index]
    image = simplejpeg.decode_jpeg(base64.b64decode(picture))
    assert image.shape[0] == H and image.shape[1] > 2 * W  # source | decoded | outlined, side by side


def test_a_clip_shorter_than_what_was_encoded_fails_the_episode(tmp_path: Path) -> None:
    frames = [render_frame(H, W, k) for k in range(N)]
    checks, _ = _episode(tmp_path, frames[:-3], frames, VideoQA())
    mismatch = checks["video.frame_mismatch"]
    assert (mismatch.verdict, mismatch.hard, mismatch.value) == ("fail", True, 3.0)
    assert "13 frames in the clip, 16 encoded" in mismatch.reason


def test_sampling_checks_a_quarter_of_the_frames_by_default(tmp_path: Path) -> None:
    frames = [render_frame(H, W, k) for k in range(N)]
    checks, plots = _episode(tmp_path, frames, frames, VideoQA())
    assert plots["front"]["sampled_frames"] == 4  # type: ignore[index] # runs 0-1 and 8-9 of 16
    assert "4 of 16 frames checked" in checks["video.psnr_min_db"].reason


def test_fidelity_off_records_nothing(tmp_path: Path) -> None:
    fidelity = EpisodeFidelity(VideoQA(fidelity=False), tmp_path / "refs", gop=2)
    fidelity.record("front", render_frame(H, W, 0))
    assert fidelity.check({}, 30) == ([], {})
    assert not (tmp_path / "refs").exists()
