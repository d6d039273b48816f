"""NAME=VALUE options address cameras whose names (file stems, folders) hold '='."""
import cv2
import numpy as np
import pytest

from densecalib_ros.commands.inputs import named_numbers, parse_masks
from densecalib_ros.commands.triangulate import parse_observations
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.method.known_intrinsics import read_known_intrinsics
from densecalib_ros.core.named_values import split_named

from test_known_intrinsics import LAB_YAML


def test_the_longest_known_camera_name_is_the_name():
    names = ["a", "a=b", "c"]
    assert split_named("a=b=/x.png", names) == ("a=b", "=", "/x.png")
    assert split_named("a=/x=1.png", names) == ("a", "=", "/x=1.png")
    assert split_named("d=/x.png", names) == ("d", "=", "/x.png")  # unknown: first '='
    assert split_named("/x.png", names) == ("/x.png", "", "")


def test_masks_intrinsics_points_and_numbers_reach_a_camera_named_with_an_equals_sign(tmp_path):
    names = ["zone=1", "zone=2"]
    mask = np.full((30, 40), 255, np.uint8)
    mask[:5] = 0
    cv2.imwrite(str(tmp_path / "m.png"), mask)
    masks = parse_masks([f"zone=2={tmp_path / 'm.png'}"], names)
    assert list(masks) == ["zone=2"] and masks["zone=2"][:5].all()
    with pytest.raises(InputError, match="there is no camera 'zone'"):
        parse_masks([f"zone=3={tmp_path / 'm.png'}"], names)

    (tmp_path / "lab.yaml").write_text(LAB_YAML)
    known = read_known_intrinsics([f"zone=1={tmp_path / 'lab.yaml'}"], names)
    assert list(known) == ["zone=1"] and known["zone=1"].width == 800

    assert parse_observations(["zone=1=512.5,300", "zone=2=10,20"]) == {
        "zone=1": (512.5, 300.0), "zone=2": (10.0, 20.0)}
    assert named_numbers(["zone=1=800"], "--focal-px", "NAME=PX") == {"zone=1": 800.0}
