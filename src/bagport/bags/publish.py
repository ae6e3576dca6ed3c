"""MCAP ``publish_time`` per message: the time the publisher sent it (``stamp: publish``).

rosbags yields only the log (receive) time, so the publish times are read with the ``mcap``
library, per topic in log-time order, the order every reader of this package yields.
ROS 1 and SQLite bags do not record a publish time.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import IO, Any, cast

import numpy as np
import numpy.typing as npt
from backports import zstd
from mcap.exceptions import McapError
from mcap.reader import McapReader, make_reader

from bagport.bags.damage import damaged_bag
from bagport.bags.records import Storage, compressed_whole
from bagport.bags.remote import RemotePath
from bagport.errors import BagReadError
from bagport.msgtypes import global_topic

__all__ = ["mcap_publish_times_ns"]

Int64Array = npt.NDArray[np.int64]


def mcap_publish_times_ns(
    files: Sequence[Path | RemotePath], topics: Iterable[str], uri: str
) -> dict[str, tuple[Int64Array, Int64Array]]:
    """Per topic: ``(log_ns, publish_ns)`` sorted by log time (ties keep file order), from the
    bag's ``.mcap`` files (local, or remote and read through the same ranged reads and spill)."""
    wanted = tuple(global_topic(t) for t in topics)
    if not wanted:  # nothing asked: no file is opened (a file-compressed one would be read whole)
        return {}
    recorded = [*wanted, *(t.removeprefix("/") for t in wanted)]  # a relative name is the global one
    pairs: dict[str, list[tuple[int, int]]] = {t: [] for t in wanted}
    try:
        for file in files:
            with file.open("rb") as handle:
                for _, channel, message in _mcap_reader(handle, file.name).iter_messages(topics=recorded):
                    pairs[global_topic(channel.topic)].append(
                        (int(message.log_time), int(message.publish_time))
                    )
    except (KeyError, IndexError, struct.error) as err:  # the mcap library on a damaged summary or record
        raise damaged_bag(  # MCAP: its fixes do not depend on a metadata.yaml
            err,
            uri=uri,
            storage=Storage.MCAP,
            files=files,
            action="its publish times cannot be read",
            metadata_yaml=False,
        ) from err
    except (McapError, OSError, ValueError) as err:
        raise BagReadError(
            f"publish times cannot be read ({type(err).__name__}: {err})",
            uri=uri,
            fix="use 'align: {stamp: receive}' or 'stamp: header' for this bag.",
        ) from err
    out: dict[str, tuple[Int64Array, Int64Array]] = {}
    for topic, rows in pairs.items():
        array = np.asarray(rows, dtype=np.int64).reshape(-1, 2)
        order = np.argsort(array[:, 0], kind="stable")
        out[topic] = (array[order, 0], array[order, 1])
    return out


class _ForwardOnly:
    """A stream read front to back only: the mcap library then reads records in file order, with no seek
    to a summary at the end (which a decompressing stream could only reach by decompressing it all, twice)."""

    def __init__(self, stream: zstd.ZstdFile) -> None:
        self._stream = stream

    def read(self, size: int = -1) -> bytes:
        return self._stream.read(size)

    def seekable(self) -> bool:
        return False


def _mcap_reader(handle: Any, name: str) -> McapReader:
    """The mcap library's reader of one data file; a file-compressed one (``.mcap.zstd``: rosbag2's
    ``compression_mode: file``) through its decompression, as rosbags reads it (the rows are sorted after)."""
    if compressed_whole(name):
        return make_reader(cast(IO[bytes], _ForwardOnly(zstd.ZstdFile(handle))))
    return make_reader(handle)
