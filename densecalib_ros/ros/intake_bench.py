"""How many of a rig's frames densecalib_node receives, and at what CPU cost (`densecalib
bench-node`).

Driver processes play the cameras: one process publishing every camera (a multi-camera driver,
or drivers sharing a component container) or one process per camera, with the Fast DDS profile
(FASTRTPS_DEFAULT_PROFILES_FILE) they are given: Fast DDS's shared-memory segment is one per
process, for all of its topics. The node runs as its users start it: `densecalib_node` in a
process of its own. What it received, and the frames it counted lost from the gaps in the
stamps, are read from its /diagnostics; its CPU time from /proc (Linux). Every run starts a fresh
node: the failure this was built to catch (session 28: an executor that took both cores in 4 of
16 node starts) came with a start, not with a frame.

The images are a blurred noise texture per camera that moves a few pixels from frame to frame
(motion tracking, `sync_window_s`, then sees motion); their messages are built before publishing,
so the drivers' cost is the middleware's, not the rendering's."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..core.errors import InputError
from ..core.io.image_encoding import COMPRESSED_FORMATS, encode_compressed

NODE_NAME = "densecalib_bench_node"
TOPIC_PREFIX = "/densecalib_bench"
_READY_TIMEOUT_S = 60.0  # the node's start (pycolmap, OpenCV imports) and discovery
_TAIL_S = 0.2  # after the last frame: it reaches the node (the CPU time is read then)
_SETTLE_S = 1.0  # after the last frame: the node's queues drain before its counts are read
_DIAG_TIMEOUT_S = 5.0  # the node publishes /diagnostics at 1 Hz
_MOVE_PX = 3  # the texture's shift from one frame to the next
_MAX_PREBUILT_BYTES = 256 * 2 ** 20  # messages built before publishing, all cameras together
DRIVER_LAYOUTS = {"one": "one driver process for all cameras",
                  "per-camera": "a driver process per camera"}


@dataclass
class IntakeBenchSpec:
    """The rig to play. encoding: a raw sensor_msgs/Image encoding (mono8, rgb8, bgr8) or jpeg /
    png (CompressedImage on '<topic>/compressed'); qos: 'sensor' (best effort, depth 5: what
    most camera drivers publish with) or 'reliable' (depth 10); sync_window_s: the node's
    parameter of that name (0: motion tracking off)."""

    cameras: int = 4
    width: int = 768
    height: int = 512
    encoding: str = "mono8"
    rate_hz: float = 15.0
    seconds: float = 10.0
    qos: str = "sensor"
    sync_window_s: float = 0.0

    @property
    def frames(self) -> int:
        return max(1, int(round(self.rate_hz * self.seconds)))

    @property
    def raw_frame_bytes(self) -> int:
        """One frame's pixels (a compressed one's source image)."""
        return self.width * self.height * (1 if self.encoding == "mono8" else 3)

    @property
    def compressed(self) -> bool:
        return self.encoding in COMPRESSED_FORMATS

    def topics(self) -> list[str]:
        suffix = "/compressed" if self.compressed else ""
        return [f"{TOPIC_PREFIX}/cam{c}/image_raw{suffix}" for c in range(self.cameras)]

    def names(self) -> list[str]:
        return [f"cam{c}" for c in range(self.cameras)]


def check_spec(spec: IntakeBenchSpec) -> None:
    if not 2 <= spec.cameras <= 64:
        raise InputError(f"--cameras {spec.cameras}: give 2 to 64 cameras (the node takes two "
                         "or more).")
    if not (16 <= spec.width <= 16384 and 16 <= spec.height <= 16384):
        raise InputError(f"--size {spec.width}x{spec.height}: give 16 to 16384 px a side.")
    if spec.encoding not in ("mono8", "rgb8", "bgr8", *COMPRESSED_FORMATS):
        raise InputError(f"--encoding {spec.encoding}: choose mono8, rgb8, bgr8, jpeg or png.")
    if not 0.1 <= spec.rate_hz <= 1000.0:
        raise InputError(f"--rate {spec.rate_hz}: give 0.1 to 1000 frames a second.")
    if not 0.5 <= spec.seconds <= 3600.0:
        raise InputError(f"--seconds {spec.seconds}: give 0.5 to 3600 s.")
    if spec.qos not in ("sensor", "reliable"):
        raise InputError(f"--qos {spec.qos}: choose sensor or reliable.")
    if spec.sync_window_s < 0.0:
        raise InputError(f"--sync-window-s {spec.sync_window_s}: give 0 (off) or more.")


# --- what the node says on /diagnostics ------------------------------------------------------

_PER_CAMERA = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)=(\d+)")


def per_camera_counts(value: str) -> dict[str, int]:
    """'cam0=150, cam1=149' (received_per_camera) or 'cam0=3 (2 % lately, 15.0 fps), ...'
    (lost_frames_per_camera) -> {camera: count}."""
    return {name: int(count) for name, count in _PER_CAMERA.findall(value)}


def _node_values(msg, node_name: str) -> Optional[dict[str, str]]:
    for status in msg.status:
        if status.name.split(":")[0] == node_name:
            return {kv.key: kv.value for kv in status.values}
    return None


# --- CPU time -------------------------------------------------------------------------------

def process_cpu_s(pid: int) -> Optional[float]:
    """User + system CPU seconds of a running process (Linux /proc); None where unreadable."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


# --- the drivers ---------------------------------------------------------------------------

def _textures(spec: IntakeBenchSpec, cameras: list[int]) -> list[np.ndarray]:
    import cv2

    shape = (spec.height, spec.width) if spec.encoding == "mono8" else (spec.height, spec.width, 3)
    out = []
    for c in cameras:
        noise = np.random.default_rng(c).integers(0, 256, shape, dtype=np.uint8)
        out.append(cv2.GaussianBlur(noise, (0, 0), 2.0))
    return out


def _phases(spec: IntakeBenchSpec) -> int:
    """How many shifted frames per camera are built beforehand (cycled through while publishing)."""
    return int(np.clip(_MAX_PREBUILT_BYTES // max(1, spec.raw_frame_bytes * spec.cameras), 2, 16))


def _messages(spec: IntakeBenchSpec, cameras: list[int]) -> list[list]:
    """messages[camera][phase], their stamps set when published."""
    from .conversions import numpy_to_compressed_msg, numpy_to_image_msg

    out = []
    for c, texture in zip(cameras, _textures(spec, cameras)):
        frame_id = f"cam{c}_optical_frame"
        msgs = []
        for k in range(_phases(spec)):
            image = np.roll(texture, _MOVE_PX * k, axis=1)
            msgs.append(numpy_to_compressed_msg(image, spec.encoding, 0, frame_id)
                        if spec.compressed else
                        numpy_to_image_msg(image, spec.encoding, 0, frame_id))
        out.append(msgs)
    return out


def driver_main() -> int:
    """A driver process: `python -c '...driver_main()' JSON` with JSON = {"spec", "cameras",
    "domain_id"}. Prints "ready" once every publisher has a subscriber, reads "START_MONOTONIC_S
    STAMP0_NS" from stdin, publishes on that schedule and prints its figures as one JSON line."""
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import CompressedImage, Image

    from .conversions import time_from_ns
    from .rig_nodes import wait_until

    job = json.loads(sys.argv[1])
    spec, cameras = IntakeBenchSpec(**job["spec"]), list(job["cameras"])
    messages = _messages(spec, cameras)
    qos = (qos_profile_sensor_data if spec.qos == "sensor"
           else QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    context = Context()
    rclpy.init(args=[], context=context, domain_id=int(job["domain_id"]))
    try:
        node = rclpy.create_node(f"densecalib_bench_driver_{cameras[0]}", context=context)
        topics = spec.topics()
        publishers = [node.create_publisher(CompressedImage if spec.compressed else Image,
                                            topics[c], qos) for c in cameras]
        if not wait_until(lambda: all(p.get_subscription_count() > 0 for p in publishers),
                          _READY_TIMEOUT_S, 0.05):
            print("no subscriber", flush=True)
            return 3
        print("ready", flush=True)
        start_s, stamp0_ns = sys.stdin.readline().split()
        t0, stamp0_ns = float(start_s), int(stamp0_ns)
        period_s, late = 1.0 / spec.rate_hz, 0
        cpu0 = time.process_time()
        for k in range(spec.frames):
            wait = t0 + k * period_s - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            elif wait < -period_s:
                late += 1
            stamp = time_from_ns(stamp0_ns + int(round(k * period_s * 1e9)))
            for pub, msgs in zip(publishers, messages):
                msg = msgs[k % len(msgs)]
                msg.header.stamp = stamp
                pub.publish(msg)
        print(json.dumps(dict(late=late, publish_s=time.monotonic() - t0,
                              cpu_s=time.process_time() - cpu0)), flush=True)
        time.sleep(0.5)  # best effort: the last frames leave before the participant goes
        node.destroy_node()
        return 0
    finally:
        rclpy.try_shutdown(context=context)


# --- one run --------------------------------------------------------------------------------

def _python(code: str) -> list[str]:
    return [sys.executable, "-c", f"import sys; {code}"]


def _node_command(spec: IntakeBenchSpec, output_dir: str) -> list[str]:
    topics, names = spec.topics(), spec.names()
    transport = "compressed" if spec.compressed else "raw"
    params = [f"image_topics:={topics}", f"camera_names:={names}",
              f"transports:={[transport] * len(topics)}", f"output_dir:={output_dir}",
              f"sync_window_s:={float(spec.sync_window_s)}"]
    args = ["--ros-args", "-r", f"__node:={NODE_NAME}"]
    for p in params:
        args += ["-p", p]
    return _python("from densecalib_ros.ros.main import main; sys.exit(main())") + args


class _Process:
    """A child process whose output lines are collected as they come."""

    def __init__(self, command: list[str], env: dict[str, str], stdin: bool = False):
        self.proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                                     text=True, env=env)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def running(self) -> bool:
        return self.proc.poll() is None

    def tail(self, n: int = 15) -> str:
        return "\n".join(self.lines[-n:])

    def stop(self, timeout_s: float = 20.0, grace_s: float = 0.0) -> Optional[int]:
        """Let it end by itself for grace_s, then SIGINT, then after timeout_s SIGKILL."""
        try:
            self.proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            pass
        if self.running():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(2.0)
        return self.proc.returncode


class _DiagnosticsListener:
    """The node's latest /diagnostics values, on a context and thread of this process."""

    def __init__(self, domain_id: int):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.context = Context()
        rclpy.init(args=[], context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("densecalib_bench_listener", context=self.context)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_msg, 10)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self.node)
        self._lock = threading.Lock()
        self._values: dict[str, str] = {}
        self.count = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on_msg(self, msg) -> None:
        values = _node_values(msg, NODE_NAME)
        if values is not None:
            with self._lock:
                self._values, self.count = values, self.count + 1

    def _spin(self) -> None:
        while not self._stop.is_set():
            self._executor.spin_once(timeout_sec=0.1)

    def values(self) -> dict[str, str]:
        with self._lock:
            return dict(self._values)

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self._thread.join(2.0)
        self._executor.shutdown(timeout_sec=0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _result_line(driver: _Process) -> str:
    """The driver's figures (a JSON line), '' before it printed them."""
    return next((line for line in reversed(driver.lines) if line.startswith("{")), "")


def _driver_groups(spec: IntakeBenchSpec, drivers: str) -> list[list[int]]:
    cams = list(range(spec.cameras))
    return [[c] for c in cams] if drivers == "per-camera" else [cams]


def run_once(spec: IntakeBenchSpec, drivers: str, domain_id: int, node_env: dict[str, str],
             driver_env: dict[str, str], listener: "_DiagnosticsListener") -> dict:
    """Start a node (in `node_env`) and the driver processes (in `driver_env`: one for all
    cameras, or one per camera), play the rig once, read what the node received."""
    from .rig_nodes import wait_until

    procs: list[_Process] = []
    with tempfile.TemporaryDirectory(prefix="densecalib_bench_node_") as output_dir:
        node = _Process(_node_command(spec, output_dir), node_env)
        try:
            for group in _driver_groups(spec, drivers):
                job = json.dumps(dict(spec=asdict(spec), cameras=group, domain_id=domain_id))
                procs.append(_Process(_python(
                    "from densecalib_ros.ros.intake_bench import driver_main; "
                    "sys.exit(driver_main())") + [job], driver_env, stdin=True))
            ready = wait_until(lambda: not node.running() or all(
                "ready" in p.lines or not p.running() for p in procs), _READY_TIMEOUT_S, 0.05)
            if not node.running():
                raise RuntimeError("densecalib_node exited; its last lines:\n" + node.tail())
            if not ready or not all("ready" in p.lines for p in procs):
                raise RuntimeError(
                    f"densecalib_node did not subscribe to every camera within "
                    f"{_READY_TIMEOUT_S:.0f} s (or a driver process failed). The node's last "
                    "lines:\n" + node.tail() + "\nA driver's:\n"
                    + next((p.tail() for p in procs if "ready" not in p.lines), ""))
            time.sleep(0.5)  # every publisher matched: let the last discovery replies settle
            t0, stamp0_ns = time.monotonic() + 0.3, time.time_ns() + 300_000_000
            for p in procs:
                p.proc.stdin.write(f"{t0!r} {stamp0_ns}\n")
                p.proc.stdin.flush()
            time.sleep(max(0.0, t0 - time.monotonic()))
            cpu0 = process_cpu_s(node.proc.pid)
            limit_s = spec.seconds + 30.0
            published = wait_until(lambda: all(_result_line(p) or not p.running()
                                               for p in procs), limit_s, 0.01)
            time.sleep(_TAIL_S)  # the last frames reach the node
            cpu1, window_s = process_cpu_s(node.proc.pid), time.monotonic() - t0
            if not published:
                raise RuntimeError("a driver process did not finish publishing in time")
            # Not waiting for the drivers to end: a participant's teardown hung once in ~30
            # runs; they are stopped below, once the counts are read.
            time.sleep(_SETTLE_S)
            # Two fresh /diagnostics messages after the settling: the later holds the final counts.
            seen = listener.count
            wait_until(lambda: listener.count >= seen + 2, 2 * _DIAG_TIMEOUT_S, 0.05)
            values = listener.values()
        finally:
            for p in procs:
                p.stop(5.0, grace_s=5.0)
            rc = node.stop()
    if not values:
        raise RuntimeError("no /diagnostics from densecalib_node; its last lines:\n"
                           + node.tail())
    figures = []
    for p in procs:
        try:
            figures.append(json.loads(_result_line(p)))
        except ValueError:
            raise RuntimeError("a driver process failed; its last lines:\n" + p.tail()) from None
    received = per_camera_counts(values.get("received_per_camera", ""))
    lost = per_camera_counts(values.get("lost_frames_per_camera", ""))
    names = spec.names()
    intake = next((m.group(1) for line in node.lines
                   for m in [re.search(r"over UDP with a ([\d.]+ MB) receive buffer", line)] if m),
                  None)
    return dict(published=spec.frames, publish_s=max(f["publish_s"] for f in figures),
                node_intake=f"UDP, {intake} receive buffer" if intake else "middleware defaults",
                late_frames=sum(f["late"] for f in figures),
                drivers_cpu_s=sum(f["cpu_s"] for f in figures),
                received={n: received.get(n, 0) for n in names},
                lost_counted={n: lost.get(n, 0) for n in names},
                matched_frame_sets=int(values.get("matched_frame_sets", "0") or 0),
                node_cpu_s=(cpu1 - cpu0) if cpu0 is not None and cpu1 is not None else None,
                node_cpu_window_s=window_s, node_exit=rc)


def run_bench(spec: IntakeBenchSpec, runs: int = 1, drivers: str = "one",
              domain_id: Optional[int] = None, driver_profile: Optional[str] = None,
              log=print) -> dict:
    """`runs` runs of the rig against a fresh node each; a JSON-ready report. drivers: 'one'
    process publishing every camera or 'per-camera' processes; driver_profile: a Fast DDS XML
    profile for the driver processes (the node keeps this process's environment); domain_id:
    None picks one off the user's default domain and a live rig."""
    check_spec(spec)
    if runs < 1:
        raise InputError(f"--runs {runs}: give 1 or more.")
    if drivers not in DRIVER_LAYOUTS:
        raise InputError(f"--drivers {drivers}: choose one or per-camera.")
    if driver_profile is not None and not Path(driver_profile).is_file():
        raise InputError(f"--driver-profile {driver_profile}: no such file.")
    if domain_id is None:
        domain_id = 50 + os.getpid() % 50
    node_env = {**os.environ, "ROS_DOMAIN_ID": str(domain_id)}
    node_env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    driver_env = dict(node_env)
    if driver_profile is not None:
        driver_env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(Path(driver_profile).resolve())
    import rclpy

    frame_bytes = (len(encode_compressed(_textures(spec, [0])[0], spec.encoding))
                   if spec.compressed else spec.raw_frame_bytes)
    listener = _DiagnosticsListener(domain_id)
    try:
        report = dict(spec=asdict(spec), drivers=drivers, frames=spec.frames,
                      frame_bytes=frame_bytes, domain_id=domain_id,
                      rmw=rclpy.get_rmw_implementation_identifier(),
                      driver_profile=driver_env.get("FASTRTPS_DEFAULT_PROFILES_FILE", ""),
                      node_profile=node_env.get("FASTRTPS_DEFAULT_PROFILES_FILE", ""), runs=[])
        for r in range(runs):
            log(f"run {r + 1}/{runs}: starting densecalib_node, {DRIVER_LAYOUTS[drivers]}")
            report["runs"].append(run_once(spec, drivers, domain_id, node_env, driver_env,
                                           listener))
            log(format_run(report["runs"][-1], r + 1))
    finally:
        listener.close()
    return report


# --- output --------------------------------------------------------------------------------

def format_run(run: dict, index: int) -> str:
    received = run["received"]
    pub = run["published"]
    cameras = ", ".join(f"{n} {k}" for n, k in received.items())
    lost = sum(run["lost_counted"].values())
    cpu = ("unmeasured" if run["node_cpu_s"] is None else
           f"{100 * run['node_cpu_s'] / run['node_cpu_window_s']:.0f} % of a core")
    late = f", {run['late_frames']} sets published late" if run["late_frames"] else ""
    return (f"run {index}: received of {pub}: {cameras}; counted lost {lost}; frame sets "
            f"matched {run['matched_frame_sets']}; node CPU {cpu}; publishing took "
            f"{run['publish_s']:.1f} s{late}")


def format_report(report: dict) -> str:
    s = report["spec"]
    runs = report["runs"]
    lines = [f"densecalib_node intake: {s['cameras']} cameras x {s['width']}x{s['height']} "
             f"{s['encoding']} ({report['frame_bytes'] / 1024:.0f} kB a frame) at "
             f"{s['rate_hz']:g} Hz for {s['seconds']:g} s ({report['frames']} frames a camera), "
             f"{s['qos']} QoS, motion tracking "
             + (f"on ({s['sync_window_s']:g} s)" if s["sync_window_s"] > 0 else "off")
             + f"; {DRIVER_LAYOUTS[report['drivers']]}; {report['rmw']}, driver profile: "
             f"{report['driver_profile'] or 'none'}, node: "
             + ", ".join(sorted({r.get('node_intake', '?') for r in runs}))]
    lines.append(f"{'run':>4} {'min received':>13} {'all cameras':>12} {'lost counted':>13} "
                 f"{'sets matched':>13} {'node CPU':>9}")
    for i, run in enumerate(runs, 1):
        received = list(run["received"].values())
        whole = sum(k == run["published"] for k in received)
        cpu = ("-" if run["node_cpu_s"] is None else
               f"{100 * run['node_cpu_s'] / run['node_cpu_window_s']:.0f} %")
        lines.append(f"{i:>4} {min(received):>7} / {run['published']:<4} "
                     f"{whole:>5} of {len(received):<4} {sum(run['lost_counted'].values()):>13} "
                     f"{run['matched_frame_sets']:>13} {cpu:>9}")
    frac = [min(r["received"].values()) / r["published"] for r in runs]
    lines.append(f"frames received by the worst camera: median {100 * np.median(frac):.1f} %, "
                 f"lowest {100 * min(frac):.1f} % over {len(runs)} run(s); node CPU in % of one "
                 "core while the frames arrived")
    return "\n".join(lines)
