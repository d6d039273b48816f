"""`densecalib undistort`: resample a rig's images (or videos) to distortion-free pinhole
cameras (core.products.undistort) and write them with the matching calibration (PINHOLE cameras,
same extrinsics), all or nothing; or, with --stereo-pair, a pair's images rectified
(core.products.stereo) with the calibration of the rectified pair."""
from __future__ import annotations

import argparse
import copy
import functools
import logging
from pathlib import Path

import cv2
import numpy as np

from ..core.errors import InputError
from ..core.io.video_io import VIDEO_CODECS
from ..core.products.undistort import DEFAULT_MAX_FOV_DEG

log = logging.getLogger("densecalib.undistort")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder, a node's output_dir or a calibration.json")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--images", metavar="DIR",
                        help="images to undistort: DIR/<camera>.<ext> or DIR/<camera>/*, as for "
                             "calibrate; every image of each calibrated camera is written")
    source.add_argument("--videos", metavar="DIR",
                        help="videos to undistort: DIR/<camera>.<ext> (mp4, avi, mov, ...), "
                             "every frame, at the same frame rate (for tools that need pinhole "
                             "videos, e.g. DANNCE with fisheye cameras)")
    parser.add_argument("--codec", choices=tuple(VIDEO_CODECS), default=None,
                        help="with --videos: mp4v (.mp4, default), MJPG (.avi, larger, less "
                             "loss) or FFV1 (.mkv, lossless, largest)")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output folder (replaced): the same layout (images as PNG), and "
                             "calibration.json + <camera>.yaml of the undistorted cameras")
    parser.add_argument("--max-fov", type=float, default=None, metavar="DEG",
                        help="widest view across the undistorted image (fisheye lenses; default "
                             f"{DEFAULT_MAX_FOV_DEG:g} deg)")
    parser.add_argument("--stereo-pair", nargs=2, metavar=("LEFT", "RIGHT"),
                        help="instead: rectify these two cameras' images as a stereo pair "
                             "(corresponding points on one row; as cv2.initUndistortRectifyMap "
                             "with the pair's R and P, see `export --format ros-stereo`); the "
                             "output calibration holds the rectified pair, LEFT as reference")
    parser.add_argument("--alpha", type=float, default=None,
                        help="with --stereo-pair: 0 = only valid pixels (default), 1 = every "
                             "source pixel")


def run(args: argparse.Namespace) -> int:
    from ..core.io.camera_info import camera_info_yaml
    from ..core.io.export import (CALIBRATION_MARKERS, calibration_folder, read_calibration,
                                  write_calibration_files)
    from ..core.io.safe_write import (check_output_folder, replace_directory_atomic,
                                      write_text_atomic)
    from ..core.io.image_io import camera_image_files
    from ..core.products.undistort import undistortion_maps

    try:
        _check_options(args)
        inputs = [p for p in (args.images, args.videos) if p] + [
            calibration_folder(args.calibration)]
        check_output_folder(args.out, CALIBRATION_MARKERS, inputs)
        _refuse_a_calibration(args.out)
        rig = read_calibration(args.calibration)
        targets, rect = _targets(rig, args)
        if rect is not None:
            rig = _rectified_rig(rig, targets)
        source_dir = args.images or args.videos
        what = "videos" if args.videos else "images"
        jobs = {name: (_camera_video(args.videos, name) if args.videos
                       else camera_image_files(args.images, name)) for name in rig.cameras}
        missing = [n for n, files in jobs.items() if not files]
        if len(missing) == len(jobs):
            raise InputError(f"No {what} of the calibrated cameras ({', '.join(jobs)}) in "
                             f"{source_dir}: use DIR/<camera>.<ext>"
                             + ("" if args.videos else " or DIR/<camera>/ images") + ".")
        for name in missing:
            log.warning("No %s of camera %s in %s: skipped.", what, name, source_dir)
        flat = args.videos or not any((Path(args.images) / n).is_dir() for n in jobs)
        frames = {}  # camera -> frames written (videos)
        out_rig = copy.deepcopy(rig)
        out_rig.quality.undistorted_from = str(args.calibration)

        def build(tmp: Path) -> None:
            for name, files in jobs.items():
                if not files:
                    continue
                source = rig.cameras[name].intrinsics
                target, target_from_source = targets[name]
                maps = functools.cache(lambda s=source, t=target, r=target_from_source:
                                       undistortion_maps(s, t, r))  # once the size is checked
                out_rig.cameras[name].intrinsics = target
                if args.videos:
                    dest = tmp / f"{name}{VIDEO_CODECS[args.codec]}"
                    frames[name] = _remap_video(files[0], dest, maps, source, target,
                                                args.codec)
                    log.info("%s: %d frames, focal %.1f px", name, frames[name],
                             target.params[0])
                    continue
                for path in files:
                    _remap_image(path, tmp / f"{name}.png" if flat
                                 else tmp / name / f"{path.stem}.png", maps, source, name)
                log.info("%s: %d image(s), focal %.1f px, principal point (%.1f, %.1f)", name,
                         len(files), target.params[0], target.params[2] - 0.5,
                         target.params[3] - 0.5)
            for name in missing:
                del out_rig.cameras[name]
            if missing and args.stereo_pair:
                raise InputError(f"No {what} of camera {', '.join(missing)} of the stereo pair "
                                 f"in {source_dir}.")
            write_calibration_files(out_rig, tmp)
            if args.stereo_pair:  # stereo_image_proc takes the baseline from the right P's Tx
                for name, projection in ((rect.left, rect.projection_left),
                                         (rect.right, rect.projection_right)):
                    write_text_atomic(tmp / f"{name}.yaml", camera_info_yaml(
                        name, out_rig.cameras[name].intrinsics, np.eye(3), projection))

        replace_directory_atomic(build, args.out, CALIBRATION_MARKERS, inputs)
    except InputError as exc:
        log.error("%s", exc)
        return 2
    done = "rectified" if args.stereo_pair else "undistorted"
    count = (f"{len(frames)} {done} video(s) ({sum(frames.values())} frames)" if args.videos
             else f"{sum(len(f) for f in jobs.values())} {done} image(s)")
    print(f"wrote {args.out}: {count} of {len(jobs) - len(missing)} camera(s) and their pinhole "
          "calibration")
    return 0


def _check_options(args: argparse.Namespace) -> None:
    """InputError for an option out of range or of another mode (rather than ignored unsaid);
    then the defaults of those not given."""
    for option, value, mode, given in (
            ("--codec", args.codec, "--videos", args.videos),
            ("--alpha", args.alpha, "--stereo-pair", args.stereo_pair)):
        if value is not None and not given:
            raise InputError(f"{option} goes with {mode}.")
    if args.max_fov is not None and args.stereo_pair:
        raise InputError("--max-fov sets a single camera's view; a stereo pair's view is "
                         "--alpha's (0 = only valid pixels, 1 = every source pixel).")
    args.codec = args.codec or "mp4v"
    args.alpha = 0.0 if args.alpha is None else args.alpha
    args.max_fov = DEFAULT_MAX_FOV_DEG if args.max_fov is None else args.max_fov
    if not 0.0 < args.max_fov < 180.0:
        raise InputError(f"--max-fov {args.max_fov:g}: give an angle between 0 and 180 deg.")


def _refuse_a_calibration(out: str) -> None:
    """InputError where OUT holds a calibration that is not an earlier output of undistort (whose
    calibration.json records quality.undistorted_from): replacing it would lose that calibration,
    its COLMAP model and reference views."""
    from ..core.io.export import read_calibration

    if not (Path(out) / "calibration.json").is_file():
        return
    try:
        undistorted_from = read_calibration(out).quality.undistorted_from
    except InputError:  # a damaged calibration is still not ours to replace
        undistorted_from = None
    if not undistorted_from:
        raise InputError(f"{out} holds a calibration, not an earlier output of undistort: "
                         "writing there would replace it. Give a new folder.")


def _targets(rig, args: argparse.Namespace) -> tuple[dict, object]:
    """(camera -> (target pinhole camera, rotation of the target from the source camera or
    None), the stereo pair's rectification or None)."""
    from ..core.products.stereo import stereo_pair
    from ..core.products.undistort import pinhole_for, rectified_pinhole

    if not args.stereo_pair:
        return {name: (pinhole_for(cam.intrinsics, args.max_fov), None)
                for name, cam in rig.cameras.items()}, None
    rect = stereo_pair(rig, args.stereo_pair, args.alpha, left_to_right=False)
    if rect.horizontal and not rect.right_is_right:  # mirrored: a disparity matcher fails on it
        raise InputError(f"Camera {rect.right} lies to the left of {rect.left}: give the pair "
                         f"left camera first: --stereo-pair {rect.right} {rect.left}.")
    return {rect.left: (rectified_pinhole(rect.projection_left, rect.width, rect.height),
                        rect.rect_from_left),
            rect.right: (rectified_pinhole(rect.projection_right, rect.width, rect.height),
                         rect.rect_from_right)}, rect


def _remap_image(path: Path, dest: Path, maps, source, name: str) -> None:
    """Write image `path` of camera `name`, resampled by maps() (map_x, map_y), as PNG to
    dest."""
    from ..core.io.image_io import read_image

    image = read_image(path)
    if (image.shape[1], image.shape[0]) != (source.width, source.height):
        raise InputError(f"{path} is {image.shape[1]}x{image.shape[0]}, but camera {name} was "
                         f"calibrated at {source.width}x{source.height}: give the images it "
                         "was calibrated on, or the calibration of these.")
    undistorted = cv2.remap(image, *maps(), cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    dest.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(dest), cv2.cvtColor(undistorted, cv2.COLOR_RGB2BGR)):
        raise InputError(f"Cannot write {dest}: check the disk and permissions.")


def _camera_video(directory: str, name: str) -> list[Path]:
    """[the video of camera `name` in directory] (DIR/<name>.<video ext>), or []."""
    from ..core.io.file_kinds import VIDEO_EXTENSIONS

    return sorted(p for p in Path(directory).glob(f"{name}.*")
                  if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS)[:1]


def _remap_video(path: Path, dest: Path, maps, source, target, codec: str) -> int:
    """Write every frame of video `path` resampled by maps() (map_x, map_y) to dest at the same
    frame rate; returns the number of frames."""
    from ..core.io.video_io import probe_video, transcode_video

    info = probe_video(path)
    if (info.width, info.height) != (source.width, source.height):
        raise InputError(f"{path} is {info.width}x{info.height}, but its camera was calibrated "
                         f"at {source.width}x{source.height}.")
    map_x, map_y = maps()
    return transcode_video(info, dest, codec, size=(target.width, target.height),
                           transform=lambda frame: cv2.remap(frame, map_x, map_y,
                                                             cv2.INTER_LINEAR,
                                                             borderMode=cv2.BORDER_CONSTANT))


def _rectified_rig(rig, targets):
    """The rig of the rectified pair: the two cameras (keeping the source intrinsics until the
    images are resampled), each turned into its rectified frame, expressed from the left one."""
    from ..core.types import RigCalibration, RigCamera

    turned = {}
    for name, (_, rect_from_cam) in targets.items():
        pose = np.eye(4)
        pose[:3, :3] = rect_from_cam
        turned[name] = pose @ rig.cameras[name].cam_from_rig
    left = next(iter(targets))
    rig_from_left = np.linalg.inv(turned[left])
    quality = rig.quality.copy()
    quality.stereo_rectified_pair = list(targets)
    if quality.floor is not None:  # the floor frame, from the new rig frame (the left camera)
        floor = dict(quality.floor)
        floor_from_rig = np.asarray(floor["floor_from_rig"], dtype=np.float64).reshape(4, 4)
        floor["floor_from_rig"] = (floor_from_rig @ rig_from_left).ravel().tolist()
        floor["camera_heights"] = {n: h for n, h in floor["camera_heights"].items()
                                   if n in targets}
        quality.floor = floor
    return RigCalibration(
        reference_camera=left,
        cameras={name: RigCamera(name, rig.cameras[name].intrinsics, pose @ rig_from_left)
                 for name, pose in turned.items()},
        quality=quality, metric_scale=rig.metric_scale)
