"""ROS image payloads <-> numpy, without ROS (used by the bag reader and by the node's conversions).

Works on the fields of sensor_msgs/Image (encoding, height, width, step, is_bigendian, data) and
sensor_msgs/CompressedImage (format, data), whatever object carries them (an rclpy message or a
`rosbags` deserialised message). Output images for the pipeline are uint8: (H, W, 3) RGB or (H, W)
gray; 16-bit images are shifted down to 8 bits by their used bit depth (a 12-bit camera keeps its
full contrast).
"""
from __future__ import annotations

import cv2
import numpy as np

from .errors import InputError

# encoding -> (channels, dtype, channel order to reach RGB or gray)
RAW_ENCODINGS = {
    "rgb8": (3, np.uint8, "rgb"), "bgr8": (3, np.uint8, "bgr"),
    "rgba8": (4, np.uint8, "rgba"), "bgra8": (4, np.uint8, "bgra"),
    "mono8": (1, np.uint8, "gray"), "8UC1": (1, np.uint8, "gray"),
    "8UC3": (3, np.uint8, "bgr"),
    "mono16": (1, np.uint16, "gray"), "16UC1": (1, np.uint16, "gray"),
}
COMPRESSED_FORMATS = ("jpeg", "png")


def raw_to_array(encoding: str, height: int, width: int, step: int, data,
                 is_bigendian: bool = False) -> np.ndarray:
    """The pixels of a sensor_msgs/Image as stored: (H, W) or (H, W, C), dtype uint8/uint16,
    channel order of `encoding` (no conversion)."""
    if encoding not in RAW_ENCODINGS:
        raise InputError(f"Unsupported image encoding {encoding!r}: publish one of "
                         f"{', '.join(RAW_ENCODINGS)} or a CompressedImage (jpeg/png).")
    channels, dtype, _ = RAW_ENCODINGS[encoding]
    itemsize = np.dtype(dtype).itemsize
    buf = np.frombuffer(bytes(data) if not isinstance(data, np.ndarray) else data.tobytes(),
                        dtype=np.uint8)
    row_bytes = width * channels * itemsize
    if step < row_bytes or buf.size < step * height:
        raise InputError(f"Malformed {encoding} image: {width}x{height} needs step >= {row_bytes} "
                         f"and {step * height} bytes, got step {step} and {buf.size} bytes.")
    rows = buf[: step * height].reshape(height, step)[:, :row_bytes]
    pixels = rows.copy().view(np.dtype(dtype).newbyteorder(">" if is_bigendian else "<"))
    pixels = pixels.astype(dtype)  # native byte order
    return pixels.reshape((height, width, channels) if channels > 1 else (height, width))


def to_pipeline_image(pixels: np.ndarray, order: str) -> np.ndarray:
    """Stored pixels in channel `order` (rgb, bgr, rgba, bgra, gray) -> uint8 RGB (H, W, 3) or
    gray (H, W)."""
    if pixels.dtype == np.uint16:
        bits = max(8, int(pixels.max()).bit_length())
        pixels = (pixels >> (bits - 8)).astype(np.uint8)
    if order == "gray":
        return np.ascontiguousarray(pixels)
    if order in ("bgr", "bgra"):
        pixels = pixels[..., 2::-1]
    return np.ascontiguousarray(pixels[..., :3])


def decode_raw(encoding: str, height: int, width: int, step: int, data,
               is_bigendian: bool = False) -> np.ndarray:
    """sensor_msgs/Image fields -> uint8 RGB (H, W, 3) or gray (H, W)."""
    pixels = raw_to_array(encoding, height, width, step, data, is_bigendian)
    return to_pipeline_image(pixels, RAW_ENCODINGS[encoding][2])


def decode_compressed(fmt: str, data) -> np.ndarray:
    """sensor_msgs/CompressedImage fields -> uint8 RGB (H, W, 3) or gray (H, W).
    `fmt` is e.g. "jpeg", "png", "rgb8; jpeg compressed bgr8" (image_transport's format)."""
    buf = np.frombuffer(bytes(data) if not isinstance(data, np.ndarray) else data.tobytes(),
                        dtype=np.uint8)
    image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"Cannot decode a CompressedImage of format {fmt!r} ({buf.size} bytes): "
                         "expected jpeg or png data.")
    if image.ndim == 2:
        return to_pipeline_image(image, "gray")
    return to_pipeline_image(image, "bgra" if image.shape[2] == 4 else "bgr")


def encode_raw(image: np.ndarray, encoding: str) -> tuple[int, int, int, bytes]:
    """uint8 RGB (H, W, 3) or gray (H, W) (uint16 for mono16) -> (height, width, step, data) of a
    little-endian sensor_msgs/Image with `encoding` in rgb8, bgr8, mono8, mono16."""
    image = np.asarray(image)
    if encoding == "rgb8":
        out = _as_rgb(image)
    elif encoding == "bgr8":
        out = _as_rgb(image)[..., ::-1]
    elif encoding == "mono8":
        out = _as_gray(image)
    elif encoding == "mono16":
        out = image.astype("<u2") if image.dtype == np.uint16 else \
            _as_gray(image).astype("<u2") * 257
    else:
        raise InputError(f"Cannot encode images as {encoding!r}: use rgb8, bgr8, mono8 or mono16.")
    out = np.ascontiguousarray(out)
    height, width = out.shape[:2]
    return height, width, out.strides[0], out.tobytes()


def encode_compressed(image: np.ndarray, fmt: str = "jpeg", jpeg_quality: int = 95) -> bytes:
    """uint8 RGB (H, W, 3) or gray (H, W) -> jpeg or png bytes (CompressedImage.data)."""
    if fmt not in COMPRESSED_FORMATS:
        raise InputError(f"Unsupported compressed format {fmt!r}: use jpeg or png.")
    image = np.asarray(image)
    bgr = image if image.ndim == 2 else np.ascontiguousarray(image[..., ::-1])
    params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if fmt == "jpeg" else []
    ok, buf = cv2.imencode(".jpg" if fmt == "jpeg" else ".png", bgr, params)
    if not ok:
        raise InputError(f"OpenCV could not encode a {image.shape} image as {fmt}.")
    return buf.tobytes()


def _as_rgb(image: np.ndarray) -> np.ndarray:
    if image.dtype != np.uint8:
        raise InputError(f"Expected a uint8 image, got {image.dtype}.")
    return np.repeat(image[..., None], 3, axis=2) if image.ndim == 2 else image[..., :3]


def _as_gray(image: np.ndarray) -> np.ndarray:
    if image.dtype != np.uint8:
        raise InputError(f"Expected a uint8 image, got {image.dtype}.")
    return image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image[..., :3]),
                                                      cv2.COLOR_RGB2GRAY)
