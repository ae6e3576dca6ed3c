"""Message types bagport bundles beyond the standard ROS sets: camera streams recorded as video.

Both are small and public (foxglove/schemas ``foxglove_msgs``; ros-misc-utilities
``ffmpeg_image_transport_msgs``). A bag that embeds its own definition of either type wins;
a ``--msg-path`` definition overrides these.
"""

from __future__ import annotations

from bagport.msgtypes import RosType

__all__ = ["BUNDLED_DEFINITIONS"]

_COMPRESSED_VIDEO = """\
# A single frame of a compressed video bitstream (foxglove_msgs, foxglove/schemas)
builtin_interfaces/Time timestamp
string frame_id
uint8[] data
string format
"""

_FFMPEG_PACKET = """\
# One encoded packet of ffmpeg_image_transport (ffmpeg_image_transport_msgs)
std_msgs/Header header
int32 width
int32 height
string encoding
uint64 pts
uint8 flags
bool is_bigendian
uint8[] data
"""

BUNDLED_DEFINITIONS: dict[str, str] = {
    RosType.COMPRESSED_VIDEO.value: _COMPRESSED_VIDEO,
    RosType.FFMPEG_PACKET.value: _FFMPEG_PACKET,
}
"""``{type name: .msg text}`` of the bundled non-standard types."""
