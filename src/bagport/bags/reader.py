"""Open any supported bag by URI and stream its messages (rosbags underneath)."""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import yaml
from fsspec.core import url_to_fs
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Nodetype
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.typesys import Stores, get_typestore

from bagport.bags.detect import detect_storage
from bagport.bags.message import BagMessage, HeaderLayout
from bagport.bags.records import BagInfo, Storage, TopicInfo
from bagport.bags.typesources import complete_typestore, parse_msg_definitions, undefined_type_error
from bagport.errors import BagportError, BagReadError, TransientError
from bagport.uris import is_local

__all__ = ["BagReader", "open_bag"]

_HEADER = "std_msgs/msg/Header"
_SUFFIX = {Storage.ROS1: ".bag", Storage.MCAP: ".mcap", Storage.SQLITE3: ".db3"}
_ROSBAGS_ERRORS = (AnyReaderError, Ros1ReaderError, Ros2ReaderError)


class BagReader(Protocol):
    @property
    def info(self) -> BagInfo: ...

    def messages(self, topics: Sequence[str] | None = None) -> Iterator[BagMessage]: ...

    def close(self) -> None: ...

    @property
    def undefined_types(self) -> dict[str, str]:
        """``{topic: msgtype}`` of topics whose type no source defines (reading them fails)."""
        ...

    def __enter__(self) -> BagReader: ...

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None: ...


def _custom_data(path: Path) -> dict[str, str]:
    metadata = path / "metadata.yaml" if path.is_dir() else None
    if metadata is None or not metadata.is_file():
        return {}
    try:
        info = yaml.safe_load(metadata.read_text()) or {}
        data = info.get("rosbag2_bagfile_information", {}).get("custom_data") or {}
    except (yaml.YAMLError, OSError, AttributeError):
        return {}
    return {str(k): str(v) for k, v in dict(data).items()}


def _reader_paths(path: Path, storage: Storage, scratch: Path) -> list[Path]:
    """Paths for AnyReader, which goes by file name: files whose suffix does not match their content
    (a ROS 1 bag without ``.bag``, a rosbag2 folder named ``*.bag``) are linked under a fitting name."""
    if path.is_file():
        suffix = _SUFFIX[storage]
        if path.suffix == suffix:
            return [path]
        link = scratch / f"bag{suffix}"
        link.symlink_to(path.resolve())
        return [link]
    if (path / "metadata.yaml").is_file():
        if path.suffix == ".bag":
            link = scratch / "bag"
            link.symlink_to(path.resolve(), target_is_directory=True)
            return [link]
        return [path]
    suffix = ".mcap" if storage is Storage.MCAP else ".db3"
    return sorted(p for p in path.iterdir() if p.suffix == suffix)


class RosbagsReader:
    """``BagReader`` over rosbags' AnyReader: rosbag2 (MCAP, SQLite) and ROS 1."""

    def __init__(
        self,
        uri: str,
        path: Path,
        storage: Storage,
        cleanup: Path | None,
        msg_definitions: Mapping[str, str] | None = None,
    ) -> None:
        self._uri = uri
        self._cleanup = cleanup
        self._scratch = Path(tempfile.mkdtemp(prefix="bagport-link-"))
        paths = _reader_paths(path, storage, self._scratch)
        store = Stores.ROS1_NOETIC if storage is Storage.ROS1 else Stores.ROS2_HUMBLE
        try:
            extra = parse_msg_definitions(msg_definitions or {})
            bundled = get_typestore(store)
            self._reader: Any = AnyReader(paths, default_typestore=bundled)
            self._reader.open()
            msgtypes = {c.msgtype for c in self._reader.connections}
            lacking = complete_typestore(self._reader.typestore, msgtypes, extra, bundled)
        except BagportError:
            self.close()
            raise
        except _ROSBAGS_ERRORS as err:
            self.close()
            raise BagReadError(f"cannot be opened: {err}", uri=uri, fix=_fix_for(err)) from err
        except (OSError, ValueError, KeyError, IndexError) as err:
            self.close()
            raise BagReadError(
                f"cannot be opened ({type(err).__name__}: {err})",
                uri=uri,
                fix="the bag is corrupt or truncated.",
            ) from err
        files = [p for p in (path.iterdir() if path.is_dir() else [path]) if p.is_file()]
        counts: dict[str, tuple[str, int]] = {}
        for conn in self._reader.connections:
            msgtype, count = counts.get(conn.topic, (conn.msgtype, 0))
            counts[conn.topic] = (msgtype, count + int(conn.msgcount))
        message_count = int(self._reader.message_count)
        self._info = BagInfo(
            uri=uri,
            storage=storage,
            files=tuple(sorted(p.name for p in files)),
            size_bytes=sum(p.stat().st_size for p in files),
            start_ns=int(self._reader.start_time) if message_count else 0,
            end_ns=int(self._reader.end_time) if message_count else 0,
            message_count=message_count,
            topics=tuple(TopicInfo(name, mt, c) for name, (mt, c) in sorted(counts.items())),
            custom_data=_custom_data(path),
        )
        self._layout = HeaderLayout.ROS1 if storage is Storage.ROS1 else HeaderLayout.CDR
        self._lacking = lacking

    @property
    def info(self) -> BagInfo:
        return self._info

    @property
    def undefined_types(self) -> dict[str, str]:
        return {c.topic: c.msgtype for c in self._reader.connections if c.msgtype in self._lacking}

    def _header_layout(self, msgtype: str) -> str | None:
        fields = self._reader.typestore.fielddefs.get(msgtype)
        if not fields or not fields[1]:
            return None
        _, (nodetype, detail) = fields[1][0]
        return self._layout if nodetype == Nodetype.NAME and detail == _HEADER else None

    def messages(self, topics: Sequence[str] | None = None) -> Iterator[BagMessage]:
        wanted = None if topics is None else frozenset(topics)
        conns = [c for c in self._reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        for conn in conns:
            if conn.msgtype in self._lacking:
                raise undefined_type_error(self._uri, conn.topic, conn.msgtype, self._lacking[conn.msgtype])
        layouts = {c.msgtype: self._header_layout(c.msgtype) for c in conns}
        deserialize = self._reader.deserialize
        try:
            for conn, log_ns, raw in self._reader.messages(connections=conns):
                yield BagMessage(
                    conn.topic, conn.msgtype, int(log_ns), raw, deserialize, layouts[conn.msgtype]
                )
        except _ROSBAGS_ERRORS as err:
            raise BagReadError(f"reading failed: {err}", uri=self._uri, fix=_fix_for(err)) from err
        except (OSError, ValueError, KeyError, IndexError, EOFError) as err:
            raise BagReadError(
                f"reading failed ({type(err).__name__}: {err})",
                uri=self._uri,
                fix="the bag is corrupt or truncated.",
            ) from err

    def close(self) -> None:
        reader = getattr(self, "_reader", None)
        if reader is not None and getattr(reader, "isopen", True):
            with contextlib.suppress(Exception):
                reader.close()
        shutil.rmtree(self._scratch, ignore_errors=True)
        if self._cleanup is not None:
            shutil.rmtree(self._cleanup, ignore_errors=True)

    def __enter__(self) -> RosbagsReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _fix_for(err: Exception) -> str:
    text = str(err).lower()
    if "index" in text or "reindex" in text:
        return "reindex the bag (`rosbag reindex` for ROS 1, `ros2 bag reindex` for rosbag2)."
    return "check that the file is a complete, uncorrupted bag."


def _fetch(uri: str, storage_options: Mapping[str, Any]) -> tuple[Path, Path | None]:
    """Local path of the bag; a remote bag is copied to a private temp folder first."""
    try:
        fs, path = url_to_fs(uri, **storage_options)
    except (ValueError, ImportError) as err:
        raise BagReadError(f"cannot be opened ({err})", uri=uri, fix="check the URI scheme.") from err
    if is_local(fs):
        return Path(path), None
    scratch = Path(tempfile.mkdtemp(prefix="bagport-bag-"))
    local = scratch / path.rstrip("/").rsplit("/", 1)[-1]
    try:
        if fs.isdir(path):
            local.mkdir()
            for remote in fs.find(path):
                target = local / remote[len(path.rstrip("/")) + 1 :]
                target.parent.mkdir(parents=True, exist_ok=True)
                fs.get_file(remote, str(target))
        else:
            fs.get_file(path, str(local))
    except FileNotFoundError as err:
        shutil.rmtree(scratch, ignore_errors=True)
        raise BagReadError("does not exist", uri=uri, fix="check the manifest uri.") from err
    except PermissionError as err:
        shutil.rmtree(scratch, ignore_errors=True)
        raise BagReadError(
            f"access denied ({err})", uri=uri, fix="check the credentials for this store."
        ) from err
    except (ConnectionError, TimeoutError, OSError) as err:
        shutil.rmtree(scratch, ignore_errors=True)
        raise TransientError(f"{uri}: download failed ({type(err).__name__}: {err}); try again") from err
    return local, scratch


def open_bag(
    uri: str,
    *,
    storage_options: Mapping[str, Any] | None = None,
    msg_definitions: Mapping[str, str] | None = None,
) -> BagReader:
    """Open a rosbag2 folder, an .mcap, a .db3 or a ROS 1 .bag from any fsspec URI.

    ``msg_definitions`` (``{type name: .msg text}``, see :func:`bagport.bags.read_msg_path`) define
    types the bag does not embed and no bundled type store has."""
    local, cleanup = _fetch(uri, storage_options or {})
    try:
        storage = detect_storage(local, uri)
        return RosbagsReader(uri, local, storage, cleanup, msg_definitions)
    except BagportError:
        if cleanup is not None:
            shutil.rmtree(cleanup, ignore_errors=True)
        raise
