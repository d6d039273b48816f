"""The node's parameters: their table (default, description, read-only, range), their validation
into Settings, and the core pipeline configuration they select. Kept apart from the node so that the
rules a parameter obeys are read in one place (and tested without spinning a node)."""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from rcl_interfaces.msg import FloatingPointRange, IntegerRange
from rclpy.parameter import Parameter

from ..core.config import (DEFAULT_PIPELINE, LENS_MODELS, PIPELINES, PRESETS, PipelineConfig,
                           make_config)
from ..core.errors import InputError
from ..core.io.bag import camera_names_from_topics, topic_namespace
from ..core.io.sync import DEFAULT_MAX_FRAME_SETS
from ..core.method.known_intrinsics import read_known_intrinsics
from ..core.method.masks import read_mask
from ..core.method.matching import available_matchers
from ..core.monitor.consistency import DEFAULT_TOLERANCE_PX
from ..core.products.floor import VIEWS as FLOOR_VIEWS

TRANSPORTS = ("auto", "raw", "compressed")
RIG_FRAME_AXES = ("optical", "body")
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_FRAME_RE = re.compile(r"^[A-Za-z0-9_/.\-]+$")


def _range(lo, hi, integer: bool):
    return ({"integer_range": [IntegerRange(from_value=lo, to_value=hi, step=0)]} if integer else
            {"floating_point_range": [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]})


# name -> (default, or the type of an optional array; description; read-only; range kwargs)
PARAMETERS: dict[str, tuple[Any, str, bool, dict]] = {
    "image_topics": (Parameter.Type.STRING_ARRAY,
                     "image topics, one per camera (sensor_msgs/Image or CompressedImage); "
                     "at least two", True, {}),
    "camera_names": (Parameter.Type.STRING_ARRAY,
                     "camera names, one per topic (default: from the topics, "
                     "/stereo/left/image_raw -> stereo_left)", True, {}),
    "transports": (Parameter.Type.STRING_ARRAY,
                   "per topic (or one for all): auto (topic type from the graph; '.../compressed' "
                   "is compressed), raw (Image) or compressed (CompressedImage)", True, {}),
    "slop_s": (0.02, "approximate-time synchronisation: max stamp spread within a frame set [s]",
               True, _range(0.0, 10.0, False)),
    "stamp_offsets_s": (Parameter.Type.DOUBLE_ARRAY,
                        "per camera, how far its stamping clock runs ahead of the others' [s] "
                        "(cameras on unsynchronised computers; ~/sync measures them from the "
                        "images, as `densecalib calibrate --bag ... --time-offset auto` does "
                        "from a recording): empty = all 0. Changed at run time, the buffered "
                        "frame sets are dropped (they were paired by the old offsets)",
                        False, {}),
    "sync_window_s": (0.0, "track each camera's motion over its latest this many seconds, for "
                      "~/sync to measure stamp_offsets_s from (costs a half-size decode of every "
                      "image); 0 = off", True, _range(0.0, 3600.0, False)),
    "sync_queue_size": (10, "pending messages per topic while waiting for partners", True,
                        _range(1, 1000, True)),
    "buffer_size": (50, "frame sets kept for calibration; the oldest is dropped when full", True,
                    _range(1, 10000, True)),
    "min_interval_s": (0.5, "frame sets closer in time than this to the last buffered one are "
                       "skipped [s]", True, _range(0.0, 3600.0, False)),
    "min_frame_sets": (1, "frame sets needed before a calibration starts", False,
                       _range(1, 10000, True)),
    "check_tolerance_px": (DEFAULT_TOLERANCE_PX, "~/check: a camera pair or triple fits when its "
                           "median epipolar / transfer error is at most this [px]", False,
                           _range(0.01, 1000.0, False)),
    "check_interval_s": (0.0, "watch: check the calibration this often [s] (as ~/check) on the "
                         "frame sets that arrived since the last check, if any, and show the "
                         "outcome on /diagnostics (WARN when a camera moved); 0 = off", False,
                         _range(0.0, 86400.0, False)),
    "recalibrate_on_change": (False, "watch: when a check finds that the calibration no longer "
                              "fits on two frame sets or more, start a recalibration (as "
                              "~/calibrate: from the frame sets since the change; a worse result "
                              "is refused)", False, {}),
    "max_frame_sets": (DEFAULT_MAX_FRAME_SETS, "a calibration uses at most this many buffered "
                       "frame sets, evenly spaced over the buffer", False, _range(1, 10000, True)),
    "preset": ("regular", "method preset: regular (pinhole + radial) or fisheye", False, {}),
    "camera_lens": (Parameter.Type.STRING_ARRAY,
                    "per camera its lens, pinhole or fisheye, for a rig mixing lenses (empty: "
                    "the preset's for all)", False, {}),
    "mask_files": (Parameter.Type.STRING_ARRAY,
                   "images of the cameras' size, black where matches are not used (an info "
                   "strip, the rig's own structure): empty, one for every camera, or one per "
                   "camera ('' = none)", False, {}),
    "detect_info_strips": (True, "find burnt-in info strips (a trail camera's bar of date and "
                           "temperature along the top or bottom edge) and ignore their rows in "
                           "cameras without a mask_files entry", False, {}),
    "new_content_only": (True, "asift (matcher or second_matcher) matches frame sets after the "
                         "first only where a camera's image shows what its earlier frame sets "
                         "did not (false: whole images)", False, {}),
    "intrinsics_files": (Parameter.Type.STRING_ARRAY,
                         "intrinsics to keep (cameras calibrated before: camera_info YAML, a "
                         "densecalib calibration, an anipose calibration.toml, a Kalibr "
                         "camchain or an OpenCV calibration file, a stereo one as "
                         "'left,right=PATH'): empty, one file or folder naming its cameras, "
                         "or one per camera ('' = calibrate that camera's intrinsics); only the "
                         "extrinsics of those cameras are calibrated", False, {}),
    "keep_intrinsics": (False, "recalibrations keep the last good calibration's intrinsics and "
                        "calibrate the extrinsics only (mounts bumped, lenses untouched; off "
                        "after a refocus or zoom)", False, {}),
    "pipeline": (DEFAULT_PIPELINE, "SfM pipeline: incremental or global", False, {}),
    "matcher": ("sift", "matcher backend", False, {}),
    "second_matcher": ("asift", "where perspective cameras matched with sift come out "
                       "undetermined (a camera not registered, runs that disagree, focal lengths "
                       "looser than 1 % where the cameras do not all look one way), match again "
                       "with this one and keep the better-determined calibration (none: keep "
                       "sift's)", False, {}),
    "consensus_runs": (5, "sample + SfM up to this many times with different seeds and keep the "
                       "run that fits all keypoint matches best (stops after 2 runs that agree, "
                       "1 where its focal starts all agree and it registered every camera; 1 = "
                       "one run, no focal hops)", False, _range(1, 20, True)),
    "share_intrinsics": (False, "one set of intrinsics for cameras of the same image size "
                         "(identical cameras: same model, lens and zoom)", False, {}),
    "separate_intrinsics": (False, "the cameras are of different models: never calibrate them "
                            "as units of one model (tried, where they could be, when the "
                            "calibration runs disagree)", False, {}),
    "initial_focal_px": (Parameter.Type.DOUBLE_ARRAY,
                         "known focal lengths [px]: one for all cameras or one per camera "
                         "(empty: estimated from the images); the calibration starts from them "
                         "and still refines them", False, {}),
    "max_image_side_px": (1024, "images are matched at most at this size [px]", False,
                          _range(64, 16384, True)),
    "output_dir": ("~/.ros/densecalib", "calibration files: <output_dir>/<UTC time>/ and a "
                   "'latest' symlink", True, {}),
    "keep_calibrations": (0, "keep only this many calibrations in output_dir, the newest (by "
                          "their names' UTC time; the one `latest` points to always stays): the "
                          "oldest are removed after each calibration; 0 = keep all", False,
                          _range(0, 100000, True)),
    "rig_frame": ("rig", "parent frame of the cameras' transforms on /tf_static, at the "
                  "reference camera (its axes: rig_frame_axes)", True, {}),
    "rig_frame_axes": ("optical", "axes of rig_frame: 'optical' (the reference camera's optical "
                       "frame: z forward, x right, y down) or 'body' (REP-103: x forward, y "
                       "left, z up, for a reference camera mounted level and looking forward "
                       "along x)", True, {}),
    "floor": ("", "after each calibration find the floor in the scene points and publish "
              "floor_frame -> rig_frame on /tf_static: '' (off), 'upright' (cameras mounted "
              "upright) or 'top' (all looking straight down); see `calibrate --floor`. Turned "
              "on at run time, the current calibration's floor (found now in its saved scene "
              "points if it has none, and recorded in its calibration.json) is published at "
              "once; turned off, /tf_static is republished without it", False, {}),
    "floor_frame": ("floor", "frame of the floor (z up), the parent of rig_frame when floor is "
                    "on", True, {}),
    "frame_names": (Parameter.Type.STRING_ARRAY,
                    "optical frame per camera (default <camera>_optical_frame)", True, {}),
    "camera_info_topics": (Parameter.Type.STRING_ARRAY,
                           "CameraInfo topic per camera (default ~/<camera>/camera_info: not the "
                           "driver's own, which it publishes itself)",
                           True, {}),
    "stereo_pairs": (Parameter.Type.STRING_ARRAY,
                     "stereo pairs, each as its left then its right camera (e.g. [front_left, "
                     "front_right, rear_left, rear_right]), whose CameraInfo (published and sent "
                     "to set_camera_info) carry the pair's stereo rectification (R, and P with "
                     "Tx = -fx' baseline) for stereo_image_proc; empty: R = I, P = [K | 0] for "
                     "every camera", False, {}),
    "call_set_camera_info": (False, "after a calibration, call each camera's set_camera_info",
                             False, {}),
    "set_camera_info_services": (Parameter.Type.STRING_ARRAY,
                                 "set_camera_info service per camera (default <image topic "
                                 "ns>/set_camera_info)", True, {}),
    "set_camera_info_timeout_s": (5.0, "timeout of each set_camera_info call [s]", False,
                                  _range(0.01, 600.0, False)),
    "known_baseline_m": (0.0, "if > 0: distance between baseline_cameras [m], gives metric "
                         "translations", False, _range(0.0, 1.0e6, False)),
    "baseline_cameras": (Parameter.Type.STRING_ARRAY,
                         "the two cameras whose distance is known_baseline_m", False, {}),
    "replay_bag": ("", "rosbag2 folder/file to replay into the node at start-up (its "
                   "image_topics)", True, {}),
    "replay_rate": (0.0, "replay speed factor (0 = as fast as possible)", True,
                    _range(0.0, 1000.0, False)),
    "calibrate_after_replay": (True, "start a calibration when the replay ends", True, {}),
}


@dataclass
class Settings:
    """Validated node parameters (see PARAMETERS for their meaning)."""

    image_topics: list[str]
    camera_names: list[str]
    transports: list[str]
    slop_s: float
    stamp_offsets_s: list[float]
    sync_window_s: float
    sync_queue_size: int
    buffer_size: int
    min_interval_s: float
    min_frame_sets: int
    max_frame_sets: int
    check_tolerance_px: float
    check_interval_s: float
    recalibrate_on_change: bool
    preset: str
    camera_lens: dict[str, str]
    camera_masks: dict  # camera name -> bool (H, W), True = ignored (core.method.masks)
    detect_info_strips: bool
    new_content_only: bool
    known_intrinsics: dict  # camera name -> CameraIntrinsics kept (core.method.known_intrinsics)
    keep_intrinsics: bool
    pipeline: str
    matcher: str
    share_intrinsics: bool
    separate_intrinsics: bool
    initial_focal_px: dict[str, float]
    consensus_runs: int
    second_matcher: Optional[str]
    max_image_side_px: int
    output_dir: Path
    keep_calibrations: int
    rig_frame: str
    rig_frame_axes: str
    floor: str
    floor_frame: str
    frame_names: list[str]
    camera_info_topics: list[str]
    stereo_pairs: list[tuple[str, str]]
    call_set_camera_info: bool
    set_camera_info_services: list[str]
    set_camera_info_timeout_s: float
    known_baseline_m: float
    baseline_cameras: list[str]
    replay_bag: str
    replay_rate: float
    calibrate_after_replay: bool


def pipeline_config(s: Settings) -> PipelineConfig:
    """The core pipeline configuration the node's method parameters select."""
    return make_config(s.preset, s.pipeline, s.matcher, max_image_side_px=s.max_image_side_px,
                       sfm__share_intrinsics=s.share_intrinsics,
                       cameras__units_from_images=not s.separate_intrinsics,
                       consensus_runs=s.consensus_runs, detect_info_strips=s.detect_info_strips,
                       new_content_matchers=("asift",) if s.new_content_only else (),
                       second_matcher=s.second_matcher,
                       cameras__initial_focal_px=s.initial_focal_px, cameras__lens=s.camera_lens,
                       cameras__masks=s.camera_masks, cameras__known_intrinsics=s.known_intrinsics)


def _per_camera(values: list[str], n: int, what: str, default) -> list[str]:
    if not values:
        return [default(i) for i in range(n)]
    if len(values) != n:
        raise InputError(f"{what} has {len(values)} entries for {n} image topics: give one per "
                         "topic or leave it empty for the default.")
    return list(values)


def is_list_parameter(name: str) -> bool:
    return isinstance(PARAMETERS[name][0], Parameter.Type)


def list_parameter_value(name: str, value: Any) -> list:
    """A list parameter's value as a list of its element type. The list parameters take any
    array type (dynamic typing): `ros2 param set N "[]"` sends an empty BOOL_ARRAY and "[800]" an
    INTEGER_ARRAY, which rclpy's declared-type check would refuse with a message of types."""
    if value is None:
        return []
    example = "['a', 'b']" if PARAMETERS[name][0] == Parameter.Type.STRING_ARRAY else "[0.5, 1.0]"
    if isinstance(value, str) and value.strip().startswith("["):
        # ros2param sends a list mixing ints and floats ("[0, 0.35]") as this string
        import yaml
        try:
            value = yaml.safe_load(value)
        except yaml.YAMLError:
            pass
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise InputError(f"{name} is a list: write it in brackets, e.g. {name}:=\"{example}\" "
                         f"(got {value!r}).")
    items = list(value)
    if PARAMETERS[name][0] == Parameter.Type.DOUBLE_ARRAY:
        if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in items):
            raise InputError(f"{name} is a list of numbers, e.g. {example} (got {items}).")
        return [float(x) for x in items]
    if not all(isinstance(x, str) for x in items):
        raise InputError(f"{name} is a list of strings, e.g. {example} (got {items}).")
    return items


def parse_settings(values: dict[str, Any]) -> Settings:
    """Validate raw parameter values (None = not set) into Settings; raises InputError with a
    message naming the parameter and the accepted values."""
    v = {k: (list_parameter_value(k, values.get(k)) if is_list_parameter(k) else
             values.get(k) if values.get(k) is not None else PARAMETERS[k][0])
         for k in PARAMETERS}
    topics, names, transports, stamp_offsets = _cameras(v)
    n = len(topics)
    _check_choices(v)
    lenses, camera_masks, known_intrinsics = _lenses(v, names)
    frames, rig_frame, floor_frame = _frames(v, names)
    info_topics, services = _camera_info_outputs(v, names, topics)
    pairs, baseline_cams = _camera_pairs(v, names)
    focals = [float(f) for f in v["initial_focal_px"]]
    if len(focals) not in (0, 1, n) or not all(math.isfinite(f) and f > 0 for f in focals):
        raise InputError(f"initial_focal_px must be empty, one positive focal length [px] for all "
                         f"cameras or one per camera ({n}), got {focals}.")
    initial_focal_px = {"*": focals[0]} if len(focals) == 1 else dict(zip(names, focals))
    return Settings(
        image_topics=topics, camera_names=names, transports=transports,
        slop_s=float(v["slop_s"]), stamp_offsets_s=stamp_offsets or [0.0] * n,
        sync_window_s=float(v["sync_window_s"]),
        sync_queue_size=int(v["sync_queue_size"]),
        buffer_size=int(v["buffer_size"]), min_interval_s=float(v["min_interval_s"]),
        min_frame_sets=int(v["min_frame_sets"]), max_frame_sets=int(v["max_frame_sets"]),
        check_tolerance_px=float(v["check_tolerance_px"]),
        check_interval_s=float(v["check_interval_s"]),
        recalibrate_on_change=bool(v["recalibrate_on_change"]),
        preset=v["preset"],
        camera_lens=dict(zip(names, lenses)), camera_masks=camera_masks,
        detect_info_strips=bool(v["detect_info_strips"]),
        new_content_only=bool(v["new_content_only"]),
        known_intrinsics=known_intrinsics, keep_intrinsics=bool(v["keep_intrinsics"]),
        pipeline=v["pipeline"],
        matcher=v["matcher"], share_intrinsics=bool(v["share_intrinsics"]),
        separate_intrinsics=bool(v["separate_intrinsics"]),
        initial_focal_px=initial_focal_px,
        consensus_runs=int(v["consensus_runs"]),
        second_matcher=None if v["second_matcher"] == "none"
        else v["second_matcher"],
        max_image_side_px=int(v["max_image_side_px"]),
        output_dir=Path(os.path.expanduser(str(v["output_dir"]))),
        keep_calibrations=int(v["keep_calibrations"]), rig_frame=rig_frame,
        rig_frame_axes=v["rig_frame_axes"],
        floor=v["floor"], floor_frame=floor_frame,
        frame_names=frames, camera_info_topics=info_topics, stereo_pairs=pairs,
        call_set_camera_info=bool(v["call_set_camera_info"]), set_camera_info_services=services,
        set_camera_info_timeout_s=float(v["set_camera_info_timeout_s"]),
        known_baseline_m=float(v["known_baseline_m"]), baseline_cameras=baseline_cams,
        replay_bag=os.path.expanduser(v["replay_bag"]), replay_rate=float(v["replay_rate"]),
        calibrate_after_replay=bool(v["calibrate_after_replay"]))


def _cameras(v: dict) -> tuple[list, list, list, list]:
    """(image_topics, camera_names, transports, stamp_offsets_s), checked."""
    topics = list(v["image_topics"])
    if len(topics) < 2:
        raise InputError(f"image_topics must list at least two image topics (one per camera), got "
                         f"{topics or 'none'}.")
    if len(set(topics)) != len(topics) or any(not t.strip("/") for t in topics):
        raise InputError(f"image_topics must be distinct, non-empty topic names, got {topics}.")
    n = len(topics)
    names = _per_camera(list(v["camera_names"]), n, "camera_names",
                        lambda i: camera_names_from_topics(topics)[i])
    bad = [c for c in names if not _NAME_RE.match(c)]
    if bad or len(set(names)) != n:
        raise InputError(f"camera_names must be distinct identifiers ([A-Za-z_][A-Za-z0-9_]*), "
                         f"got {names}.")
    transports = list(v["transports"]) or ["auto"]
    if len(transports) == 1:
        transports = transports * n
    transports = _per_camera(transports, n, "transports", None)
    if any(t not in TRANSPORTS for t in transports):
        raise InputError(f"transports must be one of {', '.join(TRANSPORTS)} per topic, got "
                         f"{transports}.")
    stamp_offsets = [float(o) for o in v["stamp_offsets_s"]]
    if stamp_offsets and (len(stamp_offsets) != n
                          or not all(math.isfinite(o) for o in stamp_offsets)):
        raise InputError(f"stamp_offsets_s must be empty or one offset [s] per camera ({n}), got "
                         f"{stamp_offsets}.")
    return topics, names, transports, stamp_offsets


def _check_choices(v: dict) -> None:
    """The parameters that take one of a few values, and the buffer, output and bag."""
    for key, allowed in (("preset", PRESETS), ("pipeline", PIPELINES),
                         ("matcher", available_matchers()),
                         ("second_matcher", [*available_matchers(), "none"]),
                         ("rig_frame_axes", RIG_FRAME_AXES)):
        if v[key] not in allowed:
            raise InputError(f"{key} must be one of {', '.join(allowed)}, got {v[key]!r}.")
    if v["floor"] not in ("", *FLOOR_VIEWS):
        raise InputError(f"floor must be '' (off) or one of {', '.join(FLOOR_VIEWS)}, got "
                         f"{v['floor']!r}.")
    if v["min_frame_sets"] > v["buffer_size"]:
        raise InputError(f"min_frame_sets ({v['min_frame_sets']}) cannot exceed buffer_size "
                         f"({v['buffer_size']}).")
    if not str(v["output_dir"]).strip():
        raise InputError("output_dir must name a directory for the calibration files.")
    if v["replay_bag"] and not Path(os.path.expanduser(v["replay_bag"])).exists():
        raise InputError(f"replay_bag {v['replay_bag']} does not exist: give a rosbag2 folder or "
                         "an .mcap/.db3 file, or leave it empty.")


def _lenses(v: dict, names: list) -> tuple[list, dict, dict]:
    """(camera_lens per camera or [], camera masks by name, known intrinsics by name)."""
    n = len(names)
    lenses = list(v["camera_lens"])
    if lenses and (len(lenses) != n or any(lens not in LENS_MODELS for lens in lenses)):
        raise InputError(f"camera_lens must be empty or give one lens per camera ({n}), each "
                         f"{' or '.join(LENS_MODELS)}, got {lenses}.")
    mask_files = list(v["mask_files"])
    if len(mask_files) == 1:
        mask_files = mask_files * n
    mask_files = _per_camera(mask_files, n, "mask_files", lambda i: "")
    camera_masks = {name: read_mask(os.path.expanduser(path))
                    for name, path in zip(names, mask_files) if path}
    intrinsics_files = [os.path.expanduser(p) for p in v["intrinsics_files"]]
    if len(intrinsics_files) == 1:
        intrinsics_files = [p for p in intrinsics_files if p.strip()]
    elif intrinsics_files:
        intrinsics_files = [f"{name}={path}" for name, path in zip(
            names, _per_camera(intrinsics_files, n, "intrinsics_files", None)) if path]
    known_intrinsics = read_known_intrinsics(intrinsics_files, names)
    unknown = sorted(set(known_intrinsics) - set(names))
    if unknown:
        raise InputError(f"intrinsics_files name camera(s) {', '.join(unknown)}, which are not "
                         f"among {names}: give one file per camera in camera_names' order.")
    return lenses, camera_masks, known_intrinsics


def _frames(v: dict, names: list) -> tuple[list, str, str]:
    """(frame_names, rig_frame, floor_frame): valid tf frame ids, all different."""
    frames = _per_camera(list(v["frame_names"]), len(names), "frame_names",
                         lambda i: f"{names[i]}_optical_frame")
    rig_frame = v["rig_frame"]
    for f in frames + [rig_frame]:
        if not _FRAME_RE.match(f):
            raise InputError(f"Frame name {f!r} is not a valid tf frame id (letters, digits, "
                             "'_', '/', '.', '-').")
    if rig_frame in frames or len(set(frames)) != len(names):
        raise InputError(f"rig_frame {rig_frame!r} and frame_names {frames} must all differ "
                         "(a transform from a frame to itself is invalid in tf).")
    floor_frame = v["floor_frame"]
    if not _FRAME_RE.match(floor_frame) or floor_frame in frames + [rig_frame]:
        raise InputError(f"floor_frame {floor_frame!r} must be a valid tf frame id that differs "
                         f"from rig_frame and frame_names.")
    return frames, rig_frame, floor_frame


def _camera_info_outputs(v: dict, names: list, topics: list) -> tuple[list, list]:
    """(camera_info_topics, set_camera_info_services), one per camera, distinct."""
    n = len(names)
    # the node's own namespace by default: the driver publishes <image ns>/camera_info itself,
    # and two publishers of different CameraInfo on one topic leave each reader one at random
    info_topics = _per_camera(list(v["camera_info_topics"]), n, "camera_info_topics",
                              lambda i: f"~/{names[i]}/camera_info")
    services = _per_camera(list(v["set_camera_info_services"]), n, "set_camera_info_services",
                           lambda i: f"{topic_namespace(topics[i])}/set_camera_info")
    for what, lst in (("camera_info_topics", info_topics),
                      ("set_camera_info_services", services)):
        if len(set(lst)) != n:
            raise InputError(f"The default {what} collide ({lst}): set {what} explicitly, one per "
                             "camera.")
    return info_topics, services


def _camera_pairs(v: dict, names: list) -> tuple[list, list]:
    """(stereo_pairs as (left, right) tuples, baseline_cameras)."""
    paired = list(v["stereo_pairs"])
    if len(paired) % 2 or len(set(paired)) != len(paired) or any(c not in names
                                                                 for c in paired):
        raise InputError(f"stereo_pairs must list pairs of cameras of {names}, each as left then "
                         f"right, no camera twice (a CameraInfo holds one rectification), got "
                         f"{paired}.")
    baseline_cams = list(v["baseline_cameras"])
    if v["known_baseline_m"] > 0:
        if len(baseline_cams) != 2 or len(set(baseline_cams)) != 2 or \
                any(c not in names for c in baseline_cams):
            raise InputError(f"known_baseline_m > 0 needs baseline_cameras = two different names "
                             f"of {names}, got {baseline_cams}.")
    elif baseline_cams and (len(baseline_cams) != 2 or any(c not in names for c in baseline_cams)):
        raise InputError(f"baseline_cameras must be two of {names}, got {baseline_cams}.")
    return list(zip(paired[::2], paired[1::2])), baseline_cams
