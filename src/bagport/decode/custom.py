"""User decoders referenced from a contract as ``module:function``."""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from typing import Any

from bagport.errors import ContractError

__all__ = ["CustomDecoder", "resolve_decoder"]

CustomDecoder = Callable[[Any, Any], Any]
"""``(msg, spec) -> np.ndarray``; ``spec`` has ``names``, ``msgtype``, ``topic``, ``key``."""


def resolve_decoder(ref: str, *, where: str) -> CustomDecoder:
    """Import ``module:function`` and check it takes ``(msg, spec)``."""
    module_name, _, func_name = ref.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise ContractError(
            f"decoder module {module_name!r} cannot be imported ({err})",
            file=where,
            field="decoder",
            fix="install the package that provides it or fix the 'module:function' reference.",
        ) from err
    func = getattr(module, func_name, None)
    if func is None or not callable(func):
        raise ContractError(
            f"decoder {ref!r}: module {module_name!r} has no callable {func_name!r}",
            file=where,
            field="decoder",
            fix="check the function name after the ':'.",
        )
    try:
        inspect.signature(func).bind(None, None)
    except TypeError as err:
        raise ContractError(
            f"decoder {ref!r} must accept two positional arguments (msg, spec)",
            file=where,
            field="decoder",
            fix="define it as 'def decode(msg, spec) -> np.ndarray'.",
        ) from err
    except ValueError:  # builtins without a signature: accept
        pass
    return func  # type: ignore[no-any-return]
