"""Message decoders: numeric vectors, images, and user-supplied decoders."""

from __future__ import annotations

from bagport.decode.custom import CustomDecoder, register_decoder, registered_decoder, resolve_decoder
from bagport.decode.image import ImageKind, decode_image, image_channels, is_depth
from bagport.decode.paths import VectorExtractor, field_at
from bagport.decode.resize import resize_image, resize_rgb
from bagport.decode.tf import child_frames, find_transform, transform_stamp_ns
from bagport.decode.vector import make_extractor

__all__ = [
    "CustomDecoder",
    "ImageKind",
    "VectorExtractor",
    "child_frames",
    "decode_image",
    "field_at",
    "find_transform",
    "image_channels",
    "is_depth",
    "make_extractor",
    "register_decoder",
    "registered_decoder",
    "resize_image",
    "resize_rgb",
    "resolve_decoder",
    "transform_stamp_ns",
]
