"""The manifest: which bags to convert, with an optional default task and metadata.

```yaml
bags:
  - uri: bags/episode_000          # rosbag2 folder, .mcap, .db3, ROS 1 .bag; local, file:// or s3://
    task: pick up the red cube     # used when the bag itself carries no task prompt
    metadata: {operator: alice}
  - uri: s3://fleet/2026-11-*/*.mcap   # globs expand, sorted
  - uri: bags/long_session           # one episode of a bag: a window in seconds from the bag's
    start_s: 12.5                    #   first message (start_s/end_s) or in ROS time (start_ns/end_ns);
    end_s: 47.0                      #   the same bag may be listed again with another window
```
Relative paths are relative to the manifest file. A ``.csv`` manifest holds the same entries as a
header row and one row per bag, its other columns as metadata (:mod:`bagport.manifest_csv`).
"""

from __future__ import annotations

import posixpath
from dataclasses import dataclass, field
from typing import Any

import pydantic
import yaml
from fsspec.core import url_to_fs
from pydantic import JsonValue
from pydantic_core import ErrorDetails, PydanticCustomError

from bagport.errors import ManifestError
from bagport.manifest_csv import csv_entries
from bagport.timewindow import WHOLE_BAG, TimeWindow
from bagport.uris import is_local, protocol_of, read_text_file
from bagport.yamlsource import (
    DuplicateKeyError,
    ValidationProblem,
    YamlJson,
    YamlSource,
    explain_validation,
    load_yaml,
    primary_error,
)

__all__ = ["BagEntry", "Manifest", "load_manifest", "parse_manifest"]

_GLOB_CHARS = frozenset("*?[")


_CLASH = "manifest_key_clash"
"""The pydantic error type of two keys of one entry that do not fit together; its ctx is a :class:`_Clash`."""


@dataclass(frozen=True, slots=True)
class _Clash:
    """Two keys of one manifest entry that do not fit together (``start_s`` and ``start_ns``...)."""

    what: str
    keys: tuple[str, str]
    fix: str

    def error(self) -> PydanticCustomError:
        return PydanticCustomError(_CLASH, "{what}", {"what": self.what, "keys": self.keys, "fix": self.fix})

    @classmethod
    def of(cls, error: ErrorDetails) -> _Clash | None:
        """The clash a pydantic error reports, ``None`` for any other error."""
        ctx = error.get("ctx")
        if error["type"] != _CLASH or ctx is None:
            return None
        return cls(what=ctx["what"], keys=tuple(ctx["keys"]), fix=ctx["fix"])


def _window_clash(entry: _Entry) -> _Clash | None:
    """The first rule between the window keys of ``entry`` it breaks: an end given on both clocks, or on one
    clock ending at or before it starts."""
    for bound in ("start", "end"):
        in_s, in_ns = f"{bound}_s", f"{bound}_ns"
        if getattr(entry, in_s) is not None and getattr(entry, in_ns) is not None:
            return _Clash(
                f"gives both {in_s} (seconds from the bag's first message) and {in_ns} (ROS time)",
                (in_s, in_ns),
                f"keep one of the two: remove {in_s} or {in_ns}.",
            )
    for unit in ("s", "ns"):
        start, end = getattr(entry, f"start_{unit}"), getattr(entry, f"end_{unit}")
        if start is not None and end is not None and end <= start:
            return _Clash(
                f"the window ends (end_{unit} {end}) at or before it starts (start_{unit} {start})",
                (f"start_{unit}", f"end_{unit}"),
                f"give an end_{unit} greater than start_{unit}, or leave one of them out (the bag's start or end).",
            )
    return None


class _Entry(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)
    uri: str = pydantic.Field(min_length=1)
    task: str | None = None
    metadata: dict[str, YamlJson] = pydantic.Field(default_factory=dict)
    start_s: float | None = pydantic.Field(default=None, ge=0, allow_inf_nan=False)
    end_s: float | None = pydantic.Field(default=None, gt=0, allow_inf_nan=False)
    start_ns: int | None = pydantic.Field(default=None, ge=0)
    end_ns: int | None = pydantic.Field(default=None, gt=0)

    @pydantic.model_validator(mode="after")
    def _one_window(self) -> _Entry:
        clash = _window_clash(self)
        if clash is not None:
            raise clash.error()
        return self

    def window(self) -> TimeWindow:
        return TimeWindow(start_ns=self.start_ns, end_ns=self.end_ns, start_s=self.start_s, end_s=self.end_s)


class _Manifest(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)
    bags: list[_Entry] = pydantic.Field(min_length=1)


@dataclass(frozen=True, slots=True)
class BagEntry:
    """One bag to convert; ``entry`` is its index in the manifest's ``bags`` list."""

    uri: str
    entry: int
    task: str | None = None
    metadata: dict[str, JsonValue] = field(default_factory=dict)
    window: TimeWindow = WHOLE_BAG
    """``start_s``/``end_s`` (seconds from the bag start) or ``start_ns``/``end_ns`` (ROS time); none:
    the whole bag (or the episodes the contract finds in it)."""


@dataclass(frozen=True, slots=True)
class Manifest:
    source: str
    bags: tuple[BagEntry, ...]


def _is_url(uri: str) -> bool:
    return "://" in uri


def _absolute(uri: str, base_dir: str) -> str:
    """``uri`` relative to the manifest's folder (a local path or a URL such as ``s3://bucket/dir``). A local
    path is written one way (``file://``, ``.`` and a trailing ``/`` dropped), so the same bag written two
    ways is one bag: listed twice in a manifest, or already in the dataset an ``--append`` adds to."""
    uri = uri.removeprefix("file://")
    if _is_url(uri):
        return uri
    if uri.startswith("/") or not base_dir:
        return posixpath.normpath(uri) if uri else uri
    protocol, sep, path = base_dir.partition("://")
    if not sep:
        return posixpath.normpath(posixpath.join(base_dir, uri))
    return f"{protocol}://{posixpath.normpath(posixpath.join(path, uri))}"


def _expand(uri: str, where: dict[str, Any], source: str, storage_options: dict[str, Any]) -> list[str]:
    """The bags ``uri`` names (a glob expands); ``where`` locates the entry (``entry``, or ``row`` and
    ``column`` for a CSV manifest) in errors."""
    try:
        fs, path = url_to_fs(uri, **storage_options)
    except (ImportError, ValueError) as err:
        raise ManifestError(f"uri {uri!r} cannot be opened: {err}", file=source, **where) from err
    prefix = "" if is_local(fs) else f"{protocol_of(fs)}://"
    try:
        if _GLOB_CHARS & set(path):
            found = sorted(fs.glob(path))
            if not found:
                raise ManifestError(
                    f"glob {uri!r} matches no bag",
                    file=source,
                    **where,
                    fix="check the pattern and the folder.",
                )
            return [prefix + p if prefix and not p.startswith(prefix) else p for p in found]
        if not fs.exists(path):
            raise ManifestError(
                f"bag {uri!r} does not exist",
                file=source,
                **where,
                fix="fix the path (relative paths are relative to the manifest file) or remove the entry.",
            )
    except ManifestError:
        raise
    except (PermissionError, OSError) as err:
        raise ManifestError(f"bag {uri!r} cannot be reached: {err}", file=source, **where) from err
    return [uri]


def _csv_model(text: str, source: str) -> tuple[list[_Entry], list[int]]:
    """The entries of a CSV manifest and their row numbers; errors name the row and the column."""
    entries: list[_Entry] = []
    rows: list[int] = []
    for row, data in csv_entries(text, source):
        try:
            entries.append(_Entry.model_validate(data))
        except pydantic.ValidationError as err:
            raise _csv_invalid(err, data, source, row) from err
        rows.append(row)
    return entries, rows


def _csv_invalid(err: pydantic.ValidationError, data: dict[str, Any], source: str, row: int) -> ManifestError:
    """The first problem of a CSV row, at its column; a clash of two keys at the later of their columns."""
    first = primary_error(err)
    clash = _Clash.of(first)
    if clash is not None:  # the later column, as a YAML manifest names the later line
        column = max(clash.keys, key=list(data).index)
        return ManifestError(clash.what, file=source, row=row, column=column, fix=clash.fix)
    cell = str(first["loc"][0]) if first["loc"] else None
    return ManifestError(
        f"{first['msg']}" + (f" (cell {data.get(cell)!r})" if cell in data else ""),
        file=source,
        row=row,
        column=cell,
        fix="fix the cell; start_s/end_s are seconds from the bag's first message, uri is required.",
    )


def _yaml_model(text: str, source: str) -> _Manifest:
    parsed = _parse_yaml(text, source)
    if parsed.data is None:  # 0 bytes, or only comments
        raise ManifestError(
            "has no 'bags:' list: the file is empty or holds only comments",
            file=source,
            fix="write 'bags:' then one '- uri: path/to/bag' line per bag (an entry may also give task, "
            "metadata, start_s, end_s).",
        )
    try:
        return _Manifest.model_validate(parsed.data)
    except pydantic.ValidationError as err:
        raise _yaml_invalid(err, parsed, source) from err


def _yaml_invalid(err: pydantic.ValidationError, parsed: YamlSource, source: str) -> ManifestError:
    """The first problem of a YAML manifest, on its line; a problem inside ``bags[i]`` names the entry
    once (``bags[0]: line 3: start_s: ...``) and a clash of two keys the later of their lines."""
    first = primary_error(err)
    loc = tuple(first["loc"])
    entry = _entry_of(loc)
    clash = _Clash.of(first)
    if clash is not None and entry is not None:
        lines = sorted((line, key) for key in clash.keys if (line := parsed.line_of(("bags", entry, key))))
        on = ", ".join(f"{key} on line {line}" for line, key in lines)
        line = lines[-1][0] if lines else parsed.line_of(("bags", entry))
        return ManifestError(
            f"{clash.what}: {on}" if on else clash.what, file=source, entry=entry, line=line, fix=clash.fix
        )
    problem = explain_validation(err, parsed, _Manifest, _FORMAT)
    field = problem.field or "top level"
    if entry is not None:  # the error names the entry itself
        field = field.removeprefix(f"bags[{entry}]").removeprefix(".")
    # a misspelt key gets the nearest one ("did you mean 'uri'?")
    return ManifestError(
        f"{field}: {problem.what}" if field else problem.what,
        file=source,
        entry=entry,
        line=problem.line,
        fix=_NOT_JSON_FIX if first["type"] == "invalid-json-value" else _value_fix(problem, loc),
    )


def _value_fix(problem: ValidationProblem, loc: tuple[int | str, ...]) -> str:
    """The field's own advice for a value it refuses; the problem's fix for anything else."""
    if problem.missing or problem.fix != _FORMAT or len(loc) != 3:  # bags, i, field
        return problem.fix
    return _FIELD_FIXES.get(str(loc[2]), problem.fix)


def _parse_yaml(text: str, source: str) -> YamlSource:
    try:
        return load_yaml(text, source)
    except DuplicateKeyError as err:
        raise ManifestError(
            err.said,
            file=source,
            entry=_entry_of(err.loc),
            line=err.line,
            fix=f"keep one '{err.key}:' (another bag is its own '- uri: ...' entry in the one 'bags:' list).",
        ) from err
    except yaml.YAMLError as err:
        raise ManifestError(f"is not valid YAML: {err}", file=source) from err


def _entry_of(loc: tuple[int | str, ...]) -> int | None:
    """``i`` of ``bags[i]`` when ``loc`` is inside one entry of the list."""
    return loc[1] if len(loc) > 1 and loc[0] == "bags" and isinstance(loc[1], int) else None


_FORMAT = "a manifest is 'bags:' followed by a list of {uri, task, metadata, start_s, end_s} entries."
_FIELD_FIXES = {
    "start_s": "start_s and end_s are seconds from the bag's first message, 0 or more (such as 2.5).",
    "end_s": "start_s and end_s are seconds from the bag's first message, 0 or more (such as 2.5).",
    "start_ns": "start_ns and end_ns are ROS times in integer nanoseconds since the epoch (0 or more).",
    "end_ns": "start_ns and end_ns are ROS times in integer nanoseconds since the epoch (0 or more).",
    "uri": "uri is the bag's path or URL (a rosbag2 folder, an .mcap/.db3/.bag file, s3://...).",
    "task": "task is the episode's task prompt, a string.",
}
"""A bad value of an entry's field: what that field holds (a missing or unknown key keeps its own advice)."""
_NOT_JSON_FIX = (
    "metadata values are JSON values: text, numbers, true/false, lists and mappings (dates and times are "
    "read as text)."
)


def parse_manifest(
    text: str, source: str = "manifest", *, base_dir: str = "", storage_options: dict[str, Any] | None = None
) -> Manifest:
    """Validate a manifest (YAML, or CSV when ``source`` ends in ``.csv``) and expand globs; every error
    names the entry (``bags[i]``, or a CSV row and column)."""
    rows: list[int] | None = None
    if source.lower().endswith(".csv"):
        items, rows = _csv_model(text, source)
    else:
        items = _yaml_model(text, source).bags
    bags: list[BagEntry] = []
    seen: dict[tuple[str, TimeWindow], int] = {}
    for index, item in enumerate(items):
        uri = _absolute(item.uri, base_dir)
        window = item.window()
        where: dict[str, Any] = (
            {"entry": index} if rows is None else {"entry": index, "row": rows[index], "column": "uri"}
        )
        for found in _expand(uri, where, source, dict(storage_options or {})):
            key = (found, window)
            if key in seen:
                also = f"bags[{seen[key]}]" if rows is None else f"row {rows[seen[key]]}"
                raise ManifestError(
                    f"bag {found!r} is listed twice (also {also})",
                    file=source,
                    **where,
                    fix="remove the duplicate; one bag (or one window of it: start_s/end_s) is one episode.",
                )
            seen[key] = index
            bags.append(
                BagEntry(uri=found, entry=index, task=item.task, metadata=dict(item.metadata), window=window)
            )
    return Manifest(source=source, bags=tuple(bags))


def load_manifest(uri: str, *, storage_options: dict[str, Any] | None = None) -> Manifest:
    """Read a manifest from a local path or any fsspec URI."""
    text = read_text_file(
        uri,
        error=ManifestError,
        subject="file",
        fix="check the --manifest path.",
        storage_options=storage_options,
    )
    base_dir = posixpath.dirname(uri) if _is_url(uri) else posixpath.dirname(posixpath.abspath(uri))
    return parse_manifest(text, uri, base_dir=base_dir, storage_options=storage_options)
