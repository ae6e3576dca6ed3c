"""YAML loading that remembers where every value came from (file and line).

Pydantic reports errors as a path of keys and indices (``("observations", 1,
"topic")``); :class:`YamlSource` turns such a path back into a line number so an
error can point at the exact place in the user's file.
"""

from __future__ import annotations

import datetime
import difflib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any

import pydantic
import yaml
from pydantic_core import ErrorDetails

__all__ = [
    "DuplicateKeyError",
    "ValidationProblem",
    "YamlJson",
    "YamlSource",
    "explain_validation",
    "field_of",
    "load_plain",
    "load_yaml",
    "primary_error",
]

_LOADER: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
"""libyaml's safe loader where PyYAML was built with it (about 10x faster: a tiny episode parsed
its bag's metadata.yaml and its contract for a fifth of its time), else the pure-Python one."""


def _dates_as_text(value: Any) -> Any:
    """YAML's dates and times (``2026-11-02``) as the text ``str()`` gives, in lists and mappings too."""
    if isinstance(value, datetime.date | datetime.time):
        return str(value)
    if isinstance(value, list):
        return [_dates_as_text(v) for v in value]
    if isinstance(value, dict):
        return {k: _dates_as_text(v) for k, v in value.items()}
    return value


YamlJson = Annotated[pydantic.JsonValue, pydantic.BeforeValidator(_dates_as_text)]
"""Free-form YAML a user writes (manifest metadata, a contract's ``qos``): JSON values, with YAML's
unquoted dates and times read as text."""


@dataclass(frozen=True, slots=True)
class YamlSource:
    """Parsed YAML plus its node tree, for mapping value paths to lines."""

    name: str
    data: Any
    root: yaml.Node | None

    def line_of(self, loc: Sequence[int | str]) -> int | None:
        """1-based line of the deepest node on ``loc`` that exists in the file."""
        node = self.root
        line = node.start_mark.line + 1 if node is not None else None
        for part in loc:
            child = _child(node, part)
            if child is None:
                break
            anchor, node = child
            line = anchor.start_mark.line + 1
        return line


def _child(node: yaml.Node | None, part: int | str) -> tuple[yaml.Node, yaml.Node] | None:
    """(node whose line names the step, child node); for a mapping the key's line."""
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            if isinstance(key_node, yaml.ScalarNode) and key_node.value == str(part):
                return key_node, value_node
    if isinstance(node, yaml.SequenceNode) and isinstance(part, int) and 0 <= part < len(node.value):
        item: yaml.Node = node.value[part]
        return item, item
    return None


class DuplicateKeyError(yaml.MarkedYAMLError):
    """A mapping gives one key twice; YAML itself would keep the last value without a word.

    A ``yaml.YAMLError`` (``problem_mark`` at the second key), so a caller that reports bad YAML reports it
    too; ``loc`` is the path to the mapping (``("bags", 0)``) for callers that name an entry.
    """

    def __init__(self, key: str, loc: tuple[int | str, ...], first: yaml.Mark, again: yaml.Mark) -> None:
        self.key = key
        self.loc = loc
        self.line = again.line + 1
        self.first_line = first.line + 1
        super().__init__(problem=f"key {key!r} is given twice (lines {self.first_line} and {self.line})")
        self.problem_mark = again

    def __str__(self) -> str:  # MarkedYAMLError's adds a snippet of the file over several lines
        return f"line {self.line}: {self.problem}"

    @property
    def said(self) -> str:
        """The problem as a contract's or manifest's error says it, where the error gives the line itself."""
        return f"key {self.key!r} is given twice (also line {self.first_line}); YAML would silently keep the last"


def _refuse_duplicate_keys(root: yaml.Node) -> None:
    """Raise :class:`DuplicateKeyError` for the first mapping under ``root`` that gives a key twice
    (a loop, not recursion: a fuzzed file nests deeper than Python's stack)."""
    stack: list[tuple[yaml.Node, tuple[int | str, ...]]] = [(root, ())]
    seen: set[int] = set()
    while stack:
        node, loc = stack.pop()
        if id(node) in seen:  # an alias: its anchor was checked (and may contain itself)
            continue
        seen.add(id(node))
        if isinstance(node, yaml.SequenceNode):
            stack.extend((item, (*loc, index)) for index, item in reversed(list(enumerate(node.value))))
        elif isinstance(node, yaml.MappingNode):
            first: dict[tuple[str, str], yaml.Mark] = {}
            children: list[tuple[yaml.Node, tuple[int | str, ...]]] = []
            for key_node, value_node in node.value:
                if isinstance(key_node, yaml.ScalarNode) and key_node.tag != "tag:yaml.org,2002:merge":
                    key = (key_node.tag, key_node.value)
                    if key in first:
                        raise DuplicateKeyError(key_node.value, loc, first[key], key_node.start_mark)
                    first[key] = key_node.start_mark
                    children.append((value_node, (*loc, key_node.value)))
            stack.extend(reversed(children))  # popped in the file's order: the first duplicate is reported


def load_yaml(text: str, name: str) -> YamlSource:
    """Parse ``text``; raises ``yaml.YAMLError`` (with its own mark) on bad syntax, and its
    :class:`DuplicateKeyError` when a mapping gives a key twice (YAML would keep the last silently)."""
    root = yaml.compose(text, Loader=_LOADER)
    if root is not None:
        _refuse_duplicate_keys(root)
    data = yaml.load(text, Loader=_LOADER)
    return YamlSource(name=name, data=data, root=root)


def load_plain(text: str) -> Any:
    """``yaml.safe_load`` (with libyaml where available)."""
    return yaml.load(text, Loader=_LOADER)


def field_of(loc: Sequence[int | str]) -> str:
    """A value path as the user reads it: ``("bags", 0, "uri")`` -> ``bags[0].uri``."""
    return ".".join(str(p) if isinstance(p, str) else f"[{p}]" for p in loc).replace(".[", "[")


def primary_error(err: pydantic.ValidationError) -> ErrorDetails:
    """The error to show first: a misspelt field shows up twice (unknown + required
    missing) and the unknown one names the typo."""
    errors = err.errors()
    return next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])


@dataclass(frozen=True, slots=True)
class ValidationProblem:
    """The first problem of a pydantic error, placed in the user's file."""

    what: str
    line: int | None
    field: str
    fix: str
    missing: bool = False
    """The field is required and absent (not present with a bad value)."""


def explain_validation(
    err: pydantic.ValidationError, source: YamlSource, model: type[pydantic.BaseModel], default_fix: str
) -> ValidationProblem:
    """What is wrong, on which line, and how to fix it (nearest valid key for a typo)."""
    errors = err.errors()
    first = primary_error(err)
    loc = tuple(first["loc"])
    field = field_of(loc)
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "missing":
        msg = "required field is missing"
    elif first["type"] == "extra_forbidden":
        msg = "unknown field"
    more = f" ({len(errors) - 1} more problem(s) after this one)" if len(errors) > 1 else ""
    fix = _suggest(model, loc, first["type"]) or default_fix
    return ValidationProblem(msg + more, source.line_of(loc), field, fix, missing=first["type"] == "missing")


def _suggest(model: type[pydantic.BaseModel], loc: tuple[int | str, ...], err_type: str) -> str:
    if err_type != "extra_forbidden" or not loc:
        return ""
    name = str(loc[-1])
    known = _known_fields(model, loc[:-1])
    close = difflib.get_close_matches(name, known, n=1)
    if close:
        return f"did you mean '{close[0]}'?"
    return f"remove it; allowed here: {', '.join(sorted(known))}."


def _known_fields(model: type[pydantic.BaseModel], parent: tuple[int | str, ...]) -> list[str]:
    for part in parent:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(str(part))
        if field is None:
            return []
        inner = _model_in(field.annotation)
        if inner is None:
            return []
        model = inner
    return list(model.model_fields)


def _model_in(annotation: object) -> type[pydantic.BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, pydantic.BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()):
        found = _model_in(arg)
        if found is not None:
            return found
    return None
