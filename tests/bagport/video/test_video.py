"""Streaming encode and remux: colours survive, pts are frame indices, offsets stay exact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
import yaml

from bagport.errors import EncoderSettingsError, VideoError
from bagport.video import EncoderSettings, StreamingEncoder, concat_clips, iter_frames, probe_video
from bagport.video.encode import check_encoder
from tests.helpers import REPO

FAST = EncoderSettings.from_dict({"codec": "libx264", "crf": 10, "preset": "ultrafast", "g": 2})


def _frame(k: int, h: int = 32, w: int = 48) -> npt.NDArray[np.uint8]:
    img = np.zeros((h, w, 3), np.uint8)
    img[:, : w // 3] = (255, 0, 0)
    img[:, w // 3 : 2 * w // 3] = (0, 255, 0)
    img[:, 2 * w // 3 :] = (0, 0, 255)
    img[: h // 4] = (k * 37) % 256
    return img


def _clip(path: Path, frames: int, settings: EncoderSettings = FAST, start: int = 0) -> Path:
    with StreamingEncoder(path, fps=30, width=48, height=32, settings=settings) as enc:
        for k in range(frames):
            enc.write(_frame(start + k))
    return path


@pytest.mark.parametrize("settings", [EncoderSettings(), FAST], ids=["lerobot-default-av1", "x264"])
def test_colours_and_pts_round_trip(tmp_path: Path, settings: EncoderSettings) -> None:
    with StreamingEncoder(tmp_path / "c.mp4", fps=30, width=48, height=32, settings=settings) as enc:
        for k in range(10):
            enc.write(_frame(k))
    info = enc.close()
    assert info.frames == 10
    assert info.codec == ("av1" if settings.codec == "libsvtav1" else "h264")
    decoded = list(iter_frames(tmp_path / "c.mp4"))
    assert [round(pts * 30, 6) for pts, _ in decoded] == list(range(10))
    for _, rgb in decoded:
        centres = rgb[20, [8, 24, 40]].astype(int)
        assert np.abs(centres - np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]])).max() < 12


def test_300_clips_keep_exact_offsets_for_lerobot(tmp_path: Path) -> None:
    from lerobot.datasets.video_utils import decode_video_frames  # noqa: PLC0415

    first = _clip(tmp_path / "a.mp4", 2)
    second = _clip(tmp_path / "b.mp4", 3)
    clips = [first if i % 2 == 0 else second for i in range(300)]
    placements = concat_clips(clips, tmp_path / "all.mp4", fps=30)
    frames_before = 0
    for placement in placements:
        assert placement.from_timestamp_s == frames_before / 30
        frames_before += placement.frames
    assert frames_before == 750
    pts = [p for p, _ in iter_frames(tmp_path / "all.mp4")]
    np.testing.assert_allclose(pts, np.arange(750) / 30, atol=1e-9)
    assert probe_video(tmp_path / "all.mp4").frames == 750
    for placement in (placements[0], placements[150], placements[-1]):
        stamps = [placement.from_timestamp_s, placement.to_timestamp_s - 1 / 30]
        frames = decode_video_frames(tmp_path / "all.mp4", stamps, tolerance_s=1e-4, backend="pyav")
        assert tuple(frames.shape) == (2, 3, 32, 48)


def test_mismatched_clips_are_refused(tmp_path: Path) -> None:
    a = _clip(tmp_path / "a.mp4", 2)
    b = _clip(tmp_path / "b.mp4", 2, EncoderSettings())
    with pytest.raises(VideoError, match=r"b\.mp4: codec/size/pix_fmt.*differ"):
        concat_clips([a, b], tmp_path / "all.mp4", fps=30)


def test_bad_frames_and_settings_say_how_to_fix(tmp_path: Path) -> None:
    enc = StreamingEncoder(tmp_path / "c.mp4", fps=30, width=48, height=32, settings=FAST)
    with pytest.raises(
        VideoError, match=r"frame 0 is uint8\[10, 10, 3\], the clip is uint8\[32, 48, 3\].*resize"
    ):
        enc.write(np.zeros((10, 10, 3), np.uint8))
    assert enc.close().frames == 0
    with pytest.raises(VideoError, match="needs even width and height"):
        StreamingEncoder(tmp_path / "odd.mp4", fps=30, width=47, height=32, settings=FAST)
    with pytest.raises(VideoError, match=r"unknown encoder setting\(s\) \['crff'\]"):
        EncoderSettings.from_dict({"crff": 3})
    with pytest.raises(VideoError, match="cannot start encoder 'nope'"):
        StreamingEncoder(
            tmp_path / "x.mp4", fps=30, width=48, height=32, settings=EncoderSettings(codec="nope")
        )


def test_lerobot_default_options() -> None:
    assert EncoderSettings().codec_options() == {"g": "2", "crf": "30", "preset": "12"}
    assert EncoderSettings(threads=2).codec_options()["svtav1-params"] == "lp=2"
    assert EncoderSettings().to_info()["video.crf"] == 30


def test_bgr_views_encode_like_their_rgb_copy(tmp_path: Path) -> None:
    """A bgr8 image reaches the encoder as a channel-reversed view (no copy); colours stay right."""
    clips = {}
    for name in ("view", "copy"):
        with StreamingEncoder(tmp_path / f"{name}.mp4", fps=30, width=48, height=32, settings=FAST) as enc:
            for k in range(4):
                bgr = np.ascontiguousarray(_frame(k)[:, :, ::-1])  # the bytes a bgr8 message carries
                view = bgr[:, :, ::-1]
                assert view.strides[2] < 0
                enc.write(view if name == "view" else np.ascontiguousarray(view))
        clips[name] = [rgb for _, rgb in iter_frames(tmp_path / f"{name}.mp4")]
    assert len(clips["view"]) == 4
    for ours, reference in zip(clips["view"], clips["copy"], strict=True):
        assert np.array_equal(ours, reference)
    centres = clips["view"][0][20, [8, 24, 40]].astype(int)
    assert np.abs(centres - np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]])).max() < 12


def test_bagport_default_encoder_is_the_h264_fast_preset() -> None:
    from bagport.config import ConvertConfig  # noqa: PLC0415
    from bagport.video.settings import DEFAULT_ENCODER  # noqa: PLC0415

    preset = yaml.safe_load((REPO / "configs/codecs/h264-fast.yaml").read_text())
    assert preset == dict(DEFAULT_ENCODER)
    config = ConvertConfig(manifest="m.yaml", contract="c.yaml", output="out")
    assert config.encoder == preset
    assert EncoderSettings.from_dict(config.encoder).codec == "libx264"


@pytest.mark.parametrize(
    ("setting", "value", "kind"),
    [("crf", "high", "a number"), ("g", 2.5, "a whole number of frames"), ("preset", True, "a number or a name"),
     ("codec", 264, "an encoder name"), ("extra_options", ["tune"], "a mapping")],
)  # fmt: skip
def test_a_setting_of_the_wrong_kind_is_refused_by_name(setting: str, value: object, kind: str) -> None:
    with pytest.raises(VideoError, match=rf"encoder setting {setting}: .* is not {kind}.*Fix: correct it"):
        EncoderSettings.from_dict({setting: value})
    assert EncoderSettings.from_dict({"crf": None, "preset": "veryfast", "codec": "libx264"}).crf is None
    assert EncoderSettings.from_dict({"crf": 23.5, "codec": "libx264"}).codec_options()["crf"] == "23.5"


@pytest.mark.parametrize("preset", sorted((REPO / "configs" / "codecs").glob("*.yaml")), ids=lambda p: p.stem)
def test_every_shipped_codec_preset_passes_the_encoder_check(preset: Path, tmp_path: Path) -> None:
    check_encoder(EncoderSettings.from_dict(yaml.safe_load(preset.read_text())), tmp_path)


@pytest.mark.parametrize(
    ("settings", "detail"),
    [
        ({"codec": "libsvtav1", "crf": 99}, "Numerical result out of range when libsvtav1 opened"),
        ({"codec": "libx264", "extra_options": {"profile": "bogus"}}, "Invalid argument when libx264 opened"),
        ({"codec": "libx264", "pix_fmt": "yuv9000"}, "pix_fmt 'yuv9000' is not a pixel format FFmpeg knows"),
        ({"codec": "nope"}, "no encoder 'nope' in this PyAV build"),
        ({"codec": "aac"}, "'aac' encodes audio, not video"),
    ],
    ids=["option-out-of-range", "option-refused", "unknown-pix-fmt", "unknown-codec", "audio-codec"],
)
def test_settings_the_encoder_refuses_are_found_before_any_episode(
    settings: dict[str, object], detail: str, tmp_path: Path
) -> None:
    with pytest.raises(EncoderSettingsError) as err:
        check_encoder(EncoderSettings.from_dict(settings), tmp_path)
    assert err.value.detail.startswith(detail)
    assert err.value.codec == settings["codec"]
    assert "Fix: correct them in the codec preset" in str(err.value) and str(tmp_path) not in str(err.value)
