"""ROS image messages as arrays: `sensor_msgs/Image` and `CompressedImage`, colour and depth.

Colour: `rgb8`, `bgr8`, `mono8` (grey repeated into three channels), and compressed JPEG or PNG.
Depth, in metres with 0 = invalid (what every `Frame` holds): `32FC1` in metres (NaN = missing, REP
118), `16UC1` in millimetres (0 = missing), and `compressedDepth` (image_transport's plugin): a 12-byte
header (int32 format, float32 depthQuantA, depthQuantB) before a 16-bit PNG, which for `32FC1` holds
quantised inverse depth, depth = A / (value - B), and for `16UC1` the millimetres themselves.
A `depth_scale` (metres per stored unit) overrides the unit of either integer or float depth.
Every refusal is one DatasetError line naming the message (`where`).
"""

from __future__ import annotations

import struct

import numpy as np

from clipclique.errors import DatasetError
from clipclique.io.safeio import MAX_IMAGE_PIXELS, decode_image

COLOUR_ENCODINGS = ("rgb8", "bgr8", "mono8")
DEPTH_ENCODINGS = {"32FC1": 1.0, "16UC1": 0.001}  # metres per stored unit
COMPRESSED_DEPTH_HEADER = 12  # bytes: int32 format, float32 depthQuantA, float32 depthQuantB


def is_compressed(msg: object) -> bool:
    """A `CompressedImage` (it has `format`, not `encoding`)."""
    return hasattr(msg, "format") and not hasattr(msg, "encoding")


def _raw_pixels(msg: object, dtype: np.dtype, channels: int, where: str) -> np.ndarray:
    """The pixels of an uncompressed Image as (H, W[, C]), its declared size, row step and byte order checked."""
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise DatasetError(f"{where}: image is {width} x {height} pixels (empty)")
    if height * width > MAX_IMAGE_PIXELS:
        raise DatasetError(
            f"{where}: image declares {width} x {height} pixels, more than the {MAX_IMAGE_PIXELS} allowed"
        )
    row = width * channels * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if step < row or len(data) < step * (height - 1) + row:
        raise DatasetError(
            f"{where}: {msg.encoding} image of {width} x {height} needs {height} rows of {row} bytes, "
            f"the message has {len(data)} bytes with a step of {step}"
        )
    rows = (
        np.lib.stride_tricks.as_strided(data, (height, row), (step, 1))
        if step != row
        else data[: height * row].reshape(height, row)
    )
    order = ">" if msg.is_bigendian else "<"
    pixels = np.ascontiguousarray(rows).view(dtype.newbyteorder(order)).astype(dtype.newbyteorder("="), copy=False)
    return pixels.reshape(height, width, channels) if channels > 1 else pixels.reshape(height, width)


def decode_colour(msg: object, where: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a colour Image (`COLOUR_ENCODINGS`) or a JPEG/PNG CompressedImage."""
    if is_compressed(msg):
        rgb = decode_image(bytes(msg.data), where, "RGB", DatasetError)
        if rgb.size == 0:
            raise DatasetError(f"{where}: compressed image is empty")
        return rgb
    encoding = str(msg.encoding)
    if encoding == "mono8":
        return np.repeat(_raw_pixels(msg, np.dtype(np.uint8), 1, where)[..., None], 3, axis=2)
    if encoding in ("rgb8", "bgr8"):
        pixels = _raw_pixels(msg, np.dtype(np.uint8), 3, where)
        return pixels if encoding == "rgb8" else np.ascontiguousarray(pixels[..., ::-1])
    raise DatasetError(
        f"{where}: colour encoding {encoding!r} is not read; expected one of "
        f"{', '.join(COLOUR_ENCODINGS)} or a JPEG/PNG CompressedImage"
    )


def decode_depth(msg: object, where: str, depth_scale: float | None = None) -> np.ndarray:
    """(H, W) float32 metres (0 = missing) of a depth Image (`DEPTH_ENCODINGS`) or a compressedDepth message;
    `depth_scale` (metres per stored unit) replaces the encoding's unit."""
    if is_compressed(msg):
        stored, unit = _compressed_depth(msg, where)
    else:
        encoding = str(msg.encoding)
        if encoding not in DEPTH_ENCODINGS:
            raise DatasetError(
                f"{where}: depth encoding {encoding!r} is not read; expected 32FC1 (metres), "
                "16UC1 (millimetres) or a compressedDepth CompressedImage"
            )
        dtype = np.dtype(np.float32 if encoding == "32FC1" else np.uint16)
        stored, unit = _raw_pixels(msg, dtype, 1, where), DEPTH_ENCODINGS[encoding]
    metres = stored.astype(np.float32) * np.float32(depth_scale or unit)
    metres[~np.isfinite(metres) | (metres < 0)] = 0.0
    return metres


def _compressed_depth(msg: object, where: str) -> tuple[np.ndarray, float]:
    """(depth as stored, metres per stored unit) of a compressedDepth message: `32FC1` is decoded from its
    quantised inverse depth to metres (unit 1), `16UC1` stays millimetres."""
    fmt = str(msg.format)
    if "compressedDepth" not in fmt:
        raise DatasetError(
            f"{where}: a CompressedImage depth must be compressedDepth (format {fmt!r}); a JPEG or PNG "
            "colour format holds no depth"
        )
    data = bytes(msg.data)
    if len(data) <= COMPRESSED_DEPTH_HEADER:
        raise DatasetError(
            f"{where}: compressedDepth message of {len(data)} bytes holds no image after its "
            f"{COMPRESSED_DEPTH_HEADER}-byte header"
        )
    _, quant_a, quant_b = struct.unpack("<iff", data[:COMPRESSED_DEPTH_HEADER])
    png = decode_image(data[COMPRESSED_DEPTH_HEADER:], where, None, DatasetError)
    if png.ndim != 2 or png.dtype.kind not in "ui" or png.size == 0:
        raise DatasetError(f"{where}: compressedDepth image is not a single-channel integer PNG")
    encoding = fmt.split(";")[0].strip()
    if encoding == "32FC1":
        if not (np.isfinite(quant_a) and np.isfinite(quant_b)) or quant_a <= 0:
            raise DatasetError(f"{where}: compressedDepth header holds no quantisation (A {quant_a:g}, B {quant_b:g})")
        inverse = png.astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(inverse > 0, np.float32(quant_a) / (inverse - np.float32(quant_b)), np.nan)
        return depth.astype(np.float32), 1.0
    if encoding == "16UC1":
        return png, DEPTH_ENCODINGS["16UC1"]
    raise DatasetError(f"{where}: compressedDepth of {encoding!r} is not read (32FC1 or 16UC1)")


def encoding_of(msg: object) -> str:
    """What `inspect` shows as a message's encoding: Image's `encoding`, CompressedImage's `format`."""
    return str(msg.format if is_compressed(msg) else msg.encoding)
