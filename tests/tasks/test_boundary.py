"""The task boundary is typed: no ``dict[str, Any]`` (or other mapping of ``Any``) in what a task takes
or returns, including the fields of the dataclasses and models reachable from them."""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterator, Mapping, MutableMapping
from typing import Any

import pydantic
import pytest
from prefect import Task
from prefect.client.schemas.objects import State

import tasks.episode
import tasks.plan
import tasks.reduce
import tasks.segment

MAPPINGS = (dict, Mapping, MutableMapping)


def _task_functions() -> list[tuple[str, Any]]:
    found = []
    for module in (tasks.episode, tasks.plan, tasks.reduce, tasks.segment):
        for name in module.__all__:
            value = getattr(module, name)
            if isinstance(value, Task):
                found.append((f"{module.__name__}.{name}", value.fn))
    return found


def _field_hints(cls: type) -> dict[str, Any]:
    if dataclasses.is_dataclass(cls) or typing.is_typeddict(cls):
        return typing.get_type_hints(cls)
    if issubclass(cls, pydantic.BaseModel):
        return {name: field.annotation for name, field in cls.model_fields.items()}
    return {}


def untyped_mappings(hint: Any, where: str, seen: set[Any] | None = None) -> Iterator[str]:
    """Where ``hint`` (walked through unions, generics and the fields of dataclasses, typed dicts and
    pydantic models) is ``Any``, holds a mapping of ``Any``, or a bare ``dict``. Free-form user data
    is typed as JSON (``pydantic.JsonValue``), whose alias the walk does not enter."""
    seen = set() if seen is None else seen
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if isinstance(hint, type) and issubclass(hint, State):
        return  # Prefect's own result state (a failed run), not bagport data
    if hint is Any or hint in MAPPINGS or (origin in MAPPINGS and (not args or Any in args)):
        yield f"{where}: {hint}"
        return
    if origin is typing.Annotated:
        args = args[:1]
    for arg in args:
        yield from untyped_mappings(arg, where, seen)
    if isinstance(hint, type) and hint not in seen and origin is None:
        seen.add(hint)
        for name, field_hint in _field_hints(hint).items():
            yield from untyped_mappings(field_hint, f"{where} -> {hint.__name__}.{name}", seen)


TASKS = _task_functions()


@dataclasses.dataclass
class Inner:
    rows: tuple[dict[str, Any], ...]


@dataclasses.dataclass
class Outer:
    inner: Inner | None
    fine: dict[str, int]
    window: Window


class Window(typing.TypedDict, total=False):
    start_s: float
    extra: Any


def test_every_task_is_inspected() -> None:
    names = {name.rsplit(".", 1)[-1] for name, _ in TASKS}
    assert names >= {
        "convert_episode_task",
        "convert_batch_task",
        "plan_task",
        "reduce_task",
        "segment_bag_task",
    }


@pytest.mark.parametrize(("name", "fn"), TASKS, ids=[name for name, _ in TASKS])
def test_no_untyped_mapping_crosses_the_task_boundary(name: str, fn: Any) -> None:
    hints = typing.get_type_hints(fn)
    problems = [p for arg, hint in hints.items() for p in untyped_mappings(hint, f"{name}({arg})")]
    assert problems == []


def test_the_walk_finds_a_nested_untyped_mapping() -> None:
    """The check itself can fail: a mapping of Any two dataclasses deep, in a union, is found."""
    assert list(untyped_mappings(Outer, "x")) == [
        f"x -> Outer.inner -> Inner.rows: {dict[str, Any]}",
        f"x -> Outer.window -> Window.extra: {Any}",
    ]
    assert list(untyped_mappings(types.MappingProxyType, "y")) == []
    assert list(untyped_mappings(dict, "z")) == ["z: <class 'dict'>"]
