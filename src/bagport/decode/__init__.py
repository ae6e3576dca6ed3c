"""Message decoders: numeric vectors, images, and user-supplied decoders."""

from __future__ import annotations

from bagport.decode.custom import CustomDecoder, resolve_decoder
from bagport.decode.image import decode_image, resize_rgb
from bagport.decode.vector import VectorExtractor, field_at, make_extractor

__all__ = [
    "CustomDecoder",
    "VectorExtractor",
    "decode_image",
    "field_at",
    "make_extractor",
    "resize_rgb",
    "resolve_decoder",
]
