"""``bagport validate``: the invariants, then the real consumer (LeRobot) decodes every frame."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bagport.dataset.checksums import verify_checksums
from bagport.dataset.invariants import DATASET_FIX, check_invariants
from bagport.dataset.repair import interrupted_write
from bagport.errors import ValidationError

__all__ = ["ValidationReport", "validate_dataset", "video_backend"]


@dataclass(frozen=True, slots=True)
class ValidationReport:
    root: str
    episodes: int
    frames: int
    frames_decoded: int
    video_keys: tuple[str, ...]
    video_backend: str
    files_checked: int = 0
    """Files whose SHA-256 matched the run record's (0: the dataset records none)."""


def validate_dataset(
    root: str | Path,
    *,
    repo_id: str | None = None,
    decode_every: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> ValidationReport:
    """Check invariants, load with ``lerobot.LeRobotDataset`` offline, decode frames.

    ``decode_every=1`` decodes every frame of every episode (the default); a larger
    value samples every n-th frame plus each episode's last frame.
    """
    path = Path(root)
    interrupted = interrupted_write(path)
    if interrupted is not None:
        raise ValidationError(
            f"needs repair: {interrupted}",
            path=path,
            fix=f"run `bagport repair {path}` (or the same conversion again), which finishes or undoes that write.",
        )
    checked = verify_checksums(path)  # first: a changed file is named as changed, whatever it breaks
    info = check_invariants(path)
    dataset = _load_with_lerobot(path, repo_id)
    total = len(dataset)
    if total != info["total_frames"]:
        raise ValidationError(
            f"LeRobot sees {total} frames, info.json says {info['total_frames']}", path=path, fix=DATASET_FIX
        )
    video_keys = tuple(dataset.meta.video_keys)
    indices = _indices(dataset, decode_every)
    _decode_frames(path, dataset, indices, video_keys, info, progress)
    return ValidationReport(
        str(path),
        dataset.meta.total_episodes,
        total,
        len(indices),
        video_keys,
        str(dataset._video_backend),
        checked,
    )


def _load_with_lerobot(path: Path, repo_id: str | None) -> Any:
    """The dataset as LeRobot's own loader opens it, offline (``HF_HUB_OFFLINE``)."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")  # noqa: TID251 - the one exception (docs/architecture.md)
    try:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - optional, heavy
    except ImportError as err:
        raise ValidationError(
            "the lerobot package is not installed, so the dataset cannot be loaded by LeRobot",
            path=None,
            fix="install bagport with the 'lerobot' extra (the README's set-up command does).",
        ) from err
    try:
        return LeRobotDataset(repo_id or f"local/{path.name}", root=path, video_backend=video_backend())
    except Exception as err:
        raise ValidationError(
            f"LeRobotDataset failed to load it: {type(err).__name__}: {err}",
            path=path,
            fix=f"install the lerobot bagport pins (its 'lerobot' extra); if that one is installed, {DATASET_FIX}",
        ) from err


def _decode_frames(
    path: Path,
    dataset: Any,
    indices: Sequence[int],
    video_keys: Sequence[str],
    info: dict[str, Any],
    progress: Callable[[int, int], None] | None,
) -> None:
    """Read the frames at ``indices`` through LeRobot, each camera's decoded at the shape ``info`` gives."""
    for n, index in enumerate(indices):
        try:
            item = dataset[index]
        except Exception as err:
            raise ValidationError(
                f"LeRobot failed to read frame index={index}: {type(err).__name__}: {err}",
                path=path,
                fix=DATASET_FIX,
            ) from err
        for key in video_keys:
            frame = item[key]
            if tuple(frame.shape[-2:]) != tuple(info["features"][key]["shape"][:2]):
                raise ValidationError(
                    f"frame {index} of {key} decoded with shape {tuple(frame.shape)}",
                    path=path,
                    fix=DATASET_FIX,
                )
        if progress is not None:
            progress(n + 1, len(indices))


def video_backend() -> str:
    """LeRobot's default decoder (torchcodec) when it loads on this machine, else PyAV.

    torchcodec needs FFmpeg's shared libraries; without them LeRobot falls back to PyAV
    after printing a long traceback.  Decide quietly instead.
    """
    import contextlib  # noqa: PLC0415
    import importlib  # noqa: PLC0415
    import io  # noqa: PLC0415
    import logging  # noqa: PLC0415

    sink = io.StringIO()
    previous = logging.root.manager.disable
    logging.disable(logging.CRITICAL)
    try:
        with contextlib.redirect_stderr(sink), contextlib.redirect_stdout(sink):
            importlib.import_module("torchcodec.decoders")
    except (ImportError, OSError, RuntimeError):
        return "pyav"
    finally:
        logging.disable(previous)
    return "torchcodec"


def _indices(dataset: object, every: int) -> list[int]:
    total = len(dataset)  # type: ignore[arg-type]
    if every <= 1:
        return list(range(total))
    meta = dataset.meta  # type: ignore[attr-defined]
    picked: set[int] = set(range(0, total, every))
    for ep in range(meta.total_episodes):
        picked.add(int(meta.episodes[ep]["dataset_to_index"]) - 1)
    return sorted(picked)
