"""Image payloads <-> numpy (core.image_encoding) and ROS messages <-> core types
(ros.conversions): encodings, padding, byte order, compression, CameraInfo and TF conventions."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.image_encoding import (decode_compressed, decode_raw, encode_compressed,
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
    with pytest.raises(InputError, match="bayer_rggb8.*rgb8"):
        decode_raw("bayer_rggb8", 24, 32, 32, bytes(24 * 32))
    with pytest.raises(InputError, match="needs step"):
        decode_raw("rgb8", 24, 32, 96, bytes(100))
    with pytest.raises(InputError, match="Cannot decode"):
        decode_compressed("jpeg", b"not a jpeg")
    with pytest.raises(InputError, match="jpeg or png"):
        encode_compressed(RGB, "webp")


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
