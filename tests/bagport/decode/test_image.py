"""Image decoders, one encoding at a time, against pixels known in advance; resizing filters."""

from __future__ import annotations

import io
import struct
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image as PILImage
from rosbags.typesys import Stores, get_typestore

from bagport.decode import decode_image, resize_image, resize_rgb
from bagport.decode.bayer import BAYER_PATTERNS, demosaic
from bagport.decode.rvl import rvl_decode
from bagport.errors import DecodeError
from bagport.synth.images import (
    compressed_depth_payload,
    depth_frame,
    mosaic,
    raw_image_bytes,
    recorded_depth,
    rvl_encode,
)

TS = get_typestore(Stores.ROS2_HUMBLE)
Header = TS.types["std_msgs/msg/Header"]
Time = TS.types["builtin_interfaces/msg/Time"]
Image = TS.types["sensor_msgs/msg/Image"]
CompressedImage = TS.types["sensor_msgs/msg/CompressedImage"]
IMAGE, COMPRESSED = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"


def _image(encoding: str, pixels: npt.NDArray[Any], *, big_endian: bool = False, pad: int = 0) -> Any:
    """A raw Image of ``pixels`` (H, W[, C]) in their own dtype, rows padded by ``pad`` bytes."""
    array = pixels.astype(pixels.dtype.newbyteorder(">" if big_endian else "<"))
    height, width = array.shape[:2]
    row = array.reshape(height, -1).view(np.uint8)
    data = np.zeros((height, row.shape[1] + pad), dtype=np.uint8)
    data[:, : row.shape[1]] = row
    return Image(
        header=Header(stamp=Time(sec=1, nanosec=0), frame_id=""),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=int(big_endian),
        step=data.shape[1],
        data=data.ravel(),
    )


def _compressed(fmt: str, payload: bytes) -> Any:
    return CompressedImage(
        header=Header(stamp=Time(sec=1, nanosec=0), frame_id=""),
        format=fmt,
        data=np.frombuffer(payload, dtype=np.uint8),
    )


def _patches(height: int = 24, width: int = 32) -> npt.NDArray[np.uint8]:
    """Four flat colour quadrants, no two channels alike (so any channel swap shows)."""
    rgb = np.zeros((height, width, 3), dtype=np.uint8)
    h, w = height // 2, width // 2
    rgb[:h, :w] = (200, 40, 10)
    rgb[:h, w:] = (30, 220, 90)
    rgb[h:, :w] = (5, 60, 250)
    rgb[h:, w:] = (120, 130, 140)
    return rgb


def _interior(mask_px: int, height: int = 24, width: int = 32) -> npt.NDArray[np.bool_]:
    """Pixels at least ``mask_px`` away from the quadrant edges (where demosaicing mixes colours)."""
    keep = np.ones((height, width), dtype=np.bool_)
    keep[height // 2 - mask_px : height // 2 + mask_px] = False
    keep[:, width // 2 - mask_px : width // 2 + mask_px] = False
    return keep


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "rgba8", "bgra8", "8UC3"])
def test_colour_encodings_come_out_rgb(encoding: str) -> None:
    rgb = _patches()
    data, step = raw_image_bytes(rgb, encoding)
    channels = step // rgb.shape[1]
    out = decode_image(_image(encoding, data.reshape(24, 32, channels), pad=3), IMAGE)
    np.testing.assert_array_equal(out, rgb)


@pytest.mark.parametrize("encoding", ["mono8", "8UC1"])
def test_grey_encodings_become_grey_rgb(encoding: str) -> None:
    grey = np.array([[0, 17, 255]], dtype=np.uint8)
    out = decode_image(_image(encoding, grey), IMAGE)
    np.testing.assert_array_equal(out, np.repeat(grey[:, :, None], 3, axis=2))


@pytest.mark.parametrize("big_endian", [False, True], ids=["little", "big"])
def test_mono16_is_scaled_to_8_bits_over_the_full_range(big_endian: bool) -> None:
    values = np.array([[0, 128, 129, 257 * 10, 257 * 200 + 128, 65535]], dtype=np.uint16)
    out = decode_image(_image("mono16", values, big_endian=big_endian), IMAGE)
    np.testing.assert_array_equal(out[0, :, 0], [0, 0, 1, 10, 200, 255])
    assert (out[:, :, 0] == out[:, :, 2]).all()


@pytest.mark.parametrize("pattern", BAYER_PATTERNS)
def test_bayer_patterns_give_the_true_colours(pattern: str) -> None:
    rgb = _patches()
    out = decode_image(_image(f"bayer_{pattern}8", mosaic(rgb, pattern)), IMAGE)
    keep = _interior(2)
    np.testing.assert_array_equal(out[keep], rgb[keep])
    # a mosaic read with the wrong pattern gives wrong colours: the test can fail
    other = BAYER_PATTERNS[(BAYER_PATTERNS.index(pattern) + 1) % 4]
    wrong = decode_image(_image(f"bayer_{other}8", mosaic(rgb, pattern)), IMAGE)
    assert np.abs(wrong[keep].astype(int) - rgb[keep]).max() > 100


def test_flat_colour_survives_demosaicing_to_the_border() -> None:
    rgb = np.empty((7, 9, 3), dtype=np.uint8)
    rgb[:] = (90, 160, 30)
    for pattern in BAYER_PATTERNS:
        np.testing.assert_array_equal(demosaic(mosaic(rgb, pattern), pattern), rgb)


def test_bayer16_is_scaled_then_demosaiced() -> None:
    rgb = _patches()
    sixteen = mosaic(rgb, "grbg").astype(np.uint16) * np.uint16(257)
    out = decode_image(_image("bayer_grbg16", sixteen), IMAGE)
    keep = _interior(2)
    np.testing.assert_array_equal(out[keep], rgb[keep])


@pytest.mark.parametrize(
    ("pattern", "code"),
    [
        ("rggb", "COLOR_BayerBG2RGB"),
        ("bggr", "COLOR_BayerRG2RGB"),
        ("gbrg", "COLOR_BayerGR2RGB"),
        ("grbg", "COLOR_BayerGB2RGB"),
    ],
)
def test_bilinear_demosaic_matches_opencv_inside_the_image(pattern: str, code: str) -> None:
    cv2 = pytest.importorskip("cv2")  # cv_bridge's mapping of ROS Bayer names to OpenCV codes
    raw = np.random.default_rng(3).integers(0, 256, (40, 56), dtype=np.uint8)
    ours = demosaic(raw, pattern)
    theirs = cv2.cvtColor(raw, getattr(cv2, code))
    diff = np.abs(ours[2:-2, 2:-2].astype(int) - theirs[2:-2, 2:-2])
    assert diff.max() <= 1


def test_depth_16uc1_is_metres_and_zero_is_invalid() -> None:
    mm = np.array([[0, 1, 1500, 65535]], dtype=np.uint16)
    for big_endian in (False, True):
        out = decode_image(_image("16UC1", mm, big_endian=big_endian), IMAGE)
        assert out.dtype == np.float32 and out.shape == (1, 4)
        assert np.isnan(out[0, 0])
        np.testing.assert_allclose(out[0, 1:], [0.001, 1.5, 65.535], rtol=1e-6)


def test_depth_32fc1_marks_nan_inf_zero_and_negative_invalid() -> None:
    metres = np.array([[np.nan, np.inf, -np.inf, 0.0, -1.0, 0.25, 7.5]], dtype=np.float32)
    out = decode_image(_image("32FC1", metres), IMAGE)
    assert np.isnan(out[0, :5]).all()
    np.testing.assert_array_equal(out[0, 5:], [0.25, 7.5])


def test_compressed_depth_16uc1_round_trips_exactly() -> None:
    depth = np.array([[np.nan, 0.3, 1.234], [2.0, 9.999, 40.0]], dtype=np.float32)
    payload, fmt = compressed_depth_payload(depth, "16UC1")
    assert fmt == "16UC1; compressedDepth png" and payload[12:16] == b"\x89PNG"
    out = decode_image(_compressed(fmt, payload), COMPRESSED)
    np.testing.assert_array_equal(out, recorded_depth(depth, "16UC1", compressed=True))
    assert np.isnan(out[0, 0]) and out[1, 2] == np.float32(40.0)


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_compressed_depth_rvl_decodes_like_png(encoding: str) -> None:
    depth = depth_frame(48, 64, 7)
    rvl, rvl_fmt = compressed_depth_payload(depth, encoding, "rvl")
    png, png_fmt = compressed_depth_payload(depth, encoding)
    assert rvl_fmt == f"{encoding}; compressedDepth rvl"
    from_rvl = decode_image(_compressed(rvl_fmt, rvl), COMPRESSED)
    np.testing.assert_array_equal(from_rvl, decode_image(_compressed(png_fmt, png), COMPRESSED))
    np.testing.assert_array_equal(from_rvl, recorded_depth(depth, encoding, compressed=True))


def test_rvl_round_trips_a_known_16_bit_image_exactly() -> None:
    rng = np.random.default_rng(4)
    known = rng.integers(0, 65536, (60, 80)).astype(np.uint16)
    known[rng.random(known.shape) < 0.3] = 0  # holes: runs of zeros
    known[:5] = 0
    known[-1, -7:] = 0  # ends on a zero run
    known[10, :] = [0, 65535, 1, 40000, *([3] * 76)]  # largest jumps both ways
    coded = rvl_encode(known)
    assert len(coded) % 4 == 0
    np.testing.assert_array_equal(rvl_decode(coded, known.size).reshape(known.shape), known)
    # the format's own packing, worked by hand: 2 zeros, 1 non-zero, delta 3 -> zig-zag 6; nibbles
    # 2,1,6 in the top of one little-endian word
    assert rvl_encode(np.array([0, 0, 3], np.uint16)) == bytes.fromhex("00006021")
    np.testing.assert_array_equal(rvl_decode(bytes.fromhex("00006021"), 3), [0, 0, 3])


def test_compressed_depth_32fc1_inverts_the_inverse_depth_quantisation() -> None:
    depth = np.linspace(0.2, 9.9, 64, dtype=np.float32).reshape(8, 8)
    depth[0, 0] = np.nan
    depth[0, 1] = 12.0  # beyond the transport's depth_max: stored as 0 (invalid)
    payload, fmt = compressed_depth_payload(depth, "32FC1")
    out = decode_image(_compressed(fmt, payload), COMPRESSED)
    assert np.isnan(out[0, :2]).all()
    valid = np.isfinite(out)
    # the transport truncates A / d + B to an integer: the error is below one inverse-depth step d^2 / A
    step = depth[valid] ** 2 / (100 * 101)
    assert (np.abs(out[valid] - depth[valid]) <= step * 1.01).all()
    np.testing.assert_allclose(out[valid], recorded_depth(depth, "32FC1", compressed=True)[valid], rtol=1e-6)


def test_compressed_depth_errors_say_what_is_wrong() -> None:
    payload, _ = compressed_depth_payload(np.ones((2, 2), np.float32), "16UC1")
    with pytest.raises(DecodeError, match="RVL image claims"):  # a PNG payload under an rvl format
        decode_image(_compressed("16UC1; compressedDepth rvl", payload), COMPRESSED)
    rvl, fmt = compressed_depth_payload(np.ones((2, 2), np.float32), "16UC1", "rvl")
    with pytest.raises(DecodeError, match="RVL data ends after 0 of 4 pixels"):
        decode_image(_compressed(fmt, rvl[:20]), COMPRESSED)
    with pytest.raises(DecodeError, match="too short for its header"):
        decode_image(_compressed(fmt, rvl[:15]), COMPRESSED)
    with pytest.raises(DecodeError, match="12-byte header followed by a PNG"):
        decode_image(_compressed("16UC1; compressedDepth", payload[4:]), COMPRESSED)
    with pytest.raises(DecodeError, match="expected 16UC1 or 32FC1"):
        decode_image(_compressed("bgr8; compressedDepth", payload), COMPRESSED)
    rgb_png = io.BytesIO()
    PILImage.fromarray(np.zeros((2, 2, 3), np.uint8)).save(rgb_png, format="PNG")
    with pytest.raises(DecodeError, match="one 16-bit channel"):
        decode_image(
            _compressed("16UC1; compressedDepth", struct.pack("<iff", 0, 0, 0) + rgb_png.getvalue()),
            COMPRESSED,
        )


def test_sixteen_bit_png_is_depth_when_the_format_says_16uc1_else_grey() -> None:
    buf = io.BytesIO()
    PILImage.fromarray(np.array([[0, 1500, 65535]], dtype=np.uint16)).save(buf, format="PNG")
    depth = decode_image(_compressed("16UC1; png compressed", buf.getvalue()), COMPRESSED)
    assert np.isnan(depth[0, 0])
    np.testing.assert_allclose(depth[0, 1:], [1.5, 65.535], rtol=1e-6)
    grey = decode_image(_compressed("mono16; png compressed", buf.getvalue()), COMPRESSED)
    np.testing.assert_array_equal(grey[0, :, 1], [0, 6, 255])


def test_downscaling_averages_areas_instead_of_picking_pixels() -> None:
    checker = np.zeros((8, 8, 3), dtype=np.uint8)
    checker[::2, ::2] = 200
    checker[1::2, 1::2] = 200  # one-pixel checkerboard: nearest neighbour would give 0 or 200
    np.testing.assert_array_equal(resize_rgb(checker, 4, 4), np.full((4, 4, 3), 100, np.uint8))
    ramp = np.repeat(np.arange(0, 90, 10, dtype=np.uint8)[None, :, None], 3, axis=2)  # 1 x 9
    np.testing.assert_array_equal(resize_rgb(ramp, 1, 3)[0, :, 0], [10, 40, 70])  # means of thirds


def test_depth_resize_averages_valid_depth_only() -> None:
    depth = np.array(
        [[1.0, 3.0, np.nan, np.nan], [np.nan, 2.0, np.nan, 4.0], [5.0, 5.0, 6.0, 6.0], [5.0, 5.0, 6.0, 8.0]],
        dtype=np.float32,
    )
    out = resize_image(depth, 2, 2)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[0, 0], 2.0)  # the hole does not pull the depth towards 0
    assert np.isnan(out[0, 1])  # three quarters invalid: invalid
    np.testing.assert_allclose(out[1], [5.0, 6.5])


def _yuv601(rgb: tuple[int, int, int]) -> tuple[int, int, int]:
    """BT.601 limited-range Y, U, V of one RGB colour (what a USB camera sends for it)."""
    r, g, b = rgb
    y = 16 + (65.481 * r + 128.553 * g + 24.966 * b) / 255
    u = 128 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255
    v = 128 + (112.0 * r - 93.786 * g - 18.214 * b) / 255
    return round(y), round(u), round(v)


@pytest.mark.parametrize("encoding", ["yuv422", "uyvy", "yuv422_yuy2", "yuyv"])
def test_packed_yuv422_gives_the_true_colours(encoding: str) -> None:
    """A USB camera's packed 4:2:2 frames (yuv422 is UYVY, yuv422_yuy2 YUYV): four colour bars, each two
    pixels wide (a U/V pair), come out as their RGB within rounding; a row padded beyond its bytes too."""
    bars = [(200, 30, 30), (30, 200, 30), (30, 30, 200), (128, 128, 128)]
    uyvy = encoding in ("yuv422", "uyvy")
    row: list[int] = []
    for colour in bars:
        y, u, v = _yuv601(colour)
        row += [u, y, v, y] if uyvy else [y, u, y, v]
    pixels = np.array([row] * 3, dtype=np.uint8).reshape(3, len(bars) * 2, 2)  # (H, W, 2 bytes)
    out = decode_image(_image(encoding, pixels, pad=6), IMAGE)
    assert out.shape == (3, 8, 3) and out.dtype == np.uint8
    want = np.repeat(np.array(bars, dtype=np.int16), 2, axis=0)
    assert np.abs(out[1].astype(np.int16) - want).max() <= 3, out[1]


def test_packed_yuv422_with_an_odd_width_is_an_error() -> None:
    with pytest.raises(DecodeError, match=r"a yuv422 image has 3 pixels a row, .* the width must be even"):
        decode_image(_image("yuv422", np.zeros((2, 3, 2), dtype=np.uint8)), IMAGE)


def _empty_image(height: int, width: int) -> Any:
    return Image(
        header=Header(stamp=Time(sec=1, nanosec=0), frame_id=""),
        height=height,
        width=width,
        encoding="rgb8",
        is_bigendian=0,
        step=width * 3,
        data=np.zeros(0, dtype=np.uint8),
    )


@pytest.mark.parametrize("shape", [(0, 0, 3), (0, 8, 3), (6, 0, 3)])
def test_an_empty_image_is_an_error_not_a_black_frame(shape: tuple[int, int, int]) -> None:
    """Camera drivers publish 0x0 images before their first frame: no pixels, so no frame (a resize would have
    made it black without a sign)."""
    with pytest.raises(
        DecodeError, match=r"the image is empty \(\d+x\d+ rgb8\): a camera driver publishes"
    ) as caught:
        decode_image(_empty_image(*shape[:2]), "sensor_msgs/msg/Image")
    assert "manifest window" in caught.value.fix


def test_a_compressed_image_that_is_video_says_which_types_carry_video() -> None:
    with pytest.raises(DecodeError, match=r"\(format 'h264', 5 bytes\) is neither JPEG nor PNG") as caught:
        decode_image(_compressed("h264", b"\x00\x00\x00\x01\x67"), "sensor_msgs/msg/CompressedImage")
    assert "foxglove_msgs/CompressedVideo" in caught.value.fix
    assert "BytesIO" not in str(caught.value)  # not the library's text, with an address
    with pytest.raises(DecodeError, match=r"is neither JPEG nor PNG") as other:
        decode_image(_compressed("webp", b"RIFF0000WEBP"), "sensor_msgs/msg/CompressedImage")
    assert "it reads JPEG and PNG" in other.value.fix
