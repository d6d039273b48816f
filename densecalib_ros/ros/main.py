"""The node's process (the `densecalib_node` executable): the node on a multi-threaded executor,
SIGTERM and Ctrl-C as a clean shutdown that answers a waiting ~/calibrate caller, and the exit
codes (0; 1 = invalid parameters)."""
from __future__ import annotations

import os
import signal
import sys
import time

import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

from ..core.colmap_logging import show_colmap_log
from ..core.errors import InputError
from .node import DenseCalibNode
from .transport import configure_intake_transport


def main(args=None) -> int:
    # Importing pycolmap installs glog's failure signal handlers, SIGTERM's among them: a stack
    # dump and exit 143 instead of a clean shutdown (systemd, docker stop, ros2 launch send
    # SIGTERM). So import it first and give SIGTERM back to rclpy, which chains to what it finds.
    # Ceres's recovered solver failures are no operator's concern: errors only.
    show_colmap_log(verbose=False)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    transport = configure_intake_transport()  # before the participant exists
    rclpy.init(args=args)
    node, executor, rc = None, None, 0
    try:
        node = DenseCalibNode()
        if transport is not None:
            said, capped = transport
            (node.get_logger().warning if capped else node.get_logger().info)(said)
        executor = MultiThreadedExecutor(num_threads=4)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except InputError as exc:
        rclpy.logging.get_logger("densecalib_node").fatal(f"invalid parameters: {exc}")
        rc = 1
    except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
        # rclpy's own checks of the declared types and ranges, before parse_settings
        rclpy.logging.get_logger("densecalib_node").fatal(
            f"invalid parameters: {exc} (a double takes a decimal point, slop_s:=1.0; a list "
            "takes brackets, image_topics:=\"['/cam0/image_raw', '/cam1/image_raw']\"; the "
            "ranges are in docs/ros.md's parameter table)")
        rc = 1
    except Exception:
        if rclpy.ok():
            raise
        # a signal shut the context down while the node was starting: as after spin
    finally:
        if node is not None:
            node.stop()  # a waiting ~/calibrate caller is answered, the worker writes nothing
            node.jobs.answer_waiting_callers(timeout_s=2.0)
            time.sleep(0.1)  # the executor thread sends the returned answer
            if executor is not None:
                executor.shutdown(timeout_sec=0)
            node.destroy_node()
        rclpy.try_shutdown()
    if node is not None and node.jobs.worker_running:
        # The abandoned calibration is inside OpenCV or COLMAP: at interpreter exit Python ends
        # such a daemon thread by unwinding it through their C++ frames, which aborts (SIGABRT,
        # exit 134, a stack dump). Nothing of it is kept, so end the process here instead.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    return rc
