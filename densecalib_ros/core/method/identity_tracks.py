"""Pose keypoints (core.io.keypoints) as correspondences by identity: one track per (frame,
individual, joint) seen by at least two cameras, and how they join a run's sampled image tracks.

The same joint of the same animal at the same instant is one point in space from any viewpoint,
so these tracks need no image matching: they hold between cameras 90 deg apart, across plain
arena walls, where image matches thin out or go wrong. They are as good as the tool's position
(1-3 px for a trained network) and only at the instants the cameras share (synchronised videos:
frame k of every camera; an offset where one started earlier).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from ..errors import InputError
from ..types import Tracks

log = logging.getLogger(__name__)

# Below this likelihood a tool's position is not trusted: DeepLabCut's own default pcutoff (its
# plots and anipose's filters hide points under it); SLEAP's and OpenPose's scores are on the same
# 0-1 scale, where 0.6 also keeps the confident detections.
MIN_LIKELIHOOD = 0.6
# At most this many tracks, from evenly spaced frames: as many as the sampled image tracks' 4-cycle
# share (6000 of the paper's 10k), so they cover the animal's path through the volume and weigh
# like image tracks, while the SfM's time stays that of image tracks (consecutive frames of a
# walking animal repeat nearly the same points).
MAX_IDENTITY_TRACKS = 6000
# A camera whose kept keypoints lie outside its image this often has another video's keypoints,
# or a video that was scaled before the tool ran; a few just outside are a network's guesses at
# the edge, and are dropped.
MAX_OUTSIDE_FRACTION = 0.05


@dataclass
class IdentityTracks:
    """Tracks by identity (COLMAP pixels: centre of the top-left pixel at (0.5, 0.5)), the image
    size per camera where the files gave one, and the record for quality.input."""

    tracks: Tracks
    image_sizes: list = field(default_factory=list)
    record: dict = field(default_factory=dict)


def identity_tracks(keypoints: dict, camera_names: Sequence[str],
                    image_sizes: Optional[Sequence] = None,
                    min_likelihood: float = MIN_LIKELIHOOD,
                    frame_offsets: Optional[dict] = None,
                    max_tracks: int = MAX_IDENTITY_TRACKS) -> IdentityTracks:
    """Tracks from {camera: CameraKeypoints} for the rig's cameras (module docstring).
    image_sizes: (width, height) per camera (None: the file's, else unchecked); frame_offsets:
    {camera: frames} its video started that many frames before the others (its frame k + N is
    their frame k). InputError naming the camera and file for keypoints of no camera of the rig,
    files sharing no joint or individual, or keypoints outside the image."""
    offsets = dict(frame_offsets or {})
    unknown = sorted((set(keypoints) | set(offsets)) - set(camera_names))
    if unknown:
        raise InputError(f"Keypoints or offsets of camera(s) {', '.join(unknown)}, which the rig "
                         f"does not have (its cameras: {', '.join(camera_names)}): name the "
                         "files after the cameras, or give NAME=PATH.")
    cams = [c for c, n in enumerate(camera_names) if n in keypoints]
    if len(cams) < 2:
        raise InputError(f"Keypoints of {len(cams)} camera(s) given; correspondences need two "
                         "or more.")
    missing = [n for n in camera_names if n not in keypoints]
    if missing:
        log.warning("no keypoints for %s: it is calibrated from its images only",
                    ", ".join(missing))
    kps = [keypoints[camera_names[c]] for c in cams]
    joints, individuals = _shared(kps, [camera_names[c] for c in cams])
    sizes = [(image_sizes[c] if image_sizes is not None and image_sizes[c] else kp.image_size)
             for c, kp in zip(cams, kps)]
    views = [_usable(kp, camera_names[c], joints, individuals, min_likelihood, size)
             for c, kp, size in zip(cams, kps, sizes)]
    frames = [kp.frames - int(offsets.get(camera_names[c], 0)) for c, kp in zip(cams, kps)]
    tracks, used = _tracks(views, frames, cams, len(camera_names), max_tracks)
    if not tracks.num_tracks:
        spans = ", ".join(f"{camera_names[c]} frames {int(f.min())}-{int(f.max())}" if len(f)
                          else f"{camera_names[c]} none" for c, f in zip(cams, frames))
        raise InputError(
            f"No joint was seen by two cameras in one frame at likelihood >= {min_likelihood:g} "
            f"({spans}): check that the files are of videos that run together (a camera that "
            "started early needs its frame offset) and the likelihood threshold.")
    record = {"files": {camera_names[c]: kp.path for c, kp in zip(cams, kps)},
              "tool": sorted({kp.tool for kp in kps}), "min_likelihood": min_likelihood,
              "joints": list(joints), "individuals": [i for i in individuals if i],
              "frames_used": used, "tracks": tracks.num_tracks,
              **({"frame_offsets": offsets} if offsets else {})}
    all_sizes = [None] * len(camera_names)
    for c, size in zip(cams, sizes):
        all_sizes[c] = size
    return IdentityTracks(tracks, all_sizes, record)


def _shared(kps: list, names: list) -> tuple[tuple, tuple]:
    """The joints and individuals every camera's file names (in the first file's order)."""
    joints = tuple(j for j in kps[0].joints if all(j in kp.joints for kp in kps))
    individuals = tuple(i for i in kps[0].individuals if all(i in kp.individuals for kp in kps))
    for what, shared, attr in (("joints", joints, "joints"),
                               ("individuals", individuals, "individuals")):
        if not shared:
            listed = "; ".join(f"{n} ({kp.path}): {', '.join(getattr(kp, attr)) or 'one, unnamed'}"
                               for n, kp in zip(names, kps))
            raise InputError(f"The keypoint files share no {what} ({listed}): give every camera "
                             "the same tool's output, with the same body parts and animals.")
    return joints, individuals


def _usable(kp, name: str, joints: tuple, individuals: tuple, min_likelihood: float,
            size: Optional[tuple]) -> tuple[np.ndarray, np.ndarray]:
    """(xy (F, I, J, 2) OpenCV px, usable (F, I, J)): positions the tool is confident of, inside
    the image where its size is known."""
    ii = [kp.individuals.index(i) for i in individuals]
    jj = [kp.joints.index(j) for j in joints]
    xy = kp.xy_px[:, ii][:, :, jj]
    with np.errstate(invalid="ignore"):
        usable = np.isfinite(xy).all(-1) & (kp.likelihood[:, ii][:, :, jj] >= min_likelihood)
    if size is None or not usable.any():
        return xy, usable
    w, h = size
    inside = (xy[..., 0] >= -0.5) & (xy[..., 0] <= w - 0.5) & \
        (xy[..., 1] >= -0.5) & (xy[..., 1] <= h - 0.5)
    outside = usable & ~inside
    if outside.sum() > MAX_OUTSIDE_FRACTION * usable.sum():
        f, i, j = (int(v[0]) for v in np.nonzero(outside))
        raise InputError(
            f"Camera {name} ({kp.path}): {int(outside.sum())} of {int(usable.sum())} keypoints "
            f"lie outside its {w}x{h} images (frame {int(kp.frames[f])}, {joints[j]} at "
            f"({xy[f, i, j, 0]:.0f}, {xy[f, i, j, 1]:.0f})): the file is of another video, or "
            "of one scaled before the tool ran; give that camera's own keypoints, or its "
            "images' size (--image-size).")
    return xy, usable & inside


def _tracks(views: list, frames: list, cams: list, num_cameras: int, max_tracks: int
            ) -> tuple[Tracks, int]:
    """(a track per (frame, individual, joint) usable in two or more cameras, from evenly
    spaced frames when there are more than max_tracks; the number of frames used)."""
    common = np.unique(np.concatenate(frames))
    seen = np.zeros((len(common),) + views[0][1].shape[1:], np.int32)
    rows = [np.searchsorted(common, f) for f in frames]
    for (_, usable), r in zip(views, rows):
        seen[r] += usable
    per_frame = (seen >= 2).sum(axis=(1, 2))
    with_tracks = np.flatnonzero(per_frame)
    total = int(per_frame.sum())
    if total > max_tracks:
        keep = max(1, int(len(with_tracks) * max_tracks / total))
        with_tracks = with_tracks[np.round(np.linspace(0, len(with_tracks) - 1, keep)).astype(int)]
    xy = np.full((len(with_tracks),) + seen.shape[1:] + (num_cameras, 2), np.nan)
    for (view_xy, usable), r, c in zip(views, rows, cams):
        at = np.full(len(common), -1)
        at[r] = np.arange(len(r))
        src = at[with_tracks]
        has = src >= 0
        block = np.where(usable[src[has]][..., None], view_xy[src[has]], np.nan)
        xy[has, ..., c, :] = block
    valid = (seen[with_tracks] >= 2)
    xy = xy[valid] + 0.5  # OpenCV -> COLMAP pixels
    n_obs = np.isfinite(xy[..., 0]).sum(axis=1)
    T = len(xy)
    # Not of a frame set: 0 keeps what looks a track's frame set up (its colour) in range.
    return Tracks(xy, np.clip(n_obs, 2, 4).astype(np.int32), np.ones(T),
                  np.zeros(T, np.int32)), int(len(with_tracks))


def beside_sampled(sampled, identity: Tracks, given_focal_px: Optional[np.ndarray]
                   ) -> tuple[Tracks, Optional[dict], Optional[np.ndarray]]:
    """(tracks, two-view geometry, focal px) for a run's SfM (runs.sfm_run) from its sampled
    image tracks (sampling.SamplingResult, or None where the images gave none) and the identity
    tracks. The pairs' geometry is estimated again on both (None: sfm_run does): a pair the
    image matches got wrong or missed, 90 deg apart, gets it from the keypoints. The focal
    lengths given (user, EXIF) are kept; else eq. 2 runs on that geometry (None). The identity
    tracks weigh in the view order as the median sampled track (their score)."""
    if sampled is None or not sampled.tracks.num_tracks:
        tracks = identity
    else:
        scores = sampled.tracks.score[sampled.tracks.score > 0]
        weight = float(np.median(scores)) if len(scores) else 1.0
        tracks = Tracks.concatenate([sampled.tracks, Tracks(
            identity.xy_px, identity.cycle_order, np.full(identity.num_tracks, weight),
            identity.time_index)], identity.num_cameras)
    given = given_focal_px is not None and np.isfinite(given_focal_px).all()
    return tracks, None, (np.asarray(given_focal_px, np.float64) if given else None)


def with_match_tracks(match_tracks: Optional[Tracks], identity: Optional[Tracks]
                      ) -> Optional[Tracks]:
    """The keypoint-match tracks a run judges and refines its rig on (runs.sfm_run's
    match_tracks), with the identity tracks beside them."""
    if identity is None or not identity.num_tracks:
        return match_tracks
    if match_tracks is None or not match_tracks.num_tracks:
        return identity
    return Tracks.concatenate([match_tracks, identity], identity.num_cameras)
