"""Turn numeric ROS messages into 1-D feature vectors, selecting by name or path."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from bagport.decode.custom import CustomDecoder, registered_decoder, resolve_decoder
from bagport.decode.defaults import DEFAULT_FIELDS
from bagport.decode.joints import joint_state_extractor, joint_trajectory_extractor, multi_dof_extractor
from bagport.decode.paths import Vector, VectorExtractor, paths_extractor
from bagport.decode.tf import tf_extractor
from bagport.errors import DecodeError
from bagport.msgtypes import TF_TYPES, RosType

__all__ = ["ExtractorSource", "VectorExtractor", "make_extractor"]


class ExtractorSource(Protocol):
    """What an extractor needs of a contract entry (:class:`bagport.contract.SourceSpec` is one).

    A protocol, so this layer does not import the contract layer above it."""

    @property
    def key(self) -> str: ...
    @property
    def topic(self) -> str: ...
    @property
    def msgtype(self) -> str: ...
    @property
    def names(self) -> tuple[str, ...]: ...
    @property
    def decoder(self) -> str | None: ...
    @property
    def child_frame(self) -> str | None: ...
    @property
    def parent_frame(self) -> str | None: ...


_SCALAR_TYPES = frozenset({RosType.FLOAT32, RosType.FLOAT64, RosType.INT32, RosType.INT64, RosType.BOOL})
_ARRAY_TYPES = frozenset(
    {RosType.FLOAT32_MULTI_ARRAY, RosType.FLOAT64_MULTI_ARRAY, RosType.INT32_MULTI_ARRAY}
)


def _arrays_extractor(src: ExtractorSource, first_msg: Any, fields: tuple[str, ...]) -> VectorExtractor:
    """Whole array fields, their lengths fixed by the first message."""
    widths = {name: len(getattr(first_msg, name)) for name in fields}

    def extract(msg: Any) -> Vector:
        parts = []
        for name, width in widths.items():
            values = np.asarray(getattr(msg, name), dtype=np.float64)
            if values.shape != (width,):
                raise DecodeError(
                    f"{name} length changed from {width} to {values.shape[0]}",
                    topic=src.topic,
                    fix=f"select fixed elements with selector.names: ['{name}[0]', ...].",
                )
            parts.append(values)
        return np.concatenate(parts) if len(parts) > 1 else parts[0]

    names = tuple(f"{name}[{i}]" for name, width in widths.items() for i in range(width))
    return VectorExtractor(names, extract)


def _custom_extractor(src: ExtractorSource, decoder: CustomDecoder, first_msg: Any) -> VectorExtractor:
    def extract_custom(msg: Any) -> Vector:
        try:
            values = np.atleast_1d(np.asarray(decoder(msg, src), dtype=np.float64))
        except DecodeError:
            raise
        except Exception as err:  # the user's decoder failed: say which and why
            name = src.decoder or f"the decoder registered for {src.msgtype}"
            raise DecodeError(
                f"decoder {name} failed on a {src.msgtype} message ({type(err).__name__}: {err})",
                topic=src.topic,
                fix="fix the decoder; it must return a 1-D sequence of numbers.",
            ) from err
        if values.ndim != 1:
            raise DecodeError(
                f"decoder for {src.key!r} returned shape {values.shape}, not a 1-D vector",
                topic=src.topic,
                fix="return a 1-D array (flatten it in the decoder).",
            )
        return values

    width = extract_custom(first_msg).shape[0]
    names = src.names if len(src.names) == width else tuple(f"{src.key}_{i}" for i in range(width))
    return VectorExtractor(names, extract_custom)


def make_extractor(src: ExtractorSource, first_msg: Any) -> VectorExtractor:
    """Build the extractor for ``src``; the first message fixes unnamed dimensions.

    Precedence: the entry's ``decoder``, a decoder registered for the type, then the built-in ones.
    A selection of no value at all (a JointState with no names and no positions) is an error."""
    extractor = _extractor(src, first_msg)
    if not extractor.names:
        raise DecodeError(
            f"{src.key!r} selects no value: the first message on {src.topic} ({src.msgtype}) has nothing "
            "where the default selection looks (e.g. a JointState with empty name and position)",
            topic=src.topic,
            fix="list the values in selector.names: dot paths such as 'position[0]', 'velocity[1]' (by index, "
            "for a JointState without joint names), or drop the entry.",
        )
    return extractor


def _extractor(src: ExtractorSource, first_msg: Any) -> VectorExtractor:
    if src.decoder is not None:
        decoder = resolve_decoder(src.decoder, field=f"{src.key} on {src.topic}")
        return _custom_extractor(src, decoder, first_msg)
    registered = registered_decoder(src.msgtype)
    if registered is not None:
        return _custom_extractor(src, registered, first_msg)
    if src.msgtype == RosType.JOINT_STATE:
        return joint_state_extractor(src.topic, src.names, first_msg)
    if src.msgtype == RosType.JOINT_TRAJECTORY:
        return joint_trajectory_extractor(src.topic, src.names, first_msg)
    if src.msgtype == RosType.MULTI_DOF_COMMAND:
        return multi_dof_extractor(src.topic, src.names, first_msg)
    if src.msgtype in TF_TYPES and src.child_frame is not None:
        return tf_extractor(src.topic, src.names, src.child_frame, src.parent_frame)
    if src.names:
        return paths_extractor(src.topic, src.names)
    if src.msgtype in _SCALAR_TYPES:
        return paths_extractor(src.topic, ("data",))
    if src.msgtype in DEFAULT_FIELDS:
        return paths_extractor(src.topic, DEFAULT_FIELDS[src.msgtype])
    if src.msgtype in _ARRAY_TYPES:
        return _arrays_extractor(src, first_msg, ("data",))
    if src.msgtype == RosType.JOY:
        return _arrays_extractor(src, first_msg, ("axes", "buttons"))
    raise DecodeError(
        f"bagport does not know which fields of {src.msgtype} to use for {src.key!r}",
        topic=src.topic,
        fix="list the fields in selector.names (dot paths such as 'twist.linear.x'), set 'decoder: "
        "module:function', or register one with @bagport.decode.register_decoder.",
    )
