"""Cameras whose placement the raw matches contradict are moved (core.robust.placement): a camera
registered in a wrong place, two cameras wrong together, a camera facing a flat scene at a wrong
focal and distance, and correct rigs left alone."""
import numpy as np

from densecalib_ros.core.metrics import rotation_angle_deg
from densecalib_ros.core.robust.placement import group_support, repair_placements
from densecalib_ros.core.method.reconstruction import SfMState
from densecalib_ros.core.types import CameraIntrinsics, Tracks

from sfm_fixtures import gt_rig, gt_tracks

NAMES = ["a", "b", "c", "d", "e"]
SCENE_CENTRE = np.array([0.0, 0.0, 6.0])


def _rotated_about_scene(cam_from_world, angle_deg):
    """The camera turned by angle_deg about the world y axis through the scene centre."""
    a = np.radians(angle_deg)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    world_from_moved = np.eye(4)
    world_from_moved[:3, :3] = R
    world_from_moved[:3, 3] = SCENE_CENTRE - R @ SCENE_CENTRE
    return cam_from_world @ np.linalg.inv(world_from_moved)


def _state(cams, poses, tracks):
    state = SfMState.create(tracks, [CameraIntrinsics(c.model, c.width, c.height, c.params.copy())
                                     for c in cams])
    state.cam_from_world = [T.copy() for T in poses]
    return state


def _centre(T):
    return -T[:3, :3].T @ T[:3, 3]


def _assert_at_truth(state, poses, cameras):
    for c in cameras:
        assert rotation_angle_deg(state.cam_from_world[c][:3, :3] @ poses[c][:3, :3].T) < 0.5, c
        assert np.linalg.norm(_centre(state.cam_from_world[c]) - _centre(poses[c])) < 0.05, c


def test_a_camera_registered_in_a_wrong_place_is_moved_to_where_the_matches_put_it():
    cams, poses = gt_rig(5, seed=31)
    tracks = gt_tracks(cams, poses, num_points=2000, noise_px=0.3, outlier_frac=0.1, seed=31)
    state = _state(cams, poses, tracks)
    state.cam_from_world[3] = _rotated_about_scene(poses[3], 110.0)
    params = state.intrinsics[3].params
    params[0] *= 0.6  # a wrong registration usually comes with a wrong focal
    before = group_support(state, [3])

    moved = repair_placements(state, NAMES)

    assert moved == ["d"]
    assert group_support(state, [3]) > 10 * max(before, 1)
    _assert_at_truth(state, poses, [3])
    assert abs(state.camera(3).params[0] / cams[3].params[0] - 1) < 0.02
    for c in (0, 1, 2, 4):  # the others are not touched
        np.testing.assert_array_equal(state.cam_from_world[c], poses[c])


def test_two_cameras_wrong_together_are_moved_as_a_pair():
    """Cameras b and c share many matches with each other (as two nearly identical views do) and
    are turned together: each alone is held in the wrong place by the other's matches, so only
    moving the pair explains the matches with the rest of the rig."""
    cams, poses = gt_rig(5, seed=32)
    tracks = gt_tracks(cams, poses, num_points=1500, noise_px=0.3, outlier_frac=0.03, seed=32)
    pair = gt_tracks([cams[1], cams[2]], [poses[1], poses[2]], num_points=4000, noise_px=0.3,
                     outlier_frac=0.0, seed=33)
    xy = np.full((pair.num_tracks, 5, 2), np.nan)
    xy[:, 1:3] = pair.xy_px
    tracks = Tracks.concatenate([tracks, Tracks(xy, pair.cycle_order, pair.score, pair.time_index)], 5)
    state = _state(cams, poses, tracks)
    for c in (1, 2):
        state.cam_from_world[c] = _rotated_about_scene(poses[c], 35.0)

    moved = repair_placements(state, NAMES)

    assert sorted(moved) == ["b", "c"]
    _assert_at_truth(state, poses, [1, 2])


def test_a_right_rig_is_left_alone_even_with_many_wrong_matches():
    cams, poses = gt_rig(5, seed=34)
    tracks = gt_tracks(cams, poses, num_points=2000, noise_px=0.5, outlier_frac=0.3, seed=34)
    state = _state(cams, poses, tracks)
    # A slightly loose rig (what SfM on sparse tracks leaves) is still the right placement.
    rng = np.random.default_rng(34)
    for c in range(5):
        state.cam_from_world[c] = _rotated_about_scene(poses[c], rng.uniform(-0.3, 0.3))
    kept = [T.copy() for T in state.cam_from_world]

    assert repair_placements(state, NAMES) == []
    for c in range(5):
        np.testing.assert_array_equal(state.cam_from_world[c], kept[c])


def _identical_cameras(cams):
    """The rig's cameras made identical units (focal and distortion of the first, no distortion):
    a fronto-parallel plane then looks the same at focal k f from distance k d."""
    for cam in cams:
        cam.params[0] = cams[0].params[0]
        cam.params[3:] = 0.0
    return cams


def test_a_camera_facing_a_flat_scene_at_a_wrong_focal_and_distance_is_moved_to_its_peers_focal():
    """Camera c faces a wall square on; registered at 0.4x its focal and 0.4x the distance, every
    match fits exactly as well as at the truth (the focal-distance ambiguity). The other cameras
    are identical units, so the placement at their focal is taken."""
    cams, poses = gt_rig(5, seed=35)
    cams = _identical_cameras(cams)
    c, k = 2, 0.4
    R, centre = poses[c][:3, :3], _centre(poses[c])
    u, v = np.random.default_rng(35).uniform([-2.5, -1.8], [2.5, 1.8], (2000, 2)).T
    wall = centre + 6.0 * R[2] + u[:, None] * R[0] + v[:, None] * R[1]  # square on to c, 6 away
    tracks = gt_tracks(cams, poses, noise_px=0.3, outlier_frac=0.03, seed=35, points_xyz=wall)
    state = _state(cams, poses, tracks)
    state.cam_from_world[c][:3, 3] = -R @ (centre + (1 - k) * 6.0 * R[2])
    state.intrinsics[c].params[0] *= k
    before = group_support(state, [c])

    moved = repair_placements(state, NAMES)

    assert moved == ["c"]
    assert group_support(state, [c]) >= before
    _assert_at_truth(state, poses, [c])
    assert abs(state.camera(c).params[0] / cams[c].params[0] - 1) < 0.02


def test_a_camera_with_another_focal_than_its_peers_is_left_alone():
    """A right rig in which one camera has 1.8x the focal of the others (another lens on the same
    sensor): its focal is far from its peers', but no other placement fits as many matches."""
    cams, poses = gt_rig(5, seed=36)
    cams = _identical_cameras(cams)
    cams[1].params[0] *= 1.8
    tracks = gt_tracks(cams, poses, num_points=2500, noise_px=0.3, outlier_frac=0.1, seed=36)
    state = _state(cams, poses, tracks)

    assert repair_placements(state, NAMES) == []
    for c in range(5):
        np.testing.assert_array_equal(state.cam_from_world[c], poses[c])
