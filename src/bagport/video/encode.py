"""Encode frames to an MP4 clip as they arrive: pts = frame index, constant frame rate.

Colour clips take RGB uint8 (H, W, 3); depth clips (``pix_fmt`` ``gray12le``, see
:mod:`bagport.video.depth`) take 12-bit depth codes, uint16 (H, W).
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any

import av
import numpy as np
import numpy.typing as npt

from bagport.errors import EncoderSettingsError, FrameShapeError, VideoError
from bagport.video.depth import DEPTH_PIX_FMT
from bagport.video.settings import EncoderSettings

__all__ = ["ClipInfo", "StreamingEncoder", "check_encoder", "stream_codec"]


@dataclass(frozen=True, slots=True)
class ClipInfo:
    path: str
    frames: int
    fps: int
    width: int
    height: int
    codec: str
    pix_fmt: str
    size_bytes: int


class StreamingEncoder:
    """One clip; memory does not grow with the number of frames."""

    def __init__(
        self, path: str | Path, *, fps: int, width: int, height: int, settings: EncoderSettings
    ) -> None:
        if settings.pix_fmt.startswith("yuv420") and (width % 2 or height % 2):
            raise FrameShapeError(
                f"{width}x{height} frames cannot be encoded as {settings.pix_fmt} (needs even width and height)",
                path=str(path),
                fix="set 'image: {resize: [h, w]}' with even numbers for this camera in the contract.",
            )
        self._path = Path(path)
        self._fps = fps
        self._depth = settings.pix_fmt == DEPTH_PIX_FMT
        self._shape: tuple[int, ...] = (height, width) if self._depth else (height, width, 3)
        self._dtype = np.dtype(np.uint16 if self._depth else np.uint8)
        self._settings = settings
        try:
            self._container: Any = av.open(str(self._path), mode="w")
        except (av.error.FFmpegError, OSError) as err:
            raise VideoError(f"{path}: cannot create the clip ({err})") from err
        try:
            stream = _video_stream(
                self._container, path, fps=fps, width=width, height=height, settings=settings
            )
        except BaseException:
            self._container.close()
            raise
        self._stream: Any = stream
        self._frames = 0
        self._closed: ClipInfo | None = None

    def write(self, image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16]) -> None:
        """The next frame: RGB uint8 (H, W, 3), or for a depth clip uint16 depth codes (H, W)."""
        if image.shape != self._shape or image.dtype != self._dtype:
            raise FrameShapeError(
                f"frame {self._frames} is {image.dtype}{list(image.shape)}, the clip is {self._dtype}{list(self._shape)}",
                path=str(self._path),
                fix="set 'image: {resize: [h, w]}' so every frame has one size.",
            )
        if self._depth:
            frame = av.VideoFrame.from_ndarray(
                np.ascontiguousarray(image, dtype=np.uint16), format=DEPTH_PIX_FMT
            )
        else:
            frame = _video_frame(image.astype(np.uint8, copy=False))
        frame.pts = self._frames
        frame.time_base = Fraction(1, self._fps)
        try:
            for packet in self._stream.encode(frame):
                self._container.mux(packet)
        except av.error.FFmpegError as err:
            if self._frames == 0 and "avcodec_open2" in str(err.filename):  # opened at the first frame
                raise EncoderSettingsError(
                    f"{self._path}: encoder {self._settings.codec} refused its settings "
                    f"({_settings_text(self._settings)}): {err.strerror}. Fix: correct them in the codec preset.",
                    codec=self._settings.codec,
                    detail=f"{err.strerror} when {self._settings.codec} opened",
                ) from err
            raise VideoError(f"{self._path}: encoding frame {self._frames} failed: {err}") from err
        self._frames += 1

    def close(self) -> ClipInfo:
        if self._closed is not None:
            return self._closed
        try:
            if self._frames:
                for packet in self._stream.encode(None):
                    self._container.mux(packet)
        finally:
            self._container.close()
        if not self._frames:
            self._path.unlink(missing_ok=True)
            self._closed = ClipInfo(str(self._path), 0, self._fps, self._shape[1], self._shape[0], "", "", 0)
            return self._closed
        self._closed = ClipInfo(
            path=str(self._path),
            frames=self._frames,
            fps=self._fps,
            width=self._shape[1],
            height=self._shape[0],
            codec=_stream_codec_name(self._path, self._settings.codec),
            pix_fmt=self._settings.pix_fmt,
            size_bytes=self._path.stat().st_size,
        )
        return self._closed

    def __enter__(self) -> StreamingEncoder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _video_frame(rgb: npt.NDArray[np.uint8]) -> av.VideoFrame:
    """``rgb`` as a PyAV ``rgb24`` frame.

    A ``bgr8`` image arrives as a channel-reversed view of its BGR bytes (see
    :func:`bagport.decode.decode_image`); swscale swaps the channels of those bytes exactly in
    0.3 ms per 640x480 frame, where numpy's strided copy took 2 ms (a sixth of an episode).
    The encoder still gets ``rgb24``: feeding it ``bgr24`` directly is as fast but swscale's
    BGR-to-YUV path rounds worse (p99 error 5 levels instead of 2 here).
    """
    if rgb.strides[2] < 0:
        bgr = rgb[:, :, ::-1]
        if bgr.flags.c_contiguous:
            frame: av.VideoFrame = av.VideoFrame.from_ndarray(bgr, format="bgr24").reformat(format="rgb24")
            return frame
    return av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")


def _quiet(options: dict[str, str]) -> dict[str, str]:
    """x265 prints a page of banner per clip on stderr unless told otherwise (encoding unchanged)."""
    if "x265-params" in options and "log-level" not in options["x265-params"]:
        return {**options, "x265-params": options["x265-params"] + ":log-level=error"}
    return options


def stream_codec(encoder: str) -> str | None:
    """The codec of the streams ``encoder`` writes, as decoders and ``info.json``'s ``video.codec`` name it
    (``libsvtav1`` -> ``av1``, ``libx264`` -> ``h264``), without encoding anything; ``None`` for an encoder
    this PyAV build lacks (starting it says so)."""
    try:
        return str(av.Codec(encoder, "w").canonical_name)
    except ValueError:  # av's UnknownCodecError
        return None


_CODEC_NAMES: dict[str, str] = {}
"""Encoder name -> the codec name its clips have (read from the first clip this process wrote)."""


def _stream_codec_name(path: Path, encoder: str) -> str:
    """The stream's codec as decoders name it (``av1``, ``h264``), as LeRobot records it: read from the
    first clip an encoder wrote in this process (the same encoder always writes the same codec)."""
    name = _CODEC_NAMES.get(encoder)
    if name is not None:
        return name
    container: Any = av.open(str(path))
    try:
        name = _CODEC_NAMES[encoder] = str(container.streams.video[0].codec.canonical_name)
    finally:
        container.close()
    return name


def _video_stream(
    container: Any, path: str | Path, *, fps: int, width: int, height: int, settings: EncoderSettings
) -> Any:
    """The clip's video stream in ``container``; settings that cannot make one raise :class:`EncoderSettingsError`."""
    try:
        stream: Any = container.add_stream(settings.codec, rate=fps, options=_quiet(settings.codec_options()))
    except (av.error.FFmpegError, ValueError) as err:
        raise EncoderSettingsError(
            f"{path}: cannot start encoder {settings.codec!r} ({err}). Fix: pick a codec this PyAV build has "
            "(libsvtav1, libx264) in the codec preset.",
            codec=settings.codec,
            detail=f"no encoder {settings.codec!r} in this PyAV build (libsvtav1 and libx264 are)",
        ) from err
    if stream.type != "video":
        raise EncoderSettingsError(
            f"{path}: {settings.codec!r} is an encoder of {stream.type}, not video. Fix: pick a video codec "
            "(libsvtav1, libx264) in the codec preset.",
            codec=settings.codec,
            detail=f"{settings.codec!r} encodes {stream.type}, not video",
        )
    stream.width, stream.height = width, height
    try:
        stream.pix_fmt = settings.pix_fmt
    except ValueError as err:
        raise EncoderSettingsError(
            f"{path}: {err}. Fix: set pix_fmt to one {settings.codec} takes (yuv420p) in the codec preset.",
            codec=settings.codec,
            detail=f"pix_fmt {settings.pix_fmt!r} is not a pixel format FFmpeg knows",
        ) from err
    stream.time_base = Fraction(1, fps)
    return stream


def _settings_text(settings: EncoderSettings) -> str:
    options = {"pix_fmt": settings.pix_fmt, **settings.codec_options()}
    return ", ".join(f"{key}={value}" for key, value in options.items())


def check_encoder(settings: EncoderSettings, folder: Path) -> None:
    """Encode one black 64x64 frame with ``settings`` into ``folder``: settings the encoder refuses (an option
    out of range or of the wrong kind, a pixel format it lacks) fail here once, before any episode, instead
    of in every episode with the same error (:class:`EncoderSettingsError`, naming the settings)."""
    depth = settings.pix_fmt == DEPTH_PIX_FMT
    frame = np.zeros((64, 64) if depth else (64, 64, 3), dtype=np.uint16 if depth else np.uint8)
    try:
        with StreamingEncoder(
            folder / "encoder-check.mp4", fps=30, width=64, height=64, settings=settings
        ) as clip:
            clip.write(frame)
    except EncoderSettingsError as err:
        raise EncoderSettingsError(
            f"the codec settings cannot encode video: {err.detail} ({_settings_text(settings)}). Fix: correct "
            "them in the codec preset (--codec; configs/codecs/*.yaml are known to work).",
            codec=err.codec,
            detail=err.detail,
        ) from err
