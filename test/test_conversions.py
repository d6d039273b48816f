"""Image payloads <-> numpy (core.io.image_encoding) and ROS messages <-> core types
(ros.conversions): encodings, padding, byte order, compression, CameraInfo and TF conventions."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.image_encoding import (decode_compressed, decode_raw, encode_compressed,
                                                   encode_raw, raw_to_array)
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera

RNG = np.random.default_rng(3)
RGB = RNG.integers(0, 256, (24, 32, 3), dtype=np.uint8)
GRAY = RNG.integers(0, 256, (24, 32), dtype=np.uint8)


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8"])
def test_color_round_trip(encoding):
    h, w, step, data = encode_raw(RGB, encoding)
    assert (h, w, step, len(data)) == (24, 32, 96, 24 * 96)
    stored = raw_to_array(encoding, h, w, step, data)
    assert np.array_equal(stored, RGB if encoding == "rgb8" else RGB[..., ::-1])
    assert np.array_equal(decode_raw(encoding, h, w, step, data), RGB)


def test_mono8_and_mono16_round_trip():
    h, w, step, data = encode_raw(GRAY, "mono8")
    assert np.array_equal(decode_raw("mono8", h, w, step, data), GRAY)
    h, w, step, data = encode_raw(GRAY, "mono16")  # 8 -> 16 bit by *257
    assert step == 64
    assert np.array_equal(raw_to_array("mono16", h, w, step, data), GRAY.astype(np.uint16) * 257)
    assert np.array_equal(decode_raw("mono16", h, w, step, data), GRAY)


def test_mono16_twelve_bit_keeps_contrast_and_big_endian():
    twelve = (GRAY.astype(np.uint16) << 4) | 0x5  # a 12-bit sensor: max 4085
    be = twelve.astype(">u2").tobytes()
    out = decode_raw("mono16", 24, 32, 64, be, is_bigendian=True)
    assert np.array_equal(out, GRAY)  # shifted by the used 12 bits, not by 8


def test_row_padding_is_ignored():
    padded = np.zeros((24, 100), np.uint8)
    padded[:, :96] = RGB.reshape(24, 96)
    assert np.array_equal(decode_raw("rgb8", 24, 32, 100, padded.tobytes()), RGB)


def test_bgra_drops_alpha():
    bgra = np.concatenate([RGB[..., ::-1], np.full((24, 32, 1), 7, np.uint8)], axis=2)
    assert np.array_equal(decode_raw("bgra8", 24, 32, 128, bgra.tobytes()), RGB)


def test_bad_images_are_refused_with_a_reason():
    with pytest.raises(InputError, match="32FC1.*rgb8.*bayer_rggb8"):  # e.g. a depth topic
        decode_raw("32FC1", 24, 32, 128, bytes(24 * 128))
    with pytest.raises(InputError, match="even width"):
        decode_raw("yuv422", 24, 31, 62, bytes(24 * 62))
    with pytest.raises(InputError, match="needs step"):
        decode_raw("rgb8", 24, 32, 96, bytes(100))
    with pytest.raises(InputError, match="Cannot decode"):
        decode_compressed("jpeg", b"not a jpeg")
    with pytest.raises(InputError, match="jpeg or png"):
        encode_compressed(RGB, "webp")


# A smooth colour image: demosaicing interpolates, so it is exact only where colour is linear.
_YY, _XX = np.mgrid[0:24, 0:32]
SMOOTH_RGB = np.stack([_XX * 7, _YY * 9 + 20, 240 - _XX * 5], axis=2).astype(np.uint8)


def _mosaic(rgb, pattern):
    """ROS Bayer pattern, e.g. "rggb": row 0 is R G R G..., row 1 is G B G B..."""
    out = np.zeros(rgb.shape[:2], rgb.dtype)
    for k, (dy, dx) in enumerate([(0, 0), (0, 1), (1, 0), (1, 1)]):
        out[dy::2, dx::2] = rgb[dy::2, dx::2, "rgb".index(pattern[k])]
    return out


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_is_demosaiced_to_rgb(pattern):
    mosaic8 = _mosaic(SMOOTH_RGB, pattern)
    assert encode_raw(SMOOTH_RGB, f"bayer_{pattern}8") == (24, 32, 32, mosaic8.tobytes())
    out = decode_raw(f"bayer_{pattern}8", 24, 32, 32, mosaic8.tobytes())
    assert out.shape == (24, 32, 3) and out.dtype == np.uint8
    # interior (the border rows and columns are extrapolated): the right colours, not swapped
    assert np.abs(out.astype(int) - SMOOTH_RGB)[2:-2, 2:-2].max() <= 1
    # 12-bit sensor in a 16-bit big-endian message: the same colours
    mosaic12 = (mosaic8.astype(np.uint16) << 4) | 0x3
    out16 = decode_raw(f"bayer_{pattern}16", 24, 32, 64, mosaic12.astype(">u2").tobytes(),
                       is_bigendian=True)
    assert np.array_equal(out16, out)


@pytest.mark.parametrize("encoding", ["yuv422", "uyvy", "yuv422_yuy2", "yuyv"])
def test_yuv422_is_converted_to_rgb(encoding):
    rgb = SMOOTH_RGB.astype(float)
    # BT.601 video range, the convention of ROS camera drivers' 4:2:2 output
    y = 16 + (65.738 * rgb[..., 0] + 129.057 * rgb[..., 1] + 25.064 * rgb[..., 2]) / 256
    u = 128 + (-37.945 * rgb[..., 0] - 74.494 * rgb[..., 1] + 112.439 * rgb[..., 2]) / 256
    v = 128 + (112.439 * rgb[..., 0] - 94.154 * rgb[..., 1] - 18.285 * rgb[..., 2]) / 256
    u2, v2 = (u[:, 0::2] + u[:, 1::2]) / 2, (v[:, 0::2] + v[:, 1::2]) / 2  # 4:2:2 subsampling
    macro = [u2, y[:, 0::2], v2, y[:, 1::2]] if encoding in ("yuv422", "uyvy") else \
        [y[:, 0::2], u2, y[:, 1::2], v2]
    data = np.round(np.stack(macro, axis=2)).astype(np.uint8).tobytes()  # 2 bytes per pixel
    out = decode_raw(encoding, 24, 32, 64, data)
    assert out.shape == (24, 32, 3) and out.dtype == np.uint8
    assert np.abs(out.astype(int) - SMOOTH_RGB).max() <= 8  # chroma is shared by pixel pairs
    assert np.abs(out.astype(int) - SMOOTH_RGB).mean() < 3


def test_rgb16_keeps_contrast():
    twelve = (RGB.astype(np.uint16) << 4)
    assert np.array_equal(decode_raw("rgb16", 24, 32, 192, twelve.astype("<u2").tobytes()), RGB)
    assert np.array_equal(decode_raw("bgr16", 24, 32, 192,
                                     twelve[..., ::-1].astype("<u2").tobytes()), RGB)


def test_compressed_png_exact_and_jpeg_close():
    assert np.array_equal(decode_compressed("png", encode_compressed(RGB, "png")), RGB)
    png = encode_compressed(GRAY, "png")
    assert np.array_equal(decode_compressed("mono8; png compressed", png), GRAY)
    smooth = np.clip(np.add.outer(np.arange(24) * 4, np.arange(32) * 3), 0, 255).astype(np.uint8)
    smooth = np.stack([smooth, smooth[::-1], 255 - smooth], axis=2)
    out = decode_compressed("rgb8; jpeg compressed bgr8", encode_compressed(smooth, "jpeg"))
    assert out.shape == smooth.shape and out.dtype == np.uint8
    assert np.abs(out.astype(int) - smooth).mean() < 3.0


# ---------------------------------------------------------------- ROS messages
@pytest.fixture
def conv():
    pytest.importorskip("rclpy", reason="ROS message tests need rclpy (ROS 2 Jazzy)")
    from densecalib_ros.ros import conversions

    return conversions


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "mono8", "mono16"])
def test_image_messages_round_trip(conv, encoding):
    src = GRAY if encoding.startswith("mono") else RGB
    msg = conv.numpy_to_image_msg(src, encoding, 1_700_000_000_123_456_789, "cam0_optical_frame")
    assert msg.encoding == encoding and (msg.height, msg.width) == (24, 32)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert conv.message_stamp_ns(msg) == 1_700_000_000_123_456_789
    assert np.array_equal(conv.image_msg_to_numpy(msg), src)


def test_bayer_message_is_demosaiced(conv):
    """A machine-vision driver's raw Bayer frame, as the node receives it from DDS."""
    msg = conv.numpy_to_image_msg(SMOOTH_RGB, "bayer_gbrg8", 5, "f")
    assert msg.encoding == "bayer_gbrg8" and msg.step == 32
    out = conv.image_msg_to_numpy(msg)
    assert np.abs(out.astype(int) - SMOOTH_RGB)[2:-2, 2:-2].max() <= 1


def test_compressed_message_round_trip(conv):
    msg = conv.numpy_to_compressed_msg(RGB, "png", 5, "f")
    assert msg.format == "png" and msg.header.frame_id == "f"
    assert np.array_equal(conv.image_msg_to_numpy(msg), RGB)


def test_camera_info_uses_ros_conventions(conv):
    radial = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320.5, 240.5, -0.1, 0.02]))
    msg = conv.camera_info_msg("cam0", radial, "cam0_optical_frame", 0)
    assert (msg.width, msg.height, msg.header.frame_id) == (640, 480, "cam0_optical_frame")
    assert msg.distortion_model == "plumb_bob"
    assert np.allclose(msg.k, [500, 0, 320, 0, 500, 240, 0, 0, 1])  # cx, cy - 0.5
    assert np.allclose(msg.d, [-0.1, 0.02, 0, 0, 0])
    assert np.allclose(msg.p, [500, 0, 320, 0, 0, 500, 240, 0, 0, 0, 1, 0])
    fisheye = CameraIntrinsics("OPENCV_FISHEYE", 800, 600,
                               np.array([300.0, 301.0, 400.0, 300.0, 0.1, -0.01, 0.002, -0.0003]))
    msg = conv.camera_info_msg("fe", fisheye, "fe_optical_frame", 0)
    assert msg.distortion_model == "equidistant"
    assert np.allclose(msg.d, [0.1, -0.01, 0.002, -0.0003])
    assert np.allclose(msg.k, [300, 0, 399.5, 0, 301, 299.5, 0, 0, 1])


def test_tf_message_holds_rig_from_cam(conv):
    cam_from_rig = np.eye(4)
    cam_from_rig[:3, :3] = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()
    cam_from_rig[:3, 3] = [0.3, -0.1, 0.05]
    intr = CameraIntrinsics("RADIAL", 64, 48, np.array([50.0, 32, 24, 0, 0]))
    rig = RigCalibration("a", {"a": RigCamera("a", intr, np.eye(4)),
                               "b": RigCamera("b", intr, cam_from_rig)})
    msg = conv.rig_tf_message(rig, "rig", {"a": "a_optical_frame", "b": "b_optical_frame"}, 42)
    assert [(t.header.frame_id, t.child_frame_id) for t in msg.transforms] == [
        ("rig", "a_optical_frame"), ("rig", "b_optical_frame")]
    assert np.allclose(conv.transform_to_matrix(msg.transforms[0]), np.eye(4))
    rig_from_b = conv.transform_to_matrix(msg.transforms[1])
    assert np.allclose(rig_from_b @ cam_from_rig, np.eye(4), atol=1e-12)
    # b's optical centre in the rig frame is -R^T t
    assert np.allclose([msg.transforms[1].transform.translation.x,
                        msg.transforms[1].transform.translation.y,
                        msg.transforms[1].transform.translation.z],
                       -cam_from_rig[:3, :3].T @ cam_from_rig[:3, 3])


def test_point_cloud_round_trip_and_rviz_layout():
    pytest.importorskip("rclpy", reason="ROS message tests need rclpy (ROS 2 Jazzy)")
    from densecalib_ros.ros.conversions import point_cloud_msg, point_cloud_to_numpy

    rng = np.random.default_rng(3)
    xyz, rgb = rng.normal(size=(50, 3)), rng.integers(0, 256, (50, 3)).astype(np.uint8)
    msg = point_cloud_msg(xyz, rgb, "rig", 1_500_000_000)
    assert (msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec) == ("rig", 1,
                                                                                  500_000_000)
    assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [
        ("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("rgb", 12, 7)]  # FLOAT32 = 7, as RViz reads
    assert (msg.width, msg.height, msg.point_step, len(msg.data)) == (50, 1, 16, 800)
    back_xyz, back_rgb = point_cloud_to_numpy(msg)
    np.testing.assert_allclose(back_xyz, xyz, rtol=1e-6, atol=1e-6)  # float32
    np.testing.assert_array_equal(back_rgb, rgb)
    packed = np.frombuffer(bytes(msg.data), np.uint32).reshape(50, 4)[:, 3]
    assert packed[0] == (int(rgb[0, 0]) << 16) | (int(rgb[0, 1]) << 8) | int(rgb[0, 2])
    assert point_cloud_msg(np.zeros((0, 3)), None, "rig", 0).width == 0
