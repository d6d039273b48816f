"""`densecalib demo`: the README's main job, on an embedded default with no outside data.

Generates a rig (deterministic from --seed), starts densecalib_node in this process, publishes the
rig's images from one rclpy camera-driver node per camera, sends a goal to the node's ~/calibrate
action from an rclpy action client (its feedback printed as the stages go by), and prints what the
node published (CameraInfo focal lengths, /tf_static poses) against the ground
truth. Leaves OUT/rig/ (images + ground_truth.json) and the node's files OUT/<UTC time>/ +
OUT/latest. With --offline, no ROS: calibrate_rig on the same images, files in OUT/offline/.
Exit status: 0 calibrated, 1 calibration failed, 2 bad options.
"""
from __future__ import annotations

import argparse
import logging
import os
import threading
from pathlib import Path

import numpy as np

from ..core.config import DEFAULT_PIPELINE, PIPELINES, make_config
from ..core.errors import CalibrationError, InputError
from .argtypes import positive, seed

log = logging.getLogger("densecalib.demo")

MODELS = {"RADIAL": "regular", "OPENCV_FISHEYE": "fisheye"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--offline", action="store_true",
                        help="skip ROS: call calibrate_rig directly on the generated images")
    parser.add_argument("--out", default="demo_out", metavar="DIR",
                        help="output folder (default ./demo_out)")
    parser.add_argument("--cameras", type=int, default=5, help="number of cameras (3-10)")
    parser.add_argument("--model", choices=list(MODELS), default="RADIAL",
                        help="camera model of the generated rig (preset regular / fisheye)")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--time-steps", type=int, default=2,
                        help="frame sets (objects move between them)")
    parser.add_argument("--seed", type=seed, default=0, help="rig generator seed")
    parser.add_argument("--matcher", default="sift", help="matcher backend")
    parser.add_argument("--pipeline", choices=PIPELINES, default=DEFAULT_PIPELINE,
                        help=f"SfM pipeline (default: {DEFAULT_PIPELINE}; see docs/method.md)")
    parser.add_argument("--timeout", type=positive(), default=600.0, metavar="S",
                        help="seconds to wait for the calibration (the ~/calibrate action)")


def run(args: argparse.Namespace) -> int:
    from ..core.synthetic import RigSpec, generate_rig, write_rig

    if not 3 <= args.cameras <= 10:
        log.error("--cameras must be 3..10, got %d", args.cameras)
        return 2
    out = Path(args.out).resolve()
    spec = RigSpec(num_cameras=args.cameras, camera_model=args.model, width=args.width,
                   height=args.height, num_time_steps=args.time_steps, seed=args.seed)
    log.info("generating a %d-camera %s rig, %dx%d, %d frame set(s), seed %d", spec.num_cameras,
             spec.camera_model, spec.width, spec.height, spec.num_time_steps, spec.seed)
    try:
        rig = generate_rig(spec)
        write_rig(rig, out / "rig")
        config = make_config(MODELS[args.model], args.pipeline, args.matcher)
    except InputError as exc:
        log.error("%s", exc)
        return 2
    log.info("wrote the images and ground truth to %s", out / "rig")
    if args.offline:
        return _run_offline(rig, config, out)
    return _run_ros(rig, args, out)


def _run_offline(rig, config, out: Path) -> int:
    from ..core.io.export import write_calibration_files
    from ..core.io.safe_write import replace_directory_atomic
    from ..core.io.reference_view_files import latest_views
    from ..core import run_calibration

    try:
        result = run_calibration(rig.images, rig.names, config)
        views = latest_views(rig.images, rig.names, result.rig)
        replace_directory_atomic(lambda tmp: write_calibration_files(
            result.rig, tmp, result.reconstruction, reference_views=views), out / "offline")
    except CalibrationError as exc:
        log.error("calibration failed: %s", exc)
        return 1
    est = result.rig
    focal = {n: float(c.intrinsics.params[0]) for n, c in est.cameras.items()}
    rig_from_cam = {n: np.linalg.inv(c.cam_from_rig) for n, c in est.cameras.items()}
    _print_comparison(rig, focal, rig_from_cam, est.reference_camera,
                      f"offline calibrate_rig: RMS {est.quality.reprojection_rms_px:.2f} px, "
                      f"{est.quality.runtime_s:.1f} s")
    print(f"files: {out / 'offline'} (read them with: densecalib report {out / 'offline'})")
    return 0


def _run_ros(rig, args, out: Path) -> int:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.parameter import Parameter

    from ..ros.node import DenseCalibNode
    from ..ros.rig_nodes import (CalibrateGoalClient, CalibrationListener, CameraPublisherNode,
                                 wait_until)

    # Keep the demo's graph on this machine and off a user's default domain unless asked.
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    domain_id = int(os.environ.get("ROS_DOMAIN_ID", 50 + os.getpid() % 50))
    topics = [f"/demo/{name}/image_raw" for name in rig.names]
    params = dict(image_topics=topics, camera_names=list(rig.names), transports=["raw"],
                  output_dir=str(out), min_frame_sets=len(rig.images),
                  preset=MODELS[args.model], pipeline=args.pipeline, matcher=args.matcher,
                  slop_s=0.01, min_interval_s=0.5)
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    executor = MultiThreadedExecutor(num_threads=6, context=context)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    nodes = []
    # the node forwards the core library's log to rclpy's console: printed once, there
    core_log = logging.getLogger("densecalib_ros")
    core_log.propagate = False
    try:
        node = DenseCalibNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        drivers = [CameraPublisherNode(name, topic, "rgb8", context=context)
                   for name, topic in zip(rig.names, topics)]
        info_topics = {n: node.resolve_topic_name(t)
                       for n, t in zip(rig.names, node.settings.camera_info_topics)}
        listener = CalibrationListener(info_topics, "/densecalib_node/status", context=context)
        client = CalibrateGoalClient("/densecalib_node/calibrate", context=context)
        client.on_feedback = _FeedbackLines()
        nodes = [node, *drivers, listener, client]
        for n in nodes:
            executor.add_node(n)
        spinner.start()
        print(f"ROS domain {domain_id}: densecalib_node + {len(drivers)} camera driver nodes")
        if not _calibrate_through_the_node(node, drivers, client, rig, args.timeout):
            return 1
        if not wait_until(lambda: len(listener.snapshot()["camera_info"]) == len(rig.names)
                          and listener.rig_from_optical(), 10.0):
            log.error("CameraInfo / /tf_static not received within 10 s")
            return 1
        infos = listener.snapshot()["camera_info"]
        frames = listener.rig_from_optical()
        focal = {n: float(m.k[0]) for n, m in infos.items()}
        rig_from_cam = {n: frames[f"{n}_optical_frame"] for n in rig.names
                        if f"{n}_optical_frame" in frames}
        _print_comparison(rig, focal, rig_from_cam, node.calibration.reference_camera,
                          "published CameraInfo + /tf_static")
        print(f"files: {node.calibration_dir} (and {out / 'latest'}; read them with: "
              f"densecalib report {out})")
        return 0
    except (CalibrationError, TimeoutError) as exc:
        log.error("%s", exc)
        return 1
    finally:
        executor.shutdown(timeout_sec=5)
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown(context=context)
        core_log.propagate = True


def _calibrate_through_the_node(node, drivers, client, rig, timeout_s: float) -> bool:
    """Publish the rig's frame sets from the driver nodes until the node buffered each, send a
    goal to its ~/calibrate action and print the result; whether it calibrated."""
    from ..ros.rig_nodes import wait_until

    if not wait_until(lambda: all(d.num_subscribers() > 0 for d in drivers), 20.0):
        log.error("the node did not subscribe to the camera topics within 20 s")
        return False
    for t, images in enumerate(rig.images):
        for _attempt in range(3):
            for driver, image in zip(drivers, images):
                driver.publish_image(image, int((1 + t) * 1e9))
            if wait_until(lambda: len(node.sync) >= t + 1, 5.0):
                break
        print(f"published frame set {t + 1}/{len(rig.images)} on {len(drivers)} topics")
    print("sending a goal to the action /densecalib_node/calibrate ...")
    goal = client.send()
    if not goal.accepted:
        log.error("the node rejected the goal (see its status above)")
        return False
    _, result = client.result(goal, timeout_s)
    print(f"result: success={result.success}: {result.message}")
    return result.success


class _FeedbackLines:
    """The action's feedback as one printed line per stage label: where the run is, how much is
    done and the seconds left (feedback comes twice a second; the lines only when it moves on)."""

    def __init__(self):
        self._last = None

    def __call__(self, feedback) -> None:
        if (feedback.stage, feedback.label) == self._last:
            return
        self._last = (feedback.stage, feedback.label)
        left = (f", about {feedback.seconds_left:.0f} s left" if feedback.seconds_left >= 0
                else "")
        done = 100 * feedback.fraction_done
        print(f"  [{feedback.elapsed_s:5.1f} s] {feedback.label} ({done:.0f} % done{left})",
              flush=True)


def _print_comparison(rig, focal_px: dict, rig_from_cam: dict, reference: str, title: str):
    """Per camera: estimated vs true focal, and the rotation / translation-direction error of the
    camera's pose relative to the reference camera (scale-free)."""
    from ..core.metrics import auc, relative_pose_errors

    gt = rig.ground_truth()
    est_cam_from_rig = {n: np.linalg.inv(m) for n, m in rig_from_cam.items()}
    pairs = relative_pose_errors(est_cam_from_rig,
                                 {n: c.cam_from_rig for n, c in gt.cameras.items()})
    to_ref = {(p.j if p.i == reference else p.i): p for p in pairs if reference in (p.i, p.j)}
    print(f"\n{title} vs ground truth (reference camera {reference})")
    print(f"{'camera':<8} {'f_true_px':>9} {'f_est_px':>9} {'f_err_%':>7} {'rot_err_deg':>11} "
          f"{'tdir_err_deg':>12}")
    for name, cam in gt.cameras.items():
        f_true = float(cam.intrinsics.params[0])
        if name not in focal_px:
            print(f"{name:<8} {f_true:9.1f} {'-':>9} {'not calibrated':>32}")
            continue
        err = 100.0 * abs(focal_px[name] - f_true) / f_true
        p = to_ref.get(name)
        rot, tdir = (f"{p.rot_err_deg:11.2f}", f"{p.trans_dir_err_deg:12.2f}") if p else (
            f"{'(ref)':>11}", f"{'(ref)':>12}")
        print(f"{name:<8} {f_true:9.1f} {focal_px[name]:9.1f} {err:7.2f} {rot} {tdir}")
    print(f"all {len(pairs)} camera pairs: AUC@3 {auc(pairs, 3):.1f}, AUC@30 {auc(pairs, 30):.1f}, "
          f"max rotation error {max(p.rot_err_deg for p in pairs):.2f} deg, max translation-"
          f"direction error {max(p.trans_dir_err_deg for p in pairs):.2f} deg")
