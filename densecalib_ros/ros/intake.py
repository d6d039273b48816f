"""The image subscriptions, on a node and a single-threaded executor of their own.

The node's services and timers need rclpy's MultiThreadedExecutor (a ~/calibrate caller waits
for minutes, a watch check takes seconds), but that executor does not carry image streams: once
its callbacks fall behind, its spinning thread (found walking its list of pending tasks, which it
does after every wait) takes a whole core and the GIL from the callbacks, which fall further
behind (measured: docs/design-notes.md, Image intake executor). A SingleThreadedExecutor runs
each callback where it takes the message: no task list, no other thread to wait for.

The intake node ignores the process's --ros-args (use_global_arguments=False: a `__node:=` rename
would otherwise give it the main node's name); it subscribes to the topic names that the main
node resolved, with its namespace and remappings; an 'auto' topic once the graph tells its type."""
from __future__ import annotations

import threading
from typing import Callable, Optional

import rclpy
from rclpy.executors import ExternalShutdownException, ShutdownException, SingleThreadedExecutor
from rclpy.event_handler import SubscriptionEventCallbacks, UnsupportedEventTypeError
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CompressedImage, Image

INTAKE_SUFFIX = "_images"  # the intake node's name: the main node's with this after it
_WAKE_S = 0.1  # how often the spinning thread looks whether it should stop
_JOIN_TIMEOUT_S = 2.0  # a callback still running then (a decode) ends with the process


class ImageIntake:
    """Subscriptions whose callbacks run on one thread of their own, beside `parent`."""

    def __init__(self, parent: Node):
        self.node = rclpy.create_node(
            parent.get_name() + INTAKE_SUFFIX, namespace=parent.get_namespace(),
            context=parent.context, use_global_arguments=False, enable_rosout=False,
            start_parameter_services=False)
        self._executor = SingleThreadedExecutor(context=parent.context)
        self._executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="image intake", daemon=True)
        self._thread.start()

    def subscribe(self, msg_type, resolved_topic: str, callback: Callable,
                  on_lost: Optional[Callable[[int], None]] = None):
        """A best-effort (sensor data QoS) subscription to a fully resolved topic name;
        on_lost(total) hears the middleware's running count of messages it lost, where the
        middleware reports them."""
        events = None
        if on_lost is not None:
            events = SubscriptionEventCallbacks(
                message_lost=lambda info: on_lost(int(info.total_count)))
        try:
            return self.node.create_subscription(msg_type, resolved_topic, callback,
                                                 qos_profile_sensor_data, event_callbacks=events)
        except UnsupportedEventTypeError:  # a middleware without message-lost events
            return self.node.create_subscription(msg_type, resolved_topic, callback,
                                                 qos_profile_sensor_data)

    def _spin(self) -> None:
        try:
            while not self._stop.is_set() and self.node.context.ok():
                self._executor.spin_once(timeout_sec=_WAKE_S)
        except (ExternalShutdownException, ShutdownException):
            pass  # the context was shut down (Ctrl-C): the main node ends too
        except _rclpy.RCLError:
            # Ctrl-C between the check and the wait: rcl refuses a wait set on the shut-down
            # context (seen under load). Any other rcl error is a fault.
            if self.node.context.ok():
                raise

    def destroy(self) -> None:
        """Stop the thread, then the executor and the node (not while the thread waits on them:
        rclpy 7's Executor.shutdown destroys its guard condition without waiting for spin)."""
        if self._stop.is_set():
            return  # destroyed already
        self._stop.set()
        self._thread.join(_JOIN_TIMEOUT_S)
        self._executor.shutdown(timeout_sec=0)
        self.node.destroy_node()


class CameraSubscriptions:
    """Each camera's image topic subscribed on the intake, its messages added to `sync`: a topic
    whose transport is given (or whose name ends in /compressed) at once, an 'auto' one when
    subscribe_discovered finds its type in the graph."""

    def __init__(self, parent: Node, intake: ImageIntake, settings, sync):
        self._parent, self._intake, self._settings, self._sync = parent, intake, settings, sync
        self.subscriptions: list = [None] * len(settings.image_topics)
        for i, (topic, transport) in enumerate(zip(settings.image_topics, settings.transports)):
            if transport == "auto" and topic.rstrip("/").endswith("/compressed"):
                transport = "compressed"
            if transport != "auto":
                self._subscribe(i, CompressedImage if transport == "compressed" else Image)

    @property
    def complete(self) -> bool:
        return None not in self.subscriptions

    def subscribe_discovered(self) -> None:
        """Subscribe the 'auto' topics whose type the graph now tells."""
        types = dict(self._parent.get_topic_names_and_types())
        for i, topic in enumerate(self._settings.image_topics):
            if self.subscriptions[i] is not None:
                continue
            found = types.get(self._parent.resolve_topic_name(topic), [])
            if "sensor_msgs/msg/CompressedImage" in found:
                self._subscribe(i, CompressedImage)
            elif "sensor_msgs/msg/Image" in found:
                self._subscribe(i, Image)
            elif found:
                self._parent.get_logger().error(
                    f"{topic} has type {found}, not an image: fix image_topics",
                    throttle_duration_sec=30.0)

    def _subscribe(self, i: int, msg_type) -> None:
        s = self._settings
        topic = self._parent.resolve_topic_name(s.image_topics[i])  # namespace, remappings
        self.subscriptions[i] = self._intake.subscribe(
            msg_type, topic, lambda msg, i=i: self._sync.add(i, msg),
            on_lost=lambda total, i=i: self._sync.add_lost(i, total))
        given = "" if topic == s.image_topics[i] else f", image_topics: {s.image_topics[i]}"
        self._parent.get_logger().info(f"camera {s.camera_names[i]}: subscribed to {topic} "
                                       f"({msg_type.__name__}{given})")
