"""A reconstruction's points put into pycolmap with their Tracks made once per tracks and set of
active cameras (core.method.colmap_points): each build the same as one made from scratch, however
the active observations change between builds, and nothing kept once the tracks are gone."""
import gc
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from densecalib_ros.core.method import colmap_points
from densecalib_ros.core.method.reconstruction import (SfMState, build_reconstruction,
                                                       triangulate_tracks)

from sfm_fixtures import gt_rig, gt_tracks


def _observations(rec, track_of_point):
    """{track row: (xyz, [(camera, its observation's xy), ...])} as the reconstruction holds them."""
    out = {}
    for point_id, t in track_of_point.items():
        point = rec.point3D(point_id)
        seen = []
        for element in point.track.elements:
            image = rec.image(element.image_id)
            seen.append((element.image_id - 1, tuple(image.points2D[element.point2D_idx].xy)))
        out[t] = (tuple(point.xyz), sorted(seen))
    return out


def _expected(state):
    """The same from the state itself: every point's active observations in registered cameras."""
    obs = state.registered_active() & state.point_mask()[:, None]
    return {int(t): (tuple(state.points_xyz[t]),
                     sorted((int(c), tuple(state.tracks.xy_px[t, c])) for c in np.flatnonzero(obs[t])))
            for t in np.flatnonzero(state.point_mask())}


def test_points_built_from_made_tracks_hold_the_states_observations_as_they_change():
    cams, poses = gt_rig(4, seed=3)
    tracks = gt_tracks(cams, poses, num_points=300, seed=3)
    state = SfMState.create(tracks, cams)
    for c, pose in enumerate(poses):
        state.cam_from_world[c] = pose
    triangulate_tracks(state)
    rec, points = build_reconstruction(state, list("abcd"))
    assert _observations(rec, points) == _expected(state)
    # Observations switched off and a camera left out: the next build follows them, the Tracks
    # made for the earlier sets of cameras notwithstanding.
    rows = np.flatnonzero(state.tracks.observed().sum(axis=1) >= 3)[:40]
    state.active[rows, np.argmax(state.tracks.observed()[rows], axis=1)] = False
    state.cam_from_world[2] = None
    rec, points = build_reconstruction(state, list("abcd"))
    assert rec.num_reg_images() == 3
    assert _observations(rec, points) == _expected(state)
    # A copy shares the tracks, and with them what was made for them.
    copy = state.copy()
    copy.cam_from_world[2] = poses[2]
    rec, points = build_reconstruction(copy, list("abcd"))
    assert _observations(rec, points) == _expected(copy)


def test_what_was_made_for_tracks_goes_with_them():
    cams, poses = gt_rig(3, seed=4)
    state = SfMState.create(gt_tracks(cams, poses, num_points=100, seed=4), cams)
    for c, pose in enumerate(poses):
        state.cam_from_world[c] = pose
    triangulate_tracks(state)
    build_reconstruction(state, list("abc"))
    key = id(state.tracks.xy_px)
    assert key in colmap_points._MADE
    del state
    gc.collect()
    assert key not in colmap_points._MADE
