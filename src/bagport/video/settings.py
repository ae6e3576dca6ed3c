"""Encoder settings. :class:`EncoderSettings` defaults to LeRobot's (libsvtav1, yuv420p, g=2, crf=30,
preset=12); a conversion's default is :data:`DEFAULT_ENCODER` (H.264), chosen on evidence."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from bagport.errors import VideoError

__all__ = ["DEFAULT_ENCODER", "EncoderSettings", "default_encoder"]

_SVTAV1 = "libsvtav1"


DEFAULT_ENCODER: Mapping[str, Any] = {
    "codec": "libx264",
    "pix_fmt": "yuv420p",
    "g": 2,
    "crf": 23,
    "preset": "veryfast",
}
"""What ``bagport convert`` encodes with unless told otherwise (``configs/codecs/h264-fast.yaml``).

Not LeRobot's default: on the benchmark's camera streams (640x480 JPEG with sensor noise) libsvtav1
preset 12 crf 30 g 2 encoded 4-19% of frames with whole regions wrong (PSNR 17 dB against the frame
it was given; both dav1d and libaom decode them the same), and libx264 veryfast crf 23 g 2 none, at
up to 1.8x the file size (one episode alone encoded ~35% slower; a whole two-worker W1 run was
24% faster). BENCHMARKS.md has the study. LeRobot decodes
H.264; ``--codec lerobot-default`` gives LeRobot's AV1 settings (the fidelity check flags the damage).
"""


def default_encoder() -> dict[str, Any]:
    """A fresh copy of :data:`DEFAULT_ENCODER`."""
    return dict(DEFAULT_ENCODER)


_KINDS: dict[str, tuple[str, tuple[type, ...], bool]] = {
    "codec": ("an encoder name (libx264, libsvtav1)", (str,), False),
    "pix_fmt": ("a pixel format name (yuv420p)", (str,), False),
    "g": ("a whole number of frames", (int,), True),
    "crf": ("a number", (int, float), True),
    "preset": ("a number or a name", (int, str), True),
    "fast_decode": ("a whole number (0-2)", (int,), False),
    "threads": ("a whole number", (int,), True),
    "extra_options": ("a mapping of FFmpeg option names to values", (dict,), True),
}
"""Each setting's kind as the message says it, the types it takes, and whether it may be null."""


def _check_types(values: Mapping[str, Any]) -> None:
    """A setting of the wrong kind (``crf: high``) is refused here, not by the encoder of every episode."""
    for name, value in values.items():
        kind, types, nullable = _KINDS[name]
        if value is None and nullable:
            continue
        if isinstance(value, bool) or not isinstance(value, types):
            raise VideoError(
                f"encoder setting {name}: {value!r} is not {kind}"
                + (" (or null for the encoder's default)" if nullable else "")
                + ". Fix: correct it in the codec preset (--codec, configs/codecs/*.yaml)."
            )


@dataclass(frozen=True, slots=True)
class EncoderSettings:
    codec: str = _SVTAV1
    pix_fmt: str = "yuv420p"
    g: int | None = 2
    crf: float | None = 30
    preset: int | str | None = 12
    fast_decode: int = 0
    threads: int | None = None
    extra_options: Mapping[str, str] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> EncoderSettings:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise VideoError(
                f"unknown encoder setting(s) {unknown}; known: {sorted(known)}. "
                "Fix: correct the codec preset (configs/codecs/*.yaml)."
            )
        values = dict(data)
        _check_types(values)
        if "extra_options" in values:
            values["extra_options"] = {str(k): str(v) for k, v in dict(values["extra_options"] or {}).items()}
        if values.get("codec", _SVTAV1) != _SVTAV1 and "preset" not in values:
            values["preset"] = None
        settings = cls(**values)
        if settings.g is not None and settings.g < 1:
            raise VideoError(f"encoder setting g={settings.g} must be >= 1")
        return settings

    def key(self) -> str:
        """The settings as canonical text (for the ids and keys of what they encode)."""
        return json.dumps(asdict(self), sort_keys=True)

    def codec_options(self) -> dict[str, str]:
        """Options for ``av`` ``add_stream``, the way LeRobot 0.6 builds them."""
        opts: dict[str, str] = {}
        if self.g is not None:
            opts["g"] = str(self.g)
        if self.crf is not None:
            opts["crf"] = str(self.crf)
        if self.preset is not None:
            opts["preset"] = str(self.preset)
        if self.codec == _SVTAV1:
            parts = [f"fast-decode={max(0, min(2, self.fast_decode))}"] if self.fast_decode else []
            if self.threads is not None:
                parts.append(f"lp={self.threads}")
            if parts:
                opts["svtav1-params"] = ":".join(parts)
        else:
            if self.fast_decode:
                opts["tune"] = "fastdecode"
            if self.threads is not None:
                opts["threads"] = str(self.threads)
        for key, value in self.extra_options.items():
            opts.setdefault(key, value)
        return opts

    def to_info(self) -> dict[str, Any]:
        """The encoder keys LeRobot 0.6 records in ``features[key]["info"]``."""
        return {
            "video.g": self.g,
            "video.crf": self.crf,
            "video.preset": self.preset,
            "video.fast_decode": self.fast_decode,
            "video.video_backend": "pyav",
            "video.extra_options": dict(self.extra_options),
        }
