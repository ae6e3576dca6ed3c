"""MCAP ``publish_time`` per message: the time the publisher sent it (``stamp: publish``).

rosbags yields only the log (receive) time, so the publish times are read with the ``mcap``
library, per topic in log-time order, the order every reader of this package yields.
ROS 1 and SQLite bags do not record a publish time.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt
from mcap.exceptions import McapError
from mcap.reader import make_reader

from bagport.bags.damage import damaged_bag
from bagport.bags.records import Storage
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
    recorded = [*wanted, *(t.removeprefix("/") for t in wanted)]  # a relative name is the global one
    pairs: dict[str, list[tuple[int, int]]] = {t: [] for t in wanted}
    try:
        for file in files:
            with file.open("rb") as handle:
                for _, channel, message in make_reader(handle).iter_messages(topics=recorded):
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
