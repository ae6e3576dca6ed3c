"""User decoders: referenced from a contract as ``module:function``, or registered for a message type.

A decoder is ``(msg, spec) -> array-like``: ``msg`` is the deserialised message (a rosbags
dataclass with the ROS field names), ``spec`` the contract entry (:class:`bagport.contract.SourceSpec`:
``names``, ``msgtype`` (also as Rosetta's ``msg_type``), ``topic``, ``key``).  It returns the entry's values as a 1-D sequence of
numbers.

Registered decoders (``@register_decoder("acme_msgs/msg/Gripper")``) serve every contract entry of
that type that names no ``decoder`` itself.  Workers find them through the module that defines them:
either a contract entry references that module (``decoder: acme_bagport.decoders:...``), or the
installed package declares it under the ``bagport.decoders`` entry-point group, which bagport loads
the first time it meets a type it has no decoder for.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

from bagport.errors import ContractError
from bagport.msgtypes import normalize_msgtype

__all__ = [
    "ENTRY_POINT_GROUP",
    "CustomDecoder",
    "register_decoder",
    "registered_decoder",
    "resolve_decoder",
]

CustomDecoder = Callable[[Any, Any], Any]
"""``(msg, spec) -> np.ndarray``; ``spec`` has ``names``, ``msgtype`` (= ``msg_type``), ``topic``, ``key``."""

ENTRY_POINT_GROUP = "bagport.decoders"
_REGISTRY: dict[str, CustomDecoder] = {}
_entry_points_loaded = False


def _check_signature(func: Callable[..., Any], ref: str, file: str, line: int | None, field: str) -> None:
    try:
        inspect.signature(func).bind(None, None)
    except TypeError as err:
        raise ContractError(
            f"decoder {ref!r} must accept two positional arguments (msg, spec)",
            file=file,
            line=line,
            field=field,
            fix="define it as 'def decode(msg, spec) -> np.ndarray'.",
        ) from err
    except ValueError:  # builtins without a signature: accept
        pass


def resolve_decoder(
    ref: str, *, file: str = "contract", line: int | None = None, field: str = "decoder"
) -> CustomDecoder:
    """Import ``module:function`` and check it is callable as ``(msg, spec)``."""
    module_name, _, func_name = ref.partition(":")
    try:
        module = importlib.import_module(module_name)
    except Exception as err:  # any failure while importing user code is the user's to see
        raise ContractError(
            f"decoder module {module_name!r} cannot be imported ({type(err).__name__}: {err})",
            file=file,
            line=line,
            field=field,
            fix="install the package that provides it (on every worker too) or fix the 'module:function' "
            "reference; a local module needs its folder on PYTHONPATH.",
        ) from err
    func = getattr(module, func_name, None)
    if func is None or not callable(func):
        raise ContractError(
            f"decoder {ref!r}: module {module_name!r} has no callable {func_name!r}",
            file=file,
            line=line,
            field=field,
            fix="check the function name after the ':'.",
        )
    _check_signature(func, ref, file, line, field)
    return func  # type: ignore[no-any-return]


def register_decoder(msgtype: str) -> Callable[[CustomDecoder], CustomDecoder]:
    """Decorator: use this function for every contract entry of ``msgtype`` without its own decoder.

    ``msgtype`` may be ROS 1 style (``pkg/Type``).  Registering a second function for a type replaces
    the first."""

    def decorate(func: CustomDecoder) -> CustomDecoder:
        ref = f"{getattr(func, '__module__', '?')}:{getattr(func, '__qualname__', func)}"
        _check_signature(func, ref, ref, None, f"register_decoder({msgtype!r})")
        _REGISTRY[normalize_msgtype(msgtype)] = func
        return func

    return decorate


def _load_entry_points() -> None:
    global _entry_points_loaded  # noqa: PLW0603 - load plug-ins once per process
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    for point in entry_points(group=ENTRY_POINT_GROUP):
        try:
            point.load()
        except Exception as err:  # a broken plug-in must say which one
            raise ContractError(
                f"decoder plug-in {point.name!r} ({point.value}) cannot be loaded ({type(err).__name__}: {err})",
                file=f"entry point group {ENTRY_POINT_GROUP}",
                fix="fix or uninstall the package that declares it.",
            ) from err


def registered_decoder(msgtype: str) -> CustomDecoder | None:
    """The decoder registered for ``msgtype``, loading ``bagport.decoders`` plug-ins on first miss."""
    found = _REGISTRY.get(msgtype)
    if found is None and not _entry_points_loaded:
        _load_entry_points()
        found = _REGISTRY.get(msgtype)
    return found
