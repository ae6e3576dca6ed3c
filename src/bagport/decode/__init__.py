"""Message decoders: numeric vectors, images, and user-supplied decoders."""

from __future__ import annotations

from bagport.decode.custom import CustomDecoder, resolve_decoder
from bagport.decode.image import decode_image, image_channels, is_depth
from bagport.decode.resize import resize_image, resize_rgb
from bagport.decode.vector import VectorExtractor, make_extractor

__all__ = [
    "CustomDecoder",
    "VectorExtractor",
    "decode_image",
    "image_channels",
    "is_depth",
    "make_extractor",
    "resize_image",
    "resize_rgb",
    "resolve_decoder",
]
