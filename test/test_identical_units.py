"""Identical units (issue 81): cameras that are units of one model, found from their EXIF (make,
model, lens, focal length, image size) or named by the user, share one set of intrinsics in the
SfM and are estimated each on its own in the refinement on the images (one camera where the images
cannot tell them apart); the quality record and the progress say so."""
import numpy as np
import pytest
from PIL import Image

from densecalib_ros.core import (CameraIntrinsics, InputError, RigSpec, Tracks, generate_rig,
                                 make_config, run_calibration)
from densecalib_ros.core.io.exif import camera_identities, identical_unit_groups
from densecalib_ros.core.method.reconstruction import SfMState
from densecalib_ros.core.metrics import evaluate_calibration

MAKE, MODEL, BODY_SERIAL, LENS_MODEL, FOCAL_LENGTH = 0x010F, 0x0110, 0xA431, 0xA434, 0x920A


def _jpeg(path, make, model, serial, focal_mm=8.0, size=(64, 48)):
    exif = Image.Exif()
    exif[MAKE], exif[MODEL] = make, model
    sub = exif.get_ifd(0x8769)
    sub[BODY_SERIAL], sub[LENS_MODEL], sub[FOCAL_LENGTH] = serial, "f/2.8 8mm", focal_mm
    Image.new("RGB", size, (90, 90, 90)).save(path, exif=exif)
    return path


def test_exif_make_model_lens_and_focal_make_units_serials_tell_bodies(tmp_path):
    files = {"trap_a": _jpeg(tmp_path / "a.jpg", "Reconyx", "HF2X", "H100"),
             "trap_b": _jpeg(tmp_path / "b.jpg", "Reconyx", "HF2X", "H200"),
             "trap_c": _jpeg(tmp_path / "c.jpg", "Reconyx", "HF2X", "H300", focal_mm=12.0),
             "phone": _jpeg(tmp_path / "d.jpg", "Apple", "iPhone 13", "X1")}
    names = list(files)
    identities = camera_identities([[files[n] for n in names]], names)
    assert identities["trap_a"].serial == "H100" and identities["phone"].model == "iPhone 13"
    sizes = {n: (64, 48) for n in names}
    groups = identical_unit_groups(identities, sizes)
    assert [g[0] for g in groups] == [("trap_a", "trap_b")]  # trap_c's lens zoomed to 12 mm
    assert "EXIF Reconyx HF2X, lens f/2.8 8mm, 8 mm, 64x48; serial numbers H100, H200" == \
        groups[0][1]
    assert identical_unit_groups(identities, {**sizes, "trap_b": (32, 24)}) == []
    # the same body twice (one camera moved between shots)
    same = camera_identities([[files["trap_a"], _jpeg(tmp_path / "e.jpg", "Reconyx", "HF2X",
                                                      "H100")]], ["x", "y"])
    assert identical_unit_groups(same, {"x": (64, 48), "y": (64, 48)})[0][1].endswith(
        "one body (the same serial number)")


def test_units_share_one_block_in_the_sfm_and_get_their_own_after():
    config = make_config("regular", cameras__identical_units=((("a", "c"), "by hand"),))
    resolved = config.for_cameras(["a", "b", "c"])
    assert resolved.sfm.shared_intrinsics_groups == ((0, 2),)
    tracks = Tracks(np.zeros((0, 3, 2)), np.zeros(0, np.int32), np.zeros(0), np.zeros(0, np.int32))
    lenses = [CameraIntrinsics("RADIAL", 640, 480, np.array([f, 320.0, 240.0, 0.0, 0.0]))
              for f in (500.0, 600.0, 720.0)]
    state = SfMState.create(tracks, lenses, False, (), resolved.sfm.shared_intrinsics_groups)
    assert list(state.camera_block) == [0, 1, 0] and state.camera(0).params[0] == 610.0
    own = state.with_own_blocks([0, 2])
    assert len(set(own.camera_block)) == 3 and own.camera(0).params[0] == own.camera(2).params[0]
    with pytest.raises(InputError, match="x not among the cameras"):
        make_config(cameras__identical_units=((("a", "x"), ""),)).for_cameras(["a", "b"])
    with pytest.raises(InputError, match="different lenses"):
        make_config(cameras__identical_units=((("a", "b"), ""),),
                    cameras__lens={"b": "fisheye"}).for_cameras(["a", "b"])


def test_a_calibration_of_units_says_so_and_stays_right():
    """Three units of one model 50 deg apart: calibrated with one set of intrinsics in the SfM,
    each unit's own after the refinement on the images; right, recorded and said."""
    rig = generate_rig(RigSpec(num_cameras=3, width=640, height=480, seed=17, gap_deg=50.0,
                               max_arc_deg=360.0, lens_mix="identical"))
    units = ((tuple(rig.names), "the test's units"),)
    messages = []
    result = run_calibration(rig.images, rig.names,
                             make_config("regular", sfm__num_threads=1,
                                         cameras__identical_units=units),
                             progress=messages.append)
    q = result.rig.quality
    assert q.identical_units == [{"cameras": rig.names, "why": "the test's units"}]
    assert any("identical units (the test's units): one set of intrinsics in the SfM, each "
               "unit's own in the refinement on the images" in m for m in messages)
    metrics = evaluate_calibration(result.rig, rig.ground_truth())
    assert metrics["num_registered"] == 3 and metrics["auc3"] >= 66.0, metrics
