"""Give a synthetic MCAP bag publish times of its own (rosbags writes ``publish_time = log_time``).

A rosbag2 recorder that stores the publisher's send time (Jazzy and later) writes messages whose
``publish_time`` comes before their ``log_time``; this rewrites an MCAP file the same way.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from bagport.errors import BagportError

__all__ = ["rewrite_publish_times"]


def rewrite_publish_times(
    file: Path, publish_ns: Iterable[tuple[str, int, int]], *, crcs: bool = False
) -> None:
    """``publish_ns``: ``(topic, log_ns, publish_ns)`` per message; messages not listed keep theirs.
    The file is written with chunk CRCs; ``crcs`` adds a data-section CRC and makes 64 KiB chunks."""
    wanted: dict[tuple[str, int], list[int]] = defaultdict(list)
    for topic, log_ns, publish in publish_ns:
        wanted[(topic, log_ns)].append(publish)
    scratch = file.with_suffix(".rewrite")
    with file.open("rb") as source, scratch.open("wb") as target:
        reader = make_reader(source)
        header = reader.get_header()
        chunk_size = 64 * 1024 if crcs else 1024 * 1024
        writer = Writer(target, chunk_size, CompressionType.NONE, enable_crcs=True, enable_data_crcs=crcs)
        writer.start(profile=header.profile, library=header.library)
        summary = reader.get_summary()
        if summary is None:
            raise BagportError(f"{file}: MCAP file without a summary; nothing was rewritten.")
        schema_ids = {
            sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()
        }
        channel_ids = {
            cid: writer.register_channel(
                c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), c.metadata
            )
            for cid, c in summary.channels.items()
        }
        for _, channel, message in reader.iter_messages(log_time_order=False):
            pending = wanted.get((channel.topic, message.log_time))
            publish = pending.pop(0) if pending else message.publish_time
            writer.add_message(
                channel_ids[channel.id], message.log_time, message.data, publish, message.sequence
            )
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        writer.finish()  # type: ignore[no-untyped-call]
    scratch.replace(file)
