"""A LeRobot dataset read back through the real ``LeRobotDataset``, frame by frame, as numpy: what the
other formats' tests compare their output with."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

__all__ = ["LeRobotFrame", "lerobot_frames"]


@dataclass(frozen=True, slots=True)
class LeRobotFrame:
    episode_index: int
    frame_index: int
    timestamp: float
    task: str
    vectors: dict[str, npt.NDArray[np.float32]]
    images: dict[str, npt.NDArray[np.uint8]]
    """RGB ``HxWx3`` uint8, as LeRobot decodes them."""


def lerobot_frames(root: Path, repo_id: str = "test/formats") -> Iterator[LeRobotFrame]:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    from bagport.dataset.validate import video_backend  # noqa: PLC0415

    dataset = LeRobotDataset(repo_id, root=root, video_backend=video_backend())
    cameras = set(dataset.meta.video_keys)
    vectors = [k for k, v in dataset.meta.features.items() if v["dtype"] == "float32" and k not in cameras]
    for index in range(len(dataset)):
        item = dataset[index]
        yield LeRobotFrame(
            int(item["episode_index"]),
            int(item["frame_index"]),
            float(item["timestamp"]),
            str(item["task"]),
            {k: item[k].numpy() for k in vectors},
            {k: np.rint(item[k].numpy().transpose(1, 2, 0) * 255).astype(np.uint8) for k in cameras},
        )
