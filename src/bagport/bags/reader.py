"""Open any supported bag by URI and stream its messages (rosbags underneath)."""

from __future__ import annotations

import contextlib
import json
import shutil
import struct
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from backports import zstd
from fsspec.core import url_to_fs
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore

from bagport.bags.bundled import BUNDLED_DEFINITIONS
from bagport.bags.checksums import bag_checksums
from bagport.bags.damage import STORAGE_ERRORS, checked_records, damaged_bag, short_read
from bagport.bags.detect import detect_storage
from bagport.bags.download import download_bag
from bagport.bags.indexcount import index_time_range, window_counts
from bagport.bags.interface import BagReader
from bagport.bags.layout import BagPath, ReadPlan, plan_reads
from bagport.bags.mcap_layout import check_profiles, check_summaries
from bagport.bags.message import BagMessage, HeaderLayout
from bagport.bags.publish import Int64Array, mcap_publish_times_ns
from bagport.bags.records import BagInfo, Storage, TopicInfo
from bagport.bags.remote import RemoteBag, RemotePath, TransferStats
from bagport.bags.typeload import TolerantAnyReader, is_service_event
from bagport.bags.typesources import (
    CheckedDeserializer,
    complete_bag_types,
    parse_msg_definitions,
    undefined_type_error,
)
from bagport.errors import BagportError, BagReadError
from bagport.msgtypes import RosType, global_topic, normalize_msgtype
from bagport.scratch import scratch_dir
from bagport.uris import is_local

__all__ = ["BagReader", "open_bag"]

_HEADER = "std_msgs/msg/Header"
_TIME = "builtin_interfaces/msg/Time"
_STAMP_FIRST = frozenset({RosType.COMPRESSED_VIDEO.value})
"""Types without a Header whose first field is the capture time (foxglove's ``timestamp``)."""
RANGED_STORAGES = frozenset({Storage.MCAP})
"""Read in place on remote stores (summary + chunk index); other formats are downloaded first."""


class RosbagsReader:
    """``BagReader`` over rosbags' AnyReader: rosbag2 (MCAP, SQLite) and ROS 1."""

    def __init__(
        self,
        uri: str,
        path: BagPath,
        storage: Storage,
        cleanup: Path | None,
        remote: RemoteBag | None = None,
        msg_definitions: Mapping[str, str] | None = None,
    ) -> None:
        self._uri = uri
        self._cleanup = cleanup
        self._remote = remote
        self._scratch: Path | None = None  # made only when a file needs another name (_link_folder)
        try:
            plan = plan_reads(path, storage, self._link_folder, uri)
        except BaseException:
            self.close()
            raise
        self._decompress = plan.message_compression
        self._mcap_files = plan.data_files if storage is Storage.MCAP else []
        self._data_files = plan.data_files
        self._metadata_yaml = plan.metadata_yaml
        self._lacking = self._open(plan, storage, msg_definitions)
        self._info = self._bag_info(storage, plan)
        self._layout = HeaderLayout.ROS1 if storage is Storage.ROS1 else HeaderLayout.CDR
        if remote is not None:
            self._transfer = remote.stats
        elif cleanup is not None:
            size = self._info.size_bytes
            self._transfer = TransferStats("download", bytes_read=size, requests=len(plan.files))
        else:
            self._transfer = TransferStats("local")

    def _open(
        self, plan: ReadPlan, storage: Storage, msg_definitions: Mapping[str, str] | None
    ) -> dict[str, str]:
        """Open rosbags' reader on the planned files with every type it can load (the bag's own, bagport's
        bundled ones, ``msg_definitions``); returns the types still lacking a definition. A bag that cannot
        be opened closes this reader and raises :class:`BagReadError` (its damage located)."""
        uri = self._uri
        store = Stores.ROS1_NOETIC if storage is Storage.ROS1 else Stores.ROS2_HUMBLE
        mcap_files = plan.data_files if storage is Storage.MCAP else []
        try:
            ours = parse_msg_definitions(BUNDLED_DEFINITIONS, "bagport's bundled types")
            given = parse_msg_definitions(msg_definitions or {})
            extra = {**ours, **given}
            bundled = get_typestore(store)
            # the type store is shared by bags with the same definitions, storage and extra types
            store_key = f"{store}:{json.dumps(sorted((msg_definitions or {}).items()))}"
            self._reader: Any = TolerantAnyReader(plan.paths, default_typestore=bundled, store_key=store_key)
            self._reader.open()
            check_summaries(uri, mcap_files)
            msgtypes = {normalize_msgtype(c.msgtype) for c in self._reader.connections}
            lacking, sources = complete_bag_types(
                self._reader, msgtypes, extra, bundled, store.name.replace("_", " ")
            )
            for msgtype in set(ours) - set(given):  # foxglove/ffmpeg packets: bagport ships their .msg
                if sources.get(msgtype, "").startswith("--msg-path"):
                    sources[msgtype] = f"bagport's bundled {msgtype} definition"
            self._deserialize = CheckedDeserializer(uri, self._reader.deserialize, sources)
        except BagportError:
            self.close()
            raise
        except STORAGE_ERRORS as err:
            try:
                # rosbags refuses an MCAP file of another profile ("Profile is not ros2"), which reads as
                # damage: say what the file is (read only when opening failed: a request per remote file)
                check_profiles(uri, mcap_files, metadata_yaml=plan.metadata_yaml)
                error = damaged_bag(
                    err,
                    uri=uri,
                    storage=storage,
                    files=plan.data_files,
                    action="cannot be opened",
                    metadata_yaml=plan.metadata_yaml,
                )
            finally:
                self.close()
            raise error from err
        except BaseException:  # TransientError from a ranged read, KeyboardInterrupt
            self.close()
            raise
        return lacking

    def _bag_info(self, storage: Storage, plan: ReadPlan) -> BagInfo:
        """The open bag's facts; keeps what its index promises per topic (:meth:`_check_counts`)."""
        counts: dict[str, tuple[str, int]] = {}
        for conn in self._reader.connections:
            topic = global_topic(conn.topic)
            msgtype, count = counts.get(topic, (normalize_msgtype(conn.msgtype), 0))
            counts[topic] = (msgtype, count + int(conn.msgcount))
        self._promised = {topic: count for topic, (_, count) in counts.items()}
        message_count = int(self._reader.message_count)
        listed_ns = (int(self._reader.start_time), int(self._reader.end_time)) if message_count else (0, 0)
        start_ns, end_ns, stale = self._times(*listed_ns) if message_count else (0, 0, ())
        return BagInfo(
            uri=self._uri,
            storage=storage,
            files=tuple(sorted(p.name for p in plan.files)),
            size_bytes=sum(p.stat().st_size for p in plan.files),
            start_ns=start_ns,
            end_ns=end_ns,
            message_count=message_count,
            topics=tuple(TopicInfo(name, mt, c) for name, (mt, c) in sorted(counts.items())),
            custom_data=plan.custom_data,
            checksums=bag_checksums(storage, plan.data_files),
            warnings=(*plan.warnings, *self._reader.warnings(), *stale),
            listed_span_ns=listed_ns if stale else None,
        )

    def _times(self, start_ns: int, end_ns: int) -> tuple[int, int, tuple[str, ...]]:
        """The bag's first log time and one past its last, from its data files' indexes where they say
        (:func:`index_time_range`), with a warning when ``metadata.yaml`` says otherwise: windows
        (``start_s``/``end_s``) and a whole-bag episode count from these times, so stale metadata (the real
        ``wbag``'s covers only the last of its five files) must not cut the recording short. ``start_ns``,
        ``end_ns``: the times rosbags gives (``metadata.yaml``'s for a rosbag2 folder)."""
        try:
            found = index_time_range(self._reader)
        except STORAGE_ERRORS:
            found = None  # reading the messages says what is wrong
        if found is None or (found[0], found[1] + 1) == (start_ns, end_ns):
            return start_ns, end_ns, ()
        first_ns, last_ns = found
        stale = (
            f"metadata.yaml gives the recording's log times as {start_ns}..{end_ns - 1} ns but its data files "
            f"hold messages from {first_ns} to {last_ns} ns: the data files' times are used (metadata.yaml was "
            "written for another file of the recording, or edited; `ros2 bag reindex` rewrites it)"
        )
        return first_ns, last_ns + 1, (stale,)

    @property
    def transfer(self) -> TransferStats:
        """What reading this bag cost on its store so far (bytes, requests, how it was accessed)."""
        return self._transfer

    @property
    def info(self) -> BagInfo:
        return self._info

    @property
    def undefined_types(self) -> dict[str, str]:
        conns = self._reader.connections
        return {
            global_topic(c.topic): t for c in conns if (t := normalize_msgtype(c.msgtype)) in self._lacking
        }

    def _header_layout(self, msgtype: str) -> str | None:
        fields = self._reader.typestore.fielddefs.get(msgtype)
        if not fields or not fields[1]:
            return None
        _, (nodetype, detail) = fields[1][0]
        if nodetype == Nodetype.NAME and detail == _TIME and msgtype in _STAMP_FIRST:
            return HeaderLayout.ROS1_TIME if self._layout == HeaderLayout.ROS1 else HeaderLayout.CDR
        return self._layout if nodetype == Nodetype.NAME and detail == _HEADER else None

    def _connections(self, topics: Sequence[str] | None) -> list[Any]:
        """Connections to read: the requested topics (global names: ``/joint_states`` also reads a
        ROS 1 bag's relative ``joint_states``), or every data topic (no service events, no types that
        could not be loaded). A requested topic of an unloadable type is an error."""
        unloadable: dict[str, str] = self._reader.unloadable
        if topics is None:
            return [
                c
                for c in self._reader.connections
                if normalize_msgtype(c.msgtype) not in unloadable and not is_service_event(c.topic, c.msgtype)
            ]
        wanted = frozenset(global_topic(t) for t in topics)
        conns = [c for c in self._reader.connections if global_topic(c.topic) in wanted]
        for conn in conns:
            msgtype = normalize_msgtype(conn.msgtype)
            if msgtype in unloadable:
                raise BagReadError(
                    f"topic {global_topic(conn.topic)} has type {msgtype}, which cannot be loaded: "
                    f"{unloadable[msgtype]}",
                    uri=self._uri,
                    topic=global_topic(conn.topic),
                    fix="provide the type's .msg definition with --msg-path, or drop the topic from the contract.",
                )
        return conns

    def messages(
        self, topics: Sequence[str] | None = None, *, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[BagMessage]:
        conns = self._connections(topics)
        if not conns:
            return
        names = {(c.topic, c.msgtype): (global_topic(c.topic), normalize_msgtype(c.msgtype)) for c in conns}
        for topic, msgtype in names.values():
            if msgtype in self._lacking:
                raise undefined_type_error(self._uri, topic, msgtype, self._lacking[msgtype])
        layouts = {msgtype: self._header_layout(msgtype) for _, msgtype in names.values()}
        deserialize = self._deserialize
        yielded = dict.fromkeys((topic for topic, _ in names.values()), 0)
        records = checked_records(
            self._reader.messages(connections=conns, start=start_ns, stop=stop_ns),
            uri=self._uri,
            storage=self._info.storage,
            files=self._data_files,
            metadata_yaml=self._metadata_yaml,
        )
        for conn, log_ns, raw in records:
            topic, msgtype = names[conn.topic, conn.msgtype]
            try:
                payload = zstd.decompress(raw) if self._decompress else raw
            except zstd.ZstdError as err:
                raise BagReadError(
                    f"a message on {topic} at log time {log_ns} ns does not decompress ({err})",
                    uri=self._uri,
                    topic=topic,
                    fix="copy the bag again from the robot or a backup; its bytes changed after recording.",
                ) from err
            yielded[topic] += 1
            yield BagMessage(topic, msgtype, log_ns, payload, deserialize, layouts[msgtype], self._uri)
        window = "" if start_ns is None and stop_ns is None else f" in [{start_ns}, {stop_ns}) ns"
        self._check_counts(yielded, self._promised_in(conns, start_ns, stop_ns), window)

    def _promised_in(self, conns: list[Any], start_ns: int | None, stop_ns: int | None) -> dict[str, int]:
        """Messages per topic the bag promises in ``[start_ns, stop_ns)``: the metadata's (or index's)
        totals when the window holds the whole bag, else what the data files' indexes count inside it
        (topics of an MCAP file without chunks have no count there, and go unchecked)."""
        if (start_ns is None or start_ns <= self._info.start_ns) and (
            stop_ns is None or stop_ns >= self._info.end_ns
        ):
            return self._promised
        try:
            counts: dict[str, int] = {}
            for topic, count in window_counts(self._reader, conns, start_ns, stop_ns).items():
                counts[global_topic(topic)] = counts.get(global_topic(topic), 0) + count
            return counts
        except (OSError, ValueError, KeyError, IndexError, struct.error) as err:
            storage, files, action = self._info.storage, self._data_files, "its message index cannot be read"
            raise damaged_bag(
                err,
                uri=self._uri,
                storage=storage,
                files=files,
                action=action,
                metadata_yaml=self._metadata_yaml,
            ) from err

    def _check_counts(self, yielded: dict[str, int], promises: Mapping[str, int], window: str) -> None:
        """Fewer messages than the index promises is an error naming the topic, never a short dataset."""
        for topic, count in yielded.items():
            promised = promises.get(topic, 0)
            if count < promised:
                what = f"yielded {count} messages on {topic}{window}, its index promises {promised}"
                raise short_read(
                    what,
                    uri=self._uri,
                    topic=topic,
                    storage=self._info.storage,
                    files=self._data_files,
                    metadata_yaml=self._metadata_yaml,
                )

    def publish_times_ns(self, topics: Sequence[str]) -> dict[str, tuple[Int64Array, Int64Array]]:
        """Per topic ``(log_ns, publish_ns)`` in log order; empty when the storage has no publish time."""
        if not self._mcap_files:
            return {}
        return mcap_publish_times_ns(self._mcap_files, topics, self._uri)

    def _link_folder(self) -> Path:
        """This reader's scratch folder for the links that rename a bag's files, made at its first use (a
        rosbag2 folder read as it is needs none: a folder made and removed per bag cost 1-6 ms)."""
        if self._scratch is None:
            self._scratch = scratch_dir("link")
        return self._scratch

    def close(self) -> None:
        reader = getattr(self, "_reader", None)
        if reader is not None and getattr(reader, "isopen", True):
            with contextlib.suppress(Exception):
                reader.close()
        if self._scratch is not None:
            shutil.rmtree(self._scratch, ignore_errors=True)
        remote = getattr(self, "_remote", None)
        if remote is not None:
            remote.close()
        if self._cleanup is not None:
            shutil.rmtree(self._cleanup, ignore_errors=True)

    def __enter__(self) -> RosbagsReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _open_ranged(
    uri: str, storage_options: Mapping[str, Any], msg_definitions: Mapping[str, str] | None
) -> RosbagsReader | None:
    """A reader over a remote MCAP bag read in place with ranged reads; ``None`` to download it."""
    try:
        fs, path = url_to_fs(uri, **storage_options)
    except (ValueError, ImportError):
        return None
    if is_local(fs):
        return None
    remote = RemoteBag(fs, uri)
    try:
        root = RemotePath(remote, path)
        storage = detect_storage(root, uri)
    except (BagportError, OSError):
        remote.close()
        return None  # the download path reports it with the right error class
    if storage not in RANGED_STORAGES:
        remote.close()
        return None
    return RosbagsReader(uri, root, storage, None, remote, msg_definitions)


def open_bag(
    uri: str,
    *,
    storage_options: Mapping[str, Any] | None = None,
    msg_definitions: Mapping[str, str] | None = None,
) -> BagReader:
    """Open a rosbag2 folder, an .mcap, a .db3 or a ROS 1 .bag from any fsspec URI.

    A remote MCAP bag is read in place (its summary, then only the chunks holding the
    topics asked for); other remote bags are downloaded to a private temp folder first.
    ``msg_definitions`` (``{type name: .msg text}``, see :func:`bagport.bags.read_msg_path`) define
    types the bag does not embed and no bundled type store has.
    """
    ranged = _open_ranged(uri, storage_options or {}, msg_definitions)
    if ranged is not None:
        return ranged
    local, cleanup = download_bag(uri, storage_options or {})
    try:
        storage = detect_storage(local, uri)
        return RosbagsReader(uri, local, storage, cleanup, None, msg_definitions)
    except BagportError:
        if cleanup is not None:
            shutil.rmtree(cleanup, ignore_errors=True)
        raise
