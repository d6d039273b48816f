"""ROS image payloads <-> numpy, without ROS (used by the bag reader and by the node's conversions).

Works on the fields of sensor_msgs/Image (encoding, height, width, step, is_bigendian, data) and
sensor_msgs/CompressedImage (format, data), whatever object carries them (an rclpy message or a
`rosbags` deserialised message). Output images for the pipeline are uint8: (H, W, 3) RGB or (H, W)
gray; 16-bit images are shifted down to 8 bits by their used bit depth (a 12-bit camera keeps its
full contrast). Bayer mosaics (what machine-vision drivers publish, and rigs record to save
bandwidth) are demosaiced and YUV 4:2:2 (USB cameras) converted, both to RGB.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError

BAYER_PATTERNS = ("rggb", "bggr", "gbrg", "grbg")  # ROS names: the first two rows' filters
# encoding -> (channels, dtype, layout to reach RGB or gray); names as in sensor_msgs
# image_encodings.hpp
RAW_ENCODINGS = {
    "rgb8": (3, np.uint8, "rgb"), "bgr8": (3, np.uint8, "bgr"),
    "rgba8": (4, np.uint8, "rgba"), "bgra8": (4, np.uint8, "bgra"),
    "rgb16": (3, np.uint16, "rgb"), "bgr16": (3, np.uint16, "bgr"),
    "rgba16": (4, np.uint16, "rgba"), "bgra16": (4, np.uint16, "bgra"),
    "mono8": (1, np.uint8, "gray"), "8UC1": (1, np.uint8, "gray"),
    "8UC3": (3, np.uint8, "bgr"),
    "mono16": (1, np.uint16, "gray"), "16UC1": (1, np.uint16, "gray"),
    **{f"bayer_{p}{bits}": (1, dtype, f"bayer_{p}") for p in BAYER_PATTERNS
       for bits, dtype in ((8, np.uint8), (16, np.uint16))},
    # 4:2:2, two bytes per pixel: "yuv422"/"uyvy" is U Y0 V Y1, "yuv422_yuy2"/"yuyv" is Y0 U Y1 V
    "yuv422": (2, np.uint8, "uyvy"), "uyvy": (2, np.uint8, "uyvy"),
    "yuv422_yuy2": (2, np.uint8, "yuyv"), "yuyv": (2, np.uint8, "yuyv"),
}
COMPRESSED_FORMATS = ("jpeg", "png")
BAYER8_ENCODINGS = tuple(f"bayer_{p}8" for p in BAYER_PATTERNS)

# OpenCV names a Bayer pattern by the second row's second and third pixels, so ROS's rggb (first
# row R G) is OpenCV's "BG"; test_conversions checks each pattern on a mosaiced image.
_TO_RGB = {
    "bayer_rggb": cv2.COLOR_BayerBG2RGB, "bayer_bggr": cv2.COLOR_BayerRG2RGB,
    "bayer_gbrg": cv2.COLOR_BayerGR2RGB, "bayer_grbg": cv2.COLOR_BayerGB2RGB,
    "uyvy": cv2.COLOR_YUV2RGB_UYVY, "yuyv": cv2.COLOR_YUV2RGB_YUY2,
}


def _byte_buffer(data) -> np.ndarray:
    """A message's `data` (bytes, array.array, list or numpy array) as a uint8 array."""
    return np.frombuffer(bytes(data) if not isinstance(data, np.ndarray) else data.tobytes(),
                         dtype=np.uint8)


def raw_to_array(encoding: str, height: int, width: int, step: int, data,
                 is_bigendian: bool = False) -> np.ndarray:
    """The pixels of a sensor_msgs/Image as stored: (H, W) or (H, W, C), dtype uint8/uint16,
    channel order of `encoding` (no conversion)."""
    if encoding not in RAW_ENCODINGS:
        raise InputError(f"Unsupported image encoding {encoding!r}: publish one of "
                         f"{', '.join(RAW_ENCODINGS)} or a CompressedImage (jpeg/png).")
    channels, dtype, layout = RAW_ENCODINGS[encoding]
    if layout in ("uyvy", "yuyv") and width % 2:
        raise InputError(f"Malformed {encoding} image: 4:2:2 needs an even width, got {width}.")
    itemsize = np.dtype(dtype).itemsize
    buf = _byte_buffer(data)
    row_bytes = width * channels * itemsize
    if step < row_bytes or buf.size < step * height:
        raise InputError(f"Malformed {encoding} image: {width}x{height} needs step >= {row_bytes} "
                         f"and {max(step, row_bytes) * height} bytes, got step {step} and "
                         f"{buf.size} bytes.")
    rows = buf[: step * height].reshape(height, step)[:, :row_bytes]
    pixels = rows.copy().view(np.dtype(dtype).newbyteorder(">" if is_bigendian else "<"))
    pixels = pixels.astype(dtype)  # native byte order
    return pixels.reshape((height, width, channels) if channels > 1 else (height, width))


def to_pipeline_image(pixels: np.ndarray, order: str) -> np.ndarray:
    """Stored pixels in layout `order` (rgb, bgr, rgba, bgra, gray, bayer_<pattern>, uyvy, yuyv)
    -> uint8 RGB (H, W, 3) or gray (H, W)."""
    if pixels.dtype == np.uint16:
        bits = max(8, int(pixels.max()).bit_length())
        pixels = (pixels >> (bits - 8)).astype(np.uint8)
    if order in _TO_RGB:
        return cv2.cvtColor(np.ascontiguousarray(pixels), _TO_RGB[order])
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


def decode_compressed(fmt: str, data, half_grey: bool = False) -> np.ndarray:
    """sensor_msgs/CompressedImage fields -> uint8 RGB (H, W, 3) or gray (H, W).
    `fmt` is e.g. "jpeg", "png", "rgb8; jpeg compressed bgr8" (image_transport's format).
    half_grey: grey at half size instead, which JPEG decodes in a fraction of the time."""
    buf = _byte_buffer(data)
    image = cv2.imdecode(buf, cv2.IMREAD_REDUCED_GRAYSCALE_2 if half_grey
                         else cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"Cannot decode a CompressedImage of format {fmt!r} ({buf.size} bytes): "
                         "expected jpeg or png data.")
    if image.ndim == 2:
        return to_pipeline_image(image, "gray")
    return to_pipeline_image(image, "bgra" if image.shape[2] == 4 else "bgr")


def encode_raw(image: np.ndarray, encoding: str) -> tuple[int, int, int, bytes]:
    """uint8 RGB (H, W, 3) or gray (H, W) (uint16 for mono16) -> (height, width, step, data) of a
    little-endian sensor_msgs/Image with `encoding` in rgb8, bgr8, mono8, mono16 or bayer_<pattern>8
    (the colour filter of a raw sensor, e.g. bayer_rggb8: rows R G R G.. and G B G B..)."""
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
    elif encoding in BAYER8_ENCODINGS:
        rgb, pattern = _as_rgb(image), encoding[len("bayer_"):-1]
        out = np.empty(rgb.shape[:2], np.uint8)
        for k, (dy, dx) in enumerate([(0, 0), (0, 1), (1, 0), (1, 1)]):
            out[dy::2, dx::2] = rgb[dy::2, dx::2, "rgb".index(pattern[k])]
    else:
        raise InputError(f"Cannot encode images as {encoding!r}: use rgb8, bgr8, mono8, mono16 or "
                         f"one of {', '.join(BAYER8_ENCODINGS)}.")
    out = np.ascontiguousarray(out)
    height, width = out.shape[:2]
    return height, width, out.strides[0], out.tobytes()


def encode_compressed(image: np.ndarray, fmt: str = "jpeg", jpeg_quality: int = 95) -> bytes:
    """uint8 RGB (H, W, 3) or gray (H, W) -> jpeg or png bytes (CompressedImage.data)."""
    if fmt not in COMPRESSED_FORMATS:
        raise InputError(f"Unsupported compressed format {fmt!r}: use jpeg or png.")
    image = np.asarray(image)
    bgr = image if image.ndim == 2 else np.ascontiguousarray(image[..., ::-1])
    if fmt == "png":
        refuse_png_if_it_would_abort()
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


def refuse_png_if_it_would_abort() -> None:
    """InputError (with the fix) where writing a PNG would abort the process: pycolmap was
    imported before densecalib_ros and cv2 (densecalib_ros/__init__.py)."""
    import densecalib_ros

    if densecalib_ros.PNG_ABORTS:
        raise InputError(densecalib_ros.WRONG_IMPORT_ORDER)
